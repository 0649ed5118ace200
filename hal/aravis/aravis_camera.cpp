#include "hal/aravis/aravis_camera.h"

#include <arv.h>
#include <time.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <sstream>

#include "core/clock.h"
#include "core/log.h"

namespace commonlight::hal::aravis {

namespace {

// The message of a GError (and frees it).
std::string takeMessage(GError*& error) {
    std::string message = error != nullptr && error->message != nullptr ? error->message : "unknown error";
    g_clear_error(&error);
    return message;
}

Result<void> check(GError*& error, const std::string& id, std::string_view what) {
    if (error == nullptr) return {};
    return fail(ErrorCode::kDevice, id + ": " + std::string(what) + ": " + takeMessage(error));
}

std::int64_t realtimeNowNs() noexcept {
    timespec ts{};
    clock_gettime(CLOCK_REALTIME, &ts);
    return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

// The fill-in of a short buffer: what arrived is copied, the rest is black.
void copyPacked(const std::uint8_t* src, std::size_t src_bytes, Image& out) {
    const std::size_t needed = out.sizeBytes();
    const std::size_t n = std::min(src_bytes, needed);
    if (src != nullptr && n > 0) std::memcpy(out.data(), src, n);
    if (n < needed) std::memset(out.data() + n, 0, needed - n);
}

void onControlLost(ArvDevice*, gpointer data);

}  // namespace

struct AravisCamera::Impl {
    ArvCamera* camera = nullptr;
    ArvDevice* device = nullptr;  // owned by camera
    ArvStream* stream = nullptr;
    gulong control_lost_handler = 0;
    std::atomic<bool> control_lost{false};
    bool device_failed = false;  // the camera thread ended with a device error
    bool gain_in_db = false;     // "Gain" in dB; otherwise "GainRaw" in the device's raw units
    bool has_exposure_auto = false;
    bool has_gain_auto = false;
    bool has_balance_white_auto = false;

    ~Impl() {
        if (stream != nullptr) g_object_unref(stream);
        if (device != nullptr && control_lost_handler != 0) g_signal_handler_disconnect(device, control_lost_handler);
        if (camera != nullptr) g_object_unref(camera);
    }
};

namespace {

void onControlLost(ArvDevice*, gpointer data) {
    // Runs on Aravis's heartbeat thread: only flag it; the camera thread reports it.
    static_cast<AravisCamera::Impl*>(data)->control_lost.store(true, std::memory_order_release);
}

bool featureAvailable(ArvCamera* camera, const char* feature) {
    GError* error = nullptr;
    const bool available = arv_camera_is_feature_available(camera, feature, &error) != FALSE;
    g_clear_error(&error);
    return available;
}

// GigE: only the client holding the control privilege may configure and stream. Aravis opens
// a device another client controls in monitor mode; take control now or say who has it.
Result<void> ensureControl(ArvDevice* device, const std::string& id) {
    if (!ARV_IS_GV_DEVICE(device)) return {};
    ArvGvDevice* gv = ARV_GV_DEVICE(device);
    if (arv_gv_device_is_controller(gv)) return {};
    GError* error = nullptr;
    if (arv_gv_device_take_control(gv, &error)) return {};
    return fail(ErrorCode::kDevice, id + ": another client controls the camera (" + takeMessage(error) +
                                        "); a client that died releases it after the device's heartbeat timeout");
}

}  // namespace

Result<std::unique_ptr<AravisCamera>> AravisCamera::open(const CameraUri& uri) {
    if (uri.path.empty()) {
        return fail(ErrorCode::kUsage, "camera URI '" + uri.text + "': expected aravis:<device address or id>");
    }
    CL_TRY(const AravisOptions options, AravisOptions::fromUri(uri));
    const std::string id = "aravis:" + uri.path;
    auto impl = std::make_unique<Impl>();
    GError* error = nullptr;
    impl->camera = arv_camera_new(uri.path.c_str(), &error);
    if (impl->camera == nullptr) {
        const bool not_found = error != nullptr && error->domain == ARV_DEVICE_ERROR && error->code == ARV_DEVICE_ERROR_NOT_FOUND;
        return fail(not_found ? ErrorCode::kNotFound : ErrorCode::kDevice,
                    id + ": cannot open the camera: " + takeMessage(error));
    }
    impl->device = arv_camera_get_device(impl->camera);
    impl->control_lost_handler =
        g_signal_connect(impl->device, "control-lost", G_CALLBACK(onControlLost), impl.get());
    impl->gain_in_db = featureAvailable(impl->camera, "Gain");
    impl->has_exposure_auto = featureAvailable(impl->camera, "ExposureAuto");
    impl->has_gain_auto = featureAvailable(impl->camera, "GainAuto");
    impl->has_balance_white_auto = featureAvailable(impl->camera, "BalanceWhiteAuto");
    auto camera = std::unique_ptr<AravisCamera>(new AravisCamera(id, std::move(impl), options));
    // Metadata of the first frames: the device's current settings.
    camera->refreshExposureAndGain();
    return camera;
}

AravisCamera::AravisCamera(std::string id, std::unique_ptr<Impl> impl, AravisOptions options)
    : Camera(std::move(id)), impl_(std::move(impl)), options_(options) {}

AravisCamera::~AravisCamera() { stop(); }

std::vector<StreamFormat> AravisCamera::doFormats() const {
    std::lock_guard lock(mutex_);
    GError* error = nullptr;
    guint n = 0;
    gint64* pfncs = arv_camera_dup_available_pixel_formats(impl_->camera, &n, &error);
    if (error != nullptr) {
        log::warning(id() + ": cannot list the pixel formats: " + takeMessage(error));
        g_free(pfncs);
        return {};
    }
    gint sensor_w = 0;
    gint sensor_h = 0;
    arv_camera_get_sensor_size(impl_->camera, &sensor_w, &sensor_h, &error);
    g_clear_error(&error);
    gint wmin = 0, wmax = 0, hmin = 0, hmax = 0;
    arv_camera_get_width_bounds(impl_->camera, &wmin, &wmax, &error);
    g_clear_error(&error);
    arv_camera_get_height_bounds(impl_->camera, &hmin, &hmax, &error);
    g_clear_error(&error);
    // The full sensor when the device says how large it is, else the largest region now allowed.
    const int width = sensor_w > 0 ? sensor_w : wmax;
    const int height = sensor_h > 0 ? sensor_h : hmax;
    // The device's current format first: without `format`, negotiation keeps it.
    const auto current = static_cast<gint64>(arv_camera_get_pixel_format(impl_->camera, &error));
    g_clear_error(&error);
    if (gint64* found = std::find(pfncs, pfncs + n, current); found != pfncs + n) std::rotate(pfncs, found, found + 1);
    std::vector<StreamFormat> out;
    for (guint i = 0; i < n; ++i) {
        const auto format = fromPfnc(static_cast<std::uint32_t>(pfncs[i]));
        if (!format) continue;
        if (std::any_of(out.begin(), out.end(), [&](const StreamFormat& f) { return f.format == *format; })) continue;
        out.push_back(StreamFormat{*format, width, height, {}, 0.0});
    }
    g_free(pfncs);
    return out;
}

Result<StreamFormat> AravisCamera::doConfigure(const StreamConfig& config) {
    const std::vector<StreamFormat> full = doFormats();
    std::vector<StreamFormat> offered = full;
    // Any region inside the sensor is offered: the requested size, when it fits at (x, y).
    if (config.width > 0 && config.height > 0) {
        for (const auto& f : full) {
            if (options_.x + config.width <= f.width && options_.y + config.height <= f.height) {
                offered.push_back(StreamFormat{f.format, config.width, config.height, {}, 0.0});
            }
        }
    } else if (options_.x > 0 || options_.y > 0) {
        // An offset without a size: the largest region that fits.
        for (auto& f : offered) {
            f.width -= options_.x;
            f.height -= options_.y;
        }
    }
    StreamConfig without_rate = config;
    without_rate.fps = 0.0;
    CL_TRY(StreamFormat chosen, negotiate(offered, without_rate, id()));

    std::lock_guard lock(mutex_);
    CL_TRY_VOID(ensureControl(impl_->device, id()));
    GError* error = nullptr;
    guint n = 0;
    gint64* available = arv_camera_dup_available_pixel_formats(impl_->camera, &n, &error);
    CL_TRY_VOID(check(error, id(), "listing pixel formats"));
    std::uint32_t pfnc = 0;
    for (const std::uint32_t wanted : toPfnc(chosen.format)) {
        if (std::any_of(available, available + n, [&](gint64 a) { return static_cast<std::uint32_t>(a) == wanted; })) {
            pfnc = wanted;
            break;
        }
    }
    g_free(available);
    if (pfnc == 0) return fail(ErrorCode::kInternal, id() + ": negotiated a format the device does not list");
    arv_camera_set_pixel_format(impl_->camera, pfnc, &error);
    CL_TRY_VOID(check(error, id(), "setting PixelFormat"));
    arv_camera_set_region(impl_->camera, options_.x, options_.y, chosen.width, chosen.height, &error);
    CL_TRY_VOID(check(error, id(), "setting the region " + std::to_string(chosen.width) + "x" +
                                       std::to_string(chosen.height) + "+" + std::to_string(options_.x) + "+" +
                                       std::to_string(options_.y)));
    gint x = 0, y = 0, w = 0, h = 0;
    arv_camera_get_region(impl_->camera, &x, &y, &w, &h, &error);
    CL_TRY_VOID(check(error, id(), "reading the region back"));
    if (x != options_.x || y != options_.y || w != chosen.width || h != chosen.height) {
        return fail(ErrorCode::kUnsupported,
                    id() + ": asked for the region " + std::to_string(chosen.width) + "x" + std::to_string(chosen.height) +
                        "+" + std::to_string(options_.x) + "+" + std::to_string(options_.y) + ", the device set " +
                        std::to_string(w) + "x" + std::to_string(h) + "+" + std::to_string(x) + "+" +
                        std::to_string(y) + " (sizes and offsets must be multiples of its increments)");
    }
    const bool has_rate = arv_camera_is_frame_rate_available(impl_->camera, &error) != FALSE;
    g_clear_error(&error);
    if (config.fps > 0) {
        if (!has_rate) return fail(ErrorCode::kUnsupported, id() + ": the device has no frame rate control");
        double min = 0, max = 0;
        arv_camera_get_frame_rate_bounds(impl_->camera, &min, &max, &error);
        CL_TRY_VOID(check(error, id(), "reading the frame rate bounds"));
        if (config.fps < min || config.fps > max) {
            std::ostringstream msg;
            msg << id() << ": cannot stream @" << config.fps << " fps; the device offers " << min << " to " << max
                << " fps";
            return fail(ErrorCode::kUnsupported, msg.str());
        }
        arv_camera_set_frame_rate(impl_->camera, config.fps, &error);
        CL_TRY_VOID(check(error, id(), "setting AcquisitionFrameRate"));
    }
    if (has_rate) {
        chosen.fps = arv_camera_get_frame_rate(impl_->camera, &error);
        g_clear_error(&error);
    }
    active_pfnc_ = pfnc;
    return chosen;
}

void AravisCamera::refreshExposureAndGain() {
    std::lock_guard lock(mutex_);
    if (auto e = readControl(Control::kExposureUs)) exposure_us_.store(*e, std::memory_order_relaxed);
    if (auto g = readControl(Control::kAnalogGain)) gain_.store(*g, std::memory_order_relaxed);
    if (auto a = readControl(Control::kAutoExposure)) auto_exposure_.store(*a != 0.0, std::memory_order_relaxed);
}

Result<void> AravisCamera::doStart() {
    std::lock_guard lock(mutex_);
    CL_TRY_VOID(ensureControl(impl_->device, id()));
    GError* error = nullptr;
    ArvCamera* cam = impl_->camera;
    if (arv_camera_is_gv_device(cam)) {
        if (options_.packet_size > 0) {
            arv_camera_gv_set_packet_size(cam, options_.packet_size, &error);
            CL_TRY_VOID(check(error, id(), "setting the packet size " + std::to_string(options_.packet_size)));
        } else {
            arv_camera_gv_auto_packet_size(cam, &error);
            if (error != nullptr) log::warning(id() + ": packet size negotiation failed: " + takeMessage(error));
        }
    }
    arv_camera_set_acquisition_mode(cam, ARV_ACQUISITION_MODE_CONTINUOUS, &error);
    CL_TRY_VOID(check(error, id(), "setting AcquisitionMode Continuous"));
    const guint payload = arv_camera_get_payload(cam, &error);
    CL_TRY_VOID(check(error, id(), "reading PayloadSize"));
    if (payload == 0) return fail(ErrorCode::kDevice, id() + ": the device reports a payload of 0 bytes");
    ArvStream* stream = arv_camera_create_stream(cam, nullptr, nullptr, &error);
    if (stream == nullptr) {
        return fail(ErrorCode::kDevice, id() + ": cannot create the stream: " + takeMessage(error));
    }
    g_clear_error(&error);
    if (ARV_IS_GV_STREAM(stream)) {
        GObjectClass* klass = G_OBJECT_GET_CLASS(stream);
        if (g_object_class_find_property(klass, "packet-resend") != nullptr) {
            g_object_set(stream, "packet-resend",
                         options_.packet_resend ? ARV_GV_STREAM_PACKET_RESEND_ALWAYS : ARV_GV_STREAM_PACKET_RESEND_NEVER,
                         nullptr);
        }
        if (options_.packet_timeout_ms && g_object_class_find_property(klass, "packet-timeout") != nullptr) {
            g_object_set(stream, "packet-timeout", static_cast<guint>(*options_.packet_timeout_ms * 1000), nullptr);
        }
        if (options_.frame_retention_ms && g_object_class_find_property(klass, "frame-retention") != nullptr) {
            g_object_set(stream, "frame-retention", static_cast<guint>(*options_.frame_retention_ms * 1000), nullptr);
        }
    }
    // Every device buffer is allocated here, once; the camera thread requeues them.
    for (int i = 0; i < options_.buffers; ++i) arv_stream_push_buffer(stream, arv_buffer_new_allocate(payload));
    impl_->stream = stream;
    impl_->control_lost.store(false, std::memory_order_relaxed);
    impl_->device_failed = false;
    frame_ids_.reset();
    clock_.reset();
    arv_camera_start_acquisition(cam, &error);
    if (error != nullptr) {
        g_object_unref(impl_->stream);
        impl_->stream = nullptr;
        return fail(ErrorCode::kDevice, id() + ": cannot start the acquisition: " + takeMessage(error));
    }
    thread_ = std::jthread([this](std::stop_token stop) { run(std::move(stop)); });
    return {};
}

void AravisCamera::doStop() noexcept {
    if (thread_.joinable()) {
        thread_.request_stop();
        thread_.join();
    }
    std::lock_guard lock(mutex_);
    if (!impl_->device_failed && !impl_->control_lost.load(std::memory_order_acquire)) {
        GError* error = nullptr;
        arv_camera_stop_acquisition(impl_->camera, &error);
        if (error != nullptr) log::warning(id() + ": stopping the acquisition: " + takeMessage(error));
    }
    if (impl_->stream != nullptr) {
        g_object_unref(impl_->stream);  // stops the stream thread and frees its buffers
        impl_->stream = nullptr;
    }
}

void AravisCamera::run(std::stop_token stop) {
    constexpr guint64 kPollUs = 100'000;  // stop() is noticed within this
    constexpr std::int64_t kRefreshNs = 200'000'000;
    const std::int64_t timeout_ns = static_cast<std::int64_t>(options_.timeout_ms) * 1'000'000;
    std::int64_t last_frame_ns = monotonicNowNs();
    std::int64_t last_refresh_ns = last_frame_ns;
    while (!stop.stop_requested()) {
        if (impl_->control_lost.load(std::memory_order_acquire)) {
            impl_->device_failed = true;
            emitEvent({CameraEvent::Type::kDeviceError,
                       Error{ErrorCode::kDevice, id() + ": lost control of the device (disconnected or powered off)"}});
            return;
        }
        ArvBuffer* buffer = arv_stream_timeout_pop_buffer(impl_->stream, kPollUs);
        const std::int64_t now = monotonicNowNs();
        if (buffer == nullptr) {
            if (now - last_frame_ns > timeout_ns) {
                impl_->device_failed = true;
                emitEvent({CameraEvent::Type::kDeviceError,
                           Error{ErrorCode::kDevice, id() + ": no frame for " + std::to_string(options_.timeout_ms) +
                                                         " ms (device disconnected or stream stalled; URI option timeout_ms)"}});
                return;
            }
            continue;
        }
        last_frame_ns = now;
        deliver(buffer);
        arv_stream_push_buffer(impl_->stream, buffer);
        if (auto_exposure_.load(std::memory_order_relaxed) && now - last_refresh_ns > kRefreshNs) {
            // The camera chooses exposure and gain: read what it chose, for the metadata.
            last_refresh_ns = now;
            refreshExposureAndGain();
        }
    }
}

void AravisCamera::deliver(void* opaque) {
    auto* buffer = static_cast<ArvBuffer*>(opaque);
    const ArvBufferStatus status = arv_buffer_get_status(buffer);
    if (status == ARV_BUFFER_STATUS_ABORTED || status == ARV_BUFFER_STATUS_CLEARED) return;  // no frame in it
    // Host arrival: Aravis's system timestamp (CLOCK_REALTIME when the frame arrived) moved to
    // CLOCK_MONOTONIC; our own pop time when it has none.
    const std::int64_t mono_now = monotonicNowNs();
    const auto system_ns = static_cast<std::int64_t>(arv_buffer_get_system_timestamp(buffer));
    const std::int64_t host_arrival_ns =
        system_ns > 0 ? std::min(mono_now, system_ns + (mono_now - realtimeNowNs())) : mono_now;
    const std::uint64_t sequence = frame_ids_.unwrap(arv_buffer_get_frame_id(buffer));
    const auto device_ns = static_cast<std::int64_t>(arv_buffer_get_timestamp(buffer));

    FrameHandle frame = acquireFrame();
    if (!frame) return;  // counted by the base class: lost in our pipeline
    FrameMetadata& meta = frame->meta;
    meta = FrameMetadata{};
    meta.sequence = sequence;
    if (device_ns > 0) {
        const auto mapped = clock_.toHost(device_ns, host_arrival_ns);
        meta.timestamp_ns = mapped.host_ns;
        meta.timestamp_source = TimestampSource::kSensor;
    } else {
        meta.timestamp_ns = host_arrival_ns;
        meta.timestamp_source = TimestampSource::kHost;
    }
    meta.exposure_us = exposure_us_.load(std::memory_order_relaxed);
    meta.analog_gain = gain_.load(std::memory_order_relaxed);

    const StreamFormat& format = activeFormat();
    size_t size = 0;
    const auto* data = static_cast<const std::uint8_t*>(arv_buffer_get_data(buffer, &size));
    if (status == ARV_BUFFER_STATUS_SUCCESS && arv_buffer_get_payload_type(buffer) != ARV_BUFFER_PAYLOAD_TYPE_IMAGE) {
        // Chunk data, JPEG, multipart: not streamed by this backend.
        frame->image.clear();
        meta.status = FrameStatus::kCorrupt;
        meta.arrival_ns = monotonicNowNs();
        emitFrame(std::move(frame));
        return;
    }
    if (status == ARV_BUFFER_STATUS_SUCCESS) {
        const auto pfnc = static_cast<std::uint32_t>(arv_buffer_get_image_pixel_format(buffer));
        const int w = arv_buffer_get_image_width(buffer);
        const int h = arv_buffer_get_image_height(buffer);
        if (pfnc != active_pfnc_ || w != format.width || h != format.height) {
            // Another client changed the device under us: these pixels are not what we configured.
            frame->image.clear();
            meta.status = FrameStatus::kCorrupt;
            meta.arrival_ns = monotonicNowNs();
            emitFrame(std::move(frame));
            return;
        }
    } else {
        meta.status = FrameStatus::kIncomplete;
        incomplete_.fetch_add(1, std::memory_order_relaxed);
    }
    frame->image.reshape(format.format, format.width, format.height);
    if (format.format == PixelFormat::kGray16) {
        copyGray16(data, data != nullptr ? size : 0, active_pfnc_, format.width, format.height, frame->image.data(),
                   frame->image.stride());
    } else {
        copyPacked(data, data != nullptr ? size : 0, frame->image);
    }
    meta.arrival_ns = monotonicNowNs();
    emitFrame(std::move(frame));
}

std::vector<ControlInfo> AravisCamera::doControls() const {
    std::lock_guard lock(mutex_);
    std::vector<ControlInfo> out;
    GError* error = nullptr;
    ArvCamera* cam = impl_->camera;
    double min = 0, max = 0;
    if (arv_camera_is_exposure_time_available(cam, &error)) {
        arv_camera_get_exposure_time_bounds(cam, &min, &max, &error);
        if (error == nullptr) out.push_back({Control::kExposureUs, min, max, 0.0, exposure_us_.load()});
    }
    g_clear_error(&error);
    if (arv_camera_is_gain_available(cam, &error)) {
        arv_camera_get_gain_bounds(cam, &min, &max, &error);
        if (error == nullptr) {
            if (impl_->gain_in_db) {
                out.push_back({Control::kAnalogGain, std::pow(10.0, min / 20.0), std::pow(10.0, max / 20.0), 0.0, gain_.load()});
            } else {
                out.push_back({Control::kAnalogGain, min, max, 1.0, gain_.load()});
            }
        }
    }
    g_clear_error(&error);
    if (impl_->has_exposure_auto || impl_->has_gain_auto) out.push_back({Control::kAutoExposure, 0, 1, 1, 0});
    if (impl_->has_balance_white_auto) out.push_back({Control::kAutoWhiteBalance, 0, 1, 1, 0});
    if (arv_camera_is_frame_rate_available(cam, &error)) {
        arv_camera_get_frame_rate_bounds(cam, &min, &max, &error);
        if (error == nullptr) out.push_back({Control::kFrameRate, min, max, 0.0, 0.0});
    }
    g_clear_error(&error);
    return out;
}

Result<double> AravisCamera::readControl(Control control) const {
    GError* error = nullptr;
    ArvCamera* cam = impl_->camera;
    const std::string name(controlName(control));
    const auto unsupported = [&] {
        return fail(ErrorCode::kUnsupported, id() + ": control " + name + " is not supported by this device");
    };
    switch (control) {
        case Control::kExposureUs: {
            if (!arv_camera_is_exposure_time_available(cam, &error)) {
                g_clear_error(&error);
                return unsupported();
            }
            const double value = arv_camera_get_exposure_time(cam, &error);
            CL_TRY_VOID(check(error, id(), "reading the exposure time"));
            return value;
        }
        case Control::kAnalogGain: {
            if (!arv_camera_is_gain_available(cam, &error)) {
                g_clear_error(&error);
                return unsupported();
            }
            const double value = arv_camera_get_gain(cam, &error);
            CL_TRY_VOID(check(error, id(), "reading the gain"));
            return impl_->gain_in_db ? std::pow(10.0, value / 20.0) : value;
        }
        case Control::kAutoExposure: {
            if (!impl_->has_exposure_auto && !impl_->has_gain_auto) return unsupported();
            const ArvAuto mode = impl_->has_exposure_auto ? arv_camera_get_exposure_time_auto(cam, &error)
                                                          : arv_camera_get_gain_auto(cam, &error);
            CL_TRY_VOID(check(error, id(), "reading the auto exposure mode"));
            return mode == ARV_AUTO_OFF ? 0.0 : 1.0;
        }
        case Control::kAutoWhiteBalance: {
            if (!impl_->has_balance_white_auto) return unsupported();
            const char* mode = arv_camera_get_string(cam, "BalanceWhiteAuto", &error);
            CL_TRY_VOID(check(error, id(), "reading BalanceWhiteAuto"));
            return mode != nullptr && std::strcmp(mode, "Off") != 0 ? 1.0 : 0.0;
        }
        case Control::kFrameRate: {
            if (!arv_camera_is_frame_rate_available(cam, &error)) {
                g_clear_error(&error);
                return unsupported();
            }
            const double value = arv_camera_get_frame_rate(cam, &error);
            CL_TRY_VOID(check(error, id(), "reading the frame rate"));
            return value;
        }
    }
    return unsupported();
}

std::string AravisCamera::doResponseSpec() const {
    ArvCamera* camera = impl_->camera;
    if (!featureAvailable(camera, "Gamma")) return "linear";  // machine-vision cameras without it are linear
    GError* error = nullptr;
    if (featureAvailable(camera, "GammaEnable")) {
        const gboolean enabled = arv_camera_get_boolean(camera, "GammaEnable", &error);
        if (error != nullptr) {
            g_clear_error(&error);
            return "linear";
        }
        if (!enabled) return "linear";
    }
    const double gamma = arv_camera_get_float(camera, "Gamma", &error);
    if (error != nullptr || !(gamma > 0.0) || !std::isfinite(gamma)) {
        g_clear_error(&error);
        return "linear";
    }
    return gammaResponseSpec(gamma);
}

Result<double> AravisCamera::doGetControl(Control control) const {
    std::lock_guard lock(mutex_);
    return readControl(control);
}

Result<void> AravisCamera::doSetControl(Control control, double value) {
    std::unique_lock lock(mutex_);
    GError* error = nullptr;
    ArvCamera* cam = impl_->camera;
    const std::string name(controlName(control));
    const auto out_of_range = [&](double min, double max) {
        std::ostringstream msg;
        msg << id() << ": " << name << " " << value << " is outside the device's range " << min << " to " << max;
        return fail(ErrorCode::kUsage, msg.str());
    };
    switch (control) {
        case Control::kExposureUs: {
            CL_TRY_VOID(readControl(control));  // kUnsupported when absent
            double min = 0, max = 0;
            arv_camera_get_exposure_time_bounds(cam, &min, &max, &error);
            CL_TRY_VOID(check(error, id(), "reading the exposure bounds"));
            if (value < min || value > max) return out_of_range(min, max);
            arv_camera_set_exposure_time(cam, value, &error);
            CL_TRY_VOID(check(error, id(), "setting the exposure time"));
            break;
        }
        case Control::kAnalogGain: {
            CL_TRY_VOID(readControl(control));
            double min = 0, max = 0;
            arv_camera_get_gain_bounds(cam, &min, &max, &error);
            CL_TRY_VOID(check(error, id(), "reading the gain bounds"));
            if (impl_->gain_in_db) {
                if (value <= 0) return fail(ErrorCode::kUsage, id() + ": gain must be positive (linear)");
                const double db = 20.0 * std::log10(value);
                if (db < min || db > max) return out_of_range(std::pow(10.0, min / 20.0), std::pow(10.0, max / 20.0));
                arv_camera_set_gain(cam, db, &error);
            } else {
                if (value < min || value > max) return out_of_range(min, max);
                arv_camera_set_gain(cam, value, &error);
            }
            CL_TRY_VOID(check(error, id(), "setting the gain"));
            break;
        }
        case Control::kAutoExposure: {
            if (!impl_->has_exposure_auto && !impl_->has_gain_auto) {
                return fail(ErrorCode::kUnsupported, id() + ": control " + name + " is not supported by this device");
            }
            const ArvAuto mode = value != 0.0 ? ARV_AUTO_CONTINUOUS : ARV_AUTO_OFF;
            if (impl_->has_exposure_auto) {
                arv_camera_set_exposure_time_auto(cam, mode, &error);
                CL_TRY_VOID(check(error, id(), "setting ExposureAuto"));
            }
            if (impl_->has_gain_auto) {
                arv_camera_set_gain_auto(cam, mode, &error);
                CL_TRY_VOID(check(error, id(), "setting GainAuto"));
            }
            auto_exposure_.store(value != 0.0, std::memory_order_relaxed);
            break;
        }
        case Control::kAutoWhiteBalance: {
            if (!impl_->has_balance_white_auto) {
                return fail(ErrorCode::kUnsupported, id() + ": control " + name + " is not supported by this device");
            }
            arv_camera_set_string(cam, "BalanceWhiteAuto", value != 0.0 ? "Continuous" : "Off", &error);
            CL_TRY_VOID(check(error, id(), "setting BalanceWhiteAuto"));
            break;
        }
        case Control::kFrameRate: {
            CL_TRY_VOID(readControl(control));
            double min = 0, max = 0;
            arv_camera_get_frame_rate_bounds(cam, &min, &max, &error);
            CL_TRY_VOID(check(error, id(), "reading the frame rate bounds"));
            if (value < min || value > max) return out_of_range(min, max);
            arv_camera_set_frame_rate(cam, value, &error);
            CL_TRY_VOID(check(error, id(), "setting the frame rate"));
            break;
        }
    }
    lock.unlock();
    // Every later frame's metadata carries the values the device now holds.
    refreshExposureAndGain();
    return {};
}

Result<std::vector<CameraInfo>> enumerateCameras() {
    arv_update_device_list();
    const unsigned int n = arv_get_n_devices();
    std::vector<CameraInfo> out;
    for (unsigned int i = 0; i < n; ++i) {
        const char* device_id = arv_get_device_id(i);
        if (device_id == nullptr) continue;
        const char* address = arv_get_device_address(i);
        const char* vendor = arv_get_device_vendor(i);
        const char* model = arv_get_device_model(i);
        const char* protocol = arv_get_device_protocol(i);
        CameraInfo info;
        info.uri = std::string("aravis:") + device_id;
        info.backend = "aravis";
        info.name = std::string(vendor != nullptr ? vendor : "") + " " + (model != nullptr ? model : "") + " (" +
                    (protocol != nullptr ? protocol : "?") + (address != nullptr ? std::string(" ") + address : "") + ")";
        CameraUri uri;
        uri.text = info.uri;
        uri.scheme = "aravis";
        uri.path = device_id;
        if (auto camera = AravisCamera::open(uri)) {
            info.formats = (*camera)->formats();
        } else {
            info.name += " [cannot open: " + camera.error().message + "]";
        }
        out.push_back(std::move(info));
    }
    return out;
}

}  // namespace commonlight::hal::aravis

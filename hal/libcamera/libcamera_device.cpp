// The only file of commonlight that includes libcamera. Kept thin: everything that can be
// decided without libcamera lives in mapping.cpp and libcamera_camera.cpp, tested there.
//
// Version differences (libcamera/version.h, checked at compile time):
//  - 0.0.x .. 0.4: auto exposure is controls::AeEnable.
//  - >= 0.5: AeEnable is only a compatibility wrapper; auto exposure is ExposureTimeMode and
//    AnalogueGainMode (Auto/Manual), used when the camera lists them.
//  - generateConfiguration() takes a StreamRoles vector up to 0.1 and a Span<const StreamRole>
//    later; generateConfiguration({role}) compiles against both.
//  - Request::reuse(ReuseBuffers), Camera::disconnected, properties::Model and
//    controls::FrameDurationLimits (int64_t[2], microseconds) exist in every release we support.
#include "hal/libcamera/libcamera_device.h"

#include <sys/mman.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <map>
#include <mutex>

#include <libcamera/camera.h>
#include <libcamera/camera_manager.h>
#include <libcamera/control_ids.h>
#include <libcamera/controls.h>
#include <libcamera/formats.h>
#include <libcamera/framebuffer.h>
#include <libcamera/framebuffer_allocator.h>
#include <libcamera/property_ids.h>
#include <libcamera/request.h>
#include <libcamera/stream.h>
#include <libcamera/version.h>

#include "hal/libcamera/mapping.h"

#define COMMONLIGHT_LIBCAMERA_AT_LEAST(major, minor) \
    (LIBCAMERA_VERSION_MAJOR > (major) || (LIBCAMERA_VERSION_MAJOR == (major) && LIBCAMERA_VERSION_MINOR >= (minor)))

namespace commonlight::hal::libcamera_backend {

namespace {

namespace lc = ::libcamera;

#define CL_STR2(x) #x
#define CL_STR(x) CL_STR2(x)
constexpr std::string_view kCompiledVersion =
    "v" CL_STR(LIBCAMERA_VERSION_MAJOR) "." CL_STR(LIBCAMERA_VERSION_MINOR) "." CL_STR(LIBCAMERA_VERSION_PATCH);

std::string errnoText(int negative_errno) { return std::strerror(negative_errno < 0 ? -negative_errno : negative_errno); }

// ---- the process-wide camera manager ----------------------------------------------------------

struct Manager {
    lc::CameraManager manager;
    bool started = false;
    ~Manager() {
        if (started) manager.stop();
    }
};

std::mutex g_manager_mutex;
std::weak_ptr<Manager> g_manager;

// libcamera logs INFO and WARN lines to stderr on every start (its version; on Debian, "No IPA
// found" because the IPA modules are a separate package), which would clutter `commonlight
// cameras`. Unless the user chose levels with LIBCAMERA_LOG_LEVELS, only its errors are shown.
// libcamera's logger reads that variable once, when it is created, which happens when the first
// log category is used: lazily, inside the first CameraManager. So setting the variable before
// the first manager starts is enough (logSetLevel() cannot do it: it only reaches categories
// that already exist). setenv() runs once, under g_manager_mutex, before libcamera has threads.
void quietLibcameraLog() {
    static bool done = false;
    if (done) return;
    done = true;
    setenv("LIBCAMERA_LOG_LEVELS", "*:ERROR", 0);  // 0: a user's setting wins
}

Result<std::shared_ptr<Manager>> sharedManager() {
    std::lock_guard lock(g_manager_mutex);
    if (auto existing = g_manager.lock()) return existing;
    quietLibcameraLog();
    auto fresh = std::make_shared<Manager>();
    if (const int ret = fresh->manager.start(); ret != 0) {
        return fail(ErrorCode::kDevice, "libcamera: starting the camera manager failed: " + errnoText(ret));
    }
    fresh->started = true;
    g_manager = fresh;
    return fresh;
}

lc::StreamRole toLibcamera(StreamRole role) {
    switch (role) {
        case StreamRole::kViewfinder: return lc::StreamRole::Viewfinder;
        case StreamRole::kVideoRecording: return lc::StreamRole::VideoRecording;
        case StreamRole::kStillCapture: return lc::StreamRole::StillCapture;
        case StreamRole::kRaw: return lc::StreamRole::Raw;
    }
    return lc::StreamRole::Viewfinder;
}

std::string modelOf(const lc::Camera& camera) {
    if (const auto model = camera.properties().get(lc::properties::Model); model && !model->empty()) return *model;
    return camera.id();
}

std::vector<DeviceFormat> formatsOf(lc::Camera& camera, StreamRole role) {
    std::vector<DeviceFormat> out;
    const std::unique_ptr<lc::CameraConfiguration> config = camera.generateConfiguration({toLibcamera(role)});
    if (!config || config->empty()) return out;
    const lc::StreamFormats& formats = config->at(0).formats();
    for (const lc::PixelFormat& pf : formats.pixelformats()) {
        const DeviceFormatId id{pf.fourcc(), pf.modifier()};
        std::vector<lc::Size> sizes = formats.sizes(pf);
        if (sizes.empty()) {
            // A continuous range: offer its ends.
            const lc::SizeRange range = formats.range(pf);
            sizes.push_back(range.max);
            if (range.min != range.max) sizes.push_back(range.min);
        }
        for (const lc::Size& size : sizes) {
            out.push_back({id, static_cast<int>(size.width), static_cast<int>(size.height)});
        }
    }
    return out;
}

std::optional<double> numeric(const lc::ControlValue& value) {
    if (value.isNone() || value.isArray()) return std::nullopt;
    switch (value.type()) {
        case lc::ControlTypeBool: return value.get<bool>() ? 1.0 : 0.0;
        case lc::ControlTypeByte: return static_cast<double>(value.get<uint8_t>());
        case lc::ControlTypeInteger32: return static_cast<double>(value.get<int32_t>());
        case lc::ControlTypeInteger64: return static_cast<double>(value.get<int64_t>());
        case lc::ControlTypeFloat: return static_cast<double>(value.get<float>());
        default: return std::nullopt;
    }
}

std::optional<DeviceRange> rangeOf(const lc::ControlInfoMap& map, const lc::ControlId& id) {
    const auto it = map.find(&id);
    if (it == map.end()) return std::nullopt;
    const lc::ControlInfo& info = it->second;
    DeviceRange range;
    range.min = numeric(info.min()).value_or(0.0);
    range.max = numeric(info.max()).value_or(range.min);
    range.default_value = numeric(info.def()).value_or(range.min);
    return range;
}

// ---- the device -------------------------------------------------------------------------------

class LibcameraDevice final : public Device {
public:
    LibcameraDevice(std::shared_ptr<Manager> manager, std::shared_ptr<lc::Camera> camera)
        : manager_(std::move(manager)), camera_(std::move(camera)), id_(camera_->id()), model_(modelOf(*camera_)) {
        camera_->requestCompleted.connect(this, &LibcameraDevice::onRequestCompleted);
        camera_->disconnected.connect(this, &LibcameraDevice::onDisconnected);
    }
    ~LibcameraDevice() override {
        stop();
        release();
        camera_->requestCompleted.disconnect(this);
        camera_->disconnected.disconnect(this);
        camera_->release();
    }

    const std::string& cameraId() const override { return id_; }
    const std::string& model() const override { return model_; }
    std::vector<DeviceFormat> formats(StreamRole role) const override { return formatsOf(*camera_, role); }

    DeviceControls controls() const override {
        const lc::ControlInfoMap& map = camera_->controls();
        DeviceControls out;
        out.exposure_time_us = rangeOf(map, lc::controls::ExposureTime);
        out.analogue_gain = rangeOf(map, lc::controls::AnalogueGain);
        out.ae_enable = rangeOf(map, lc::controls::AeEnable);
#if COMMONLIGHT_LIBCAMERA_AT_LEAST(0, 5)
        if (map.find(&lc::controls::ExposureTimeMode) != map.end()) out.ae_enable = DeviceRange{0, 1, 1};
#endif
        out.awb_enable = rangeOf(map, lc::controls::AwbEnable);
        out.frame_duration_us = rangeOf(map, lc::controls::FrameDurationLimits);
        return out;
    }

    Result<ConfigureResult> configure(StreamRole role, const DeviceStreamConfig& wanted) override {
        config_ = camera_->generateConfiguration({toLibcamera(role)});
        if (!config_ || config_->empty()) {
            return fail(ErrorCode::kDevice, "libcamera camera " + id_ + " offers no configuration for the " +
                                                std::string(streamRoleName(role)) + " role");
        }
        lc::StreamConfiguration& stream = config_->at(0);
        stream.pixelFormat = lc::PixelFormat(wanted.format.fourcc, wanted.format.modifier);
        stream.size = lc::Size(static_cast<unsigned>(wanted.width), static_cast<unsigned>(wanted.height));
        if (wanted.buffer_count > 0) stream.bufferCount = wanted.buffer_count;
        ConfigureResult result;
        switch (config_->validate()) {
            case lc::CameraConfiguration::Valid: result.status = ValidationStatus::kValid; break;
            case lc::CameraConfiguration::Adjusted: result.status = ValidationStatus::kAdjusted; break;
            case lc::CameraConfiguration::Invalid: result.status = ValidationStatus::kInvalid; break;
        }
        result.config.format = {stream.pixelFormat.fourcc(), stream.pixelFormat.modifier()};
        result.config.width = static_cast<int>(stream.size.width);
        result.config.height = static_cast<int>(stream.size.height);
        result.config.stride = stream.stride;
        result.config.frame_size = stream.frameSize;
        result.config.buffer_count = stream.bufferCount;
        if (result.status == ValidationStatus::kInvalid) return result;
        if (const int ret = camera_->configure(config_.get()); ret != 0) {
            return fail(ErrorCode::kDevice, "libcamera camera " + id_ + ": configure failed: " + errnoText(ret));
        }
        stream_ = stream.stream();
        return result;
    }

    Result<unsigned> allocate() override {
        release();
        if (stream_ == nullptr) return fail(ErrorCode::kDevice, "libcamera camera " + id_ + ": allocate before configure");
        allocator_ = std::make_unique<lc::FrameBufferAllocator>(camera_);
        if (const int ret = allocator_->allocate(stream_); ret < 0) {
            allocator_.reset();
            return fail(ErrorCode::kDevice, "libcamera camera " + id_ + ": allocating buffers failed: " + errnoText(ret));
        }
        const auto& buffers = allocator_->buffers(stream_);
        planes_.assign(buffers.size(), {});
        for (std::size_t i = 0; i < buffers.size(); ++i) {
            lc::FrameBuffer* buffer = buffers[i].get();
            if (auto mapped = mapBuffer(*buffer, planes_[i]); !mapped) {
                release();
                return fail(std::move(mapped).error());
            }
            std::unique_ptr<lc::Request> request = camera_->createRequest(i);
            if (!request) {
                release();
                return fail(ErrorCode::kDevice, "libcamera camera " + id_ + ": creating a request failed");
            }
            if (const int ret = request->addBuffer(stream_, buffer); ret < 0) {
                release();
                return fail(ErrorCode::kDevice, "libcamera camera " + id_ + ": adding a buffer to a request failed: " +
                                                    errnoText(ret));
            }
            requests_.push_back(std::move(request));
        }
        return static_cast<unsigned>(requests_.size());
    }

    void release() noexcept override {
        requests_.clear();
        for (const auto& [address, length] : mappings_) munmap(address, length);
        mappings_.clear();
        planes_.clear();
        if (allocator_ && stream_ != nullptr) allocator_->free(stream_);
        allocator_.reset();
    }

    void setHandlers(CompletionHandler on_complete, DisconnectHandler on_disconnect) override {
        on_complete_ = std::move(on_complete);
        on_disconnect_ = std::move(on_disconnect);
    }

    Result<void> start(const RequestControls& initial) override {
        lc::ControlList controls(camera_->controls());
        apply(initial, controls);
        if (const int ret = camera_->start(&controls); ret != 0) {
            return fail(ErrorCode::kDevice, "libcamera camera " + id_ + ": start failed: " + errnoText(ret));
        }
        started_ = true;
        return {};
    }

    Result<void> queue(unsigned index, const RequestControls& controls) override {
        if (index >= requests_.size()) return fail(ErrorCode::kInternal, "libcamera camera " + id_ + ": no request " + std::to_string(index));
        lc::Request* request = requests_[index].get();
        request->reuse(lc::Request::ReuseBuffers);
        if (!controls.empty()) apply(controls, request->controls());
        if (const int ret = camera_->queueRequest(request); ret < 0) {
            return fail(ErrorCode::kDevice, "libcamera camera " + id_ + ": queueing a request failed: " + errnoText(ret));
        }
        return {};
    }

    void stop() noexcept override {
        if (!started_) return;
        started_ = false;
        camera_->stop();  // pending requests complete, cancelled, before this returns
    }

private:
    Result<void> mapBuffer(const lc::FrameBuffer& buffer, std::array<PlaneData, 3>& planes) {
        // Planes may share one dmabuf at different offsets: map each fd once, whole.
        std::map<int, std::pair<std::uint8_t*, std::size_t>> mapped;
        std::map<int, std::size_t> extent;
        for (const auto& plane : buffer.planes()) {
            const std::size_t offset = plane.offset == lc::FrameBuffer::Plane::kInvalidOffset ? 0 : plane.offset;
            auto& end = extent[plane.fd.get()];
            end = std::max(end, offset + plane.length);
        }
        for (const auto& [fd, length] : extent) {
            void* address = mmap(nullptr, length, PROT_READ, MAP_SHARED, fd, 0);
            if (address == MAP_FAILED) {
                const int err = errno;
                return fail(ErrorCode::kDevice, "libcamera camera " + id_ + ": mapping a buffer failed: " + errnoText(err));
            }
            mappings_.emplace_back(address, length);
            mapped[fd] = {static_cast<std::uint8_t*>(address), length};
        }
        std::size_t i = 0;
        for (const auto& plane : buffer.planes()) {
            if (i == planes.size()) break;
            const std::size_t offset = plane.offset == lc::FrameBuffer::Plane::kInvalidOffset ? 0 : plane.offset;
            planes[i++] = PlaneData{mapped[plane.fd.get()].first + offset, 0, plane.length};
        }
        return {};
    }

    void apply(const RequestControls& in, lc::ControlList& out) const {
        if (in.exposure_time_us) out.set(lc::controls::ExposureTime, *in.exposure_time_us);
        if (in.analogue_gain) out.set(lc::controls::AnalogueGain, *in.analogue_gain);
        if (in.ae_enable) {
#if COMMONLIGHT_LIBCAMERA_AT_LEAST(0, 5)
            const lc::ControlInfoMap& map = camera_->controls();
            if (map.find(&lc::controls::ExposureTimeMode) != map.end()) {
                out.set(lc::controls::ExposureTimeMode,
                        *in.ae_enable ? lc::controls::ExposureTimeModeAuto : lc::controls::ExposureTimeModeManual);
                if (map.find(&lc::controls::AnalogueGainMode) != map.end()) {
                    out.set(lc::controls::AnalogueGainMode,
                            *in.ae_enable ? lc::controls::AnalogueGainModeAuto : lc::controls::AnalogueGainModeManual);
                }
            } else {
                out.set(lc::controls::AeEnable, *in.ae_enable);
            }
#else
            out.set(lc::controls::AeEnable, *in.ae_enable);
#endif
        }
        if (in.awb_enable) out.set(lc::controls::AwbEnable, *in.awb_enable);
        if (in.frame_duration_us) {
            const std::int64_t limits[2] = {*in.frame_duration_us, *in.frame_duration_us};
            out.set(lc::controls::FrameDurationLimits, lc::Span<const std::int64_t, 2>(limits));
        }
    }

    // libcamera's thread.
    void onRequestCompleted(lc::Request* request) {
        if (!on_complete_) return;
        CompletedRequest done;
        done.index = static_cast<unsigned>(request->cookie());
        if (request->status() == lc::Request::RequestCancelled) done.status = CompletedRequest::Status::kCancelled;
        if (const lc::FrameBuffer* buffer = request->findBuffer(stream_); buffer != nullptr && done.index < planes_.size()) {
            const lc::FrameMetadata& md = buffer->metadata();
            done.sequence = md.sequence;
            done.buffer_timestamp_ns = md.timestamp;
            if (md.status == lc::FrameMetadata::FrameError && done.status == CompletedRequest::Status::kOk) {
                done.status = CompletedRequest::Status::kError;
            }
            if (md.status == lc::FrameMetadata::FrameCancelled) done.status = CompletedRequest::Status::kCancelled;
            const auto used = md.planes();
            const auto& planes = planes_[done.index];
            for (std::size_t i = 0; i < planes.size() && planes[i].data != nullptr; ++i) {
                done.planes[i] = planes[i];
                done.planes[i].bytes_used = i < used.size() ? used[i].bytesused : 0;
                done.plane_count = static_cast<unsigned>(i + 1);
            }
        } else if (done.status == CompletedRequest::Status::kOk) {
            done.status = CompletedRequest::Status::kError;
        }
        const lc::ControlList& metadata = request->metadata();
        if (const auto ts = metadata.get(lc::controls::SensorTimestamp)) done.sensor_timestamp_ns = *ts;
        if (const auto exposure = metadata.get(lc::controls::ExposureTime)) done.exposure_time_us = *exposure;
        if (const auto gain = metadata.get(lc::controls::AnalogueGain)) done.analogue_gain = *gain;
        if (const auto duration = metadata.get(lc::controls::FrameDuration)) done.frame_duration_us = *duration;
        on_complete_(done);
    }

    void onDisconnected() {
        if (on_disconnect_) on_disconnect_();
    }

    std::shared_ptr<Manager> manager_;  // outlives the camera
    std::shared_ptr<lc::Camera> camera_;
    std::string id_;
    std::string model_;
    std::unique_ptr<lc::CameraConfiguration> config_;
    lc::Stream* stream_ = nullptr;
    std::unique_ptr<lc::FrameBufferAllocator> allocator_;
    std::vector<std::unique_ptr<lc::Request>> requests_;
    std::vector<std::pair<void*, std::size_t>> mappings_;
    std::vector<std::array<PlaneData, 3>> planes_;  // per request, data pointers into mappings_
    CompletionHandler on_complete_;
    DisconnectHandler on_disconnect_;
    bool started_ = false;
};

std::string listOf(const std::vector<std::shared_ptr<lc::Camera>>& cameras) {
    if (cameras.empty()) return " none";
    std::string out;
    for (std::size_t i = 0; i < cameras.size(); ++i) {
        out += "\n  " + std::to_string(i) + ": " + cameras[i]->id() + " (" + modelOf(*cameras[i]) + ")";
    }
    return out;
}

}  // namespace

Result<std::vector<CameraListing>> listCameras(StreamRole role) {
    CL_TRY(const std::shared_ptr<Manager> manager, sharedManager());
    std::vector<CameraListing> out;
    for (const auto& camera : manager->manager.cameras()) {
        out.push_back({camera->id(), modelOf(*camera), formatsOf(*camera, role)});
    }
    return out;
}

Result<std::unique_ptr<Device>> openDevice(std::string_view selector, const std::string& uri) {
    CL_TRY(std::shared_ptr<Manager> manager, sharedManager());
    const auto cameras = manager->manager.cameras();
    std::shared_ptr<lc::Camera> camera;
    const bool numeric_selector =
        !selector.empty() && selector.size() < 6 && std::all_of(selector.begin(), selector.end(), [](char c) { return c >= '0' && c <= '9'; });
    if (numeric_selector) {
        const std::size_t index = std::stoul(std::string(selector));
        if (index < cameras.size()) camera = cameras[index];
    }
    if (!camera) camera = manager->manager.get(std::string(selector));
    if (!camera) {
        return fail(ErrorCode::kNotFound, uri + ": no libcamera camera '" + std::string(selector) +
                                              "'; libcamera lists:" + listOf(cameras));
    }
    if (const int ret = camera->acquire(); ret != 0) {
        return fail(ErrorCode::kDevice, uri + ": cannot acquire libcamera camera " + camera->id() + ": " +
                                            (ret == -EBUSY ? std::string("in use by another process or camera") : errnoText(ret)));
    }
    return std::unique_ptr<Device>(std::make_unique<LibcameraDevice>(std::move(manager), std::move(camera)));
}

std::string libcameraVersion() { return lc::CameraManager::version(); }

std::string_view compiledLibcameraVersion() noexcept { return kCompiledVersion; }

}  // namespace commonlight::hal::libcamera_backend

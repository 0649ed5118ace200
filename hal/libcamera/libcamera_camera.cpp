#include "hal/libcamera/libcamera_camera.h"

#include <time.h>

#include <algorithm>
#include <utility>

#include "core/clock.h"
#include "core/log.h"

namespace commonlight::hal::libcamera_backend {

namespace {

std::int64_t boottimeNowNs() noexcept {
    timespec ts{};
    clock_gettime(CLOCK_BOOTTIME, &ts);
    return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

}  // namespace

LibcameraCamera::LibcameraCamera(std::string id, std::unique_ptr<Device> device, LibcameraOptions options)
    : Camera(std::move(id)), device_(std::move(device)), options_(options), device_controls_(device_->controls()) {}

LibcameraCamera::~LibcameraCamera() {
    stop();
    if (allocated_) device_->release();
}

std::vector<StreamFormat> LibcameraCamera::doFormats() const { return offeredFormats(device_->formats(options_.role)); }

Result<StreamFormat> LibcameraCamera::doConfigure(const StreamConfig& config) {
    const std::vector<StreamFormat> offered = doFormats();
    CL_TRY(StreamFormat negotiated, negotiate(offered, config, id()));
    RequestControls rate;
    if (config.fps > 0) {
        const auto range = fpsRange(device_controls_);
        if (!range) {
            return commonlight::fail(ErrorCode::kUnsupported,
                                     id() + ": cannot set " + std::to_string(config.fps) +
                                         " fps: the camera has no FrameDurationLimits control");
        }
        CL_TRY_VOID(setRequestControl(Control::kFrameRate, config.fps, device_controls_, rate, id()));
    }
    if (allocated_) {
        device_->release();
        allocated_ = false;
    }
    CL_TRY(const ConfigureResult result, device_->configure(options_.role, deviceConfigFor(negotiated, options_.buffers)));
    CL_TRY(Acceptance accepted, acceptConfiguration(result, negotiated, offered, id()));
    if (!accepted.warning.empty()) log::warning(accepted.warning);
    format_ = accepted.format;
    device_config_ = result.config;
    std::lock_guard lock(controls_mutex_);
    pending_.merge(rate);
    requested_.merge(rate);
    return format_;
}

Result<void> LibcameraCamera::doStart() {
    if (!allocated_) {
        CL_TRY(request_count_, device_->allocate());
        if (request_count_ == 0) return commonlight::fail(ErrorCode::kDevice, id() + ": libcamera allocated no buffers");
        allocated_ = true;
    }
    device_->setHandlers([this](const CompletedRequest& request) { onComplete(request); }, [this] { onDisconnect(); });
    sequence_.reset();
    failed_.store(false);
    reported_exposure_us_.store(0.0);
    reported_gain_.store(0.0);
    reported_fps_.store(0.0);
    RequestControls initial;
    {
        std::lock_guard lock(controls_mutex_);
        initial = std::exchange(pending_, {});
    }
    CL_TRY_VOID(device_->start(initial));
    running_.store(true);
    // One request per buffer, queued once; completions requeue them.
    for (unsigned i = 0; i < request_count_; ++i) {
        if (auto queued = device_->queue(i, {}); !queued) {
            running_.store(false);
            device_->stop();
            return commonlight::fail(ErrorCode::kDevice, id() + ": queueing request " + std::to_string(i) +
                                                             " failed: " + queued.error().message);
        }
    }
    return {};
}

void LibcameraCamera::doStop() noexcept {
    running_.store(false);
    device_->stop();  // pending requests come back cancelled and are not requeued
}

void LibcameraCamera::onComplete(const CompletedRequest& request) {
    if (request.status == CompletedRequest::Status::kCancelled || !running_.load()) return;
    const std::int64_t mono_now = monotonicNowNs();
    FrameHandle frame = acquireFrame();
    if (frame) {
        Frame& f = *frame;
        f.meta = FrameMetadata{};
        f.meta.status = copyFrame(request, format_, device_config_, f.image);
        f.meta.sequence = sequence_.next(request.sequence);
        const FrameTiming timing = frameTiming(request, mono_now, boottimeNowNs());
        f.meta.timestamp_ns = timing.timestamp_ns;
        f.meta.timestamp_source = timing.source;
        f.meta.exposure_us = request.exposure_time_us ? static_cast<double>(*request.exposure_time_us) : 0.0;
        f.meta.analog_gain = request.analogue_gain ? static_cast<double>(*request.analogue_gain) : 0.0;
    } else {
        sequence_.next(request.sequence);  // keep the unwrapper in step
    }
    if (request.status == CompletedRequest::Status::kError) failed_requests_.fetch_add(1, std::memory_order_relaxed);
    if (request.exposure_time_us) reported_exposure_us_.store(*request.exposure_time_us, std::memory_order_relaxed);
    if (request.analogue_gain) reported_gain_.store(*request.analogue_gain, std::memory_order_relaxed);
    if (request.frame_duration_us && *request.frame_duration_us > 0) {
        reported_fps_.store(fpsForFrameDurationUs(*request.frame_duration_us), std::memory_order_relaxed);
    }

    // The pixels are copied: the request goes back at once, with the controls set since.
    RequestControls controls;
    {
        std::lock_guard lock(controls_mutex_);
        controls = std::exchange(pending_, {});
    }
    if (auto queued = device_->queue(request.index, controls); !queued && running_.load()) {
        reportFailure(id() + ": requeueing a request failed: " + queued.error().message);
        return;
    }
    if (frame) {
        frame->meta.arrival_ns = monotonicNowNs();
        emitFrame(std::move(frame));
    }
}

void LibcameraCamera::onDisconnect() {
    reportFailure(id() + ": camera disconnected (libcamera camera " + device_->cameraId() + ")");
}

void LibcameraCamera::reportFailure(std::string message) {
    running_.store(false);
    if (failed_.exchange(true)) return;  // one event per stream
    emitEvent({CameraEvent::Type::kDeviceError, Error{ErrorCode::kDevice, std::move(message)}});
}

std::vector<ControlInfo> LibcameraCamera::doControls() const { return controlInfos(device_controls_); }

Result<void> LibcameraCamera::doSetControl(Control control, double value) {
    RequestControls change;
    CL_TRY_VOID(setRequestControl(control, value, device_controls_, change, id()));
    std::lock_guard lock(controls_mutex_);
    pending_.merge(change);
    requested_.merge(change);
    return {};
}

Result<double> LibcameraCamera::doGetControl(Control control) const {
    const auto unsupported = [&] {
        return commonlight::fail(ErrorCode::kUnsupported,
                                 id() + ": control " + std::string(controlName(control)) + " is not supported by this camera");
    };
    std::lock_guard lock(controls_mutex_);
    switch (control) {
        case Control::kExposureUs: {
            if (!device_controls_.exposure_time_us) return unsupported();
            if (const double reported = reported_exposure_us_.load(); reported > 0) return reported;
            if (requested_.exposure_time_us) return static_cast<double>(*requested_.exposure_time_us);
            return device_controls_.exposure_time_us->default_value;
        }
        case Control::kAnalogGain: {
            if (!device_controls_.analogue_gain) return unsupported();
            if (const double reported = reported_gain_.load(); reported > 0) return reported;
            if (requested_.analogue_gain) return static_cast<double>(*requested_.analogue_gain);
            return device_controls_.analogue_gain->default_value;
        }
        case Control::kAutoExposure: {
            if (!device_controls_.ae_enable) return unsupported();
            if (requested_.ae_enable) return *requested_.ae_enable ? 1.0 : 0.0;
            return device_controls_.ae_enable->default_value != 0 ? 1.0 : 0.0;
        }
        case Control::kAutoWhiteBalance: {
            if (!device_controls_.awb_enable) return unsupported();
            if (requested_.awb_enable) return *requested_.awb_enable ? 1.0 : 0.0;
            return device_controls_.awb_enable->default_value != 0 ? 1.0 : 0.0;
        }
        case Control::kFrameRate: {
            const auto range = fpsRange(device_controls_);
            if (!range) return unsupported();
            if (const double reported = reported_fps_.load(); reported > 0) return reported;
            if (requested_.frame_duration_us) return fpsForFrameDurationUs(*requested_.frame_duration_us);
            if (format_.fps > 0) return format_.fps;
            return fpsForFrameDurationUs(static_cast<std::int64_t>(device_controls_.frame_duration_us->default_value));
        }
    }
    return unsupported();
}

}  // namespace commonlight::hal::libcamera_backend

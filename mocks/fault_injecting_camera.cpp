#include "mocks/fault_injecting_camera.h"

#include <algorithm>

namespace commonlight::mocks {

namespace {

Result<std::uint64_t> count(const hal::CameraUri& uri, std::string_view key, std::uint64_t fallback) {
    CL_TRY(const auto value, uri.integer(key));
    if (!value) return fallback;
    if (*value < 0) {
        return fail(ErrorCode::kUsage,
                    "camera URI '" + uri.text + "': option '" + std::string(key) + "' must not be negative");
    }
    return static_cast<std::uint64_t>(*value);
}

// Flips 16 bytes spread over the image (or all of a smaller one): enough that no check passes.
void scramble(Image& image) {
    const std::size_t size = image.sizeBytes();
    if (size == 0) return;
    const std::size_t step = std::max<std::size_t>(1, size / 16);
    for (std::size_t i = 0, flipped = 0; i < size && flipped < 16; i += step, ++flipped) image.data()[i] ^= 0xA5;
}

}  // namespace

Result<void> FaultOptions::validate() const {
    if (stall_ms < 0) return fail(ErrorCode::kUsage, "fault_stall_ms must not be negative");
    if ((stall_ms > 0) != (stall_at > 0)) {
        return fail(ErrorCode::kUsage, "fault_stall_ms and fault_stall_at go together (stall T ms before frame K)");
    }
    return {};
}

Result<FaultOptions> FaultOptions::fromUri(const hal::CameraUri& uri) {
    FaultOptions options;
    CL_TRY(options.drop_every, count(uri, "fault_drop_every", 0));
    CL_TRY(const std::uint64_t stall_ms, count(uri, "fault_stall_ms", 0));
    options.stall_ms = static_cast<std::int64_t>(stall_ms);
    CL_TRY(options.stall_at, count(uri, "fault_stall_at", 0));
    CL_TRY(options.corrupt_at, count(uri, "fault_corrupt_at", 0));
    if (uri.option("fault_disconnect_after")) {
        CL_TRY(options.disconnect_after, count(uri, "fault_disconnect_after", 0));
    }
    if (auto valid = options.validate(); !valid) {
        return fail(std::move(valid.error()).prepend("camera URI '" + uri.text + "'"));
    }
    return options;
}

Result<std::unique_ptr<FaultInjectingCamera>> FaultInjectingCamera::wrap(std::unique_ptr<hal::Camera> inner,
                                                                         FaultOptions options, Clock& clock) {
    CL_TRY_VOID(options.validate());
    if (inner == nullptr) return fail(ErrorCode::kInternal, "fault injection needs a camera to wrap");
    if (inner->state() == State::kStreaming) {
        return fail(ErrorCode::kUsage, inner->id() + ": cannot add fault injection to a streaming camera");
    }
    return std::unique_ptr<FaultInjectingCamera>(new FaultInjectingCamera(std::move(inner), options, clock));
}

FaultInjectingCamera::FaultInjectingCamera(std::unique_ptr<hal::Camera> inner, FaultOptions options, Clock& clock)
    : Camera(inner->id()), options_(options), clock_(clock), inner_(std::move(inner)) {
    inner_->setFrameAllocator(this);
    inner_->setFrameCallback([this](FrameHandle frame) { onFrame(std::move(frame)); });
    inner_->setEventCallback([this](const hal::CameraEvent& event) { onEvent(event); });
}

FaultInjectingCamera::~FaultInjectingCamera() { stop(); }

std::vector<hal::StreamFormat> FaultInjectingCamera::doFormats() const {
    std::lock_guard lock(inner_mutex_);
    return inner_->formats();
}

Result<hal::StreamFormat> FaultInjectingCamera::doConfigure(const hal::StreamConfig& config) {
    std::lock_guard lock(inner_mutex_);
    return inner_->configure(config);
}

Result<void> FaultInjectingCamera::doStart() {
    received_ = 0;
    delivered_in_stream_ = 0;
    disconnected_.store(false, std::memory_order_release);
    stop_source_ = std::stop_source();
    stopping_ = stop_source_.get_token();
    stopper_ = std::jthread([this](std::stop_token stop) { stopInnerWhenDisconnected(std::move(stop)); });
    std::lock_guard lock(inner_mutex_);
    if (auto started = inner_->start(); !started) {
        stopper_.request_stop();
        stopper_.join();
        return started;
    }
    return {};
}

void FaultInjectingCamera::doStop() noexcept {
    stop_source_.request_stop();
    stopper_.request_stop();
    if (stopper_.joinable()) stopper_.join();
    std::lock_guard lock(inner_mutex_);
    inner_->stop();
}

std::vector<hal::ControlInfo> FaultInjectingCamera::doControls() const {
    std::lock_guard lock(inner_mutex_);
    return inner_->controls();
}

Result<void> FaultInjectingCamera::doSetControl(hal::Control control, double value) {
    std::lock_guard lock(inner_mutex_);
    return inner_->setControl(control, value);
}

Result<double> FaultInjectingCamera::doGetControl(hal::Control control) const {
    std::lock_guard lock(inner_mutex_);
    return inner_->getControl(control);
}

Result<void> FaultInjectingCamera::doTrigger() {
    if (disconnected()) return fail(ErrorCode::kDevice, id() + ": device disconnected (fault injection)");
    std::lock_guard lock(inner_mutex_);
    return inner_->trigger();
}

FrameHandle FaultInjectingCamera::acquire() noexcept {
    if (disconnected()) return FrameHandle();  // a gone device captures nothing
    return acquireFrame();
}

void FaultInjectingCamera::onFrame(FrameHandle frame) {
    // Frames already under way when the device went, or while stop() winds down: lost.
    if (disconnected() || stopping_.stop_requested()) return;
    const std::uint64_t k = ++received_;
    if (options_.disconnect_after == 0u) {
        disconnect();
        return;
    }
    // Step 1: a stall before frame K; the frame then arrives late.
    if (options_.stall_at == k) {
        stalled_.fetch_add(1, std::memory_order_relaxed);
        if (!clock_.sleepUntil(clock_.nowNs() + options_.stall_ms * 1'000'000, stopping_)) return;
        frame->meta.arrival_ns = clock_.nowNs();
    }
    // Step 2: lost at the device; its sequence number stays a gap.
    if (options_.drop_every > 0 && k % options_.drop_every == 0) {
        dropped_.fetch_add(1, std::memory_order_relaxed);
        return;
    }
    // Step 3: damaged on the way.
    if (options_.corrupt_at == k) {
        scramble(frame->image);
        frame->meta.status = FrameStatus::kCorrupt;
        corrupted_.fetch_add(1, std::memory_order_relaxed);
    }
    emitFrame(std::move(frame));
    delivered_.fetch_add(1, std::memory_order_relaxed);
    // Step 4: the device goes away after N frames.
    if (options_.disconnect_after == ++delivered_in_stream_) disconnect();
}

void FaultInjectingCamera::onEvent(const hal::CameraEvent& event) {
    if (!disconnected() && !stopping_.stop_requested()) emitEvent(event);
}

void FaultInjectingCamera::disconnect() {
    {
        std::lock_guard lock(disconnect_mutex_);
        disconnected_.store(true, std::memory_order_release);
    }
    disconnect_cv_.notify_all();
    emitEvent(hal::CameraEvent{hal::CameraEvent::Type::kDeviceError,
                               Error{ErrorCode::kDevice, id() + ": device disconnected (fault injection)"}});
}

void FaultInjectingCamera::stopInnerWhenDisconnected(std::stop_token stop) {
    {
        std::unique_lock lock(disconnect_mutex_);
        if (!disconnect_cv_.wait(lock, stop, [&] { return disconnected(); })) return;
    }
    std::lock_guard lock(inner_mutex_);
    inner_->stop();
}

std::string FaultInjectingCamera::doResponseSpec() const {
    const std::lock_guard lock(inner_mutex_);
    return inner_->responseSpec();
}

std::optional<CameraModel> FaultInjectingCamera::doCalibration() const {
    const std::lock_guard lock(inner_mutex_);
    return inner_->calibration();
}

}  // namespace commonlight::mocks

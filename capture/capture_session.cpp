#include "capture/capture_session.h"

#include <string>
#include <utility>

namespace commonlight::capture {

namespace {
constexpr std::size_t kMaxSlots = 256;
}  // namespace

Result<void> CaptureOptions::validate() const {
    if (slots < 1 || slots > kMaxSlots) {
        return fail(ErrorCode::kUsage, "capture slots must be between 1 and " + std::to_string(kMaxSlots) +
                                           ", got " + std::to_string(slots));
    }
    if (latency_samples < 1) return fail(ErrorCode::kUsage, "capture latency_samples must be at least 1");
    return {};
}

Result<std::unique_ptr<CaptureSession>> CaptureSession::create(std::unique_ptr<hal::Camera> camera,
                                                               const CaptureOptions& options, const Clock& clock) {
    if (camera == nullptr) return fail(ErrorCode::kUsage, "capture session: no camera");
    if (auto valid = options.validate(); !valid) return fail(std::move(valid.error()).prepend(camera->id()));
    return std::unique_ptr<CaptureSession>(new CaptureSession(std::move(camera), options, clock));
}

CaptureSession::CaptureSession(std::unique_ptr<hal::Camera> camera, const CaptureOptions& options, const Clock& clock)
    : options_(options),
      clock_(&clock),
      camera_(std::move(camera)),
      mailbox_(options.sync ? MailboxMode::kLossless : MailboxMode::kNewestWins),
      collector_(options.latency_samples) {
    mailbox_.close();  // no stream before start(): next() returns the end
}

CaptureSession::~CaptureSession() { stop(); }

Result<void> CaptureSession::start() {
    const std::string& id = camera_->id();
    if (streaming_) return fail(ErrorCode::kUsage, id + ": capture already started");
    if (camera_->state() != hal::Camera::State::kConfigured) {
        return fail(ErrorCode::kUsage, id + ": configure the camera before starting capture");
    }
    const hal::StreamFormat& format = camera_->activeFormat();
    if (format.format == PixelFormat::kInvalid || format.width <= 0 || format.height <= 0) {
        return fail(ErrorCode::kUsage, id + ": the camera negotiated no usable format (" + hal::describe(format) + ")");
    }

    // Step 1: a fresh mailbox. A frame the last consumer never took goes back to the pool.
    mailbox_.reopen();

    // Step 2: the pool, sized for the negotiated format. Kept when nothing changed.
    if (pool_ != nullptr && pool_->inUse() > 0) {
        mailbox_.close();
        return fail(ErrorCode::kUsage, id + ": " + std::to_string(pool_->inUse()) +
                                           " frame(s) of the previous stream are still held; release them first");
    }
    const std::size_t mjpeg_bytes =
        options_.mjpeg_slot_bytes > 0 ? options_.mjpeg_slot_bytes : mjpegSlotBytes(format.width, format.height);
    if (pool_ == nullptr || pool_->format() != format.format || pool_->width() != format.width ||
        pool_->height() != format.height || pool_->slotCount() != options_.slots ||
        (isCompressed(format.format) && pool_->slotBytes() != mjpeg_bytes)) {
        pool_ = std::make_unique<FramePool>(options_.slots, format.format, format.width, format.height, mjpeg_bytes);
    }

    // Step 3: counters start at zero for this stream.
    collector_.reset();
    without_slot_base_.store(camera_->framesWithoutSlot(), std::memory_order_relaxed);

    // Step 4: wire the camera and start it. The callbacks run on the camera thread.
    camera_->setFrameAllocator(pool_.get());
    camera_->setFrameCallback([this](FrameHandle frame) { onFrame(std::move(frame)); });
    camera_->setEventCallback([this](const hal::CameraEvent& event) { onEvent(event); });
    if (auto started = camera_->start(); !started) {
        mailbox_.close();
        return started;
    }
    streaming_ = true;
    return {};
}

void CaptureSession::stop() noexcept {
    if (!streaming_) return;
    // Close first: a lossless put() on the camera thread wakes up, so stop() can join it.
    mailbox_.close();
    camera_->stop();
    streaming_ = false;
}

NextFrame CaptureSession::next(std::stop_token stop, std::chrono::nanoseconds timeout) {
    NextFrame taken = mailbox_.take(std::move(stop), timeout);
    if (taken && taken->has_value()) {
        collector_.onDelivery((**taken)->meta, clock_->nowNs());
    } else if (!taken && taken.error().code == ErrorCode::kTimeout) {
        taken.error().prepend(camera_->id());
    }
    return taken;
}

CaptureStats CaptureSession::stats() const {
    return collector_.snapshot(framesWithoutSlot(), mailbox_.dropped(), mailbox_.discarded());
}

std::uint64_t CaptureSession::framesWithoutSlot() const noexcept {
    return camera_->framesWithoutSlot() - without_slot_base_.load(std::memory_order_relaxed);
}

void CaptureSession::onFrame(FrameHandle frame) {
    if (!frame) return;
    collector_.onArrival(frame->meta, framesWithoutSlot());
    mailbox_.put(std::move(frame));  // newest-wins: never blocks; lossless (--sync): waits for the consumer
}

void CaptureSession::onEvent(const hal::CameraEvent& event) {
    if (event.type == hal::CameraEvent::Type::kEndOfStream) {
        mailbox_.close();
        return;
    }
    // Once per stream: the allocation of the message is fine here.
    Error error{ErrorCode::kDevice, event.error.message};
    if (error.message.empty()) error.message = "device error";
    if (error.message.find(camera_->id()) == std::string::npos) error.prepend(camera_->id());
    mailbox_.close(std::move(error));
}

}  // namespace commonlight::capture

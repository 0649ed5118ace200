#include "mocks/memory_camera.h"

#include <cmath>

namespace commonlight::mocks {

MemoryCamera::MemoryCamera(Image frame, double fps, PlaybackOptions options, Clock& clock)
    : hal::Camera("memory:" + std::string(pixelFormatName(frame.format())) + "/" + std::to_string(frame.width()) +
                  "x" + std::to_string(frame.height())),
      frame_(std::move(frame)),
      fps_(fps),
      clock_(clock),
      pacer_(clock, options) {}

MemoryCamera::~MemoryCamera() { doStop(); }

std::vector<hal::StreamFormat> MemoryCamera::doFormats() const {
    return {{frame_.format(), frame_.width(), frame_.height(), {fps_}, 0.0}};
}

Result<hal::StreamFormat> MemoryCamera::doConfigure(const hal::StreamConfig& config) {
    return hal::negotiate(doFormats(), config, id());
}

Result<void> MemoryCamera::doStart() {
    pacer_.reset();
    thread_ = std::jthread([this](std::stop_token stop) { run(stop); });
    return {};
}

void MemoryCamera::doStop() noexcept {
    if (thread_.joinable()) {
        thread_.request_stop();
        thread_.join();
    }
}

void MemoryCamera::run(std::stop_token stop) {
    const double interval_ns = 1e9 / fps_;
    for (std::uint64_t n = 0;; ++n) {
        const auto timestamp = static_cast<std::int64_t>(std::llround(static_cast<double>(n) * interval_ns));
        if (!pacer_.waitUntilDue(timestamp, stop)) return;
        FrameHandle slot = acquireFrame();
        if (!slot) continue;  // counted by the base class; the sequence number stays a gap
        slot->image.assign(frame_);
        slot->meta = {};
        slot->meta.sequence = n;
        slot->meta.timestamp_ns = timestamp;
        slot->meta.timestamp_source = TimestampSource::kSimulated;
        slot->meta.arrival_ns = clock_.nowNs();
        emitFrame(std::move(slot));
    }
}

}  // namespace commonlight::mocks

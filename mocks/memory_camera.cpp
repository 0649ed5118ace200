#include "mocks/memory_camera.h"

#include <cmath>

namespace commonlight::mocks {

MemoryCamera::MemoryCamera(Image frame, double fps, PlaybackOptions options, Clock& clock)
    : PacedCamera("memory:" + std::string(pixelFormatName(frame.format())) + "/" + std::to_string(frame.width()) +
                  "x" + std::to_string(frame.height()),
                  clock, options),
      frame_(std::move(frame)),
      fps_(fps) {}

MemoryCamera::~MemoryCamera() { stop(); }

std::vector<hal::StreamFormat> MemoryCamera::doFormats() const {
    return {{frame_.format(), frame_.width(), frame_.height(), {fps_}, 0.0}};
}

Result<hal::StreamFormat> MemoryCamera::doConfigure(const hal::StreamConfig& config) {
    return hal::negotiate(doFormats(), config, id());
}

void MemoryCamera::run(std::stop_token stop) {
    const double interval_ns = 1e9 / fps_;
    for (std::uint64_t n = 0;; ++n) {
        const auto timestamp = static_cast<std::int64_t>(std::llround(static_cast<double>(n) * interval_ns));
        if (!pacer().waitUntilDue(timestamp, stop)) return;
        FrameHandle slot = acquireFrame();
        if (!slot) continue;  // counted by the base class; the sequence number stays a gap
        slot->image.assign(frame_);
        slot->meta = {};
        slot->meta.sequence = n;
        slot->meta.timestamp_ns = timestamp;
        slot->meta.timestamp_source = TimestampSource::kSimulated;
        slot->meta.arrival_ns = clock().nowNs();
        emitFrame(std::move(slot));
    }
}

}  // namespace commonlight::mocks

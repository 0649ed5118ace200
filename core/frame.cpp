#include "core/frame.h"

#include <cmath>

namespace commonlight {

std::string_view frameStatusName(FrameStatus status) noexcept {
    switch (status) {
        case FrameStatus::kOk: return "ok";
        case FrameStatus::kCorrupt: return "corrupt";
        case FrameStatus::kIncomplete: return "incomplete";
    }
    return "unknown";
}

std::string_view timestampSourceName(TimestampSource source) noexcept {
    switch (source) {
        case TimestampSource::kUnknown: return "unknown";
        case TimestampSource::kSensor: return "sensor";
        case TimestampSource::kDriver: return "driver";
        case TimestampSource::kHost: return "host";
        case TimestampSource::kRecording: return "recording";
        case TimestampSource::kSimulated: return "simulated";
    }
    return "unknown";
}

std::int64_t midExposureNs(std::int64_t timestamp_ns, double exposure_us, bool end_of_frame) noexcept {
    // Exposures beyond 1000 s are no camera's; they are treated as unknown (no overflow).
    if (!(exposure_us > 0.0) || !(exposure_us < 1e9)) return timestamp_ns;
    const std::int64_t half_ns = std::llround(exposure_us * 500.0);
    return end_of_frame ? timestamp_ns - half_ns : timestamp_ns + half_ns;
}

std::int64_t midExposureNs(const FrameMetadata& meta) noexcept {
    const bool end_of_frame = meta.timestamp_source == TimestampSource::kDriver || meta.timestamp_source == TimestampSource::kHost;
    return midExposureNs(meta.timestamp_ns, meta.exposure_us, end_of_frame);
}

}  // namespace commonlight

#include "core/frame.h"

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

}  // namespace commonlight

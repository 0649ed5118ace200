// Playback pacing shared by the cameras that replay recordings (replay:, video:).
//
// A recording carries its own timestamps; the Pacer decides when each one is due on an injected
// Clock (tests drive it with a ManualClock):
//   realtime  frame t is due when clock >= anchor + (t - t_first) / speed; the anchor is the clock
//             time at which the first frame of the stream was asked for
//   max       every frame is due at once (as fast as the reader goes)
//   step      one frame per trigger() (a software trigger); triggers given ahead accumulate
#pragma once

#include <condition_variable>
#include <cstdint>
#include <mutex>
#include <optional>
#include <stop_token>
#include <string>

#include "core/clock.h"
#include "core/result.h"
#include "hal/camera_uri.h"

namespace commonlight::mocks {

enum class PlaybackRate { kRealtime, kMax, kStep };

// The URI options rate=realtime|max|step, loop=0|1 and speed=<factor> (realtime only).
struct PlaybackOptions {
    PlaybackRate rate = PlaybackRate::kRealtime;
    bool loop = false;
    double speed = 1.0;  // > 0; 2 plays twice as fast

    // kUsage naming the problem when the fields contradict each other.
    Result<void> validate() const;
    // Reads rate/loop/speed from a URI; errors (kUsage) name the URI and the key.
    static Result<PlaybackOptions> fromUri(const hal::CameraUri& uri);
};

// The URI options PlaybackOptions::fromUri reads, for hal::Backend::options.
inline constexpr const char* kPlaybackOptionNames[] = {"rate", "loop", "speed"};

// The offset added to every timestamp of the next pass of a looping recording, so that its
// timestamps keep increasing: the length of one pass plus one nominal frame interval.
inline std::int64_t loopPeriodNs(std::int64_t first_ns, std::int64_t last_ns, std::int64_t interval_ns) noexcept {
    return last_ns - first_ns + interval_ns;
}

// The nominal frame interval of a recording: 1 / rate_hz when known, else the mean interval of
// its timestamps, else (a single frame and no rate) 1/30 s.
std::int64_t nominalIntervalNs(double rate_hz, std::int64_t first_ns, std::int64_t last_ns, std::size_t count) noexcept;

class Pacer {
public:
    // `clock` is borrowed and must outlive the pacer.
    Pacer(Clock& clock, PlaybackOptions options) noexcept : clock_(clock), options_(options) {}
    Pacer(const Pacer&) = delete;
    Pacer& operator=(const Pacer&) = delete;

    const PlaybackOptions& options() const noexcept { return options_; }

    // Forgets the time anchor and any pending triggers. Call before the camera thread starts.
    void reset();

    // Camera thread: blocks until the frame stamped `timestamp_ns` is due (see the top of this
    // file). Returns false, at once, when `stop` is requested.
    bool waitUntilDue(std::int64_t timestamp_ns, std::stop_token stop);

    // Control thread: releases one frame in step mode; kUnsupported (naming `camera`) otherwise.
    Result<void> trigger(const std::string& camera);

private:
    Clock& clock_;
    const PlaybackOptions options_;
    // Realtime anchor; camera thread only.
    std::optional<std::int64_t> first_timestamp_ns_;
    std::int64_t anchor_ns_ = 0;
    // Step mode: triggers not yet consumed.
    std::mutex mutex_;
    std::condition_variable_any triggered_;
    std::uint64_t pending_triggers_ = 0;
};

}  // namespace commonlight::mocks

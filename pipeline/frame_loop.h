// The pipeline's threads (DESIGN.md section 1) and what crosses between them.
//
//   camera thread      the capture session's: frames into a newest-wins mailbox
//   pipeline thread    FrameSource::next() -> FrameRunner::track(): conversion, tracking, the
//                      virtual objects' poses, the frame handed to the lighting thread
//                      -> TrackedFrameHandoff (newest wins)
//   main thread        (owns GL) FrameRunner::composite() -> files, window
//   lighting thread    lighting/engine.h, at its own rate; the compositor draws with its newest
//                      snapshot and never waits for it
//
// In real time the pipeline thread tracks frame n+1 while the main thread composites frame n. A
// tracked frame that the main thread did not take before the next one was tracked is replaced
// (newest wins, counted), so the frame shown is at most the one tracked before the newest. With
// `sync` there is no pipeline thread: each frame goes through every stage, its lighting update
// included, before the next is taken, so the output is deterministic.
#pragma once

#include <array>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <mutex>
#include <optional>
#include <stop_token>
#include <vector>

#include "capture/capture_session.h"
#include "core/frame.h"
#include "core/image.h"
#include "core/pose.h"
#include "core/result.h"
#include "tracking/tracker.h"

namespace commonlight::pipeline {

// One frame after the pipeline stage, on its way to the compositor. Owns its pixels (the camera's
// pool slot is given back as soon as the frame is tracked); reused from frame to frame.
struct TrackedFrame {
    FrameMetadata meta;
    Image rgb;                  // RGB8 at the camera's size; empty without lighting and compositor
    Image raw;                  // the camera's own YUYV or NV12 bytes, for the compositor (it converts
                                // them in its final pass); empty for other formats or without it
    tracking::FrameTrack track;
    std::vector<std::optional<Rigid3d>> virtual_poses;  // world_from_object per Scene::virtual_objects
    double scene_time_s = 0.0;  // seconds since the runner's first frame, by frame timestamps
    double frame_period_ns = 0.0;  // the frames' period so far (smoothed), 0 before the second frame
    std::uint64_t index = 0;    // 0-based count of the frames this runner tracked
};

// Where the pipeline's frames come from (play and bench: a capture session; live: a camera that
// reconnects, pipeline/camera_source.h).
class FrameSource {
public:
    virtual ~FrameSource() = default;
    // The pipeline thread (the caller's thread with `sync`). Waits for the next frame; nullopt when
    // the stream ended; an error ends the run (kCancelled: `stop` was requested, not a failure).
    // A frame whose status is not ok is skipped by the loop (the source counts it).
    virtual Result<std::optional<FrameHandle>> next(std::stop_token stop) = 0;
};

// A capture session as a frame source: its frames until its end; no frame within `timeout` is a
// failure (kTimeout). The session is borrowed.
class SessionSource final : public FrameSource {
public:
    SessionSource(capture::CaptureSession& session, std::chrono::nanoseconds timeout) : session_(&session), timeout_(timeout) {}
    Result<std::optional<FrameHandle>> next(std::stop_token stop) override { return session_->next(stop, timeout_); }

private:
    capture::CaptureSession* session_;
    std::chrono::nanoseconds timeout_;
};

// What the caller does between the stages. Each callback says its thread; none may throw.
struct LoopCallbacks {
    // Pipeline thread, after each frame tracked (poses.csv, progress). Must not block for long.
    std::function<void(const TrackedFrame&)> on_tracked;
    // Pipeline thread: a frame that could not be converted (kBadInput: counted, the run goes on).
    std::function<void(const Frame&, const Error&)> on_bad_frame;
    // Main thread, after each frame composited (or, without a compositor, taken by the main
    // thread): show it, read the keys. False ends the run.
    std::function<bool(const TrackedFrame&)> on_frame;
    // Main thread, real time only: no new frame for `idle_period` (a lost camera, a stall); `last`
    // is the last frame shown (null before the first). Keeps a window alive. False ends the run.
    std::function<bool(const TrackedFrame* last)> on_idle;
    std::chrono::milliseconds idle_period{100};
};

struct LoopStats {
    std::uint64_t tracked = 0;     // frames through the pipeline stage
    std::uint64_t composited = 0;  // frames through the main thread's stage
    std::uint64_t replaced = 0;    // tracked frames a newer one replaced before the main thread took them
    std::uint64_t bad_frames = 0;  // frames that could not be converted
    bool stopped = false;          // a callback ended the run
    std::optional<Error> failure;  // what ended the run, when it failed
};

// The hand-over of tracked frames from the pipeline thread to the main thread, through three
// buffers that are reused (nothing is allocated once their images have the camera's size): the
// producer fills one, one waits as the newest, the consumer works on the third. Newest wins: a
// frame the consumer did not take before a newer one was published is replaced (counted).
//
// Just in time: the producer asks waitForDemand() before it takes a camera frame, and starts when
// the consumer will want a frame within the producer's own time per frame. So a frame does not
// wait, tracked, for a busy compositor while newer camera frames arrive (the camera's mailbox
// keeps the newest meanwhile): the latency is that of one thread doing both stages, and the rate
// that of the slower stage.
//
// Threads: writable(), waitForDemand(), publish() and close() from one producer; take() from one
// consumer; the counters from any thread.
class TrackedFrameHandoff {
public:
    enum class Taken { kFrame, kTimeout, kEnd };

    // Producer: waits until no published frame is left untaken and the consumer expects to be
    // done with its frame within `lead_ns`. False when `stop` was requested.
    bool waitForDemand(std::int64_t lead_ns, std::stop_token stop);
    // Producer: the buffer to fill; it stays the producer's until publish().
    TrackedFrame& writable() noexcept { return buffers_[write_]; }
    // Producer: the filled buffer becomes the newest; an older one nobody took is replaced (counted).
    void publish();
    // Producer: no frame follows (`error`: the run failed). The consumer still gets the newest.
    void close(std::optional<Error> error = std::nullopt);

    // Consumer: waits up to `timeout` for a frame newer than the last one taken. kFrame: `frame`
    // points at it, valid until the next take(); `busy_ns` is how long the consumer expects to
    // work on it (for waitForDemand). kEnd: closed and nothing newer is left.
    Taken take(std::chrono::nanoseconds timeout, const TrackedFrame*& frame, std::int64_t busy_ns = 0);

    std::optional<Error> error() const;
    std::uint64_t published() const;
    std::uint64_t replaced() const;

private:
    mutable std::mutex mutex_;
    std::condition_variable ready_cv_;       // the consumer waits for a frame
    std::condition_variable_any demand_cv_;  // the producer waits for the consumer's demand
    std::int64_t busy_until_ns_ = 0;         // when the consumer expects to want the next frame (0: now)
    std::uint64_t demand_changes_ = 0;       // wakes the producer
    std::array<TrackedFrame, 3> buffers_;
    int write_ = 0;  // the producer's: only publish() changes it, on the producer's thread
    int ready_ = 1;  // guarded by mutex_
    int read_ = 2;   // guarded by mutex_
    bool fresh_ = false;  // ready_ holds a frame not yet taken
    bool closed_ = false;
    std::optional<Error> error_;
    std::uint64_t published_ = 0, replaced_ = 0;
};

}  // namespace commonlight::pipeline

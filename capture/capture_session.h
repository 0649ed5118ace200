// CaptureSession: one camera, its frame pool, the mailbox to the pipeline, and capture stats.
//
// Threads:
//   - control thread: create(), start(), stop(), the destructor;
//   - camera thread (the camera backend's own thread, which is the session's capture thread):
//     runs the frame and event callbacks. The frame callback only counts the frame (atomics)
//     and puts it into the mailbox: it never blocks (newest-wins mode) and never allocates;
//   - consumer thread (the pipeline): next();
//   - any thread: stats().
//
// Ownership: the session owns the camera (unique_ptr), the FramePool, the Mailbox and the stats.
// next() lends the consumer a FrameHandle; every handle must be released before stop()+start()
// again and before the session is destroyed (the pool asserts it).
#pragma once

#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <stop_token>

#include "capture/frame_pool.h"
#include "capture/mailbox.h"
#include "capture/stats.h"
#include "core/clock.h"
#include "core/frame.h"
#include "core/result.h"
#include "hal/camera.h"

namespace commonlight::capture {

struct CaptureOptions {
    // Pool slots. Newest-wins needs 3 to never starve the camera (one being filled, one in the
    // mailbox, one with the consumer); the 4th absorbs a consumer that holds one frame longer.
    std::size_t slots = 4;
    // Lossless mailbox (`--sync`): the camera thread waits until the pipeline took the previous
    // frame, so every frame is processed. Only for replay cameras (a live device would overrun).
    bool sync = false;
    // Byte capacity of an MJPEG slot; 0: mjpegSlotBytes(width, height) = 3 bytes per pixel.
    std::size_t mjpeg_slot_bytes = 0;
    // Latency samples kept for the percentiles (reservoir sampling beyond).
    std::size_t latency_samples = SampleReservoir::kDefaultCapacity;

    // kUsage naming the bad field.
    Result<void> validate() const;
};

// What next() returns: a frame; std::nullopt once the stream ended cleanly (every frame has been
// taken); or an Error: kDevice naming the camera when it failed, kTimeout when no frame came in
// time, kCancelled when a stop was requested. After the end, every call returns the end again;
// before the first start(), next() returns the end at once.
using NextFrame = Result<std::optional<FrameHandle>>;

class CaptureSession {
public:
    // Fails with kUsage for a null camera or options that fail validate(). `clock` times the
    // hand-over for the latency stats: it must run on the same time line as the camera's
    // FrameMetadata::arrival_ns (CLOCK_MONOTONIC for real backends). Borrowed: it must outlive
    // the session.
    static Result<std::unique_ptr<CaptureSession>> create(std::unique_ptr<hal::Camera> camera,
                                                          const CaptureOptions& options,
                                                          const Clock& clock = SteadyClock::instance());
    ~CaptureSession();
    CaptureSession(const CaptureSession&) = delete;
    CaptureSession& operator=(const CaptureSession&) = delete;

    // Control thread. The camera must be configured (hal::Camera::configure). Sizes the pool from
    // the negotiated activeFormat(), resets the stats, wires the callbacks and starts streaming.
    // kUsage when streaming already, when the camera is not configured, or when a frame from the
    // previous run is still held; the camera's own error when it cannot start.
    Result<void> start();

    // Control thread. Ends the stream (the consumer gets the end) and stops the camera: no
    // callback runs after it returns. Never fails; does nothing when not streaming.
    void stop() noexcept;

    // Consumer thread. See NextFrame. Records the hand-over in the stats.
    NextFrame next(std::stop_token stop, std::chrono::nanoseconds timeout);

    // Any thread: a consistent-enough snapshot (each counter is exact; they are read one by one).
    CaptureStats stats() const;

    bool streaming() const noexcept { return streaming_; }
    // The camera, borrowed: controls, id, activeFormat. Do not start/stop it behind the session.
    hal::Camera& camera() noexcept { return *camera_; }
    const hal::Camera& camera() const noexcept { return *camera_; }
    // The pool of the current (or last) stream; null before the first start().
    const FramePool* pool() const noexcept { return pool_.get(); }
    const CaptureOptions& options() const noexcept { return options_; }

private:
    CaptureSession(std::unique_ptr<hal::Camera> camera, const CaptureOptions& options, const Clock& clock);

    // Camera thread; must not block (newest-wins) or allocate.
    void onFrame(FrameHandle frame);
    // Camera thread; must not block.
    void onEvent(const hal::CameraEvent& event);
    std::uint64_t framesWithoutSlot() const noexcept;

    CaptureOptions options_;
    const Clock* clock_;
    // Declaration order is destruction order in reverse: the mailbox releases its frame into the
    // pool, and the camera (stopped by the destructor) goes before the pool it borrowed.
    std::unique_ptr<FramePool> pool_;
    std::unique_ptr<hal::Camera> camera_;
    Mailbox mailbox_;
    CaptureStatsCollector collector_;
    std::atomic<std::uint64_t> without_slot_base_{0};  // camera's framesWithoutSlot() at start()
    bool streaming_ = false;
};

}  // namespace commonlight::capture

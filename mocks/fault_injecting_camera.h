// FaultInjectingCamera: a decorator that wraps any camera and injects the faults a real device
// shows, so that the capture pipeline's handling of them can be tested exactly.
//
//   replay:SEQ?fault_drop_every=3                  frames 3, 6, 9, ... never arrive (sequence gaps)
//   replay:SEQ?fault_stall_at=10&fault_stall_ms=500   the camera thread blocks 500 ms before frame 10
//   replay:SEQ?fault_corrupt_at=4                  frame 4 arrives kCorrupt with scrambled bytes
//   replay:SEQ?fault_disconnect_after=5            5 frames, then kDeviceError and nothing more
//
// Frames are numbered 1, 2, 3, ... in the order the wrapped camera delivers them (every frame
// that reaches the wrapper counts, dropped ones included). formats/configure/controls/trigger
// are forwarded to the wrapped camera, whose id this camera takes.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <stop_token>
#include <thread>

#include "core/clock.h"
#include "hal/camera.h"
#include "hal/camera_uri.h"

namespace commonlight::mocks {

struct FaultOptions {
    std::uint64_t drop_every = 0;                   // drop every Nth frame; 0: none
    std::int64_t stall_ms = 0;                      // block this long (on the clock) ...
    std::uint64_t stall_at = 0;                     // ... before frame K; 0: no stall
    std::uint64_t corrupt_at = 0;                   // corrupt frame K; 0: none
    std::optional<std::uint64_t> disconnect_after;  // disconnect after N delivered frames

    Result<void> validate() const;
    // Reads the fault_* options; errors (kUsage) name the URI and the key.
    static Result<FaultOptions> fromUri(const hal::CameraUri& uri);
};

// The URI options FaultOptions::fromUri reads, for hal::Wrapper::options.
inline constexpr const char* kFaultOptionNames[] = {"fault_drop_every", "fault_stall_ms", "fault_stall_at",
                                                    "fault_corrupt_at", "fault_disconnect_after"};

class FaultInjectingCamera final : public hal::Camera, private FrameAllocator {
public:
    // Takes ownership of `inner` (state Opened or Configured, not streaming). Stalls wait on
    // `clock`, which is borrowed and must outlive this camera.
    static Result<std::unique_ptr<FaultInjectingCamera>> wrap(std::unique_ptr<hal::Camera> inner, FaultOptions options,
                                                              Clock& clock);
    ~FaultInjectingCamera() override;

    const hal::Camera& inner() const noexcept { return *inner_; }

    // Counts of injected faults since construction; readable from any thread.
    std::uint64_t framesDropped() const noexcept { return dropped_.load(std::memory_order_relaxed); }
    std::uint64_t framesStalled() const noexcept { return stalled_.load(std::memory_order_relaxed); }
    std::uint64_t framesCorrupted() const noexcept { return corrupted_.load(std::memory_order_relaxed); }
    std::uint64_t framesDelivered() const noexcept { return delivered_.load(std::memory_order_relaxed); }
    bool disconnected() const noexcept { return disconnected_.load(std::memory_order_acquire); }

private:
    FaultInjectingCamera(std::unique_ptr<hal::Camera> inner, FaultOptions options, Clock& clock);

    std::vector<hal::StreamFormat> doFormats() const override;
    Result<hal::StreamFormat> doConfigure(const hal::StreamConfig& config) override;
    Result<void> doStart() override;
    void doStop() noexcept override;
    std::vector<hal::ControlInfo> doControls() const override;
    Result<void> doSetControl(hal::Control control, double value) override;
    Result<double> doGetControl(hal::Control control) const override;
    Result<void> doTrigger() override;
    std::string doResponseSpec() const override;
    std::optional<CameraModel> doCalibration() const override;

    // FrameAllocator for the wrapped camera: our own allocator's slots (counted by our
    // framesWithoutSlot()), none at all once disconnected. Wrapped camera's thread.
    FrameHandle acquire() noexcept override;
    // Wrapped camera's thread: applies the faults and passes the frame or event on.
    void onFrame(FrameHandle frame);
    void onEvent(const hal::CameraEvent& event);
    void disconnect();
    // Stopper thread: stops the wrapped camera once it disconnected (it cannot stop itself from
    // its own thread).
    void stopInnerWhenDisconnected(std::stop_token stop);

    const FaultOptions options_;
    Clock& clock_;
    // inner_ is used by the control thread and, after a disconnect, by the stopper thread.
    mutable std::mutex inner_mutex_;
    std::unique_ptr<hal::Camera> inner_;

    // Set by doStart() before the wrapped camera starts, then used on its thread only.
    std::uint64_t received_ = 0;             // frames that reached us in this stream
    std::uint64_t delivered_in_stream_ = 0;  // frames we passed on in this stream
    // Requested by doStop(): interrupts a stall and silences what the wrapped camera still
    // delivers before its own stop() returns.
    std::stop_source stop_source_;
    std::stop_token stopping_;

    std::atomic<std::uint64_t> dropped_{0};
    std::atomic<std::uint64_t> stalled_{0};
    std::atomic<std::uint64_t> corrupted_{0};
    std::atomic<std::uint64_t> delivered_{0};
    std::atomic<bool> disconnected_{false};

    std::mutex disconnect_mutex_;
    std::condition_variable_any disconnect_cv_;
    std::jthread stopper_;
};

}  // namespace commonlight::mocks

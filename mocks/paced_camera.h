// Base of the cameras whose own thread paces recorded or generated frames with a Pacer
// (replay:, video:, sim: and MemoryCamera): it owns the pacer and the camera thread, starts the
// thread on start(), stops and joins it on stop(), and answers trigger() in step mode.
#pragma once

#include <stop_token>
#include <string>
#include <thread>

#include "core/clock.h"
#include "hal/camera.h"
#include "mocks/pacer.h"

namespace commonlight::mocks {

class PacedCamera : public hal::Camera {
protected:
    // `clock` paces playback and stamps arrival_ns; borrowed, it must outlive the camera.
    PacedCamera(std::string id, Clock& clock, PlaybackOptions options)
        : hal::Camera(std::move(id)), clock_(clock), pacer_(clock, options) {}

    // Derived destructors must call stop() first: run() uses the derived object's members, which
    // are destroyed before this base (and its thread) is.
    ~PacedCamera() override = default;

    Clock& clock() const noexcept { return clock_; }
    // The camera thread blocks in pacer().waitUntilDue(timestamp, stop) before each frame.
    Pacer& pacer() noexcept { return pacer_; }

private:
    // Control thread, in start() before the camera thread starts: reopen files, reset counters.
    virtual Result<void> beforeStart() { return {}; }
    // Control thread, in stop() after the camera thread has been joined.
    virtual void afterStop() noexcept {}
    // The camera thread: paces, emits frames (and an end-of-stream event when a recording ends)
    // and returns when `stop` is requested or the stream is over.
    virtual void run(std::stop_token stop) = 0;

    Result<void> doStart() final {
        CL_TRY_VOID(beforeStart());
        pacer_.reset();
        thread_ = std::jthread([this](std::stop_token stop) { run(std::move(stop)); });
        return {};
    }
    void doStop() noexcept final {
        if (thread_.joinable()) {
            thread_.request_stop();
            thread_.join();
        }
        afterStop();
    }
    Result<void> doTrigger() final { return pacer_.trigger(id()); }

    Clock& clock_;
    Pacer pacer_;
    std::jthread thread_;
};

}  // namespace commonlight::mocks

// A small camera for testing the hal base class: it records which do*() functions ran and, when
// started, emits a given number of frames and then kEndOfStream from its own thread.
#pragma once

#include <thread>
#include <vector>

#include "hal/camera.h"

namespace commonlight::testing {

class FakeCamera final : public hal::Camera {
public:
    explicit FakeCamera(std::string id = "fake:0",
                        std::vector<hal::StreamFormat> formats = {{PixelFormat::kYuyv, 640, 480, {30, 15}, 0},
                                                                  {PixelFormat::kMjpeg, 1280, 720, {30}, 0},
                                                                  {PixelFormat::kYuyv, 320, 240, {60, 30}, 0}})
        : Camera(std::move(id)), formats_(std::move(formats)) {}
    ~FakeCamera() override { stop(); }

    // Knobs, set from the test thread while not streaming.
    int frames_per_stream = 0;
    bool fail_start = false;
    bool fail_configure = false;

    // What ran (test thread only).
    int configure_calls = 0;
    int start_calls = 0;
    int stop_calls = 0;
    int trigger_calls = 0;

private:
    std::vector<hal::StreamFormat> doFormats() const override { return formats_; }
    Result<hal::StreamFormat> doConfigure(const hal::StreamConfig& config) override {
        ++configure_calls;
        if (fail_configure) return fail(ErrorCode::kDevice, id() + ": configure failed (fake)");
        return hal::negotiate(formats_, config, id());
    }
    Result<void> doStart() override {
        ++start_calls;
        if (fail_start) return fail(ErrorCode::kDevice, id() + ": start failed (fake)");
        thread_ = std::jthread([this, n = frames_per_stream](std::stop_token stop) {
            for (int i = 0; i < n && !stop.stop_requested(); ++i) {
                FrameHandle frame = acquireFrame();
                if (!frame) continue;
                frame->meta.sequence = static_cast<std::uint64_t>(i);
                emitFrame(std::move(frame));
            }
            if (!stop.stop_requested()) emitEvent(hal::CameraEvent{hal::CameraEvent::Type::kEndOfStream, {}});
        });
        return {};
    }
    void doStop() noexcept override {
        ++stop_calls;
        thread_.request_stop();
        if (thread_.joinable()) thread_.join();
    }
    std::vector<hal::ControlInfo> doControls() const override {
        return {hal::ControlInfo{hal::Control::kExposureUs, 10, 100000, 1, 10000}};
    }
    Result<void> doSetControl(hal::Control control, double value) override {
        if (control != hal::Control::kExposureUs) {
            return fail(ErrorCode::kUnsupported, id() + ": " + std::string(hal::controlName(control)) + " (fake)");
        }
        exposure_us_ = value;
        return {};
    }
    Result<double> doGetControl(hal::Control control) const override {
        if (control != hal::Control::kExposureUs) return fail(ErrorCode::kUnsupported, "unsupported");
        return exposure_us_;
    }
    Result<void> doTrigger() override {
        ++trigger_calls;
        return {};
    }

    std::vector<hal::StreamFormat> formats_;
    double exposure_us_ = 10000;
    std::jthread thread_;
};

}  // namespace commonlight::testing

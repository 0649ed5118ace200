// The libcamera camera (`libcamera:<id or index>`): the commonlight state machine over a
// libcamera_backend::Device (hal/libcamera/device.h).
//
// configure() negotiates against the formats generateConfiguration({role}) offers, lets libcamera
// validate the result (Adjusted: accepted with a warning naming the change; Invalid: kUsage
// listing what the camera offers) and configures it. start() allocates the buffers and one
// request per buffer once, and queues them all. Each completed request is copied into a pool
// slot (acquireFrame()) on libcamera's thread, the request is requeued at once with its buffer
// and any controls set since, and the frame is handed over: nothing is allocated per frame.
// A disconnect ends the stream with a kDeviceError naming the camera.
#pragma once

#include <atomic>
#include <memory>
#include <mutex>
#include <string>

#include "hal/camera.h"
#include "hal/libcamera/device.h"
#include "hal/libcamera/mapping.h"

namespace commonlight::hal::libcamera_backend {

struct LibcameraOptions {
    StreamRole role = StreamRole::kViewfinder;
    unsigned buffers = 4;  // requests in flight (0: what libcamera proposes)
};

class LibcameraCamera final : public Camera {
public:
    LibcameraCamera(std::string id, std::unique_ptr<Device> device, LibcameraOptions options = {});
    ~LibcameraCamera() override;

    // libcamera's adjusted configuration, after configure().
    const DeviceStreamConfig& deviceConfig() const noexcept { return device_config_; }
    // Requests whose buffer libcamera marked FrameError (delivered as kCorrupt frames when a
    // slot was free). Frames lost for want of a slot are framesWithoutSlot().
    std::uint64_t failedRequests() const noexcept { return failed_requests_.load(std::memory_order_relaxed); }

private:
    std::vector<StreamFormat> doFormats() const override;
    Result<StreamFormat> doConfigure(const StreamConfig& config) override;
    Result<void> doStart() override;
    void doStop() noexcept override;
    std::vector<ControlInfo> doControls() const override;
    Result<void> doSetControl(Control control, double value) override;
    Result<double> doGetControl(Control control) const override;

    // On libcamera's thread.
    void onComplete(const CompletedRequest& request);
    void onDisconnect();
    void reportFailure(std::string message);

    std::unique_ptr<Device> device_;
    LibcameraOptions options_;
    DeviceControls device_controls_;

    // Set by configure() / start() on the control thread, read on libcamera's thread.
    StreamFormat format_;
    DeviceStreamConfig device_config_;
    bool allocated_ = false;
    unsigned request_count_ = 0;
    std::atomic<bool> running_{false};
    std::atomic<bool> failed_{false};

    // Controls set since the last requeue (control thread writes, libcamera's thread takes).
    mutable std::mutex controls_mutex_;
    RequestControls pending_;
    RequestControls requested_;  // every control ever set, for getControl() before metadata arrives

    // The camera thread only.
    SequenceUnwrapper sequence_;

    // What the last completed request reported (0 = not yet).
    std::atomic<double> reported_exposure_us_{0.0};
    std::atomic<double> reported_gain_{0.0};
    std::atomic<double> reported_fps_{0.0};
    std::atomic<std::uint64_t> failed_requests_{0};
};

}  // namespace commonlight::hal::libcamera_backend

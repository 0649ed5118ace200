// aravis:<device id or address>: a GigE Vision (or USB3 Vision) camera through Aravis.
// docs/cameras-aravis.md describes the URI options, formats, controls, timestamps and errors.
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "hal/aravis/aravis_support.h"
#include "hal/camera.h"
#include "hal/camera_uri.h"

namespace commonlight::hal::aravis {

// Everything this backend knows about one device, for `commonlight cameras`.
Result<std::vector<CameraInfo>> enumerateCameras();

class AravisCamera final : public Camera {
public:
    // Opens the device the URI names (an address such as 127.0.0.1, or an Aravis device id).
    static Result<std::unique_ptr<AravisCamera>> open(const CameraUri& uri);
    ~AravisCamera() override;

    // Frames delivered with status kIncomplete (missing packets, timeouts inside a frame).
    std::uint64_t incompleteFrames() const noexcept { return incomplete_.load(std::memory_order_relaxed); }

    struct Impl;  // GLib/Aravis objects; defined in aravis_camera.cpp

private:
    AravisCamera(std::string id, std::unique_ptr<Impl> impl, AravisOptions options);

    std::vector<StreamFormat> doFormats() const override;
    Result<StreamFormat> doConfigure(const StreamConfig& config) override;
    Result<void> doStart() override;
    void doStop() noexcept override;
    std::vector<ControlInfo> doControls() const override;
    Result<void> doSetControl(Control control, double value) override;
    Result<double> doGetControl(Control control) const override;
    // GenICam SFNC: GammaEnable false (or absent with no Gamma) -> "linear"; Gamma G enabled ->
    // the camera encodes out = in^G, so the response is "gamma:<1/G>" (decode: in = out^(1/G)).
    std::string doResponseSpec() const override;

    void run(std::stop_token stop);
    void deliver(void* buffer);  // ArvBuffer*
    void refreshExposureAndGain();
    Result<double> readControl(Control control) const;  // with mutex_ held

    std::unique_ptr<Impl> impl_;
    const AravisOptions options_;
    mutable std::mutex mutex_;  // every call into the ArvCamera (control thread vs camera thread)
    std::uint32_t active_pfnc_ = 0;
    std::atomic<double> exposure_us_{0.0};
    std::atomic<double> gain_{0.0};
    std::atomic<bool> auto_exposure_{false};
    std::atomic<std::uint64_t> incomplete_{0};
    FrameIdUnwrapper frame_ids_;   // camera thread
    DeviceClockMapper clock_;      // camera thread
    std::jthread thread_;
};

}  // namespace commonlight::hal::aravis

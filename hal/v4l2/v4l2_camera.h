// A V4L2 video capture device (single-planar, memory-mapped streaming I/O).
//
//   open:      open(O_RDWR|O_NONBLOCK), VIDIOC_QUERYCAP (capture + streaming), ENUM_FMT /
//              ENUM_FRAMESIZES / ENUM_FRAMEINTERVALS -> formats(), QUERYCTRL -> controls().
//   configure: hal::negotiate over the formats, S_FMT (the driver's answer is checked), S_PARM.
//   start:     REQBUFS (mmap), QUERYBUF + mmap, QBUF all, STREAMON, camera thread.
//   thread:    poll(device, stop eventfd) -> DQBUF -> copy into a pool slot -> QBUF at once.
//   stop:      wake the thread, join, STREAMOFF, munmap, REQBUFS 0.
//
// Every system call goes through the System seam (v4l2_system.h); tests pass a fake device.
// Formats: YUYV, MJPEG (and JPEG), NV12, GREY; other formats the device offers are not listed.
// Controls by numeric id (names changed across kernels): EXPOSURE_ABSOLUTE (100 us units),
// EXPOSURE_AUTO, ANALOGUE_GAIN (else GAIN, in the driver's units), AUTO_WHITE_BALANCE, and the
// frame rate through S_PARM.
#pragma once

#include <linux/videodev2.h>

#include <atomic>
#include <cstdint>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "core/result.h"
#include "hal/camera.h"
#include "hal/v4l2/v4l2_system.h"

namespace commonlight::hal::v4l2 {

struct V4l2Options {
    int buffers = 4;          // driver buffers requested (REQBUFS); the driver may grant more
    int timeout_ms = 10000;   // no frame for this long while streaming -> device error; 0: wait forever
    int ae_refresh_frames = 8;  // with auto exposure on, re-read exposure/gain every N frames
};

// The V4L2 pixel format (fourcc) for ours, 0 when V4L2 has none we stream.
std::uint32_t toFourcc(PixelFormat format) noexcept;
// Ours for a V4L2 fourcc; kInvalid for formats this backend does not stream.
PixelFormat fromFourcc(std::uint32_t fourcc) noexcept;

class V4l2Camera final : public Camera {
public:
    // Opens `path` (e.g. /dev/video0) through `system` (borrowed; must outlive the camera).
    // kNotFound when the path does not exist; kUnsupported when it is not a streaming capture
    // device; kDevice for permission or busy errors. Messages name the path and the call.
    static Result<std::unique_ptr<V4l2Camera>> open(System& system, const std::string& path,
                                                    const V4l2Options& options = {});
    ~V4l2Camera() override;

    const std::string& path() const noexcept { return path_; }
    const std::string& card() const noexcept { return card_; }
    const std::string& driver() const noexcept { return driver_; }
    // The driver's buffer count after start() (REQBUFS may grant more or fewer than asked).
    std::size_t bufferCount() const noexcept { return buffers_.size(); }

private:
    struct Buffer {
        void* data = nullptr;
        std::size_t length = 0;
    };
    // What QUERYCTRL said about one control the device has.
    struct DeviceControl {
        std::uint32_t id = 0;
        bool present = false;
        std::int32_t min = 0, max = 0, step = 0, default_value = 0;
    };
    // A stepwise/continuous frame size range, for sizes asked for that the list does not hold.
    struct SizeRange {
        PixelFormat format = PixelFormat::kInvalid;
        std::uint32_t min_w = 0, max_w = 0, step_w = 1, min_h = 0, max_h = 0, step_h = 1;
    };

    V4l2Camera(System& system, std::string path, int fd, const V4l2Options& options);
    Result<void> queryCapabilities();
    Result<void> enumerateFormats();
    std::vector<double> frameRates(std::uint32_t fourcc, std::uint32_t width, std::uint32_t height);
    void queryControls();
    void releaseBuffers() noexcept;
    void run(std::stop_token stop);  // the camera thread
    void deliver(const v4l2_buffer& buffer);
    void refreshExposure() noexcept;
    Error callError(std::string_view call, int error) const;
    const DeviceControl* control(Control control) const noexcept;
    Result<std::int32_t> readControl(const DeviceControl& c) const;
    Result<void> writeControl(const DeviceControl& c, std::int32_t value);

    std::vector<StreamFormat> doFormats() const override { return formats_; }
    Result<StreamFormat> doConfigure(const StreamConfig& config) override;
    Result<void> doStart() override;
    void doStop() noexcept override;
    std::vector<ControlInfo> doControls() const override;
    Result<void> doSetControl(Control control, double value) override;
    Result<double> doGetControl(Control control) const override;
    std::string doResponseSpec() const override;

    System& system_;
    std::string path_;
    int fd_ = -1;
    V4l2Options options_;
    std::string card_;
    std::string driver_;
    bool timeperframe_ = false;  // S_PARM can set the frame rate
    std::vector<StreamFormat> formats_;
    std::vector<SizeRange> ranges_;

    DeviceControl exposure_{};       // V4L2_CID_EXPOSURE_ABSOLUTE, 100 us units
    DeviceControl exposure_auto_{};  // V4L2_CID_EXPOSURE_AUTO (menu)
    DeviceControl gain_{};           // V4L2_CID_ANALOGUE_GAIN, else V4L2_CID_GAIN
    DeviceControl awb_{};            // V4L2_CID_AUTO_WHITE_BALANCE
    DeviceControl gamma_{};          // V4L2_CID_GAMMA (UVC: gamma x 100)

    // The configured format as the driver set it.
    std::uint32_t fourcc_ = 0;
    std::uint32_t bytes_per_line_ = 0;
    std::uint32_t size_image_ = 0;

    std::vector<Buffer> buffers_;
    int stop_fd_ = -1;  // eventfd that wakes the camera thread's poll for stop()
    std::jthread thread_;

    // Per-frame metadata cache: written by the control thread (set/get) and by the camera thread
    // (refresh with auto exposure on), read by the camera thread.
    std::atomic<double> exposure_us_{0.0};
    std::atomic<double> analog_gain_{0.0};
    std::atomic<bool> auto_exposure_on_{false};
    std::uint32_t frames_since_refresh_ = 0;  // camera thread
};

// Lists the capture devices among /dev/video0 .. /dev/video63, opened through `system` one by one
// (not by listing /dev: libpw-v4l2 serves /dev/videoN paths that do not exist as files).
std::vector<CameraInfo> enumerateCameras(System& system, int max_index = 64);

}  // namespace commonlight::hal::v4l2

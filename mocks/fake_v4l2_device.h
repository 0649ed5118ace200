// A fake V4L2 capture device behind the backend's system-call seam (hal/v4l2/v4l2_system.h), with
// the kernel's state machine: capabilities, formats / frame sizes / frame intervals, controls,
// S_FMT that adjusts to the nearest size like a driver, REQBUFS / QUERYBUF / mmap of real memory,
// buffer states (dequeued -> queued -> done -> dequeued) with EINVAL on illegal transitions,
// EBUSY for REQBUFS while streaming or while buffers are mapped, EAGAIN on DQBUF with nothing
// done, and a disconnect after which every call fails with ENODEV and poll() reports POLLERR.
//
// Frames come from the test: produceFrame() fills the oldest queued buffer (a pattern, or given
// bytes) and marks it done; with no buffer queued (a slow consumer) the frame is lost at the
// device and the sequence counter still advances, so the gap shows. Readiness goes through a real
// eventfd, so poll() works: each open() returns a dup() of the device's eventfd.
//
// Thread-safe: the test thread produces while the camera thread dequeues.
#pragma once

#ifdef COMMONLIGHT_HAVE_V4L2

#include <linux/videodev2.h>

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "hal/v4l2/v4l2_system.h"

namespace commonlight::mocks {

struct FakeV4l2Size {
    // Discrete (step_width == 0) or stepwise (width/height are the maximum).
    std::uint32_t width = 0;
    std::uint32_t height = 0;
    std::uint32_t min_width = 0, min_height = 0, step_width = 0, step_height = 0;
    std::vector<std::uint32_t> fps;  // discrete frame intervals 1/fps, fastest first
};

struct FakeV4l2Format {
    std::uint32_t fourcc = V4L2_PIX_FMT_YUYV;
    std::vector<FakeV4l2Size> sizes;
};

struct FakeV4l2Control {
    std::uint32_t id = 0;
    std::int32_t min = 0, max = 0, step = 1, default_value = 0;
    std::int32_t value = 0;
};

struct FakeV4l2Config {
    std::string card = "Fake V4L2 camera";
    std::string driver = "fakev4l2";
    std::uint32_t capabilities = V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_STREAMING;
    std::vector<FakeV4l2Format> formats;
    std::vector<FakeV4l2Control> controls;
    bool timeperframe = true;       // S_PARM sets the rate (V4L2_CAP_TIMEPERFRAME)
    std::uint32_t line_padding = 0;  // bytesperline = width * bpp + padding (uncompressed)
    std::uint32_t max_buffers = 8;  // REQBUFS grants at most this many
    // Added to every buffer's flags: the timestamp type and source.
    std::uint32_t timestamp_flags = V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC | V4L2_BUF_FLAG_TSTAMP_SRC_SOE;
    int open_errno = 0;  // open() fails with this (EACCES, EBUSY) when set
    // S_FMT never sets a width above this (0: no limit), like a driver short of USB bandwidth
    // that falls back to a smaller size than the one it listed.
    std::uint32_t max_set_width = 0;

    // A typical webcam: YUYV 640x480 @30/15 and 320x240 @30, MJPEG 1280x720 @30 and 640x480,
    // NV12 and GREY 640x480 @30; exposure, auto exposure, gain and auto white balance.
    static FakeV4l2Config webcam();
};

// One produced frame; unset fields take the defaults.
struct FakeV4l2Frame {
    std::optional<std::vector<std::uint8_t>> payload;  // bytes to put in the buffer (else the pattern)
    std::optional<std::uint32_t> bytesused;            // else the payload's size or sizeimage
    std::uint32_t flags = 0;                           // extra flags (V4L2_BUF_FLAG_ERROR)
    std::optional<timeval> timestamp;                  // else CLOCK_MONOTONIC now
};

class FakeV4l2Device {
public:
    explicit FakeV4l2Device(FakeV4l2Config config);
    ~FakeV4l2Device();
    FakeV4l2Device(const FakeV4l2Device&) = delete;
    FakeV4l2Device& operator=(const FakeV4l2Device&) = delete;

    // The byte the pattern puts at offset i of the frame with this sequence number.
    static std::uint8_t patternByte(std::uint32_t sequence, std::size_t i) noexcept {
        return static_cast<std::uint8_t>(sequence * 31u + i * 7u + (i >> 8));
    }

    // --- the test's side ---
    // Fills the oldest queued buffer and marks it done. Returns its sequence number, or nullopt
    // when no buffer was queued (the frame is lost at the device; the sequence still advances)
    // or the device is not streaming (nothing happens).
    std::optional<std::uint32_t> produceFrame(const FakeV4l2Frame& frame = {});
    // Wakes poll() with no buffer done (the next DQBUF answers EAGAIN, as after a spurious wake-up).
    void spuriousWakeup();
    // Frames lost at the device without any buffer involved (the sequence jumps by n).
    void skipSequence(std::uint32_t n);
    // Unplugs the device: every later call fails with ENODEV; poll() reports POLLERR.
    void disconnect();
    // Waits until every buffer is queued again (the consumer caught up) or the timeout passes.
    bool waitAllQueued(std::chrono::milliseconds timeout);
    // Waits until the device streams (STREAMON) or the timeout passes.
    bool waitStreaming(std::chrono::milliseconds timeout);
    void setControlValue(std::uint32_t id, std::int32_t value);  // the camera's auto exposure moved
    std::int32_t controlValue(std::uint32_t id) const;

    bool streaming() const;
    std::size_t bufferCount() const;
    std::size_t mappedCount() const;
    std::uint64_t framesLost() const;  // frames lost for want of a queued buffer
    std::uint32_t currentFourcc() const;
    std::uint32_t currentWidth() const;
    std::uint32_t currentHeight() const;
    std::uint32_t bytesPerLine() const;
    double currentFps() const;
    int dqbufEagainCount() const;  // DQBUF calls answered EAGAIN
    int pollFd() const noexcept { return event_fd_; }

    // --- the seam's side (called by FakeV4l2System) ---
    int ioctl(unsigned long request, void* arg);
    void* mmap(std::size_t length, off_t offset);
    int munmap(void* addr, std::size_t length);
    bool disconnected() const;
    int openErrno() const noexcept { return config_.open_errno; }

private:
    enum class BufferState { kDequeued, kQueued, kDone };
    struct Buffer {
        std::vector<std::uint8_t> memory;
        BufferState state = BufferState::kDequeued;
        int mapped = 0;
        v4l2_buffer info{};
    };

    void setFormat(v4l2_pix_format& pix);  // adjusts to what the device can do (mutex held)
    const FakeV4l2Format* findFormat(std::uint32_t fourcc) const;
    FakeV4l2Control* findControl(std::uint32_t id);
    void fillBufferInfo(std::uint32_t index, v4l2_buffer& out) const;
    void signal();    // one more buffer done
    void unsignal();  // one fewer

    FakeV4l2Config config_;
    int event_fd_ = -1;
    mutable std::mutex mutex_;
    std::condition_variable changed_;
    v4l2_pix_format format_{};
    v4l2_fract interval_{1, 30};
    std::vector<Buffer> buffers_;
    std::vector<std::uint32_t> queued_;  // FIFO of queued buffer indices
    std::vector<std::uint32_t> done_;    // FIFO of done buffer indices
    bool streaming_ = false;
    bool disconnected_ = false;
    std::uint32_t sequence_ = 0;
    std::uint64_t lost_ = 0;
    int eagain_ = 0;
};

// The seam over any number of fake devices, each at a path ("/dev/video0").
class FakeV4l2System final : public hal::v4l2::System {
public:
    FakeV4l2Device& add(const std::string& path, FakeV4l2Config config);
    FakeV4l2Device* device(const std::string& path);
    int openCount() const;  // file descriptors open now

    int open(const char* path, int flags) override;
    int close(int fd) override;
    int ioctl(int fd, unsigned long request, void* arg) override;
    void* mmap(void* addr, std::size_t length, int prot, int flags, int fd, off_t offset) override;
    int munmap(void* addr, std::size_t length) override;
    int poll(pollfd* fds, nfds_t count, int timeout_ms) override;

    ~FakeV4l2System() override;

private:
    FakeV4l2Device* byFd(int fd) const;

    mutable std::mutex mutex_;
    std::map<std::string, std::unique_ptr<FakeV4l2Device>> devices_;
    std::map<int, FakeV4l2Device*> fds_;
};

}  // namespace commonlight::mocks

#endif  // COMMONLIGHT_HAVE_V4L2

#include "hal/v4l2/v4l2_camera.h"

#include <fcntl.h>
#include <linux/videodev2.h>
#include <sys/eventfd.h>
#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <sstream>

#include "core/clock.h"

namespace commonlight::hal::v4l2 {

namespace {

// A v4l2_buffer naming buffer `index` of our mmap capture queue.
v4l2_buffer captureBuffer(std::uint32_t index = 0) noexcept {
    v4l2_buffer buf{};
    buf.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    buf.memory = V4L2_MEMORY_MMAP;
    buf.index = index;
    return buf;
}

// A short explanation of the errno values V4L2 calls fail with.
std::string errnoText(int error) {
    std::string text = std::strerror(error);
    switch (error) {
        case EACCES: text += " (permission denied: is the user in the 'video' group?)"; break;
        case EBUSY: text += " (the device is busy: another program may be streaming from it)"; break;
        case ENODEV: text += " (the device was disconnected)"; break;
        case ENOTTY: text += " (the device does not support this call: not a V4L2 device?)"; break;
        default: break;
    }
    return text;
}

std::string fourccText(std::uint32_t fourcc) {
    std::string s;
    for (int i = 0; i < 4; ++i) {
        const char c = static_cast<char>((fourcc >> (8 * i)) & 0xff);
        s += (c >= 32 && c < 127) ? c : '?';
    }
    return s;
}

double fpsOf(const v4l2_fract& interval) {
    if (interval.numerator == 0 || interval.denominator == 0) return 0.0;
    return static_cast<double>(interval.denominator) / static_cast<double>(interval.numerator);
}

// Bytes an uncompressed frame occupies in a driver buffer with this line pitch.
std::size_t frameBytes(PixelFormat format, std::uint32_t bytes_per_line, std::uint32_t height) {
    const std::size_t rows = format == PixelFormat::kNv12 ? height + height / 2 : height;
    return static_cast<std::size_t>(bytes_per_line) * rows;
}

constexpr std::uint32_t kStepwiseSizes[][2] = {{160, 120},  {320, 240},   {640, 480},   {800, 600},  {1024, 768},
                                              {1280, 720}, {1280, 1024}, {1920, 1080}, {2560, 1440}, {3840, 2160}};

}  // namespace

std::uint32_t toFourcc(PixelFormat format) noexcept {
    switch (format) {
        case PixelFormat::kYuyv: return V4L2_PIX_FMT_YUYV;
        case PixelFormat::kMjpeg: return V4L2_PIX_FMT_MJPEG;
        case PixelFormat::kNv12: return V4L2_PIX_FMT_NV12;
        case PixelFormat::kGray8: return V4L2_PIX_FMT_GREY;
        default: return 0;
    }
}

PixelFormat fromFourcc(std::uint32_t fourcc) noexcept {
    switch (fourcc) {
        case V4L2_PIX_FMT_YUYV: return PixelFormat::kYuyv;
        case V4L2_PIX_FMT_MJPEG:
        case V4L2_PIX_FMT_JPEG: return PixelFormat::kMjpeg;
        case V4L2_PIX_FMT_NV12: return PixelFormat::kNv12;
        case V4L2_PIX_FMT_GREY: return PixelFormat::kGray8;
        default: return PixelFormat::kInvalid;
    }
}

V4l2Camera::V4l2Camera(System& system, std::string path, int fd, const V4l2Options& options)
    : Camera("v4l2:" + path), system_(system), path_(std::move(path)), fd_(fd), options_(options) {}

V4l2Camera::~V4l2Camera() {
    stop();
    if (fd_ >= 0) system_.close(fd_);
}

Error V4l2Camera::callError(std::string_view call, int error) const {
    const ErrorCode code = (error == ENOTTY || error == EINVAL) ? ErrorCode::kUnsupported : ErrorCode::kDevice;
    return Error{code, id() + ": " + std::string(call) + " failed: " + errnoText(error)};
}

Result<std::unique_ptr<V4l2Camera>> V4l2Camera::open(System& system, const std::string& path,
                                                    const V4l2Options& options) {
    const std::string id = "v4l2:" + path;
    if (options.buffers < 2 || options.buffers > 32) {
        return fail(ErrorCode::kUsage, id + ": buffers must be between 2 and 32, not " + std::to_string(options.buffers));
    }
    if (options.timeout_ms < 0) return fail(ErrorCode::kUsage, id + ": timeout_ms must be >= 0");
    const int fd = system.open(path.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0) {
        const int error = errno;
        const ErrorCode code = error == ENOENT ? ErrorCode::kNotFound : ErrorCode::kDevice;
        return fail(code, id + ": cannot open " + path + ": " + errnoText(error));
    }
    std::unique_ptr<V4l2Camera> camera(new V4l2Camera(system, path, fd, options));
    CL_TRY_VOID(camera->queryCapabilities());
    CL_TRY_VOID(camera->enumerateFormats());
    camera->queryControls();
    return camera;
}

Result<void> V4l2Camera::queryCapabilities() {
    v4l2_capability cap{};
    if (xioctl(system_, fd_, VIDIOC_QUERYCAP, &cap) < 0) {
        const int error = errno;
        if (error == ENOTTY || error == EINVAL) {
            return fail(ErrorCode::kUnsupported, id() + ": not a V4L2 device (VIDIOC_QUERYCAP: " + errnoText(error) + ")");
        }
        return fail(callError("VIDIOC_QUERYCAP", error));
    }
    card_ = std::string(reinterpret_cast<const char*>(cap.card), strnlen(reinterpret_cast<const char*>(cap.card), sizeof cap.card));
    driver_ = std::string(reinterpret_cast<const char*>(cap.driver), strnlen(reinterpret_cast<const char*>(cap.driver), sizeof cap.driver));
    const std::uint32_t caps = (cap.capabilities & V4L2_CAP_DEVICE_CAPS) ? cap.device_caps : cap.capabilities;
    if (!(caps & V4L2_CAP_VIDEO_CAPTURE)) {
        std::string why = (caps & V4L2_CAP_VIDEO_CAPTURE_MPLANE)
                              ? "a multi-planar capture device, which this backend does not support"
                              : "not a video capture device (a metadata, output or codec node?)";
        return fail(ErrorCode::kUnsupported, id() + " (" + card_ + "): " + why);
    }
    if (!(caps & V4L2_CAP_STREAMING)) {
        return fail(ErrorCode::kUnsupported, id() + " (" + card_ + "): the device has no streaming I/O (V4L2_CAP_STREAMING)");
    }
    return {};
}

std::vector<double> V4l2Camera::frameRates(std::uint32_t fourcc, std::uint32_t width, std::uint32_t height) {
    std::vector<double> rates;
    for (std::uint32_t index = 0;; ++index) {
        v4l2_frmivalenum ival{};
        ival.index = index;
        ival.pixel_format = fourcc;
        ival.width = width;
        ival.height = height;
        if (xioctl(system_, fd_, VIDIOC_ENUM_FRAMEINTERVALS, &ival) < 0) break;
        if (ival.type == V4L2_FRMIVAL_TYPE_DISCRETE) {
            const double fps = fpsOf(ival.discrete);
            if (fps > 0) rates.push_back(fps);
        } else {
            // Stepwise or continuous: the fastest and the slowest rate, and the common ones between.
            const double fastest = fpsOf(ival.stepwise.min);
            const double slowest = fpsOf(ival.stepwise.max);
            if (fastest > 0) rates.push_back(fastest);
            for (double common : {60.0, 30.0, 15.0}) {
                if (common < fastest && common > slowest) rates.push_back(common);
            }
            if (slowest > 0 && slowest != fastest) rates.push_back(slowest);
            break;
        }
    }
    return rates;
}

Result<void> V4l2Camera::enumerateFormats() {
    formats_.clear();
    ranges_.clear();
    for (std::uint32_t index = 0;; ++index) {
        v4l2_fmtdesc desc{};
        desc.index = index;
        desc.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
        if (xioctl(system_, fd_, VIDIOC_ENUM_FMT, &desc) < 0) {
            if (errno == EINVAL) break;  // the end of the list
            return fail(callError("VIDIOC_ENUM_FMT", errno));
        }
        const PixelFormat format = fromFourcc(desc.pixelformat);
        if (format == PixelFormat::kInvalid) continue;
        if (std::any_of(formats_.begin(), formats_.end(), [&](const StreamFormat& f) { return f.format == format; })) {
            continue;  // MJPEG and JPEG both offered: one is enough
        }
        for (std::uint32_t size_index = 0;; ++size_index) {
            v4l2_frmsizeenum size{};
            size.index = size_index;
            size.pixel_format = desc.pixelformat;
            if (xioctl(system_, fd_, VIDIOC_ENUM_FRAMESIZES, &size) < 0) break;
            if (size.type == V4L2_FRMSIZE_TYPE_DISCRETE) {
                formats_.push_back({format, static_cast<int>(size.discrete.width), static_cast<int>(size.discrete.height),
                                    frameRates(desc.pixelformat, size.discrete.width, size.discrete.height), 0.0});
                continue;
            }
            const auto& s = size.stepwise;
            SizeRange range{format, s.min_width, s.max_width, std::max(1u, s.step_width),
                            s.min_height, s.max_height, std::max(1u, s.step_height)};
            ranges_.push_back(range);
            auto fits = [&](std::uint32_t w, std::uint32_t h) {
                return w >= range.min_w && w <= range.max_w && h >= range.min_h && h <= range.max_h &&
                       (w - range.min_w) % range.step_w == 0 && (h - range.min_h) % range.step_h == 0;
            };
            // List the common sizes the range holds, and its largest.
            for (const auto& common : kStepwiseSizes) {
                if (fits(common[0], common[1])) {
                    formats_.push_back({format, static_cast<int>(common[0]), static_cast<int>(common[1]),
                                        frameRates(desc.pixelformat, common[0], common[1]), 0.0});
                }
            }
            if (!std::any_of(formats_.begin(), formats_.end(), [&](const StreamFormat& f) {
                    return f.format == format && f.width == static_cast<int>(s.max_width) &&
                           f.height == static_cast<int>(s.max_height);
                })) {
                formats_.push_back({format, static_cast<int>(s.max_width), static_cast<int>(s.max_height),
                                    frameRates(desc.pixelformat, s.max_width, s.max_height), 0.0});
            }
            break;
        }
    }
    return {};
}

void V4l2Camera::queryControls() {
    auto query = [&](DeviceControl& c, std::uint32_t id) {
        v4l2_queryctrl q{};
        q.id = id;
        if (xioctl(system_, fd_, VIDIOC_QUERYCTRL, &q) < 0) return false;
        if (q.flags & V4L2_CTRL_FLAG_DISABLED) return false;
        c = DeviceControl{id, true, q.minimum, q.maximum, q.step, q.default_value};
        return true;
    };
    query(exposure_, V4L2_CID_EXPOSURE_ABSOLUTE);
    query(exposure_auto_, V4L2_CID_EXPOSURE_AUTO);
    if (!query(gain_, V4L2_CID_ANALOGUE_GAIN)) query(gain_, V4L2_CID_GAIN);
    query(awb_, V4L2_CID_AUTO_WHITE_BALANCE);
    query(gamma_, V4L2_CID_GAMMA);
    if (exposure_auto_.present) {
        if (auto value = readControl(exposure_auto_)) auto_exposure_on_ = *value != V4L2_EXPOSURE_MANUAL;
    }
    if (exposure_.present) {
        if (auto value = readControl(exposure_)) exposure_us_ = 100.0 * *value;
    }
    if (gain_.present) {
        if (auto value = readControl(gain_)) analog_gain_ = *value;
    }
}

Result<StreamFormat> V4l2Camera::doConfigure(const StreamConfig& config) {
    std::vector<StreamFormat> offered = formats_;
    // A size inside a stepwise range that the list does not name is offered too.
    for (const auto& r : ranges_) {
        if (config.width <= 0 || config.height <= 0) continue;
        if (config.format != PixelFormat::kInvalid && config.format != r.format) continue;
        const auto w = static_cast<std::uint32_t>(config.width);
        const auto h = static_cast<std::uint32_t>(config.height);
        if (w >= r.min_w && w <= r.max_w && h >= r.min_h && h <= r.max_h && (w - r.min_w) % r.step_w == 0 &&
            (h - r.min_h) % r.step_h == 0) {
            offered.push_back({r.format, config.width, config.height, frameRates(toFourcc(r.format), w, h), 0.0});
        }
    }
    CL_TRY(StreamFormat chosen, negotiate(offered, config, id()));

    v4l2_format fmt{};
    fmt.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    fmt.fmt.pix.width = static_cast<std::uint32_t>(chosen.width);
    fmt.fmt.pix.height = static_cast<std::uint32_t>(chosen.height);
    fmt.fmt.pix.pixelformat = toFourcc(chosen.format);
    fmt.fmt.pix.field = V4L2_FIELD_NONE;
    // A device that offers only JPEG (not MJPEG) gets the fourcc it listed.
    if (chosen.format == PixelFormat::kMjpeg) {
        v4l2_fmtdesc desc{};
        desc.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
        bool mjpeg = false, jpeg = false;
        for (desc.index = 0; xioctl(system_, fd_, VIDIOC_ENUM_FMT, &desc) == 0; ++desc.index) {
            mjpeg = mjpeg || desc.pixelformat == V4L2_PIX_FMT_MJPEG;
            jpeg = jpeg || desc.pixelformat == V4L2_PIX_FMT_JPEG;
        }
        if (!mjpeg && jpeg) fmt.fmt.pix.pixelformat = V4L2_PIX_FMT_JPEG;
    }
    const std::uint32_t asked = fmt.fmt.pix.pixelformat;
    if (xioctl(system_, fd_, VIDIOC_S_FMT, &fmt) < 0) return fail(callError("VIDIOC_S_FMT", errno));
    const auto& pix = fmt.fmt.pix;
    if (pix.pixelformat != asked || pix.width != static_cast<std::uint32_t>(chosen.width) ||
        pix.height != static_cast<std::uint32_t>(chosen.height)) {
        std::ostringstream msg;
        msg << id() << ": asked the driver for " << fourccText(asked) << " " << chosen.width << "x" << chosen.height
            << " (VIDIOC_S_FMT), it set " << fourccText(pix.pixelformat) << " " << pix.width << "x" << pix.height
            << " instead";
        return fail(ErrorCode::kUnsupported, msg.str());
    }
    const PixelFormat format = chosen.format;
    if (!isCompressed(format)) {
        const std::size_t min_line = minStride(format, chosen.width);
        if (pix.bytesperline < min_line || pix.sizeimage < frameBytes(format, pix.bytesperline, pix.height)) {
            std::ostringstream msg;
            msg << id() << ": VIDIOC_S_FMT returned an inconsistent layout (bytesperline " << pix.bytesperline
                << ", sizeimage " << pix.sizeimage << " for " << describe(chosen) << ")";
            return fail(ErrorCode::kDevice, msg.str());
        }
    } else if (pix.sizeimage == 0) {
        return fail(ErrorCode::kDevice, id() + ": VIDIOC_S_FMT returned sizeimage 0 for MJPEG");
    }
    fourcc_ = pix.pixelformat;
    bytes_per_line_ = pix.bytesperline;
    size_image_ = pix.sizeimage;

    // The frame rate (S_PARM), when the driver can set it; the rate it chose is what we report.
    v4l2_streamparm parm{};
    parm.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    if (xioctl(system_, fd_, VIDIOC_G_PARM, &parm) == 0) {
        timeperframe_ = (parm.parm.capture.capability & V4L2_CAP_TIMEPERFRAME) != 0;
    } else {
        timeperframe_ = false;
    }
    if (timeperframe_ && chosen.fps > 0) {
        v4l2_streamparm set{};
        set.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
        set.parm.capture.timeperframe.numerator = 1000;
        set.parm.capture.timeperframe.denominator = static_cast<std::uint32_t>(std::lround(chosen.fps * 1000.0));
        if (xioctl(system_, fd_, VIDIOC_S_PARM, &set) < 0) return fail(callError("VIDIOC_S_PARM", errno));
        const double got = fpsOf(set.parm.capture.timeperframe);
        if (got > 0) chosen.fps = got;
    } else if (!timeperframe_) {
        const double current = fpsOf(parm.parm.capture.timeperframe);
        if (current > 0) chosen.fps = current;
    }
    return chosen;
}

void V4l2Camera::releaseBuffers() noexcept {
    for (auto& b : buffers_) {
        if (b.data != nullptr) system_.munmap(b.data, b.length);
    }
    buffers_.clear();
    v4l2_requestbuffers req{};
    req.count = 0;
    req.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    req.memory = V4L2_MEMORY_MMAP;
    xioctl(system_, fd_, VIDIOC_REQBUFS, &req);  // fails harmlessly after a disconnect
}

Result<void> V4l2Camera::doStart() {
    v4l2_requestbuffers req{};
    req.count = static_cast<std::uint32_t>(options_.buffers);
    req.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    req.memory = V4L2_MEMORY_MMAP;
    if (xioctl(system_, fd_, VIDIOC_REQBUFS, &req) < 0) {
        const int error = errno;
        if (error == EINVAL) {
            return fail(ErrorCode::kUnsupported, id() + ": VIDIOC_REQBUFS: the device does not support memory-mapped streaming");
        }
        return fail(callError("VIDIOC_REQBUFS", error));
    }
    if (req.count < 2) {
        releaseBuffers();
        return fail(ErrorCode::kDevice, id() + ": VIDIOC_REQBUFS granted " + std::to_string(req.count) + " buffer(s); at least 2 are needed");
    }
    buffers_.assign(req.count, Buffer{});
    for (std::uint32_t i = 0; i < req.count; ++i) {
        v4l2_buffer buf = captureBuffer(i);
        if (xioctl(system_, fd_, VIDIOC_QUERYBUF, &buf) < 0) {
            Error e = callError("VIDIOC_QUERYBUF", errno);
            releaseBuffers();
            return fail(std::move(e));
        }
        void* data = system_.mmap(nullptr, buf.length, PROT_READ | PROT_WRITE, MAP_SHARED, fd_, buf.m.offset);
        if (data == MAP_FAILED) {
            Error e = callError("mmap of buffer " + std::to_string(i), errno);
            releaseBuffers();
            return fail(std::move(e));
        }
        buffers_[i] = Buffer{data, buf.length};
    }
    for (std::uint32_t i = 0; i < req.count; ++i) {
        v4l2_buffer buf = captureBuffer(i);
        if (xioctl(system_, fd_, VIDIOC_QBUF, &buf) < 0) {
            Error e = callError("VIDIOC_QBUF", errno);
            releaseBuffers();
            return fail(std::move(e));
        }
    }
    stop_fd_ = ::eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    if (stop_fd_ < 0) {
        Error e{ErrorCode::kInternal, id() + ": eventfd: " + std::string(std::strerror(errno))};
        releaseBuffers();
        return fail(std::move(e));
    }
    int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    if (xioctl(system_, fd_, VIDIOC_STREAMON, &type) < 0) {
        Error e = callError("VIDIOC_STREAMON", errno);
        ::close(stop_fd_);
        stop_fd_ = -1;
        releaseBuffers();
        return fail(std::move(e));
    }
    frames_since_refresh_ = 0;
    thread_ = std::jthread([this](std::stop_token stop) { run(stop); });
    return {};
}

void V4l2Camera::doStop() noexcept {
    if (thread_.joinable()) {
        thread_.request_stop();
        const std::uint64_t one = 1;
        [[maybe_unused]] const ssize_t n = ::write(stop_fd_, &one, sizeof one);
        thread_.join();
    }
    int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    xioctl(system_, fd_, VIDIOC_STREAMOFF, &type);
    releaseBuffers();
    if (stop_fd_ >= 0) ::close(stop_fd_);
    stop_fd_ = -1;
}

void V4l2Camera::run(std::stop_token stop) {
    auto deviceError = [&](std::string message) {
        emitEvent(CameraEvent{CameraEvent::Type::kDeviceError, Error{ErrorCode::kDevice, id() + ": " + message}});
    };
    const int timeout = options_.timeout_ms > 0 ? options_.timeout_ms : -1;
    while (!stop.stop_requested()) {
        pollfd fds[2] = {{fd_, POLLIN, 0}, {stop_fd_, POLLIN, 0}};
        const int ready = system_.poll(fds, 2, timeout);
        if (ready < 0) {
            if (errno == EINTR) continue;
            deviceError("poll failed: " + errnoText(errno));
            return;
        }
        if (fds[1].revents != 0 || stop.stop_requested()) return;
        if (ready == 0) {
            deviceError("no frame for " + std::to_string(options_.timeout_ms) + " ms (timeout_ms)");
            return;
        }
        if (fds[0].revents & (POLLERR | POLLHUP | POLLNVAL)) {
            // Find out why: a disconnected device fails DQBUF with ENODEV.
            v4l2_buffer probe = captureBuffer();
            const int got = xioctl(system_, fd_, VIDIOC_DQBUF, &probe);
            const int error = got < 0 ? errno : 0;
            if (got == 0 && probe.index < buffers_.size()) {
                deliver(probe);  // a frame after all: keep streaming
                continue;
            }
            if (got == 0) {
                deviceError("VIDIOC_DQBUF returned buffer " + std::to_string(probe.index) + " of " +
                            std::to_string(buffers_.size()));
            } else if (error != EAGAIN) {
                deviceError("VIDIOC_DQBUF failed: " + errnoText(error));
            } else {
                deviceError(std::string("the device reported an error (poll: ") +
                            ((fds[0].revents & POLLHUP) ? "POLLHUP" : (fds[0].revents & POLLNVAL) ? "POLLNVAL" : "POLLERR") +
                            "); disconnected?");
            }
            return;
        }
        if (!(fds[0].revents & POLLIN)) continue;
        // Take every buffer that is done.
        while (!stop.stop_requested()) {
            v4l2_buffer buf = captureBuffer();
            if (xioctl(system_, fd_, VIDIOC_DQBUF, &buf) < 0) {
                if (errno == EAGAIN) break;
                deviceError("VIDIOC_DQBUF failed: " + errnoText(errno));
                return;
            }
            if (buf.index >= buffers_.size()) {
                deviceError("VIDIOC_DQBUF returned buffer " + std::to_string(buf.index) + " of " +
                            std::to_string(buffers_.size()));
                return;
            }
            deliver(buf);
        }
    }
}

void V4l2Camera::refreshExposure() noexcept {
    // Stack structs only: no allocation on the camera thread.
    if (exposure_.present) {
        v4l2_control c{exposure_.id, 0};
        if (xioctl(system_, fd_, VIDIOC_G_CTRL, &c) == 0) exposure_us_.store(100.0 * c.value, std::memory_order_relaxed);
    }
    if (gain_.present) {
        v4l2_control c{gain_.id, 0};
        if (xioctl(system_, fd_, VIDIOC_G_CTRL, &c) == 0) analog_gain_.store(c.value, std::memory_order_relaxed);
    }
}

void V4l2Camera::deliver(const v4l2_buffer& buf) {
    const std::int64_t arrival = monotonicNowNs();
    const StreamFormat& format = activeFormat();
    FrameHandle frame = acquireFrame();  // empty: counted by the base class as a frame without a slot
    if (frame) {
        const auto* src = static_cast<const std::uint8_t*>(buffers_[buf.index].data);
        const std::size_t used = std::min<std::size_t>(buf.bytesused, buffers_[buf.index].length);
        FrameStatus status = (buf.flags & V4L2_BUF_FLAG_ERROR) ? FrameStatus::kIncomplete : FrameStatus::kOk;
        Image& image = frame->image;
        if (format.format == PixelFormat::kMjpeg) {
            image.reshapeCompressed(format.width, format.height, used);
            if (used > 0) std::memcpy(image.data(), src, used);
            if (used == 0) status = FrameStatus::kIncomplete;
        } else {
            image.reshape(format.format, format.width, format.height);
            if (used < frameBytes(format.format, bytes_per_line_, static_cast<std::uint32_t>(format.height))) {
                status = FrameStatus::kIncomplete;
            }
            const int rows = format.format == PixelFormat::kNv12 ? format.height + format.height / 2 : format.height;
            const std::size_t line = image.stride();
            for (int y = 0; y < rows; ++y) {
                const std::size_t offset = static_cast<std::size_t>(y) * bytes_per_line_;
                std::uint8_t* dst = image.data() + static_cast<std::size_t>(y) * line;
                if (offset + line <= used) {
                    std::memcpy(dst, src + offset, line);
                } else {
                    const std::size_t have = offset < used ? used - offset : 0;
                    if (have > 0) std::memcpy(dst, src + offset, have);
                    std::memset(dst + have, 0, line - have);
                }
            }
        }
        FrameMetadata& meta = frame->meta;
        meta.sequence = buf.sequence;
        meta.arrival_ns = arrival;
        const std::uint32_t ts_type = buf.flags & V4L2_BUF_FLAG_TIMESTAMP_MASK;
        if (ts_type == V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC) {
            meta.timestamp_ns = static_cast<std::int64_t>(buf.timestamp.tv_sec) * 1'000'000'000 +
                                static_cast<std::int64_t>(buf.timestamp.tv_usec) * 1000;
            meta.timestamp_source = (buf.flags & V4L2_BUF_FLAG_TSTAMP_SRC_MASK) == V4L2_BUF_FLAG_TSTAMP_SRC_SOE
                                        ? TimestampSource::kSensor
                                        : TimestampSource::kDriver;
        } else {
            // TIMESTAMP_UNKNOWN (no time base) or TIMESTAMP_COPY (output-to-capture copies): ours.
            meta.timestamp_ns = arrival;
            meta.timestamp_source = TimestampSource::kHost;
        }
        if (auto_exposure_on_.load(std::memory_order_relaxed) && options_.ae_refresh_frames > 0 &&
            ++frames_since_refresh_ >= static_cast<std::uint32_t>(options_.ae_refresh_frames)) {
            frames_since_refresh_ = 0;
            refreshExposure();
        }
        meta.exposure_us = exposure_us_.load(std::memory_order_relaxed);
        meta.analog_gain = analog_gain_.load(std::memory_order_relaxed);
        meta.status = status;
    }
    // Give the buffer back to the driver at once; the pixels live in the pool slot now.
    v4l2_buffer requeue = captureBuffer(buf.index);
    if (xioctl(system_, fd_, VIDIOC_QBUF, &requeue) < 0 && errno != ENODEV) {
        // ENODEV shows up at the next poll/DQBUF as the disconnect it is.
        emitEvent(CameraEvent{CameraEvent::Type::kDeviceError,
                              Error{ErrorCode::kDevice, id() + ": VIDIOC_QBUF failed: " + errnoText(errno)}});
    }
    if (frame) emitFrame(std::move(frame));
}

const V4l2Camera::DeviceControl* V4l2Camera::control(Control c) const noexcept {
    switch (c) {
        case Control::kExposureUs: return exposure_.present ? &exposure_ : nullptr;
        case Control::kAnalogGain: return gain_.present ? &gain_ : nullptr;
        case Control::kAutoExposure: return exposure_auto_.present ? &exposure_auto_ : nullptr;
        case Control::kAutoWhiteBalance: return awb_.present ? &awb_ : nullptr;
        case Control::kFrameRate: return nullptr;
    }
    return nullptr;
}

Result<std::int32_t> V4l2Camera::readControl(const DeviceControl& c) const {
    v4l2_control ctrl{c.id, 0};
    if (xioctl(system_, fd_, VIDIOC_G_CTRL, &ctrl) < 0) {
        return fail(ErrorCode::kDevice, id() + ": VIDIOC_G_CTRL of control 0x" +
                                            [&] { std::ostringstream s; s << std::hex << c.id; return s.str(); }() +
                                            " failed: " + errnoText(errno));
    }
    return ctrl.value;
}

Result<void> V4l2Camera::writeControl(const DeviceControl& c, std::int32_t value) {
    v4l2_control ctrl{c.id, value};
    if (xioctl(system_, fd_, VIDIOC_S_CTRL, &ctrl) < 0) {
        const int error = errno;
        std::ostringstream s;
        s << id() << ": VIDIOC_S_CTRL of control 0x" << std::hex << c.id << std::dec << " to " << value
          << " failed: " << errnoText(error);
        return fail(error == ERANGE || error == EINVAL ? ErrorCode::kUsage : ErrorCode::kDevice, s.str());
    }
    return {};
}

std::vector<ControlInfo> V4l2Camera::doControls() const {
    std::vector<ControlInfo> out;
    if (exposure_.present) {
        out.push_back({Control::kExposureUs, 100.0 * exposure_.min, 100.0 * exposure_.max, 100.0 * exposure_.step,
                       100.0 * exposure_.default_value});
    }
    if (gain_.present) {
        out.push_back({Control::kAnalogGain, double(gain_.min), double(gain_.max), double(gain_.step), double(gain_.default_value)});
    }
    if (exposure_auto_.present) {
        out.push_back({Control::kAutoExposure, 0, 1, 1, exposure_auto_.default_value != V4L2_EXPOSURE_MANUAL ? 1.0 : 0.0});
    }
    if (awb_.present) out.push_back({Control::kAutoWhiteBalance, 0, 1, 1, double(awb_.default_value != 0)});
    if (timeperframe_) {
        const auto& rates = activeFormat().frame_rates;
        if (!rates.empty()) {
            const auto [lo, hi] = std::minmax_element(rates.begin(), rates.end());
            out.push_back({Control::kFrameRate, *lo, *hi, 0, *hi});
        }
    }
    return out;
}

Result<void> V4l2Camera::doSetControl(Control which, double value) {
    const std::string name(controlName(which));
    if (which == Control::kFrameRate) {
        if (!timeperframe_) {
            return fail(ErrorCode::kUnsupported, id() + ": control fps is not supported (configure first; the driver "
                                                        "must report V4L2_CAP_TIMEPERFRAME)");
        }
        if (value <= 0) return fail(ErrorCode::kUsage, id() + ": fps must be > 0");
        v4l2_streamparm set{};
        set.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
        set.parm.capture.timeperframe.numerator = 1000;
        set.parm.capture.timeperframe.denominator = static_cast<std::uint32_t>(std::lround(value * 1000.0));
        if (xioctl(system_, fd_, VIDIOC_S_PARM, &set) < 0) return fail(callError("VIDIOC_S_PARM", errno));
        return {};
    }
    const DeviceControl* c = control(which);
    if (c == nullptr) {
        return fail(ErrorCode::kUnsupported, id() + ": control " + name + " is not supported by the device");
    }
    std::int32_t raw = 0;
    switch (which) {
        case Control::kExposureUs: raw = static_cast<std::int32_t>(std::lround(value / 100.0)); break;
        case Control::kAnalogGain: raw = static_cast<std::int32_t>(std::lround(value)); break;
        case Control::kAutoExposure:
            // On: aperture priority (auto exposure time, fixed iris) when the menu has it, else auto.
            raw = value != 0 ? (c->max >= V4L2_EXPOSURE_APERTURE_PRIORITY ? V4L2_EXPOSURE_APERTURE_PRIORITY : V4L2_EXPOSURE_AUTO)
                             : V4L2_EXPOSURE_MANUAL;
            break;
        case Control::kAutoWhiteBalance: raw = value != 0 ? 1 : 0; break;
        case Control::kFrameRate: break;
    }
    if (raw < c->min || raw > c->max) {
        std::ostringstream s;
        s << id() << ": " << name << " " << value << " is out of the device's range";
        if (which == Control::kExposureUs) {
            s << " [" << 100.0 * c->min << ", " << 100.0 * c->max << "]";
        } else {
            s << " [" << c->min << ", " << c->max << "]";
        }
        return fail(ErrorCode::kUsage, s.str());
    }
    CL_TRY_VOID(writeControl(*c, raw));
    // Keep the per-frame metadata cache current (read back: the driver may round).
    CL_TRY(const std::int32_t now, readControl(*c));
    if (which == Control::kExposureUs) exposure_us_ = 100.0 * now;
    if (which == Control::kAnalogGain) analog_gain_ = now;
    if (which == Control::kAutoExposure) auto_exposure_on_ = now != V4L2_EXPOSURE_MANUAL;
    return {};
}

// The gamma control (UVC: gamma x 100) has no absolute meaning across devices: at its default the
// webcam's ISP applies its own curve, which is sRGB's in practice; moved away from the default,
// the encoding exponent is sRGB's 2.2 scaled by value / default (a user who turned gamma from 100
// to 150 made the curve 1.5x as steep). A device without the control: sRGB, the webcam default.
// `--response` overrides either.
std::string V4l2Camera::doResponseSpec() const {
    if (!gamma_.present) return "srgb";
    auto value = readControl(gamma_);
    if (!value || *value == gamma_.default_value || gamma_.default_value <= 0 || *value <= 0) return "srgb";
    const double g = std::clamp(2.2 * static_cast<double>(*value) / static_cast<double>(gamma_.default_value), 0.2, 5.0);
    char spec[32];
    std::snprintf(spec, sizeof spec, "gamma:%.4g", g);
    return spec;
}

Result<double> V4l2Camera::doGetControl(Control which) const {
    if (which == Control::kFrameRate) {
        v4l2_streamparm parm{};
        parm.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
        if (xioctl(system_, fd_, VIDIOC_G_PARM, &parm) < 0) return fail(callError("VIDIOC_G_PARM", errno));
        const double fps = fpsOf(parm.parm.capture.timeperframe);
        if (fps <= 0) return fail(ErrorCode::kUnsupported, id() + ": the driver reports no frame rate");
        return fps;
    }
    const DeviceControl* c = control(which);
    if (c == nullptr) {
        return fail(ErrorCode::kUnsupported, id() + ": control " + std::string(controlName(which)) + " is not supported by the device");
    }
    CL_TRY(const std::int32_t raw, readControl(*c));
    switch (which) {
        case Control::kExposureUs: return 100.0 * raw;
        case Control::kAnalogGain: return double(raw);
        case Control::kAutoExposure: return raw != V4L2_EXPOSURE_MANUAL ? 1.0 : 0.0;
        case Control::kAutoWhiteBalance: return raw != 0 ? 1.0 : 0.0;
        case Control::kFrameRate: break;
    }
    return fail(ErrorCode::kInternal, id() + ": unreachable control");
}

std::vector<CameraInfo> enumerateCameras(System& system, int max_index) {
    std::vector<CameraInfo> out;
    for (int i = 0; i < max_index; ++i) {
        const std::string path = "/dev/video" + std::to_string(i);
        auto camera = V4l2Camera::open(system, path);
        if (!camera) continue;  // absent, not a capture node, or not ours to open
        CameraInfo info;
        info.uri = (*camera)->id();
        info.name = (*camera)->card();
        info.backend = "v4l2";
        info.formats = (*camera)->formats();
        out.push_back(std::move(info));
    }
    return out;
}

}  // namespace commonlight::hal::v4l2

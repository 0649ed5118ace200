#include "mocks/fake_v4l2_device.h"

#ifdef COMMONLIGHT_HAVE_V4L2

#include <sys/eventfd.h>
#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <ctime>

namespace commonlight::mocks {

namespace {

constexpr off_t kOffsetStep = 0x10000;  // buffer i is mapped at offset i * kOffsetStep

std::uint32_t bitsPerPixel(std::uint32_t fourcc) {
    switch (fourcc) {
        case V4L2_PIX_FMT_YUYV: return 16;
        case V4L2_PIX_FMT_NV12:
        case V4L2_PIX_FMT_GREY: return 8;
        default: return 0;  // compressed
    }
}

int failWith(int error) {
    errno = error;
    return -1;
}

void copyString(std::uint8_t* dst, std::size_t size, const std::string& src) {
    std::memset(dst, 0, size);
    std::memcpy(dst, src.data(), std::min(size - 1, src.size()));
}

}  // namespace

FakeV4l2Config FakeV4l2Config::webcam() {
    FakeV4l2Config c;
    c.formats = {
        {V4L2_PIX_FMT_YUYV, {{640, 480, 0, 0, 0, 0, {30, 15}}, {320, 240, 0, 0, 0, 0, {30}}}},
        {V4L2_PIX_FMT_MJPEG, {{1280, 720, 0, 0, 0, 0, {30}}, {640, 480, 0, 0, 0, 0, {30}}}},
        {V4L2_PIX_FMT_NV12, {{640, 480, 0, 0, 0, 0, {30}}}},
        {V4L2_PIX_FMT_GREY, {{640, 480, 0, 0, 0, 0, {30}}}},
    };
    c.controls = {
        {V4L2_CID_EXPOSURE_ABSOLUTE, 1, 5000, 1, 156, 156},
        {V4L2_CID_EXPOSURE_AUTO, 0, 3, 1, V4L2_EXPOSURE_APERTURE_PRIORITY, V4L2_EXPOSURE_APERTURE_PRIORITY},
        {V4L2_CID_GAIN, 0, 255, 1, 32, 32},
        {V4L2_CID_AUTO_WHITE_BALANCE, 0, 1, 1, 1, 1},
    };
    return c;
}

FakeV4l2Device::FakeV4l2Device(FakeV4l2Config config) : config_(std::move(config)) {
    event_fd_ = ::eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK | EFD_SEMAPHORE);
    if (event_fd_ < 0) std::abort();  // the test cannot run without it
    // Power-on format: the first size of the first format.
    format_.pixelformat = config_.formats.empty() ? V4L2_PIX_FMT_YUYV : config_.formats[0].fourcc;
    if (!config_.formats.empty() && !config_.formats[0].sizes.empty()) {
        format_.width = config_.formats[0].sizes[0].width;
        format_.height = config_.formats[0].sizes[0].height;
    } else {
        format_.width = 640;
        format_.height = 480;
    }
    setFormat(format_);
}

FakeV4l2Device::~FakeV4l2Device() { ::close(event_fd_); }

const FakeV4l2Format* FakeV4l2Device::findFormat(std::uint32_t fourcc) const {
    for (const auto& f : config_.formats) {
        if (f.fourcc == fourcc) return &f;
    }
    return nullptr;
}

FakeV4l2Control* FakeV4l2Device::findControl(std::uint32_t id) {
    for (auto& c : config_.controls) {
        if (c.id == id) return &c;
    }
    return nullptr;
}

void FakeV4l2Device::setFormat(v4l2_pix_format& pix) {
    // Like a driver: an unknown format becomes the first one, a size becomes the nearest offered.
    const FakeV4l2Format* format = findFormat(pix.pixelformat);
    if (format == nullptr && !config_.formats.empty()) format = &config_.formats[0];
    if (format != nullptr) {
        pix.pixelformat = format->fourcc;
        std::uint32_t best_w = pix.width, best_h = pix.height;
        long best = -1;
        for (const auto& s : format->sizes) {
            std::uint32_t w = s.width, h = s.height;
            if (s.step_width != 0) {
                w = std::clamp(pix.width, s.min_width, s.width);
                h = std::clamp(pix.height, s.min_height, s.height);
                w = s.min_width + (w - s.min_width) / s.step_width * s.step_width;
                h = s.min_height + (h - s.min_height) / std::max(1u, s.step_height) * std::max(1u, s.step_height);
            }
            const long d = std::labs(long(w) - long(pix.width)) + std::labs(long(h) - long(pix.height));
            if (best < 0 || d < best) {
                best = d;
                best_w = w;
                best_h = h;
            }
        }
        pix.width = best_w;
        pix.height = best_h;
        if (config_.max_set_width != 0 && pix.width > config_.max_set_width) {
            // Fall back to the largest listed size that fits.
            std::uint32_t w = 0, h = 0;
            for (const auto& s : format->sizes) {
                const std::uint32_t sw = s.step_width != 0 ? std::min(s.width, config_.max_set_width) : s.width;
                if (sw <= config_.max_set_width && sw > w) {
                    w = sw;
                    h = s.height;
                }
            }
            if (w != 0) {
                pix.width = w;
                pix.height = h;
            }
        }
    }
    pix.field = V4L2_FIELD_NONE;
    const std::uint32_t bpp = bitsPerPixel(pix.pixelformat);
    if (bpp != 0) {
        pix.bytesperline = pix.width * bpp / 8 + config_.line_padding;
        pix.sizeimage = pix.bytesperline * (pix.pixelformat == V4L2_PIX_FMT_NV12 ? pix.height * 3 / 2 : pix.height);
    } else {
        pix.bytesperline = 0;
        pix.sizeimage = pix.width * pix.height;  // room for a JPEG of about 8 bits per pixel
    }
    pix.colorspace = V4L2_COLORSPACE_SRGB;
}

void FakeV4l2Device::signal() {
    const std::uint64_t one = 1;
    [[maybe_unused]] const ssize_t n = ::write(event_fd_, &one, sizeof one);
}

void FakeV4l2Device::unsignal() {
    std::uint64_t value = 0;
    [[maybe_unused]] const ssize_t n = ::read(event_fd_, &value, sizeof value);
}

void FakeV4l2Device::fillBufferInfo(std::uint32_t index, v4l2_buffer& out) const {
    const Buffer& b = buffers_[index];
    out = b.info;
    out.index = index;
    out.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    out.memory = V4L2_MEMORY_MMAP;
    out.length = static_cast<std::uint32_t>(b.memory.size());
    out.m.offset = static_cast<std::uint32_t>(index * kOffsetStep);
    out.flags &= ~(V4L2_BUF_FLAG_QUEUED | V4L2_BUF_FLAG_DONE | V4L2_BUF_FLAG_MAPPED);
    if (b.mapped > 0) out.flags |= V4L2_BUF_FLAG_MAPPED;
    if (b.state == BufferState::kQueued) out.flags |= V4L2_BUF_FLAG_QUEUED;
    if (b.state == BufferState::kDone) out.flags |= V4L2_BUF_FLAG_DONE;
}

int FakeV4l2Device::ioctl(unsigned long request, void* arg) {
    std::unique_lock lock(mutex_);
    if (disconnected_) return failWith(ENODEV);
    switch (request) {
        case VIDIOC_QUERYCAP: {
            auto* cap = static_cast<v4l2_capability*>(arg);
            *cap = {};
            copyString(cap->driver, sizeof cap->driver, config_.driver);
            copyString(cap->card, sizeof cap->card, config_.card);
            copyString(cap->bus_info, sizeof cap->bus_info, "platform:fake");
            cap->version = 0x060100;
            cap->capabilities = config_.capabilities | V4L2_CAP_DEVICE_CAPS;
            cap->device_caps = config_.capabilities;
            return 0;
        }
        case VIDIOC_ENUM_FMT: {
            auto* d = static_cast<v4l2_fmtdesc*>(arg);
            if (d->type != V4L2_BUF_TYPE_VIDEO_CAPTURE || d->index >= config_.formats.size()) return failWith(EINVAL);
            const auto& f = config_.formats[d->index];
            d->pixelformat = f.fourcc;
            d->flags = bitsPerPixel(f.fourcc) == 0 ? V4L2_FMT_FLAG_COMPRESSED : 0;
            copyString(d->description, sizeof d->description, "fake format");
            return 0;
        }
        case VIDIOC_ENUM_FRAMESIZES: {
            auto* s = static_cast<v4l2_frmsizeenum*>(arg);
            const FakeV4l2Format* f = findFormat(s->pixel_format);
            if (f == nullptr || s->index >= f->sizes.size()) return failWith(EINVAL);
            const auto& size = f->sizes[s->index];
            if (size.step_width != 0) {
                if (s->index != 0) return failWith(EINVAL);
                s->type = V4L2_FRMSIZE_TYPE_STEPWISE;
                s->stepwise = {size.min_width, size.width, size.step_width, size.min_height, size.height, size.step_height};
            } else {
                s->type = V4L2_FRMSIZE_TYPE_DISCRETE;
                s->discrete = {size.width, size.height};
            }
            return 0;
        }
        case VIDIOC_ENUM_FRAMEINTERVALS: {
            auto* iv = static_cast<v4l2_frmivalenum*>(arg);
            const FakeV4l2Format* f = findFormat(iv->pixel_format);
            if (f == nullptr) return failWith(EINVAL);
            for (const auto& size : f->sizes) {
                const bool match = size.step_width == 0
                                       ? (size.width == iv->width && size.height == iv->height)
                                       : (iv->width >= size.min_width && iv->width <= size.width &&
                                          iv->height >= size.min_height && iv->height <= size.height);
                if (!match) continue;
                if (iv->index >= size.fps.size()) return failWith(EINVAL);
                iv->type = V4L2_FRMIVAL_TYPE_DISCRETE;
                iv->discrete = {1, size.fps[iv->index]};
                return 0;
            }
            return failWith(EINVAL);
        }
        case VIDIOC_G_FMT:
        case VIDIOC_S_FMT:
        case VIDIOC_TRY_FMT: {
            auto* f = static_cast<v4l2_format*>(arg);
            if (f->type != V4L2_BUF_TYPE_VIDEO_CAPTURE) return failWith(EINVAL);
            if (request == VIDIOC_G_FMT) {
                f->fmt.pix = format_;
                return 0;
            }
            if (request == VIDIOC_S_FMT && !buffers_.empty()) return failWith(EBUSY);
            setFormat(f->fmt.pix);
            if (request == VIDIOC_S_FMT) format_ = f->fmt.pix;
            return 0;
        }
        case VIDIOC_G_PARM:
        case VIDIOC_S_PARM: {
            auto* p = static_cast<v4l2_streamparm*>(arg);
            if (p->type != V4L2_BUF_TYPE_VIDEO_CAPTURE) return failWith(EINVAL);
            if (request == VIDIOC_S_PARM && config_.timeperframe && p->parm.capture.timeperframe.numerator != 0 &&
                p->parm.capture.timeperframe.denominator != 0) {
                const double wanted = double(p->parm.capture.timeperframe.denominator) / p->parm.capture.timeperframe.numerator;
                const FakeV4l2Format* f = findFormat(format_.pixelformat);
                std::uint32_t best = interval_.denominator;
                double best_d = -1;
                for (const auto& size : f ? f->sizes : std::vector<FakeV4l2Size>{}) {
                    if (size.step_width == 0 && (size.width != format_.width || size.height != format_.height)) continue;
                    for (std::uint32_t fps : size.fps) {
                        const double d = std::abs(fps - wanted);
                        if (best_d < 0 || d < best_d) {
                            best_d = d;
                            best = fps;
                        }
                    }
                }
                interval_ = {1, best};
            }
            p->parm.capture = {};
            p->parm.capture.capability = config_.timeperframe ? V4L2_CAP_TIMEPERFRAME : 0;
            p->parm.capture.timeperframe = interval_;
            return 0;
        }
        case VIDIOC_REQBUFS: {
            auto* r = static_cast<v4l2_requestbuffers*>(arg);
            if (r->type != V4L2_BUF_TYPE_VIDEO_CAPTURE || r->memory != V4L2_MEMORY_MMAP) return failWith(EINVAL);
            if (streaming_) return failWith(EBUSY);
            if (std::any_of(buffers_.begin(), buffers_.end(), [](const Buffer& b) { return b.mapped > 0; })) {
                return failWith(EBUSY);
            }
            buffers_.clear();
            queued_.clear();
            done_.clear();
            const std::uint32_t count = std::min(r->count, config_.max_buffers);
            buffers_.resize(count);
            for (auto& b : buffers_) b.memory.assign(format_.sizeimage, 0);
            r->count = count;
            r->capabilities = V4L2_BUF_CAP_SUPPORTS_MMAP;
            changed_.notify_all();
            return 0;
        }
        case VIDIOC_QUERYBUF: {
            auto* b = static_cast<v4l2_buffer*>(arg);
            if (b->type != V4L2_BUF_TYPE_VIDEO_CAPTURE || b->index >= buffers_.size()) return failWith(EINVAL);
            fillBufferInfo(b->index, *b);
            return 0;
        }
        case VIDIOC_QBUF: {
            auto* b = static_cast<v4l2_buffer*>(arg);
            if (b->type != V4L2_BUF_TYPE_VIDEO_CAPTURE || b->memory != V4L2_MEMORY_MMAP || b->index >= buffers_.size()) {
                return failWith(EINVAL);
            }
            Buffer& buffer = buffers_[b->index];
            if (buffer.state != BufferState::kDequeued) return failWith(EINVAL);  // queued or done already
            buffer.state = BufferState::kQueued;
            queued_.push_back(b->index);
            fillBufferInfo(b->index, *b);
            changed_.notify_all();
            return 0;
        }
        case VIDIOC_DQBUF: {
            auto* b = static_cast<v4l2_buffer*>(arg);
            if (b->type != V4L2_BUF_TYPE_VIDEO_CAPTURE || b->memory != V4L2_MEMORY_MMAP || !streaming_) {
                return failWith(EINVAL);
            }
            if (done_.empty()) {
                ++eagain_;
                // No buffer done: a spurious wake-up is spent (the readiness counter matches done_).
                std::uint64_t drained = 0;
                while (::read(event_fd_, &drained, sizeof drained) > 0) {
                }
                return failWith(EAGAIN);
            }
            const std::uint32_t index = done_.front();
            done_.erase(done_.begin());
            buffers_[index].state = BufferState::kDequeued;
            unsignal();
            fillBufferInfo(index, *b);
            changed_.notify_all();
            return 0;
        }
        case VIDIOC_STREAMON:
        case VIDIOC_STREAMOFF: {
            const int type = *static_cast<int*>(arg);
            if (type != V4L2_BUF_TYPE_VIDEO_CAPTURE) return failWith(EINVAL);
            if (request == VIDIOC_STREAMON) {
                if (buffers_.empty()) return failWith(EINVAL);
                streaming_ = true;
            } else {
                streaming_ = false;
                for (auto& b : buffers_) b.state = BufferState::kDequeued;
                for (std::size_t i = 0; i < done_.size(); ++i) unsignal();
                queued_.clear();
                done_.clear();
            }
            changed_.notify_all();
            return 0;
        }
        case VIDIOC_QUERYCTRL: {
            auto* q = static_cast<v4l2_queryctrl*>(arg);
            const FakeV4l2Control* c = findControl(q->id);
            if (c == nullptr) return failWith(EINVAL);
            const std::uint32_t id = q->id;
            *q = {};
            q->id = id;
            q->type = (id == V4L2_CID_EXPOSURE_AUTO) ? V4L2_CTRL_TYPE_MENU
                      : (c->min == 0 && c->max == 1) ? V4L2_CTRL_TYPE_BOOLEAN
                                                     : V4L2_CTRL_TYPE_INTEGER;
            copyString(q->name, sizeof q->name, "fake control");
            q->minimum = c->min;
            q->maximum = c->max;
            q->step = c->step;
            q->default_value = c->default_value;
            return 0;
        }
        case VIDIOC_G_CTRL:
        case VIDIOC_S_CTRL: {
            auto* ctrl = static_cast<v4l2_control*>(arg);
            FakeV4l2Control* c = findControl(ctrl->id);
            if (c == nullptr) return failWith(EINVAL);
            if (request == VIDIOC_G_CTRL) {
                ctrl->value = c->value;
                return 0;
            }
            if (ctrl->value < c->min || ctrl->value > c->max) return failWith(ERANGE);
            c->value = ctrl->value;
            return 0;
        }
        default: return failWith(ENOTTY);
    }
}

void* FakeV4l2Device::mmap(std::size_t length, off_t offset) {
    std::lock_guard lock(mutex_);
    if (disconnected_) {
        errno = ENODEV;
        return MAP_FAILED;
    }
    const auto index = static_cast<std::size_t>(offset / kOffsetStep);
    if (offset % kOffsetStep != 0 || index >= buffers_.size() || length == 0 || length > buffers_[index].memory.size()) {
        errno = EINVAL;
        return MAP_FAILED;
    }
    ++buffers_[index].mapped;
    return buffers_[index].memory.data();
}

int FakeV4l2Device::munmap(void* addr, std::size_t) {
    std::lock_guard lock(mutex_);
    for (auto& b : buffers_) {
        if (b.mapped > 0 && b.memory.data() == addr) {
            --b.mapped;
            return 0;
        }
    }
    return failWith(EINVAL);
}

std::optional<std::uint32_t> FakeV4l2Device::produceFrame(const FakeV4l2Frame& frame) {
    std::lock_guard lock(mutex_);
    if (!streaming_ || disconnected_) return std::nullopt;
    const std::uint32_t sequence = sequence_++;
    if (queued_.empty()) {
        ++lost_;
        return std::nullopt;
    }
    const std::uint32_t index = queued_.front();
    queued_.erase(queued_.begin());
    Buffer& b = buffers_[index];
    std::size_t used = b.memory.size();
    if (frame.payload) {
        used = std::min(frame.payload->size(), b.memory.size());
        std::memcpy(b.memory.data(), frame.payload->data(), used);
    } else {
        for (std::size_t i = 0; i < b.memory.size(); ++i) b.memory[i] = patternByte(sequence, i);
    }
    if (frame.bytesused) used = std::min<std::size_t>(*frame.bytesused, b.memory.size());
    b.info = {};
    b.info.bytesused = static_cast<std::uint32_t>(used);
    b.info.sequence = sequence;
    b.info.field = V4L2_FIELD_NONE;
    b.info.flags = config_.timestamp_flags | frame.flags;
    if (frame.timestamp) {
        b.info.timestamp = *frame.timestamp;
    } else {
        timespec now{};
        clock_gettime(CLOCK_MONOTONIC, &now);
        b.info.timestamp.tv_sec = now.tv_sec;
        b.info.timestamp.tv_usec = now.tv_nsec / 1000;
    }
    b.state = BufferState::kDone;
    done_.push_back(index);
    signal();
    changed_.notify_all();
    return sequence;
}

void FakeV4l2Device::spuriousWakeup() {
    std::lock_guard lock(mutex_);
    signal();
}

void FakeV4l2Device::skipSequence(std::uint32_t n) {
    std::lock_guard lock(mutex_);
    sequence_ += n;
    lost_ += n;
}

void FakeV4l2Device::disconnect() {
    std::lock_guard lock(mutex_);
    disconnected_ = true;
    signal();  // wake every poll; FakeV4l2System::poll turns it into POLLERR
    changed_.notify_all();
}

bool FakeV4l2Device::waitAllQueued(std::chrono::milliseconds timeout) {
    std::unique_lock lock(mutex_);
    return changed_.wait_for(lock, timeout, [&] {
        return !buffers_.empty() && queued_.size() == buffers_.size();
    });
}

bool FakeV4l2Device::waitStreaming(std::chrono::milliseconds timeout) {
    std::unique_lock lock(mutex_);
    return changed_.wait_for(lock, timeout, [&] { return streaming_; });
}

void FakeV4l2Device::setControlValue(std::uint32_t id, std::int32_t value) {
    std::lock_guard lock(mutex_);
    if (FakeV4l2Control* c = findControl(id)) c->value = value;
}

std::int32_t FakeV4l2Device::controlValue(std::uint32_t id) const {
    std::lock_guard lock(mutex_);
    for (const auto& c : config_.controls) {
        if (c.id == id) return c.value;
    }
    return 0;
}

bool FakeV4l2Device::streaming() const {
    std::lock_guard lock(mutex_);
    return streaming_;
}
std::size_t FakeV4l2Device::bufferCount() const {
    std::lock_guard lock(mutex_);
    return buffers_.size();
}
std::size_t FakeV4l2Device::mappedCount() const {
    std::lock_guard lock(mutex_);
    return static_cast<std::size_t>(std::count_if(buffers_.begin(), buffers_.end(), [](const Buffer& b) { return b.mapped > 0; }));
}
std::uint64_t FakeV4l2Device::framesLost() const {
    std::lock_guard lock(mutex_);
    return lost_;
}
std::uint32_t FakeV4l2Device::currentFourcc() const {
    std::lock_guard lock(mutex_);
    return format_.pixelformat;
}
std::uint32_t FakeV4l2Device::currentWidth() const {
    std::lock_guard lock(mutex_);
    return format_.width;
}
std::uint32_t FakeV4l2Device::currentHeight() const {
    std::lock_guard lock(mutex_);
    return format_.height;
}
std::uint32_t FakeV4l2Device::bytesPerLine() const {
    std::lock_guard lock(mutex_);
    return format_.bytesperline;
}
double FakeV4l2Device::currentFps() const {
    std::lock_guard lock(mutex_);
    return double(interval_.denominator) / interval_.numerator;
}
int FakeV4l2Device::dqbufEagainCount() const {
    std::lock_guard lock(mutex_);
    return eagain_;
}
bool FakeV4l2Device::disconnected() const {
    std::lock_guard lock(mutex_);
    return disconnected_;
}

// --- FakeV4l2System ---

FakeV4l2System::~FakeV4l2System() {
    for (const auto& [fd, device] : fds_) ::close(fd);
}

FakeV4l2Device& FakeV4l2System::add(const std::string& path, FakeV4l2Config config) {
    std::lock_guard lock(mutex_);
    auto& slot = devices_[path];
    slot = std::make_unique<FakeV4l2Device>(std::move(config));
    return *slot;
}

FakeV4l2Device* FakeV4l2System::device(const std::string& path) {
    std::lock_guard lock(mutex_);
    auto it = devices_.find(path);
    return it == devices_.end() ? nullptr : it->second.get();
}

int FakeV4l2System::openCount() const {
    std::lock_guard lock(mutex_);
    return static_cast<int>(fds_.size());
}

FakeV4l2Device* FakeV4l2System::byFd(int fd) const {
    std::lock_guard lock(mutex_);
    auto it = fds_.find(fd);
    return it == fds_.end() ? nullptr : it->second;
}

int FakeV4l2System::open(const char* path, int) {
    std::lock_guard lock(mutex_);
    auto it = devices_.find(path);
    if (it == devices_.end()) return failWith(ENOENT);
    if (it->second->openErrno() != 0) return failWith(it->second->openErrno());
    if (it->second->disconnected()) return failWith(ENODEV);
    const int fd = ::dup(it->second->pollFd());
    if (fd < 0) return -1;
    fds_[fd] = it->second.get();
    return fd;
}

int FakeV4l2System::close(int fd) {
    {
        std::lock_guard lock(mutex_);
        if (fds_.erase(fd) == 0) return failWith(EBADF);
    }
    return ::close(fd);
}

int FakeV4l2System::ioctl(int fd, unsigned long request, void* arg) {
    FakeV4l2Device* d = byFd(fd);
    if (d == nullptr) return failWith(EBADF);
    return d->ioctl(request, arg);
}

void* FakeV4l2System::mmap(void*, std::size_t length, int, int, int fd, off_t offset) {
    FakeV4l2Device* d = byFd(fd);
    if (d == nullptr) {
        errno = EBADF;
        return MAP_FAILED;
    }
    return d->mmap(length, offset);
}

int FakeV4l2System::munmap(void* addr, std::size_t length) {
    std::vector<FakeV4l2Device*> all;
    {
        std::lock_guard lock(mutex_);
        for (const auto& [path, device] : devices_) all.push_back(device.get());
    }
    for (FakeV4l2Device* d : all) {
        if (d->munmap(addr, length) == 0) return 0;
    }
    return failWith(EINVAL);
}

int FakeV4l2System::poll(pollfd* fds, nfds_t count, int timeout_ms) {
    const int ready = ::poll(fds, count, timeout_ms);
    if (ready < 0) return ready;
    int n = 0;
    for (nfds_t i = 0; i < count; ++i) {
        FakeV4l2Device* d = byFd(fds[i].fd);
        if (d != nullptr && d->disconnected()) fds[i].revents = POLLERR | POLLHUP;
        if (fds[i].revents != 0) ++n;
    }
    return n;
}

}  // namespace commonlight::mocks

#endif  // COMMONLIGHT_HAVE_V4L2

#include "capture/frame_pool.h"

#include <algorithm>
#include <cassert>
#include <limits>

namespace commonlight::capture {

std::size_t mjpegSlotBytes(int width, int height) noexcept {
    constexpr std::size_t kMinBytes = 64 * 1024;
    if (width <= 0 || height <= 0) return kMinBytes;
    return std::max(kMinBytes, static_cast<std::size_t>(width) * static_cast<std::size_t>(height) * 3);
}

FramePool::FramePool(std::size_t slots, PixelFormat format, int width, int height, std::size_t mjpeg_bytes)
    : format_(format), width_(width), height_(height) {
    assert(slots > 0 && slots <= std::numeric_limits<std::uint32_t>::max());
    assert(format != PixelFormat::kInvalid && width >= 0 && height >= 0);
    slots_.resize(slots);
    free_.reserve(slots);
    for (std::size_t i = 0; i < slots; ++i) {
        Frame& frame = slots_[i];
        if (isCompressed(format)) {
            frame.image.reserve(mjpeg_bytes > 0 ? mjpeg_bytes : mjpegSlotBytes(width, height));
        } else {
            frame.image.reshape(format, width, height);
        }
        prepare(frame);
        // Pushed in reverse so that acquire() hands out slot 0 first.
        free_.push_back(static_cast<std::uint32_t>(slots - 1 - i));
    }
    slot_bytes_ = slots_.front().image.capacity();
}

FramePool::~FramePool() {
    assert(in_use_.load() == 0 && "FramePool destroyed while a FrameHandle still holds one of its slots");
}

void FramePool::prepare(Frame& frame) noexcept {
    frame.meta = FrameMetadata{};
    if (isCompressed(format_)) {
        frame.image.reshapeCompressed(width_, height_, 0);
    } else {
        frame.image.reshape(format_, width_, height_);  // within capacity: never allocates
    }
}

FrameHandle FramePool::acquire() noexcept {
    std::uint32_t index = 0;
    {
        std::lock_guard lock(mutex_);
        if (free_.empty()) {
            acquire_failures_.fetch_add(1, std::memory_order_relaxed);
            return FrameHandle();
        }
        index = free_.back();
        free_.pop_back();
        const std::size_t in_use = in_use_.fetch_add(1, std::memory_order_relaxed) + 1;
        if (in_use > peak_in_use_.load(std::memory_order_relaxed)) {
            peak_in_use_.store(in_use, std::memory_order_relaxed);
        }
    }
    // The slot is ours alone from here: reset it outside the lock.
    Frame& frame = slots_[index];
    prepare(frame);
    return FrameHandle(&frame, this);
}

void FramePool::recycle(Frame* frame) noexcept {
    assert(frame >= slots_.data() && frame < slots_.data() + slots_.size() && "frame is not from this pool");
    const auto index = static_cast<std::uint32_t>(frame - slots_.data());
    std::lock_guard lock(mutex_);
    assert(std::find(free_.begin(), free_.end(), index) == free_.end() && "slot recycled twice");
    free_.push_back(index);  // capacity reserved for every slot: never allocates
    in_use_.fetch_sub(1, std::memory_order_relaxed);
}

}  // namespace commonlight::capture

// FramePool: a fixed number of pre-allocated frame slots lent out as FrameHandles.
//
// Every slot's Image is allocated once, in the constructor, for one pixel format and size, so a
// stream never allocates per frame. acquire() never blocks: it returns an empty handle when all
// slots are out (the camera then counts the frame in framesWithoutSlot()). A handle gives its
// slot back when it is destroyed or reset, on whatever thread does that.
//
// Ownership: the pool owns the slots; a FrameHandle borrows one. The pool must outlive every
// handle it gave out: destroying it with a slot still lent is a contract violation (asserted in
// debug builds; in release builds the handle would dangle).
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <mutex>
#include <vector>

#include "core/frame.h"
#include "core/image.h"

namespace commonlight::capture {

// The byte capacity given to an MJPEG slot of width x height when the caller names none:
// 3 bytes per pixel (at least 64 KiB). UVC cameras announce at most the size of the same frame
// in YUYV (2 bytes per pixel) as their largest compressed frame, so this bound leaves room; a
// backend that gets a larger frame marks it kIncomplete rather than growing the slot.
std::size_t mjpegSlotBytes(int width, int height) noexcept;

class FramePool final : public FrameAllocator, public FrameRecycler {
public:
    // `slots` frames of `format` at width x height (packed stride). For MJPEG each slot reserves
    // `mjpeg_bytes` bytes (0: mjpegSlotBytes(width, height)) and is handed out with size 0.
    FramePool(std::size_t slots, PixelFormat format, int width, int height, std::size_t mjpeg_bytes = 0);
    // Asserts (debug) that every slot is back.
    ~FramePool();
    FramePool(const FramePool&) = delete;
    FramePool& operator=(const FramePool&) = delete;

    // Any thread. Lends a free slot with default metadata and the pool's format and size (an
    // uncompressed slot is reshaped within its capacity: no allocation). Empty handle when all
    // slots are out; never blocks beyond a short internal lock.
    FrameHandle acquire() noexcept override;

    std::size_t slotCount() const noexcept { return slots_.size(); }
    // Slots currently lent out.
    std::size_t inUse() const noexcept { return in_use_.load(std::memory_order_relaxed); }
    // The most slots ever lent out at once.
    std::size_t peakInUse() const noexcept { return peak_in_use_.load(std::memory_order_relaxed); }
    // acquire() calls that found no free slot.
    std::uint64_t acquireFailures() const noexcept { return acquire_failures_.load(std::memory_order_relaxed); }
    // Byte capacity of each slot's Image.
    std::size_t slotBytes() const noexcept { return slot_bytes_; }
    PixelFormat format() const noexcept { return format_; }
    int width() const noexcept { return width_; }
    int height() const noexcept { return height_; }

private:
    // Called by FrameHandle on the thread that drops it; takes a short internal lock.
    void recycle(Frame* frame) noexcept override;
    void prepare(Frame& frame) noexcept;

    PixelFormat format_;
    int width_;
    int height_;
    std::size_t slot_bytes_ = 0;
    std::vector<Frame> slots_;               // sized once in the constructor, never resized
    std::mutex mutex_;
    std::vector<std::uint32_t> free_;        // stack of free slot indices; capacity = slot count
    std::atomic<std::size_t> in_use_{0};
    std::atomic<std::size_t> peak_in_use_{0};
    std::atomic<std::uint64_t> acquire_failures_{0};
};

}  // namespace commonlight::capture

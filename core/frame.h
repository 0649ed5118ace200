// Frame = pixels + metadata, and the move-only FrameHandle that lends a pool slot to its holder.
//
// Frames live in slots owned by a frame pool (capture::FramePool). Whoever holds the FrameHandle
// may read and write the frame; destroying or resetting the handle gives the slot back, on the
// thread that destroys it. Nothing is allocated per frame.
#pragma once

#include <cstdint>
#include <string_view>
#include <utility>

#include "core/image.h"

namespace commonlight {

enum class FrameStatus : std::uint8_t {
    kOk,
    kCorrupt,     // the pixels could not be decoded or failed a check; do not use them
    kIncomplete,  // the device delivered fewer bytes than the format needs
};

enum class TimestampSource : std::uint8_t {
    kUnknown,
    kSensor,     // start of exposure as reported by the sensor, converted to CLOCK_MONOTONIC
    kDriver,     // driver's buffer timestamp (end of frame), CLOCK_MONOTONIC
    kHost,       // CLOCK_MONOTONIC when our process received the frame
    kRecording,  // the timestamp stored in a recorded sequence (its own epoch)
    kSimulated,  // the simulated camera's time
};

std::string_view frameStatusName(FrameStatus status) noexcept;
std::string_view timestampSourceName(TimestampSource source) noexcept;

struct FrameMetadata {
    std::uint64_t sequence = 0;     // device frame counter; gaps mean frames lost at the device
    std::int64_t timestamp_ns = 0;  // the frame's time, in the epoch given by timestamp_source
    TimestampSource timestamp_source = TimestampSource::kUnknown;
    std::int64_t arrival_ns = 0;    // CLOCK_MONOTONIC (or the injected clock) when the backend
                                    // handed the frame over; latency is measured from it
    double exposure_us = 0.0;       // 0 when unknown
    double analog_gain = 0.0;       // linear gain, 0 when unknown
    FrameStatus status = FrameStatus::kOk;
};

// The instant a frame's image stands for (docs/tracking.md, "Timestamps"): the middle of its
// exposure. A frame's timestamp_ns is the start of its exposure (as libcamera's SensorTimestamp
// and V4L2's start-of-exposure buffers stamp it): the image is the light gathered over
// [timestamp_ns, timestamp_ns + exposure], so a moving camera's image shows, to first order, the
// pose at its middle.
// - exposure unknown (0, negative, not finite): the timestamp itself (an instantaneous exposure);
// - `end_of_frame` (V4L2's end-of-frame buffer timestamps, kDriver; a host's arrival time, kHost):
//   the exposure ended at about the timestamp (the readout, unknown, is neglected), so its middle
//   is half an exposure before it.
std::int64_t midExposureNs(std::int64_t timestamp_ns, double exposure_us, bool end_of_frame = false) noexcept;
// The same from a frame's metadata: end_of_frame for kDriver and kHost timestamps.
std::int64_t midExposureNs(const FrameMetadata& meta) noexcept;

struct Frame {
    Image image;
    FrameMetadata meta;
};

class FrameHandle;

// Whoever owns frame slots. recycle() is called from the thread that drops the handle and must
// not block for long.
class FrameRecycler {
public:
    virtual void recycle(Frame* frame) noexcept = 0;

protected:
    ~FrameRecycler() = default;
};

// Hands out free slots; acquire() returns an empty handle when none is free (never blocks).
class FrameAllocator {
public:
    virtual FrameHandle acquire() noexcept = 0;

protected:
    ~FrameAllocator() = default;
};

// Move-only lease of one frame slot.
class FrameHandle {
public:
    FrameHandle() noexcept = default;
    FrameHandle(Frame* frame, FrameRecycler* owner) noexcept : frame_(frame), owner_(owner) {}
    FrameHandle(FrameHandle&& other) noexcept
        : frame_(std::exchange(other.frame_, nullptr)), owner_(std::exchange(other.owner_, nullptr)) {}
    FrameHandle& operator=(FrameHandle&& other) noexcept {
        if (this != &other) {
            reset();
            frame_ = std::exchange(other.frame_, nullptr);
            owner_ = std::exchange(other.owner_, nullptr);
        }
        return *this;
    }
    FrameHandle(const FrameHandle&) = delete;
    FrameHandle& operator=(const FrameHandle&) = delete;
    ~FrameHandle() { reset(); }

    // Gives the slot back now.
    void reset() noexcept {
        if (frame_ != nullptr && owner_ != nullptr) owner_->recycle(frame_);
        frame_ = nullptr;
        owner_ = nullptr;
    }

    explicit operator bool() const noexcept { return frame_ != nullptr; }
    Frame* get() const noexcept { return frame_; }
    Frame* operator->() const noexcept { return frame_; }
    Frame& operator*() const noexcept { return *frame_; }

private:
    Frame* frame_ = nullptr;
    FrameRecycler* owner_ = nullptr;
};

}  // namespace commonlight

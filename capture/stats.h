// Capture statistics: frame rates, jitter, where frames were lost, and hand-over latency.
//
// A CaptureStatsCollector is fed from two threads: onArrival() by the producer (the camera
// thread, lock-free atomics only) and onDelivery() by the consumer (the pipeline thread, a short
// uncontended lock). snapshot() may be called from any thread. Nothing allocates per frame: the
// latency samples live in a SampleReservoir allocated up front.
#pragma once

#include <atomic>
#include <cstdint>
#include <mutex>

#include "core/percentiles.h"
#include "core/frame.h"

namespace commonlight::capture {

// Frames that did not reach the consumer with usable pixels, by cause. The four counts are
// disjoint: each frame is counted at most once.
struct DropCounts {
    // Lost at the device: gaps in FrameMetadata::sequence between consecutive frames the camera
    // handed over, less the frames the backend discarded for want of a pool slot in the same
    // interval (a backend may have numbered those before it found no slot).
    std::uint64_t device = 0;
    // Discarded by the backend because every pool slot was out (Camera::framesWithoutSlot()).
    std::uint64_t no_slot = 0;
    // Replaced in the newest-wins mailbox before the consumer took them.
    std::uint64_t mailbox = 0;
    // Delivered with status kCorrupt or kIncomplete: the consumer got them, but not their pixels.
    std::uint64_t corrupt = 0;

    std::uint64_t total() const noexcept { return device + no_slot + mailbox + corrupt; }
};

struct CaptureStats {
    std::uint64_t frames_received = 0;   // frames the camera handed to the session
    std::uint64_t frames_delivered = 0;  // frames the consumer took (corrupt ones included)
    double fps = 0.0;        // delivered frames per second of frame time (FrameMetadata::timestamp_ns)
    double wall_fps = 0.0;   // delivered frames per second of the session clock (hand-over times)
    double jitter_ms = 0.0;  // population std dev of the intervals between delivered frames'
                             // timestamps; frames dropped in between widen an interval
    DropCounts drops;
    // Frames the camera made after the consumer stopped taking (replaced in the mailbox after its
    // last take, or put after the stream was closed): not lost by the user, so not in `drops`.
    std::uint64_t frames_discarded = 0;
    // FrameMetadata::arrival_ns to the hand-over to the consumer, in ms. Frames without an
    // arrival time (arrival_ns == 0) give no sample.
    Percentiles latency_ms;
};

class CaptureStatsCollector {
public:
    explicit CaptureStatsCollector(std::size_t latency_samples = SampleReservoir::kDefaultCapacity);
    CaptureStatsCollector(const CaptureStatsCollector&) = delete;
    CaptureStatsCollector& operator=(const CaptureStatsCollector&) = delete;

    // Control thread, while neither producer nor consumer runs: forget everything.
    void reset() noexcept;

    // Producer thread (one at a time). `frames_without_slot` is the backend's count of frames
    // discarded for want of a slot since the stream started, read when this frame arrived.
    // Lock-free; never blocks or allocates.
    void onArrival(const FrameMetadata& meta, std::uint64_t frames_without_slot) noexcept;

    // Consumer thread (one at a time): the frame was handed to the consumer at `handover_ns`, on
    // the same clock as FrameMetadata::arrival_ns. Never allocates.
    void onDelivery(const FrameMetadata& meta, std::int64_t handover_ns) noexcept;

    // Any thread. The no-slot and mailbox counts are kept by the camera and the mailbox; the
    // caller passes them in.
    CaptureStats snapshot(std::uint64_t frames_without_slot, std::uint64_t mailbox_drops,
                          std::uint64_t mailbox_discarded = 0) const;

private:
    // Producer side: the atomics are read by snapshot(); the rest is the producer's own.
    std::atomic<std::uint64_t> received_{0};
    std::atomic<std::uint64_t> device_drops_{0};
    bool have_previous_ = false;
    std::uint64_t previous_sequence_ = 0;
    std::uint64_t previous_without_slot_ = 0;

    // Consumer side, under mutex_.
    mutable std::mutex mutex_;
    std::uint64_t delivered_ = 0;
    std::uint64_t corrupt_ = 0;
    std::int64_t last_timestamp_ns_ = 0;
    std::int64_t first_handover_ns_ = 0;
    std::int64_t last_handover_ns_ = 0;
    std::uint64_t intervals_ = 0;  // Welford's running mean and sum of squares of intervals (ms)
    double interval_mean_ms_ = 0.0;
    double interval_m2_ = 0.0;
    SampleReservoir latency_ms_;
};

}  // namespace commonlight::capture

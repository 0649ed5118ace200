#include "capture/stats.h"

#include <algorithm>
#include <cmath>

namespace commonlight::capture {

namespace {
constexpr double kNsPerMs = 1e6;
constexpr double kNsPerS = 1e9;

// Frames per second over `frames` frames spanning first..last ns; 0 when undefined.
double rate(std::uint64_t frames, std::int64_t first_ns, std::int64_t last_ns) noexcept {
    if (frames < 2 || last_ns <= first_ns) return 0.0;
    return static_cast<double>(frames - 1) * kNsPerS / static_cast<double>(last_ns - first_ns);
}
}  // namespace

CaptureStatsCollector::CaptureStatsCollector(std::size_t latency_samples) : latency_ms_(latency_samples) {}

void CaptureStatsCollector::reset() noexcept {
    received_.store(0, std::memory_order_relaxed);
    device_drops_.store(0, std::memory_order_relaxed);
    have_previous_ = false;
    previous_sequence_ = 0;
    previous_without_slot_ = 0;
    std::lock_guard lock(mutex_);
    delivered_ = corrupt_ = 0;
    last_timestamp_ns_ = first_handover_ns_ = last_handover_ns_ = 0;
    intervals_ = 0;
    interval_mean_ms_ = interval_m2_ = 0.0;
    latency_ms_.clear();
}

void CaptureStatsCollector::onArrival(const FrameMetadata& meta, std::uint64_t frames_without_slot) noexcept {
    received_.fetch_add(1, std::memory_order_relaxed);
    if (have_previous_ && meta.sequence > previous_sequence_ + 1) {
        // Hard case: a backend that numbers a frame before it finds no slot leaves a gap that is
        // not the device's. Subtract the slotless frames of this interval (never below zero).
        const std::uint64_t gap = meta.sequence - previous_sequence_ - 1;
        const std::uint64_t slotless = frames_without_slot - std::min(frames_without_slot, previous_without_slot_);
        if (gap > slotless) device_drops_.fetch_add(gap - slotless, std::memory_order_relaxed);
    }
    // A sequence that goes back (a device reset, a looping replay) starts counting afresh.
    have_previous_ = true;
    previous_sequence_ = meta.sequence;
    previous_without_slot_ = frames_without_slot;
}

void CaptureStatsCollector::onDelivery(const FrameMetadata& meta, std::int64_t handover_ns) noexcept {
    std::lock_guard lock(mutex_);
    if (meta.status != FrameStatus::kOk) ++corrupt_;
    if (delivered_ == 0) {
        first_handover_ns_ = handover_ns;
    } else if (meta.timestamp_ns > last_timestamp_ns_) {
        // Welford: numerically stable running variance of the intervals.
        const double interval_ms = static_cast<double>(meta.timestamp_ns - last_timestamp_ns_) / kNsPerMs;
        ++intervals_;
        const double delta = interval_ms - interval_mean_ms_;
        interval_mean_ms_ += delta / static_cast<double>(intervals_);
        interval_m2_ += delta * (interval_ms - interval_mean_ms_);
    }
    ++delivered_;
    last_timestamp_ns_ = meta.timestamp_ns;
    last_handover_ns_ = handover_ns;
    if (meta.arrival_ns != 0) {
        latency_ms_.add(static_cast<double>(std::max<std::int64_t>(0, handover_ns - meta.arrival_ns)) / kNsPerMs);
    }
}

CaptureStats CaptureStatsCollector::snapshot(std::uint64_t frames_without_slot, std::uint64_t mailbox_drops,
                                             std::uint64_t mailbox_discarded) const {
    CaptureStats stats;
    stats.frames_discarded = mailbox_discarded;
    stats.frames_received = received_.load(std::memory_order_relaxed);
    stats.drops.device = device_drops_.load(std::memory_order_relaxed);
    stats.drops.no_slot = frames_without_slot;
    stats.drops.mailbox = mailbox_drops;
    std::lock_guard lock(mutex_);
    stats.frames_delivered = delivered_;
    stats.drops.corrupt = corrupt_;
    // From the mean interval, so a timestamp that goes back (a looping replay) does not skew it.
    stats.fps = intervals_ > 0 && interval_mean_ms_ > 0.0 ? 1000.0 / interval_mean_ms_ : 0.0;
    stats.wall_fps = rate(delivered_, first_handover_ns_, last_handover_ns_);
    stats.jitter_ms = intervals_ > 0 ? std::sqrt(interval_m2_ / static_cast<double>(intervals_)) : 0.0;
    stats.latency_ms = latency_ms_.percentiles();
    return stats;
}

}  // namespace commonlight::capture

#include "pipeline/frame_loop.h"

#include <utility>

#include "core/clock.h"

namespace commonlight::pipeline {

void TrackedFrameHandoff::publish() {
    {
        std::lock_guard lock(mutex_);
        if (fresh_) ++replaced_;
        std::swap(write_, ready_);
        fresh_ = true;
        ++published_;
    }
    ready_cv_.notify_one();
}

void TrackedFrameHandoff::close(std::optional<Error> error) {
    {
        std::lock_guard lock(mutex_);
        if (closed_) return;
        closed_ = true;
        error_ = std::move(error);
    }
    ready_cv_.notify_one();
}

bool TrackedFrameHandoff::waitForDemand(std::int64_t lead_ns, std::stop_token stop) {
    std::unique_lock lock(mutex_);
    while (!stop.stop_requested()) {
        // Step 1: the consumer wants a frame when nothing is waiting for it and its current one is
        // (nearly) done.
        const std::int64_t now = monotonicNowNs();
        std::int64_t start_ns = now;
        if (!fresh_) {
            start_ns = busy_until_ns_ - lead_ns;
            if (busy_until_ns_ == 0 || now >= start_ns) return true;
        } else {
            start_ns = now + 1'000'000'000;  // until the consumer takes it
        }
        // Step 2: wait until then, or until the consumer's state changes.
        const std::uint64_t seen = demand_changes_;
        const auto deadline = std::chrono::steady_clock::now() + std::chrono::nanoseconds(start_ns - now);
        demand_cv_.wait_until(lock, stop, deadline, [&] { return demand_changes_ != seen; });
    }
    return false;
}

TrackedFrameHandoff::Taken TrackedFrameHandoff::take(std::chrono::nanoseconds timeout, const TrackedFrame*& frame,
                                                     std::int64_t busy_ns) {
    std::unique_lock lock(mutex_);
    // The consumer is free: it wants a frame now.
    busy_until_ns_ = 0;
    ++demand_changes_;
    demand_cv_.notify_one();
    if (!ready_cv_.wait_for(lock, timeout, [this] { return fresh_ || closed_; })) return Taken::kTimeout;
    if (!fresh_) return Taken::kEnd;
    std::swap(read_, ready_);
    fresh_ = false;
    frame = &buffers_[read_];
    busy_until_ns_ = busy_ns > 0 ? monotonicNowNs() + busy_ns : 0;
    ++demand_changes_;
    demand_cv_.notify_one();
    return Taken::kFrame;
}

std::optional<Error> TrackedFrameHandoff::error() const {
    std::lock_guard lock(mutex_);
    return error_;
}

std::uint64_t TrackedFrameHandoff::published() const {
    std::lock_guard lock(mutex_);
    return published_;
}

std::uint64_t TrackedFrameHandoff::replaced() const {
    std::lock_guard lock(mutex_);
    return replaced_;
}

}  // namespace commonlight::pipeline

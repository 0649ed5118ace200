#include "core/clock.h"

#include <chrono>
#include <ctime>

namespace commonlight {

std::int64_t monotonicNowNs() noexcept {
    timespec ts{};
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

std::int64_t SteadyClock::nowNs() const { return monotonicNowNs(); }

bool SteadyClock::sleepUntil(std::int64_t deadline_ns, std::stop_token stop) {
    std::unique_lock lock(mutex_);
    while (!stop.stop_requested()) {
        const std::int64_t remaining = deadline_ns - monotonicNowNs();
        if (remaining <= 0) return true;
        wake_.wait_for(lock, stop, std::chrono::nanoseconds(remaining), [] { return false; });
    }
    return false;
}

SteadyClock& SteadyClock::instance() {
    static SteadyClock clock;
    return clock;
}

std::int64_t ManualClock::nowNs() const {
    std::lock_guard lock(mutex_);
    return now_ns_;
}

bool ManualClock::sleepUntil(std::int64_t deadline_ns, std::stop_token stop) {
    std::unique_lock lock(mutex_);
    if (now_ns_ >= deadline_ns) return !stop.stop_requested();
    ++sleepers_;
    changed_.notify_all();
    const bool reached = changed_.wait(lock, stop, [&] { return now_ns_ >= deadline_ns; });
    --sleepers_;
    return reached;
}

void ManualClock::advance(std::int64_t delta_ns) {
    std::lock_guard lock(mutex_);
    now_ns_ += delta_ns;
    changed_.notify_all();
}

void ManualClock::set(std::int64_t now_ns) {
    std::lock_guard lock(mutex_);
    now_ns_ = now_ns;
    changed_.notify_all();
}

void ManualClock::waitForSleepers(int count) {
    std::unique_lock lock(mutex_);
    changed_.wait(lock, [&] { return sleepers_ >= count; });
}

int ManualClock::sleepers() const {
    std::lock_guard lock(mutex_);
    return sleepers_;
}

}  // namespace commonlight

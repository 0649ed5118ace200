// Clocks. Everything that paces or timestamps frames takes a Clock&, so tests drive time with a
// ManualClock and never sleep.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <mutex>
#include <stop_token>

namespace commonlight {

class Clock {
public:
    virtual ~Clock() = default;
    // Nanoseconds on this clock's time line (CLOCK_MONOTONIC for the steady clock).
    virtual std::int64_t nowNs() const = 0;
    // Blocks until nowNs() >= deadline_ns or a stop is requested on `stop`.
    // Returns true when the deadline was reached, false when stopped.
    virtual bool sleepUntil(std::int64_t deadline_ns, std::stop_token stop) = 0;
};

// CLOCK_MONOTONIC (std::chrono::steady_clock on Linux).
class SteadyClock final : public Clock {
public:
    std::int64_t nowNs() const override;
    bool sleepUntil(std::int64_t deadline_ns, std::stop_token stop) override;
    // A process-wide instance.
    static SteadyClock& instance();

private:
    std::mutex mutex_;
    std::condition_variable_any wake_;
};

// Time moves only when a test says so. Threads sleeping on it wake when advance() passes their
// deadline; waitForSleepers() lets a test wait until a worker thread is parked on the clock.
class ManualClock final : public Clock {
public:
    explicit ManualClock(std::int64_t start_ns = 0) : now_ns_(start_ns) {}
    std::int64_t nowNs() const override;
    bool sleepUntil(std::int64_t deadline_ns, std::stop_token stop) override;

    void advance(std::int64_t delta_ns);
    void set(std::int64_t now_ns);
    // Blocks until at least `count` threads are inside sleepUntil() waiting for a future time.
    void waitForSleepers(int count);
    int sleepers() const;

private:
    mutable std::mutex mutex_;
    std::condition_variable_any changed_;
    std::int64_t now_ns_;
    int sleepers_ = 0;
};

// CLOCK_MONOTONIC in nanoseconds.
std::int64_t monotonicNowNs() noexcept;

}  // namespace commonlight

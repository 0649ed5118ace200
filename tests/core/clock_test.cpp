#include "core/clock.h"

#include <atomic>
#include <thread>

#include <gtest/gtest.h>

namespace commonlight {
namespace {

TEST(ManualClock, SleeperWakesOnlyWhenTimePassesTheDeadline) {
    ManualClock clock(1000);
    std::atomic<int> woke{0};
    std::jthread sleeper([&](std::stop_token stop) {
        if (clock.sleepUntil(5000, stop)) woke = 1;
    });
    clock.waitForSleepers(1);
    clock.advance(3000);  // 4000 < 5000: still asleep
    clock.waitForSleepers(1);
    EXPECT_EQ(woke.load(), 0);
    clock.advance(1000);
    sleeper.join();
    EXPECT_EQ(woke.load(), 1);
    EXPECT_EQ(clock.nowNs(), 5000);
}

TEST(ManualClock, StopWakesASleeper) {
    ManualClock clock;
    std::atomic<int> result{-1};
    std::jthread sleeper([&](std::stop_token stop) { result = clock.sleepUntil(1'000'000'000, stop) ? 1 : 0; });
    clock.waitForSleepers(1);
    sleeper.request_stop();
    sleeper.join();
    EXPECT_EQ(result.load(), 0);
}

TEST(SteadyClock, DeadlineInThePastReturnsAtOnce) {
    std::stop_source source;
    auto& clock = SteadyClock::instance();
    EXPECT_TRUE(clock.sleepUntil(clock.nowNs() - 1, source.get_token()));
    source.request_stop();
    EXPECT_FALSE(clock.sleepUntil(clock.nowNs() + 10'000'000'000, source.get_token()));
}

}  // namespace
}  // namespace commonlight

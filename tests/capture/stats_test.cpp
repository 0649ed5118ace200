#include "capture/stats.h"

#include <cmath>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/percentiles.h"
#include "capture/stage_timings.h"
#include "core/clock.h"

namespace commonlight::capture {
namespace {

constexpr std::int64_t kMs = 1'000'000;

TEST(Percentiles, NearestRankOfOneToHundred) {
    SampleReservoir samples(1000);
    for (int i = 100; i >= 1; --i) samples.add(i);  // order does not matter
    const Percentiles p = samples.percentiles();
    EXPECT_EQ(p.count, 100u);
    EXPECT_EQ(p.p50, 50.0);
    EXPECT_EQ(p.p95, 95.0);
    EXPECT_EQ(p.max, 100.0);
}

TEST(Percentiles, SmallAndEmptySets) {
    EXPECT_EQ(SampleReservoir(4).percentiles().p95, 0.0);
    EXPECT_EQ(SampleReservoir(4).percentiles().count, 0u);
    const std::vector<double> one = {7.0};
    EXPECT_EQ(nearestRank(one, 50.0), 7.0);
    EXPECT_EQ(nearestRank(one, 95.0), 7.0);
    const std::vector<double> twenty = [] {
        std::vector<double> v;
        for (int i = 1; i <= 20; ++i) v.push_back(i);
        return v;
    }();
    EXPECT_EQ(nearestRank(twenty, 95.0), 19.0);  // ceil(0.95 * 20) = 19, despite rounding
    EXPECT_EQ(nearestRank(twenty, 50.0), 10.0);
}

TEST(Percentiles, ReservoirBeyondCapacityIsDeterministicAndKeepsTheExactMax) {
    SampleReservoir a(16);
    SampleReservoir b(16);
    for (int i = 0; i < 10000; ++i) {
        const double v = (i * 7919) % 1000;  // a scrambled 0..999
        a.add(v);
        b.add(v);
    }
    EXPECT_EQ(a.capacity(), 16u);  // never grew
    const Percentiles pa = a.percentiles();
    const Percentiles pb = b.percentiles();
    EXPECT_EQ(pa.count, 10000u);
    EXPECT_EQ(pa.max, 999.0);
    EXPECT_EQ(pa.p50, pb.p50);
    EXPECT_EQ(pa.p95, pb.p95);
    EXPECT_LE(pa.p50, pa.p95);
    a.clear();
    EXPECT_EQ(a.percentiles().count, 0u);
}

TEST(Percentiles, ConstantStreamGivesThatConstant) {
    SampleReservoir samples(8);
    for (int i = 0; i < 1000; ++i) samples.add(2.5);
    const Percentiles p = samples.percentiles();
    EXPECT_EQ(p.p50, 2.5);
    EXPECT_EQ(p.p95, 2.5);
    EXPECT_EQ(p.max, 2.5);
}

FrameMetadata meta(std::uint64_t sequence, std::int64_t timestamp_ns, std::int64_t arrival_ns,
                   FrameStatus status = FrameStatus::kOk) {
    FrameMetadata m;
    m.sequence = sequence;
    m.timestamp_ns = timestamp_ns;
    m.arrival_ns = arrival_ns;
    m.status = status;
    return m;
}

TEST(CaptureStats, SequenceGapsCountDeviceDropsLessSlotlessFrames) {
    CaptureStatsCollector stats;
    // Sequences 0 1 2 5 6 10 11: gaps of 2 and 3. The backend found no slot for one frame between
    // 6 and 10 (it numbered it), so only 2 of that gap were lost at the device.
    stats.onArrival(meta(0, 0, 1), 0);
    stats.onArrival(meta(1, 0, 1), 0);
    stats.onArrival(meta(2, 0, 1), 0);
    stats.onArrival(meta(5, 0, 1), 0);
    stats.onArrival(meta(6, 0, 1), 0);
    stats.onArrival(meta(10, 0, 1), 1);
    stats.onArrival(meta(11, 0, 1), 1);
    const CaptureStats s = stats.snapshot(1, 0);
    EXPECT_EQ(s.frames_received, 7u);
    EXPECT_EQ(s.drops.device, 2u + 2u);
    EXPECT_EQ(s.drops.no_slot, 1u);
    EXPECT_EQ(s.drops.total(), 5u);
}

TEST(CaptureStats, SlotlessFramesBeyondTheGapDoNotGoNegative) {
    CaptureStatsCollector stats;
    stats.onArrival(meta(0, 0, 1), 0);
    stats.onArrival(meta(2, 0, 1), 3);  // 3 slotless frames a backend did not number; gap 1
    stats.onArrival(meta(3, 0, 1), 3);
    EXPECT_EQ(stats.snapshot(3, 0).drops.device, 0u);
}

TEST(CaptureStats, SequenceThatGoesBackStartsAfreshAndDuplicatesAreNoGap) {
    CaptureStatsCollector stats;
    stats.onArrival(meta(100, 0, 1), 0);
    stats.onArrival(meta(0, 0, 1), 0);  // a looping replay
    stats.onArrival(meta(0, 0, 1), 0);
    stats.onArrival(meta(1, 0, 1), 0);
    stats.onArrival(meta(3, 0, 1), 0);
    EXPECT_EQ(stats.snapshot(0, 0).drops.device, 1u);
}

TEST(CaptureStats, RatesJitterLatencyAndCorruptFramesFromKnownTimings) {
    CaptureStatsCollector stats;
    // Timestamps 0 10 20 40 50 ms: intervals 10 10 20 10 (mean 12.5 ms -> 80 fps; population
    // variance ((2.5^2) * 3 + 7.5^2) / 4 = 18.75). Latencies 1..5 ms. Hand-overs 25 ms apart.
    const std::int64_t timestamps_ms[] = {0, 10, 20, 40, 50};
    const std::int64_t base = 1000 * kMs;
    for (int i = 0; i < 5; ++i) {
        const std::int64_t handover = base + i * 25 * kMs;
        const std::int64_t arrival = handover - (i + 1) * kMs;
        const FrameStatus status = i == 3 ? FrameStatus::kIncomplete : FrameStatus::kOk;
        stats.onDelivery(meta(static_cast<std::uint64_t>(i), timestamps_ms[i] * kMs, arrival, status), handover);
    }
    const CaptureStats s = stats.snapshot(3, 7);
    EXPECT_EQ(s.frames_delivered, 5u);
    EXPECT_NEAR(s.fps, 80.0, 1e-9);
    EXPECT_NEAR(s.wall_fps, 40.0, 1e-9);
    EXPECT_NEAR(s.jitter_ms, std::sqrt(18.75), 1e-9);
    EXPECT_EQ(s.latency_ms.count, 5u);
    EXPECT_DOUBLE_EQ(s.latency_ms.p50, 3.0);
    EXPECT_DOUBLE_EQ(s.latency_ms.p95, 5.0);
    EXPECT_DOUBLE_EQ(s.latency_ms.max, 5.0);
    EXPECT_EQ(s.drops.corrupt, 1u);
    EXPECT_EQ(s.drops.no_slot, 3u);
    EXPECT_EQ(s.drops.mailbox, 7u);
    EXPECT_EQ(s.drops.total(), 11u);

    stats.reset();
    const CaptureStats empty = stats.snapshot(0, 0);
    EXPECT_EQ(empty.frames_delivered, 0u);
    EXPECT_EQ(empty.fps, 0.0);
    EXPECT_EQ(empty.latency_ms.count, 0u);
}

TEST(CaptureStats, FramesWithoutArrivalTimeGiveNoLatencySample) {
    CaptureStatsCollector stats;
    stats.onDelivery(meta(0, 0, 0), 5 * kMs);
    stats.onDelivery(meta(1, 33 * kMs, 30 * kMs), 32 * kMs);
    const CaptureStats s = stats.snapshot(0, 0);
    EXPECT_EQ(s.latency_ms.count, 1u);
    EXPECT_DOUBLE_EQ(s.latency_ms.max, 2.0);
    EXPECT_EQ(s.jitter_ms, 0.0);  // one interval: no spread
}

TEST(StageTimings, RecordsByIdInRegistrationOrder) {
    StageTimings timings({"capture", "convert", "track"});
    EXPECT_EQ(timings.size(), 3u);
    const auto convert = timings.id("convert");
    EXPECT_EQ(timings.name(convert), "convert");
    EXPECT_FALSE(timings.find("render"));
    for (int i = 1; i <= 20; ++i) timings.add(convert, i);
    timings.addNs(timings.id("capture"), 3 * kMs);
    const auto summary = timings.summary();
    ASSERT_EQ(summary.size(), 3u);
    EXPECT_EQ(summary[0].name, "capture");
    EXPECT_DOUBLE_EQ(summary[0].ms.max, 3.0);
    EXPECT_EQ(summary[1].name, "convert");
    EXPECT_EQ(summary[1].ms.p50, 10.0);
    EXPECT_EQ(summary[1].ms.p95, 19.0);
    EXPECT_EQ(summary[1].ms.max, 20.0);
    EXPECT_EQ(summary[2].ms.count, 0u);
}

TEST(StageTimings, TimerMeasuresOnTheGivenClock) {
    const std::vector<std::string> names = {"detect"};
    StageTimings timings(names);
    ManualClock clock(5 * kMs);
    {
        StageTimer timer(timings, 0, clock);
        clock.advance(4 * kMs);
    }  // recorded on scope exit
    {
        StageTimer timer(timings, 0, clock);
        clock.advance(6 * kMs);
        EXPECT_DOUBLE_EQ(timer.stop(), 6.0);
        clock.advance(100 * kMs);
        EXPECT_EQ(timer.stop(), 0.0);  // once only
    }
    const Percentiles p = timings.percentiles(0);
    EXPECT_EQ(p.count, 2u);
    EXPECT_DOUBLE_EQ(p.p50, 4.0);
    EXPECT_DOUBLE_EQ(p.max, 6.0);
}

}  // namespace
}  // namespace commonlight::capture

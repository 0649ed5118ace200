// The real-time loop's quality governor (pipeline/quality_governor.h): steps down while
// compositing takes most of the frame period, back up only after a long stretch with room, never
// past its levels, and ignores frames it cannot judge.
#include "pipeline/quality_governor.h"

#include <gtest/gtest.h>

#include <cmath>

namespace commonlight::pipeline {
namespace {

constexpr double kPeriod = 33.3e6;  // ns

render::CompositorOptions configured(int msaa, int light_samples) {
    render::CompositorOptions o;
    o.msaa_samples = msaa;
    o.area_light_samples = light_samples;
    return o;
}

// Frames of `load` x the period until the level changes (or `limit` frames); how many it took.
int framesUntilChange(QualityGovernor& g, double load, int limit) {
    for (int i = 1; i <= limit; ++i) {
        if (g.step(load * kPeriod, kPeriod)) return i;
    }
    return -1;
}

TEST(QualityGovernor, LevelsFromTheConfiguredOptions) {
    const QualityGovernor full(configured(4, 4));
    ASSERT_EQ(full.levels().size(), 3u);
    EXPECT_EQ(full.levels()[0].msaa_samples, 4);
    EXPECT_EQ(full.levels()[0].area_light_samples, 4);
    EXPECT_EQ(full.levels()[1].msaa_samples, 1);
    EXPECT_EQ(full.levels()[1].area_light_samples, 4);
    EXPECT_EQ(full.levels()[2].msaa_samples, 1);
    EXPECT_EQ(full.levels()[2].area_light_samples, 2);
    // Nothing to give up: no MSAA and one light sample configured.
    EXPECT_EQ(QualityGovernor(configured(1, 1)).levels().size(), 1u);
    EXPECT_EQ(QualityGovernor(configured(1, 3)).levels().back().area_light_samples, 1);
    // apply() changes those two options only.
    render::CompositorOptions o = configured(4, 4);
    o.camera_matching = true;
    const render::CompositorOptions same = full.apply(o);
    EXPECT_EQ(same.msaa_samples, 4);
    EXPECT_TRUE(same.camera_matching);
}

TEST(QualityGovernor, StepsDownWhileBehindAndStopsAtTheLowestLevel) {
    QualityGovernor g(configured(4, 4));
    // Behind the camera (1.2 periods a frame): down after kStepDownFrames such frames.
    EXPECT_EQ(framesUntilChange(g, 1.2, 100), QualityGovernor::kStepDownFrames);
    EXPECT_EQ(g.level(), 1);
    EXPECT_EQ(g.apply(configured(4, 4)).msaa_samples, 1);
    EXPECT_EQ(framesUntilChange(g, 1.2, 100), QualityGovernor::kStepDownFrames);
    EXPECT_EQ(g.level(), 2);
    EXPECT_EQ(g.apply(configured(4, 4)).area_light_samples, 2);
    // Still behind at the lowest level: it stays there.
    EXPECT_EQ(framesUntilChange(g, 1.2, 500), -1);
    EXPECT_EQ(g.level(), 2);
    const nlohmann::json j = g.json();
    EXPECT_EQ(j["changes"], 2);
    EXPECT_EQ(j["levels"][0]["frames"], QualityGovernor::kStepDownFrames);
    EXPECT_EQ(j["levels"][2]["frames"], 500);
}

TEST(QualityGovernor, KeepsAFrameThatFitsAndStepsUpOnlyWithRoomForLong) {
    QualityGovernor g(configured(4, 4));
    // Busy but keeping up (80% of the period): no change at the configured level.
    EXPECT_EQ(framesUntilChange(g, 0.8, 1000), -1);
    EXPECT_EQ(g.level(), 0);
    ASSERT_EQ(framesUntilChange(g, 1.5, 100), QualityGovernor::kStepDownFrames);
    // Between the thresholds (one level's cost ratio above the lower level's load): stays.
    EXPECT_EQ(framesUntilChange(g, 0.75, 1000), -1);
    EXPECT_EQ(g.level(), 1);
    // Room (40%): back up, but only after kStepUpFrames frames of it (the smoothed load first
    // has to fall below the threshold: a few frames more).
    const int up = framesUntilChange(g, 0.4, 1000);
    EXPECT_GE(up, QualityGovernor::kStepUpFrames);
    EXPECT_LE(up, QualityGovernor::kStepUpFrames + 5);
    EXPECT_EQ(g.level(), 0);
    // Slow frames alone among others that fit (busy at 80%) do not step down: the smoothed load
    // must stay high for kStepDownFrames frames.
    for (int i = 0; i < 300; ++i) EXPECT_FALSE(g.step((i % 10 == 5 ? 2.0 : 0.8) * kPeriod, kPeriod)) << i;
    EXPECT_EQ(g.level(), 0);
}

TEST(QualityGovernor, FramesItCannotJudgeChangeNothing) {
    QualityGovernor g(configured(4, 4));
    for (int i = 0; i < 200; ++i) {
        EXPECT_FALSE(g.step(2.0 * kPeriod, 0.0));  // no period yet
        EXPECT_FALSE(g.step(std::nan(""), kPeriod));
        EXPECT_FALSE(g.step(-1.0, kPeriod));
    }
    EXPECT_EQ(g.level(), 0);
    EXPECT_EQ(g.json()["levels"][0]["frames"], 600);
    EXPECT_NE(g.summary().find("MSAA 4, 4 light samples: 600 frames (0 changes)"), std::string::npos);
}

TEST(QualityGovernor, StartsAtTheBestLevelWhoseMeasuredDrawLeavesRoom) {
    // Draws of 40%, 55% and 70% of the period, fastest last: the best level at or under
    // kStepUpLoad (0.6) is the second.
    QualityGovernor g(configured(4, 4));
    EXPECT_EQ(g.startAt({0.9 * kPeriod, 0.55 * kPeriod, 0.4 * kPeriod}, kPeriod), 1);
    EXPECT_EQ(g.level(), 1);
    EXPECT_EQ(g.json()["changes"], 0);
    // The loop goes on from there: behind, it steps down as from any level; busy at 80% it stays.
    EXPECT_EQ(framesUntilChange(g, 1.2, 100), QualityGovernor::kStepDownFrames);
    EXPECT_EQ(g.level(), 2);
    EXPECT_EQ(framesUntilChange(g, 0.8, 500), -1);
    // Every level fits: the configured one.
    QualityGovernor fast(configured(4, 4));
    EXPECT_EQ(fast.startAt({0.3 * kPeriod, 0.2 * kPeriod, 0.1 * kPeriod}, kPeriod), 0);
    // None fits: the lowest.
    QualityGovernor slow(configured(4, 4));
    EXPECT_EQ(slow.startAt({3.0 * kPeriod, 2.0 * kPeriod, 1.0 * kPeriod}, kPeriod), 2);
    // Times it cannot judge are too slow; an unknown period keeps the configured level.
    QualityGovernor odd(configured(4, 4));
    EXPECT_EQ(odd.startAt({std::nan(""), -1.0}, kPeriod), 2);
    EXPECT_EQ(odd.startAt({std::nan(""), 0.1 * kPeriod}, kPeriod), 1);
    QualityGovernor unknown(configured(4, 4));
    EXPECT_EQ(unknown.startAt({0.9 * kPeriod, 0.9 * kPeriod, 0.9 * kPeriod}, 0.0), 0);
    EXPECT_EQ(unknown.startAt({0.9 * kPeriod, 0.9 * kPeriod, 0.9 * kPeriod}, std::nan("")), 0);
}

}  // namespace
}  // namespace commonlight::pipeline

// LightingPacer: the lighting's pace in real time from the frames dropped.
#include <gtest/gtest.h>

#include <optional>

#include "pipeline/lighting_pacer.h"

namespace commonlight::pipeline {
namespace {

// `n` frames without a drop; the changes they made, in order.
std::vector<int> calm(LightingPacer& pacer, int n) {
    std::vector<int> changes;
    for (int i = 0; i < n; ++i) {
        if (const std::optional<int> every = pacer.step(0, true)) changes.push_back(*every);
    }
    return changes;
}

TEST(LightingPacer, EveryFrameWhileNoFrameIsDropped) {
    LightingPacer pacer;
    EXPECT_TRUE(calm(pacer, 1000).empty());
    EXPECT_EQ(pacer.every(), 1);
    EXPECT_EQ(pacer.changes(), 0u);
    EXPECT_EQ(pacer.json()["frames"]["1"].get<int>(), 1000);
}

TEST(LightingPacer, ADropSlowsItAndCalmFramesBringItBack) {
    LightingPacer pacer;
    calm(pacer, LightingPacer::kGraceFrames);
    EXPECT_EQ(pacer.step(1, true), std::optional<int>(2));
    EXPECT_EQ(pacer.step(3, true), std::optional<int>(3));  // how many were dropped does not matter
    EXPECT_EQ(pacer.step(1, true), std::optional<int>(4));
    EXPECT_EQ(pacer.step(1, true), std::nullopt);  // at most kMaxEvery
    EXPECT_EQ(pacer.every(), LightingPacer::kMaxEvery);
    // One step back per kCalmFrames frames without a drop; a drop restarts the count.
    EXPECT_TRUE(calm(pacer, LightingPacer::kCalmFrames - 1).empty());
    EXPECT_EQ(pacer.step(0, true), std::optional<int>(3));
    EXPECT_TRUE(calm(pacer, LightingPacer::kCalmFrames - 10).empty());
    EXPECT_EQ(pacer.step(2, true), std::optional<int>(4));
    EXPECT_EQ(calm(pacer, 3 * LightingPacer::kCalmFrames), (std::vector<int>{3, 2, 1}));
    EXPECT_TRUE(calm(pacer, 5 * LightingPacer::kCalmFrames).empty());
    EXPECT_EQ(pacer.changes(), 8u);
    const nlohmann::json j = pacer.json();
    EXPECT_EQ(j["every"].get<int>(), 1);
    EXPECT_EQ(j["frames"]["4"].get<int>(), 1 + 2 * LightingPacer::kCalmFrames);  // the frame at 4 before the calm, two calm runs
    EXPECT_NE(pacer.summary().find("every 4th frame"), std::string::npos) << pacer.summary();
}

TEST(LightingPacer, DropsBeforeTheFirstSnapshotOrInTheGraceFramesDoNotCount) {
    LightingPacer pacer;
    for (int i = 0; i < LightingPacer::kGraceFrames; ++i) EXPECT_EQ(pacer.step(5, true), std::nullopt) << i;
    for (int i = 0; i < 40; ++i) EXPECT_EQ(pacer.step(5, false), std::nullopt) << i;  // the first full update
    EXPECT_EQ(pacer.every(), 1);
    EXPECT_EQ(pacer.step(1, true), std::optional<int>(2));
}

}  // namespace
}  // namespace commonlight::pipeline

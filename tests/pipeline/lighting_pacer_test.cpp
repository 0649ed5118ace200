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

// A drop, then the frames it is held for (no full update ends): the change it makes, if any.
std::optional<int> drop(LightingPacer& pacer, std::uint64_t dropped = 1) {
    std::optional<int> changed = pacer.step(dropped, true);
    for (int i = 0; i < LightingPacer::kRefitFrames; ++i) {
        if (const std::optional<int> every = pacer.step(0, true)) {
            EXPECT_FALSE(changed.has_value());
            changed = every;
        }
    }
    return changed;
}

TEST(LightingPacer, ADropSlowsItAndCalmFramesBringItBack) {
    LightingPacer pacer;
    calm(pacer, LightingPacer::kGraceFrames);
    EXPECT_EQ(drop(pacer), std::optional<int>(2));
    EXPECT_EQ(drop(pacer, 3), std::optional<int>(3));  // how many were dropped does not matter
    EXPECT_EQ(drop(pacer), std::optional<int>(4));
    EXPECT_EQ(drop(pacer), std::nullopt);  // at most kMaxEvery
    EXPECT_EQ(pacer.every(), LightingPacer::kMaxEvery);
    // One step back per kCalmFrames frames without a drop; a drop restarts the count.
    EXPECT_TRUE(calm(pacer, LightingPacer::kCalmFrames - 1).empty());
    EXPECT_EQ(pacer.step(0, true), std::optional<int>(3));
    EXPECT_TRUE(calm(pacer, LightingPacer::kCalmFrames - 10).empty());
    EXPECT_EQ(drop(pacer, 2), std::optional<int>(4));
    EXPECT_EQ(calm(pacer, 3 * LightingPacer::kCalmFrames), (std::vector<int>{3, 2, 1}));
    EXPECT_TRUE(calm(pacer, 5 * LightingPacer::kCalmFrames).empty());
    EXPECT_EQ(pacer.changes(), 8u);
    const nlohmann::json j = pacer.json();
    EXPECT_EQ(j["every"].get<int>(), 1);
    EXPECT_NE(pacer.summary().find("every 4th frame"), std::string::npos) << pacer.summary();
    std::uint64_t frames = 0;
    for (const auto& [every, n] : j["frames"].items()) frames += n.get<std::uint64_t>();
    EXPECT_EQ(frames, static_cast<std::uint64_t>(LightingPacer::kGraceFrames + 4 * (1 + LightingPacer::kRefitFrames) +
                                                 2 * LightingPacer::kCalmFrames - 10 + 1 + LightingPacer::kRefitFrames +
                                                 8 * LightingPacer::kCalmFrames));
}

// A full update (the lights refitted) takes both cores whatever the pace: drops around it, before
// it ends or just after, are not the pace's.
TEST(LightingPacer, DropsAroundAFullUpdateDoNotCount) {
    LightingPacer pacer;
    std::uint64_t full = 1;  // the first update, before the frames
    for (int i = 0; i < LightingPacer::kGraceFrames + 10; ++i) EXPECT_EQ(pacer.step(0, true, full), std::nullopt);
    // A drop, then the full update ends two frames later: forgotten.
    EXPECT_EQ(pacer.step(1, true, full), std::nullopt);
    EXPECT_EQ(pacer.step(0, true, full), std::nullopt);
    EXPECT_EQ(pacer.step(0, true, ++full), std::nullopt);
    // Drops in the frames right after it: not counted either.
    for (int i = 0; i < LightingPacer::kRefitFrames - 1; ++i) EXPECT_EQ(pacer.step(1, true, full), std::nullopt) << i;
    for (int i = 0; i < 3 * LightingPacer::kRefitFrames; ++i) EXPECT_EQ(pacer.step(0, true, full), std::nullopt) << i;
    EXPECT_EQ(pacer.every(), 1);
    // A drop far from any full update counts, once held for kRefitFrames frames.
    EXPECT_EQ(pacer.step(1, true, full), std::nullopt);
    for (int i = 0; i < LightingPacer::kRefitFrames - 1; ++i) EXPECT_EQ(pacer.step(0, true, full), std::nullopt) << i;
    EXPECT_EQ(pacer.step(0, true, full), std::optional<int>(2));
}

TEST(LightingPacer, DropsBeforeTheFirstSnapshotOrInTheGraceFramesDoNotCount) {
    LightingPacer pacer;
    for (int i = 0; i < LightingPacer::kGraceFrames; ++i) EXPECT_EQ(pacer.step(5, true), std::nullopt) << i;
    for (int i = 0; i < 40; ++i) EXPECT_EQ(pacer.step(5, false), std::nullopt) << i;  // the first full update
    EXPECT_EQ(pacer.every(), 1);
    EXPECT_EQ(drop(pacer), std::optional<int>(2));
}

}  // namespace
}  // namespace commonlight::pipeline

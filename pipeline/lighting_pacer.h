// LightingPacer: how often the lighting thread solves in real time (`--lighting-every auto`, the
// default of `play` and `live`), from whether the camera's frames are being dropped.
//
// The lighting thread shares the cores with tracking and compositing. Solving for every frame
// (an incremental update: 4-6 ms on the sample, 11-14 ms with `live --move-object`) keeps the
// shadows one frame behind the objects; on this 2-core machine it costs no frame rate (play: 60-61
// of 61 frames either way; live: 28.9-29.8 fps against 29.3-29.7 solving for every second frame).
// A slower machine would lose frames to it. So the pacer starts at every frame and, when the
// pipeline thread finds frames dropped before it took them, solves for one frame fewer in each
// run of frames (every 2nd, 3rd, up to kMaxEvery-th); after kCalmFrames frames without a drop it
// steps back towards every frame. Drops the pace does not cause are not held against it: while
// the lighting has published nothing yet (its first, full update), in the first kGraceFrames
// frames (the compositor's programs compiling), and around a full update (the lights refitted:
// 75-120 ms of both cores whatever the pace; `live` drops most of its frames there): a drop is
// held for kRefitFrames frames and forgotten when a full update ends meanwhile or ended less than
// kRefitFrames frames before it.
//
// Pure logic: the pipeline thread calls step() for each frame it tracks and applies the answer
// (LightingEngine::setUpdateEvery()).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace commonlight::pipeline {

class LightingPacer {
public:
    static constexpr int kMaxEvery = 4;
    static constexpr int kCalmFrames = 60;   // two seconds at 30 fps without a drop: one step back
    static constexpr int kGraceFrames = 15;
    static constexpr int kRefitFrames = 6;   // 0.2 s at 30 fps

    // One tracked frame: `dropped` frames were lost before it (its sequence number's gap), whether
    // the lighting has published a snapshot yet, and how many full updates it has made so far.
    // The new "every" when it changed.
    std::optional<int> step(std::uint64_t dropped, bool lighting_published, std::uint64_t full_updates = 0);

    int every() const noexcept { return every_; }
    std::uint64_t changes() const noexcept { return changes_; }
    // For the metrics: {"every": now, "changes", "frames": {"1": n, "2": n, ...}} (frames tracked
    // at each setting).
    nlohmann::json json() const;
    // "every frame: 50 frames, every 2nd frame: 11 frames (1 change)".
    std::string summary() const;

private:
    int every_ = 1;
    int calm_ = 0;              // frames without a drop since the last drop or change
    int pending_ = -1;          // frames a drop has been held (-1: none)
    std::uint64_t full_updates_ = 0;
    int since_refit_ = kRefitFrames;  // frames since a full update ended (kRefitFrames: long ago)
    std::uint64_t frames_ = 0;  // frames seen
    std::uint64_t changes_ = 0;
    std::vector<std::uint64_t> frames_at_ = std::vector<std::uint64_t>(kMaxEvery, 0);
};

}  // namespace commonlight::pipeline

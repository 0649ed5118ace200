// QualityGovernor: keeps the real-time loop at the camera's rate on a machine too slow to composite
// every frame at the configured quality.
//
// After each composite the loop reports how long the frame took on its thread against the
// camera's frame period. When that load, smoothed, stays above kStepDownLoad for kStepDownFrames
// frames (a quarter of a second at 30 fps: one slow frame is not enough) the compositor steps down
// one level; when it stays below kStepUpLoad for kStepUpFrames frames it steps back up. The levels,
// from the configured options: as configured; no MSAA (llvmpipe shades every sample, so 4 samples
// cost most where the virtual objects are); then also half the shadow maps per area light. The gap
// between the two thresholds is wider than one level's cost ratio (measured 1.2 to 1.4 on the
// sample), so the governor does not oscillate between two levels.
//
// Only the pipelined real-time loop uses it (sync playback, the one-thread loop and the
// benchmarks' fixed cases draw at the configured quality); `play` and `live` take --fixed-quality
// to turn it off. Pure logic, no GL: the caller applies apply() to the compositor's options when
// step() says the level changed.
#pragma once

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "render/compositor.h"

namespace commonlight::pipeline {

class QualityGovernor {
public:
    static constexpr double kStepDownLoad = 0.9;  // smoothed composite time / frame period
    static constexpr double kStepUpLoad = 0.6;
    static constexpr int kStepDownFrames = 8;    // consecutive frames above kStepDownLoad before stepping down
    static constexpr int kStepUpFrames = 90;     // ... below kStepUpLoad before stepping up

    struct Level {
        int msaa_samples = 4;
        int area_light_samples = 4;
    };

    explicit QualityGovernor(const render::CompositorOptions& configured);

    // One composited frame: its time on the compositing thread and the camera's frame period (ns;
    // a period <= 0, unknown yet, is ignored). True when the level changed.
    bool step(double composite_ns, double period_ns);

    // Before the loop: the level to start at, from one uncontended draw per level (ns, by level;
    // a missing or nonsense time counts as too slow) against the camera's frame period: the best
    // level whose load is at most kStepUpLoad (the load the loop would step up to it at), else the
    // lowest. A period <= 0 (unknown) keeps the configured level. Counts no frame and no change.
    // Returns the level.
    int startAt(const std::vector<double>& draw_ns, double period_ns);

    int level() const noexcept { return level_; }
    const std::vector<Level>& levels() const noexcept { return levels_; }
    // The compositor's options at the current level (everything else as in `options`).
    render::CompositorOptions apply(render::CompositorOptions options) const { return applyLevel(std::move(options), level_); }
    // The same at another level (0 .. levels() - 1; clamped).
    render::CompositorOptions applyLevel(render::CompositorOptions options, int level) const;

    // For the metrics: frames composited at each level, the number of changes, the current level.
    nlohmann::json json() const;
    // "MSAA 4, 4 light samples: 120 frames; MSAA 1, 4 light samples: 180 frames (2 changes)".
    std::string summary() const;

private:
    std::vector<Level> levels_;
    std::vector<std::uint64_t> frames_at_;
    int level_ = 0;
    double load_ = 0.0;       // smoothed
    int frames_heavy_ = 0;    // consecutive frames above kStepDownLoad (since the last change)
    int frames_light_ = 0;    // consecutive frames below kStepUpLoad (since the last change)
    std::uint64_t changes_ = 0;
};

}  // namespace commonlight::pipeline

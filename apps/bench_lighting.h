// `commonlight bench lighting`: the lighting module's speed against its error, on sequences the
// benchmark renders with the simulated camera (mocks/sim, path tracing) and keeps between runs
// (docs/lighting.md, "Benchmark").
//
// Cases:
//   solver    the radiosity solve alone (true lights and albedos) on the room and the desk: element
//             radiance against the path tracer's average over the same element, for several element
//             counts, hierarchical against the uniform-grid gather (setup and solve time against RMS
//             error, table and plot; the speed-up at equal error; --solver-csv: per-element figures)
//   known     known light geometry, unknown emission (the desk): emission error per light and
//             reflectance error, at sensor noise 0, 1, 3% and after 1, 10, 60 frames
//   distant   an unknown distant light (the sunlit scene): dominant direction error, the sun's
//             irradiance error and the sun + sky irradiance on an open horizontal surface, same
//             noise levels and frame counts
//   nothing   no light in the scene (the desk): every surface emits; the ratio
//   ratio     the predicted ratio B/B~ against the simulator's with/without frames over
//             masks/changed (RMS and mean signed error), desk and room, against a reference
//             rendered at 8x the sequence's spp over the changed region (and against the frames)
//   shading   light direction from a known sphere's shading against seed 002's Tables 1-3
//   cluster   real mesh proxies (real spheres, 320 triangles) in a room, with and without clustering:
//             links, elements, setup and solve time, error against the unclustered solve at fine settings
//   incremental  (--incremental; not in the default set) a virtual object moving along a path for
//             `steps` steps on the desk and in the room: incremental update time (p50/p95/max),
//             elements and links over time, ratio B/B~ against the path tracer at some steps, the
//             refinement thresholds swept (speed against error), full re-solves side by side, and a
//             long check of `stress_moves` random moves (element count bounded, equal to a fresh solve)
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/result.h"

namespace commonlight::apps {

struct BenchLightingOptions {
    std::filesystem::path source_dir = ".";                      // the repository (data/)
    std::filesystem::path data_dir = "out/bench/lighting-data";  // rendered sequences, kept between runs
    std::vector<std::string> cases;                              // empty: all
    int width = 320;   // rendered frames (the estimator works on these)
    int spp = 32;      // samples per pixel of the rendered sequences
    int frames = 60;   // frames of the moving camera (the estimate is reported after 1, 10 and this many)
    std::string json;
    std::string plot;
    std::filesystem::path solver_csv;  // the solver case's per-element errors, one CSV per configuration
    // Case `incremental` (--incremental): a virtual object moving along a path on the desk and in
    // the room, updated incrementally (lighting/influence.h) against full re-solves and the path tracer.
    int steps = 300;            // steps of the path
    int truth_every = 60;       // path-traced truth at every n-th step (and the last)
    int full_every = 20;        // a full re-solve beside the incremental update at every n-th step (0: none, not
                                // even at the truth's steps: for profiling the incremental update alone)
    std::vector<std::string> incremental_scenes;  // of "desk", "room"; empty: both
    bool direct_analysis = false;  // at the truth's steps: where the ratio's error is, and per-texel shadow rays for the direct term
    int stress_moves = 10000;   // random moves of the long check (desk); 0: none
    bool sweep = true;          // the refinement thresholds swept
    // Case `cluster`: the ball's path to the statue and back, this many times (40 moves each way);
    // `cluster_moves_only`: only that timing (no solves against the reference, no ratios), and
    // `cluster_method` "clustered" or "unclustered" alone (empty: both), for profiling.
    int cluster_repeats = 3;
    bool cluster_moves_only = false;
    std::string cluster_method;
};

// Every case's name (all but `incremental` run by default).
std::vector<std::string> benchLightingCaseNames();

// Case `solver` (apps/bench_lighting_solver.cpp); `plot`: its PNG (solve time against error), or empty.
Result<nlohmann::json> runSolverCase(const BenchLightingOptions& options, const std::string& plot);

// Case `cluster` (apps/bench_lighting_cluster.cpp).
Result<nlohmann::json> runClusterCase(const BenchLightingOptions& options);

// Case `incremental` (apps/bench_lighting_incremental.cpp); `plot`: its PNG, or empty.
Result<nlohmann::json> runIncrementalCase(const BenchLightingOptions& options, const std::string& plot);

int runBenchLighting(const BenchLightingOptions& options);

}  // namespace commonlight::apps

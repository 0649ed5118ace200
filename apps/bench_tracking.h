// `commonlight bench tracking`: tracking's speed against its error, on sequences rendered by the
// simulated camera (docs/tracking.md, "Benchmark").
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "core/result.h"

namespace commonlight::apps {

struct BenchTrackingOptions {
    std::filesystem::path source_dir = ".";          // the repository (data/)
    std::filesystem::path data_dir = "out/bench/tracking-data";  // rendered sequences, kept between runs
    std::vector<std::string> cases;                  // empty: all
    int max_frames = 0;                              // 0: every frame of each sequence
    int spp = 4;                                     // samples per pixel of rendered sequences
    std::uint64_t seed = 1;                          // the simulator's sample and noise seed
    std::string json;
    std::string plot;
};

// The case names, in the order they run.
std::vector<std::string> benchTrackingCaseNames();

int runBenchTracking(const BenchTrackingOptions& options);

}  // namespace commonlight::apps

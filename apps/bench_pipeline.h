// `commonlight bench pipeline`: the whole system's speed against its error on a recorded sequence
// with ground truth (the bundled sample by default).
//
// Cases:
//   compositor  draw + read-back time per frame at 640x480 and 1280x720, with and without MSAA,
//               with the sample's lighting snapshot (p50, p95)
//   system      every frame in order (--sync): composite error against groundtruth/composite
//               (PSNR, linear RMSE over the frame and masks/changed) and the stage times, with
//               lighting on and off, MSAA 4 and 1
//   realtime    playback at the recorded rate (looped for `seconds`): frames composited per
//               second, latency from frame arrival to composite ready, how old the lighting was;
//               with the pipeline thread, and with both stages on one thread for comparison
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "core/result.h"

namespace commonlight::apps {

struct BenchPipelineOptions {
    std::filesystem::path sequence = "data/sample";
    std::string json;
    std::string plot;
    int repeats = 30;  // draws per compositor configuration
    double seconds = 6.0;  // real-time playback per configuration
    std::vector<std::string> cases;  // empty: all
};

// The case names, for --cases.
inline std::vector<std::string> benchPipelineCaseNames() { return {"system", "compositor", "realtime"}; }

int runBenchPipeline(const BenchPipelineOptions& options);

}  // namespace commonlight::apps

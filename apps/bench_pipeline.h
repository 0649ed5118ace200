// `commonlight bench pipeline`: the whole system's speed against its error on a recorded sequence
// with ground truth (the bundled sample by default).
//
// Cases:
//   compositor  draw + read-back time per frame at 640x480 and 1280x720, with and without MSAA,
//               objects still and moving, the frame as RGB8, YUYV and NV12, camera matching on,
//               with the sample's lighting snapshot (p50, p95, CPU, each pass)
//   system      every frame in order (--sync): composite error against groundtruth/composite
//               (PSNR, linear RMSE over the frame and masks/changed) and the stage times, with
//               lighting on and off, MSAA 4 and 1, camera matching on
//   matching    camera matching on frame 30: the frame's noise and blur as estimated and their
//               cost; the noise in the virtual objects' pixels of the ground truth and of the
//               composite without and with matching
//   realtime    playback at the recorded rate (looped for `seconds`): frames composited per
//               second, frames dropped, latency from frame arrival to composite ready, how old the
//               lighting was; with the pipeline thread, and with both stages on one thread
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
    std::vector<std::string> cases;  // empty: all (benchPipelineCaseNames())
    std::string modulation_region = "tiles";  // compositor case: render::ModulationRegion (tiles, rectangle, frame)
};

std::vector<std::string> benchPipelineCaseNames();

int runBenchPipeline(const BenchPipelineOptions& options);

}  // namespace commonlight::apps

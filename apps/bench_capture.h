// `commonlight bench capture`: the capture path's speed and losses, per camera, side by side with
// GStreamer's aravissrc on the same GigE camera (docs/capture.md, "Benchmark").
#pragma once

#include <string>

namespace commonlight::apps {

struct BenchCaptureOptions {
    std::string sequence = "data/sample";  // what the replay camera plays
    std::string gige;                      // address of a GigE camera (serve-gige); empty: no GigE cases
    double seconds = 5.0;                  // per case
    std::string json;
};

int runBenchCapture(const BenchCaptureOptions& options);

}  // namespace commonlight::apps

// commonlight bench tracking|capture: speed against error (docs/tracking.md, docs/capture.md).
#include <cstdlib>
#include <memory>

#include "apps/app.h"
#include "apps/bench_capture.h"
#include "apps/bench_tracking.h"

namespace commonlight::apps {

void addBenchCommand(CLI::App& app, Runner& runner) {
    CLI::App* bench = app.add_subcommand("bench", "Speed against error on simulated sequences with ground truth");
    bench->require_subcommand(1);
    auto options = std::make_shared<BenchTrackingOptions>();
    if (const char* source = std::getenv("COMMONLIGHT_SOURCE_DIR")) options->source_dir = source;
    CLI::App* tracking = bench->add_subcommand("tracking", "Tag detection, single-tag and bundle pose, filter, edges");
    tracking->add_option("--json", options->json, "Write the figures as JSON");
    tracking->add_option("--plot", options->plot, "Draw speed against error (PNG)");
    tracking->add_option("--cases", options->cases, "Cases to run (default: all)")
        ->check(CLI::IsMember(benchTrackingCaseNames()))
        ->delimiter(',');
    tracking->add_option("--frames", options->max_frames, "At most this many frames per case (0: all)")
        ->check(CLI::NonNegativeNumber);
    tracking->add_option("--spp", options->spp, "Samples per pixel of the sequences rendered for the benchmark")
        ->check(CLI::Range(1, 4096))
        ->capture_default_str();
    tracking->add_option("--data", options->data_dir, "Where rendered sequences are kept between runs")
        ->capture_default_str();
    tracking->add_option("--source", options->source_dir, "The repository (for data/); default: . or $COMMONLIGHT_SOURCE_DIR");
    tracking->footer("Cases: desk (the bundled sample), desk720, small, fronto, oblique75, blur, wide, occluded. "
                     "Sequences other than desk are rendered once with the simulated camera.");
    tracking->callback([options, &runner] { runner = [options] { return runBenchTracking(*options); }; });

    auto capture_options = std::make_shared<BenchCaptureOptions>();
    CLI::App* capture = bench->add_subcommand("capture", "Frames, drops, hand-over latency and CPU per frame of the capture path");
    capture->add_option("--sequence", capture_options->sequence, "Sequence the replay camera plays")->capture_default_str();
    capture->add_option("--gige", capture_options->gige,
                        "Address of a GigE camera (commonlight serve-gige) for the Aravis and aravissrc cases");
    capture->add_option("--seconds", capture_options->seconds, "Seconds per case")
        ->check(CLI::PositiveNumber)
        ->capture_default_str();
    capture->add_option("--json", capture_options->json, "Write the figures as JSON");
    capture->callback([capture_options, &runner] { runner = [capture_options] { return runBenchCapture(*capture_options); }; });
}

}  // namespace commonlight::apps

// commonlight bench tracking [--json F] [--plot F.png]: speed against error (docs/tracking.md).
#include <cstdlib>
#include <memory>

#include "apps/app.h"
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
}

}  // namespace commonlight::apps

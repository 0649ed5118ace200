// commonlight bench tracking|capture|lighting: speed against error (docs/tracking.md, docs/capture.md).
#include <cstdlib>
#include <memory>

#include "apps/app.h"
#include "apps/bench_capture.h"
#include "apps/bench_lighting.h"
#include "apps/bench_pipeline.h"
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
    tracking->add_option("--seed", options->seed,
                         "Seed of the simulated camera's samples and noise for rendered sequences (another seed: "
                         "other renders of the same views; use another --data folder)")
        ->check(CLI::PositiveNumber)
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

    auto lighting_options = std::make_shared<BenchLightingOptions>();
    if (const char* source = std::getenv("COMMONLIGHT_SOURCE_DIR")) lighting_options->source_dir = source;
    CLI::App* lighting = bench->add_subcommand("lighting", "Light and reflectance estimation, the radiosity solve, the ratio B/B~");
    lighting->add_option("--json", lighting_options->json, "Write the figures as JSON");
    lighting->add_option("--plot", lighting_options->plot, "Draw the solver's time against its error (PNG)");
    lighting->add_option("--cases", lighting_options->cases, "Cases to run (default: all)")
        ->check(CLI::IsMember(benchLightingCaseNames()))
        ->delimiter(',');
    lighting->add_option("--width", lighting_options->width, "Width of the rendered frames (height keeps the camera's aspect)")
        ->check(CLI::Range(64, 1920))
        ->capture_default_str();
    lighting->add_option("--spp", lighting_options->spp, "Samples per pixel of the rendered sequences")
        ->check(CLI::Range(1, 4096))
        ->capture_default_str();
    lighting->add_option("--frames", lighting_options->frames, "Frames of the moving camera (estimates after 1, 10 and this many)")
        ->check(CLI::Range(10, 600))
        ->capture_default_str();
    lighting->add_option("--data", lighting_options->data_dir, "Where rendered sequences are kept between runs")
        ->capture_default_str();
    lighting->add_option("--solver-csv", lighting_options->solver_csv,
                         "Write the solver case's per-element truth and model radiance (direct and total) as CSV files in this folder");
    lighting->add_option("--source", lighting_options->source_dir, "The repository (for data/); default: . or $COMMONLIGHT_SOURCE_DIR");
    auto incremental = std::make_shared<bool>(false);
    lighting->add_flag("--incremental", *incremental, "Only the incremental case: a virtual object moving along a path (lighting/influence.h)");
    lighting->add_option("--steps", lighting_options->steps, "Incremental case: steps of the path")->check(CLI::Range(2, 100000));
    lighting->add_option("--stress-moves", lighting_options->stress_moves, "Incremental case: random moves of the long check (0: none)")
        ->check(CLI::Range(0, 10000000));
    lighting->add_flag("--no-sweep", [lighting_options](std::int64_t) { lighting_options->sweep = false; },
                       "Incremental case: do not sweep the refinement thresholds");
    lighting->add_option("--full-every", lighting_options->full_every,
                         "Incremental case: a full re-solve beside the update every N steps and at the truth's steps (0: none, for profiling)")
        ->check(CLI::Range(0, 100000))
        ->capture_default_str();
    lighting->add_flag("--direct-analysis", lighting_options->direct_analysis,
                       "Incremental case: at the truth's steps, the ratio's error by face and by depth of shadow, and the direct "
                       "light by per-texel shadow rays against the elements'");
    lighting->add_option("--scenes", lighting_options->incremental_scenes, "Incremental case: the scenes (default: desk and room)")
        ->check(CLI::IsMember({"desk", "room"}))
        ->delimiter(',');
    lighting->add_option("--cluster-repeats", lighting_options->cluster_repeats,
                         "Cluster case: the ball's path to the statue and back this many times (40 moves each way)")
        ->check(CLI::Range(1, 10000))
        ->capture_default_str();
    lighting->add_flag("--cluster-moves-only", lighting_options->cluster_moves_only,
                       "Cluster case: only the moves' timing (no solves against the reference, no ratios)");
    lighting->add_option("--cluster-method", lighting_options->cluster_method, "Cluster case: time this method's moves alone")
        ->check(CLI::IsMember({"clustered", "unclustered"}));
    lighting->footer("Cases: solver (radiosity against the path tracer, hierarchical against uniform), known (desk: "
                     "emissions, reflectances), distant (sunlit: direction), nothing (no light in the scene), ratio "
                     "(B/B~ against the simulator over masks/changed). Sequences are rendered once and kept.");
    lighting->callback([lighting_options, incremental, &runner] {
        if (*incremental) lighting_options->cases = {"incremental"};
        runner = [lighting_options] { return runBenchLighting(*lighting_options); };
    });

    auto pipeline_options = std::make_shared<BenchPipelineOptions>();
    CLI::App* pipe = bench->add_subcommand("pipeline", "The whole pipeline: compositor time, composite error (lighting on/off), real-time fps and latency");
    pipe->add_option("--sequence", pipeline_options->sequence, "A sequence with ground truth")->capture_default_str();
    pipe->add_option("--json", pipeline_options->json, "Write the figures as JSON");
    pipe->add_option("--repeats", pipeline_options->repeats, "Draws per compositor configuration")->capture_default_str();
    pipe->add_option("--seconds", pipeline_options->seconds, "Seconds of real-time playback per configuration")
        ->check(CLI::PositiveNumber)
        ->capture_default_str();
    pipe->add_option("--cases", pipeline_options->cases, "Cases to run (default: all)")
        ->check(CLI::IsMember(benchPipelineCaseNames()))
        ->delimiter(',');
    pipe->add_option("--modulation-region", pipeline_options->modulation_region,
                     "Compositor: where the final pass modulates: tiles (where the snapshot changes something), rectangle (one "
                     "around them), frame (everywhere); the composites are the same")
        ->check(CLI::IsMember({"tiles", "rectangle", "frame"}))
        ->capture_default_str();
    pipe->footer("Cases: system (composite error and stage times, every frame), compositor (draw and read-back time, "
                 "per pass), matching (camera matching's estimates and the noise of the virtual objects against the ground "
                 "truth), realtime (playback at the recorded rate: fps, latency, lighting lag; pipeline thread and one thread).");
    pipe->callback([pipeline_options, &runner] { runner = [pipeline_options] { return runBenchPipeline(*pipeline_options); }; });
}

}  // namespace commonlight::apps

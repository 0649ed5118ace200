// commonlight play SEQ [--metrics M.json] [--sync]: runs the pipeline on a recording.
//
// The sequence is replayed as a camera through a capture session (frame pool, mailbox,
// statistics); every frame is converted and tracked (pipeline/frame_pipeline.h) when the scene
// places tags and the sequence has intrinsics, and the pose error is measured when it has ground
// truth. Every tracked frame goes to the lighting thread (pipeline/lighting_stage.h) unless
// --no-lighting, and is composited (pipeline/runner.h) unless --no-composite. In real time
// tracking runs on the pipeline thread and compositing on this one (pipeline/frame_loop.h).
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <memory>

#include "apps/app.h"
#include "apps/quiet.h"
#include "pipeline/lighting_stage.h"
#include "pipeline/runner.h"
#include "apps/progress.h"
#include "apps/report.h"
#include "capture/capture_session.h"
#include "capture/convert.h"
#include "capture/stage_timings.h"
#include "core/clock.h"
#include "core/log.h"
#include "core/scene_io.h"
#include "mocks/replay_camera.h"

namespace commonlight::apps {

namespace {

struct PlayOptions {
    std::string sequence;
    std::string scene;  // default: SEQ/scene.yaml when present
    std::string metrics;
    std::string out;           // composited frames (PNG)
    std::string video;         // composited MP4
    std::string side_by_side;  // frame | composite | truth of one frame
    std::size_t side_by_side_frame = 30;
    bool window = false;
    bool no_composite = false;
    bool sync = false;
    bool no_track = false;
    bool no_lighting = false;
    int lighting_every = 0;
    bool fixed_quality = false;
    bool full_frame = false;
    std::string response;  // --response: overrides sensor.yaml's
    std::size_t slots = 4;
};

// How long to wait for a frame before calling the camera stuck: the longest gap of the
// recording (played in real time) plus a margin.
std::chrono::nanoseconds frameTimeout(const Sequence& seq, bool sync) {
    std::int64_t longest = 0;
    if (!sync) {
        for (std::size_t i = 1; i < seq.frames.size(); ++i) {
            longest = std::max(longest, seq.frames[i].timestamp_ns - seq.frames[i - 1].timestamp_ns);
        }
    }
    return std::chrono::nanoseconds(longest) + std::chrono::seconds(10);
}

int runPlay(const PlayOptions& options) {
    // Step 1: open the recording as a camera.
    mocks::PlaybackOptions playback;
    playback.rate = options.sync ? mocks::PlaybackRate::kMax : mocks::PlaybackRate::kRealtime;
    auto replay = mocks::ReplayCamera::open(options.sequence, playback, SteadyClock::instance());
    if (!replay) return reportError(replay.error());
    mocks::ReplayCamera* camera = replay->get();  // borrowed; the session owns it

    // The scene the later stages will use; read and validated now so a broken file stops us
    // before any work.
    std::optional<std::filesystem::path> scene_path = camera->sequence().scenePath();
    if (!options.scene.empty()) scene_path = options.scene;
    std::optional<Scene> scene;
    if (scene_path) {
        auto read = readScene(*scene_path);
        if (!read) return reportError(read.error());
        scene = std::move(*read);
        say("scene %s: %zu tags, %zu real objects, %zu lights, %zu virtual objects\n", scene_path->c_str(),
                    scene->tags.items.size(), scene->real_objects.size(), scene->lights.size(),
                    scene->virtual_objects.size());
    }
    // Tracking needs the scene's tags and the camera's intrinsics (sensor.yaml, else the scene's).
    std::optional<CameraModel> intrinsics = camera->sequence().sensor.camera;
    if (!intrinsics && scene) intrinsics = scene->camera;
    std::optional<pipeline::GroundTruth> truth;
    if (!camera->sequence().groundtruth_poses.empty()) {
        auto t = pipeline::GroundTruth::fromSequence(camera->sequence(), false);
        if (!t) return reportError(t.error());
        truth = std::move(*t);
    }
    // The camera's response (how codes became linear light): --response, else sensor.yaml's.
    auto response = pipeline::sequenceResponse(camera->sequence(), options.response);
    if (!response) return reportError(response.error());
    const std::size_t recorded = camera->sequence().frames.size();
    const auto timeout = frameTimeout(camera->sequence(), options.sync);
    if (auto configured = camera->configure({}); !configured) return reportError(configured.error());
    const hal::StreamFormat format = camera->activeFormat();

    // Step 2: the capture session.
    capture::CaptureOptions capture_options;
    capture_options.sync = options.sync;
    capture_options.slots = options.slots;
    auto session = capture::CaptureSession::create(std::move(*replay), capture_options);
    if (!session) return reportError(session.error());
    say("playing %s: %zu frames, %s, %s\n", options.sequence.c_str(), recorded, hal::describe(format).c_str(),
                options.sync ? "every frame (--sync)" : "at the recorded rate");

    // Step 3: the per-frame pipeline (pipeline/runner.h): tracking, lighting thread.
    std::unique_ptr<pipeline::FrameRunner> runner;
    if (!options.no_track && scene && !scene->tags.items.empty() && intrinsics) {
        pipeline::RunnerOptions runner_options;
        runner_options.sync = options.sync;
        runner_options.lighting = !options.no_lighting;
        runner_options.lighting_every = options.lighting_every;
        runner_options.adapt_quality = !options.fixed_quality;
        runner_options.tracker.tracking_mode = !options.full_frame;
        runner_options.ground_truth = truth ? &*truth : nullptr;
        runner_options.sequence = &camera->sequence();
        runner_options.response = *response;
        runner_options.radiance_scale = camera->sequence().sensor.radiance_scale;
        runner_options.composite = !options.no_composite;
        runner_options.context = options.window ? render::ContextKind::kWindow : render::ContextKind::kOffscreen;
        runner_options.frames_dir = options.out;
        runner_options.video = options.video;
        runner_options.fps = format.fps > 0.0 ? format.fps : 30.0;
        runner_options.side_by_side = options.side_by_side;
        runner_options.side_by_side_frame = std::min(options.side_by_side_frame, recorded > 0 ? recorded - 1 : 0);
        auto created = pipeline::FrameRunner::create(*scene, *intrinsics, runner_options);
        if (!created) return reportError(created.error());
        runner = std::move(*created);
        if (runner->lighting()) {
            say("lighting: %s, response %s%s\n", options.sync ? "every frame" : "real time (newest wins)",
                        response->name().c_str(),
                        camera->sequence().sensor.radiance_scale ? "" : ", no radiance_scale: emissions in relative units");
        }
    } else if (!options.no_track) {
        log::info(std::string("tracking off: ") + (!scene ? "no scene" : !intrinsics ? "no intrinsics in sensor.yaml or the scene"
                                                                                      : "the scene places no tags"));
    }
    // The recording starts playing once everything is ready (the lighting setup and the GL
    // context take a moment, and in real time the replay would run on meanwhile), in real time
    // with the lighting thread's first update made from the first frame: the first full update
    // takes about a second, a large part of a short recording.
    if (runner && runner->lighting() && !options.sync) {
        Frame first;
        if (auto read = camera->readFrame(0, first); read) {
            const std::int64_t warm_ns = monotonicNowNs();
            auto warmed = runner->warmUp(first);
            // A failed first update is the lighting thread's to report and retry: playback goes on.
            if (!warmed) log::warning(warmed.error().message + " (playing without lighting until the thread's first update)");
            if (warmed && *warmed) say("lighting: first update from the first frame in %.2f s, before playing\n", static_cast<double>(monotonicNowNs() - warm_ns) / 1e9);
        } else {
            log::warning(read.error().message + " (no lighting before the first frame)");
        }
    }
    if (auto started = (*session)->start(); !started) return reportError(started.error());
    capture::StageTimings convert_only({"convert"});
    capture::StageTimings& timings = runner ? runner->timings() : convert_only;
    std::uint64_t undecodable = 0;
    std::optional<Error> failure;
    const std::int64_t start_ns = monotonicNowNs();
    Progress progress("play", recorded);
    // Every frame the session delivers counts for the progress bar (the pipeline thread's).
    struct CountingSource final : pipeline::FrameSource {
        pipeline::SessionSource session;
        Progress* progress;
        std::uint64_t handled = 0;
        CountingSource(capture::CaptureSession& s, std::chrono::nanoseconds t, Progress& p) : session(s, t), progress(&p) {}
        Result<std::optional<FrameHandle>> next(std::stop_token stop) override {
            auto frame = session.next(stop);
            if (frame && frame->has_value()) progress->update(++handled);
            return frame;
        }
    } source(**session, timeout, progress);
    if (runner) {
        // Step 4: the pipeline (pipeline/frame_loop.h): in real time tracking runs on the pipeline
        // thread while this thread composites; with --sync every stage in order.
        pipeline::LoopCallbacks callbacks;
        callbacks.on_bad_frame = [&undecodable](const Frame& frame, const Error& error) {
            ++undecodable;
            log::warning("frame " + std::to_string(frame.meta.timestamp_ns) + ": " + error.message);
        };
        render::GlContext* gl = runner->glContext();
        if (gl && gl->kind() == render::ContextKind::kWindow) {
            callbacks.on_frame = [gl](const pipeline::TrackedFrame&) {
                gl->present();
                gl->pollKeys();
                return !gl->shouldClose();
            };
            callbacks.on_idle = [gl](const pipeline::TrackedFrame*) {
                gl->pollKeys();
                return !gl->shouldClose();
            };
        }
        const pipeline::LoopStats loop = runner->run(source, callbacks, stopToken());
        failure = loop.failure;
    } else {
        // Without tracking: capture and conversion only, on this thread.
        capture::PixelConverter converter;
        Image rgb;
        while (true) {
            auto next = source.next(stopToken());
            if (!next) {
                if (next.error().code != ErrorCode::kCancelled) failure = next.error();
                break;
            }
            if (!next->has_value()) break;  // end of the recording
            FrameHandle frame = std::move(**next);
            if (frame->meta.status != FrameStatus::kOk) continue;  // counted by the session's stats
            capture::StageTimer convert_timer(timings, timings.id("convert"));
            if (auto converted = converter.convert(frame->image, PixelFormat::kRgb8, rgb); !converted) {
                ++undecodable;
                log::warning("frame " + std::to_string(frame->meta.timestamp_ns) + ": " + converted.error().message);
            }
        }
    }
    const double seconds = static_cast<double>(monotonicNowNs() - start_ns) / 1e9;
    progress.finish();
    (*session)->stop();
    if (runner) runner->stop();
    const capture::CaptureStats stats = (*session)->stats();
    const std::uint64_t corrupt = stats.drops.corrupt + undecodable;

    // Step 5: report.
    say("played %llu of %zu frames in %.2f s (%llu corrupt)\n",
                static_cast<unsigned long long>(stats.frames_delivered), recorded, seconds,
                static_cast<unsigned long long>(corrupt));
    if (!quiet()) printCaptureStats(stats);
    if (!quiet()) printStages(timings);
    if (runner) {
        say("tracked: %llu of %llu frames with a camera pose\n",
                    static_cast<unsigned long long>(runner->tracking().framesWithPose()),
                    static_cast<unsigned long long>(stats.frames_delivered));
        say("%s", runner->summary().c_str());
    }
    if (!options.metrics.empty()) {
        nlohmann::json metrics = captureJson(stats);
        metrics["sequence"] = options.sequence;
        metrics["mode"] = options.sync ? "sync" : "realtime";
        metrics["duration_s"] = seconds;
        metrics["corrupt_frames"] = corrupt;
        metrics["stages_ms"] = stagesJson(timings);
        if (runner) metrics.update(runner->metricsJson());
        if (auto written = writeJson(options.metrics, metrics); !written) return reportError(written.error());
        say("metrics written to %s\n", options.metrics.c_str());
    }
    if (failure) return reportError(*failure);
    if (stopToken().stop_requested()) return 130;
    if (corrupt > 0) {
        return reportError(Error{ErrorCode::kBadInput, options.sequence + ": " + std::to_string(corrupt) +
                                                           " frames could not be decoded (see the warnings above)"});
    }
    return kExitOk;
}

}  // namespace

void addPlayCommand(CLI::App& app, Runner& runner) {
    auto options = std::make_shared<PlayOptions>();
    CLI::App* sub = app.add_subcommand("play", "Run the pipeline on a recorded sequence (docs/formats-sequence.md)");
    sub->add_option("sequence", options->sequence, "Sequence folder (SEQ, SEQ/cam0 or a EuRoC mav0 folder)")->required();
    sub->add_option("--scene", options->scene, "Scene file (default: SEQ/scene.yaml when present)");
    sub->add_option("--metrics", options->metrics, "Write the metrics JSON here (docs/cli.md)");
    sub->add_option("--out", options->out, "Write the composited frames here (PNG, named like the recording's frames)");
    sub->add_option("--video", options->video, "Write the composited frames as an MP4 (OpenCV videoio, mp4v)");
    sub->add_option("--side-by-side", options->side_by_side,
                    "Write frame | composite | ground truth (when the sequence has it) of one frame as a PNG");
    sub->add_option("--side-by-side-frame", options->side_by_side_frame, "Which frame for --side-by-side (0-based)")
        ->capture_default_str();
    sub->add_flag("--window", options->window, "Show the composite in a window as it plays (needs a display)");
    sub->add_flag("--no-composite", options->no_composite, "Track and light only; no compositor (no GL needed)");
    sub->add_flag("--sync", options->sync,
                  "Process every frame in order as fast as possible (deterministic), instead of at the recorded rate");
    sub->add_flag("--no-track", options->no_track, "Capture and convert only; no tracking (and so no lighting)");
    sub->add_flag("--no-lighting", options->no_lighting, "Track only; no lighting thread");
    addRealTimeOptions(*sub, options->lighting_every, options->fixed_quality);
    sub->add_flag("--full-frame", options->full_frame, "Detect tags over the whole of every frame (default: around the predicted tags, whole frame every 15)");
    sub->add_option("--response", options->response,
                    "The camera's response: srgb, linear, gamma:G or a response file (default: sensor.yaml's)");
    sub->add_option("--slots", options->slots, "Frame pool slots")->check(CLI::Range(3, 64))->capture_default_str();
    sub->footer("Exit codes: 0 ok, 2 usage, 3 bad input (corrupt frames are reported and counted), 4 device error");
    sub->callback([options, &runner] { runner = [options] { return runPlay(*options); }; });
}

}  // namespace commonlight::apps

// commonlight live --camera URI --scene S [--record SEQ] [--headless --frames N --out DIR]
//
// The live pipeline: a camera through a capture session (newest frame wins), tracking on every
// frame taken, the photometry locked after a settle period, optional recording, reconnection with
// back-off when the camera is lost (pipeline/camera_source.h), and the window with its overlay and
// keys (pipeline/live_window.h). Tracking runs on the pipeline thread, compositing on this one
// (pipeline/frame_loop.h).
//
//   Step 1  scene, intrinsics, ground truth (optional), output files
//   Step 2  open the camera, the recording, the per-frame pipeline and the window
//   Step 3  the frames: FrameRunner::run (poses.csv on the pipeline thread, the window on this one)
//   Step 4  summary and metrics
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <memory>
#include <numbers>
#include <optional>

#include "apps/app.h"
#include "apps/quiet.h"
#include "apps/progress.h"
#include "apps/report.h"
#include "capture/stage_timings.h"
#include "core/calibration_io.h"
#include "core/clock.h"
#include "core/log.h"
#include "core/response.h"
#include "core/scene_io.h"
#include "core/sequence_io.h"
#include "pipeline/camera_source.h"
#include "pipeline/live_window.h"
#include "pipeline/runner.h"

namespace commonlight::apps {

namespace {

namespace fs = std::filesystem;

struct LiveOptions {
    std::string camera;
    std::string scene;
    std::string calib;
    std::string ground_truth;
    std::string record;
    std::string out;
    bool headless = false;
    std::uint64_t frames = 0;  // 0: until Ctrl-C
    double settle_s = 2.0;
    bool no_lock = false;
    bool no_reconnect = false;
    double reconnect_max_s = 60.0;
    double timeout_s = 5.0;
    bool edges = false;
    bool no_lighting = false;
    int lighting_every = 0;
    bool fixed_quality = false;
    bool full_frame = false;
    bool composite = false;    // --composite: headless runs composite offscreen too
    std::string screenshots;   // where key s writes (default: --out, else the current folder)
    std::string response;  // --response: overrides what the camera reports
    bool move_object = false;      // --move-object: virtual object 0 goes back and forth (soak tests)
    double metrics_interval_s = 0.0;  // --metrics-interval: a metrics line every S seconds (0: none)
};

// --move-object: virtual object 0 back and forth along world x, +-5 cm with a 4 s period, by the
// wall clock (a looping replay's timestamps start over). Main thread.
class ObjectMover {
public:
    void update(pipeline::FrameRunner& runner) {
        if (runner.scene().virtual_objects.empty()) return;
        const std::int64_t now = monotonicNowNs();
        if (start_ns_ == 0) start_ns_ = now;
        const double t = static_cast<double>(now - start_ns_) / 1e9;
        const double x = 0.05 * std::sin(2.0 * std::numbers::pi * t / 4.0);
        runner.moveVirtualObject(0, Eigen::Vector3d(x - applied_, 0.0, 0.0));
        applied_ = x;
    }

private:
    std::int64_t start_ns_ = 0;
    double applied_ = 0.0;
};

// --metrics-interval: every S seconds one line on stdout (flushed) with the frames the main thread
// took in that interval and their rate, the largest lighting lag of the interval (frame timestamp
// minus the snapshot's), the lighting version and the render module's live GL objects. Main thread.
class MetricsPrinter {
public:
    explicit MetricsPrinter(double interval_s) : interval_ns_(static_cast<std::int64_t>(interval_s * 1e9)) {}

    void onFrame(const pipeline::FrameRunner& runner) {
        ++frames_;
        const auto& info = runner.lastComposite();
        if (info.lighting_lag_ms) lag_ms_ = std::max(lag_ms_.value_or(-1e300), *info.lighting_lag_ms);
        if (info.lighting_lag_frames) lag_frames_ = std::max(lag_frames_.value_or(-1e300), *info.lighting_lag_frames);
        version_ = info.lighting_version;
        maybePrint();
    }
    void maybePrint() {
        const std::int64_t now = monotonicNowNs();
        if (start_ns_ == 0) start_ns_ = last_ns_ = now;
        if (now - last_ns_ < interval_ns_) return;
        const double dt = static_cast<double>(now - last_ns_) / 1e9;
        const render::GlObjectCounts gl = render::liveGlObjects();
        const long gl_total = gl.textures + gl.buffers + gl.framebuffers + gl.renderbuffers + gl.programs + gl.vertex_arrays;
        const auto opt = [](const std::optional<double>& v) { return v ? fmtNumber(*v) : std::string("nan"); };
        std::printf("metrics: t_s=%.1f frames=%llu fps=%.2f lag_ms_max=%s lag_frames_max=%s lighting_version=%llu "
                    "gl_objects=%ld gl_textures=%ld gl_buffers=%ld gl_framebuffers=%ld gl_renderbuffers=%ld "
                    "gl_programs=%ld gl_vertex_arrays=%ld\n",
                    static_cast<double>(now - start_ns_) / 1e9, static_cast<unsigned long long>(frames_),
                    static_cast<double>(frames_) / dt, opt(lag_ms_).c_str(), opt(lag_frames_).c_str(),
                    static_cast<unsigned long long>(version_), gl_total, gl.textures, gl.buffers, gl.framebuffers,
                    gl.renderbuffers, gl.programs, gl.vertex_arrays);
        std::fflush(stdout);
        last_ns_ = now;
        frames_ = 0;
        lag_ms_.reset();
        lag_frames_.reset();
    }

private:
    static std::string fmtNumber(double v) {
        char text[32];
        std::snprintf(text, sizeof text, "%.2f", v);
        return text;
    }
    std::int64_t interval_ns_;
    std::int64_t start_ns_ = 0, last_ns_ = 0;
    std::uint64_t frames_ = 0;
    std::optional<double> lag_ms_, lag_frames_;
    std::uint64_t version_ = 0;
};

std::string poseRow(std::int64_t timestamp_ns, const tracking::FrameTrack& track) {
    return std::to_string(timestamp_ns) + "," + tracking::trackStatusName(track.status) + "," +
           (track.cam_from_world ? poseColumns(*track.cam_from_world) : std::string(",,,,,,")) + "\n";
}

// Where key r records when --record was not given: DIR/live-YYYYMMDD-HHMMSS (DIR: --out, else the
// current folder).
fs::path defaultRecordFolder(const LiveOptions& options) {
    const std::time_t now = std::time(nullptr);
    std::tm local{};
    localtime_r(&now, &local);
    char name[32];
    std::strftime(name, sizeof name, "live-%Y%m%d-%H%M%S", &local);
    return (options.out.empty() ? fs::current_path() : fs::path(options.out)) / name;
}

int runLive(const LiveOptions& options) {
    // Step 1: scene, intrinsics, ground truth, outputs.
    auto scene = readScene(options.scene);
    if (!scene) return reportError(scene.error());
    std::optional<Sequence> truth_sequence;
    std::optional<pipeline::GroundTruth> truth;
    if (!options.ground_truth.empty()) {
        auto seq = readSequence(options.ground_truth);
        if (!seq) return reportError(seq.error());
        truth_sequence = std::move(*seq);
        auto t = pipeline::GroundTruth::fromSequence(*truth_sequence, /*by_content=*/true);
        if (!t) return reportError(t.error());
        truth = std::move(*t);
    }
    std::optional<CameraModel> intrinsics;
    if (!options.calib.empty()) {
        auto c = readCalibration(options.calib);
        if (!c) return reportError(c.error());
        intrinsics = *c;
    } else if (scene->camera) {
        intrinsics = scene->camera;
    }
    std::unique_ptr<std::FILE, int (*)(std::FILE*)> poses(nullptr, &std::fclose);
    if (!options.out.empty()) {
        std::error_code ec;
        fs::create_directories(options.out, ec);
        if (ec) return reportError(Error{ErrorCode::kIo, options.out + ": cannot create the folder: " + ec.message()});
        const fs::path file = fs::path(options.out) / "poses.csv";
        poses.reset(std::fopen(file.c_str(), "w"));
        if (!poses) return reportError(Error{ErrorCode::kIo, file.string() + ": cannot create the file"});
        std::fprintf(poses.get(), "timestamp_ns,status,tx,ty,tz,qw,qx,qy,qz\n");
    }

    // Step 2: the camera (reopened with back-off when lost), its recording, the pipeline.
    const hal::CameraRegistry registry = makeCameraRegistry();
    pipeline::CameraSourceOptions camera_options;
    camera_options.uri = options.camera;
    camera_options.frames = options.frames;
    camera_options.timeout_s = options.timeout_s;
    camera_options.reconnect = !options.no_reconnect;
    camera_options.reconnect_max_s = options.reconnect_max_s;
    camera_options.lock_photometry = !options.no_lock;
    camera_options.settle_s = options.settle_s;
    auto camera = pipeline::CameraSource::open(registry, camera_options);
    if (!camera) return reportError(camera.error());
    const hal::StreamFormat format = (*camera)->format();
    // Without --calib or the scene's camera: what the camera source knows (a recording's
    // sensor.yaml, the simulated lens), else the ground-truth recording's (a served recording).
    if (!intrinsics) intrinsics = (*camera)->calibration();
    if (!intrinsics && truth_sequence && truth_sequence->sensor.camera) intrinsics = truth_sequence->sensor.camera;
    if (!intrinsics) {
        return reportError(Error{ErrorCode::kUsage, options.camera + " does not report its calibration: give --calib "
                                                                     "(or a scene with camera:)"});
    }
    if (format.width != intrinsics->width || format.height != intrinsics->height) {
        return reportError(Error{ErrorCode::kUsage, options.camera + " streams " + hal::describe(format) +
                                                        " but the calibration is " + std::to_string(intrinsics->width) +
                                                        "x" + std::to_string(intrinsics->height)});
    }
    SensorInfo sensor;
    sensor.rate_hz = format.fps;
    sensor.camera = *intrinsics;
    sensor.comment = "recorded by commonlight live from " + options.camera;
    if (!options.record.empty()) {
        if (auto started = (*camera)->startRecording(options.record, sensor); !started) return reportError(started.error());
    }
    // The per-frame pipeline (pipeline/runner.h) with the lighting thread in real time (newest
    // wins, it never holds the frames back). The response: --response, else what the camera
    // reports (Aravis: its Gamma feature; replay: the recording's sensor.yaml).
    pipeline::RunnerOptions runner_options;
    runner_options.tracker.edges = options.edges;
    runner_options.ground_truth = truth ? &*truth : nullptr;
    runner_options.lighting = !options.no_lighting;
    runner_options.lighting_every = options.lighting_every;
    runner_options.adapt_quality = !options.fixed_quality;
    runner_options.tracker.tracking_mode = !options.full_frame;
    {
        const std::string spec = options.response.empty() ? (*camera)->responseSpec() : options.response;
        auto response = ResponseCurve::parse(spec, fs::current_path());
        if (!response) return reportError(Error{response.error().code, "response '" + spec + "': " + response.error().message});
        runner_options.response = *response;
    }
    if (truth_sequence) runner_options.radiance_scale = truth_sequence->sensor.radiance_scale;
    runner_options.composite = !options.headless || options.composite;
    runner_options.context = options.headless ? render::ContextKind::kOffscreen : render::ContextKind::kWindow;
    runner_options.fps = format.fps > 0.0 ? format.fps : 30.0;
    auto runner = pipeline::FrameRunner::create(*scene, *intrinsics, runner_options);
    if (!runner) return reportError(runner.error());
    // A new connection's timestamps may start over: the tracking restarts (pipeline thread).
    (*camera)->setOnReconnect([r = runner->get()] { return r->restart(); });
    std::unique_ptr<pipeline::LiveWindow> window;
    if (!options.headless) {
        pipeline::LiveWindowOptions window_options;
        window_options.screenshots = !options.screenshots.empty() ? fs::path(options.screenshots)
                                     : !options.out.empty()        ? fs::path(options.out)
                                                                   : fs::current_path();
        window_options.record = !options.record.empty() ? fs::path(options.record) : defaultRecordFolder(options);
        window_options.sensor = sensor;
        auto created = pipeline::LiveWindow::create(**runner, **camera, window_options);
        if (!created) return reportError(created.error());
        window = std::move(*created);
        if (options.record.empty()) log::info("key r records to " + window_options.record.string());
    }
    say("live: %s (%s), scene %s%s\n", options.camera.c_str(), hal::describe(format).c_str(),
                options.scene.c_str(), options.record.empty() ? "" : (", recording to " + options.record).c_str());
    if ((*runner)->lighting()) say("lighting: real time, response %s\n", runner_options.response.name().c_str());

    // Step 3: the frames. The pipeline thread takes them from the camera, tracks them and writes
    // poses.csv; this thread composites the newest and runs the window.
    Progress progress("live", options.frames);
    pipeline::LoopCallbacks callbacks;
    callbacks.on_tracked = [&](const pipeline::TrackedFrame& frame) {
        if (poses) {
            std::fputs(poseRow(frame.meta.timestamp_ns, frame.track).c_str(), poses.get());
            std::fflush(poses.get());  // readable as it grows
        }
        progress.update(frame.index + 1);
    };
    bool warned_bad = false;
    callbacks.on_bad_frame = [&warned_bad](const Frame& frame, const Error& error) {
        if (!warned_bad) log::warning("frame " + std::to_string(frame.meta.timestamp_ns) + ": " + error.message);
        warned_bad = true;
    };
    std::optional<ObjectMover> mover;
    if (options.move_object) mover.emplace();
    std::optional<MetricsPrinter> metrics_printer;
    if (options.metrics_interval_s > 0.0) metrics_printer.emplace(options.metrics_interval_s);
    if (window || mover || metrics_printer) {
        pipeline::FrameRunner* r = runner->get();
        callbacks.on_frame = [&window, &mover, &metrics_printer, r](const pipeline::TrackedFrame& frame) {
            if (mover) mover->update(*r);
            if (metrics_printer) metrics_printer->onFrame(*r);
            return window ? window->onFrame(frame) : true;
        };
        callbacks.on_idle = [&window, &metrics_printer](const pipeline::TrackedFrame* last) {
            if (metrics_printer) metrics_printer->maybePrint();
            return window ? window->onIdle(last) : true;
        };
    }
    const std::int64_t start_ns = monotonicNowNs();
    const pipeline::LoopStats loop = (*runner)->run(**camera, callbacks, stopToken());
    (*runner)->stop();
    progress.finish();
    const double seconds = static_cast<double>(monotonicNowNs() - start_ns) / 1e9;
    const pipeline::CameraTotals totals = (*camera)->finish();
    const std::optional<capture::RecorderSummary> recorded = (*camera)->stopRecording();
    window.reset();

    // Step 4: report.
    const capture::StageTimings& timings = (*runner)->timings();
    say("live: %llu frames in %.2f s (%.2f per s); %llu reconnects\n", static_cast<unsigned long long>(totals.taken),
                seconds, seconds > 0 ? static_cast<double>(totals.taken) / seconds : 0.0,
                static_cast<unsigned long long>(totals.reconnects));
    say("  dropped   at the device %llu, no free buffer %llu, replaced in the mailbox %llu; corrupt %llu; "
                "not trackable %llu\n",
                static_cast<unsigned long long>(totals.device), static_cast<unsigned long long>(totals.no_slot),
                static_cast<unsigned long long>(totals.mailbox), static_cast<unsigned long long>(totals.corrupt),
                static_cast<unsigned long long>(loop.bad_frames));
    say("  latency   p50 %.3f ms, p95 %.3f ms (last connection, frame arrival to hand-over)\n", totals.last.latency_ms.p50,
                totals.last.latency_ms.p95);
    if (runner_options.composite) {
        say("  composited %llu of %llu frames tracked (%llu replaced by newer ones before the compositor took them)\n",
                    static_cast<unsigned long long>(loop.composited), static_cast<unsigned long long>(loop.tracked),
                    static_cast<unsigned long long>(loop.replaced));
    }
    if (!quiet()) printStages(timings);
    say("tracked: %llu of %llu frames with a camera pose\n",
                static_cast<unsigned long long>((*runner)->tracking().framesWithPose()), static_cast<unsigned long long>(totals.taken));
    say("%s", (*runner)->summary().c_str());
    if (truth) {
        if ((*runner)->tracking().framesWithoutTruth() > 0) {
            log::warning(std::to_string((*runner)->tracking().framesWithoutTruth()) + " frames matched no frame of " +
                         options.ground_truth + " (not bit-identical to the recording)");
        }
    }
    if (recorded) {
        say("recorded %zu frames to %s (dropped by the recorder %llu, refused by the sequence %llu)\n",
                    recorded->frames_written, recorded->root.c_str(), static_cast<unsigned long long>(recorded->dropped),
                    static_cast<unsigned long long>(recorded->rejected));
        if (recorded->first_rejection) log::warning(recorded->first_rejection->message);
    }
    if (!options.out.empty()) {
        nlohmann::json metrics = captureJson(totals.last);
        metrics["frames"] = totals.taken;
        metrics["frames_received"] = totals.received;
        metrics["dropped_frames"] = totals.device + totals.no_slot + totals.mailbox;
        metrics["dropped"] = {{"device", totals.device}, {"no_slot", totals.no_slot}, {"mailbox", totals.mailbox}};
        metrics["corrupt_frames"] = totals.corrupt;
        metrics["reconnects"] = totals.reconnects;
        metrics["camera"] = options.camera;
        metrics["duration_s"] = seconds;
        metrics["stages_ms"] = stagesJson(timings);
        metrics.update((*runner)->metricsJson());
        const fs::path file = fs::path(options.out) / "metrics.json";
        if (auto written = writeJson(file, metrics); !written) return reportError(written.error());
        say("metrics written to %s\n", file.c_str());
    }
    if (recorded && recorded->write_error) return reportError(*recorded->write_error);
    if (loop.failure) {
        if (recorded) log::info("the recording holds every frame received before the error");
        return reportError(*loop.failure);
    }
    return stopToken().stop_requested() ? 130 : kExitOk;
}

}  // namespace

void addLiveCommand(CLI::App& app, Runner& runner) {
    auto options = std::make_shared<LiveOptions>();
    CLI::App* sub = app.add_subcommand("live", "The live pipeline on a camera: tracking, lighting and the AR window");
    sub->add_option("--camera", options->camera, "Camera URI, e.g. v4l2:/dev/video0, aravis:192.168.1.20 (docs/cli.md)")->required();
    sub->add_option("--scene", options->scene, "Scene file: tags, proxies, lights, virtual objects")->required();
    sub->add_option("--calib", options->calib, "Camera calibration (OpenCV or ROS YAML); default: the scene's camera:");
    sub->add_option("--ground-truth", options->ground_truth,
                    "A recorded sequence the camera serves bit-exactly (serve-gige): frames are matched by their pixels "
                    "and the pose error is reported");
    sub->add_option("--record", options->record,
                    "Record the camera's frames to this new sequence folder from the start (the window's key r stops "
                    "and restarts recording: SEQ-2, SEQ-3, ...)");
    sub->add_flag("--headless", options->headless, "No window: process and report (poses, metrics, --record)");
    sub->add_flag("--composite", options->composite, "With --headless: composite offscreen too (the metrics gain the compositor's)");
    sub->add_option("--screenshots", options->screenshots, "Folder for the window's screenshots (key s; default --out or .)");
    sub->add_option("--frames", options->frames, "Stop after N frames (default: until Ctrl-C or the stream ends)");
    sub->add_option("--out", options->out, "Folder for metrics.json and poses.csv");
    sub->add_option("--settle", options->settle_s, "Seconds of auto exposure before the photometry is locked")
        ->check(CLI::NonNegativeNumber)
        ->capture_default_str();
    sub->add_flag("--no-lock", options->no_lock, "Leave auto exposure and auto white balance as the camera has them");
    sub->add_flag("--no-reconnect", options->no_reconnect, "End with the device error instead of reconnecting");
    sub->add_option("--reconnect-max", options->reconnect_max_s, "Seconds to keep trying to reconnect (back-off 0.25 s to 8 s)")
        ->check(CLI::PositiveNumber)
        ->capture_default_str();
    sub->add_option("--timeout", options->timeout_s, "Seconds without a frame before the camera counts as lost")
        ->check(CLI::PositiveNumber)
        ->capture_default_str();
    sub->add_flag("--edges", options->edges, "Refine the pose with the edges of the scene's proxy geometry");
    sub->add_flag("--no-lighting", options->no_lighting, "Track only; no lighting thread");
    addRealTimeOptions(*sub, options->lighting_every, options->fixed_quality);
    sub->add_flag("--full-frame", options->full_frame, "Detect tags over the whole of every frame (default: around the predicted tags, whole frame every 15)");
    sub->add_flag("--move-object", options->move_object,
                  "Move the first virtual object back and forth along world x (+-5 cm, 4 s period), e.g. headless soak tests");
    sub->add_option("--metrics-interval", options->metrics_interval_s,
                    "Print a metrics line every S seconds: fps, lighting lag, live GL objects (scripts/soak reads it)")
        ->check(CLI::NonNegativeNumber);
    sub->add_option("--response", options->response,
                    "The camera's response: srgb, linear, gamma:G or a response file (default: what the camera reports)");
    sub->footer("Exit codes: 0 ok, 2 usage, 3 bad input, 4 device error (after the reconnection attempts), 130 Ctrl-C");
    sub->callback([options, &runner] { runner = [options] { return runLive(*options); }; });
}

}  // namespace commonlight::apps

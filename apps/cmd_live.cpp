// commonlight live --camera URI --scene S [--record SEQ] [--headless --frames N --out DIR]
//
// The live pipeline: a camera through a capture session (newest frame wins), tracking on every
// frame taken, the photometry locked after a settle period, optional recording, and reconnection
// with back-off when the camera is lost.
//
//   Step 1  scene, intrinsics, ground truth (optional), output files
//   Step 2  open the camera and start a session; on a device error, retry with back-off
//   Step 3  per frame: record, track, lock the photometry once settled, write the pose
//   Step 4  summary and metrics
#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <mutex>
#include <thread>

#include "apps/app.h"
#include "core/response.h"
#include "pipeline/runner.h"
#include "apps/progress.h"
#include "apps/report.h"
#include "capture/capture_session.h"
#include "capture/photometry_lock.h"
#include "capture/recorder.h"
#include "capture/stage_timings.h"
#include "core/calibration_io.h"
#include "core/clock.h"
#include "core/log.h"
#include "core/scene_io.h"
#include "core/sequence_io.h"
#include "render/compositor.h"

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
    bool composite = false;    // --composite: headless runs composite offscreen too
    std::string screenshots;   // where key s writes (default: --out, else the current folder)
    std::string response;  // --response: overrides what the camera reports
};

// Sleeps up to `seconds`, waking early on Ctrl-C. False when stopped.
bool sleepUnlessStopped(double seconds) {
    std::mutex mutex;
    std::condition_variable_any cv;
    std::unique_lock lock(mutex);
    std::stop_token stop = stopToken();
    return !cv.wait_for(lock, stop, std::chrono::duration<double>(seconds), [] { return false; });
}

// Sums of the sessions' statistics (one session per connection).
struct Totals {
    std::uint64_t received = 0, delivered = 0, device = 0, no_slot = 0, mailbox = 0, corrupt = 0;
    void add(const capture::CaptureStats& s) {
        received += s.frames_received;
        delivered += s.frames_delivered;
        device += s.drops.device;
        no_slot += s.drops.no_slot;
        mailbox += s.drops.mailbox;
        corrupt += s.drops.corrupt;
    }
};

Result<std::unique_ptr<capture::CaptureSession>> connect(const hal::CameraRegistry& registry, const std::string& uri) {
    CL_TRY(std::unique_ptr<hal::Camera> camera, registry.openConfigured(uri));
    capture::CaptureOptions capture_options;  // newest wins: a live camera never waits for us
    CL_TRY(std::unique_ptr<capture::CaptureSession> session,
           capture::CaptureSession::create(std::move(camera), capture_options));
    CL_TRY_VOID(session->start());
    return session;
}

std::string poseRow(std::int64_t timestamp_ns, const tracking::FrameTrack& track) {
    return std::to_string(timestamp_ns) + "," + tracking::trackStatusName(track.status) + "," +
           (track.cam_from_world ? poseColumns(*track.cam_from_world) : std::string(",,,,,,")) + "\n";
}

// The window's state between frames: selection, pause, screenshots.
struct WindowKeys {
    std::size_t selected = 0;
    bool lighting_shown = true;
    bool paused = false;
    int screenshot_count = 0;
    fs::path screenshots;
};

// Shows the frame's composite, handles the keys (docs/cli.md): space pause, l lighting on/off,
// d next debug view, s screenshot, tab next virtual object, arrows and page up/down move it by
// 1 cm. The title carries the overlay's figures. False when the window was closed.
bool handleWindow(render::GlContext& window, pipeline::FrameRunner& runner, const tracking::FrameTrack& track,
                  WindowKeys& keys) {
    do {
        for (int key : window.pollKeys()) {
            const double step = 0.01;
            Eigen::Vector3d move = Eigen::Vector3d::Zero();
            switch (key) {
                case 32: keys.paused = !keys.paused; break;                                    // space
                case 'L': keys.lighting_shown = !keys.lighting_shown; runner.setLightingShown(keys.lighting_shown); break;
                case 'D':
                    if (render::Compositor* c = runner.compositor()) {
                        render::CompositorOptions o = c->options();
                        o.debug = render::nextDebugView(o.debug);
                        c->setOptions(o);
                        log::info(std::string("view: ") + render::debugViewName(o.debug));
                    }
                    break;
                case 'S': {
                    auto shot = window.readWindow();
                    const fs::path file = keys.screenshots / ("screenshot-" + std::to_string(keys.screenshot_count++) + ".png");
                    if (shot && pipeline::writePng(file, shot->view())) {
                        log::info("screenshot: " + file.string());
                    } else {
                        log::warning("cannot write the screenshot " + file.string());
                    }
                    break;
                }
                case 258:  // tab
                    if (!runner.scene().virtual_objects.empty()) {
                        keys.selected = (keys.selected + 1) % runner.scene().virtual_objects.size();
                        log::info("selected: " + runner.scene().virtual_objects[keys.selected].name);
                    }
                    break;
                case 262: move.x() = step; break;   // right
                case 263: move.x() = -step; break;  // left
                case 265: move.y() = step; break;   // up
                case 264: move.y() = -step; break;  // down
                case 266: move.z() = step; break;   // page up
                case 267: move.z() = -step; break;  // page down
                default: break;
            }
            if (!move.isZero()) runner.moveVirtualObject(keys.selected, move);
        }
        if (window.shouldClose()) return false;
        if (keys.paused) std::this_thread::sleep_for(std::chrono::milliseconds(30));
    } while (keys.paused);
    // The overlay: fps, latency, tracking state, lighting version and lag.
    char title[256];
    const lighting::SnapshotPtr snapshot = runner.lighting() ? runner.lighting()->latest() : nullptr;
    const capture::Percentiles composite = runner.timings().percentiles(runner.timings().id("pipeline"));
    std::snprintf(title, sizeof title, "commonlight | %s | pipeline p50 %.0f ms | lighting v%llu%s | %s",
                  tracking::trackStatusName(track.status), composite.p50,
                  static_cast<unsigned long long>(snapshot ? snapshot->version : 0), keys.lighting_shown ? "" : " (off)",
                  render::debugViewName(runner.compositor() ? runner.compositor()->options().debug : render::DebugView::kNone));
    window.setTitle(title);
    window.present();
    return true;
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
    } else if (truth_sequence && truth_sequence->sensor.camera) {
        intrinsics = truth_sequence->sensor.camera;  // the served recording's camera
    }
    if (!intrinsics) {
        return reportError(Error{ErrorCode::kUsage, "no camera calibration: give --calib (or a scene with camera:)"});
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

    // Step 2: the camera.
    const hal::CameraRegistry registry = makeCameraRegistry();
    auto session = connect(registry, options.camera);
    if (!session) return reportError(session.error());
    const hal::StreamFormat format = (*session)->camera().activeFormat();
    if (format.width != intrinsics->width || format.height != intrinsics->height) {
        return reportError(Error{ErrorCode::kUsage, options.camera + " streams " + hal::describe(format) +
                                                        " but the calibration is " + std::to_string(intrinsics->width) +
                                                        "x" + std::to_string(intrinsics->height)});
    }
    std::unique_ptr<capture::Recorder> recorder;
    if (!options.record.empty()) {
        SensorInfo sensor;
        sensor.rate_hz = format.fps;
        sensor.camera = *intrinsics;
        sensor.comment = "recorded by commonlight live from " + options.camera;
        auto r = capture::Recorder::start(options.record, sensor);
        if (!r) return reportError(r.error());
        recorder = std::move(*r);
    }
    // Step 2b: the per-frame pipeline (pipeline/runner.h) with the lighting thread in real time
    // (newest wins, it never holds the frames back). The response: --response, else what the
    // camera reports (Aravis: its Gamma feature; replay: the recording's sensor.yaml).
    pipeline::RunnerOptions runner_options;
    runner_options.tracker.edges = options.edges;
    runner_options.ground_truth = truth ? &*truth : nullptr;
    runner_options.lighting = !options.no_lighting;
    {
        const std::string spec = options.response.empty() ? (*session)->camera().responseSpec() : options.response;
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
    capture::StageTimings& timings = (*runner)->timings();
    render::GlContext* window = (*runner)->glContext();
    if (window && window->kind() != render::ContextKind::kWindow) window = nullptr;
    WindowKeys keys;
    keys.screenshots = !options.screenshots.empty() ? fs::path(options.screenshots)
                       : !options.out.empty()        ? fs::path(options.out)
                                                     : fs::current_path();
    std::printf("live: %s (%s), scene %s%s\n", options.camera.c_str(), hal::describe(format).c_str(),
                options.scene.c_str(), options.record.empty() ? "" : (", recording to " + options.record).c_str());
    if ((*runner)->lighting()) std::printf("lighting: real time, response %s\n", runner_options.response.name().c_str());

    // Step 3: the frames.
    capture::PhotometryLock photometry(static_cast<std::int64_t>(options.settle_s * 1e9));
    const auto timeout = std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::duration<double>(options.timeout_s));
    Totals totals;
    std::uint64_t taken = 0, reconnects = 0, bad_frames = 0;
    std::optional<Error> failure;
    Progress progress("live", options.frames);
    const std::int64_t start_ns = monotonicNowNs();
    while (options.frames == 0 || taken < options.frames) {
        capture::NextFrame next = (*session)->next(stopToken(), timeout);
        if (next && !next->has_value()) break;  // the stream ended (a recording's end)
        if (!next) {
            if (next.error().code == ErrorCode::kCancelled) break;
            Error lost = next.error();
            if (lost.code == ErrorCode::kTimeout) {
                lost = Error{ErrorCode::kDevice, options.camera + ": no frame for " + std::to_string(options.timeout_s) + " s"};
            }
            log::error("camera lost: " + lost.message);
            (*session)->stop();
            totals.add((*session)->stats());
            session->reset();
            if (options.no_reconnect) {
                failure = lost;
                break;
            }
            // Back-off: 0.25 s doubling to 8 s, until the camera is back or reconnect_max_s passed.
            double backoff = 0.25;
            const std::int64_t lost_ns = monotonicNowNs();
            while (true) {
                if (!sleepUnlessStopped(backoff)) break;
                auto again = connect(registry, options.camera);
                if (again) {
                    session = std::move(again);
                    break;
                }
                const double waited = static_cast<double>(monotonicNowNs() - lost_ns) / 1e9;
                log::warning("reconnecting to " + options.camera + " failed after " + std::to_string(waited) +
                             " s: " + again.error().message);
                if (waited >= options.reconnect_max_s) break;
                backoff = std::min(backoff * 2.0, 8.0);
            }
            if (!*session) {
                if (!stopToken().stop_requested()) {
                    failure = Error{ErrorCode::kDevice, options.camera + ": lost and not back within " +
                                                            std::to_string(options.reconnect_max_s) + " s (" + lost.message + ")"};
                }
                break;
            }
            ++reconnects;
            photometry.reset();
            if (auto restarted = (*runner)->restart(); !restarted) return reportError(restarted.error());
            log::info("reconnected to " + options.camera);
            continue;
        }
        FrameHandle frame = std::move(**next);
        ++taken;
        progress.update(taken);
        if (recorder) recorder->push(*frame);
        if (!options.no_lock) {
            auto locked = photometry.onFrame((*session)->camera(), frame->meta.arrival_ns);
            if (!locked) {
                log::warning("cannot lock the photometry: " + locked.error().message);
            } else if (*locked) {
                char settled[32];
                std::snprintf(settled, sizeof settled, "%.1f s", options.settle_s);
                log::info(std::string("photometry locked after ") + settled + ": " + (*locked)->describe());
            }
        }
        if (frame->meta.status != FrameStatus::kOk) continue;  // counted by the session
        auto tracked = (*runner)->process(*frame);
        if (!tracked) {
            if (tracked.error().code != ErrorCode::kBadInput) {
                failure = tracked.error();
                break;
            }
            if (bad_frames++ == 0) log::warning("frame " + std::to_string(frame->meta.timestamp_ns) + ": " + tracked.error().message);
            continue;
        }
        if (poses) std::fputs(poseRow(frame->meta.timestamp_ns, *tracked).c_str(), poses.get());
        if (window && !handleWindow(*window, **runner, *tracked, keys)) break;
    }
    (*runner)->stop();
    progress.finish();
    const double seconds = static_cast<double>(monotonicNowNs() - start_ns) / 1e9;
    capture::CaptureStats last;
    if (*session) {
        (*session)->stop();
        last = (*session)->stats();
        totals.add(last);
    }
    std::optional<capture::RecorderSummary> recorded;
    if (recorder) recorded = recorder->finish();

    // Step 4: report.
    std::printf("live: %llu frames in %.2f s (%.2f per s); %llu reconnects\n", static_cast<unsigned long long>(taken),
                seconds, seconds > 0 ? static_cast<double>(taken) / seconds : 0.0,
                static_cast<unsigned long long>(reconnects));
    std::printf("  dropped   at the device %llu, no free buffer %llu, replaced in the mailbox %llu; corrupt %llu; "
                "not trackable %llu\n",
                static_cast<unsigned long long>(totals.device), static_cast<unsigned long long>(totals.no_slot),
                static_cast<unsigned long long>(totals.mailbox), static_cast<unsigned long long>(totals.corrupt),
                static_cast<unsigned long long>(bad_frames));
    std::printf("  latency   p50 %.3f ms, p95 %.3f ms (last connection, frame arrival to hand-over)\n", last.latency_ms.p50,
                last.latency_ms.p95);
    printStages(timings);
    std::printf("tracked: %llu of %llu frames with a camera pose\n",
                static_cast<unsigned long long>((*runner)->tracking().framesWithPose()), static_cast<unsigned long long>(taken));
    std::printf("%s", (*runner)->summary().c_str());
    if (truth) {
        if ((*runner)->tracking().framesWithoutTruth() > 0) {
            log::warning(std::to_string((*runner)->tracking().framesWithoutTruth()) + " frames matched no frame of " +
                         options.ground_truth + " (not bit-identical to the recording)");
        }
    }
    if (recorded) {
        std::printf("recorded %zu frames to %s (dropped by the recorder %llu, refused by the sequence %llu)\n",
                    recorded->frames_written, options.record.c_str(), static_cast<unsigned long long>(recorded->dropped),
                    static_cast<unsigned long long>(recorded->rejected));
        if (recorded->first_rejection) log::warning(recorded->first_rejection->message);
    }
    if (!options.out.empty()) {
        nlohmann::json metrics = captureJson(last);
        metrics["frames"] = taken;
        metrics["frames_received"] = totals.received;
        metrics["dropped_frames"] = totals.device + totals.no_slot + totals.mailbox;
        metrics["dropped"] = {{"device", totals.device}, {"no_slot", totals.no_slot}, {"mailbox", totals.mailbox}};
        metrics["corrupt_frames"] = totals.corrupt;
        metrics["reconnects"] = reconnects;
        metrics["camera"] = options.camera;
        metrics["duration_s"] = seconds;
        metrics["stages_ms"] = stagesJson(timings);
        metrics.update((*runner)->metricsJson());
        const fs::path file = fs::path(options.out) / "metrics.json";
        if (auto written = writeJson(file, metrics); !written) return reportError(written.error());
        std::printf("metrics written to %s\n", file.c_str());
    }
    if (recorded && recorded->write_error) return reportError(*recorded->write_error);
    if (failure) {
        if (recorder) log::info("the recording holds every frame received before the error");
        return reportError(*failure);
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
    sub->add_option("--record", options->record, "Also record the camera's frames to this new sequence folder");
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
    sub->add_option("--response", options->response,
                    "The camera's response: srgb, linear, gamma:G or a response file (default: what the camera reports)");
    sub->footer("Exit codes: 0 ok, 2 usage, 3 bad input, 4 device error (after the reconnection attempts), 130 Ctrl-C");
    sub->callback([options, &runner] { runner = [options] { return runLive(*options); }; });
}

}  // namespace commonlight::apps

#include "apps/bench_pipeline.h"

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cstdio>
#include <memory>

#include "apps/app.h"
#include "apps/report.h"
#include "capture/capture_session.h"
#include "capture/percentiles.h"
#include "core/clock.h"
#include "core/log.h"
#include "core/scene_io.h"
#include "mocks/replay_camera.h"
#include "pipeline/runner.h"

namespace commonlight::apps {

namespace {

namespace fs = std::filesystem;

struct Loaded {
    Sequence sequence;
    Scene scene;
    CameraModel camera;
    ResponseCurve response;
    std::optional<pipeline::GroundTruth> truth;
};

Result<Loaded> load(const fs::path& path) {
    Loaded l;
    CL_TRY(l.sequence, readSequence(path));
    const std::optional<fs::path> scene_path = l.sequence.scenePath();
    if (!scene_path) return fail(ErrorCode::kBadInput, path.string() + ": no scene.yaml (the benchmark needs proxies and tags)");
    CL_TRY(l.scene, readScene(*scene_path));
    if (!l.sequence.sensor.camera) return fail(ErrorCode::kBadInput, path.string() + ": sensor.yaml has no intrinsics");
    l.camera = *l.sequence.sensor.camera;
    CL_TRY(l.response, pipeline::sequenceResponse(l.sequence, ""));
    if (!l.sequence.groundtruth_poses.empty()) {
        CL_TRY(pipeline::GroundTruth t, pipeline::GroundTruth::fromSequence(l.sequence, false));
        l.truth = std::move(t);
    }
    return l;
}

// Plays the sequence through a runner (sync: every frame; else at the recorded rate). Returns
// the metrics (play's keys) and the wall time.
// With `seconds` > 0 the recording loops until that much time has passed (real time).
Result<nlohmann::json> playThrough(const Loaded& l, const pipeline::RunnerOptions& base, bool sync,
                                   std::shared_ptr<const lighting::LightingSnapshot>* last_snapshot = nullptr,
                                   double seconds_limit = 0.0) {
    mocks::PlaybackOptions playback;
    playback.rate = sync ? mocks::PlaybackRate::kMax : mocks::PlaybackRate::kRealtime;
    playback.loop = seconds_limit > 0.0;
    CL_TRY(std::unique_ptr<mocks::ReplayCamera> replay, mocks::ReplayCamera::open(l.sequence.root, playback, SteadyClock::instance()));
    CL_TRY_VOID(replay->configure({}));
    capture::CaptureOptions capture_options;
    capture_options.sync = sync;
    CL_TRY(std::unique_ptr<capture::CaptureSession> session, capture::CaptureSession::create(std::move(replay), capture_options));
    pipeline::RunnerOptions options = base;
    options.sync = sync;
    // The comparison with ground truth (files read per frame) only where its figures are wanted:
    // every frame in order; in real time it would take the compositor's time.
    options.sequence = sync ? &l.sequence : nullptr;
    options.response = l.response;
    options.radiance_scale = l.sequence.sensor.radiance_scale;
    options.ground_truth = l.truth ? &*l.truth : nullptr;
    CL_TRY(std::unique_ptr<pipeline::FrameRunner> runner, pipeline::FrameRunner::create(l.scene, l.camera, options));
    CL_TRY_VOID(session->start());
    const std::int64_t start = monotonicNowNs();
    // The session's frames, until the time is up.
    struct TimedSource final : pipeline::FrameSource {
        pipeline::SessionSource session;
        std::int64_t end_ns;
        TimedSource(capture::CaptureSession& s, std::int64_t end) : session(s, std::chrono::seconds(20)), end_ns(end) {}
        Result<std::optional<FrameHandle>> next(std::stop_token stop) override {
            if (end_ns > 0 && monotonicNowNs() >= end_ns) return std::optional<FrameHandle>();
            return session.next(stop);
        }
    } source(*session, seconds_limit > 0.0 ? start + static_cast<std::int64_t>(seconds_limit * 1e9) : 0);
    const pipeline::LoopStats loop = runner->run(source, {}, stopToken());
    if (loop.failure) return fail(*loop.failure);
    const std::uint64_t processed = loop.composited;
    const double seconds = static_cast<double>(monotonicNowNs() - start) / 1e9;
    session->stop();
    runner->stop();
    if (last_snapshot && runner->lighting()) *last_snapshot = runner->lighting()->latest();
    nlohmann::json m = captureJson(session->stats());
    m.update(runner->metricsJson());
    m["stages_ms"] = stagesJson(runner->timings());
    m["processed"] = processed;
    m["tracked"] = loop.tracked;
    m["duration_s"] = seconds;
    m["processed_fps"] = seconds > 0 ? static_cast<double>(processed) / seconds : 0.0;
    m["tracked_fps"] = seconds > 0 ? static_cast<double>(loop.tracked) / seconds : 0.0;
    return m;
}

}  // namespace

bool wants(const BenchPipelineOptions& options, const std::string& name) {
    return options.cases.empty() || std::find(options.cases.begin(), options.cases.end(), name) != options.cases.end();
}

int runBenchPipeline(const BenchPipelineOptions& options) {
    auto loaded = load(options.sequence);
    if (!loaded) return reportError(loaded.error());
    const Loaded& l = *loaded;
    nlohmann::json out;
    out["sequence"] = options.sequence.string();

    std::shared_ptr<const lighting::LightingSnapshot> snapshot;  // the system case's, for the compositor case
    // Case system: every frame, lighting on/off, MSAA 4/1.
    if (wants(options, "system")) {
        std::printf("== system (every frame of %s, against groundtruth/composite)\n", options.sequence.c_str());
        std::printf("  %-26s %9s %12s %12s %12s %12s\n", "configuration", "PSNR dB", "RMSE frame", "RMSE changed", "composite ms",
                    "lighting ms");
        struct Config {
            const char* name;
            bool lighting;
            int msaa;
        };
        nlohmann::json system = nlohmann::json::array();
        for (const Config& c : {Config{"lighting on, MSAA 4", true, 4}, Config{"lighting on, no MSAA", true, 1},
                                Config{"lighting off, MSAA 4", false, 4}}) {
            pipeline::RunnerOptions r;
            r.lighting = c.lighting;
            r.composite = true;
            r.compositor.msaa_samples = c.msaa;
            auto m = playThrough(l, r, true, c.lighting && !snapshot ? &snapshot : nullptr);
            if (!m) return reportError(m.error());
            const nlohmann::json e = m->value("composite_error", nlohmann::json::object());
            const nlohmann::json st = (*m)["stages_ms"];
            const double comp = st.contains("composite") ? st["composite"]["p50"].get<double>() : 0.0;
            const double lit = st.contains("lighting") ? st["lighting"]["p50"].get<double>() : 0.0;
            std::printf("  %-26s %9.2f %12.4f %12.4f %12.1f %12.1f\n", c.name, e.value("psnr_db", 0.0), e.value("rmse_linear", 0.0),
                        e.value("rmse_linear_changed", 0.0), comp, lit);
            system.push_back({{"configuration", c.name}, {"lighting", c.lighting}, {"msaa", c.msaa}, {"composite_error", e},
                              {"stages_ms", st}, {"lighting_metrics", m->value("lighting", nlohmann::json())}});
        }
        out["system"] = system;
    }

    // Case compositor: draw + read back at two sizes.
    if (wants(options, "compositor")) {
        std::printf("== compositor (draw and read back, the sample's snapshot)\n");
        const std::int64_t frame_ts = l.sequence.frames[std::min<std::size_t>(30, l.sequence.frames.size() - 1)].timestamp_ns;
        std::optional<Rigid3d> world_from_cam = l.truth ? l.truth->atTimestamp(frame_ts) : std::nullopt;
        const cv::Mat bgr = cv::imread((l.sequence.cam_dir / "data" / l.sequence.frames[std::min<std::size_t>(30, l.sequence.frames.size() - 1)].filename).string());
        if (bgr.empty() || !world_from_cam) return reportError(Error{ErrorCode::kBadInput, options.sequence.string() + ": frame 30 or its ground truth is missing"});
        nlohmann::json compositor = nlohmann::json::array();
        auto context = render::GlContext::create({});
        if (!context) return reportError(context.error());
        for (const auto& [w, h] : {std::pair{640, 480}, std::pair{1280, 720}}) {
            for (int msaa : {4, 1}) {
                const CameraModel camera = l.camera.scaledTo(w, h);
                cv::Mat resized, rgb;
                cv::resize(bgr, resized, cv::Size(w, h), 0, 0, cv::INTER_AREA);
                cv::cvtColor(resized, rgb, cv::COLOR_BGR2RGB);
                render::CompositorOptions co;
                co.msaa_samples = msaa;
                auto c = render::Compositor::create(**context, l.scene, camera, l.response, co);
                if (!c) return reportError(c.error());
                render::FrameInput in;
                in.image = ImageView{PixelFormat::kRgb8, w, h, rgb.step, rgb.data, rgb.step * static_cast<std::size_t>(h)};
                in.cam_from_world = world_from_cam->inverse();
                in.exposure_gain = 1.0;
                for (const std::optional<FrameMetaRecord>& meta : l.sequence.meta) {
                    if (meta && meta->timestamp_ns == frame_ts && meta->exposure_us > 0) {
                        in.exposure_gain = meta->exposure_us * 1e-6 * (meta->analog_gain > 0 ? meta->analog_gain : 1.0);
                    }
                }
                std::vector<double> ms;
                const lighting::LightingSnapshot empty{};
                for (int k = 0; k < options.repeats + 2; ++k) {
                    const std::int64_t t0 = monotonicNowNs();
                    if (auto drawn = (*c)->draw(in, snapshot ? *snapshot : empty); !drawn) return reportError(drawn.error());
                    if (auto read = (*c)->read(); !read) return reportError(read.error());
                    if (k >= 2) ms.push_back(static_cast<double>(monotonicNowNs() - t0) / 1e6);  // the first two warm up
                }
                std::sort(ms.begin(), ms.end());
                const double p50 = capture::nearestRank(ms, 50), p95 = capture::nearestRank(ms, 95);
                std::printf("  %4dx%-4d MSAA %d: p50 %.1f ms, p95 %.1f ms\n", w, h, msaa, p50, p95);
                compositor.push_back({{"width", w}, {"height", h}, {"msaa", msaa}, {"ms", {{"p50", p50}, {"p95", p95}}}});
            }
        }
        out["compositor"] = compositor;
        out["renderer"] = (*context)->renderer();
        context->reset();
    }

    // Case realtime: playback at the recorded rate, looped for --seconds, with the pipeline
    // thread (tracking of frame n+1 overlaps compositing of frame n) and, for comparison, with
    // both stages on one thread one after the other (as before the pipeline thread).
    if (wants(options, "realtime")) {
        const double period_ms = l.sequence.sensor.rate_hz > 0 ? 1000.0 / l.sequence.sensor.rate_hz : 1000.0 / 30.0;
        std::printf("== realtime (%.0f s at the recorded rate, %dx%d, lighting on, MSAA 4; a frame is %.1f ms)\n", options.seconds,
                    l.camera.width, l.camera.height, period_ms);
        std::printf("  %-34s %9s %9s %15s %15s %17s %8s\n", "threads", "fps", "tracked", "latency p50 ms", "latency p95 ms",
                    "lighting lag p50", "replaced");
        nlohmann::json realtime = nlohmann::json::array();
        for (const bool pipeline_thread : {true, false}) {
            pipeline::RunnerOptions r;
            r.composite = true;
            r.pipeline_thread = pipeline_thread;
            auto m = playThrough(l, r, false, nullptr, options.seconds);
            if (!m) return reportError(m.error());
            const nlohmann::json c = (*m)["compositor"];
            const auto p = [&](const char* key, const char* q) {
                return c.contains(key) ? c[key][q].get<double>() : 0.0;
            };
            const char* name = pipeline_thread ? "pipeline thread + main thread" : "one thread (track, then composite)";
            std::printf("  %-34s %9.1f %9.1f %8.1f (%.1f f) %8.1f (%.1f f) %10.1f frames %8llu\n", name,
                        (*m)["processed_fps"].get<double>(), (*m)["tracked_fps"].get<double>(), p("latency_ms", "p50"),
                        p("latency_ms", "p50") / period_ms, p("latency_ms", "p95"), p("latency_ms", "p95") / period_ms,
                        p("lighting_lag_frames", "p50"), static_cast<unsigned long long>(c.value("replaced", 0)));
            (*m)["threads"] = name;
            realtime.push_back(*m);
        }
        out["realtime"] = realtime;
    }
    if (!options.json.empty()) {
        if (auto written = writeJson(options.json, out); !written) return reportError(written.error());
        std::printf("json: %s\n", options.json.c_str());
    }
    return kExitOk;
}

}  // namespace commonlight::apps

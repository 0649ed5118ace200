#include "apps/bench_pipeline.h"

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cstdio>
#include <memory>

#include <sys/resource.h>

#include "apps/app.h"
#include "apps/report.h"
#include "capture/capture_session.h"
#include "core/percentiles.h"
#include "core/clock.h"
#include "core/log.h"
#include "core/scene_io.h"
#include "mocks/replay_camera.h"
#include "pipeline/runner.h"
#include "render/camera_matching.h"

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


double cpuSeconds() {
    rusage usage{};
    getrusage(RUSAGE_SELF, &usage);
    return static_cast<double>(usage.ru_utime.tv_sec + usage.ru_stime.tv_sec) +
           static_cast<double>(usage.ru_utime.tv_usec + usage.ru_stime.tv_usec) / 1e6;
}

// An RGB image as a camera would send it in YUYV or NV12 (OpenCV's BT.601 I420 conversion, its
// chroma interleaved; YUYV takes each row pair's chroma).
std::vector<std::uint8_t> toYuv(const cv::Mat& rgb, PixelFormat format) {
    cv::Mat i420;
    cv::cvtColor(rgb, i420, cv::COLOR_RGB2YUV_I420);
    const int w = rgb.cols, h = rgb.rows;
    const std::uint8_t* y = i420.data;
    const std::uint8_t* u = y + static_cast<std::size_t>(w) * static_cast<std::size_t>(h);
    const std::uint8_t* v = u + static_cast<std::size_t>(w / 2) * static_cast<std::size_t>(h / 2);
    std::vector<std::uint8_t> out(imageBytes(format, w, h, minStride(format, w)));
    for (int r = 0; r < h; ++r) {
        for (int x = 0; x < w; x += 2) {
            const std::size_t c = static_cast<std::size_t>(r / 2) * static_cast<std::size_t>(w / 2) + static_cast<std::size_t>(x / 2);
            const std::size_t p = static_cast<std::size_t>(r) * static_cast<std::size_t>(w) + static_cast<std::size_t>(x);
            if (format == PixelFormat::kYuyv) {
                std::uint8_t* o = out.data() + 2 * p;
                o[0] = y[p];
                o[1] = u[c];
                o[2] = y[p + 1];
                o[3] = v[c];
            } else {
                out[p] = y[p];
                out[p + 1] = y[p + 1];
                if (r % 2 == 0) {
                    std::uint8_t* o = out.data() + static_cast<std::size_t>(w) * static_cast<std::size_t>(h) + static_cast<std::size_t>(r / 2) * static_cast<std::size_t>(w) + static_cast<std::size_t>(x);
                    o[0] = u[c];
                    o[1] = v[c];
                }
            }
        }
    }
    return out;
}

// The sample's lighting snapshot at the end of a synchronous run (when the system case did not
// leave one).
Result<std::shared_ptr<const lighting::LightingSnapshot>> sampleSnapshot(const Loaded& l) {
    std::shared_ptr<const lighting::LightingSnapshot> snapshot;
    pipeline::RunnerOptions r;
    r.lighting = true;
    r.composite = false;
    CL_TRY(nlohmann::json m, playThrough(l, r, true, &snapshot));
    (void)m;
    return snapshot;
}

// Case compositor: draw + read back of frame 30 with the sample's snapshot at two sizes, MSAA 4
// and 1; "static" draws the same frame again (the shadow maps are reused), "moving" moves the
// virtual objects by 5 mm every draw, back and forth over 20 cm (their shadow maps are drawn again
// every draw, the real proxies' when the objects leave the sphere those cover). Wall
// time (p50, p95) and CPU time of the process (all of llvmpipe's threads) per frame; then the
// same draws in profiling mode (glFinish after each pass): the mean wall/CPU time of each pass.
// CPU time is what to compare between runs on a machine shared with other work.
Result<nlohmann::json> benchCompositor(const Loaded& l, const BenchPipelineOptions& options,
                                       std::shared_ptr<const lighting::LightingSnapshot> snapshot) {
    if (!snapshot) {
        CL_TRY(snapshot, sampleSnapshot(l));
    }
    std::printf("== compositor (draw and read back of frame 30, the sample's snapshot)\n");
    const std::size_t index = std::min<std::size_t>(30, l.sequence.frames.size() - 1);
    const std::int64_t frame_ts = l.sequence.frames[index].timestamp_ns;
    std::optional<Rigid3d> world_from_cam = l.truth ? l.truth->atTimestamp(frame_ts) : std::nullopt;
    const cv::Mat bgr = cv::imread((l.sequence.cam_dir / "data" / l.sequence.frames[index].filename).string());
    if (bgr.empty() || !world_from_cam) return fail(ErrorCode::kBadInput, l.sequence.root.string() + ": frame 30 or its ground truth is missing");
    std::vector<std::optional<Rigid3d>> poses;
    for (const VirtualObject& v : l.scene.virtual_objects) poses.push_back(worldFromObject(v, l.scene.tags, 0.0));
    nlohmann::json cases = nlohmann::json::array();
    CL_TRY(std::unique_ptr<render::GlContext> context, render::GlContext::create({}));
    const lighting::LightingSnapshot empty{};
    struct Case {
        int w, h, msaa;
        bool moving;
        PixelFormat format;
        bool matching = false;
    };
    std::vector<Case> specs;
    for (const auto& [w, h] : {std::pair{640, 480}, std::pair{1280, 720}}) {
        for (int msaa : {4, 1}) {
            for (const bool moving : {false, true}) specs.push_back({w, h, msaa, moving, PixelFormat::kRgb8});
        }
    }
    // The frame as a camera sends it, converted in the final pass.
    specs.push_back({640, 480, 4, false, PixelFormat::kYuyv});
    specs.push_back({640, 480, 4, false, PixelFormat::kNv12});
    // Camera matching on (measured at the first draw and every 30th).
    specs.push_back({640, 480, 4, false, PixelFormat::kRgb8, true});
    for (const Case& spec : specs) {
        const int w = spec.w, h = spec.h, msaa = spec.msaa;
        const bool moving = spec.moving;
        const CameraModel camera = l.camera.scaledTo(w, h);
        cv::Mat resized, rgb;
        cv::resize(bgr, resized, cv::Size(w, h), 0, 0, cv::INTER_AREA);
        cv::cvtColor(resized, rgb, cv::COLOR_BGR2RGB);
        const std::vector<std::uint8_t> yuv = spec.format == PixelFormat::kRgb8 ? std::vector<std::uint8_t>{} : toYuv(rgb, spec.format);
        render::CompositorOptions co;
        co.msaa_samples = msaa;
        co.camera_matching = spec.matching;
        co.modulation_region = options.modulation_region == "frame"       ? render::ModulationRegion::kFrame
                               : options.modulation_region == "rectangle" ? render::ModulationRegion::kRectangle
                                                                          : render::ModulationRegion::kTiles;
        CL_TRY(std::unique_ptr<render::Compositor> c, render::Compositor::create(*context, l.scene, camera, l.response, co));
        render::FrameInput in;
        in.image = spec.format == PixelFormat::kRgb8
                       ? ImageView{PixelFormat::kRgb8, w, h, rgb.step, rgb.data, rgb.step * static_cast<std::size_t>(h)}
                       : ImageView{spec.format, w, h, minStride(spec.format, w), yuv.data(), yuv.size()};
        in.cam_from_world = world_from_cam->inverse();
        in.exposure_gain = 1.0;
        for (const std::optional<FrameMetaRecord>& meta : l.sequence.meta) {
            if (meta && meta->timestamp_ns == frame_ts && meta->exposure_us > 0) {
                in.exposure_gain = meta->exposure_us * 1e-6 * (meta->analog_gain > 0 ? meta->analog_gain : 1.0);
            }
        }
        const auto drawOnce = [&](int k) -> Result<void> {
            in.virtual_poses = poses;
            if (moving) {
                // 5 mm a draw (15 cm/s at 30 fps), back and forth over 20 cm: the real proxies'
                // shadow maps are fitted again when the objects leave their sphere.
                const int phase = k % 80;
                const double offset = 5e-3 * (phase < 40 ? phase : 80 - phase);
                for (auto& p : in.virtual_poses) {
                    if (p) p->translation.x() += offset;
                }
            }
            CL_TRY_VOID(c->draw(in, snapshot ? *snapshot : empty));
            CL_TRY(Image read, c->read());
            (void)read;
            return {};
        };
        std::vector<double> ms;
        double cpu = 0.0;
        for (int k = 0; k < options.repeats + 2; ++k) {
            const std::int64_t t0 = monotonicNowNs();
            const double c0 = cpuSeconds();
            CL_TRY_VOID(drawOnce(k));
            if (k >= 2) {  // the first two warm up
                ms.push_back(static_cast<double>(monotonicNowNs() - t0) / 1e6);
                cpu += cpuSeconds() - c0;
            }
        }
        std::sort(ms.begin(), ms.end());
        const double p50 = nearestRank(ms, 50), p95 = nearestRank(ms, 95);
        const double cpu_ms = 1e3 * cpu / static_cast<double>(ms.size());
        // Profiling: the same draws with glFinish after each pass.
        co.profile = true;
        c->setOptions(co);
        std::vector<std::pair<std::string, std::pair<double, double>>> passes;
        const int profiled = std::max(3, options.repeats / 3);
        for (int k = 0; k < profiled; ++k) {
            CL_TRY_VOID(drawOnce(k));
            for (const render::PassTime& t : c->passTimes()) {
                auto it = std::find_if(passes.begin(), passes.end(), [&](const auto& p) { return p.first == t.name; });
                if (it == passes.end()) {
                    passes.emplace_back(t.name, std::pair{t.ms / profiled, t.cpu_ms / profiled});
                } else {
                    it->second.first += t.ms / profiled;
                    it->second.second += t.cpu_ms / profiled;
                }
            }
        }
        const std::string format(pixelFormatName(spec.format));
        std::printf("  %4dx%-4d %-4s MSAA %d %-7s%s p50 %6.1f ms, p95 %6.1f ms, CPU %6.1f ms |", w, h, format.c_str(), msaa,
                    moving ? "moving" : "static", spec.matching ? " matching" : "", p50, p95, cpu_ms);
        nlohmann::json pass_json = nlohmann::json::object();
        for (const auto& [name, t] : passes) {
            std::printf(" %s %.1f/%.1f", name.c_str(), t.first, t.second);
            pass_json[name] = {{"ms", t.first}, {"cpu_ms", t.second}};
        }
        // Where the final pass modulated (the last draw): pixels of the frame, the virtual layer's included.
        const render::FinalPassArea& area = c->finalPassArea();
        const double modulated = static_cast<double>(area.modulated + area.with_virtual) / (static_cast<double>(w) * h);
        std::printf(" | modulated %.0f%% (%d tiles), %d draws\n", 100.0 * modulated, area.modulated_tiles, area.draws);
        cases.push_back({{"width", w}, {"height", h}, {"format", format}, {"msaa", msaa}, {"moving", moving}, {"camera_matching", spec.matching},
                         {"ms", {{"p50", p50}, {"p95", p95}}}, {"cpu_ms", cpu_ms}, {"passes_ms", pass_json},
                         {"final_pass", {{"modulated_fraction", modulated}, {"modulated_tiles", area.modulated_tiles}, {"draws", area.draws}}}});
    }
    return nlohmann::json{{"cases", cases}, {"renderer", context->renderer()}};
}

// The deviation of the noise (codes, per channel) in the pixels of `mask`, eroded by 3 px (edges
// and silhouettes left out): the median absolute residual of Immerkaer's mask (see
// render/camera_matching.h).
Eigen::Vector3d maskedNoise(const cv::Mat& rgb, const cv::Mat& mask) {
    cv::Mat inner;
    cv::erode(mask, inner, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(7, 7)));
    const cv::Mat kernel = (cv::Mat_<float>(3, 3) << 1, -2, 1, -2, 4, -2, 1, -2, 1);
    std::vector<cv::Mat> channels;
    cv::split(rgb, channels);
    Eigen::Vector3d out = Eigen::Vector3d::Zero();
    for (int c = 0; c < 3; ++c) {
        cv::Mat f, r;
        channels[static_cast<std::size_t>(c)].convertTo(f, CV_32F);
        cv::filter2D(f, r, CV_32F, kernel);
        std::vector<float> values;
        for (int y = 1; y < r.rows - 1; ++y) {
            for (int x = 1; x < r.cols - 1; ++x) {
                if (inner.at<std::uint8_t>(y, x) > 127) values.push_back(std::abs(r.at<float>(y, x)));
            }
        }
        if (values.empty()) continue;
        std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(values.size() / 2), values.end());
        out[c] = 1.4826 * values[values.size() / 2] / 6.0;
    }
    return out;
}

// Case matching: camera matching on frame 30 of the sample. What the estimators measure on the
// frame and what they cost; the noise in the virtual objects' pixels (masks/virtual) of the
// path-traced ground truth and of the composite without and with matching.
Result<nlohmann::json> benchMatching(const Loaded& l, std::shared_ptr<const lighting::LightingSnapshot> snapshot) {
    if (!snapshot) {
        CL_TRY(snapshot, sampleSnapshot(l));
    }
    std::printf("== camera matching (frame 30 of the sample)\n");
    const std::size_t index = std::min<std::size_t>(30, l.sequence.frames.size() - 1);
    const SequenceFrame& f = l.sequence.frames[index];
    const cv::Mat bgr = cv::imread((l.sequence.cam_dir / "data" / f.filename).string());
    const std::string stem = std::filesystem::path(f.filename).stem().string();
    const cv::Mat mask = cv::imread((l.sequence.root / "groundtruth/masks/virtual" / (stem + ".png")).string(), cv::IMREAD_GRAYSCALE);
    cv::Mat truth_bgr;
    for (const char* ext : {".png", ".jpg"}) {
        const std::filesystem::path path = l.sequence.root / "groundtruth/composite" / (stem + ext);
        if (truth_bgr.empty() && std::filesystem::exists(path)) truth_bgr = cv::imread(path.string());
    }
    std::optional<Rigid3d> world_from_cam = l.truth ? l.truth->atTimestamp(f.timestamp_ns) : std::nullopt;
    if (bgr.empty() || mask.empty() || truth_bgr.empty() || !world_from_cam) {
        return fail(ErrorCode::kBadInput, l.sequence.root.string() + ": frame 30, its ground-truth composite, pose or masks/virtual is missing");
    }
    cv::Mat rgb;
    cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
    const ImageView view{PixelFormat::kRgb8, rgb.cols, rgb.rows, rgb.step, rgb.data, rgb.step * static_cast<std::size_t>(rgb.rows)};
    std::int64_t t0 = monotonicNowNs();
    CL_TRY(render::NoiseProfile noise, render::estimateNoise(view));
    const double noise_ms = static_cast<double>(monotonicNowNs() - t0) / 1e6;
    t0 = monotonicNowNs();
    CL_TRY(render::BlurEstimate blur, render::estimateBlur(view, l.response));
    const double blur_ms = static_cast<double>(monotonicNowNs() - t0) / 1e6;
    std::printf("  frame: noise %.2f %.2f %.2f codes (%.1f ms), blur %.3f px from %d edges (spread %.3f, %.1f ms)\n", noise.overall[0],
                noise.overall[1], noise.overall[2], noise_ms, blur.sigma_px, blur.edges, blur.spread, blur_ms);
    nlohmann::json out{{"frame_noise_codes", {noise.overall[0], noise.overall[1], noise.overall[2]}},
                       {"frame_blur_px", blur.sigma_px},
                       {"blur_edges", blur.edges},
                       {"noise_ms", noise_ms},
                       {"blur_ms", blur_ms}};
    cv::Mat truth_rgb;
    cv::cvtColor(truth_bgr, truth_rgb, cv::COLOR_BGR2RGB);
    const Eigen::Vector3d truth_noise = maskedNoise(truth_rgb, mask);
    std::printf("  noise in the virtual objects' pixels (codes R G B): ground truth %.2f %.2f %.2f\n", truth_noise[0], truth_noise[1],
                truth_noise[2]);
    out["virtual_noise_truth"] = {truth_noise[0], truth_noise[1], truth_noise[2]};
    CL_TRY(std::unique_ptr<render::GlContext> context, render::GlContext::create({}));
    for (const bool matching : {false, true}) {
        render::CompositorOptions co;
        co.camera_matching = matching;
        CL_TRY(std::unique_ptr<render::Compositor> c, render::Compositor::create(*context, l.scene, l.camera, l.response, co));
        render::FrameInput in;
        in.image = view;
        in.cam_from_world = world_from_cam->inverse();
        for (const std::optional<FrameMetaRecord>& meta : l.sequence.meta) {
            if (meta && meta->timestamp_ns == f.timestamp_ns && meta->exposure_us > 0) {
                in.exposure_gain = meta->exposure_us * 1e-6 * (meta->analog_gain > 0 ? meta->analog_gain : 1.0);
            }
        }
        CL_TRY_VOID(c->draw(in, *snapshot));
        CL_TRY(Image composite, c->read());
        cv::Mat composite_rgb(composite.height(), composite.width(), CV_8UC3, composite.data(), composite.stride());
        const Eigen::Vector3d n = maskedNoise(composite_rgb, mask);
        std::printf("  noise in the virtual objects' pixels (codes R G B): composite %s matching %.2f %.2f %.2f", matching ? "with" : "without",
                    n[0], n[1], n[2]);
        if (matching && c->cameraMatch()) std::printf(" (layer blurred by %.3f px)", c->cameraMatch()->added_sigma_px);
        std::printf("\n");
        out[matching ? "virtual_noise_matching" : "virtual_noise_plain"] = {n[0], n[1], n[2]};
        if (matching && c->cameraMatch()) out["added_blur_px"] = c->cameraMatch()->added_sigma_px;
    }
    return out;
}

}  // namespace

std::vector<std::string> benchPipelineCaseNames() { return {"system", "compositor", "matching", "realtime"}; }

int runBenchPipeline(const BenchPipelineOptions& options) {
    auto loaded = load(options.sequence);
    if (!loaded) return reportError(loaded.error());
    const Loaded& l = *loaded;
    nlohmann::json out;
    out["sequence"] = options.sequence.string();

    const std::vector<std::string> cases = options.cases.empty() ? benchPipelineCaseNames() : options.cases;
    const auto wanted = [&](const char* name) { return std::find(cases.begin(), cases.end(), name) != cases.end(); };
    std::shared_ptr<const lighting::LightingSnapshot> snapshot;
    if (wanted("system")) {
        // Case system: every frame, lighting on/off, MSAA 4/1.
        std::printf("== system (every frame of %s, against groundtruth/composite)\n", options.sequence.c_str());
        std::printf("  %-32s %9s %12s %12s %12s %12s\n", "configuration", "PSNR dB", "RMSE frame", "RMSE changed", "composite ms",
                    "lighting ms");
        struct Config {
            const char* name;
            bool lighting;
            int msaa;
            bool matching;
            int light_samples = 4;  // shadow maps per area light (2: the quality governor's lowest level)
        };
        nlohmann::json system = nlohmann::json::array();
        for (const Config& c : {Config{"lighting on, MSAA 4", true, 4, false}, Config{"lighting on, no MSAA", true, 1, false},
                                Config{"lighting on, no MSAA, 2 samples", true, 1, false, 2},
                                Config{"lighting off, MSAA 4", false, 4, false}, Config{"lighting on, MSAA 4, matching", true, 4, true}}) {
            pipeline::RunnerOptions r;
            r.lighting = c.lighting;
            r.composite = true;
            r.compositor.msaa_samples = c.msaa;
            r.compositor.camera_matching = c.matching;
            r.compositor.area_light_samples = c.light_samples;
            auto m = playThrough(l, r, true, c.lighting && !snapshot ? &snapshot : nullptr);
            if (!m) return reportError(m.error());
            const nlohmann::json e = m->value("composite_error", nlohmann::json::object());
            const nlohmann::json st = (*m)["stages_ms"];
            const double comp = st.contains("composite") ? st["composite"]["p50"].get<double>() : 0.0;
            const double lit = st.contains("lighting") ? st["lighting"]["p50"].get<double>() : 0.0;
            std::printf("  %-32s %9.2f %12.4f %12.4f %12.1f %12.1f\n", c.name, e.value("psnr_db", 0.0), e.value("rmse_linear", 0.0),
                        e.value("rmse_linear_changed", 0.0), comp, lit);
            system.push_back({{"configuration", c.name}, {"lighting", c.lighting}, {"msaa", c.msaa}, {"camera_matching", c.matching},
                              {"area_light_samples", c.light_samples}, {"composite_error", e},
                              {"stages_ms", st}, {"lighting_metrics", m->value("lighting", nlohmann::json())}});
        }
        out["system"] = system;
    }

    if (wanted("matching")) {
        auto m = benchMatching(l, snapshot);
        if (!m) return reportError(m.error());
        out["matching"] = *m;
    }

    if (wanted("compositor")) {
        auto c = benchCompositor(l, options, snapshot);
        if (!c) return reportError(c.error());
        out["compositor"] = (*c)["cases"];
        out["renderer"] = (*c)["renderer"];
    }

    // Case realtime: playback at the recorded rate, looped for --seconds, with the pipeline
    // thread (tracking of frame n+1 overlaps compositing of frame n) and, for comparison, with
    // both stages on one thread one after the other (as before the pipeline thread), both at
    // MSAA 4; then the pipeline thread with the quality governor (play's and live's default).
    if (wanted("realtime")) {
        const double period_ms = l.sequence.sensor.rate_hz > 0 ? 1000.0 / l.sequence.sensor.rate_hz : 1000.0 / 30.0;
        std::printf("== realtime (%.0f s at the recorded rate, %dx%d, lighting on, MSAA 4; a frame is %.1f ms)\n", options.seconds,
                    l.camera.width, l.camera.height, period_ms);
        std::printf("  %-34s %9s %9s %15s %15s %17s %8s\n", "threads", "fps", "tracked", "latency p50 ms", "latency p95 ms",
                    "lighting lag p50", "replaced");
        nlohmann::json realtime = nlohmann::json::array();
        for (const auto& [pipeline_thread, adapt] : {std::pair{true, false}, std::pair{false, false}, std::pair{true, true}}) {
            pipeline::RunnerOptions r;
            r.composite = true;
            r.pipeline_thread = pipeline_thread;
            r.adapt_quality = adapt;
            auto m = playThrough(l, r, false, nullptr, options.seconds);
            if (!m) return reportError(m.error());
            const nlohmann::json c = (*m)["compositor"];
            const auto p = [&](const char* key, const char* q) {
                return c.contains(key) ? c[key][q].get<double>() : 0.0;
            };
            const char* name = !pipeline_thread ? "one thread (track, then composite)"
                               : adapt          ? "pipeline thread, quality governor"
                                                : "pipeline thread + main thread";
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

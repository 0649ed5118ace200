#include "pipeline/lighting_stage.h"

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <tbb/task_arena.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <thread>

#include "core/log.h"
#include "core/thread_priority.h"
#include "lighting/scene_lighting.h"

namespace commonlight::pipeline {

namespace fs = std::filesystem;

Result<ResponseCurve> sequenceResponse(const Sequence& sequence, const std::string& override_spec) {
    if (!override_spec.empty()) {
        auto r = ResponseCurve::parse(override_spec, fs::current_path());
        if (!r) return fail(r.error().code, "--response: " + r.error().message);
        return r;
    }
    auto r = ResponseCurve::parse(sequence.sensor.response, sequence.cam_dir);
    if (!r) return fail(r.error().code, (sequence.cam_dir / "sensor.yaml").string() + ": key 'response': " + r.error().message);
    return r;
}

void RatioErrors::add(const Image& predicted, const ImageView& frame, const ImageView& composite, const ImageView& changed,
                      const ImageView* coverage, const ResponseCurve& response) {
    ++frames_;
    const auto lum = [&](const std::uint8_t* p) {
        return 0.2126 * response.toLinear(0, p[0]) + 0.7152 * response.toLinear(1, p[1]) + 0.0722 * response.toLinear(2, p[2]);
    };
    for (int y = 0; y < frame.height; ++y) {
        const auto* pr = reinterpret_cast<const float*>(predicted.view().row(y));
        for (int x = 0; x < frame.width; ++x) {
            if (changed.row(y)[x] < 128) continue;
            if (coverage && coverage->row(y)[x] > 0) continue;
            if (!std::isfinite(pr[3 * x + 1])) continue;
            const double a = lum(frame.row(y) + 3 * x);
            // Hard case: a nearly black pixel has no meaningful ratio (noise over noise).
            if (a < 0.01) continue;
            const double b = lum(composite.row(y) + 3 * x);
            const double p = 0.2126 * pr[3 * x] + 0.7152 * pr[3 * x + 1] + 0.0722 * pr[3 * x + 2];
            errors_.push_back(p - b / a);
        }
    }
}

nlohmann::json RatioErrors::json() const {
    double se = 0.0, sum = 0.0;
    for (double e : errors_) {
        se += e * e;
        sum += e;
    }
    const double n = static_cast<double>(errors_.size());
    return {{"rms", n > 0 ? std::sqrt(se / n) : 0.0}, {"mean_signed", n > 0 ? sum / n : 0.0}, {"pixels", errors_.size()},
            {"frames", frames_}};
}

Result<std::unique_ptr<LightingStage>> LightingStage::create(const Scene& scene, const CameraModel& camera,
                                                             const ResponseCurve& response, std::optional<double> radiance_scale,
                                                             bool sync, const Sequence* sequence, int update_every) {
    auto stage = std::unique_ptr<LightingStage>(new LightingStage());
    lighting::EngineOptions options;
    options.sync = sync;
    options.response = response;
    options.radiance_scale = radiance_scale;
    options.update_every = update_every;
    CL_TRY(stage->engine_, lighting::LightingEngine::create(scene, camera, options));
    stage->scene_ = scene;
    stage->response_ = response;
    stage->sync_ = sync;
    stage->sequence_ = sequence;
    std::error_code ec;
    stage->have_truth_ = sequence && fs::is_directory(sequence->root / "groundtruth/composite", ec) &&
                         fs::is_directory(sequence->root / "groundtruth/masks/changed", ec);
    stage->engine_->start();
    if (stage->have_truth_ && !sync) stage->measurer_ = std::thread([s = stage.get()] { s->measureLoop(); });
    return stage;
}

LightingStage::~LightingStage() {
    stop();
}

void LightingStage::stop() {
    // The measuring thread finishes the frame it was given last, then the engine stops.
    if (measurer_.joinable()) {
        {
            std::lock_guard lock(measure_mutex_);
            measure_stop_ = true;
        }
        measure_wake_.notify_all();
        measurer_.join();
    }
    if (engine_) engine_->stop();
}

void LightingStage::measureLoop() {
    // A measurement, not the product: it yields the CPU to tracking, compositing and the lighting,
    // when it traces on its own (the truth has masks/virtual: measure()). Otherwise it holds the
    // lighting's model while it traces, and a lower priority would hold the lighting thread up.
    std::error_code ec;
    if (fs::is_directory(sequence_->root / "groundtruth/masks/virtual", ec) &&
        !setCurrentThreadNice(currentThreadNice() + 10)) {
        log::warning("lighting measurement: could not lower its thread's priority");
    }
    // The newest frame left unmeasured because an update was in progress: measured once the run
    // is over (waiting for the update), unless a later frame was measured since.
    std::optional<MeasureJob> skipped;
    const auto run = [&](MeasureJob& job, bool wait) {
        auto measured = measure(job.rgb.view(), job.meta, job.cam_from_world, wait);
        if (!measured && !measure_warned_) {
            measure_warned_ = true;
            log::warning(measured.error().message + " (the ratio error against the ground truth is not measured for it)");
        }
        return measured && *measured;
    };
    while (true) {
        MeasureJob job;
        {
            std::unique_lock lock(measure_mutex_);
            measure_wake_.wait(lock, [&] { return measure_job_.has_value() || measure_stop_; });
            if (!measure_job_) break;
            job = std::move(*measure_job_);
            measure_job_.reset();
        }
        if (run(job, false)) {
            skipped.reset();
        } else {
            skipped = std::move(job);
        }
    }
    if (skipped) run(*skipped, true);
}

Result<void> LightingStage::submit(const ImageView& rgb8, const FrameMetadata& meta, const std::optional<Rigid3d>& cam_from_world,
                                   const std::vector<Rigid3d>& virtual_poses) {
    engine_->setVirtualPoses(virtual_poses);
    lighting::Observation obs;
    obs.rgb8 = rgb8;
    obs.timestamp_ns = meta.timestamp_ns;
    obs.cam_from_world = cam_from_world;
    obs.exposure_us = meta.exposure_us;
    obs.analog_gain = meta.analog_gain;
    return engine_->submit(obs);
}

Result<void> LightingStage::process(const ImageView& rgb8, const FrameMetadata& meta,
                                    const std::optional<Rigid3d>& cam_from_world,
                                    const std::vector<Rigid3d>& virtual_poses) {
    if (warmed_ && *warmed_ == meta.timestamp_ns) {
        warmed_.reset();  // (observed by warmUp(): the objects' poses alone)
        engine_->setVirtualPoses(virtual_poses);
    } else {
        CL_TRY_VOID(submit(rgb8, meta, cam_from_world, virtual_poses));
    }
    ++frames_;
    if (!have_truth_ || !cam_from_world || (frames_ - 1) % 5 != 0) return {};
    if (sync_) {
        CL_TRY_VOID(measure(rgb8, meta, *cam_from_world, true));
        return {};
    }
    MeasureJob job{Image::copyOf(rgb8), meta, *cam_from_world};
    {
        std::lock_guard lock(measure_mutex_);
        measure_job_ = std::move(job);
    }
    measure_wake_.notify_one();
    return {};
}

Result<void> LightingStage::warmUp(const ImageView& rgb8, const FrameMetadata& meta, const Rigid3d& cam_from_world,
                                   const std::vector<Rigid3d>& virtual_poses, double timeout_s) {
    const std::uint64_t before = engine_->stats().updates;
    CL_TRY_VOID(submit(rgb8, meta, cam_from_world, virtual_poses));
    warmed_ = meta.timestamp_ns;
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
    while (engine_->stats().updates == before) {
        if (std::optional<Error> error = engine_->lastError()) return fail(std::move(*error));
        if (std::chrono::steady_clock::now() > deadline) {
            return fail(ErrorCode::kTimeout, "lighting: no first update within " + std::to_string(timeout_s) + " s");
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    return {};
}

Result<bool> LightingStage::measure(const ImageView& rgb8, const FrameMetadata& meta, const Rigid3d& cam_from_world, bool wait) {
    // The frame's files in the ground truth, by its timestamp.
    std::string stem;
    for (const SequenceFrame& f : sequence_->frames) {
        if (f.timestamp_ns == meta.timestamp_ns) stem = fs::path(f.filename).stem().string();
    }
    if (stem.empty()) return true;
    const fs::path gt = sequence_->root / "groundtruth";
    fs::path composite_file;
    for (const char* ext : {".jpg", ".png"}) {
        if (fs::exists(gt / "composite" / (stem + ext))) composite_file = gt / "composite" / (stem + ext);
    }
    const fs::path changed_file = gt / "masks/changed" / (stem + ".png");
    if (composite_file.empty() || !fs::exists(changed_file)) return true;
    // In real time the ratio is traced at every fourth pixel of every fourth row (a sixteenth of
    // the rays, 450-500 of the changed region's pixels a frame on the sample: the measurement's CPU
    // is taken from the frames played). Where the truth says which pixels show a virtual object
    // (masks/virtual), the prediction sees through the objects and needs nothing an update
    // changes: it is traced on this thread alone (its priority lowered, measureLoop()) while the
    // lighting thread goes on. Without that mask the objects must hide what is behind them, which
    // needs the lighting's model: without `wait`, an update in progress then leaves the frame
    // unmeasured, before its truth is read.
    const lighting::SnapshotPtr snapshot = engine_->latest();
    const int stride = sync_ ? 1 : 4;
    const fs::path coverage_file = gt / "masks/virtual" / (stem + ".png");
    const bool have_coverage = fs::exists(coverage_file);
    Image predicted;
    if (wait) {
        CL_TRY(predicted, engine_->ratioImage(*snapshot, cam_from_world, stride));
    } else if (have_coverage) {
        Result<Image> traced = fail(ErrorCode::kInternal, "not traced");
        tbb::task_arena(1).execute([&] { traced = engine_->realRatioImage(*snapshot, cam_from_world, stride); });
        CL_TRY(predicted, std::move(traced));
    } else {
        CL_TRY(std::optional<Image> got, engine_->tryRatioImage(*snapshot, cam_from_world, stride));
        if (!got) return false;
        predicted = std::move(*got);
    }
    const cv::Mat bgr = cv::imread(composite_file.string(), cv::IMREAD_COLOR);
    const cv::Mat changed = cv::imread(changed_file.string(), cv::IMREAD_GRAYSCALE);
    if (bgr.empty() || changed.empty() || bgr.cols != rgb8.width || bgr.rows != rgb8.height || changed.cols != rgb8.width ||
        changed.rows != rgb8.height) {
        return fail(ErrorCode::kBadInput, composite_file.string() + ": unreadable or not the frame's size (ground truth)");
    }
    cv::Mat rgb;
    cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
    const ImageView composite{PixelFormat::kRgb8, rgb.cols, rgb.rows, rgb.step, rgb.data, rgb.step * rgb.rows};
    const ImageView mask{PixelFormat::kGray8, changed.cols, changed.rows, changed.step, changed.data, changed.step * changed.rows};
    const cv::Mat coverage = have_coverage ? cv::imread(coverage_file.string(), cv::IMREAD_GRAYSCALE) : cv::Mat();
    if (have_coverage && !wait && (coverage.cols != rgb8.width || coverage.rows != rgb8.height)) {
        return fail(ErrorCode::kBadInput, coverage_file.string() + ": unreadable or not the frame's size (ground truth)");
    }
    const ImageView coverage_view{PixelFormat::kGray8, coverage.cols, coverage.rows, coverage.step, coverage.data,
                                  coverage.step * static_cast<std::size_t>(coverage.rows)};
    const std::lock_guard lock(measure_mutex_);
    ratio_errors_.add(predicted, rgb8, composite, mask, coverage.empty() ? nullptr : &coverage_view, response_);
    return true;
}

nlohmann::json LightingStage::metricsJson() const {
    const lighting::SnapshotPtr snapshot = engine_->latest();
    nlohmann::json j = lighting::lightingMetricsJson(engine_->stats(), *snapshot);
    const std::lock_guard lock(measure_mutex_);
    if (have_truth_ && ratio_errors_.count() > 0) j["shadow_ratio_error"] = ratio_errors_.json();
    return j;
}

std::string LightingStage::summary() const {
    const nlohmann::json j = metricsJson();
    char line[512];
    std::snprintf(line, sizeof line, "lighting: %llu updates, update p50 %.1f ms p95 %.1f ms, %d elements, %d links",
                  static_cast<unsigned long long>(j["updates"].get<std::uint64_t>()), j["update_ms"]["p50"].get<double>(),
                  j["update_ms"]["p95"].get<double>(), j["elements"].get<int>(), j["links"].get<int>());
    std::string out = line;
    for (const auto& [name, light] : j["lights"].items()) {
        const auto& e = light["emission"];
        std::snprintf(line, sizeof line, "\n  light %s: %s [%.2f, %.2f, %.2f]", name.c_str(),
                      light["estimated"].get<bool>() ? "estimated" : "given", e[0].get<double>(), e[1].get<double>(),
                      e[2].get<double>());
        out += line;
    }
    if (j.contains("shadow_ratio_error")) {
        std::snprintf(line, sizeof line, "\n  ratio B/B~ where the virtual objects change the scene: RMS %.4f, mean signed %+.4f (%zu px)",
                      j["shadow_ratio_error"]["rms"].get<double>(), j["shadow_ratio_error"]["mean_signed"].get<double>(),
                      j["shadow_ratio_error"]["pixels"].get<std::size_t>());
        out += line;
    }
    return out;
}

}  // namespace commonlight::pipeline

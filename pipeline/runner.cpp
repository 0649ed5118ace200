#include "pipeline/runner.h"

#include <algorithm>
#include <cmath>

#include "core/clock.h"
#include "core/log.h"

namespace commonlight::pipeline {

FrameRunner::FrameRunner(const Scene& scene, const CameraModel& camera, const RunnerOptions& options)
    : scene_(scene),
      camera_(camera),
      options_(options),
      timings_({"convert", "track", "lighting", "composite", "pipeline"}),
      offsets_(scene.virtual_objects.size(), Eigen::Vector3d::Zero()) {}

FrameRunner::~FrameRunner() { stop(); }

Result<std::unique_ptr<FrameRunner>> FrameRunner::create(const Scene& scene, const CameraModel& camera,
                                                         const RunnerOptions& options) {
    auto runner = std::unique_ptr<FrameRunner>(new FrameRunner(scene, camera, options));
    PipelineOptions tracking_options;
    tracking_options.tracker = options.tracker;
    tracking_options.ground_truth = options.ground_truth;
    // The tracker borrows the scene: the runner's own copy, which lives as long as it does.
    CL_TRY(FramePipeline tracking, FramePipeline::create(runner->camera_, runner->scene_, tracking_options, runner->timings_));
    runner->tracking_.emplace(std::move(tracking));
    if (options.lighting && !scene.real_objects.empty()) {
        CL_TRY(runner->lighting_, LightingStage::create(runner->scene_, camera, options.response, options.radiance_scale,
                                                        options.sync, options.sequence));
    } else if (options.lighting) {
        log::info("lighting off: the scene has no real proxy geometry to light");
    }
    if (options.composite) {
        render::ContextOptions context_options;
        context_options.kind = options.context;
        context_options.width = camera.width;
        context_options.height = camera.height;
        context_options.title = "commonlight";
        CL_TRY(runner->context_, render::GlContext::create(context_options));
        CL_TRY(runner->compositor_, render::Compositor::create(*runner->context_, runner->scene_, camera, options.response,
                                                               options.compositor));
        if (!options.frames_dir.empty() || !options.video.empty()) {
            CL_TRY(runner->writer_, CompositeWriter::open(options.frames_dir, options.video, camera.width, camera.height, options.fps));
        }
    }
    return runner;
}

double FrameRunner::sceneTime(std::int64_t timestamp_ns) {
    if (!first_timestamp_) first_timestamp_ = timestamp_ns;
    return static_cast<double>(timestamp_ns - *first_timestamp_) / 1e9;
}

std::vector<std::optional<Rigid3d>> FrameRunner::virtualPoses(double t_s) const {
    std::vector<std::optional<Rigid3d>> poses;
    poses.reserve(scene_.virtual_objects.size());
    for (std::size_t i = 0; i < scene_.virtual_objects.size(); ++i) {
        std::optional<Rigid3d> pose = worldFromObject(scene_.virtual_objects[i], scene_.tags, t_s);
        if (pose) pose->translation += offsets_[i];
        poses.push_back(pose);
    }
    return poses;
}

void FrameRunner::moveVirtualObject(std::size_t index, const Eigen::Vector3d& delta) {
    if (index < offsets_.size() && delta.allFinite()) offsets_[index] += delta;
}

Result<tracking::FrameTrack> FrameRunner::process(const Frame& frame) {
    capture::StageTimer pipeline_timer(timings_, timings_.id("pipeline"));
    auto tracked = tracking_->process(frame);
    if (!tracked) {
        if (tracked.error().code == ErrorCode::kBadInput) ++bad_frames_;
        return tracked;
    }
    const double t_s = sceneTime(frame.meta.timestamp_ns);
    const std::vector<std::optional<Rigid3d>> poses = virtualPoses(t_s);
    if (lighting_ || compositor_) {
        CL_TRY_VOID(converter_.convert(frame.image, PixelFormat::kRgb8, rgb_));
    }
    if (lighting_) {
        std::vector<Rigid3d> lighting_poses;
        for (const auto& pose : poses) lighting_poses.push_back(pose.value_or(Rigid3d::identity()));
        capture::StageTimer lighting_timer(timings_, timings_.id("lighting"));
        CL_TRY_VOID(lighting_->process(rgb_.view(), frame.meta, tracked->cam_from_world, lighting_poses));
    }
    if (compositor_) CL_TRY_VOID(compositeFrame(frame, tracked->cam_from_world, poses));
    ++processed_;
    return tracked;
}

void FrameRunner::setLightingShown(bool shown) {
    if (!compositor_) return;
    render::CompositorOptions o = compositor_->options();
    o.lighting = shown;
    compositor_->setOptions(o);
}

Result<void> FrameRunner::compositeFrame(const Frame& frame, const std::optional<Rigid3d>& cam_from_world,
                                         const std::vector<std::optional<Rigid3d>>& poses) {
    std::optional<capture::StageTimer> timer;
    timer.emplace(timings_, timings_.id("composite"));
    // The newest snapshot: in sync mode the one of this very frame; in real time whatever the
    // lighting thread has published (its lag is measured).
    static const lighting::LightingSnapshot kNothing{};
    const lighting::SnapshotPtr snapshot = lighting_ ? lighting_->latest() : nullptr;
    const lighting::LightingSnapshot& use = snapshot ? *snapshot : kNothing;
    if (snapshot && snapshot->version > 0) {
        const double lag_ms = static_cast<double>(frame.meta.timestamp_ns - snapshot->frame_timestamp_ns) / 1e6;
        lag_ms_.add(lag_ms);
        if (last_frame_ns_ > 0 && frame.meta.timestamp_ns > last_frame_ns_) {
            const double period = static_cast<double>(frame.meta.timestamp_ns - last_frame_ns_);
            frame_period_ns_ = frame_period_ns_ > 0.0 ? 0.9 * frame_period_ns_ + 0.1 * period : period;
        }
        if (frame_period_ns_ > 0.0) lag_frames_.add(lag_ms * 1e6 / frame_period_ns_);
    }
    last_frame_ns_ = frame.meta.timestamp_ns;
    render::FrameInput input;
    input.image = rgb_.view();
    const double exposure_s = frame.meta.exposure_us > 0.0 && std::isfinite(frame.meta.exposure_us) ? frame.meta.exposure_us * 1e-6 : 1.0;
    const double gain = frame.meta.analog_gain > 0.0 && std::isfinite(frame.meta.analog_gain) ? frame.meta.analog_gain : 1.0;
    input.exposure_gain = exposure_s * gain;
    input.cam_from_world = cam_from_world;
    input.virtual_poses = poses;
    CL_TRY_VOID(compositor_->draw(input, use));
    CL_TRY(composite_, compositor_->read());
    timer.reset();  // outputs and ground truth are not the compositor's time
    if (frame.meta.arrival_ns > 0) latency_ms_.add(static_cast<double>(monotonicNowNs() - frame.meta.arrival_ns) / 1e6);

    // Outputs and the error against ground truth.
    std::string stem = std::to_string(frame.meta.timestamp_ns);
    if (options_.sequence) {
        for (const SequenceFrame& f : options_.sequence->frames) {
            if (f.timestamp_ns == frame.meta.timestamp_ns) stem = std::filesystem::path(f.filename).stem().string();
        }
    }
    if (writer_) CL_TRY_VOID(writer_->write(composite_.view(), stem));
    std::optional<FrameTruth> truth;
    if (options_.sequence) {
        CL_TRY(truth, readFrameTruth(*options_.sequence, frame.meta.timestamp_ns));
        if (truth) composite_errors_.add(composite_.view(), truth->composite.view(), truth->changed.view(), options_.response,
                                         input.exposure_gain);
    }
    if (!options_.side_by_side.empty() && !side_by_side_done_ && processed_ >= options_.side_by_side_frame) {
        const ImageView truth_view = truth ? truth->composite.view() : ImageView{};
        CL_TRY_VOID(writeSideBySide(options_.side_by_side, rgb_.view(), composite_.view(), truth ? &truth_view : nullptr));
        side_by_side_done_ = true;
    }
    return {};
}

Result<void> FrameRunner::restart() { return tracking_->restart(); }

void FrameRunner::stop() {
    if (lighting_) lighting_->stop();
    if (writer_) writer_->finish();
}

nlohmann::json FrameRunner::metricsJson() const {
    nlohmann::json metrics;
    metrics["frames_with_pose"] = tracking_->framesWithPose();
    if (options_.ground_truth) {
        metrics["pose_error"] = tracking_->poseErrors().json();
        metrics["frames_without_truth"] = tracking_->framesWithoutTruth();
    }
    if (lighting_) metrics["lighting"] = lighting_->metricsJson();
    if (compositor_) {
        nlohmann::json c;
        c["frames"] = processed_;
        c["msaa_samples"] = compositor_->options().msaa_samples;
        c["renderer"] = context_->renderer();
        if (lag_ms_.count() > 0) {
            const capture::Percentiles lag = lag_ms_.percentiles();
            c["lighting_lag_ms"] = {{"p50", lag.p50}, {"p95", lag.p95}, {"max", lag.max}};
        }
        if (latency_ms_.count() > 0) {
            const capture::Percentiles latency = latency_ms_.percentiles();
            c["latency_ms"] = {{"p50", latency.p50}, {"p95", latency.p95}, {"max", latency.max}};
        }
        if (lag_frames_.count() > 0) {
            const capture::Percentiles lag = lag_frames_.percentiles();
            c["lighting_lag_frames"] = {{"p50", lag.p50}, {"p95", lag.p95}, {"max", lag.max}};
        }
        metrics["compositor"] = c;
        if (composite_errors_.frames() > 0) metrics["composite_error"] = composite_errors_.json();
    }
    return metrics;
}

std::string FrameRunner::summary() const {
    std::string text;
    if (tracking_->poseErrors().count() > 0) text += tracking_->poseErrors().summary() + "\n";
    if (lighting_) text += lighting_->summary() + "\n";
    if (composite_errors_.frames() > 0) {
        const nlohmann::json e = composite_errors_.json();
        char line[256];
        std::snprintf(line, sizeof line,
                      "composite against ground truth (%zu frames): PSNR %.2f dB; linear RMSE %.4f (frame), %.4f (where the virtual objects change it)\n",
                      composite_errors_.frames(), e["psnr_db"].get<double>(), e["rmse_linear"].get<double>(),
                      e["rmse_linear_changed"].get<double>());
        text += line;
    }
    return text;
}

}  // namespace commonlight::pipeline

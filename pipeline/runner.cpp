#include "pipeline/runner.h"

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
    if (lighting_) {
        std::vector<Rigid3d> lighting_poses;
        for (const auto& pose : poses) lighting_poses.push_back(pose.value_or(Rigid3d::identity()));
        capture::StageTimer lighting_timer(timings_, timings_.id("lighting"));
        CL_TRY_VOID(converter_.convert(frame.image, PixelFormat::kRgb8, rgb_));
        CL_TRY_VOID(lighting_->process(rgb_.view(), frame.meta, tracked->cam_from_world, lighting_poses));
    }
    return tracked;
}

Result<void> FrameRunner::restart() { return tracking_->restart(); }

void FrameRunner::stop() {
    if (lighting_) lighting_->stop();
}

nlohmann::json FrameRunner::metricsJson() const {
    nlohmann::json metrics;
    metrics["frames_with_pose"] = tracking_->framesWithPose();
    if (options_.ground_truth) {
        metrics["pose_error"] = tracking_->poseErrors().json();
        metrics["frames_without_truth"] = tracking_->framesWithoutTruth();
    }
    if (lighting_) metrics["lighting"] = lighting_->metricsJson();
    return metrics;
}

std::string FrameRunner::summary() const {
    std::string text;
    if (tracking_->poseErrors().count() > 0) text += tracking_->poseErrors().summary() + "\n";
    if (lighting_) text += lighting_->summary() + "\n";
    return text;
}

}  // namespace commonlight::pipeline

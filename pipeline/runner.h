// The per-frame pipeline that `play`, `live` and `bench pipeline` share: tracking, the lighting
// thread and the compositor, their stage timings, the metrics JSON (docs/cli.md) and the
// comparison with ground truth.
//
// Threads: the capture session's camera thread delivers frames; the caller's thread (the main
// thread, which owns GL) runs process() for each one: convert, track, hand the frame to the
// lighting thread, composite with the newest lighting snapshot. With `sync`, the lighting update
// of a frame finishes before that frame is composited, so the output is deterministic; without
// it the newest snapshot is used as it is (the lighting lags as in live use, and the metrics say
// by how much).
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "capture/percentiles.h"
#include "capture/stage_timings.h"
#include "core/camera_model.h"
#include "core/frame.h"
#include "core/response.h"
#include "core/scene.h"
#include "core/sequence_io.h"
#include "pipeline/composite_output.h"
#include "pipeline/frame_pipeline.h"
#include "pipeline/lighting_stage.h"
#include "render/compositor.h"
#include "render/gl_context.h"
#include "tracking/tracker.h"

namespace commonlight::pipeline {

struct RunnerOptions {
    bool sync = false;      // every stage waits for the one before it (deterministic output)
    bool lighting = true;   // run the lighting thread (needs real proxies in the scene)
    tracking::TrackerOptions tracker;
    const GroundTruth* ground_truth = nullptr;  // pose truth (by timestamp or by pixels)
    const Sequence* sequence = nullptr;         // the recording, for the lighting's and composite's ground truth
    ResponseCurve response;                     // the camera's response
    std::optional<double> radiance_scale;       // sensor.yaml's, when known

    // The compositor (off: tracking and lighting only, as `--headless` without outputs).
    bool composite = false;
    render::ContextKind context = render::ContextKind::kOffscreen;  // kWindow: a GLFW window
    render::CompositorOptions compositor;
    std::filesystem::path frames_dir;    // composited frames as PNG (empty: none)
    std::filesystem::path video;         // composited MP4 (empty: none)
    double fps = 30.0;                   // the video's rate
    std::filesystem::path side_by_side;  // frame | composite | truth of one frame (empty: none)
    std::size_t side_by_side_frame = 0;  // which frame (index among the frames processed)
};

class FrameRunner {
public:
    // Tracking needs the scene's tags; `scene` is copied.
    static Result<std::unique_ptr<FrameRunner>> create(const Scene& scene, const CameraModel& camera,
                                                       const RunnerOptions& options);
    ~FrameRunner();
    FrameRunner(const FrameRunner&) = delete;
    FrameRunner& operator=(const FrameRunner&) = delete;

    // One frame whose status is ok. A frame that cannot be converted is kBadInput (counted: the
    // caller warns and goes on); any other error ends the run.
    Result<tracking::FrameTrack> process(const Frame& frame);

    // The newest composite (RGB8), when compositing; empty before the first frame.
    const Image& composite() const noexcept { return composite_; }
    render::Compositor* compositor() noexcept { return compositor_.get(); }
    render::GlContext* glContext() noexcept { return context_.get(); }
    // Lighting on or off at run time (live: key l): off draws no modulation and no lighting
    // thread output.
    void setLightingShown(bool shown);

    // A new connection (live): forget the motion, keep the statistics.
    Result<void> restart();
    // Stops the lighting thread; the metrics stay readable.
    void stop();

    // Seconds since the first frame, by frame timestamps (virtual objects on keyframes).
    double sceneTime(std::int64_t timestamp_ns);
    // The virtual objects' world_from_object at scene time t: the scene's placement, then the
    // user's offset (live: the arrow keys move the selected object). Objects attached to a tag
    // the scene lacks are nullopt.
    std::vector<std::optional<Rigid3d>> virtualPoses(double t_s) const;
    // Moves virtual object `index` by `delta` (world translation in metres).
    void moveVirtualObject(std::size_t index, const Eigen::Vector3d& delta);
    const Scene& scene() const noexcept { return scene_; }
    const CameraModel& camera() const noexcept { return camera_; }
    const FramePipeline& tracking() const noexcept { return *tracking_; }
    const LightingStage* lighting() const noexcept { return lighting_.get(); }
    capture::StageTimings& timings() noexcept { return timings_; }
    const capture::StageTimings& timings() const noexcept { return timings_; }
    std::uint64_t badFrames() const noexcept { return bad_frames_; }

    // The metrics of the stages: stages_ms, frames_with_pose, pose_error (with truth), lighting.
    nlohmann::json metricsJson() const;
    // Summary lines (tracking, pose error, lighting).
    std::string summary() const;

private:
    FrameRunner(const Scene& scene, const CameraModel& camera, const RunnerOptions& options);

    Scene scene_;
    CameraModel camera_;
    RunnerOptions options_;
    capture::StageTimings timings_;
    std::optional<FramePipeline> tracking_;
    std::unique_ptr<LightingStage> lighting_;
    capture::PixelConverter converter_;
    Image rgb_;
    std::optional<std::int64_t> first_timestamp_;
    std::vector<Eigen::Vector3d> offsets_;  // per virtual object, world metres
    std::unique_ptr<render::GlContext> context_;
    std::unique_ptr<render::Compositor> compositor_;
    std::unique_ptr<CompositeWriter> writer_;
    Image composite_;
    CompositeErrors composite_errors_;
    capture::SampleReservoir lag_ms_;       // frame timestamp minus the snapshot's, per composite
    capture::SampleReservoir lag_frames_;
    capture::SampleReservoir latency_ms_;   // frame arrival to composite ready
    std::uint64_t processed_ = 0;
    std::int64_t last_frame_ns_ = 0;
    double frame_period_ns_ = 0.0;
    bool side_by_side_done_ = false;
    Result<void> compositeFrame(const Frame& frame, const std::optional<Rigid3d>& cam_from_world,
                                const std::vector<std::optional<Rigid3d>>& poses);
    std::uint64_t bad_frames_ = 0;
};

}  // namespace commonlight::pipeline

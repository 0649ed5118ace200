// The per-frame pipeline that `play`, `live` and `bench pipeline` share: tracking, the lighting
// thread and the compositor, their stage timings, the metrics JSON (docs/cli.md) and the
// comparison with ground truth.
//
// Threads (pipeline/frame_loop.h): run() takes frames from a FrameSource. In real time it starts
// the pipeline thread, which runs track() (conversion, tracking, the virtual objects' poses, the
// hand-over to the lighting thread) for each frame, while the caller's thread (the main thread,
// which owns GL) runs composite() on the newest tracked frame: tracking frame n+1 overlaps
// compositing frame n. With `sync` both run on the caller's thread, one frame after the other, and
// the lighting update of a frame finishes before that frame is composited, so the output is
// deterministic; without it the newest snapshot is used as it is (the lighting lags as in live
// use, and the metrics say by how much).
//
// Which thread may call what: track(), restart() and sceneTime(): the pipeline thread (inside
// run(): from the source and the callbacks that run there). composite(), redraw(),
// setLightingShown(), compositor(), glContext(), compositeImage() and lastComposite(): the thread
// that created the runner (it owns GL). moveVirtualObject(), virtualPoses(), timings(): any thread.
// metricsJson(), summary(), tracking(), lighting() statistics: once run() returned.
#pragma once

#include <cstdint>
#include <memory>
#include <mutex>
#include <stop_token>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/percentiles.h"
#include "capture/stage_timings.h"
#include "core/camera_model.h"
#include "core/frame.h"
#include "core/response.h"
#include "core/scene.h"
#include "core/sequence_io.h"
#include "pipeline/composite_measurer.h"
#include "pipeline/composite_output.h"
#include "pipeline/frame_loop.h"
#include "pipeline/frame_pipeline.h"
#include "pipeline/lighting_pacer.h"
#include "pipeline/lighting_stage.h"
#include "pipeline/quality_governor.h"
#include "render/compositor.h"
#include "render/gl_context.h"
#include "tracking/tracker.h"

namespace commonlight::pipeline {

struct RunnerOptions {
    bool sync = false;      // every stage waits for the one before it (deterministic output)
    // Real time: tracking on the pipeline thread, compositing on the caller's (false: both on the
    // caller's thread, one after the other; for comparison in `bench pipeline`).
    bool pipeline_thread = true;
    bool lighting = true;   // run the lighting thread (needs real proxies in the scene)
    // Real time: the lighting thread solves for every n-th frame at most (1: as often as it can);
    // 0: paced (pipeline/lighting_pacer.h): every frame while the camera's frames keep up, fewer
    // while frames are dropped.
    int lighting_every = 0;
    // Real time: step the compositor's quality down when compositing falls behind the camera, and
    // back up when it has room (pipeline/quality_governor.h).
    bool adapt_quality = true;
    // The frames come in order (a recording or a camera): detect only around the predicted tags,
    // full frame every `redetect_every` frames (bench tracking, desk: 3.9 ms a frame against 16.2
    // at the same error). `play` and `live` take --full-frame to turn it off.
    tracking::TrackerOptions tracker = [] {
        tracking::TrackerOptions o;
        o.tracking_mode = true;
        return o;
    }();
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

    // Every frame of `source` through the pipeline until the source ends, fails, a callback says
    // stop or `stop` is requested: real time with the pipeline thread, or in order with `sync`
    // (see above). Frames whose status is not ok are skipped.
    LoopStats run(FrameSource& source, const LoopCallbacks& callbacks, std::stop_token stop);

    // The pipeline stage of one frame whose status is ok: conversion, tracking, the virtual
    // objects' poses at the frame's time, the frame to the lighting thread (in sync mode its
    // update finishes first). The result goes into `out` (its buffers are reused). A frame that
    // cannot be converted is kBadInput (counted: the caller warns and goes on); any other error
    // ends the run.
    Result<void> track(const Frame& frame, TrackedFrame& out);
    // The main thread's stage: composites `frame` with the newest lighting snapshot, writes the
    // outputs, measures against ground truth (in real time on the measuring thread, which run()
    // waits for before it returns; nothing without a compositor but the count).
    Result<void> composite(const TrackedFrame& frame);
    // Draws `frame` again with the virtual objects where they are now (moved while paused or while
    // the camera is lost), into the window and composite(); no outputs, no metrics.
    Result<void> redraw(const TrackedFrame& frame);
    // track() then composite() on the caller's thread.
    Result<tracking::FrameTrack> process(const Frame& frame);
    // Real time with lighting, before run(): tracks `first` (a throwaway tracker: nothing is
    // counted) and waits for the lighting thread's first update from it
    // (LightingStage::warmUp), so playback starts lit. False when there is nothing to do (sync,
    // no lighting) or no pose in the frame.
    Result<bool> warmUp(const Frame& first, double timeout_s = 60.0);

    // The figures of the last composite (main thread), for the window's overlay.
    struct CompositeInfo {
        double latency_ms = 0.0;                       // frame arrival to composite ready
        std::uint64_t lighting_version = 0;            // the snapshot drawn with (0: none yet)
        std::optional<double> lighting_lag_ms;         // the frame's timestamp minus the snapshot's
        std::optional<double> lighting_lag_frames;
    };
    const CompositeInfo& lastComposite() const noexcept { return last_composite_; }

    // The newest composite (RGB8), when compositing; empty before the first frame.
    const Image& compositeImage() const noexcept { return composite_; }
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
    std::optional<QualityGovernor> governor_;  // the real-time loop's, when adapt_quality
    std::optional<LightingPacer> pacer_;       // real time with lighting_every 0 (pipeline thread)
    capture::PixelConverter converter_;
    TrackedFrame sync_frame_;  // process()'s frame
    std::optional<std::int64_t> first_timestamp_;
    mutable std::mutex offsets_mutex_;
    std::vector<Eigen::Vector3d> offsets_;  // per virtual object, world metres; guarded by offsets_mutex_
    std::unique_ptr<render::GlContext> context_;
    std::unique_ptr<render::Compositor> compositor_;
    std::unique_ptr<CompositeWriter> writer_;
    Image composite_;
    // The composites against the recording's ground truth (in real time on a thread of its own).
    std::unique_ptr<CompositeMeasurer> measurer_;
    SampleReservoir lag_ms_;       // frame timestamp minus the snapshot's, per composite
    SampleReservoir lag_frames_;
    SampleReservoir latency_ms_;   // frame arrival to composite ready
    CompositeInfo last_composite_;
    std::uint64_t processed_ = 0;  // frames composited (main thread)
    std::uint64_t tracked_ = 0;    // frames tracked (pipeline thread)
    std::int64_t last_frame_ns_ = 0;  // the last tracked frame's timestamp and sequence number
    std::uint64_t last_sequence_ = 0;
    double frame_period_ns_ = 0.0;
    bool side_by_side_done_ = false;
    std::optional<LoopStats> loop_stats_;  // the last run()'s
    std::uint64_t bad_frames_ = 0;

    LoopStats runInOrder(FrameSource& source, const LoopCallbacks& callbacks, std::stop_token stop);
    LoopStats runPipelined(FrameSource& source, const LoopCallbacks& callbacks, std::stop_token stop);
    Result<void> draw(const TrackedFrame& frame, const std::vector<std::optional<Rigid3d>>& poses,
                      lighting::SnapshotPtr* used);
};

}  // namespace commonlight::pipeline

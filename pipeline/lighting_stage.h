// The lighting stage of `play` and `live`: frames with their camera pose go to the lighting
// thread (lighting/engine.h); the metrics JSON gains its `lighting` section (docs/cli.md),
// including the error of the predicted ratio B/B~ in the region the virtual objects change,
// against the sequence's ground truth when it has it (groundtruth/composite/ and
// groundtruth/masks/changed/).
#pragma once

#include <condition_variable>
#include <filesystem>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/camera_model.h"
#include "core/frame.h"
#include "core/image.h"
#include "core/pose.h"
#include "core/response.h"
#include "core/scene.h"
#include "core/sequence_io.h"
#include "lighting/engine.h"

namespace commonlight::pipeline {

// The response of a sequence's camera: `override_spec` (--response) when given, else sensor.yaml's
// `response` (relative files against the cam0 folder). Errors name the spec or file.
Result<ResponseCurve> sequenceResponse(const Sequence& sequence, const std::string& override_spec);

// Shadow-region ratio errors: the predicted B/B~ against the truth's composite / frame (both
// linearised with the camera's response), over masks/changed pixels not covered by a virtual
// object (masks/virtual when present).
class RatioErrors {
public:
    void add(const Image& predicted, const ImageView& frame_rgb8, const ImageView& composite_rgb8, const ImageView& changed,
             const ImageView* virtual_coverage, const ResponseCurve& response);
    std::size_t count() const noexcept { return errors_.size(); }
    // {"rms", "mean_signed", "pixels", "frames"}
    nlohmann::json json() const;

private:
    std::vector<double> errors_;
    std::size_t frames_ = 0;
};

class LightingStage {
public:
    // A lighting thread for the scene and camera (sync: every frame processed before the next).
    // Ground truth is looked for in `sequence` when given. `update_every`: in real time, solve for
    // every n-th frame at most (lighting::EngineOptions::update_every).
    static Result<std::unique_ptr<LightingStage>> create(const Scene& scene, const CameraModel& camera,
                                                         const ResponseCurve& response, std::optional<double> radiance_scale,
                                                         bool sync, const Sequence* sequence, int update_every = 1);
    ~LightingStage();

    // One frame: `rgb8` at the camera's size, its pose (nullopt: counted, contributes nothing), the
    // virtual objects' world_from_object (by Scene::virtual_objects index). In sync mode it returns once the
    // snapshot for this frame is published, and measures the ratio error on every 5th frame; in
    // real time every 5th frame is copied to the stage's measuring thread (newest wins: a frame
    // still waiting when the next comes goes unmeasured; a quarter of the pixels), so reading the
    // ground truth and tracing the ratio (40-60 ms at every pixel on the sample) never holds up
    // the pipeline thread.
    Result<void> process(const ImageView& rgb8, const FrameMetadata& meta, const std::optional<Rigid3d>& cam_from_world,
                         const std::vector<Rigid3d>& virtual_poses);
    void stop();
    // Real time, before the first frame: the lighting thread's first update from this frame, waited
    // for (at most `timeout_s`), so the frames that follow are drawn lit instead of waiting for the
    // first full update (about a second on the sample). Not counted among the frames processed;
    // when the same frame (its timestamp) then comes to process(), it is counted and measured but
    // not observed again. Errors: the update's (kBadInput ...), kTimeout.
    Result<void> warmUp(const ImageView& rgb8, const FrameMetadata& meta, const Rigid3d& cam_from_world,
                        const std::vector<Rigid3d>& virtual_poses, double timeout_s);

    lighting::SnapshotPtr latest() const { return engine_->latest(); }
    // In real time, solve for every n-th frame at most from now on (LightingEngine::setUpdateEvery).
    void setUpdateEvery(int n) { engine_->setUpdateEvery(n); }
    // The full updates published so far (the lights refitted).
    std::uint64_t fullUpdates() const { return engine_->fullUpdates(); }
    nlohmann::json metricsJson() const;
    // Two lines for the summary.
    std::string summary() const;

private:
    LightingStage() = default;
    // `wait`: for an update in progress (sync; real time, once the run is over). False: not
    // waiting, an update was in progress (nothing measured).
    Result<bool> measure(const ImageView& rgb8, const FrameMetadata& meta, const Rigid3d& cam_from_world, bool wait);
    // The frame and the objects' poses to the engine (no count, no measurement).
    Result<void> submit(const ImageView& rgb8, const FrameMetadata& meta, const std::optional<Rigid3d>& cam_from_world,
                        const std::vector<Rigid3d>& virtual_poses);

    // Real time: the measuring thread's loop, and what process() hands it.
    void measureLoop();
    struct MeasureJob {
        Image rgb;
        FrameMetadata meta;
        Rigid3d cam_from_world;
    };

    std::unique_ptr<lighting::LightingEngine> engine_;
    Scene scene_;
    ResponseCurve response_;
    bool sync_ = false;
    const Sequence* sequence_ = nullptr;
    bool have_truth_ = false;
    RatioErrors ratio_errors_;  // (under measure_mutex_)
    std::uint64_t frames_ = 0;
    mutable std::mutex measure_mutex_;
    std::condition_variable measure_wake_;
    std::optional<MeasureJob> measure_job_;  // the newest frame to measure (real time)
    bool measure_stop_ = false;
    bool measure_warned_ = false;
    std::thread measurer_;
    std::optional<std::int64_t> warmed_;  // the timestamp of warmUp()'s frame, until process() has it
};

}  // namespace commonlight::pipeline

// The per-frame pipeline shared by `play` and `live`: pixel conversion and tracking, with the
// pose error against ground truth when the caller has it.
//
// Ground truth comes from a recorded sequence (groundtruth/cam_poses.csv). `play` finds a
// frame's truth by its timestamp; `live` gets frames from a device, with the device's own
// timestamps, so it finds the truth by the frame's pixels: a camera that serves a recording
// (serve-gige, or any bit-exact path) delivers the recorded bytes, and a hash of them names the
// recorded frame.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <unordered_map>
#include <vector>

#include <nlohmann/json.hpp>

#include "capture/convert.h"
#include "capture/stage_timings.h"
#include "core/camera_model.h"
#include "core/frame.h"
#include "core/pose.h"
#include "core/scene.h"
#include "core/sequence_io.h"
#include "tracking/tracker.h"

namespace commonlight::pipeline {

// 64-bit FNV-1a of a view's pixel bytes (row by row, padding excluded), with its format and size.
std::uint64_t pixelHash(const ImageView& view) noexcept;

class GroundTruth {
public:
    // The sequence's poses. With `by_content`, every frame file is read once and hashed as
    // stored, as RGB8 and as GRAY8 (errors name the file). kBadInput when the sequence has no groundtruth/cam_poses.csv.
    static Result<GroundTruth> fromSequence(const Sequence& sequence, bool by_content);

    // world_from_cam of the frame with this timestamp, or of the recorded frame with these pixels,
    // at the middle of its exposure (groundTruthOfFrame, core/sequence_io.h).
    std::optional<Rigid3d> atTimestamp(std::int64_t timestamp_ns) const;
    std::optional<Rigid3d> ofPixels(const ImageView& view) const;
    bool byContent() const noexcept { return !by_hash_.empty(); }

private:
    std::unordered_map<std::int64_t, Rigid3d> by_timestamp_;
    std::unordered_map<std::uint64_t, Rigid3d> by_hash_;
};

// Rotation (degrees) and camera-centre (millimetres) errors of the frames that had both a pose
// and a truth.
class PoseErrors {
public:
    void add(const Rigid3d& cam_from_world, const Rigid3d& world_from_cam_true);
    std::size_t count() const noexcept { return rot_deg_.size(); }
    // {"rot_deg": {p50, p95, max}, "trans_mm": {...}, "frames": n} (docs/cli.md's pose_error).
    nlohmann::json json() const;
    // One line for the summary.
    std::string summary() const;

private:
    std::vector<double> rot_deg_;
    std::vector<double> trans_mm_;
};

struct PipelineOptions {
    tracking::TrackerOptions tracker;
    // Truth lookup: by timestamp (recordings) or by pixels (live cameras serving a recording).
    const GroundTruth* ground_truth = nullptr;
};

// Stages "convert" and "track" (milliseconds) go into the caller's StageTimings.
class FramePipeline {
public:
    // Tracking needs the camera model and the scene's tags. `scene` is borrowed (edge refinement
    // reads its proxies) and must outlive the pipeline.
    static Result<FramePipeline> create(const CameraModel& camera, const Scene& scene, const PipelineOptions& options,
                                        capture::StageTimings& timings);

    // One frame. A frame that cannot be converted or has the wrong size is kBadInput (the
    // caller counts it and goes on); a detector failure is kInternal.
    Result<tracking::FrameTrack> process(const Frame& frame);

    // Forgets the motion (the filter and the tracked windows): for a new connection, whose
    // timestamps may start over. The error statistics are kept.
    Result<void> restart();

    const PoseErrors& poseErrors() const noexcept { return errors_; }
    std::uint64_t framesWithPose() const noexcept { return with_pose_; }
    std::uint64_t framesWithoutTruth() const noexcept { return without_truth_; }

private:
    FramePipeline(tracking::Tracker tracker, const CameraModel& camera, const Scene& scene,
                  const tracking::TrackerOptions& tracker_options, const PipelineOptions& options,
                  capture::StageTimings& timings);

    tracking::Tracker tracker_;
    CameraModel camera_;
    const Scene* scene_;
    tracking::TrackerOptions tracker_options_;
    PipelineOptions options_;
    capture::StageTimings* timings_;
    capture::StageTimings::StageId convert_stage_;
    capture::StageTimings::StageId track_stage_;
    capture::PixelConverter converter_;
    Image gray_;
    PoseErrors errors_;
    std::uint64_t with_pose_ = 0;
    std::uint64_t without_truth_ = 0;
};

}  // namespace commonlight::pipeline

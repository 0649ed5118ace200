// The camera pose from every corner of every scene tag in view, solved as one pose.
//
// Step 1 collects the corners of tags the scene places (world_from_tag); tags it does not know
// are listed and ignored. Step 2 starts from each tag's single-tag candidates (and the temporal
// prediction) mapped to the world, ranked by their robust cost over all corners. Step 3 runs
// Levenberg-Marquardt with Huber weights on the reprojection error in the distorted image from
// each distinct start (at most three), the lowest final cost winning; with a prediction, its own
// start is refined first and, ending near it, is the answer (predicted_minimum_deg). Step 4
// rejects the worst tag while its RMS exceeds the outlier threshold (a misplaced or moved tag, a
// wrong decoding) and solves again. The covariance comes from the Jacobian at the solution
// (pose_types.h convention).
//
// Hard cases: world coordinates far from the origin (1 km) are solved about the tags' centroid,
// so nothing cancels catastrophically; a single tag is allowed (8 corners' worth of
// information is 4 corners: the covariance says so); degenerate tags are dropped by the
// single-tag solver before they get here.
#pragma once

#include <optional>
#include <span>
#include <vector>

#include "core/camera_model.h"
#include "core/scene.h"
#include "tracking/pose_types.h"
#include "tracking/tag_detector.h"
#include "tracking/tag_pose.h"

namespace commonlight::tracking {

struct BundleOptions {
    double huber_px = 1.0;         // Huber threshold of the corner residual, pixels
    double outlier_px = 3.0;       // a tag whose corner RMS exceeds this after the fit is rejected
    double corner_sigma_px = 0.5;  // assumed corner noise for the covariance (raised when the residuals say more)
    int max_iterations = 30;
    // A start that cannot end below an earlier start's cost is given up (bundle.cpp's refine; the
    // same result up to rounding where it would have reached the winner's own minimum).
    bool give_up_hopeless_starts = true;
    // With a prediction, its own start is refined first: ending within this many degrees of it,
    // it is the answer, and the other starts (other minima: the planar ambiguity of the whole
    // board) are neither ranked nor refined; else the starts are ranked and refined as without a
    // prediction, until the best fit so far lies that near it. The tracker's prediction is the
    // motion model's: a pose near it is the one tracked, and a start refined to the same minimum
    // adds nothing (docs/tracking.md, "Speed (issue 13)", change 22). 0: every distinct start is
    // ranked and refined.
    double predicted_minimum_deg = 2.0;
    Result<void> validate() const;
};

// A detected tag with its single-tag solution (nullopt when that failed: the tag is skipped).
struct BundleTag {
    const TagDetection* detection = nullptr;
    const TagPose* single = nullptr;  // may be null: the tag then only contributes corners
    // Its corners' weight in the fit, relative to a detected tag's (1 / their variance ratio): a
    // tag verified at its predicted place (tracker step 3b) has less precise corners.
    double weight = 1.0;
};

struct BundleResult {
    Rigid3d cam_from_world;
    Matrix6d covariance = Matrix6d::Identity();
    std::vector<int> tags_used;      // ids
    std::vector<int> tags_rejected;  // ids rejected as outliers
    std::vector<int> tags_unknown;   // ids the scene does not place
    double rms_px = 0.0;             // over the corners of the tags used
    int iterations = 0;              // of the start that won
    int iterations_all_starts = 0;   // summed over every start refined (the last outlier round's)
};

// Fails with kBadInput when no tag of the scene is among `tags` or no start reprojects the
// corners in front of the camera.
Result<BundleResult> solveBundle(std::span<const BundleTag> tags, const TagSet& scene_tags, const CameraModel& camera,
                                 const std::optional<Rigid3d>& predicted_cam_from_world = std::nullopt,
                                 const BundleOptions& options = {});

}  // namespace commonlight::tracking

// The pose of one tag from its four corners, with the planar ambiguity kept and resolved.
//
// A square seen from far away or nearly head-on has two poses that reproject almost equally well
// (the tag tilted one way or mirrored the other way). Step 1 undistorts the corners with the
// calibration; step 2 gets both candidates from OpenCV's IPPE for squares (solvePnPGeneric,
// SOLVEPNP_IPPE_SQUARE); step 3 refines each with Levenberg-Marquardt on the reprojection error in
// the distorted image (solvePnPRefineLM with the lens model); step 4 chooses by the temporal
// prediction when there is one, else by the residual, and reports the ambiguity ratio.
// With a prediction within half the gate of one IPPE start and more than twice the gate from
// the other, the other is not refined: it stays the alternative as IPPE gave it (its residual
// the corner RMS of that pose), since LM cannot move it near enough to the prediction to win.
//
// Hard cases handled on purpose (each has a test in tests/tracking/tag_pose_test.cpp):
// - exactly fronto-parallel, noise-free corners, where OpenCV 4.6's IPPE can return NaN or a
//   degenerate second solution: non-finite or duplicate candidates are dropped, and when none is
//   left the pose comes from the homography decomposition instead;
// - degenerate corners (duplicated, collinear, self-crossing, a corner beyond the lens model):
//   an error, never NaN;
// - very small tags (~12 px): solved; the ambiguity ratio says how far to trust the choice.
#pragma once

#include <optional>
#include <vector>

#include "core/camera_model.h"
#include "core/result.h"
#include "tracking/pose_types.h"
#include "tracking/tag_detector.h"

namespace commonlight::tracking {

struct TagPoseOptions {
    double corner_sigma_px = 0.5;  // assumed corner noise (1 sigma, pixels) for the covariance
    // With a prediction, a candidate whose rotation is within this of the predicted one wins
    // over a candidate with a smaller residual (the residuals of the two differ by noise only).
    double prediction_gate_deg = 20.0;
    // Without a prediction, the two candidates' residual ratio (chosen over other, in [0, 1])
    // above which the residuals cannot tell them apart: the pose is reported `ambiguous`
    // (docs/tracking.md, "Ambiguous single tags": measured on synthetic 12-42 px tags).
    // Corner residuals (a tag too small for its pattern to be aligned) and the cell pattern's
    // alignment residuals (the tracker aligns both candidates) have their own threshold.
    double ambiguous_corner_ratio = 0.3;
    double ambiguous_pattern_ratio = 0.7;
    // Likewise when the chosen pose's rotation is this uncertain (1 sigma along its worst axis,
    // from its covariance): a small tag seen nearly head-on, whose tilt the image hardly fixes.
    double ambiguous_rotation_sigma_deg = 2.0;
    // With a prediction that clearly tells the two IPPE starts apart (solveTagPose's shortcut:
    // one within half the gate, the other beyond twice it), false returns the near start as IPPE
    // gave it instead of refining it with Levenberg-Marquardt (TagPose::refined is then false):
    // for a caller that refines the pose itself from there (the tracker's pattern alignment),
    // and solves again with this on when its own refinement fails.
    bool refine_predicted_start = true;
    // For corners that came from the prediction itself (the tracker's verified tags: the
    // predicted corners moved by the template's best shift, within a pixel or so):
    // Levenberg-Marquardt starts at the prediction and IPPE is not run, unless the prediction's
    // planar mirror is within half the gate of it. The refined pose must stay within half the gate
    // of the prediction and, when the prediction is nearly head-on (its mirror within twice the
    // gate), at most half as far from it as the refined pose's own mirror is (else the solve is
    // done as without this); the alternative is that mirror,
    // unrefined, with its corner residual, as IPPE's far start stays unrefined in the shortcut:
    // corners made from the prediction cannot tell its two sides apart (docs/tracking.md,
    // "Speed (issue 13)", changes 18 and 21).
    bool start_at_prediction = false;
    Result<void> validate() const;
};

struct TagPoseCandidate {
    Rigid3d cam_from_tag;
    double rms_px = 0.0;  // reprojection RMS of the 4 corners in the distorted image
};

enum class PoseChoice {
    kOnlyCandidate,  // the second candidate did not exist or coincided with the first
    kResidual,       // the smaller reprojection error won
    kPrediction,     // the candidate closer to the temporal prediction won
    kPattern,        // the smaller residual of the tag's cell pattern aligned from each candidate (tracker)
    kScene,          // the candidate that agrees with the scene's other tags in view (tracker, bundle)
    kEdges,          // the candidate whose camera pose the proxies' edges confirm (tracker, edge refinement)
};
const char* poseChoiceName(PoseChoice choice) noexcept;

struct TagPose {
    int id = -1;
    Rigid3d cam_from_tag;  // the chosen candidate, refined
    double rms_px = 0.0;
    // Reprojection error of the chosen candidate over the other's (sum of squares, both floored at
    // 1e-6 px^2), in [0, 1] when chosen by residual: near 0 unambiguous, near 1 ambiguous. Can
    // exceed 1 when the prediction chose the candidate with the larger residual.
    double ambiguity_ratio = 0.0;
    PoseChoice choice = PoseChoice::kOnlyCandidate;
    // Nothing chose (no prediction, no other evidence) and the residuals cannot tell the two
    // candidates apart (ambiguity_ratio above TagPoseOptions' threshold): cam_from_tag is the one
    // with the smaller residual, candidates[1] the other, and either may be the truth.
    bool ambiguous = false;
    std::vector<TagPoseCandidate> candidates;  // 1 or 2, refined; candidates[0] is the chosen one
    Matrix6d covariance = Matrix6d::Identity();  // of cam_from_tag (pose_types.h convention)
    // False only with TagPoseOptions::refine_predicted_start off, when the shortcut applied:
    // cam_from_tag (candidates[0]) is IPPE's pose from the undistorted corners, unrefined.
    bool refined = true;
};

// `corners` are distorted pixels (OpenCV convention) in libapriltag's order; `size` is the black
// square's edge in metres. `predicted_cam_from_tag` is the filter's prediction for this frame.
// Fails with kBadInput for degenerate corners, a non-positive size, or corners the lens model
// cannot undistort; never returns a non-finite pose, nor an unrefined one unless
// TagPoseOptions::refine_predicted_start is off (see there).
Result<TagPose> solveTagPose(int id, const std::array<Eigen::Vector2d, 4>& corners, double size,
                             const CameraModel& camera, const std::optional<Rigid3d>& predicted_cam_from_tag = std::nullopt,
                             const TagPoseOptions& options = {});

// The standard deviation of a pose's rotation along its worst axis (degrees), from its covariance
// (pose_types.h convention).
double rotationSigmaDeg(const Matrix6d& covariance);

// The other side of the planar ambiguity, approximately (weak perspective): the tag's normal
// reflected about the line of sight to its centre, the same centre. A start for refinement
// when the solver found one candidate only.
Rigid3d planarMirror(const Rigid3d& cam_from_tag);

// Checks four image corners of a quad: finite, pairwise at least `min_separation_px` apart, no
// three (nearly) collinear, convex and not self-crossing. The error names the defect.
Result<void> checkQuadCorners(const std::array<Eigen::Vector2d, 4>& corners, double min_separation_px = 0.5);

// Reprojection RMS (pixels) of the four corners of a tag of edge `size` at cam_from_tag;
// infinity when a corner is behind the camera or outside the lens model.
double tagReprojectionRms(const std::array<Eigen::Vector2d, 4>& corners, double size, const CameraModel& camera,
                          const Rigid3d& cam_from_tag);

}  // namespace commonlight::tracking

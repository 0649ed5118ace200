// Model-edge refinement of the camera pose (seed 000, section 3.1: the calibration is refined by
// maximising the image gradient at the projections of model edges). docs/edge-refine.md
// has the model, the parameters and how failures are reported.
//
// Pipeline of refinePoseWithEdges, coarse to fine over an image pyramid:
//   Step 1: sample points along the projected model edges (tracking/edge_model.h) every
//           sample_spacing_px; keep those on an edge with a front-facing adjacent face (or a
//           silhouette), not hidden by any proxy, inside the image;
//   Step 2: at each point search +-search_px (pixels of the pyramid level) along the projected
//           edge's normal for the strongest image gradient, with one polarity per edge;
//   Step 3: one robust (Tukey) Gauss-Newton step on the point-to-edge distances over the 6-dof
//           left perturbation of cam_from_world, plus the optional Gaussian prior;
//   repeat Steps 1-3 `iterations` times per level, then go one level finer.
// The search is done in the distorted image with CameraModel::project, so lens distortion is
// handled exactly. refinePoseWithEdges keeps no state between calls: calls on different threads
// may share one EdgeModel.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "core/camera_model.h"
#include "core/image.h"
#include "core/pose.h"
#include "core/result.h"
#include "tracking/edge_model.h"
#include "tracking/pose_types.h"

namespace commonlight::tracking {

struct EdgeRefineOptions {
    // Search range along the normal, +- pixels of each pyramid level (so +- 48 full-resolution
    // pixels on the coarsest of three levels). Measured on the desk (640x480, 1.2 m): starts 3
    // degrees and 37 mm off converge every time with 12, 93 % of the time with 8.
    double search_px = 12.0;
    double sample_spacing_px = 6.0;   // distance between sample points along a projected edge, full-resolution pixels
    int iterations = 6;               // search + Gauss-Newton steps per pyramid level (at most)
    // A level's iterations end when a step moves the points by less than 0.01 full-resolution
    // pixels; on the coarser levels, which only bring the pose within the next level's reach,
    // by less than this many of the level's own pixels (0: 0.01 px everywhere). Measured on the
    // desk sample: 0.1 takes 2-3 steps off the middle level, with the same errors.
    double coarse_converged_px = 0.1;
    int pyramid_levels = 3;           // 1 = full resolution only; each level halves the image
    double blur_sigma_px = 1.0;       // Gaussian blur of the full-resolution image before the gradients (0: none)
    double min_gradient = 6.0;        // grey levels per pixel; weaker maxima are not edges
    int min_points = 40;              // fewer matched points than this: not ok
    int min_edges = 3;                // fewer model edges with matched points than this: not ok
    double tukey_px = 2.5;            // Tukey biweight cut-off at full resolution (scaled by 2^level), pixels
    double image_margin_px = 4.0;     // sample points closer than this to the image border are not used
    double occlusion_epsilon = 1e-3;  // metres before a sample point that a ray may hit its own surface
    double min_sigma_px = 0.1;        // floor of the residual standard deviation used for the covariance
    // Smallest ratio of the smallest to the largest eigenvalue of the information matrix (translation
    // scaled by the median depth, so rotations and translations compare); below: poorly constrained.
    double min_information_ratio = 1e-4;
    double max_rms_px = 2.0;  // a final weighted rms distance above this: not ok (did not converge)
    // Fewer of the visible sample points matching the image at the refined pose than this: not ok.
    // A pose that converged onto the wrong image edges matches few of them (measured on the desk:
    // 86 to 93 % at the true pose, 12 to 51 % at wrong ones). Lower it for cluttered scenes with
    // poorly modelled or low-contrast edges.
    double min_inlier_fraction = 0.6;
    // With a prior, start at the finest pyramid level whose search range holds where the prior
    // allows the pose to be: the initial pose's distance from the prior's plus `prior_sigmas` of
    // the prior's standard deviation, as image motion, within half the level's +-search_px. A
    // tag bundle's prior (a fraction of a pixel) starts at full resolution, and the coarse levels'
    // iterations (each moving the pose away by their own blur's bias, then back) are skipped.
    // 0: always start at the coarsest level.
    double prior_sigmas = 3.0;

    // Names the bad field.
    Result<void> validate() const;
};

struct EdgeRefineResult {
    bool ok = false;
    std::string reason;  // why not ok: "2 edges visible, need 3", "poorly constrained: ..."
    // The refined pose when ok; the initial pose otherwise.
    Rigid3d cam_from_world;
    // Covariance of the refined pose (pose_types.h convention): the edges' cluster-robust
    // covariance (docs/edge-refine.md), fused with the prior's information when a prior is given.
    // Zero when not ok.
    Matrix6d covariance = Matrix6d::Zero();
    int edges_used = 0;                  // model edges with at least one matched point (final iteration)
    int points_used = 0;                 // matched points with a non-zero robust weight (final iteration)
    int points_visible = 0;              // sample points that passed the visibility tests (last sampling)
    double rms_px = 0.0;                 // weighted rms point-to-edge distance, full-resolution pixels
    int iterations = 0;                  // Gauss-Newton steps taken over all levels
    int first_level = 0;                 // the pyramid level the refinement started at (prior_sigmas)
    std::vector<int> points_per_object;  // points_used by real object (EdgeModel::objectNames order)
    // Wall-clock time of the refinement, and of its steps summed over the iterations.
    double seconds = 0.0;
    struct StepSeconds {
        double pyramid = 0.0;   // blur, gradients, pyramid
        double sampling = 0.0;  // Step 1: projection, facing and occlusion tests
        double search = 0.0;    // Step 2: gradient search along the normals
        double solve = 0.0;     // Step 3 and the final covariance
    } step_seconds;
};

// Refines cam_from_world_initial against the edges of `model` in `gray8` (PixelFormat::kGray8,
// the distorted image of `camera`). `prior`, when given, is a Gaussian pose prior (pose_types.h
// convention; its timestamp is ignored) added to the cost, so that tags and edges are fused.
// Errors (kBadInput) only for bad input: wrong pixel format, an image size that does not match
// the camera, an invalid camera, a non-finite initial pose or prior; kUsage for invalid options.
// Too little to go on (too few visible edges or points, a poorly constrained system, no
// convergence) is a result with ok = false and a reason.
Result<EdgeRefineResult> refinePoseWithEdges(const ImageView& gray8, const CameraModel& camera, const EdgeModel& model,
                                             const Rigid3d& cam_from_world_initial, const EdgeRefineOptions& options,
                                             const std::optional<PoseMeasurement>& prior = std::nullopt);

}  // namespace commonlight::tracking

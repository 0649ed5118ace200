// Parts of the tracker (tracker.cpp) kept apart: the image windows the detector runs on, and the
// late tags of step 3b that are aligned from their prediction instead of detected again.
#pragma once

#include <array>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "core/camera_model.h"
#include "tracking/edge_model.h"
#include "tracking/tag_align.h"
#include "tracking/tag_detector.h"
#include "tracking/tracker.h"

namespace commonlight::tracking::tracker_support {

// A tag the last frame detected, predicted where it was and missed by the decimated detector, is
// aligned from the prediction instead of detected again at full resolution
// (TrackerOptions::redetect_align_known) only when its shorter projected side is at least this
// fraction of its longer: on tags turned 75-80 degrees (`bench tracking --cases tiny75`, spans of
// 14-20 px) the alignment alone accepted tags the detector misses there, with corners 1.0 px from
// the truth (p50) against 0.88 for the detected ones, and the camera pose was 12 % worse
// (docs/tracking.md, "Speed (issue 13)", sixth round).
inline constexpr double kMinAspectAlignedKnown = 0.5;

// The box around image points, grown by `margin` of its size and at least `min_px` pixels.
PixelWindow grownBox(const std::array<Eigen::Vector2d, 4>& pts, double margin, int min_px);

// Overlapping windows (the tags of one board) become their bounding box: the detector then
// sees each tag once, whole, and pays its per-call cost once.
std::vector<PixelWindow> mergeOverlapping(std::vector<PixelWindow> windows);

// Tracking mode's windows (TrackerOptions::tracking_mode): around each scene tag `predicted`
// puts in the image whose black square's shorter span is at least window_min_span_px times the
// decimation, that faces the camera and that `occluders` (when given) do not hide, and where the
// last frame detected the others (tags the scene does not place, or all of them without a
// prediction); merged where they overlap.
std::vector<PixelWindow> trackingWindows(const CameraModel& camera, const TagSet& tags,
                                         const std::optional<Rigid3d>& predicted,
                                         const std::vector<TagDetection>& last_detections,
                                         const TrackerOptions& options, const EdgeModel* occluders = nullptr);

// Whether the tag's printed side (+z, docs/formats-scene.md) faces away from the camera: the
// camera centre on its plane or behind it.
bool facesAway(const Rigid3d& cam_from_tag);

// Whether the proxies hide the tag from `eye` (world): `min_hidden` or more of 3 x 3 points on
// its black square (0.4 of its size apart) behind them. The verification skips a tag at 3; a
// window is not drawn only at 9 (the detector still found tags with 3-8 of them hidden on `bench
// tracking --cases occluded`).
bool hiddenByProxies(const EdgeModel& occluders, const Eigen::Vector3d& eye, const TagItem& item, int min_hidden);

// A quad's shorter side over its longer (opposite sides averaged); 0 for a degenerate one.
double squareAspect(const std::array<Eigen::Vector2d, 4>& corners);

// A quad's shorter span: the shorter distance between the midpoints of opposite sides.
double shorterSpan(const std::array<Eigen::Vector2d, 4>& corners);

// The tag `id` (black square `size` metres) as aligned from its prediction: its corners where the
// aligned pose puts them, that pose its only candidate, chosen by the prediction
// (TrackedTag::aligned_known). nullopt when the alignment failed or a corner does not project.
std::optional<TrackedTag> alignedKnownTag(const TagAlignResult& aligned, int id, double size, const CameraModel& camera);

}  // namespace commonlight::tracking::tracker_support

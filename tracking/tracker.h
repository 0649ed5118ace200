// The tracking stage: one call per frame, from the grey image to the camera pose.
//
//   Step 1  detect tags: the whole frame, or (tracking mode) only windows around where the
//           prediction puts the tags; the whole frame again every N frames and whenever the
//           windows find nothing
//   Step 2  corners refined from the tags' edges; single-tag poses; each tag's cell pattern
//           aligned with the image (the candidate the prediction chooses; without one, both
//           candidates, and the pattern's residuals choose or say the tag is ambiguous)
//   Step 3  bundle: one cam_from_world from every corner of the scene's tags; with two or more
//           tags, the bundle chooses each ambiguous tag's candidate
//   Step 4  model-edge refinement (optional): the proxies' edges sharpen the pose, or carry it
//           for a while when no tag is in view
//   Step 5  temporal filter (optional): constant-velocity Kalman filter on SE(3)
// Each step's time is reported in FrameTrack::times. One Tracker per camera; not thread-safe.
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "core/camera_model.h"
#include "core/frame.h"
#include "core/image.h"
#include "core/scene.h"
#include "tracking/bundle.h"
#include "tracking/edge_refine.h"
#include "tracking/pose_filter.h"
#include "tracking/tag_align.h"
#include "tracking/tag_detector.h"
#include "tracking/tag_pose.h"
#include "tracking/tag_refine.h"
#include "tracking/tag_verify.h"

namespace commonlight::tracking {

struct TrackerOptions {
    TagDetectorOptions detector;
    TagPoseOptions tag_pose;
    // Refine each tag's corners from its black square's edges before solving (tag_refine.h).
    bool refine_corners = true;
    TagRefineOptions refine;
    // Align each tag's whole cell pattern with the image after the corner pose (tag_align.h);
    // the tag's corners then become the aligned pose's, so the bundle gets them too.
    bool align_tags = true;
    TagAlignOptions align;
    BundleOptions bundle;
    // Scene tags the frame's camera pose (the bundle of the detected tags, or the prediction when
    // no tag was detected) puts in view but the detector did not find (too small to decode): each
    // is verified at its predicted place against its known pattern (tag_verify.h) and, when
    // accepted, joins the bundle as TrackedTag::verified.
    bool verify_predicted = true;
    TagVerifyOptions verify;
    // With the scene's proxy geometry: a predicted tag whose black square the proxies hide from
    // the predicted camera (3 or more of 9 points on it) is not tried (it cannot match; its
    // verification would cost for nothing).
    bool verify_skip_occluded = true;
    // A verified tag's corners in the bundle weigh this much against a detected tag's: they are
    // the prediction moved by one shift for all four (a 0.125 px grid). Re-tuned after the
    // seventh round's Jacobian fix (docs/tracking.md, after "Speed (issue 13)"'s seventh round):
    // 0.1 -> 0.2 takes `tiny75`'s camera (bundle + filter) rotation p50 0.0149 -> 0.0122 degrees,
    // position p50 0.41 -> 0.35 mm, p95 -9 to -22 % (two renderings); `tiny`'s p50 moved -5 to
    // +11 % over three renderings (no direction common to them), its p95 0-4 % and maxima 3-7 %
    // lower. 0.35-0.5 help `tiny75` more but cost `tiny` up to +40 % at p50 on one rendering;
    // 1.0 costs it +7 to +37 %.
    double verify_bundle_weight = 0.2;
    // A predicted tag the last frame reported (detected or verified) where it is predicted now is
    // verified on its pattern's correlation alone, without comparing the plain square and the
    // other ids (tag_verify.h, `known_at_px`): a third of the verification's correlations. Not
    // in independent frames (nothing is carried from one to the next).
    bool verify_trust_last_frame = true;
    // A verified tag's corners are its prediction's moved by the template's shift: its pose is
    // solved from the prediction (TagPoseOptions::start_at_prediction) instead of IPPE's two
    // starts where the prediction is unambiguous (docs/tracking.md, "Speed (issue 13)").
    bool verify_solve_from_prediction = true;
    // Predicted foreshortened tags the verification leaves to the detector (shorter span over
    // TagVerifyOptions::max_foreshortened_span_px) that the frame's detector missed (decimated):
    // detected again at full resolution (decimate 1) in a window around each, a detected tag like
    // any other; one missed there too is verified. Without this they are not tried at all.
    bool verify_redetect_full_res = true;
    // ... except a tag the last frame detected (by either detector), predicted within half its
    // shorter span of where it was, whose shorter projected side is at least half its longer: its
    // pattern is aligned from the prediction instead (as a detected tag's is from its corners'
    // pose), without the detector (TrackedTag::aligned_known); one whose alignment fails is
    // detected as the others. Not in independent frames.
    bool redetect_align_known = true;
    // Tracking mode: detect only in windows around the predicted tags.
    bool tracking_mode = false;
    int redetect_every = 15;      // full-frame detection every N frames in tracking mode (>= 1)
    double window_margin = 0.5;   // a window is the predicted tag's box grown by this fraction of its size...
    int window_min_margin_px = 12;  // ...and at least this many pixels on each side
    // A predicted scene tag whose black square's shorter span (between the midpoints of opposite
    // sides) is under this many pixels of the decimated image (times detector.decimate in the
    // frame) gets no window: the decimated detector does not find it (`bench tracking`, decimate 2:
    // 3 of 637 tags under 10 px), and its window, merged with its neighbours', can be most of what
    // the windows cost. The verification (verify_predicted) looks for it instead; one the last
    // frame detected keeps a window where it was. 0: a window for every predicted tag.
    double window_min_span_px = 5.0;
    // Tags without a place in the scene (track --tag-size): the edge of every tag's black square.
    // 0: only the scene's tags get a single-tag pose.
    double default_tag_size = 0.0;
    bool filter = true;
    // Independent images (a folder of photos): nothing is carried from one frame to the next (no
    // prediction, no previous pose choosing between a tag's two candidate poses), so each gives
    // what it gives alone, whatever the order. Excludes `filter` and `tracking_mode`.
    bool independent_frames = false;
    PoseFilterOptions filter_options;
    // A measurement the filter's gate refuses is still taken, and the filter started again from
    // it, when it rests on two or more of the scene's tags whose corners the bundle fits within
    // this many pixels RMS (the camera jumped; docs/pose-filter.md "Hard cases").
    double jump_max_rms_px = 1.5;
    bool edges = false;  // needs the scene's proxy geometry
    EdgeRefineOptions edge_options;
    Result<void> validate() const;
};

enum class TrackStatus {
    kTracked,    // from tags (bundle), possibly refined by edges and filtered
    kEdgesOnly,  // no usable tag; the proxies' edges carried the pose from the prediction
    kPredicted,  // nothing measured; the filter's prediction (still recent enough)
    kNoPose,     // no tag of the scene in view and nothing to predict from
    // The pose rests on one tag whose two candidate poses the image cannot tell apart, and nothing
    // (prediction, other tags, proxies' edges) chose: cam_from_world is the candidate with the
    // smaller residual, alternative_cam_from_world the other. The filter is not updated.
    kAmbiguous,
};
const char* trackStatusName(TrackStatus status) noexcept;

struct TrackedTag {
    TagDetection detection;       // corners refined when the options say so (corners_refined)
    bool corners_refined = false;
    bool aligned = false;         // the pose (and the corners) come from the pattern alignment
    // The other candidate's corners (pose->candidates[1]'s: its aligned pose's, or the refined
    // corners when it was not aligned) and whether they are aligned; a tag whose candidate the
    // scene or the edges switch takes them. nullopt: the same corners as the chosen one's.
    std::optional<std::array<Eigen::Vector2d, 4>> alternative_corners;
    bool alternative_aligned = false;
    // Not detected: a scene tag predicted in view and verified there against its pattern
    // (TrackerOptions::verify_predicted); its corners are the verified prediction's.
    bool verified = false;
    // Verified on its pattern's correlation alone: the last frame reported it where it was
    // predicted (TrackerOptions::verify_trust_last_frame).
    bool verified_known = false;
    // Detected late: a scene tag the frame's (decimated) detector missed, found by the detector at
    // full resolution in a window around its prediction (TrackerOptions::verify_redetect_full_res).
    bool detected_late = false;
    // ... found late without the detector: the last frame detected it where it is predicted now,
    // and its pattern aligned from the prediction (TrackerOptions::redetect_align_known).
    bool aligned_known = false;
    std::optional<TagPose> pose;  // nullopt: unknown size, or the solver refused (see error)
    std::string error;            // why there is no pose
};

struct StageTimes {
    // Wall-clock time of each step, milliseconds.
    double detect_ms = 0, tag_pose_ms = 0, bundle_ms = 0, verify_ms = 0, edges_ms = 0, filter_ms = 0, total_ms = 0;
    // The calling thread's CPU time (CLOCK_THREAD_CPUTIME_ID) of the same steps: what a step costs
    // on a shared, loaded machine, where the wall time also counts the waits for a core. The
    // detection's misses libapriltag's worker threads when TagDetectorOptions::threads > 1. The
    // single-tag step's includes its corner refinement (refine_cpu_ms) and pattern alignment
    // (align_cpu_ms).
    // verify_*: Step 3b, the predicted tags' verification and the bundle solved again.
    double detect_cpu_ms = 0, refine_cpu_ms = 0, align_cpu_ms = 0, tag_pose_cpu_ms = 0, bundle_cpu_ms = 0, verify_cpu_ms = 0,
           edges_cpu_ms = 0, filter_cpu_ms = 0, total_cpu_ms = 0;
};

struct FrameTrack {
    std::int64_t timestamp_ns = 0;  // the frame's (the start of its exposure)
    // The instant every pose of this frame is for (cam_from_world, the tags' cam_from_tag, the
    // filter's update and prediction): the middle of the exposure (core/frame.h midExposureNs);
    // timestamp_ns when the exposure is unknown. docs/tracking.md, "Timestamps".
    std::int64_t pose_timestamp_ns = 0;
    bool full_frame_detection = true;
    std::vector<TrackedTag> tags;
    std::optional<BundleResult> bundle;
    std::optional<EdgeRefineResult> edges;
    TrackStatus status = TrackStatus::kNoPose;
    std::optional<Rigid3d> cam_from_world;  // the stage's answer: filtered when the filter is on
    std::optional<Matrix6d> covariance;
    // Status kAmbiguous: the other candidate's camera pose, and the tag's ambiguity ratio.
    std::optional<Rigid3d> alternative_cam_from_world;
    double ambiguity_ratio = 0.0;
    // The dilation of the tags' black regions (in cells of each tag, > 0 grown): the median of
    // the aligned tags' (TagAlignResult::dilation_cells), used to refine the corners of tags that
    // could not be aligned; in a sequence, the last frame's when no tag was aligned.
    std::optional<double> dilation_cells;
    StageTimes times;
};

class Tracker {
public:
    // `scene_tags`: tags with their world placement (may be empty with default_tag_size).
    // `proxies`: the scene, for edge refinement (options.edges); may be null otherwise.
    static Result<Tracker> create(const CameraModel& camera, const TagSet& scene_tags, const Scene* proxies,
                                  const TrackerOptions& options);
    Tracker(Tracker&&) noexcept;
    Tracker& operator=(Tracker&&) noexcept;
    ~Tracker();

    // `gray8`: the distorted 8-bit grey frame, the calibration's size. `meta`: its timestamp (the
    // start of its exposure; see midExposureNs for end-of-frame sources) and exposure: the poses
    // are for the middle of the exposure (FrameTrack::pose_timestamp_ns), and the filter predicts
    // to, and is updated at, that instant. Frame timestamps must not decrease; a pose instant
    // earlier than the previous frame's (an exposure shrinking by more than twice the frame
    // interval: metadata no camera produces) is raised to the previous one. Errors: a wrong
    // format or size (kBadInput), a detector failure (kInternal). A frame without tags is not an
    // error: status kNoPose (or kPredicted / kEdgesOnly).
    Result<FrameTrack> process(const ImageView& gray8, const FrameMetadata& meta);
    // The exposure unknown: the poses are for `timestamp_ns` itself (an instantaneous exposure).
    Result<FrameTrack> process(const ImageView& gray8, std::int64_t timestamp_ns);

    // The filter's pose at any instant (the renderer asks for the frame's
    // FrameTrack::pose_timestamp_ns); nullopt before the first measurement or with the filter off
    // and no pose yet.
    std::optional<Rigid3d> predict(std::int64_t timestamp_ns) const;

    const TrackerOptions& options() const noexcept;

private:
    struct State;
    explicit Tracker(std::unique_ptr<State> state);
    Result<FrameTrack> processAt(const ImageView& gray8, std::int64_t timestamp_ns, std::int64_t pose_instant_ns);
    std::unique_ptr<State> state_;
};

}  // namespace commonlight::tracking

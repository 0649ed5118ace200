#include "tracking/tracker.h"

#include "tracking/tracker_support.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <ctime>
#include <map>

namespace commonlight::tracking {
namespace {

using namespace tracker_support;

using Clock = std::chrono::steady_clock;
double msSince(Clock::time_point start) {
    return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}
// The calling thread's CPU time (StageTimes).
double threadCpuMs() {
    timespec t{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return static_cast<double>(t.tv_sec) * 1e3 + static_cast<double>(t.tv_nsec) * 1e-6;
}

// An ambiguous tag settled by the camera pose the scene's other tags (step 3) or the proxies'
// edges (step 4) give: the candidate nearer the pose this implies for the tag goes first (a lone
// candidate becomes that pose), and the tag's pose becomes it (its own tilt is what the image
// hardly fixed; both edge starts may have converged onto it from either candidate).
void settleAmbiguousTag(TrackedTag& t, const TagItem& item, const CameraModel& camera, const Rigid3d& cam_from_world,
                        PoseChoice choice) {
    TagPose& p = *t.pose;
    const Rigid3d implied = cam_from_world * item.world_from_tag;
    p.cam_from_tag = implied;
    if (p.candidates.size() > 1) {
        if (rotationErrorDeg(p.candidates[1].cam_from_tag, implied) < rotationErrorDeg(p.candidates[0].cam_from_tag, implied)) {
            std::swap(p.candidates[0], p.candidates[1]);
            p.ambiguity_ratio = 1.0 / p.ambiguity_ratio;
            // The corners go with the candidate: the other one's aligned (or refined) corners.
            if (t.alternative_corners) {
                std::swap(t.detection.corners, *t.alternative_corners);
                std::swap(t.aligned, t.alternative_aligned);
            }
        }
        p.rms_px = tagReprojectionRms(t.detection.corners, item.size, camera, implied);
    } else if (!p.candidates.empty()) {
        p.rms_px = tagReprojectionRms(t.detection.corners, item.size, camera, implied);
        p.candidates[0] = {implied, p.rms_px};
    } else {
        p.rms_px = tagReprojectionRms(t.detection.corners, item.size, camera, implied);
    }
    p.choice = choice;
    p.ambiguous = false;
}

}  // namespace

const char* trackStatusName(TrackStatus status) noexcept {
    switch (status) {
        case TrackStatus::kTracked: return "tracked";
        case TrackStatus::kEdgesOnly: return "edges_only";
        case TrackStatus::kPredicted: return "predicted";
        case TrackStatus::kNoPose: return "no_pose";
        case TrackStatus::kAmbiguous: return "ambiguous";
    }
    return "?";
}

Result<void> TrackerOptions::validate() const {
    CL_TRY_VOID(detector.validate());
    CL_TRY_VOID(tag_pose.validate());
    CL_TRY_VOID(bundle.validate());
    if (redetect_every < 1) return fail(ErrorCode::kUsage, "redetect_every must be >= 1");
    if (!(jump_max_rms_px >= 0) || !std::isfinite(jump_max_rms_px)) {
        return fail(ErrorCode::kUsage, "jump_max_rms_px must be a finite number of pixels >= 0");
    }
    if (!(window_margin >= 0) || window_min_margin_px < 0) return fail(ErrorCode::kUsage, "window margins must be >= 0");
    if (!(window_min_span_px >= 0)) return fail(ErrorCode::kUsage, "window_min_span_px must be >= 0");
    if (!(default_tag_size >= 0) || !std::isfinite(default_tag_size)) {
        return fail(ErrorCode::kUsage, "the tag size must be a positive number of metres");
    }
    if (independent_frames && (filter || tracking_mode)) {
        return fail(ErrorCode::kUsage, "independent frames have no filter and no tracking mode (each frame is tracked alone)");
    }
    if (verify_predicted) {
        const TagVerifyOptions& v = verify;
        if (!(v.min_side_px > 0) || !(v.max_side_px >= v.min_side_px) || !(v.max_foreshortened_span_px >= v.min_side_px) ||
            !(v.search_px >= 0 && v.search_px <= 3) || !(v.search_step_px >= 0.05 && v.search_step_px <= 1) ||
            !(v.min_ncc > 0 && v.min_ncc <= 1) || !(v.min_margin_square >= 0) || !(v.min_margin_other >= 0) ||
            v.other_ids < 0 || !(v.edge_margin_px >= 0) || !(v.min_contrast >= 0) || v.blur_sigma_px.empty() ||
            !(verify_bundle_weight > 0 && verify_bundle_weight <= 1) ||
            std::any_of(v.blur_sigma_px.begin(), v.blur_sigma_px.end(), [](double b) { return !(b >= 0 && b <= 2); })) {
            return fail(ErrorCode::kUsage, "verify options out of range (sides > 0, search 0-3 px in steps of 0.05-1 px, "
                                           "min_ncc in (0, 1], "
                                           "max_foreshortened_span_px >= min_side_px, margins >= 0, blur_sigma_px: one or more in [0, 2], verify_bundle_weight in (0, 1])");
        }
    }
    if (filter) CL_TRY_VOID(filter_options.validate());
    if (edges) CL_TRY_VOID(edge_options.validate());
    return {};
}

struct Tracker::State {
    CameraModel camera;
    TagSet tags;
    TrackerOptions options;
    TagDetector detector;
    // Full resolution, for the foreshortened tags the verification leaves to the detector
    // (TrackerOptions::verify_redetect_full_res); none when `detector` is at full resolution.
    std::optional<TagDetector> full_res_detector;
    TagPatternCache patterns;
    PoseFilter filter;
    std::optional<EdgeModel> edge_model;
    // The proxies as occluders for the verification of predicted tags, when edges are off.
    std::optional<EdgeModel> occluder_model;
    const EdgeModel* occluders() const { return edge_model ? &*edge_model : (occluder_model ? &*occluder_model : nullptr); }
    std::int64_t frames = 0;
    std::int64_t frames_since_full = 0;
    std::optional<std::int64_t> last_timestamp;
    std::optional<std::int64_t> last_pose_instant;        // the last frame's FrameTrack::pose_timestamp_ns
    std::optional<std::int64_t> last_measurement_instant;  // ... of the last frame with a measurement
    // Without the filter: the last pose, used as the prediction.
    std::optional<Rigid3d> last_cam_from_world;
    // The last frame's detections and single-tag poses (windows and predictions for tags the
    // scene does not place).
    std::vector<TagDetection> last_detections;
    std::map<int, Rigid3d> last_cam_from_tag;
    std::optional<double> last_dilation_cells;  // the last frame's tags' dilation (FrameTrack::dilation_cells)
    // Where the last frame's tags (detected or verified) were centred, by id (verify_trust_last_frame),
    // and the ids of those detected (not verified).
    std::map<int, Eigen::Vector2d> last_centres;
    std::vector<int> last_detected;

    State(const CameraModel& c, const TagSet& t, const TrackerOptions& o, TagDetector d)
        : camera(c), tags(t), options(o), detector(std::move(d)), patterns(o.detector.family), filter(o.filter_options) {}

    std::optional<Rigid3d> prediction(std::int64_t timestamp_ns) const {
        if (options.independent_frames) return std::nullopt;
        if (options.filter) {
            if (auto p = filter.predict(timestamp_ns)) return p->cam_from_world;
            return std::nullopt;
        }
        return last_cam_from_world;
    }

    std::vector<PixelWindow> windows(const std::optional<Rigid3d>& predicted) const {
        return trackingWindows(camera, tags, predicted, last_detections, options,
                               options.verify_skip_occluded ? occluders() : nullptr);
    }
};

Result<Tracker> Tracker::create(const CameraModel& camera, const TagSet& scene_tags, const Scene* proxies,
                                const TrackerOptions& options) {
    CL_TRY_VOID(options.validate());
    CL_TRY_VOID(camera.validate());
    CL_TRY(TagDetector detector, TagDetector::create(options.detector));
    auto state = std::make_unique<State>(camera, scene_tags, options, std::move(detector));
    if (options.verify_predicted && options.verify_redetect_full_res && options.detector.decimate > 1.0) {
        TagDetectorOptions full = options.detector;
        full.decimate = 1.0;
        full.threads = 1;  // windows of a few thousand pixels
        full.reference_pose.reset();
        CL_TRY(TagDetector d, TagDetector::create(full));
        state->full_res_detector.emplace(std::move(d));
    }
    if (options.edges) {
        if (!proxies) return fail(ErrorCode::kUsage, "edge refinement needs a scene with proxy geometry");
        CL_TRY(EdgeModel model, EdgeModel::fromScene(*proxies));
        state->edge_model.emplace(std::move(model));
    } else if (options.verify_predicted && options.verify_skip_occluded && proxies && !proxies->real_objects.empty()) {
        // Only an optimisation of the verification: proxies it cannot model (a mesh that was not
        // loaded) leave it without the occlusion test rather than fail the tracker.
        if (auto model = EdgeModel::fromScene(*proxies)) state->occluder_model.emplace(std::move(*model));
    }
    return Tracker(std::move(state));
}

Tracker::Tracker(std::unique_ptr<State> state) : state_(std::move(state)) {}
Tracker::Tracker(Tracker&&) noexcept = default;
Tracker& Tracker::operator=(Tracker&&) noexcept = default;
Tracker::~Tracker() = default;

const TrackerOptions& Tracker::options() const noexcept { return state_->options; }

std::optional<Rigid3d> Tracker::predict(std::int64_t timestamp_ns) const { return state_->prediction(timestamp_ns); }

Result<FrameTrack> Tracker::process(const ImageView& gray8, const FrameMetadata& meta) {
    return processAt(gray8, meta.timestamp_ns, midExposureNs(meta));
}

Result<FrameTrack> Tracker::process(const ImageView& gray8, std::int64_t timestamp_ns) {
    return processAt(gray8, timestamp_ns, timestamp_ns);
}

Result<FrameTrack> Tracker::processAt(const ImageView& gray8, std::int64_t timestamp_ns, std::int64_t pose_instant_ns) {
    State& s = *state_;
    const auto start = Clock::now();
    const double start_cpu = threadCpuMs();
    if (gray8.format != PixelFormat::kGray8) {
        return fail(ErrorCode::kBadInput, "tracking needs an 8-bit grey frame, got " +
                                              std::string(pixelFormatName(gray8.format)));
    }
    CL_TRY_VOID(s.camera.checkImageSize(gray8.width, gray8.height));
    if (s.last_timestamp && timestamp_ns < *s.last_timestamp) {
        return fail(ErrorCode::kBadInput, "frame timestamp " + std::to_string(timestamp_ns) +
                                              " ns is earlier than the previous frame's");
    }
    // Hard case: metadata whose exposure shrinks so fast that this frame's middle comes before
    // the last one's; the filter needs non-decreasing instants.
    if (s.last_pose_instant && pose_instant_ns < *s.last_pose_instant) pose_instant_ns = *s.last_pose_instant;
    const std::int64_t instant = pose_instant_ns;
    FrameTrack out;
    out.timestamp_ns = timestamp_ns;
    out.pose_timestamp_ns = instant;
    const std::optional<Rigid3d> predicted = s.prediction(instant);

    // Step 1: detection.
    auto t0 = Clock::now();
    double c0 = threadCpuMs();
    std::vector<TagDetection> detections;
    out.full_frame_detection = true;
    if (s.options.tracking_mode && s.frames_since_full + 1 < s.options.redetect_every) {
        const auto windows = s.windows(predicted);
        if (!windows.empty()) {
            CL_TRY(detections, s.detector.detectInWindows(gray8, windows));
            out.full_frame_detection = detections.empty();  // lost: look everywhere below
        }
    }
    if (out.full_frame_detection) {
        CL_TRY(detections, s.detector.detect(gray8));
        s.frames_since_full = 0;
    } else {
        ++s.frames_since_full;
    }
    out.times.detect_ms = msSince(t0);
    out.times.detect_cpu_ms = threadCpuMs() - c0;

    // Step 2: single-tag poses. A tag whose pattern cannot be aligned (cells too small, the
    // alignment refused) keeps its refined corners, which a response or print other than the
    // assumed one biases (tag_align.h, "Dilation"): those are refined again with the dilation the
    // frame's aligned tags measured (the same camera, the same printer), or, in a sequence, the
    // last one measured. It is carried in cells of the tag (exact for the print; for a response
    // mismatch, whose shift is in pixels, it under-corrects a tag smaller than the aligned ones
    // and never overshoots).
    t0 = Clock::now();
    c0 = threadCpuMs();
    out.tags.reserve(detections.size());
    // `item`: the scene's tag (its albedos tell the alignment the print's contrast), or null.
    const auto align = [&](const TagPattern& pattern, double size, const Rigid3d& start_pose, const TagItem* item) {
        const double a0 = threadCpuMs();
        TagAlignResult a;
        if (item && item->albedo_white > 0.0) {
            TagAlignOptions options = s.options.align;
            options.albedo_ratio = item->albedo_black / item->albedo_white;
            a = alignTagPose(gray8, s.camera, pattern, size, start_pose, options);
        } else {
            a = alignTagPose(gray8, s.camera, pattern, size, start_pose, s.options.align);
        }
        out.times.align_cpu_ms += threadCpuMs() - a0;
        return a;
    };
    // `prior`: the tag's predicted pose when the caller knows a better one than the frame's
    // prediction (step 3b: the bundle's).
    const auto solveTag = [&](const TagDetection& d, double dilation_cells, double* measured_dilation_cells,
                              const std::optional<Rigid3d>& prior = std::nullopt) {
        TrackedTag tag;
        tag.detection = d;
        if (s.options.refine_corners) {
            TagRefineOptions refine = s.options.refine;
            if (dilation_cells != 0.0) {
                // The tag's cell in the image: its mean side over the cells across its black square.
                double side = 0.0;
                for (int c = 0; c < 4; ++c) side += 0.25 * (d.corners[(c + 1) % 4] - d.corners[c]).norm();
                const TagPattern* pattern = s.patterns.get(d.id);
                refine.dilation_px += dilation_cells * side * (pattern ? pattern->cell() : 0.0);
            }
            const double r0 = threadCpuMs();
            tag.corners_refined = refineTagCorners(gray8, s.camera, tag.detection.corners, refine);
            out.times.refine_cpu_ms += threadCpuMs() - r0;
        }
        const TagItem* item = s.tags.find(d.id);
        const double size = item ? item->size : s.options.default_tag_size;
        if (size <= 0) {
            tag.error = "tag " + std::to_string(d.id) + " is not in the scene";
            return tag;
        }
        std::optional<Rigid3d> predicted_cam_from_tag = prior;
        if (prior) {
            // Given.
        } else if (item && predicted) {
            predicted_cam_from_tag = *predicted * item->world_from_tag;
        } else if (auto it = s.last_cam_from_tag.find(d.id); !s.options.independent_frames && it != s.last_cam_from_tag.end()) {
            predicted_cam_from_tag = it->second;
        }
        // A tag whose pattern will be aligned from the pose the prediction chooses is not first
        // refined on its corners (the alignment moves it anyway; docs/tracking.md, "Speed (issue 13)").
        const TagPattern* pattern = s.options.align_tags ? s.patterns.get(d.id) : nullptr;
        TagPoseOptions pose_options = s.options.tag_pose;
        pose_options.refine_predicted_start = !pattern;
        auto pose = solveTagPose(d.id, tag.detection.corners, size, s.camera, predicted_cam_from_tag, pose_options);
        if (!pose) pattern = nullptr;
        // The aligned pose becomes the tag's: its corners are where the aligned pose puts them.
        const auto adopt = [&](const TagAlignResult& a) {
            std::array<Eigen::Vector2d, 4> corners;
            for (int c = 0; c < 4; ++c) {
                const auto px = s.camera.project(a.cam_from_tag * tagCornerInTag(c, size));
                if (!px) return false;
                corners[c] = *px;
            }
            pose->cam_from_tag = a.cam_from_tag;
            pose->covariance = a.covariance;
            pose->rms_px = a.rms_px;
            tag.detection.corners = corners;
            tag.aligned = true;
            if (measured_dilation_cells) *measured_dilation_cells = a.dilation_cells;
            return true;
        };
        if (pose && !pose->refined) {
            // Aligned from IPPE's pose; where that fails (or the prediction did not choose), the
            // tag is solved again with the near start refined and goes on as it would have.
            if (pose->choice == PoseChoice::kPrediction) {
                const TagAlignResult a = align(*pattern, size, pose->cam_from_tag, item);
                if (a.ok && adopt(a)) pose->candidates[0] = {a.cam_from_tag, a.rms_px};
            }
            if (!tag.aligned) {
                pose = solveTagPose(d.id, tag.detection.corners, size, s.camera, predicted_cam_from_tag, s.options.tag_pose);
            }
            if (!pose) pattern = nullptr;
        }
        // A single candidate (the other failed the plausibility cut) that the prediction confirms,
        // within half the gate, while its planar mirror is beyond twice the gate: the prediction
        // chooses, as between two such candidates, and the mirror is not aligned as well
        // (docs/tracking.md, "Speed (issue 13)"). A mirror near the candidate (a tag seen nearly
        // head-on) is still aligned: the better of the two alignments is the more accurate one.
        const double gate = s.options.tag_pose.prediction_gate_deg;
        if (!tag.aligned && pattern && pose->choice == PoseChoice::kOnlyCandidate && predicted_cam_from_tag &&
            rotationErrorDeg(pose->cam_from_tag, *predicted_cam_from_tag) < 0.5 * gate &&
            rotationErrorDeg(planarMirror(pose->cam_from_tag), *predicted_cam_from_tag) > 2.0 * gate) {
            pose->choice = PoseChoice::kPrediction;
            pose->ambiguous = false;
        }
        if (tag.aligned) {
            // Done above.
        } else if (pattern && pose->choice == PoseChoice::kPrediction) {
            const TagAlignResult a = align(*pattern, size, pose->cam_from_tag, item);
            if (a.ok && adopt(a)) pose->candidates[0] = {a.cam_from_tag, a.rms_px};
        } else if (pattern) {
            // Nothing predicted: the cell pattern chooses. Both candidates (the second one, when
            // the corners gave one only, from the mirrored pose) are aligned; the smaller
            // alignment residual wins, and when the two residuals are too close to tell
            // (ambiguous_pattern_ratio) the tag is ambiguous. Two alignments that end on the
            // same pose, or a second one refused, leave no ambiguity. The corners' choice that the
            // pattern could not measure (its cells under min_cell_px from that pose, a tag turned
            // far from the camera) is not refuted by the other candidate's fit, which on cells of
            // about 2 px passes the RMS cut even when it is the wrong side: the corners' choice
            // stands, unaligned (docs/tracking.md, "Unmeasured candidates").
            const Rigid3d other_start = pose->candidates.size() > 1 ? pose->candidates[1].cam_from_tag
                                                                      : planarMirror(pose->candidates[0].cam_from_tag);
            TagAlignResult a[2];
            a[0] = align(*pattern, size, pose->candidates[0].cam_from_tag, item);
            if (a[0].measured) a[1] = align(*pattern, size, other_start, item);
            if (a[0].measured && !a[1].measured) {
                // One-sided: the other candidate's pattern could not be measured (its cells under
                // min_cell_px), so the pattern chose nothing. The corners' choice stands, with
                // their ratio and ambiguity, aligned when its alignment passed.
                const std::array<Eigen::Vector2d, 4> refined_corners = tag.detection.corners;
                if (a[0].ok && adopt(a[0])) {
                    pose->candidates[0] = {a[0].cam_from_tag, a[0].rms_px};
                    if (pose->candidates.size() > 1) tag.alternative_corners = refined_corners;
                }
            } else if (a[0].measured && (a[0].ok || a[1].ok)) {
                const int best = !a[1].ok || (a[0].ok && a[0].rms_px <= a[1].rms_px) ? 0 : 1;
                const TagAlignResult& chosen = a[best];
                const TagAlignResult& other = a[1 - best];
                const double corner_rms_other =
                    best == 0 ? tagReprojectionRms(tag.detection.corners, size, s.camera, other_start) : pose->candidates[0].rms_px;
                const std::array<Eigen::Vector2d, 4> refined_corners = tag.detection.corners;
                if (adopt(chosen)) {
                    pose->choice = PoseChoice::kPattern;
                    pose->candidates.assign(1, {chosen.cam_from_tag, chosen.rms_px});
                    pose->ambiguity_ratio = 0.0;
                    pose->ambiguous = false;
                    if (other.ok && rotationErrorDeg(other.cam_from_tag, chosen.cam_from_tag) > 2.0) {
                        constexpr double kFloor = 1e-6;
                        pose->candidates.push_back({other.cam_from_tag, other.rms_px});
                        pose->ambiguity_ratio = (chosen.rms_px * chosen.rms_px + kFloor) / (other.rms_px * other.rms_px + kFloor);
                        pose->ambiguous = pose->ambiguity_ratio > s.options.tag_pose.ambiguous_pattern_ratio;
                        // Its corners, should the scene or the edges choose it.
                        std::array<Eigen::Vector2d, 4> corners;
                        bool projected = true;
                        for (int c = 0; c < 4 && projected; ++c) {
                            const auto px = s.camera.project(other.cam_from_tag * tagCornerInTag(c, size));
                            if (px) corners[c] = *px;
                            projected = px.has_value();
                        }
                        tag.alternative_corners = projected ? corners : refined_corners;
                        tag.alternative_aligned = projected;
                    } else if (!other.ok) {
                        // Refused: not a pose the pattern fits. Kept as the alternative, unaligned,
                        // with the refined corners.
                        pose->candidates.push_back({other.cam_from_tag, corner_rms_other});
                        tag.alternative_corners = refined_corners;
                    }
                    // A tilt the pattern hardly fixes is not a choice either.
                    if (rotationSigmaDeg(chosen.covariance) > s.options.tag_pose.ambiguous_rotation_sigma_deg) {
                        pose->ambiguous = true;
                    }
                }
            }
        }
        if (pose) {
            tag.pose = std::move(*pose);
        } else {
            tag.error = pose.error().message;
        }
        return tag;
    };
    std::vector<double> dilations;
    for (const TagDetection& d : detections) {
        double measured = NAN;
        out.tags.push_back(solveTag(d, 0.0, &measured));
        if (std::isfinite(measured)) dilations.push_back(measured);
    }
    if (!dilations.empty()) {
        std::nth_element(dilations.begin(), dilations.begin() + static_cast<std::ptrdiff_t>(dilations.size() / 2),
                         dilations.end());
        out.dilation_cells = dilations[dilations.size() / 2];
        if (!s.options.independent_frames) s.last_dilation_cells = out.dilation_cells;
    } else if (!s.options.independent_frames && s.last_dilation_cells) {
        out.dilation_cells = *s.last_dilation_cells;
    }
    if (out.dilation_cells && s.options.refine_corners) {
        for (std::size_t k = 0; k < out.tags.size(); ++k) {
            if (!out.tags[k].aligned && out.tags[k].corners_refined) {
                out.tags[k] = solveTag(detections[k], *out.dilation_cells, nullptr);
            }
        }
    }
    out.times.tag_pose_ms = msSince(t0);
    out.times.tag_pose_cpu_ms = threadCpuMs() - c0;

    // Step 3: bundle over the scene's tags. Where two or more of them are in view, they choose
    // each ambiguous tag's candidate: the one nearer the pose the bundle gives it.
    t0 = Clock::now();
    c0 = threadCpuMs();
    std::optional<PoseMeasurement> measurement;
    std::optional<std::size_t> alone_ambiguous;  // the frame's pose rests on this ambiguous tag (out.tags) alone
    const auto runBundle = [&] {
        measurement.reset();
        alone_ambiguous.reset();
        out.bundle.reset();
        std::vector<BundleTag> bundle_tags;
        for (const TrackedTag& t : out.tags) {
            if (s.tags.find(t.detection.id) && t.pose) {
                bundle_tags.push_back({&t.detection, &*t.pose, t.verified ? s.options.verify_bundle_weight : 1.0});
            }
        }
        if (bundle_tags.empty()) return;
        auto bundle = solveBundle(bundle_tags, s.tags, s.camera, predicted, s.options.bundle);
        if (!bundle) return;
        measurement = PoseMeasurement{instant, bundle->cam_from_world, bundle->covariance};
        for (std::size_t k = 0; k < out.tags.size(); ++k) {
            TrackedTag& t = out.tags[k];
            if (!t.pose || !t.pose->ambiguous) continue;
            const TagItem* item = s.tags.find(t.detection.id);
            const auto used = std::find(bundle->tags_used.begin(), bundle->tags_used.end(), t.detection.id);
            if (!item || used == bundle->tags_used.end()) continue;
            if (bundle->tags_used.size() == 1) {
                alone_ambiguous = k;
                continue;
            }
            settleAmbiguousTag(t, *item, s.camera, bundle->cam_from_world, PoseChoice::kScene);
        }
        out.bundle = std::move(*bundle);
    };
    runBundle();
    out.times.bundle_ms = msSince(t0);
    out.times.bundle_cpu_ms = threadCpuMs() - c0;

    // Step 3b: scene tags predicted in view but not detected (too small to decode): verified at
    // their predicted place against their known pattern (tag_verify.h); an accepted one joins
    // the bundle, which is solved again.
    t0 = Clock::now();
    c0 = threadCpuMs();
    if (s.options.verify_predicted) {
        // Two passes: the tags the first accepts join the bundle, whose pose then errs less in
        // rotation and scale than the big tags' alone; the second tries again, under it, the tags
        // whose pattern correlated closely but under min_ncc (verify.retry_min_ncc).
        std::vector<int> retry;
        // A verified tag joins the frame's tags (false: refused).
        const auto accept = [&](const TagVerifyResult& v, const TagItem& item, const Rigid3d& predicted_cam_from_tag) {
            if (!v.ok) return false;
            TrackedTag tag;
            tag.detection.id = item.id;
            tag.detection.corners = v.corners;
            tag.detection.center = 0.25 * (v.corners[0] + v.corners[1] + v.corners[2] + v.corners[3]);
            tag.verified = true;
            tag.verified_known = v.alternatives_skipped;
            TagPoseOptions pose_options = s.options.tag_pose;
            pose_options.start_at_prediction = s.options.verify_solve_from_prediction;
            auto pose = solveTagPose(item.id, v.corners, item.size, s.camera, predicted_cam_from_tag, pose_options);
            if (pose) {
                tag.pose = std::move(*pose);
            } else {
                tag.error = pose.error().message;
            }
            out.tags.push_back(std::move(tag));
            return true;
        };
        // Where the last frame reported the tag, when that may spare its alternatives.
        const auto knownAt = [&](int id) -> const Eigen::Vector2d* {
            if (!s.options.verify_trust_last_frame) return nullptr;
            const auto it = s.last_centres.find(id);
            return it == s.last_centres.end() ? nullptr : &it->second;
        };
        for (int pass = 0; pass < 2; ++pass) {
            std::optional<Rigid3d> basis;
            if (measurement && !alone_ambiguous) {
                basis = measurement->cam_from_world;
            } else if (!measurement && predicted) {
                basis = predicted;
            }
            if (!basis) break;
            bool added = false;
            std::vector<int> close;
            struct ToDetect {
                const TagItem* item;
                std::array<Eigen::Vector2d, 4> corners;  // the predicted black square
                double span_px;
                Rigid3d cam_from_tag;
                std::vector<const TagPattern*> others;
            };
            std::vector<ToDetect> to_detect;
            for (const TagItem& item : s.tags.items) {
                if (pass == 1 && std::find(retry.begin(), retry.end(), item.id) == retry.end()) continue;
                const bool seen = std::any_of(out.tags.begin(), out.tags.end(),
                                              [&](const TrackedTag& t) { return t.detection.id == item.id; });
                const TagPattern* pattern = seen ? nullptr : s.patterns.get(item.id);
                if (!pattern) continue;
                std::vector<const TagPattern*> others;
                const int family_size = tagFamilySize(s.tags.family);
                for (int k = 1; k <= s.options.verify.other_ids && family_size > 1; ++k) {
                    const int other = (item.id + k) % family_size;
                    if (other != item.id) others.push_back(s.patterns.get(other));
                }
                const Rigid3d predicted_cam_from_tag = *basis * item.world_from_tag;
                if (s.options.verify_skip_occluded && s.occluders() &&
                    hiddenByProxies(*s.occluders(), basis->inverse().translation, item, 3)) {
                    continue;
                }
                const TagVerifyResult v = verifyPredictedTag(gray8, s.camera, *pattern, others, item.size,
                                                             predicted_cam_from_tag, s.options.verify, knownAt(item.id));
                if (v.wide_enough_to_detect && s.full_res_detector) {
                    to_detect.push_back({&item, v.corners, v.span_px, predicted_cam_from_tag, std::move(others)});
                    continue;
                }
                if (!accept(v, item, predicted_cam_from_tag)) {
                    if (v.ncc >= s.options.verify.retry_min_ncc && v.ncc < s.options.verify.min_ncc) close.push_back(item.id);
                    continue;
                }
                added = true;
            }
            // The foreshortened tags left to the detector: at full resolution in a window around
            // each; a tag found there (its id, near the prediction) is solved as a detected one
            // (step 2), one missed there is verified after all.
            // Step 2's split of the CPU time is for step 2's tags: this step's solves count as verify's.
            const double refine_cpu = out.times.refine_cpu_ms, align_cpu = out.times.align_cpu_ms;
            if (pass == 0 && s.options.redetect_align_known && s.options.align_tags && !to_detect.empty()) {
                // A tag the last frame reported where it is predicted now: its pattern aligned from the
                // prediction (as a detected tag's is from its corners' pose), without the detector;
                // one whose alignment fails is detected like the others.
                std::vector<ToDetect> rest;
                for (ToDetect& t : to_detect) {
                    const Eigen::Vector2d centre = 0.25 * (t.corners[0] + t.corners[1] + t.corners[2] + t.corners[3]);
                    const auto known = s.last_centres.find(t.item->id);
                    const Eigen::Vector2d* last = known == s.last_centres.end() ? nullptr : &known->second;
                    const TagPattern* pattern = s.patterns.get(t.item->id);
                    const bool detected_last = std::find(s.last_detected.begin(), s.last_detected.end(), t.item->id) !=
                                               s.last_detected.end();
                    if (!last || !detected_last || (centre - *last).norm() > 0.5 * t.span_px || !pattern ||
                        !(squareAspect(t.corners) >= kMinAspectAlignedKnown)) {
                        rest.push_back(std::move(t));
                        continue;
                    }
                    std::optional<TrackedTag> tag =
                        alignedKnownTag(align(*pattern, t.item->size, t.cam_from_tag, t.item), t.item->id, t.item->size,
                                        s.camera);
                    if (!tag) {
                        rest.push_back(std::move(t));
                        continue;
                    }
                    out.tags.push_back(std::move(*tag));
                    added = true;
                }
                to_detect = std::move(rest);
            }
            if (!to_detect.empty()) {
                std::vector<PixelWindow> windows;
                for (const ToDetect& t : to_detect) {
                    // The black square, its white border and a few pixels of surroundings: a quarter of
                    // the tag's size and at least 6 px each side (the whole tracking-mode margin, half
                    // the tag and 12 px, found the same tags on tiny75 at twice the cost).
                    windows.push_back(grownBox(t.corners, 0.25, 6));
                }
                // (Once: the second pass verifies the close ones the detector missed.)
                std::vector<TagDetection> found;
                if (pass == 0) {
                    CL_TRY(found, s.full_res_detector->detectInWindows(gray8, mergeOverlapping(std::move(windows))));
                }
                for (ToDetect& t : to_detect) {
                    const Eigen::Vector2d centre = 0.25 * (t.corners[0] + t.corners[1] + t.corners[2] + t.corners[3]);
                    const auto d = std::find_if(found.begin(), found.end(), [&](const TagDetection& f) {
                        return f.id == t.item->id && (f.center - centre).norm() <= std::max(4.0, 0.5 * t.span_px);
                    });
                    if (d != found.end()) {
                        // The frame's dilation is known by now (step 2 refined its unaligned tags with it),
                        // and the bundle's pose chooses between the tag's candidates (without a
                        // prediction, the pattern chose the wrong one of a tag 15 px across at 55
                        // degrees: corners 2.7 px off).
                        out.tags.push_back(solveTag(*d, out.dilation_cells.value_or(0.0), nullptr, t.cam_from_tag));
                        out.tags.back().detected_late = true;
                        added = true;
                        continue;
                    }
                    TagVerifyOptions all = s.options.verify;
                    all.max_foreshortened_span_px = all.max_side_px;
                    const TagVerifyResult v = verifyPredictedTag(gray8, s.camera, *s.patterns.get(t.item->id), t.others,
                                                                 t.item->size, t.cam_from_tag, all, knownAt(t.item->id));
                    if (accept(v, *t.item, t.cam_from_tag)) {
                        added = true;
                    } else if (v.ncc >= s.options.verify.retry_min_ncc && v.ncc < s.options.verify.min_ncc) {
                        close.push_back(t.item->id);
                    }
                }
            }
            out.times.refine_cpu_ms = refine_cpu;
            out.times.align_cpu_ms = align_cpu;
            if (added) runBundle();
            // A second pass only when the first moved the bundle and left close ones.
            if (!added || close.empty()) break;
            retry = std::move(close);
        }
    }
    out.times.verify_ms = msSince(t0);
    out.times.verify_cpu_ms = threadCpuMs() - c0;

    // Step 4: model edges. A frame resting on one ambiguous tag: refined from both candidates,
    // the proxies' edges choose when only one of them converges (or both end on one pose).
    t0 = Clock::now();
    c0 = threadCpuMs();
    bool edges_only = false;
    std::optional<Rigid3d> alternative;  // the other candidate's camera pose while ambiguous
    if (alone_ambiguous && out.tags[*alone_ambiguous].pose->candidates.size() > 1) {
        const TrackedTag& t = out.tags[*alone_ambiguous];
        alternative = t.pose->candidates[1].cam_from_tag * s.tags.find(t.detection.id)->world_from_tag.inverse();
    }
    if (s.edge_model && (measurement || predicted)) {
        const Rigid3d initial = measurement ? measurement->cam_from_world : *predicted;
        auto refined = refinePoseWithEdges(gray8, s.camera, *s.edge_model, initial, s.options.edge_options, measurement);
        if (refined && alternative) {
            const PoseMeasurement alt_prior{instant, *alternative, measurement->covariance};
            auto alt = refinePoseWithEdges(gray8, s.camera, *s.edge_model, *alternative, s.options.edge_options, alt_prior);
            const bool alt_ok = alt && alt->ok;
            bool resolved = false;
            if (alt_ok && !refined->ok) {
                // The edges confirm the other candidate only: it becomes the frame's.
                measurement->cam_from_world = *alternative;
                refined = std::move(alt);
                resolved = true;
            } else if (refined->ok) {
                // Confirmed: the other did not converge, or converged onto the same pose.
                resolved = !alt_ok || rotationErrorDeg(alt->cam_from_world, refined->cam_from_world) < 1.0;
            }
            if (resolved) {
                TrackedTag& t = out.tags[*alone_ambiguous];
                settleAmbiguousTag(t, *s.tags.find(t.detection.id), s.camera, refined->cam_from_world, PoseChoice::kEdges);
                alone_ambiguous.reset();
                alternative.reset();
            }
        } else if (refined && refined->ok && alone_ambiguous && !alternative &&
                   rotationSigmaDeg(refined->covariance) <= s.options.tag_pose.ambiguous_rotation_sigma_deg) {
            // One candidate, ambiguous only because the tag hardly fixes its tilt (step 2): the
            // proxies' edges converged and fix it, so the frame is no longer ambiguous.
            TrackedTag& t = out.tags[*alone_ambiguous];
            settleAmbiguousTag(t, *s.tags.find(t.detection.id), s.camera, refined->cam_from_world, PoseChoice::kEdges);
            alone_ambiguous.reset();
        }
        if (refined) {
            if (refined->ok) {
                edges_only = !measurement.has_value();
                measurement = PoseMeasurement{instant, refined->cam_from_world, refined->covariance};
            }
            out.edges = std::move(*refined);
        }
    }
    out.times.edges_ms = msSince(t0);
    out.times.edges_cpu_ms = threadCpuMs() - c0;

    // Step 5: filter. A pose resting on one ambiguous tag is reported as such (both candidates)
    // and neither updates the filter nor predicts the next frame: either may be the truth.
    t0 = Clock::now();
    c0 = threadCpuMs();
    if (measurement && alone_ambiguous) {
        out.status = TrackStatus::kAmbiguous;
        out.cam_from_world = measurement->cam_from_world;
        out.covariance = measurement->covariance;
        out.alternative_cam_from_world = alternative;
        out.ambiguity_ratio = out.tags[*alone_ambiguous].pose->ambiguity_ratio;
        measurement.reset();
    } else if (measurement) {
        out.status = edges_only ? TrackStatus::kEdgesOnly : TrackStatus::kTracked;
        if (s.options.filter) {
            CL_TRY(auto update, s.filter.update(*measurement));
            // Hard case: the camera jumped (a fast move, a replay that loops, a tracker that
            // had lost it). The gate rejects what the motion model cannot explain, which guards
            // against a single tag's wrong candidate; but a bundle of two or more of the scene's
            // tags that agree with each other has no planar ambiguity, so it is the camera that
            // moved, not the measurement that is wrong: the filter starts again from it at once
            // instead of reporting its own extrapolation for `max_consecutive_rejections` frames.
            if (update == PoseFilter::UpdateResult::kRejected && out.bundle && !edges_only &&
                out.bundle->tags_used.size() >= 2 && out.bundle->rms_px <= s.options.jump_max_rms_px) {
                s.filter.reset();
                CL_TRY(update, s.filter.update(*measurement));
            }
            if (update == PoseFilter::UpdateResult::kRejected) {
                // The measurement was refused: what is reported is the prediction.
                out.status = TrackStatus::kPredicted;
            }
            const auto filtered = s.filter.predict(instant);
            out.cam_from_world = filtered ? filtered->cam_from_world : measurement->cam_from_world;
            out.covariance = filtered ? filtered->covariance : measurement->covariance;
        } else {
            out.cam_from_world = measurement->cam_from_world;
            out.covariance = measurement->covariance;
        }
        s.last_cam_from_world = out.cam_from_world;
    } else if (s.options.filter && predicted) {
        const auto p = s.filter.predict(instant);
        const bool recent = s.last_measurement_instant &&
                            instant - *s.last_measurement_instant <= s.options.filter_options.max_gap_ns;
        if (p && recent) {
            out.status = TrackStatus::kPredicted;
            out.cam_from_world = p->cam_from_world;
            out.covariance = p->covariance;
        }
    }
    out.times.filter_ms = msSince(t0);
    out.times.filter_cpu_ms = threadCpuMs() - c0;

    // For the next frame.
    s.last_detections = std::move(detections);
    s.last_cam_from_tag.clear();
    s.last_centres.clear();
    s.last_detected.clear();
    for (const TrackedTag& t : out.tags) {
        if (t.pose && !t.pose->ambiguous) s.last_cam_from_tag[t.detection.id] = t.pose->cam_from_tag;
        if (s.options.independent_frames) continue;
        s.last_centres[t.detection.id] = t.detection.center;
        if (!t.verified) s.last_detected.push_back(t.detection.id);
    }
    if (measurement) s.last_measurement_instant = instant;
    s.last_timestamp = timestamp_ns;
    s.last_pose_instant = instant;
    ++s.frames;
    out.times.total_ms = msSince(start);
    out.times.total_cpu_ms = threadCpuMs() - start_cpu;
    return out;
}

}  // namespace commonlight::tracking

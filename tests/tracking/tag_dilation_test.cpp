// Tag pattern alignment and corner refinement on tags whose black regions look grown or shrunk:
// ink spread on the print (known, drawn by mocks/sim's tag texture) and a camera response other
// than the one the tracker assumes (linear, gamma 1.8 and 2.6 read as sRGB, and sRGB read as
// linear). Synthetic images: the tag's albedo supersampled 6 x 6 per pixel through a pinhole,
// blurred in linear light (the optics), encoded with the camera's response. The range bias the
// dilation causes must go away when the alignment solves for it.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

#include <Eigen/Geometry>
#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "core/camera_model.h"
#include "core/image.h"
#include "mocks/sim/sensor.h"
#include "mocks/sim/tag_texture.h"
#include "tracking/tag_align.h"
#include "tracking/tag_detector.h"
#include "tracking/tag_pose.h"
#include "tracking/tag_refine.h"
#include "tracking/tracker.h"

namespace commonlight::tracking {
namespace {

using mocks::sim::SensorResponse;

constexpr int kId = 3;
constexpr double kSize = 0.1;

CameraModel camera() {
    CameraModel cam;
    cam.width = 640;
    cam.height = 480;
    cam.fx = cam.fy = 500;
    cam.cx = 319.5;
    cam.cy = 239.5;
    return cam;
}

// The tag `distance` metres in front of the camera, turned `tilt_deg` about its x axis and
// `yaw_deg` about its y axis, a little off the optical axis.
Rigid3d tagPose(double distance, double tilt_deg, double yaw_deg) {
    const double d2r = M_PI / 180.0;
    const Eigen::Matrix3d r = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix() *
                              Eigen::AngleAxisd(tilt_deg * d2r, Eigen::Vector3d::UnitX()).toRotationMatrix() *
                              Eigen::AngleAxisd(yaw_deg * d2r, Eigen::Vector3d::UnitY()).toRotationMatrix();
    return Rigid3d(Eigen::Quaterniond(r), Eigen::Vector3d(0.03, -0.02, distance));
}

struct Conditions {
    SensorResponse response = SensorResponse::kSrgb;
    double gamma = 2.2;
    double ink_spread_cells = 0.0;
    double blur_sigma_px = 0.9;
};

struct Placed {
    int id;
    Rigid3d cam_from_tag;
};

// The 8-bit image of the tags (edge kSize) on a grey background (albedo 0.3), lit evenly.
Image renderTags(const std::vector<Placed>& tags, const Conditions& c) {
    const CameraModel cam = camera();
    cv::Mat linear(cam.height, cam.width, CV_32F, cv::Scalar(0.3));
    for (const Placed& placed : tags) {
    const Rigid3d& cam_from_tag = placed.cam_from_tag;
    auto texture = mocks::sim::TagTexture::make("tag36h11", placed.id);
    EXPECT_TRUE(texture);
    mocks::sim::PlacedTag tag;
    tag.texture = *texture;
    tag.size = kSize;
    tag.half_extent = 0.5 * kSize / texture->widthAtBorder() * texture->totalWidth();
    tag.ink_spread_cells = c.ink_spread_cells;
    const Rigid3d tag_from_cam = cam_from_tag.inverse();
    // Only the pixels near the printed square are traced (the rest is background).
    Eigen::AlignedBox2d box;
    for (const double x : {-tag.half_extent, tag.half_extent}) {
        for (const double y : {-tag.half_extent, tag.half_extent}) box.extend(*cam.project(cam_from_tag * Eigen::Vector3d(x, y, 0)));
    }
    const int u0 = std::max(0, static_cast<int>(box.min().x()) - 3), u1 = std::min(cam.width, static_cast<int>(box.max().x()) + 4);
    const int v0 = std::max(0, static_cast<int>(box.min().y()) - 3), v1 = std::min(cam.height, static_cast<int>(box.max().y()) + 4);
    constexpr int kSub = 6;
    for (int v = v0; v < v1; ++v) {
        for (int u = u0; u < u1; ++u) {
            double sum = 0;
            for (int sy = 0; sy < kSub; ++sy) {
                for (int sx = 0; sx < kSub; ++sx) {
                    const Eigen::Vector3d ray((u - 0.5 + (sx + 0.5) / kSub - cam.cx) / cam.fx,
                                              (v - 0.5 + (sy + 0.5) / kSub - cam.cy) / cam.fy, 1.0);
                    const Eigen::Vector3d o = tag_from_cam.translation;
                    const Eigen::Vector3d dir = tag_from_cam.rotation * ray;
                    const double lambda = -o.z() / dir.z();
                    const Eigen::Vector3d p = o + lambda * dir;
                    sum += lambda > 0 && tag.contains(p.x(), p.y()) ? tag.albedoAt(p.x(), p.y()) : 0.3;
                }
            }
            linear.at<float>(v, u) = static_cast<float>(sum / (kSub * kSub));
        }
    }
    }
    cv::GaussianBlur(linear, linear, cv::Size(0, 0), c.blur_sigma_px);
    Image out(PixelFormat::kGray8, cam.width, cam.height);
    for (int v = 0; v < cam.height; ++v) {
        for (int u = 0; u < cam.width; ++u) {
            // Exposed so that the white cells (albedo 0.8) come out at 90% of full scale.
            const double value = mocks::sim::applyResponse(c.response, 0.9 / 0.8 * linear.at<float>(v, u), c.gamma);
            out.data()[v * out.stride() + u] = static_cast<std::uint8_t>(std::lround(255.0 * value));
        }
    }
    return out;
}

Image renderTag(const Rigid3d& cam_from_tag, const Conditions& c) { return renderTags({{kId, cam_from_tag}}, c); }

double rangeErrorPct(const Rigid3d& estimate, const Rigid3d& truth) {
    return 100.0 * (estimate.translation.norm() / truth.translation.norm() - 1.0);
}

struct Outcome {
    double range_pct_fixed = 0, range_pct_joint = 0;  // without and with the dilation solved
    double rot_deg_fixed = 0, rot_deg_joint = 0;
    double dilation_cells = 0, dilation_px = 0;
};

// Aligns from the true pose moved 1.5% further away and tilted 0.5 degrees.
Outcome align(const Conditions& c, bool tracker_srgb, const Rigid3d& truth) {
    const Image image = renderTag(truth, c);
    auto pattern = TagPattern::make("tag36h11", kId);
    EXPECT_TRUE(pattern);
    Rigid3d start = truth;
    start.translation *= 1.015;
    start.rotation = Eigen::AngleAxisd(0.5 * M_PI / 180.0, Eigen::Vector3d(1, 1, 0).normalized()) * truth.rotation;
    TagAlignOptions options;
    options.srgb = tracker_srgb;
    options.iterations = 8;
    // The dilation alone (the response measured and corrected: AlignmentMeasuresTheResponseMismatch).
    options.estimate_response = false;
    Outcome out;
    TagAlignOptions fixed = options;
    fixed.estimate_dilation = false;
    fixed.max_rms_px = 10;  // measure the biased fit too
    const TagAlignResult a = alignTagPose(image.view(), camera(), *pattern, kSize, start, fixed);
    EXPECT_TRUE(a.ok) << a.reason;
    const TagAlignResult b = alignTagPose(image.view(), camera(), *pattern, kSize, start, options);
    EXPECT_TRUE(b.ok) << b.reason;
    out.range_pct_fixed = rangeErrorPct(a.cam_from_tag, truth);
    out.range_pct_joint = rangeErrorPct(b.cam_from_tag, truth);
    out.rot_deg_fixed = rotationErrorDeg(a.cam_from_tag, truth);
    out.rot_deg_joint = rotationErrorDeg(b.cam_from_tag, truth);
    out.dilation_cells = b.dilation_cells;
    out.dilation_px = b.dilation_px;
    EXPECT_NEAR(a.dilation_cells, 0.0, 1e-12);
    return out;
}

struct Case {
    const char* name;
    Conditions conditions;
    bool tracker_srgb;
};

TEST(TagDilation, AlignmentRemovesTheRangeBiasOfResponseAndPrint) {
    const Case cases[] = {
        {"matched sRGB", {}, true},
        {"ink +10% of a cell", {.ink_spread_cells = 0.10}, true},
        {"ink -8% of a cell", {.ink_spread_cells = -0.08}, true},
        {"linear read as sRGB", {.response = SensorResponse::kLinear}, true},
        {"sRGB read as linear", {}, false},
        {"gamma 1.8 read as sRGB", {.response = SensorResponse::kGamma, .gamma = 1.8}, true},
        {"gamma 2.6 read as sRGB", {.response = SensorResponse::kGamma, .gamma = 2.6}, true},
        {"linear read as sRGB, defocused", {.response = SensorResponse::kLinear, .blur_sigma_px = 1.6}, true},
    };
    for (const Rigid3d& truth : {tagPose(0.9, 25, 10), tagPose(1.3, 50, -15)}) {
        for (const Case& k : cases) {
            const Outcome o = align(k.conditions, k.tracker_srgb, truth);
            std::printf("  %-32s at %.1f m: range %+.3f%% -> %+.3f%%, rotation %.3f -> %.3f deg, dilation %+.3f cells "
                        "(%+.3f px)\n",
                        k.name, truth.translation.norm(), o.range_pct_fixed, o.range_pct_joint, o.rot_deg_fixed,
                        o.rot_deg_joint, o.dilation_cells, o.dilation_px);
            SCOPED_TRACE(k.name);
            // Measured: 0.2% at most at 0.9 m (issue 13's target), up to 0.35% at 1.3 m and 50
            // degrees (cells foreshortened to 3 px: linear read as sRGB under a blur of 1.6 px,
            // an edge shift in pixels that the dilation in cells fits only on average).
            EXPECT_LT(std::abs(o.range_pct_joint), 0.4);
            // Where the dilation biased the range, the bias is gone (to a quarter at most).
            if (std::abs(o.range_pct_fixed) > 0.8) {
                EXPECT_LT(std::abs(o.range_pct_joint), 0.25 * std::abs(o.range_pct_fixed));
            }
            // One more parameter costs a little rotation on steep views, never much (measured: at
            // most 0.26 degrees, ink -8% at 1.3 m, 0.14 -> 0.40).
            EXPECT_LT(o.rot_deg_joint, o.rot_deg_fixed + 0.3);
            EXPECT_LT(o.rot_deg_joint, 0.7);
            if (k.conditions.ink_spread_cells != 0.0 && k.conditions.response == SensorResponse::kSrgb && k.tracker_srgb) {
                // The print's dilation is measured as it was printed.
                EXPECT_NEAR(o.dilation_cells, k.conditions.ink_spread_cells, 0.025);
            }
        }
    }
    // The bias is real without the dilation: the tests above can fail. Black grown by 10% of a
    // cell makes the tag look larger, so nearer.
    const Outcome grown = align({.ink_spread_cells = 0.10}, true, tagPose(0.9, 25, 10));
    EXPECT_LT(grown.range_pct_fixed, -0.5);
    const Outcome linear = align({.response = SensorResponse::kLinear}, true, tagPose(0.9, 25, 10));
    EXPECT_GT(std::abs(linear.range_pct_fixed), 0.3);
}

TEST(TagDilation, CornerRefinementUsesTheDilation) {
    const Rigid3d truth = tagPose(0.9, 20, 5);
    const Image image = renderTag(truth, {.ink_spread_cells = 0.10});
    const CameraModel cam = camera();
    std::array<Eigen::Vector2d, 4> true_corners;
    for (int c = 0; c < 4; ++c) true_corners[c] = *cam.project(truth * tagCornerInTag(c, kSize));
    const Eigen::Vector2d centre = 0.25 * (true_corners[0] + true_corners[1] + true_corners[2] + true_corners[3]);
    // Mean outward offset of the refined corners from the true ones, pixels.
    const auto outward = [&](double dilation_px) {
        auto corners = true_corners;
        for (int c = 0; c < 4; ++c) corners[c] += Eigen::Vector2d(0.3 * ((c & 1) ? 1 : -1), 0.2 * ((c & 2) ? 1 : -1));
        TagRefineOptions options;
        options.dilation_px = dilation_px;
        EXPECT_TRUE(refineTagCorners(image.view(), cam, corners, options));
        double sum = 0;
        for (int c = 0; c < 4; ++c) sum += (corners[c] - true_corners[c]).dot((true_corners[c] - centre).normalized());
        return sum / 4;
    };
    // The alignment measures the dilation; the corners refined with it lose their outward bias.
    auto pattern = TagPattern::make("tag36h11", kId);
    ASSERT_TRUE(pattern);
    const TagAlignResult a = alignTagPose(image.view(), cam, *pattern, kSize, truth);
    ASSERT_TRUE(a.ok) << a.reason;
    const double biased = outward(0.0), corrected = outward(a.dilation_px);
    std::printf("  corners' outward offset: %.3f px without, %.3f px with the measured dilation (%.3f px)\n", biased,
                corrected, a.dilation_px);
    // A corner moves by sqrt(2) times an edge's shift (along the diagonal).
    EXPECT_GT(biased, 0.5 * std::sqrt(2.0) * a.dilation_px);
    EXPECT_LT(std::abs(corrected), 0.05);
}

TEST(TagDilation, TrackerRefinesTheTagsItCannotAlignWithTheFramesDilation) {
    // Two tags printed with the black grown by 10% of a cell: tag 3 near (cells of 7 px), tag 8
    // farther (cells of 4.5 px) and, with min_cell_px 5, too small to align: its corners are
    // refined with the dilation the near tag measured.
    const Rigid3d near = tagPose(0.9, 20, 0) * Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(-0.09, 0, 0));
    Rigid3d far = tagPose(1.4, 20, 0);
    far.translation.x() += 0.09;
    const Image image = renderTags({{3, near}, {8, far}}, {.ink_spread_cells = 0.10});
    TagSet tags;
    tags.items.push_back({3, kSize, Rigid3d()});
    tags.items.push_back({8, kSize, Rigid3d()});
    const auto run = [&](bool near_in_view) {
        TrackerOptions options;
        options.independent_frames = true;
        options.filter = false;
        options.detector.decimate = 1;
        options.align.min_cell_px = 5.0;
        Image view = Image::copyOf(image.view());
        if (!near_in_view) {
            // Hide the near tag: paint its half of the image background grey.
            const std::uint8_t grey = view.data()[5 * view.stride() + 5];
            for (int v = 0; v < view.height(); ++v) std::fill_n(view.data() + v * view.stride(), 300, grey);
        }
        auto tracker = Tracker::create(camera(), tags, nullptr, options);
        EXPECT_TRUE(tracker);
        auto track = tracker->process(view.view(), 0);
        EXPECT_TRUE(track);
        return *track;
    };
    const auto farTag = [](const FrameTrack& t) -> const TrackedTag* {
        for (const auto& tag : t.tags) {
            if (tag.detection.id == 8) return &tag;
        }
        return nullptr;
    };
    const FrameTrack both = run(true), alone = run(false);
    const TrackedTag* far_both = farTag(both);
    const TrackedTag* far_alone = farTag(alone);
    ASSERT_TRUE(far_both && far_alone && far_both->pose && far_alone->pose);
    EXPECT_FALSE(far_both->aligned);
    EXPECT_TRUE(far_both->corners_refined);
    ASSERT_TRUE(both.dilation_cells);
    EXPECT_NEAR(*both.dilation_cells, 0.10, 0.02);
    EXPECT_FALSE(alone.dilation_cells);  // no aligned tag, and the frames are independent
    const double with = rangeErrorPct(far_both->pose->cam_from_tag, far);
    const double without = rangeErrorPct(far_alone->pose->cam_from_tag, far);
    std::printf("  far tag's range error: %+.3f%% alone, %+.3f%% with the near tag's dilation (%.3f cells)\n", without,
                with, *both.dilation_cells);
    EXPECT_LT(without, -1.0);  // black grown: the tag looks larger, nearer
    EXPECT_LT(std::abs(with), 0.4);
}

TEST(TagDilation, PointsNearLJunctionsAreNotSampled) {
    // A blur rounds every convex corner of a black or a white region: near an L junction of the
    // pattern the edge found lies inside the region by a fraction of the blur, in pixels. On a
    // foreshortened tag that is a scale error that differs along and across the tag, which the
    // dilation (in cells) cannot absorb: a tilt and a range error. Noise-free images, so what
    // is measured is that bias alone.
    auto pattern = TagPattern::make("tag36h11", kId);
    ASSERT_TRUE(pattern);
    int l_ends = 0;
    for (const auto& e : pattern->edges()) l_ends += (e.corner_a ? 1 : 0) + (e.corner_b ? 1 : 0);
    std::printf("  tag %d: %zu boundaries, %d ends at an L junction\n", kId, pattern->edges().size(), l_ends);
    EXPECT_GT(l_ends, 0);
    EXPECT_LT(l_ends, static_cast<int>(pattern->edges().size()));
    double sum_with = 0, sum_without = 0;
    for (const Rigid3d& truth : {tagPose(1.2, 45, 10), tagPose(1.3, 50, -15), tagPose(1.1, 35, 30)}) {
        for (const double blur : {0.6, 1.0}) {
            const Image image = renderTag(truth, {.blur_sigma_px = blur});
            Rigid3d start = truth;
            start.translation *= 1.01;
            start.rotation = Eigen::AngleAxisd(0.5 * M_PI / 180.0, Eigen::Vector3d(1, 1, 0).normalized()) * truth.rotation;
            TagAlignOptions options;
            options.iterations = 8;
            TagAlignOptions near_corners = options;
            near_corners.corner_clearance_px = 0.0;
            const TagAlignResult a = alignTagPose(image.view(), camera(), *pattern, kSize, start, near_corners);
            const TagAlignResult b = alignTagPose(image.view(), camera(), *pattern, kSize, start, options);
            ASSERT_TRUE(a.ok && b.ok) << a.reason << b.reason;
            const double rot_a = rotationErrorDeg(a.cam_from_tag, truth), rot_b = rotationErrorDeg(b.cam_from_tag, truth);
            std::printf("  %.1f m, blur %.1f px, cells %.1f px: rotation %.3f -> %.3f deg, range %+.3f%% -> %+.3f%%, "
                        "points %d -> %d\n",
                        truth.translation.norm(), blur, b.cell_px, rot_a, rot_b, rangeErrorPct(a.cam_from_tag, truth),
                        rangeErrorPct(b.cam_from_tag, truth), a.points, b.points);
            // Measured: 0.14-0.40 degrees with the points near L junctions, 0.11-0.21 without,
            // lower on every view.
            EXPECT_LT(rot_b, rot_a);
            sum_with += rot_a;
            sum_without += rot_b;
        }
    }
    std::printf("  mean rotation error %.3f -> %.3f deg\n", sum_with / 6, sum_without / 6);
    EXPECT_LT(sum_without, 0.75 * sum_with);  // measured: 0.292 -> 0.182 degrees
}

TEST(TagDilation, StronglyForeshortenedTagsKeepThePointsNearLJunctions) {
    // Tilted 70 degrees the tag's sides differ by a factor of 3: the clearance would leave its
    // short boundaries their midpoints alone. There every point is sampled, as with no clearance.
    auto pattern = TagPattern::make("tag36h11", kId);
    ASSERT_TRUE(pattern);
    for (const auto& [tilt, yaw] : {std::pair{70.0, 10.0}, std::pair{72.0, -20.0}}) {
        const Rigid3d truth = tagPose(0.55, tilt, yaw);
        const Image image = renderTag(truth, {.blur_sigma_px = 0.8});
        TagAlignOptions options;
        options.iterations = 8;
        TagAlignOptions no_clearance = options;
        no_clearance.corner_clearance_px = 0.0;
        TagAlignOptions no_aspect_limit = options;
        no_aspect_limit.corner_clearance_min_aspect = 0.0;
        const TagAlignResult a = alignTagPose(image.view(), camera(), *pattern, kSize, truth, no_clearance);
        const TagAlignResult b = alignTagPose(image.view(), camera(), *pattern, kSize, truth, options);
        const TagAlignResult c = alignTagPose(image.view(), camera(), *pattern, kSize, truth, no_aspect_limit);
        ASSERT_TRUE(a.ok && b.ok && c.ok) << a.reason << b.reason << c.reason;
        std::printf("  tilt %.0f deg, cells %.1f px: points %d with the limit, %d without any clearance, %d with the "
                    "clearance regardless of the tilt\n",
                    tilt, b.cell_px, b.points, a.points, c.points);
        ASSERT_GE(b.cell_px, options.corner_clearance_min_cell_px);  // the aspect alone decides
        EXPECT_EQ(b.points, a.points);
        EXPECT_LT(c.points, b.points);
        EXPECT_TRUE(b.cam_from_tag.translation.isApprox(a.cam_from_tag.translation, 1e-12));
    }
}

TEST(TagDilation, AlignmentMeasuresTheResponseMismatch) {
    // Read through a response other than the camera's, a blurred step is bent: its halfway
    // crossing is not the middle of the linear step (a linear camera read as sRGB: about 73 % of
    // it), where the edge is steepest and noise moves it least. The alignment measures the tag's
    // black and white cells against its albedos (0.04 / 0.8, the scene's defaults) and, on a
    // gross mismatch, finds the edges through the gamma curve those levels imply: the edges are
    // then at the middle of the linear step, so the response's share of the dilation is gone. A
    // print's ink spread is no response, and a moderate mismatch keeps the assumed curve.
    struct ResponseCase {
        const char* name;
        Conditions conditions;
        bool tracker_srgb;
        double gamma_lo, gamma_hi;  // the gamma expected to replace the assumed curve (0: none)
    };
    const ResponseCase cases[] = {
        {"matched sRGB", {}, true, 0, 0},
        {"ink +10% of a cell", {.ink_spread_cells = 0.10}, true, 0, 0},
        {"ink -8% of a cell", {.ink_spread_cells = -0.08}, true, 0, 0},
        {"gamma 1.8 read as sRGB", {.response = SensorResponse::kGamma, .gamma = 1.8}, true, 0, 0},
        {"linear read as sRGB", {.response = SensorResponse::kLinear}, true, 0.9, 1.2},
        {"sRGB read as linear", {}, false, 2.0, 2.6},
    };
    auto pattern = TagPattern::make("tag36h11", kId);
    ASSERT_TRUE(pattern);
    for (const Rigid3d& truth : {tagPose(0.9, 25, 10), tagPose(1.3, 50, -15)}) {
        for (const ResponseCase& k : cases) {
            SCOPED_TRACE(k.name);
            const Image image = renderTag(truth, k.conditions);
            Rigid3d start = truth;
            start.translation *= 1.015;
            TagAlignOptions options;
            options.srgb = k.tracker_srgb;
            options.iterations = 8;
            TagAlignOptions assumed = options;
            assumed.estimate_response = false;
            const TagAlignResult a = alignTagPose(image.view(), camera(), *pattern, kSize, start, assumed);
            const TagAlignResult b = alignTagPose(image.view(), camera(), *pattern, kSize, start, options);
            ASSERT_TRUE(a.ok && b.ok) << a.reason << b.reason;
            std::printf("  %-24s at %.1f m: mismatch %.3f, gamma %.3f, dilation %+.3f -> %+.3f px, range %+.3f%% -> "
                        "%+.3f%%, rotation %.3f -> %.3f deg\n",
                        k.name, truth.translation.norm(), b.response_exponent_measured, b.response_gamma,
                        a.dilation_px, b.dilation_px, rangeErrorPct(a.cam_from_tag, truth),
                        rangeErrorPct(b.cam_from_tag, truth), rotationErrorDeg(a.cam_from_tag, truth),
                        rotationErrorDeg(b.cam_from_tag, truth));
            EXPECT_EQ(a.response_exponent_measured, 0.0);
            EXPECT_EQ(a.response_gamma, 0.0);
            EXPECT_GT(b.response_exponent_measured, 0.0);
            if (k.gamma_hi == 0) {
                EXPECT_EQ(b.response_gamma, 0.0);
                EXPECT_NEAR(b.response_exponent_measured, k.conditions.response == SensorResponse::kGamma ? 0.9 : 1.0,
                            0.25);
                // The assumed curve, untouched: the same fit.
                EXPECT_TRUE(b.cam_from_tag.translation.isApprox(a.cam_from_tag.translation, 1e-12));
            } else {
                EXPECT_GE(b.response_gamma, k.gamma_lo);
                EXPECT_LE(b.response_gamma, k.gamma_hi);
                // The response's share of the dilation is gone (to a quarter at most).
                EXPECT_LT(std::abs(b.dilation_px), std::abs(a.dilation_px) / 4);
                EXPECT_LT(std::abs(rangeErrorPct(b.cam_from_tag, truth)), 0.3);
            }
        }
    }
}

}  // namespace
}  // namespace commonlight::tracking

// Single-tag pose: both planar candidates, LM refinement, the choice, and the hard cases of
// issue 4 (fronto-parallel noise-free, 80 degrees, 12 px, strong distortion, degenerate corners).
// Ground truth: corners projected from known poses with CameraModel::project.
#include "tracking/tag_pose.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <random>

#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>

namespace commonlight::tracking {
namespace {

using Eigen::Vector2d;
using Eigen::Vector3d;
using Corners = std::array<Vector2d, 4>;

CameraModel camera(double k1 = 0.0) {
    CameraModel c;
    c.width = 1280;
    c.height = 720;
    c.fx = c.fy = 900;
    c.cx = 639.5;
    c.cy = 359.5;
    c.distortion.k1 = k1;
    return c;
}

// A tag of edge `size` at distance `distance` on the optical axis (shifted by `offset`), tilted
// by `tilt_deg` about its x axis and turned by `roll_deg` about the viewing axis.
Rigid3d tagPose(double distance, double tilt_deg, double roll_deg = 0.0, const Vector3d& offset = Vector3d::Zero()) {
    // Tag facing the camera: its +z towards the camera (camera looks along +z), so flip about x.
    const Eigen::Quaterniond facing(Eigen::AngleAxisd(std::numbers::pi, Vector3d::UnitX()));
    const Eigen::Quaterniond tilt(Eigen::AngleAxisd(tilt_deg * std::numbers::pi / 180, Vector3d::UnitX()));
    const Eigen::Quaterniond roll(Eigen::AngleAxisd(roll_deg * std::numbers::pi / 180, Vector3d::UnitZ()));
    return {roll * facing * tilt, Vector3d(0, 0, distance) + offset};
}

Corners project(const CameraModel& cam, const Rigid3d& cam_from_tag, double size) {
    Corners c;
    for (int i = 0; i < 4; ++i) {
        const auto p = cam.project(cam_from_tag * tagCornerInTag(i, size));
        EXPECT_TRUE(p);
        c[i] = *p;
    }
    return c;
}

TEST(TagPose, ExactlyFrontoParallelNoiseFree) {
    // OpenCV 4.6's IPPE misbehaves on exactly this input; the result must still be exact.
    const CameraModel cam = camera();
    for (const double roll : {0.0, 90.0, 37.0}) {
        const Rigid3d truth = tagPose(0.8, 0.0, roll);
        const Corners corners = project(cam, truth, 0.1);
        auto pose = solveTagPose(3, corners, 0.1, cam);
        ASSERT_TRUE(pose) << pose.error().message;
        EXPECT_TRUE(pose->cam_from_tag.isValid());
        EXPECT_LT(rotationErrorDeg(pose->cam_from_tag, truth), 1e-6) << "roll " << roll;
        EXPECT_LT(translationError(pose->cam_from_tag, truth), 1e-9);
        EXPECT_LT(pose->rms_px, 1e-6);
        EXPECT_TRUE(pose->covariance.allFinite());
    }
}

TEST(TagPose, FrontoParallelOffAxisAndOnTheOpticalCentre) {
    const CameraModel cam = camera(-0.2);
    const Rigid3d truth = tagPose(1.2, 0.0, 0.0, Vector3d(0.3, -0.2, 0));
    auto pose = solveTagPose(1, project(cam, truth, 0.16), 0.16, cam);
    ASSERT_TRUE(pose) << pose.error().message;
    EXPECT_LT(rotationErrorDeg(pose->cam_from_tag, truth), 1e-6);
}

TEST(TagPose, Tag80DegreesFromTheView) {
    const CameraModel cam = camera();
    const Rigid3d truth = tagPose(0.6, 80.0, 15.0);
    const Corners corners = project(cam, truth, 0.1);
    auto pose = solveTagPose(0, corners, 0.1, cam);
    ASSERT_TRUE(pose) << pose.error().message;
    EXPECT_LT(rotationErrorDeg(pose->cam_from_tag, truth), 1e-5);
    EXPECT_LT(translationError(pose->cam_from_tag, truth), 1e-8);
    EXPECT_LT(pose->ambiguity_ratio, 1e-3) << "an 80-degree view is not ambiguous without noise";
}

TEST(TagPose, TwelvePixelTagWithNoiseStaysFiniteAndClose) {
    const CameraModel cam = camera();
    // 0.1 m at 7.5 m with f = 900 px: 12 px.
    const Rigid3d truth = tagPose(7.5, 30.0, 10.0);
    const Corners clean = project(cam, truth, 0.1);
    EXPECT_NEAR((clean[1] - clean[0]).norm(), 12.0, 0.5);
    std::mt19937 rng(5);
    std::normal_distribution<double> noise(0.0, 0.2);
    int solved = 0;
    for (int trial = 0; trial < 200; ++trial) {
        Corners noisy = clean;
        for (auto& c : noisy) c += Vector2d(noise(rng), noise(rng));
        auto pose = solveTagPose(0, noisy, 0.1, cam);
        ASSERT_TRUE(pose) << pose.error().message;
        ASSERT_TRUE(pose->cam_from_tag.isValid());
        ASSERT_EQ(pose->candidates.size() == 2 || pose->candidates.size() == 1, true);
        EXPECT_LE(pose->ambiguity_ratio, 1.0);
        // Position along the ray is known to a few percent; the tilt may flip (ambiguity).
        EXPECT_LT(translationError(pose->cam_from_tag, truth), 0.05 * 7.5);
        // One of the two candidates is near the truth.
        double best = 1e9;
        for (const auto& c : pose->candidates) best = std::min(best, rotationErrorDeg(c.cam_from_tag, truth));
        EXPECT_LT(best, 25.0);
        ++solved;
    }
    EXPECT_EQ(solved, 200);
}

TEST(TagPose, PredictionLeavesTheFarCandidateUnrefined) {
    // With a prediction near one IPPE start and far (over 40 degrees) from the other, only the
    // near one is refined: the chosen pose is bit for bit the one both refinements give, and the
    // far candidate stays, as IPPE gave it, the alternative. A prediction near neither refines both.
    const CameraModel cam = camera(-0.2);
    const Rigid3d truth = tagPose(2.5, 30.0, 10.0, Vector3d(0.3, -0.2, 0.0));
    const Corners clean = project(cam, truth, 0.1);
    std::mt19937 rng(5);
    std::normal_distribution<double> noise(0.0, 0.3);
    for (int trial = 0; trial < 50; ++trial) {
        Corners noisy = clean;
        for (auto& c : noisy) c += Vector2d(noise(rng), noise(rng));
        auto alone = solveTagPose(0, noisy, 0.1, cam);
        ASSERT_TRUE(alone) << alone.error().message;
        ASSERT_EQ(alone->candidates.size(), 2u);
        const int near = rotationErrorDeg(alone->candidates[0].cam_from_tag, truth) <
                                 rotationErrorDeg(alone->candidates[1].cam_from_tag, truth)
                             ? 0
                             : 1;
        const TagPoseCandidate& near_refined = alone->candidates[static_cast<std::size_t>(near)];
        const TagPoseCandidate& far_refined = alone->candidates[static_cast<std::size_t>(1 - near)];
        const Rigid3d predicted = expSe3((Vector6d() << 0.03, -0.02, 0.0, 0.005, 0.0, 0.0).finished()) * truth;
        ASSERT_GT(rotationErrorDeg(far_refined.cam_from_tag, predicted), 45.0) << "the case must be unambiguous";
        auto guided = solveTagPose(0, noisy, 0.1, cam, predicted);
        ASSERT_TRUE(guided) << guided.error().message;
        EXPECT_EQ(guided->choice, PoseChoice::kPrediction);
        EXPECT_EQ(guided->cam_from_tag.translation, near_refined.cam_from_tag.translation);
        EXPECT_EQ(guided->cam_from_tag.rotation.coeffs(), near_refined.cam_from_tag.rotation.coeffs());
        ASSERT_EQ(guided->candidates.size(), 2u);
        const TagPoseCandidate& far = guided->candidates[1];
        EXPECT_LT(rotationErrorDeg(far.cam_from_tag, far_refined.cam_from_tag), 5.0);  // the same minimum's start
        EXPECT_GT(far.rms_px, far_refined.rms_px);  // not refined (LM lowers the residual of a noisy start)
        // Near neither (25 degrees off the truth about another axis): both refined, as without one.
        const Rigid3d elsewhere = expSe3((Vector6d() << 0.0, 0.0, 0.44, 0.0, 0.0, 0.0).finished()) * truth;
        auto both = solveTagPose(0, noisy, 0.1, cam, elsewhere);
        ASSERT_TRUE(both) << both.error().message;
        ASSERT_EQ(both->candidates.size(), 2u);
        for (const TagPoseCandidate& c : both->candidates) {
            const bool found =
                std::any_of(alone->candidates.begin(), alone->candidates.end(), [&](const TagPoseCandidate& a) {
                    return a.cam_from_tag.translation == c.cam_from_tag.translation && a.rms_px == c.rms_px;
                });
            EXPECT_TRUE(found) << "trial " << trial;
        }
    }
}

TEST(TagPose, UnrefinedPredictedStartIsIppesPoseAndTheRestIsUnchanged) {
    // refine_predicted_start = false (the tracker, which aligns the tag's pattern from there):
    // where the prediction clearly chooses, the chosen pose is the near IPPE start, not refined
    // (its corner residual above the refined one's, still close to the truth) and flagged as such;
    // the alternative is the same unrefined far start. Without a prediction, or with one near
    // neither start, the result is bit for bit the default's.
    const CameraModel cam = camera(-0.2);
    const Rigid3d truth = tagPose(2.5, 30.0, 10.0, Vector3d(0.3, -0.2, 0.0));
    const Corners clean = project(cam, truth, 0.1);
    std::mt19937 rng(7);
    std::normal_distribution<double> noise(0.0, 0.3);
    TagPoseOptions fast;
    fast.refine_predicted_start = false;
    for (int trial = 0; trial < 30; ++trial) {
        Corners noisy = clean;
        for (auto& c : noisy) c += Vector2d(noise(rng), noise(rng));
        const Rigid3d predicted = expSe3((Vector6d() << 0.03, -0.02, 0.0, 0.005, 0.0, 0.0).finished()) * truth;
        auto refined = solveTagPose(0, noisy, 0.1, cam, predicted);
        auto unrefined = solveTagPose(0, noisy, 0.1, cam, predicted, fast);
        ASSERT_TRUE(refined && unrefined);
        EXPECT_TRUE(refined->refined);
        EXPECT_FALSE(unrefined->refined);
        EXPECT_EQ(unrefined->choice, PoseChoice::kPrediction);
        ASSERT_EQ(unrefined->candidates.size(), 2u);
        EXPECT_GE(unrefined->rms_px, refined->rms_px - 1e-9);  // LM lowers the corner residual
        EXPECT_LT(rotationErrorDeg(unrefined->cam_from_tag, refined->cam_from_tag), 2.0);
        EXPECT_LT(translationError(unrefined->cam_from_tag, refined->cam_from_tag), 0.02);
        EXPECT_EQ(unrefined->candidates[1].rms_px, refined->candidates[1].rms_px);  // the same far start
        EXPECT_TRUE(unrefined->covariance.allFinite());
        for (const std::optional<Rigid3d>& other :
             {std::optional<Rigid3d>{},
              std::optional<Rigid3d>{expSe3((Vector6d() << 0.0, 0.0, 0.44, 0.0, 0.0, 0.0).finished()) * truth}}) {
            auto a = solveTagPose(0, noisy, 0.1, cam, other);
            auto b = solveTagPose(0, noisy, 0.1, cam, other, fast);
            ASSERT_TRUE(a && b);
            EXPECT_TRUE(b->refined);
            EXPECT_EQ(a->cam_from_tag.translation, b->cam_from_tag.translation);
            EXPECT_EQ(a->cam_from_tag.rotation.coeffs(), b->cam_from_tag.rotation.coeffs());
            EXPECT_EQ(a->rms_px, b->rms_px);
        }
    }
}

TEST(TagPose, StartAtPredictionSkipsIppeWhereThePredictionChooses) {
    // start_at_prediction (the tracker's verified tags): a prediction is refined alone, onto the
    // minimum the default reaches from IPPE's near start, and the alternative is the refined
    // pose's planar mirror (IPPE was not run), also nearly head-on (its mirror within twice the
    // gate; change 21). One the refinement leaves by more than half the gate is solved bit for bit
    // as by default, and the chosen pose is never the unrefined mirror (exactly head-on, where the
    // refined pose's mirror can be the nearer one to the prediction).
    const CameraModel cam = camera(-0.2);
    std::mt19937 rng(11);
    std::normal_distribution<double> noise(0.0, 0.3);
    TagPoseOptions fast;
    fast.start_at_prediction = true;
    const auto sameBits = [](const TagPose& a, const TagPose& b) {
        return a.cam_from_tag.translation == b.cam_from_tag.translation &&
               a.cam_from_tag.rotation.coeffs() == b.cam_from_tag.rotation.coeffs() && a.rms_px == b.rms_px &&
               a.candidates.size() == b.candidates.size() && a.ambiguity_ratio == b.ambiguity_ratio;
    };
    double max_head_on_deg = 0.0, max_head_on_m = 0.0;
    int head_on_alone = 0;
    for (int trial = 0; trial < 30; ++trial) {
        const Rigid3d truth = tagPose(2.5, 30.0 + trial, 10.0 * trial, Vector3d(0.3, -0.2, 0.0));
        Corners noisy = project(cam, truth, 0.1);
        for (auto& c : noisy) c += Vector2d(noise(rng), noise(rng));
        const Rigid3d predicted = expSe3((Vector6d() << 0.03, -0.02, 0.0, 0.005, 0.0, 0.0).finished()) * truth;
        auto full = solveTagPose(0, noisy, 0.1, cam, predicted);
        auto quick = solveTagPose(0, noisy, 0.1, cam, predicted, fast);
        ASSERT_TRUE(full && quick);
        EXPECT_EQ(quick->choice, PoseChoice::kPrediction);
        EXPECT_TRUE(quick->refined);
        EXPECT_LT(rotationErrorDeg(quick->cam_from_tag, full->cam_from_tag), 1e-4) << "trial " << trial;
        EXPECT_LT(translationError(quick->cam_from_tag, full->cam_from_tag), 1e-7);
        EXPECT_NEAR(quick->rms_px, full->rms_px, 1e-9);
        ASSERT_EQ(quick->candidates.size(), 2u);
        EXPECT_LT(rotationErrorDeg(quick->candidates[1].cam_from_tag, planarMirror(quick->cam_from_tag)), 1e-9);
        EXPECT_FALSE(quick->ambiguous);
        EXPECT_TRUE(quick->covariance.allFinite());
        // Nearly head-on (its mirror about 16 degrees away): refined alone as well.
        const Rigid3d head_on = tagPose(2.5, 8.0, 10.0 * trial, Vector3d(0.3, -0.2, 0.0));
        Corners head_on_corners = project(cam, head_on, 0.1);
        for (auto& c : head_on_corners) c += Vector2d(noise(rng), noise(rng));
        auto a = solveTagPose(0, head_on_corners, 0.1, cam, head_on);
        auto b = solveTagPose(0, head_on_corners, 0.1, cam, head_on, fast);
        ASSERT_TRUE(a && b);
        // Where the noisy corners' minimum lies nearer the prediction's mirror side than the
        // refined pose's own mirror does, the solve falls back to the default's, bit for bit.
        if (!sameBits(*a, *b)) {
            ++head_on_alone;
            EXPECT_EQ(b->choice, PoseChoice::kPrediction);
            EXPECT_LT(rotationErrorDeg(b->cam_from_tag, a->cam_from_tag), 1e-5) << "trial " << trial;
            EXPECT_LT(translationError(b->cam_from_tag, a->cam_from_tag), 1e-7) << "trial " << trial;
            EXPECT_NEAR(b->rms_px, a->rms_px, 1e-6) << "trial " << trial;
            ASSERT_EQ(b->candidates.size(), 2u);
            EXPECT_LT(rotationErrorDeg(b->candidates[1].cam_from_tag, planarMirror(b->cam_from_tag)), 1e-9);
            max_head_on_deg = std::max(max_head_on_deg, rotationErrorDeg(b->cam_from_tag, a->cam_from_tag));
            max_head_on_m = std::max(max_head_on_m, translationError(b->cam_from_tag, a->cam_from_tag));
        }
        // Its mirror within half the gate (0-5 degrees off its line of sight), corners made from
        // the prediction as the tracker's verified tags' are (moved by a shift): one flat valley,
        // where LM from the prediction stops elsewhere than from IPPE's starts: as by default.
        const Rigid3d facing = tagPose(2.5, 0.2 * (trial % 25), 10.0 * trial);
        Corners facing_corners = project(cam, facing, 0.1);
        for (auto& c : facing_corners) c += Vector2d(0.25, -0.15);
        auto e = solveTagPose(0, facing_corners, 0.1, cam, facing);
        auto f = solveTagPose(0, facing_corners, 0.1, cam, facing, fast);
        ASSERT_TRUE(e && f);
        EXPECT_TRUE(sameBits(*e, *f)) << "trial " << trial;
        // 25 degrees off the truth: as by default.
        const Rigid3d elsewhere = expSe3((Vector6d() << 0.0, 0.0, 0.44, 0.0, 0.0, 0.0).finished()) * truth;
        auto c = solveTagPose(0, noisy, 0.1, cam, elsewhere);
        auto d = solveTagPose(0, noisy, 0.1, cam, elsewhere, fast);
        ASSERT_TRUE(c && d);
        EXPECT_TRUE(sameBits(*c, *d)) << "trial " << trial;
    }
    std::printf("  nearly head-on: %d of 30 refined alone, within %.3g degrees and %.3g m of the default's\n",
                head_on_alone, max_head_on_deg, max_head_on_m);
    EXPECT_GE(head_on_alone, 15);
}

TEST(TagPose, PredictionResolvesTheAmbiguity) {
    const CameraModel cam = camera();
    const Rigid3d truth = tagPose(3.0, 20.0, 5.0);
    const Corners clean = project(cam, truth, 0.08);
    std::mt19937 rng(11);
    std::normal_distribution<double> noise(0.0, 0.3);
    int wrong_by_residual = 0, wrong_with_prediction = 0;
    for (int trial = 0; trial < 300; ++trial) {
        Corners noisy = clean;
        for (auto& c : noisy) c += Vector2d(noise(rng), noise(rng));
        auto alone = solveTagPose(0, noisy, 0.08, cam);
        // The prediction is the truth disturbed by 3 degrees (a filter's typical error).
        const Rigid3d predicted = expSe3((Vector6d() << 0.05, 0.0, 0.0, 0.01, 0.0, 0.0).finished()) * truth;
        auto guided = solveTagPose(0, noisy, 0.08, cam, predicted);
        ASSERT_TRUE(alone && guided);
        if (rotationErrorDeg(alone->cam_from_tag, truth) > 20) ++wrong_by_residual;  // the mirror is ~40 deg away
        if (rotationErrorDeg(guided->cam_from_tag, truth) > 20) {
            ++wrong_with_prediction;
            for (const auto& c : guided->candidates) {
                std::printf("    candidate: %.2f deg from the truth, rms %.3f px\n",
                            rotationErrorDeg(c.cam_from_tag, truth), c.rms_px);
            }
        }
        if (guided->candidates.size() == 2) {
            EXPECT_EQ(guided->choice, PoseChoice::kPrediction);
        }
    }
    std::printf("  flipped poses in 300 noisy frames: %d by residual, %d with a prediction\n", wrong_by_residual,
                wrong_with_prediction);
    EXPECT_GT(wrong_by_residual, 10) << "the case should be ambiguous";
    EXPECT_EQ(wrong_with_prediction, 0);
}

TEST(TagPose, StrongDistortionCornersAreUndistortedAndFitted) {
    const CameraModel cam = camera(-0.4);
    // Near the image corner, where k1 = -0.4 moves points by tens of pixels.
    const Rigid3d truth = tagPose(0.9, 25.0, 10.0, Vector3d(0.38, 0.2, 0));
    const Corners corners = project(cam, truth, 0.1);
    for (const Vector2d& c : corners) {
        const auto ideal = cam.undistortPixel(c);
        ASSERT_TRUE(ideal);
        EXPECT_LT((cam.distortPixel(*ideal) - c).norm(), 0.05) << "undistortion round trip";
    }
    auto pose = solveTagPose(2, corners, 0.1, cam);
    ASSERT_TRUE(pose) << pose.error().message;
    EXPECT_LT(rotationErrorDeg(pose->cam_from_tag, truth), 1e-5);
    EXPECT_LT(pose->rms_px, 1e-6);
}

// The refinement ends at a minimum of the corners' reprojection error in the distorted image:
// OpenCV's solvePnPRefineLM, run from each candidate to convergence (500 steps, 1e-14), moves it by
// nothing and improves it by nothing. Noisy corners under strong distortion (k1 -0.4, k2 0.1, p1
// 0.002), near the image corner, so that IPPE's start on the undistorted corners is not the minimum.
TEST(TagPose, CandidatesAreMinimaOfTheDistortedReprojection) {
    CameraModel cam = camera(-0.4);
    cam.distortion.k2 = 0.1;
    cam.distortion.p1 = 0.002;
    cv::Mat k_mat;
    cv::eigen2cv(cam.K(), k_mat);
    const cv::Mat dist = (cv::Mat_<double>(1, 5) << cam.distortion.k1, cam.distortion.k2, cam.distortion.p1,
                          cam.distortion.p2, cam.distortion.k3);
    std::mt19937 rng(11);
    std::normal_distribution<double> noise(0.0, 0.3);
    int candidates = 0;
    double max_moved_deg = 0.0, max_gain_px = 0.0;
    for (int trial = 0; trial < 40; ++trial) {
        const Rigid3d truth = tagPose(0.6 + 0.02 * trial, 10.0 + trial, 7.0 * trial, Vector3d(0.25, 0.12, 0));
        Corners corners = project(cam, truth, 0.05);
        for (auto& c : corners) c += Vector2d(noise(rng), noise(rng));
        const auto pose = solveTagPose(0, corners, 0.05, cam);
        ASSERT_TRUE(pose) << pose.error().message;
        for (const TagPoseCandidate& c : pose->candidates) {
            std::vector<cv::Point3d> object;
            std::vector<cv::Point2d> image;
            for (int i = 0; i < 4; ++i) {
                const Vector3d o = tagCornerInTag(i, 0.05);
                object.emplace_back(o.x(), o.y(), o.z());
                image.emplace_back(corners[i].x(), corners[i].y());
            }
            cv::Mat rmat, rvec, tvec;
            cv::eigen2cv(Eigen::Matrix3d(c.cam_from_tag.rotationMatrix()), rmat);
            cv::Rodrigues(rmat, rvec);
            cv::eigen2cv(Vector3d(c.cam_from_tag.translation), tvec);
            cv::solvePnPRefineLM(object, image, k_mat, dist, rvec, tvec,
                                 cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 500, 1e-14));
            cv::Rodrigues(rvec, rmat);
            Eigen::Matrix3d r;
            cv::cv2eigen(rmat, r);
            Vector3d t;
            cv::cv2eigen(tvec, t);
            const Rigid3d converged(Eigen::Quaterniond(r), t);
            max_moved_deg = std::max(max_moved_deg, rotationErrorDeg(converged, c.cam_from_tag));
            max_gain_px = std::max(max_gain_px, c.rms_px - tagReprojectionRms(corners, 0.05, cam, converged));
            ++candidates;
        }
    }
    std::printf("  %d candidates: OpenCV's converged LM moves them by at most %.2g deg, lowers the RMS by at most %.2g px\n",
                candidates, max_moved_deg, max_gain_px);
    EXPECT_GE(candidates, 40);
    EXPECT_LT(max_moved_deg, 1e-3);
    EXPECT_LT(max_gain_px, 1e-7);
}

TEST(TagPose, DegenerateCornersAreErrorsNotNan) {
    const CameraModel cam = camera();
    const Corners good = project(cam, tagPose(1.0, 10.0), 0.1);
    Corners duplicated = good;
    duplicated[2] = duplicated[1];
    Corners collinear = good;
    collinear[2] = 0.5 * (collinear[1] + collinear[3]);
    Corners all_on_a_line = {Vector2d(10, 10), Vector2d(20, 20), Vector2d(30, 30), Vector2d(40, 40)};
    Corners crossing = good;
    std::swap(crossing[1], crossing[2]);
    Corners not_finite = good;
    not_finite[0].x() = std::nan("");
    Corners point = {Vector2d(5, 5), Vector2d(5, 5), Vector2d(5, 5), Vector2d(5, 5)};
    for (const auto& [name, corners] : {std::pair{"duplicated", duplicated}, std::pair{"collinear", collinear},
                                        std::pair{"all on a line", all_on_a_line}, std::pair{"crossing", crossing},
                                        std::pair{"NaN", not_finite}, std::pair{"a point", point}}) {
        auto pose = solveTagPose(4, corners, 0.1, cam);
        ASSERT_FALSE(pose) << name;
        EXPECT_EQ(pose.error().code, ErrorCode::kBadInput) << name;
        EXPECT_NE(pose.error().message.find("tag 4"), std::string::npos) << pose.error().message;
    }
    EXPECT_FALSE(solveTagPose(4, good, 0.0, cam));
    EXPECT_FALSE(solveTagPose(4, good, std::nan(""), cam));
    Rigid3d nan_prediction;
    nan_prediction.translation.x() = std::nan("");
    EXPECT_FALSE(solveTagPose(4, good, 0.1, cam, nan_prediction));
}

TEST(TagPose, CornersBeyondTheLensFoldAreAnError) {
    CameraModel cam = camera(-0.6);  // folds at a normalised radius of ~0.75
    const Corners far_out = {Vector2d(-400, -300), Vector2d(-350, -300), Vector2d(-350, -250), Vector2d(-400, -250)};
    auto pose = solveTagPose(1, far_out, 0.1, cam);
    ASSERT_FALSE(pose);
    EXPECT_EQ(pose.error().code, ErrorCode::kBadInput);
}

TEST(TagPose, CovarianceMatchesTheScatterOfNoisySolutions) {
    const CameraModel cam = camera();
    const Rigid3d truth = tagPose(1.0, 35.0, 20.0);
    const Corners clean = project(cam, truth, 0.12);
    std::mt19937 rng(3);
    std::normal_distribution<double> noise(0.0, 0.5);
    TagPoseOptions options;
    options.corner_sigma_px = 0.5;
    Matrix6d scatter = Matrix6d::Zero();
    Matrix6d predicted = Matrix6d::Zero();
    constexpr int kTrials = 2000;
    for (int trial = 0; trial < kTrials; ++trial) {
        Corners noisy = clean;
        for (auto& c : noisy) c += Vector2d(noise(rng), noise(rng));
        auto pose = solveTagPose(0, noisy, 0.12, cam, truth, options);
        ASSERT_TRUE(pose);
        const Vector6d xi = logSe3(truth * pose->cam_from_tag.inverse());
        scatter += xi * xi.transpose();
        predicted += pose->covariance;
    }
    scatter /= kTrials;
    predicted /= kTrials;
    for (int k = 0; k < 6; ++k) {
        EXPECT_NEAR(std::sqrt(scatter(k, k) / predicted(k, k)), 1.0, 0.15) << "axis " << k;
    }
}

}  // namespace
}  // namespace commonlight::tracking

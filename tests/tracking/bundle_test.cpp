// Multi-tag bundle: one pose from every corner, robust to a moved tag, exact far from the origin.
// Ground truth: corners projected from known poses.
#include <cmath>
#include <numbers>
#include <random>

#include <gtest/gtest.h>

#include <cstdio>

#include "tracking/bundle.h"
#include "tracking/projection.h"

namespace commonlight::tracking {
namespace {

using Eigen::Vector2d;
using Eigen::Vector3d;

CameraModel camera() {
    CameraModel c;
    c.width = 1280;
    c.height = 720;
    c.fx = c.fy = 900;
    c.cx = 639.5;
    c.cy = 359.5;
    c.distortion.k1 = -0.15;
    c.distortion.k2 = 0.03;
    return c;
}

// A board of four 8 cm tags on a table at height 0.75, around `origin`.
TagSet board(const Vector3d& origin) {
    TagSet tags;
    const double xs[] = {-0.06, 0.06};
    int id = 0;
    for (double y : {0.06, -0.06}) {
        for (double x : xs) tags.items.push_back({id++, 0.08, Rigid3d({1, 0, 0, 0}, origin + Vector3d(x, y, 0.75))});
    }
    return tags;
}

struct Frame {
    std::vector<TagDetection> detections;
    std::vector<std::optional<TagPose>> singles;
};

Frame observe(const CameraModel& cam, const TagSet& tags, const Rigid3d& cam_from_world, double noise_px,
              std::mt19937& rng) {
    std::normal_distribution<double> noise(0.0, noise_px);
    Frame f;
    for (const TagItem& item : tags.items) {
        TagDetection d;
        d.id = item.id;
        for (int c = 0; c < 4; ++c) {
            const auto p = cam.project(cam_from_world * (item.world_from_tag * tagCornerInTag(c, item.size)));
            EXPECT_TRUE(p);
            d.corners[c] = *p + Vector2d(noise(rng), noise(rng));
        }
        f.detections.push_back(d);
    }
    for (const TagDetection& d : f.detections) {
        auto pose = solveTagPose(d.id, d.corners, 0.08, cam);
        f.singles.push_back(pose ? std::optional<TagPose>(*pose) : std::nullopt);
    }
    return f;
}

std::vector<BundleTag> bundleTags(const Frame& f) {
    std::vector<BundleTag> out;
    for (std::size_t i = 0; i < f.detections.size(); ++i) {
        out.push_back({&f.detections[i], f.singles[i] ? &*f.singles[i] : nullptr});
    }
    return out;
}

Rigid3d viewOf(const Vector3d& origin) {
    auto world_from_cam = worldFromCamLookingAt(origin + Vector3d(0.3, -0.9, 1.5), origin + Vector3d(0, 0, 0.75));
    EXPECT_TRUE(world_from_cam);
    return world_from_cam->inverse();
}

// The bundle's LM passes the pixel its cost already projected: the Jacobian must be the one
// projecting again gives, bit for bit (the bundle's output is unchanged by the reuse).
TEST(Bundle, JacobianFromTheKnownPixelEqualsProjectingAgain) {
    const CameraModel cam = camera();
    for (const Vector3d& p : {Vector3d(0.1, -0.05, 0.9), Vector3d(-0.4, 0.3, 0.7), Vector3d(0.0, 0.0, 2.0)}) {
        const auto full = projectWithJacobian(cam, p);
        ASSERT_TRUE(full.has_value());
        const auto reused = projectWithJacobian(cam, p, *cam.project(p));
        ASSERT_TRUE(reused.has_value());
        EXPECT_EQ(reused->pixel, full->pixel);
        EXPECT_EQ(reused->d_pixel_d_xi, full->d_pixel_d_xi);
        EXPECT_EQ(reused->d_pixel_d_p, full->d_pixel_d_p);
    }
    EXPECT_FALSE(projectWithJacobian(cam, Vector3d(0.1, 0.0, -1.0), Vector2d(0, 0)).has_value());
}

TEST(Bundle, NoiseFreeIsExact) {
    const CameraModel cam = camera();
    const TagSet tags = board(Vector3d::Zero());
    const Rigid3d truth = viewOf(Vector3d::Zero());
    std::mt19937 rng(1);
    const Frame f = observe(cam, tags, truth, 0.0, rng);
    const auto bt = bundleTags(f);
    auto result = solveBundle(bt, tags, cam);
    ASSERT_TRUE(result) << result.error().message;
    EXPECT_LT(rotationErrorDeg(result->cam_from_world, truth), 1e-7);
    EXPECT_LT(translationError(result->cam_from_world, truth), 1e-9);
    EXPECT_EQ(result->tags_used.size(), 4u);
    EXPECT_TRUE(result->tags_rejected.empty());
}

TEST(Bundle, OneKilometreFromTheOriginIsAsAccurate) {
    const CameraModel cam = camera();
    for (const Vector3d& origin : {Vector3d(0, 0, 0), Vector3d(1000.0, -1000.0, 50.0), Vector3d(3.1e4, 2.7e4, 0)}) {
        const TagSet tags = board(origin);
        const Rigid3d truth = viewOf(origin);
        std::mt19937 rng(2);
        const Frame f = observe(cam, tags, truth, 0.0, rng);
        const auto bt = bundleTags(f);
        auto result = solveBundle(bt, tags, cam);
        ASSERT_TRUE(result) << result.error().message;
        EXPECT_LT(rotationErrorDeg(result->cam_from_world, truth), 1e-6) << origin.transpose();
        // Camera centre in the world: metres-level coordinates, sub-micrometre error.
        const Vector3d centre = result->cam_from_world.inverse().translation;
        EXPECT_LT((centre - truth.inverse().translation).norm(), 1e-7) << origin.transpose();
    }
}

TEST(Bundle, MovedTagIsRejectedAsAnOutlier) {
    const CameraModel cam = camera();
    const TagSet tags = board(Vector3d::Zero());
    TagSet moved = tags;
    const Rigid3d truth = viewOf(Vector3d::Zero());
    std::mt19937 rng(3);
    // The scene says tag 2 is where it was; the real tag moved 3 cm.
    moved.items[2].world_from_tag.translation += Vector3d(0.03, 0.0, 0.0);
    const Frame f = observe(cam, moved, truth, 0.3, rng);
    const auto bt = bundleTags(f);
    auto result = solveBundle(bt, tags, cam);
    ASSERT_TRUE(result) << result.error().message;
    ASSERT_EQ(result->tags_rejected.size(), 1u);
    EXPECT_EQ(result->tags_rejected[0], 2);
    // The same pose as a bundle that never saw tag 2.
    std::vector<BundleTag> without;
    for (const BundleTag& t : bt) {
        if (t.detection->id != 2) without.push_back(t);
    }
    auto clean = solveBundle(without, tags, cam);
    ASSERT_TRUE(clean);
    EXPECT_LT(rotationErrorDeg(result->cam_from_world, clean->cam_from_world), 1e-6);
    EXPECT_LT(translationError(result->cam_from_world, clean->cam_from_world), 1e-8);
    // And what it would be with the moved tag kept is worse.
    BundleOptions keep_all;
    keep_all.outlier_px = 1e9;
    auto polluted = solveBundle(bt, tags, cam, std::nullopt, keep_all);
    ASSERT_TRUE(polluted);
    EXPECT_GT(translationError(polluted->cam_from_world, truth), translationError(result->cam_from_world, truth));
}

// A tag whose corners are less precise (BundleTag::weight < 1: the tracker's verified tags)
// pulls the pose less: tag 3's corners are all 0.4 px off (under the outlier threshold); at
// weight 0.1 the camera centre is less than half as far from the truth as at 1. A weight that
// is not positive is an error naming the tag.
TEST(Bundle, WeightedTagPullsLess) {
    const CameraModel cam = camera();
    const TagSet tags = board(Vector3d::Zero());
    const Rigid3d truth = viewOf(Vector3d::Zero());
    std::mt19937 rng(9);
    Frame f = observe(cam, tags, truth, 0.0, rng);
    for (auto& c : f.detections[3].corners) c += Vector2d(0.4, 0.0);
    auto bt = bundleTags(f);
    auto equal = solveBundle(bt, tags, cam);
    bt[3].weight = 0.1;
    auto weighted = solveBundle(bt, tags, cam);
    ASSERT_TRUE(equal && weighted);
    const double e_equal = translationError(equal->cam_from_world.inverse(), truth.inverse());
    const double e_weighted = translationError(weighted->cam_from_world.inverse(), truth.inverse());
    std::printf("camera centre error with tag 3 0.4 px off: weight 1 %.3f mm, weight 0.1 %.3f mm\n", 1000 * e_equal,
                1000 * e_weighted);
    EXPECT_LT(e_weighted, 0.5 * e_equal);
    bt[3].weight = 0.0;
    auto bad = solveBundle(bt, tags, cam);
    ASSERT_FALSE(bad);
    EXPECT_NE(bad.error().message.find("tag 3"), std::string::npos);
}

TEST(Bundle, UnknownTagsAreListedAndIgnored) {
    const CameraModel cam = camera();
    const TagSet tags = board(Vector3d::Zero());
    const Rigid3d truth = viewOf(Vector3d::Zero());
    std::mt19937 rng(4);
    Frame f = observe(cam, tags, truth, 0.2, rng);
    f.detections[3].id = 99;  // not in the scene
    if (f.singles[3]) f.singles[3]->id = 99;
    const auto bt = bundleTags(f);
    auto result = solveBundle(bt, tags, cam);
    ASSERT_TRUE(result) << result.error().message;
    EXPECT_EQ(result->tags_unknown, std::vector<int>{99});
    EXPECT_EQ(result->tags_used.size(), 3u);

    // Only unknown tags: an error that says so, not a pose.
    TagSet other;
    other.items.push_back({42, 0.08, Rigid3d::identity()});
    auto none = solveBundle(bt, other, cam);
    ASSERT_FALSE(none);
    EXPECT_NE(none.error().message.find("none of the detected tags"), std::string::npos);
    EXPECT_FALSE(solveBundle({}, tags, cam));
}

TEST(Bundle, BeatsTheSingleTagsAndItsCovarianceMatchesTheScatter) {
    const CameraModel cam = camera();
    const TagSet tags = board(Vector3d::Zero());
    const Rigid3d truth = viewOf(Vector3d::Zero());
    std::mt19937 rng(5);
    constexpr int kTrials = 500;
    Matrix6d scatter = Matrix6d::Zero(), predicted = Matrix6d::Zero();
    double bundle_rot = 0.0, single_rot = 0.0;
    for (int trial = 0; trial < kTrials; ++trial) {
        const Frame f = observe(cam, tags, truth, 0.5, rng);
        const auto bt = bundleTags(f);
        auto result = solveBundle(bt, tags, cam);
        ASSERT_TRUE(result) << result.error().message;
        const Vector6d xi = logSe3(truth * result->cam_from_world.inverse());
        scatter += xi * xi.transpose();
        predicted += result->covariance;
        bundle_rot += rotationErrorDeg(result->cam_from_world, truth);
        ASSERT_TRUE(f.singles[0]);
        single_rot += rotationErrorDeg(f.singles[0]->cam_from_tag * tags.items[0].world_from_tag.inverse(), truth);
    }
    std::printf("  mean rotation error: bundle %.3f deg, single tag %.3f deg\n", bundle_rot / kTrials,
                single_rot / kTrials);
    EXPECT_LT(bundle_rot, 0.5 * single_rot);
    scatter /= kTrials;
    predicted /= kTrials;
    for (int k = 0; k < 6; ++k) EXPECT_NEAR(std::sqrt(scatter(k, k) / predicted(k, k)), 1.0, 0.2) << "axis " << k;
}

TEST(Bundle, UsesThePredictionAsAStart) {
    const CameraModel cam = camera();
    TagSet one;
    one.items.push_back({0, 0.08, Rigid3d({1, 0, 0, 0}, Vector3d(0, 0, 0.75))});
    const Rigid3d truth = viewOf(Vector3d::Zero());
    std::mt19937 rng(6);
    const Frame f = observe(cam, one, truth, 0.0, rng);
    // Without single-tag candidates, the prediction is the only start.
    std::vector<BundleTag> bt = {{&f.detections[0], nullptr}};
    EXPECT_FALSE(solveBundle(bt, one, cam));
    const Rigid3d near = expSe3((Vector6d() << 0.02, -0.01, 0.01, 0.01, 0.0, -0.01).finished()) * truth;
    auto result = solveBundle(bt, one, cam, near);
    ASSERT_TRUE(result) << result.error().message;
    EXPECT_LT(rotationErrorDeg(result->cam_from_world, truth), 1e-6);
}

// A start in the board's other planar minimum crawls to the iteration cap at a cost thousands of
// times the winner's; once it cannot end below the earlier start's cost it is given up (issue 13,
// pass 11). The result is the one refining every start to the end gives, with far fewer steps.
TEST(Bundle, AHopelessStartIsGivenUpWithoutChangingTheResult) {
    const CameraModel cam = camera();
    const TagSet tags = board(Vector3d::Zero());
    std::mt19937 rng(11);
    BundleOptions all;
    all.give_up_hopeless_starts = false;
    int steps = 0, steps_all = 0, fewer = 0;
    for (int trial = 0; trial < 40; ++trial) {
        // Views 0.75-1.05 m above the board, 0.3-0.4 m to its side: the tags' candidates give
        // starts in both of the board's minima.
        const Vector3d eye(0.2 * (trial % 5) - 0.4, -0.3 - 0.05 * (trial % 3), 1.5 + 0.1 * (trial % 4));
        auto world_from_cam = worldFromCamLookingAt(eye, Vector3d(0.02 * (trial % 3), 0, 0.75));
        ASSERT_TRUE(world_from_cam);
        const Frame f = observe(cam, tags, world_from_cam->inverse(), 0.4, rng);
        const auto bt = bundleTags(f);
        const auto given_up = solveBundle(bt, tags, cam);
        const auto refined = solveBundle(bt, tags, cam, std::nullopt, all);
        ASSERT_TRUE(given_up && refined);
        // The same minimum: where a start given up would have reached the winner's own minimum
        // and ended a rounding error below it (LM's stop at a relative decrease of 1e-14), the
        // poses differ by up to 1e-8 degrees and 1e-10 m.
        EXPECT_LT(rotationErrorDeg(given_up->cam_from_world, refined->cam_from_world), 1e-7) << "trial " << trial;
        EXPECT_LT((given_up->cam_from_world.translation - refined->cam_from_world.translation).norm(), 1e-9);
        EXPECT_NEAR(given_up->rms_px, refined->rms_px, 1e-8);
        EXPECT_EQ(given_up->tags_used, refined->tags_used);
        EXPECT_LE(given_up->iterations_all_starts, refined->iterations_all_starts);
        steps += given_up->iterations_all_starts;
        steps_all += refined->iterations_all_starts;
        fewer += given_up->iterations_all_starts < refined->iterations_all_starts;
    }
    std::printf("  LM steps over every start: %d given up, %d refined to the end; fewer in %d of 40 frames\n", steps,
                steps_all, fewer);
    EXPECT_GE(fewer, 30);
    EXPECT_LT(steps, 0.5 * steps_all);
}

// With a prediction, its own start is refined first and, ending within predicted_minimum_deg (2)
// of it, is the answer; else the starts are ranked and refined until the best fit lies that near
// (issue 13, change 22): the same pose as refining every start, in fewer steps; a prediction
// further off than that leaves every start refined, as before.
TEST(Bundle, StartsBeyondTheMinimumNearThePredictionAreNotRefined) {
    const CameraModel cam = camera();
    const TagSet tags = board(Vector3d::Zero());
    std::mt19937 rng(23);
    BundleOptions all;
    all.predicted_minimum_deg = 0.0;
    int steps = 0, steps_all = 0, fewer = 0;
    for (int trial = 0; trial < 40; ++trial) {
        const Vector3d eye(0.2 * (trial % 5) - 0.4, -0.3 - 0.05 * (trial % 3), 1.5 + 0.1 * (trial % 4));
        auto world_from_cam = worldFromCamLookingAt(eye, Vector3d(0.02 * (trial % 3), 0, 0.75));
        ASSERT_TRUE(world_from_cam);
        const Rigid3d truth = world_from_cam->inverse();
        const Frame f = observe(cam, tags, truth, 0.4, rng);
        const auto bt = bundleTags(f);
        // A motion model's prediction: 0.3-0.6 degrees and a few mm off.
        const double a = 0.005 + 0.0025 * (trial % 3);
        const Rigid3d near = expSe3((Vector6d() << a, -a, 0.5 * a, 0.003, -0.002, 0.004).finished()) * truth;
        const auto fast = solveBundle(bt, tags, cam, near);
        const auto every = solveBundle(bt, tags, cam, near, all);
        ASSERT_TRUE(fast && every);
        // The same minimum (LM from another start stops up to 1.4e-7 degrees and 1.9e-9 m apart).
        EXPECT_LT(rotationErrorDeg(fast->cam_from_world, every->cam_from_world), 1e-6) << "trial " << trial;
        EXPECT_LT((fast->cam_from_world.translation - every->cam_from_world.translation).norm(), 1e-8);
        EXPECT_LT(rotationErrorDeg(fast->cam_from_world, truth), 2.0);  // not the board's other minimum
        EXPECT_EQ(fast->tags_used, every->tags_used);
        EXPECT_LE(fast->iterations_all_starts, every->iterations_all_starts);
        steps += fast->iterations_all_starts;
        steps_all += every->iterations_all_starts;
        fewer += fast->iterations_all_starts < every->iterations_all_starts;
        // A prediction 10 degrees off: no fit lies near it, every start is refined (after the
        // prediction's own).
        const Rigid3d off = expSe3((Vector6d() << 0.12, -0.12, 0.0, 0.0, 0.0, 0.0).finished()) * truth;
        const auto far_fast = solveBundle(bt, tags, cam, off);
        const auto far_every = solveBundle(bt, tags, cam, off, all);
        ASSERT_TRUE(far_fast && far_every);
        EXPECT_GE(far_fast->iterations_all_starts, far_every->iterations_all_starts) << "trial " << trial;
        EXPECT_LT(rotationErrorDeg(far_fast->cam_from_world, far_every->cam_from_world), 1e-7) << "trial " << trial;
        EXPECT_LT((far_fast->cam_from_world.translation - far_every->cam_from_world.translation).norm(), 1e-9);
    }
    std::printf("  LM steps over every start, predicted: %d with the stop, %d without; fewer in %d of 40 frames\n",
                steps, steps_all, fewer);
    EXPECT_GE(fewer, 30);
    EXPECT_LT(steps, 0.8 * steps_all);
}

// The projection's Jacobian (the distortion's part analytic since issue 13's pass 11) against
// central differences of CameraModel::project, with every distortion term.
TEST(Bundle, ProjectionJacobianMatchesDifferences) {
    CameraModel cam = camera();
    cam.distortion = {-0.3, 0.09, 0.002, -0.0015, -0.01};
    std::mt19937 rng(17);
    std::uniform_real_distribution<double> uni(-1.0, 1.0);
    double worst = 0.0;
    for (int i = 0; i < 200; ++i) {
        const Vector3d p(0.5 * uni(rng), 0.3 * uni(rng), 1.0 + 0.3 * uni(rng));
        const auto proj = projectWithJacobian(cam, p);
        ASSERT_TRUE(proj);
        for (int k = 0; k < 3; ++k) {
            constexpr double h = 1e-6;
            Vector3d step = Vector3d::Zero();
            step[k] = h;
            const auto plus = cam.project(p + step), minus = cam.project(p - step);
            ASSERT_TRUE(plus && minus);
            const Vector2d numeric = (*plus - *minus) / (2 * h);
            worst = std::max(worst, (numeric - proj->d_pixel_d_p.col(k)).norm() / numeric.norm());
        }
    }
    EXPECT_LT(worst, 1e-6);
}

}  // namespace
}  // namespace commonlight::tracking

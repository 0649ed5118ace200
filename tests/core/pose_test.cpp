#include "core/pose.h"

#include <algorithm>
#include <cmath>

#include <gtest/gtest.h>

namespace commonlight {
namespace {

TEST(Pose, RpyFollowsTheSceneConvention) {
    // yaw 90 degrees about world z: x axis goes to y.
    const Rigid3d yaw = Rigid3d::fromRpyDeg(Eigen::Vector3d::Zero(), {0, 0, 90});
    EXPECT_NEAR((yaw * Eigen::Vector3d::UnitX() - Eigen::Vector3d::UnitY()).norm(), 0, 1e-12);
    // R = Rz(yaw) Ry(pitch) Rx(roll): roll is applied first.
    const Rigid3d both = Rigid3d::fromRpyDeg(Eigen::Vector3d::Zero(), {90, 0, 90});
    // Rx(90) takes y to z, Rz(90) keeps z.
    EXPECT_NEAR((both * Eigen::Vector3d::UnitY() - Eigen::Vector3d::UnitZ()).norm(), 0, 1e-12);
}

TEST(Pose, RpyRoundTripsIncludingGimbalLock) {
    for (const Eigen::Vector3d& rpy : {Eigen::Vector3d(10, 20, 30), Eigen::Vector3d(-170, 45, 120),
                                      Eigen::Vector3d(0, 90, 30), Eigen::Vector3d(0, -90, -60)}) {
        const Rigid3d pose = Rigid3d::fromRpyDeg({1, 2, 3}, rpy);
        const Rigid3d again = Rigid3d::fromRpyDeg({1, 2, 3}, pose.rpyDeg());
        EXPECT_LT(rotationErrorDeg(pose, again), 1e-9) << rpy.transpose();
    }
}

TEST(Pose, CompositionReadsLeftToRight) {
    const Rigid3d world_from_tag = Rigid3d::fromRpyDeg({0.5, 0, 0.75}, {0, 0, 30});
    const Rigid3d world_from_cam = Rigid3d::fromRpyDeg({0, -1, 1.5}, {-120, 0, 10});
    const Rigid3d cam_from_world = world_from_cam.inverse();
    const Rigid3d cam_from_tag = cam_from_world * world_from_tag;
    const Eigen::Vector3d p_in_tag(0.01, 0.02, 0.0);
    const Eigen::Vector3d via_world = cam_from_world * (world_from_tag * p_in_tag);
    EXPECT_LT((cam_from_tag * p_in_tag - via_world).norm(), 1e-12);
    EXPECT_LT(rotationErrorDeg(world_from_cam * cam_from_world, Rigid3d::identity()), 1e-9);
}

TEST(Pose, FromMatrixValidatesRigidity) {
    const Rigid3d pose = Rigid3d::fromRpyDeg({1, 2, 3}, {5, 6, 7});
    const auto back = Rigid3d::fromMatrix(pose.matrix());
    ASSERT_TRUE(back);
    EXPECT_LT(rotationErrorDeg(*back, pose), 1e-9);
    EXPECT_LT(translationError(*back, pose), 1e-12);

    Eigen::Matrix4d scaled = pose.matrix();
    scaled.topLeftCorner<3, 3>() *= 2.0;
    EXPECT_FALSE(Rigid3d::fromMatrix(scaled));
    Eigen::Matrix4d mirrored = Eigen::Matrix4d::Identity();
    mirrored(0, 0) = -1.0;
    EXPECT_FALSE(Rigid3d::fromMatrix(mirrored));
    Eigen::Matrix4d nan = pose.matrix();
    nan(0, 3) = NAN;
    EXPECT_FALSE(Rigid3d::fromMatrix(nan));
}

TEST(Pose, IsValidRejectsNaN) {
    Rigid3d pose;
    EXPECT_TRUE(pose.isValid());
    pose.translation.x() = NAN;
    EXPECT_FALSE(pose.isValid());
}

TEST(Pose, InterpolateEndpointsAndMidpoint) {
    const Rigid3d a = Rigid3d::fromRpyDeg({0, 0, 0}, {0, 0, 0});
    const Rigid3d b = Rigid3d::fromRpyDeg({2, 0, 0}, {0, 0, 90});
    const Rigid3d mid = interpolate(a, b, 0.5);
    EXPECT_NEAR(rotationErrorDeg(mid, a), 45.0, 1e-9);
    EXPECT_NEAR(mid.translation.x(), 1.0, 1e-12);
    EXPECT_LT(rotationErrorDeg(interpolate(a, b, 1.0), b), 1e-9);
}

TEST(Pose, LookAtUsesOpenCvCameraAxes) {
    auto pose = worldFromCamLookingAt({0, -2, 1}, {0, 0, 1});
    ASSERT_TRUE(pose);
    // Looking along +y: camera x is world +x, camera y (down) is world -z.
    EXPECT_LT((pose->rotation * Eigen::Vector3d::UnitX() - Eigen::Vector3d::UnitX()).norm(), 1e-12);
    EXPECT_LT((pose->rotation * Eigen::Vector3d::UnitY() + Eigen::Vector3d::UnitZ()).norm(), 1e-12);
    EXPECT_LT((pose->inverse() * Eigen::Vector3d(0, 0, 1) - Eigen::Vector3d(0, 0, 2)).norm(), 1e-12);
    EXPECT_FALSE(worldFromCamLookingAt({0, 0, 1}, {0, 0, 1}));
    EXPECT_FALSE(worldFromCamLookingAt({0, 0, 2}, {0, 0, 1}));  // straight down: roll undefined
}

TEST(Pose, Se3ExpLogRoundTripIncludingHardCases) {
    const Rigid3d cases[] = {
        Rigid3d::identity(),
        Rigid3d::fromRpyDeg({1, -2, 3}, {10, 20, 30}),
        Rigid3d::fromRpyDeg({0.5, 0, 0}, {0, 0, 1e-9}),   // tiny rotation: Taylor branch
        Rigid3d::fromRpyDeg({0.5, 0.1, 0}, {0, 0, 180}),  // rotation of pi
        Rigid3d::fromRpyDeg({1000.0, -2000.0, 5.0}, {-170, 80, 45}),
    };
    for (const Rigid3d& pose : cases) {
        const Rigid3d back = expSe3(logSe3(pose));
        EXPECT_LT(rotationErrorDeg(back, pose), 1e-9);
        EXPECT_LT(translationError(back, pose), 1e-9 * std::max(1.0, pose.translation.norm()));
        EXPECT_TRUE(logSe3(pose).allFinite());
    }
}

TEST(Pose, Se3InterpolationFollowsTheScrew) {
    // A pure rotation about an axis through (1, 0, 0): the midpoint stays on the circle of radius 1.
    const Rigid3d about_x1 = Rigid3d(Eigen::Quaterniond::Identity(), {1, 0, 0}) *
                             Rigid3d::fromRpyDeg({0, 0, 0}, {0, 0, 90}) *
                             Rigid3d(Eigen::Quaterniond::Identity(), {-1, 0, 0});
    const Rigid3d mid = interpolateSe3(Rigid3d::identity(), about_x1, 0.5);
    EXPECT_NEAR(rotationErrorDeg(mid, Rigid3d::identity()), 45.0, 1e-9);
    // The origin moves on the circle around (1, 0, 0): it stays at distance 1 from it.
    EXPECT_NEAR((mid.translation - Eigen::Vector3d(1, 0, 0)).norm(), 1.0, 1e-12);
    EXPECT_LT(translationError(interpolateSe3(Rigid3d::identity(), about_x1, 1.0), about_x1), 1e-12);
    EXPECT_LT(translationError(interpolateSe3(about_x1, about_x1, 0.3), about_x1), 1e-12);
}
}  // namespace
}  // namespace commonlight

#include "mocks/sim/trajectory.h"

#include <gtest/gtest.h>

namespace commonlight::mocks::sim {
namespace {

TEST(Trajectory, KeyframesInterpolateOnSe3AndHoldOutside) {
    auto trajectory = Trajectory::parse(R"(
rate_hz: 10
keyframes:
  - {t: 0.0, eye: [0, -2, 1], target: [0, 0, 1]}
  - {t: 1.0, world_from_cam: {t: [1, -2, 1], rpy_deg: [-90, 0, 20]}}
)", "traj.yaml");
    ASSERT_TRUE(trajectory) << trajectory.error().message;
    EXPECT_EQ(trajectory->frameCount(), 11);
    const Rigid3d start = trajectory->worldFromCam(0.0);
    const Rigid3d end = trajectory->worldFromCam(1.0);
    EXPECT_LT(translationError(trajectory->worldFromCam(-5.0), start), 1e-12);
    EXPECT_LT(translationError(trajectory->worldFromCam(5.0), end), 1e-12);
    const Rigid3d mid = trajectory->worldFromCam(0.5);
    EXPECT_LT(translationError(mid, interpolateSe3(start, end, 0.5)), 1e-12);
    EXPECT_NEAR(rotationErrorDeg(mid, start), 0.5 * rotationErrorDeg(end, start), 1e-9);
}

TEST(Trajectory, OrbitKeepsTheTargetCentredAtItsRadius) {
    auto trajectory = Trajectory::parse(
        "orbit: {target: [0.1, 0.2, 0.75], radius: 1.2, height: 0.5, from_deg: -30, to_deg: 30, duration: 2}\n", "o.yaml");
    ASSERT_TRUE(trajectory) << trajectory.error().message;
    EXPECT_EQ(trajectory->frameCount(), 61);  // 30 fps default
    for (double t : {0.0, 0.7, 2.0}) {
        const Rigid3d world_from_cam = trajectory->worldFromCam(t);
        const Eigen::Vector3d target_in_cam = world_from_cam.inverse() * Eigen::Vector3d(0.1, 0.2, 0.75);
        EXPECT_NEAR(target_in_cam.x(), 0.0, 1e-12);
        EXPECT_NEAR(target_in_cam.y(), 0.0, 1e-12);
        const Eigen::Vector3d offset = world_from_cam.translation - Eigen::Vector3d(0.1, 0.2, 0.75);
        EXPECT_NEAR(offset.head<2>().norm(), 1.2, 1e-12);
        EXPECT_NEAR(offset.z(), 0.5, 1e-12);
    }
}

TEST(Trajectory, PanMovesTheTargetOnALine) {
    auto trajectory = Trajectory::parse("pan: {eye: [0, -1, 1.3], from: [-0.3, 0, 0.75], to: [0.3, 0, 0.75], duration: 1}\n",
                                        "p.yaml");
    ASSERT_TRUE(trajectory) << trajectory.error().message;
    const Rigid3d mid = trajectory->worldFromCam(0.5);
    const Eigen::Vector3d target_in_cam = mid.inverse() * Eigen::Vector3d(0, 0, 0.75);
    EXPECT_NEAR(target_in_cam.x(), 0.0, 1e-12);
    EXPECT_NEAR(target_in_cam.y(), 0.0, 1e-12);
}

TEST(Trajectory, BadFilesNameTheKey) {
    struct Case {
        const char* text;
        const char* expected;
    };
    const Case cases[] = {
        {"keyframes: []\n", "needs at least one keyframe"},
        {"keyframes:\n  - {t: 1, eye: [0, -1, 1], target: [0, 0, 1]}\n  - {t: 1, eye: [0, -2, 1], target: [0, 0, 1]}\n",
         "keyframes[1].t': times must increase"},
        {"keyframes:\n  - {t: 0, eye: [0, 0, 2], target: [0, 0, 1]}\n", "parallel to the up vector"},
        {"keyframes:\n  - {t: 0, eye: [0, 0, 2]}\n", "keyframes[0].target': missing"},
        {"keyframes:\n  - {t: 0, world_from_cam: {t: [0, 0, 1]}, eye: [0, 0, 2]}\n", "give either eye + target or world_from_cam"},
        {"orbit: {target: [0, 0, 0], radius: -1, height: 0, from_deg: 0, to_deg: 1, duration: 1}\n", "orbit.radius"},
        {"orbit: {target: [0, 0, 0], radius: 1, height: 0, from_deg: 0, to_deg: 1, duration: 1, speed: 2}\n",
         "unknown key"},
        {"pan: {eye: [0, 0, 0], from: [0, 1, 0], to: [0, 1, 0], duration: 1}\nkeyframes: []\n", "exactly one of"},
        {"rate_hz: 0\npan: {eye: [0, 0, 0], from: [0, 1, 0], to: [0, 1, 0], duration: 1}\n", "rate_hz"},
    };
    for (const auto& c : cases) {
        auto trajectory = Trajectory::parse(c.text, "t.yaml");
        ASSERT_FALSE(trajectory) << c.text;
        EXPECT_NE(trajectory.error().message.find("t.yaml"), std::string::npos) << trajectory.error().message;
        EXPECT_NE(trajectory.error().message.find(c.expected), std::string::npos) << trajectory.error().message;
    }
}

}  // namespace
}  // namespace commonlight::mocks::sim

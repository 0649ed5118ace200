// The alignment's corner clearance, tested before the projection (tag_align.cpp): the points it
// drops are exactly those within corner_clearance_px of an L junction, and the Jacobian it uses
// is the projection's bit for bit.
#include <gtest/gtest.h>

#include "tests/tracking/synthetic_tags.h"
#include "tracking/projection.h"
#include "tracking/tag_align.h"

namespace commonlight::tracking {
namespace {

TEST(TagAlignClearance, PointJacobianIsTheProjections) {
    CameraModel cam = testing::syntheticCamera();
    cam.distortion.k1 = -0.3;
    cam.distortion.k2 = 0.1;
    cam.distortion.p1 = 0.001;
    cam.distortion.p2 = -0.002;
    for (const Eigen::Vector3d& p : {Eigen::Vector3d(0.1, -0.05, 1.0), Eigen::Vector3d(-0.2, 0.15, 0.7)}) {
        const auto full = projectWithJacobian(cam, p);
        const auto alone = pixelJacobianOfPoint(cam, p);
        ASSERT_TRUE(full && alone);
        for (int i = 0; i < 6; ++i) EXPECT_EQ((*alone)(i), full->d_pixel_d_p(i)) << i;
    }
    EXPECT_FALSE(pixelJacobianOfPoint(cam, Eigen::Vector3d(0.1, 0.1, -1.0)));
}

// A fronto-parallel tag: each boundary is one cell long in the image, so the quarter points next
// to an L junction are cell / 4 px from it: all dropped on cells of 4 px (1 px < 2 px), none on
// cells of 10 px (2.5 px).
TEST(TagAlignClearance, DropsExactlyThePointsNearLJunctions) {
    const CameraModel cam = testing::syntheticCamera();
    auto pattern = TagPattern::make("tag36h11", 30);
    ASSERT_TRUE(pattern);
    int corner_ends = 0;
    for (const auto& e : pattern->edges()) corner_ends += (e.corner_a ? 1 : 0) + (e.corner_b ? 1 : 0);
    ASSERT_GT(corner_ends, 20);
    for (const double cell_px : {4.0, 10.0}) {
        const double size = 0.1, z = 500.0 * size / (8.0 * cell_px);
        const Rigid3d pose(Eigen::Quaterniond(Eigen::AngleAxisd(3.14159265358979, Eigen::Vector3d::UnitX())),
                           Eigen::Vector3d(0.0021, -0.0013, z));
        const Image img = testing::renderSyntheticTags(cam, {{30, size, pose}});
        TagAlignOptions none;
        none.corner_clearance_px = 0.0;
        const TagAlignResult all = alignTagPose(img.view(), cam, *pattern, size, pose, none);
        const TagAlignResult cleared = alignTagPose(img.view(), cam, *pattern, size, pose);
        ASSERT_TRUE(all.ok && cleared.ok) << all.reason << cleared.reason;
        EXPECT_EQ(all.points, 3 * static_cast<int>(pattern->edges().size())) << cell_px;
        EXPECT_EQ(all.points - cleared.points, cell_px < 8.0 ? corner_ends : 0) << cell_px;
    }
}

}  // namespace
}  // namespace commonlight::tracking

// lighting/influence_impl.h LinkPoints::keptHold(): a blocked link's answers kept against the
// objects that did not move (transmissionToSource()) hold only for those very objects and only
// until one of them moves, is removed or brought back, also when the link was not re-answered at
// that change (a later commit that changes another object alone does not make them hold again).
#include "lighting/influence_impl.h"

#include <gtest/gtest.h>

namespace commonlight::lighting {
namespace {

TEST(LinkPoints, KeptAnswersDroppedWhenAKeptObjectChanges) {
    Face floor;
    floor.origin = {-5, -5, -3};
    floor.edge_s = {10, 0, 0};
    floor.edge_t = {0, 10, 0};
    floor.normal = {0, 0, 1};
    floor.area = 100.0;
    VirtualShape sphere, box;
    sphere.sphere_radius = 0.1;
    box.sphere_radius = 0.2;  // (a second object: its shape plays no part in the stamps)
    auto built = RayScene::build({floor}, {}, {sphere, box});
    ASSERT_TRUE(built) << built.error().message;
    RayScene& rays = **built;
    const std::uint32_t ball = RayScene::virtualBit(0), still = RayScene::virtualBit(1);
    const auto move = [&](int v, double x) {
        rays.setVirtualPose(v, Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(x, 0, 0)));
        ASSERT_TRUE(rays.commitVirtual());
    };
    move(0, 0.1);
    LinkPoints lp;
    // Nothing kept yet: holds for no object alone.
    EXPECT_TRUE(lp.keptHold(0u, rays));
    EXPECT_FALSE(lp.keptHold(still, rays));
    // Kept against the object that did not move.
    lp.kept_objects = still;
    lp.kept_at = rays.virtualStamp();
    EXPECT_TRUE(lp.keptHold(still, rays));
    EXPECT_FALSE(lp.keptHold(still | ball, rays));  // for other objects
    EXPECT_FALSE(lp.keptHold(0u, rays));
    move(0, 0.2);  // the ball moves: still holds
    EXPECT_TRUE(lp.keptHold(still, rays));
    move(1, 1.0);  // the kept object moves
    EXPECT_FALSE(lp.keptHold(still, rays));
    move(0, 0.3);  // and then the ball alone: the kept answers stay dropped
    EXPECT_FALSE(lp.keptHold(still, rays));
    // Kept again, then the object removed, then brought back.
    lp.kept_at = rays.virtualStamp();
    EXPECT_TRUE(lp.keptHold(still, rays));
    rays.setVirtualEnabled(1, false);
    ASSERT_TRUE(rays.commitVirtual());
    EXPECT_FALSE(lp.keptHold(still, rays));
    lp.kept_at = rays.virtualStamp();
    rays.setVirtualEnabled(1, true);
    ASSERT_TRUE(rays.commitVirtual());
    EXPECT_FALSE(lp.keptHold(still, rays));
    // A commit with nothing pending changes nothing.
    lp.kept_at = rays.virtualStamp();
    ASSERT_TRUE(rays.commitVirtual());
    EXPECT_TRUE(lp.keptHold(still, rays));
}

}  // namespace
}  // namespace commonlight::lighting

// A full update keeps the texel cache's visibility (lighting/texel_direct.h renew()): the lights'
// polygons and the real faces stay, only their emissions change, so each texel's answer is made
// again from its kept fractions; what the virtual objects reached since the last textures is
// traced again (movedSinceSeen()). The textures keep their layouts through it too: only the
// texels whose leaves' values moved or whose answers went are made again.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "core/scene_io.h"
#include "lighting/estimator.h"
#include "lighting/texel_direct.h"
#include "texel_direct_support.h"

namespace commonlight::lighting {
namespace {

// Two lamps over a floor, a ball moving between them. A cache traced with one pair of emissions,
// the ball moved, then renewed with another pair, answers every texel exactly as a cache traced
// afresh with the new emissions and the ball where it is now; it traces only the texels whose
// shafts the ball's move reached.
TEST(TexelDirectRenew, RenewedAnswersEqualAFreshCacheWithTheNewEmissions) {
    const FloorUnderTwoLamps setup(0.05);
    ASSERT_TRUE(setup.rays);
    RayScene& scene = *setup.rays;
    const Face& floor = setup.floor;
    const LightGeometry &lamp = setup.lamp, &lamp2 = setup.lamp2;
    constexpr int kSide = 40;
    const std::vector<Eigen::Vector3d> points = texelCentres(floor, kSide);
    const std::vector<TexelDirectCache::Light> before{{&lamp, Eigen::Vector3d::Constant(80.0)}, {&lamp2, Eigen::Vector3d(20, 30, 40)}};
    const std::vector<TexelDirectCache::Light> after{{&lamp, Eigen::Vector3d(40.0, 90.0, 10.0)}, {&lamp2, Eigen::Vector3d(70, 5, 25)}};
    const auto place = [&](const Eigen::Vector3d& centre) {
        scene.setVirtualPose(0, Rigid3d(Eigen::Quaterniond::Identity(), centre));
        ASSERT_TRUE(scene.commitVirtual());
    };
    place({-0.1, 0.05, 0.15});
    TexelDirectCache kept(scene, 8);
    kept.reset(before, {floor});
    EXPECT_EQ(kept.movedSinceSeen().size(), 1u) << "before the first seen(): every object (where it is)";
    Eigen::Vector3d a0, a1, b0, b1;
    for (std::size_t k = 0; k < points.size(); ++k) kept.at(0, k, kSide, kSide, points[k], floor.normal, a0, a1);
    kept.seen();
    EXPECT_TRUE(kept.movedSinceSeen().empty()) << "nothing moved since";
    place({0.12, -0.04, 0.2});
    const std::vector<Ball> moved = kept.movedSinceSeen();
    ASSERT_EQ(moved.size(), 2u) << "the ball where it was and where it is";
    EXPECT_LT((moved[0].centre - Eigen::Vector3d(-0.1, 0.05, 0.15)).norm(), 1e-12);
    EXPECT_LT((moved[1].centre - Eigen::Vector3d(0.12, -0.04, 0.2)).norm(), 1e-12);
    ASSERT_TRUE(kept.sameGeometry(after, {floor}));
    EXPECT_FALSE(kept.sameGeometry({after[1], after[0]}, {floor})) << "the lights in another order";
    EXPECT_FALSE(kept.sameGeometry(after, {squareFloor(0.5)})) << "another face";
    kept.forget(moved);
    kept.renew(after);
    TexelDirectCache fresh(scene, 8);
    fresh.reset(after, {floor});
    const long traced_before = kept.traced();
    int shadowed = 0;
    for (std::size_t k = 0; k < points.size(); ++k) {
        kept.at(0, k, kSide, kSide, points[k], floor.normal, a0, a1);
        fresh.at(0, k, kSide, kSide, points[k], floor.normal, b0, b1);
        ASSERT_EQ(a0, b0) << "texel " << k << " without the ball";
        ASSERT_EQ(a1, b1) << "texel " << k << " with the ball";
        if (b1.y() < 0.9 * b0.y()) ++shadowed;
    }
    const long traced = kept.traced() - traced_before;
    EXPECT_GT(shadowed, 20) << "the ball shadows the floor";
    EXPECT_GT(traced, 0) << "the texels the move reached traced again";
    EXPECT_LT(traced, static_cast<long>(points.size()) / 2) << "the others kept";
}

// A ball over a floor under two lamps, seen from above, through the estimator: made by solveWith()
// with given emissions (a fresh hierarchy and textures each time).
class FloorEstimator : public ::testing::Test {
protected:
    void SetUp() override {
        const std::string yaml = R"(
real:
  - {name: floor, plane: {size: [1.2, 1.2]}, albedo: [0.5, 0.5, 0.5]}
lights:
  - {name: lamp, area: {size: [0.12, 0.12]}, world_from_object: {t: [0.05, 0.0, 0.8], rpy_deg: [180, 0, 0]}, radiance: [100, 100, 100]}
  - {name: lamp2, area: {size: [0.1, 0.1]}, world_from_object: {t: [-0.3, 0.2, 0.7], rpy_deg: [180, 0, 0]}, radiance: [60, 60, 60]}
virtual:
  - {name: ball, sphere: {radius: 0.06}, material: {albedo: [0.0, 0.0, 0.0]}, world_from_object: {t: [0, 0, 0.2]}}
lighting: {max_elements: 3000}
)";
        auto parsed = parseScene(yaml, "texel_direct_renew.yaml");
        ASSERT_TRUE(parsed) << parsed.error().message;
        scene = std::move(*parsed);
        cam.width = 160;
        cam.height = 120;
        cam.fx = cam.fy = 140.0;
        cam.cx = 79.5;
        cam.cy = 59.5;
        options.refine_unobserved = true;
        options.initial_element_size = 0.2;
        options.light_refinement_size = 0.08;
        albedo.assign(scene.real_objects.size(), Eigen::Vector3d::Constant(0.5));
    }
    std::unique_ptr<Estimator> make(const std::vector<Eigen::Vector3d>& emission, const std::vector<Rigid3d>& poses) {
        auto est = Estimator::create(scene, cam, {}, options);
        EXPECT_TRUE(est) << est.error().message;
        if (!est) return nullptr;
        (*est)->setViewer(Rigid3d::fromRpyDeg(Eigen::Vector3d(0.0, 0.0, 1.0), Eigen::Vector3d(180, 0, 0)).inverse());
        EXPECT_TRUE((*est)->solveWith(emission, albedo, poses));
        return std::move(*est);
    }
    static Rigid3d ballAt(double x, double y) { return Rigid3d::fromRpyDeg(Eigen::Vector3d(x, y, 0.2), Eigen::Vector3d::Zero()); }
    // An estimator that saw the first emissions with the ball at x = 0.03, then 0.06; `poses` hold
    // the ball where both tests end it, (0.065, 0.005), not yet updated there.
    std::unique_ptr<Estimator> movedTwice(std::vector<Rigid3d>& poses) {
        poses = SceneLighting::scenePoses(scene, 0.0);
        auto est = make(first_emission, poses);
        if (!est) return nullptr;
        for (double x : {0.03, 0.06}) {
            poses[0] = ballAt(x, 0.0);
            EXPECT_TRUE(est->update(poses));
        }
        poses[0] = ballAt(0.065, 0.005);
        return est;
    }
    // The largest ratio difference and relative B~ difference between two snapshots' floor
    // textures, and the texels in the ball's shadow (ratio under 0.9 in `b`).
    struct Differences {
        double ratio = 1e300, original = 1e300;
        int shadow = 0;
    };
    static Differences compare(const LightingSnapshot& a_snap, const LightingSnapshot& b_snap) {
        Differences out;
        const FaceModulation* a = a_snap.findFace(0, 0);
        const FaceModulation* b = b_snap.findFace(0, 0);
        EXPECT_TRUE(a && b);
        if (!a || !b || a->ratio.size() != b->ratio.size()) return out;
        out.ratio = out.original = 0.0;
        for (std::size_t k = 0; k < a->ratio.size(); ++k) {
            out.ratio = std::max(out.ratio, static_cast<double>((a->ratio[k] - b->ratio[k]).cwiseAbs().maxCoeff()));
            const double scale = std::max(1e-6f, b->original[k].maxCoeff());
            out.original = std::max(out.original, static_cast<double>((a->original[k] - b->original[k]).cwiseAbs().maxCoeff()) / scale);
            if (b->ratio[k].y() < 0.9f) ++out.shadow;
        }
        return out;
    }

    Scene scene;
    CameraModel cam;
    EstimatorOptions options;
    std::vector<Eigen::Vector3d> albedo;
    const std::vector<Eigen::Vector3d> first_emission{Eigen::Vector3d::Constant(100.0), Eigen::Vector3d::Constant(60.0)};
};

// A full update (solveWith(), new emissions) with the ball moved a little further traces a fraction
// of the texels the same update traces from scratch, and its textures are those of an estimator
// that only ever saw the new emissions and the ball where it ended.
TEST_F(FloorEstimator, AFullUpdateTracesOnlyWhatTheObjectsReachedAndEqualsAFreshEstimate) {
    const std::vector<Eigen::Vector3d> new_emission{Eigen::Vector3d(200.0, 100.0, 50.0), Eigen::Vector3d(20.0, 60.0, 90.0)};
    std::vector<Rigid3d> poses;
    auto moving = movedTwice(poses);
    ASSERT_TRUE(moving);
    ASSERT_TRUE(moving->solveWith(new_emission, albedo, poses));
    ASSERT_TRUE(moving->stats().full);
    const long renewed_traced = moving->stats().texels_traced;
    auto last = moving->update(poses);
    auto fresh_est = make(new_emission, poses);
    ASSERT_TRUE(last && fresh_est);
    const long fresh_traced = fresh_est->stats().texels_traced;
    auto fresh = fresh_est->update(poses);
    ASSERT_TRUE(fresh);
    EXPECT_GT(fresh_traced, 300) << "the same update from scratch traces the ball's influence on the floor";
    EXPECT_GT(renewed_traced, 0) << "the full update traces where the ball was and is";
    EXPECT_LT(renewed_traced * 3, fresh_traced * 2) << "and keeps the rest (the ball's own shadows are most of what it changes)";
    const Differences d = compare(*last, *fresh);
    EXPECT_GT(d.shadow, 50) << "the ball's shadow is in the textures";
    EXPECT_LT(d.ratio, 0.01) << "largest ratio difference against a fresh estimate";
    EXPECT_LT(d.original, 0.01) << "largest relative B~ difference against a fresh estimate";
}

// A full update of the same hierarchy (requestFullUpdate(): B~ solved again, the influence from
// nothing) keeps each face's texture layout and box filters: it makes again only the texels
// whose leaves' values moved (here, with the same emissions, few), and its textures are those of
// a fresh estimator with the ball where it ended.
TEST_F(FloorEstimator, AFullUpdateKeepsTheTextureLayoutAndMakesOnlyWhatMoved) {
    std::vector<Rigid3d> poses;
    auto moving = movedTwice(poses);
    ASSERT_TRUE(moving);
    moving->requestFullUpdate();
    auto full = moving->update(poses);
    ASSERT_TRUE(full);
    ASSERT_TRUE(moving->stats().full);
    const long built = moving->stats().texels_built, texels = moving->stats().texels;
    auto fresh_est = make(first_emission, poses);
    ASSERT_TRUE(fresh_est);
    const long fresh_texels = fresh_est->stats().texels;
    auto fresh = fresh_est->update(poses);
    ASSERT_TRUE(fresh);
    EXPECT_EQ(texels, fresh_texels) << "the full update visits every face's texels";
    EXPECT_GT(built, 0) << "the texels the ball's move reached are made again";
    EXPECT_LT(built * 4, texels) << "the rest are kept";
    const Differences d = compare(*full, *fresh);
    EXPECT_GT(d.shadow, 50) << "the ball's shadow is in the textures";
    EXPECT_LT(d.ratio, 0.01) << "largest ratio difference against a fresh estimate";
    EXPECT_LT(d.original, 0.01) << "largest relative B~ difference against a fresh estimate";
}

}  // namespace
}  // namespace commonlight::lighting

// Hard cases of the renderer: degenerate geometry and lights, rays along surfaces, a camera
// inside a box, bad scenes. Nothing may produce a NaN or an infinity; zero is the sensible answer
// wherever no light can arrive.
#include <cmath>
#include <numbers>

#include <gtest/gtest.h>

#include "mocks/sim/render.h"

namespace commonlight::mocks::sim {
namespace {

using Eigen::Vector3d;

Light light(const std::string& name, LightShape shape, const Rigid3d& pose, double value) {
    return {name, shape, pose, RgbOrEstimate::constant(Vector3d::Constant(value))};
}

RealObject plane(const std::string& name, double size, const Rigid3d& pose, double albedo) {
    return {name, PlaneShape{{size, size}}, pose, RgbOrEstimate::constant(Vector3d::Constant(albedo))};
}

CameraModel camera(int width, int height, double f) {
    CameraModel c;
    c.width = width;
    c.height = height;
    c.fx = c.fy = f;
    c.cx = 0.5 * width - 0.5;
    c.cy = 0.5 * height - 0.5;
    return c;
}

// Every pixel finite and >= 0; returns the sum of the red channel.
double expectFiniteAndNonNegative(const RenderOutput& out) {
    EXPECT_EQ(out.nonfinite_samples, 0);
    double sum = 0.0;
    for (int v = 0; v < out.height; ++v) {
        const auto* row = reinterpret_cast<const float*>(out.radiance.data() + v * out.radiance.stride());
        for (int i = 0; i < 3 * out.width; ++i) {
            EXPECT_TRUE(std::isfinite(row[i]) && row[i] >= 0.0f) << "pixel " << i / 3 << "," << v << " = " << row[i];
            if (i % 3 == 0) sum += row[i];
        }
    }
    return sum;
}

TEST(RenderHardCases, RaysParallelToAPlane) {
    // The camera sits exactly in the plane of a huge floor and looks along it: the centre row's
    // rays are parallel to the floor, the rows below graze it at ever larger distances.
    Scene scene;
    scene.real_objects.push_back(plane("floor", 1000.0, Rigid3d::identity(), 0.5));
    scene.lights.push_back(
        light("sun", DirectionalLightShape{Vector3d(0, 0.3, -1).normalized()}, Rigid3d::identity(), 5));
    scene.lights.push_back(light("sky", DistantLightShape{8}, Rigid3d::identity(), 1));
    auto sim = SimScene::build(scene);
    ASSERT_TRUE(sim) << sim.error().message;
    RenderRequest r;
    r.scene = &*sim;
    r.camera = camera(32, 33, 20);  // odd height: row 16 is exactly horizontal
    // Looking along +y: camera x = world x, camera y = world -z, camera z = world y.
    Eigen::Matrix3d rotation;
    rotation << 1, 0, 0, 0, 0, 1, 0, -1, 0;
    r.world_from_cam = Rigid3d(Eigen::Quaterniond(rotation), Vector3d::Zero());
    r.spp = 16;
    auto out = render(r);
    ASSERT_TRUE(out) << out.error().message;
    EXPECT_GT(expectFiniteAndNonNegative(*out), 0.0);
    // A receiver whose normal lies in the plane of an area light, at the light's edge: the light
    // is exactly at its horizon and sends it nothing.
    Scene edge;
    edge.lights.push_back(light("panel", AreaLightShape{{1, 1}}, Rigid3d::fromRpyDeg({0, 0, 1}, {180, 0, 0}), 10));
    auto edge_sim = SimScene::build(edge);
    ASSERT_TRUE(edge_sim) << edge_sim.error().message;
    const Vector3d e = estimateIrradiance(*edge_sim, {0.5, 0, 1}, Vector3d::UnitX(), 256, 1);
    EXPECT_TRUE(e.allFinite());
    EXPECT_EQ(e.x(), 0.0);
    // A point in the light's own plane, facing down: the light is edge-on.
    EXPECT_EQ(estimateIrradiance(*edge_sim, {2, 0, 1}, -Vector3d::UnitZ(), 64, 1).x(), 0.0);
}

TEST(RenderHardCases, CameraInsideABox) {
    // A closed box (outward-facing triangles) seen from inside, lit by a point light at the
    // camera. Direct light only: a wall straight ahead at distance d has radiance
    // rho I / (pi d^2) at the image centre.
    constexpr double kRho = 0.5;
    constexpr double kIntensity = 4.0;
    Scene scene;
    scene.real_objects.push_back(
        {"room", BoxShape{{2, 3, 2.5}}, Rigid3d::identity(), RgbOrEstimate::constant(Vector3d::Constant(kRho))});
    scene.lights.push_back(light("bulb", PointLightShape{}, Rigid3d::identity(), kIntensity));
    auto sim = SimScene::build(scene);
    ASSERT_TRUE(sim) << sim.error().message;
    RenderRequest r;
    r.scene = &*sim;
    r.camera = camera(33, 33, 40);
    Eigen::Matrix3d rotation;  // looking along +y
    rotation << 1, 0, 0, 0, 0, 1, 0, -1, 0;
    r.world_from_cam = Rigid3d(Eigen::Quaterniond(rotation), Vector3d::Zero());
    r.spp = 64;
    r.max_depth = 1;
    auto out = render(r);
    ASSERT_TRUE(out) << out.error().message;
    expectFiniteAndNonNegative(*out);
    const auto* centre = reinterpret_cast<const float*>(out->radiance.data() + 16 * out->radiance.stride()) + 3 * 16;
    const double expected = kRho * kIntensity / (std::numbers::pi * 1.5 * 1.5);
    EXPECT_NEAR(centre[0], expected, 1e-3 * expected);              // the pixel footprint averages cos/d^2: ~1e-4
    for (const std::int32_t id : out->object_id) EXPECT_EQ(id, 0);  // every pixel sees the box
    // With interreflections the box is brighter, and still finite.
    r.max_depth = 16;
    auto bounced = render(r);
    ASSERT_TRUE(bounced) << bounced.error().message;
    expectFiniteAndNonNegative(*bounced);
    EXPECT_GT(reinterpret_cast<const float*>(bounced->radiance.data() + 16 * bounced->radiance.stride())[3 * 16],
              1.2 * expected);
}

TEST(RenderHardCases, ZeroAreaLightsEmitNothing) {
    Scene scene;
    scene.real_objects.push_back(plane("floor", 4, Rigid3d::identity(), 0.5));
    scene.lights.push_back(light("slit", AreaLightShape{{0.0, 1.0}}, Rigid3d::fromRpyDeg({0, 0, 1}, {180, 0, 0}), 100));
    scene.lights.push_back(light("dot", DiscLightShape{0.0}, Rigid3d::fromRpyDeg({0, 0, 1}, {180, 0, 0}), 100));
    auto sim = SimScene::build(scene);
    ASSERT_TRUE(sim) << sim.error().message;
    EXPECT_TRUE(sim->lights().empty());
    const Vector3d e = estimateIrradiance(*sim, {0, 0, 0}, Vector3d::UnitZ(), 64, 3);
    EXPECT_EQ(e, Vector3d::Zero());
}

TEST(RenderHardCases, LightFacingAwayGivesExactZero) {
    // An area light 1 m above a floor but facing up; a disc facing away too.
    Scene scene;
    scene.real_objects.push_back(plane("floor", 4, Rigid3d::identity(), 0.5));
    scene.lights.push_back(light("up", AreaLightShape{{1, 1}}, Rigid3d({1, 0, 0, 0}, {0, 0, 1}), 10));
    scene.lights.push_back(light("disc", DiscLightShape{0.3}, Rigid3d({1, 0, 0, 0}, {1, 0, 1}), 10));
    auto sim = SimScene::build(scene);
    ASSERT_TRUE(sim) << sim.error().message;
    EXPECT_EQ(estimateIrradiance(*sim, {0, 0, 0}, Vector3d::UnitZ(), 256, 1), Vector3d::Zero());
    EXPECT_EQ(estimateIrradiance(*sim, {1, 0, 0}, Vector3d::UnitZ(), 256, 1), Vector3d::Zero());
    // Seen from below (a camera under the light, looking up) the light's back is black too.
    RenderRequest r;
    r.scene = &*sim;
    r.camera = camera(16, 16, 10);
    Eigen::Matrix3d rotation;  // looking up (+z), image y = world -y
    rotation << 1, 0, 0, 0, -1, 0, 0, 0, 1;
    r.world_from_cam = Rigid3d(Eigen::Quaterniond(rotation), Vector3d(0, 0, 0.5));
    r.spp = 16;
    auto out = render(r);
    ASSERT_TRUE(out) << out.error().message;
    EXPECT_EQ(expectFiniteAndNonNegative(*out), 0.0);
}

TEST(RenderHardCases, PointLightOnTheReceiver) {
    // I / d^2 at d = 0 would be infinite: the probe at the light's position gets nothing from it.
    Scene scene;
    scene.lights.push_back(light("bulb", PointLightShape{}, Rigid3d({1, 0, 0, 0}, {0, 0, 0}), 1));
    auto sim = SimScene::build(scene);
    ASSERT_TRUE(sim) << sim.error().message;
    const Vector3d e = estimateIrradiance(*sim, {0, 0, 0}, Vector3d::UnitZ(), 4, 1);
    EXPECT_TRUE(e.allFinite());
    EXPECT_EQ(e.x(), 0.0);
}

TEST(RenderHardCases, NearMirrorGgxAndGrazingViewsStayFinite) {
    // A GGX sphere with the smallest roughness (alpha clamps at 1e-3) reflecting a small bright
    // light, and a GGX floor seen at grazing angles.
    Scene scene;
    scene.lights.push_back(light("spot", DiscLightShape{0.01}, Rigid3d::fromRpyDeg({0, 0, 2}, {180, 0, 0}), 1e4));
    scene.lights.push_back(light("sky", DistantLightShape{8}, Rigid3d::identity(), 1));
    VirtualObject mirror;
    mirror.name = "mirror";
    mirror.shape = SphereShape{0.3};
    mirror.material = {MaterialType::kGgx, Vector3d::Constant(0.95), 1e-6};
    mirror.placement = FixedPlacement{Rigid3d({1, 0, 0, 0}, {0, 0, 0.3})};
    scene.virtual_objects.push_back(mirror);
    VirtualObject floor;
    floor.name = "floor";
    floor.shape = PlaneShape{{50, 50}};
    floor.material = {MaterialType::kGgx, Vector3d::Constant(0.5), 0.05};
    scene.virtual_objects.push_back(floor);
    SimSceneOptions options;
    options.include_virtual = true;
    auto sim = SimScene::build(scene, options);
    ASSERT_TRUE(sim) << sim.error().message;
    RenderRequest r;
    r.scene = &*sim;
    r.camera = camera(40, 30, 30);
    Eigen::Matrix3d rotation;  // looking along +y, just above the floor
    rotation << 1, 0, 0, 0, 0, 1, 0, -1, 0;
    r.world_from_cam = Rigid3d(Eigen::Quaterniond(rotation), Vector3d(0, -2, 0.05));
    r.spp = 32;
    auto out = render(r);
    ASSERT_TRUE(out) << out.error().message;
    EXPECT_GT(expectFiniteAndNonNegative(*out), 0.0);
    double coverage = 0.0;
    for (float c : out->virtual_coverage) coverage += c;
    EXPECT_GT(coverage, 10.0);
}

TEST(RenderHardCases, DegenerateMeshTrianglesAreHarmless) {
    auto mesh = std::make_shared<Mesh>();
    mesh->positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {2, 2, 0}};
    mesh->indices = {0, 1, 2, 0, 0, 1, 3, 3, 3};  // one good triangle, two degenerate ones
    Scene scene;
    scene.real_objects.push_back(
        {"sheet", MeshShape{"sheet.obj", mesh}, Rigid3d::identity(), RgbOrEstimate::constant(Vector3d::Constant(0.5))});
    scene.lights.push_back(light("bulb", PointLightShape{}, Rigid3d({1, 0, 0, 0}, {0.2, 0.2, 1}), 1));
    auto sim = SimScene::build(scene);
    ASSERT_TRUE(sim) << sim.error().message;
    const auto hit = sim->intersect({0.25, 0.25, 1}, -Vector3d::UnitZ());
    ASSERT_TRUE(hit);
    EXPECT_NEAR(hit->t, 1.0, 1e-12);
    EXPECT_NEAR(hit->n.z(), 1.0, 1e-12);
    EXPECT_TRUE(estimateIrradiance(*sim, {0.25, 0.25, 0.5}, -Vector3d::UnitZ(), 16, 1).allFinite());
}

TEST(RenderHardCases, RaysFromInsideASphereHitItsFarSide) {
    // A camera (or a bounce) inside an analytic sphere: the hit is the exit point, refined in
    // double precision, with the outward normal (the ray arrives on its back side).
    Scene scene;
    scene.real_objects.push_back({"dome", SphereShape{2.0}, Rigid3d({1, 0, 0, 0}, {0.1, 0.2, 0.3}),
                                  RgbOrEstimate::constant(Vector3d::Constant(0.5))});
    auto sim = SimScene::build(scene);
    ASSERT_TRUE(sim) << sim.error().message;
    for (const Vector3d& dir : {Vector3d(1, 0, 0), Vector3d(0.3, -0.4, 0.866).normalized(), Vector3d(0, 0, -1)}) {
        const auto hit = sim->intersect({0.1, 0.2, 0.3}, dir);
        ASSERT_TRUE(hit);
        EXPECT_NEAR(hit->t, 2.0, 1e-12);
        EXPECT_FALSE(hit->front);
        EXPECT_NEAR(hit->n.dot(dir), 1.0, 1e-12);
    }
    // From outside, the near side.
    const auto outside = sim->intersect({0.1, 0.2, 5.3}, -Vector3d::UnitZ());
    ASSERT_TRUE(outside);
    EXPECT_NEAR(outside->t, 3.0, 1e-12);
    EXPECT_TRUE(outside->front);
}

TEST(RenderHardCases, BadScenesFailWithTheirNames) {
    Scene estimated;
    estimated.lights.push_back(
        {"ceiling panel", AreaLightShape{{1, 1}}, Rigid3d::identity(), RgbOrEstimate::estimate()});
    auto a = SimScene::build(estimated);
    ASSERT_FALSE(a);
    EXPECT_EQ(a.error().code, ErrorCode::kBadInput);
    EXPECT_NE(a.error().message.find("ceiling panel"), std::string::npos) << a.error().message;
    EXPECT_NE(a.error().message.find("radiance"), std::string::npos) << a.error().message;

    Scene unloaded;
    unloaded.real_objects.push_back({"shelf", MeshShape{"shelf.gltf", nullptr}, Rigid3d::identity(), {}});
    auto b = SimScene::build(unloaded);
    ASSERT_FALSE(b);
    EXPECT_NE(b.error().message.find("shelf"), std::string::npos) << b.error().message;

    Scene bad_family;
    bad_family.tags.family = "tag99h99";
    bad_family.tags.items.push_back({0, 0.1, Rigid3d::identity(), 0.04, 0.8});
    auto c = SimScene::build(bad_family);
    ASSERT_FALSE(c);
    EXPECT_NE(c.error().message.find("tag99h99"), std::string::npos) << c.error().message;

    // An `estimate` albedo renders with the documented default, 0.5.
    Scene default_albedo;
    default_albedo.real_objects.push_back(
        {"floor", PlaneShape{{1, 1}}, Rigid3d::identity(), RgbOrEstimate::estimate()});
    auto d = SimScene::build(default_albedo);
    ASSERT_TRUE(d) << d.error().message;
    const auto hit = d->intersect({0, 0, 1}, -Vector3d::UnitZ());
    ASSERT_TRUE(hit);
    EXPECT_EQ(hit->bsdf.albedo, Vector3d::Constant(0.5));

    RenderRequest no_scene;
    EXPECT_FALSE(render(no_scene));
    RenderRequest bad_spp;
    bad_spp.scene = &*d;
    bad_spp.camera = camera(8, 8, 8);
    bad_spp.spp = 0;
    auto e = render(bad_spp);
    ASSERT_FALSE(e);
    EXPECT_EQ(e.error().code, ErrorCode::kUsage);
}

TEST(RenderHardCases, LensFoldSamplesSeeNothing) {
    // k1 so strong that the image corners lie beyond the fold of the lens model: those samples
    // have no ray and count as black, the rest of the image renders.
    Scene scene;
    scene.lights.push_back(light("sky", DistantLightShape{8}, Rigid3d::identity(), 1));
    auto sim = SimScene::build(scene);
    ASSERT_TRUE(sim) << sim.error().message;
    RenderRequest r;
    r.scene = &*sim;
    r.camera = camera(40, 40, 10);
    r.camera.distortion.k1 = -0.5;
    Eigen::Matrix3d rotation;  // looking up
    rotation << 1, 0, 0, 0, -1, 0, 0, 0, 1;
    r.world_from_cam = Rigid3d(Eigen::Quaterniond(rotation), Vector3d::Zero());
    r.spp = 4;
    auto out = render(r);
    ASSERT_TRUE(out) << out.error().message;
    expectFiniteAndNonNegative(*out);
    const auto* first = reinterpret_cast<const float*>(out->radiance.data());
    const auto* middle = reinterpret_cast<const float*>(out->radiance.data() + 20 * out->radiance.stride()) + 3 * 20;
    EXPECT_EQ(first[0], 0.0f);         // the corner is beyond the fold
    EXPECT_FLOAT_EQ(middle[0], 1.0f);  // the sky straight up
}

}  // namespace
}  // namespace commonlight::mocks::sim

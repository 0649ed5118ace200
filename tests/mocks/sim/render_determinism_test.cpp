// Determinism (same seed, same bytes, whatever the number of threads) and whole-frame renders
// against closed forms, with the render speed.
#include <tbb/global_control.h>

#include <cmath>
#include <cstdio>
#include <numbers>

#include <gtest/gtest.h>

#include "mocks/sim/render.h"

namespace commonlight::mocks::sim {
namespace {

using Eigen::Vector3d;

CameraModel smallCamera(int width, int height) {
    CameraModel camera;
    camera.width = width;
    camera.height = height;
    camera.fx = camera.fy = 0.8 * width;
    camera.cx = 0.5 * width - 0.5;
    camera.cy = 0.5 * height - 0.5;
    camera.distortion = {-0.2, 0.05, 0.001, -0.001, 0.0};
    return camera;
}

// Camera at `eye` looking at `target`, image y down (OpenCV), world z up.
Rigid3d lookAt(const Vector3d& eye, const Vector3d& target) {
    const Vector3d z = (target - eye).normalized();
    const Vector3d x = z.cross(Vector3d::UnitZ()).normalized();
    Eigen::Matrix3d r;
    r.col(0) = x;
    r.col(1) = z.cross(x);
    r.col(2) = z;
    return {Eigen::Quaterniond(r), eye};
}

Light light(const std::string& name, LightShape shape, const Rigid3d& pose, double value) {
    return {name, shape, pose, RgbOrEstimate::constant(Vector3d::Constant(value))};
}

// A small room with every kind of object and light: real floor, walls, box and sphere; a tag on
// the floor; rectangle, disc, point, directional lights and a sky; virtual Lambertian, GGX and
// emissive objects.
Scene everythingScene() {
    Scene scene;
    const auto albedo = [](double r, double g, double b) { return RgbOrEstimate::constant({r, g, b}); };
    scene.real_objects.push_back({"floor", PlaneShape{{3, 3}}, Rigid3d::identity(), albedo(0.5, 0.45, 0.4)});
    scene.real_objects.push_back(
        {"wall", PlaneShape{{3, 2}}, Rigid3d::fromRpyDeg({0, 1.5, 1}, {90, 0, 0}), albedo(0.7, 0.7, 0.6)});
    scene.real_objects.push_back({"box", BoxShape{{0.3, 0.3, 0.3}}, Rigid3d::fromRpyDeg({0.4, 0.3, 0.15}, {0, 0, 25}),
                                  RgbOrEstimate::estimate()});
    scene.real_objects.push_back(
        {"ball", SphereShape{0.12}, Rigid3d({1, 0, 0, 0}, {-0.4, 0.2, 0.12}), albedo(0.2, 0.6, 0.3)});
    scene.tags.items.push_back({0, 0.12, Rigid3d::fromRpyDeg({0, -0.2, 0}, {0, 0, 15}), 0.04, 0.8});
    scene.lights.push_back(
        light("panel", AreaLightShape{{0.5, 0.3}}, Rigid3d::fromRpyDeg({0, 0.3, 1.8}, {180, 0, 0}), 8));
    scene.lights.push_back(
        light("lamp", DiscLightShape{0.08}, Rigid3d::fromRpyDeg({0.6, -0.5, 0.8}, {150, 20, 0}), 20));
    scene.lights.push_back(light("bulb", PointLightShape{}, Rigid3d({1, 0, 0, 0}, {-0.8, -0.3, 1.0}), 2));
    scene.lights.push_back(
        light("sun", DirectionalLightShape{Vector3d(0.3, 0.5, -1).normalized()}, Rigid3d::identity(), 3));
    scene.lights.push_back(light("sky", DistantLightShape{32}, Rigid3d::identity(), 0.2));
    VirtualObject ball;
    ball.name = "chrome";
    ball.shape = SphereShape{0.1};
    ball.material = {MaterialType::kGgx, Vector3d(0.9, 0.8, 0.7), 0.2};
    ball.placement = FixedPlacement{Rigid3d({1, 0, 0, 0}, {0.0, 0.1, 0.1})};
    scene.virtual_objects.push_back(ball);
    VirtualObject glow;
    glow.name = "glow";
    glow.shape = BoxShape{{0.1, 0.1, 0.1}};
    glow.emission = Vector3d(3, 2, 1);
    glow.placement = KeyframePlacement{
        {{0.0, Rigid3d({1, 0, 0, 0}, {-0.2, -0.3, 0.05})}, {1.0, Rigid3d({1, 0, 0, 0}, {0.2, -0.3, 0.05})}}};
    scene.virtual_objects.push_back(glow);
    return scene;
}

RenderRequest request(const SimScene& scene, std::uint64_t seed) {
    RenderRequest r;
    r.scene = &scene;
    r.camera = smallCamera(64, 48);
    r.world_from_cam = lookAt({0.2, -1.6, 1.0}, {0, 0, 0.2});
    r.spp = 8;
    r.seed = seed;
    r.frame_index = 3;
    r.max_depth = 6;
    return r;
}

bool sameOutput(const RenderOutput& a, const RenderOutput& b) {
    return samePixels(a.radiance.view(), b.radiance.view()) && a.object_id == b.object_id &&
           a.virtual_coverage == b.virtual_coverage;
}

RenderOutput renderWithThreads(const RenderRequest& r, int threads) {
    const tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
    auto out = render(r);
    EXPECT_TRUE(out) << out.error().message;
    return std::move(*out);
}

TEST(RenderDeterminism, SameSeedSameBytesWhateverTheThreadCount) {
    SimSceneOptions options;
    options.include_virtual = true;
    options.time_s = 0.5;
    auto scene = SimScene::build(everythingScene(), options);
    ASSERT_TRUE(scene) << scene.error().message;
    const RenderOutput one_thread = renderWithThreads(request(*scene, 42), 1);
    const RenderOutput two_threads = renderWithThreads(request(*scene, 42), 2);
    const RenderOutput again = renderWithThreads(request(*scene, 42), 2);
    EXPECT_TRUE(sameOutput(one_thread, two_threads));
    EXPECT_TRUE(sameOutput(two_threads, again));
    EXPECT_EQ(one_thread.nonfinite_samples, 0);
    // Something is in the picture: the image is not black and virtual objects are seen.
    double sum = 0.0;
    const auto* px = reinterpret_cast<const float*>(one_thread.radiance.data());
    for (int i = 0; i < 3 * 64 * 48; ++i) sum += px[i];
    EXPECT_GT(sum, 0.0);
    double coverage = 0.0;
    for (float c : one_thread.virtual_coverage) coverage += c;
    EXPECT_GT(coverage, 1.0);

    // A different seed or frame gives different noise.
    const RenderOutput other_seed = renderWithThreads(request(*scene, 43), 2);
    EXPECT_FALSE(samePixels(one_thread.radiance.view(), other_seed.radiance.view()));
    RenderRequest next_frame = request(*scene, 42);
    next_frame.frame_index = 4;
    EXPECT_FALSE(samePixels(one_thread.radiance.view(), renderWithThreads(next_frame, 2).radiance.view()));
}

TEST(RenderDeterminism, MotionBlurAndRollingShutterAreDeterministicToo) {
    auto scene = SimScene::build(everythingScene(), {});
    ASSERT_TRUE(scene) << scene.error().message;
    RenderRequest r = request(*scene, 7);
    const Rigid3d start = r.world_from_cam;
    // The camera pans while the frame is exposed and read out.
    r.world_from_cam_at = [start](double t) {
        return start * Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.5 * t, Vector3d::UnitY())), Vector3d::Zero());
    };
    r.exposure_s = 0.02;
    r.rolling_shutter_row_time_s = 1e-3;
    const RenderOutput a = renderWithThreads(r, 1);
    const RenderOutput b = renderWithThreads(r, 2);
    EXPECT_TRUE(sameOutput(a, b));
    EXPECT_EQ(a.nonfinite_samples, 0);
    // And the motion changes the picture.
    RenderRequest still = request(*scene, 7);
    EXPECT_FALSE(samePixels(a.radiance.view(), renderWithThreads(still, 2).radiance.view()));
}

constexpr double kFloorRho = 0.6;
constexpr double kSunIrradiance = 10.0;
const Vector3d kSunDirection = Vector3d(0.2, 0.3, -1.0).normalized();

// A large floor under a directional light.
Scene floorScene() {
    Scene scene;
    scene.real_objects.push_back(
        {"floor", PlaneShape{{20, 20}}, Rigid3d::identity(), RgbOrEstimate::constant(Vector3d::Constant(kFloorRho))});
    scene.lights.push_back(light("sun", DirectionalLightShape{kSunDirection}, Rigid3d::identity(), kSunIrradiance));
    return scene;
}

// The floor at 640 x 480, direct light only.
RenderRequest floorRequest(const SimScene& scene) {
    RenderRequest r;
    r.scene = &scene;
    r.camera = smallCamera(640, 480);
    r.world_from_cam = lookAt({0, -2, 1.5}, {0, 0, 0});
    r.spp = 4;
    r.max_depth = 1;
    return r;
}

TEST(RenderFrame, LitFloorHasRadianceRhoETimesCosOverPi) {
    // A floor of albedo rho under a directional light of irradiance E at angle theta, direct
    // light only: every floor pixel is rho E cos(theta) / pi, whatever the view. Also reports the
    // render speed at 640 x 480 (samples per second per core).
    auto sim = SimScene::build(floorScene());
    ASSERT_TRUE(sim) << sim.error().message;
    auto out = render(floorRequest(*sim));
    ASSERT_TRUE(out) << out.error().message;
    const double expected = kFloorRho * kSunIrradiance * -kSunDirection.z() / std::numbers::pi;
    int floor_pixels = 0;
    double worst = 0.0;
    for (int v = 0; v < 480; ++v) {
        const auto* row = reinterpret_cast<const float*>(out->radiance.data() + v * out->radiance.stride());
        for (int u = 0; u < 640; ++u) {
            // Pixels whose 3 x 3 neighbourhood is all floor (near the plane's edges a pixel is
            // partly empty space).
            bool interior = u > 0 && v > 0 && u < 639 && v < 479;
            for (int dv = -1; interior && dv <= 1; ++dv) {
                for (int du = -1; du <= 1; ++du) interior = interior && out->object_id[(v + dv) * 640 + u + du] == 0;
            }
            if (!interior) continue;
            ++floor_pixels;
            worst = std::max(worst, std::abs(row[3 * u] - expected) / expected);
        }
    }
    EXPECT_GT(floor_pixels, 100000);
    EXPECT_LT(worst, 1e-5);
    std::printf("  floor: %d pixels, worst rel. error %.2e\n", floor_pixels, worst);
}

TEST(RenderFrame, RoomWithEveryKindOfLightAndObjectStaysFinite) {
    // Every light type, Lambertian and GGX objects, paths up to the maximum depth with Russian
    // roulette: no sample may be NaN or infinite. (Speed is measured by bench/sim_bench.cpp.)
    SimSceneOptions options;
    options.include_virtual = true;
    auto room = SimScene::build(everythingScene(), options);
    ASSERT_TRUE(room) << room.error().message;
    RenderRequest r = request(*room, 1);
    r.camera = smallCamera(160, 120);
    r.spp = 4;
    auto out = render(r);
    ASSERT_TRUE(out) << out.error().message;
    EXPECT_EQ(out->nonfinite_samples, 0);
    EXPECT_EQ(out->samples, std::int64_t{160} * 120 * 4);
}

}  // namespace
}  // namespace commonlight::mocks::sim

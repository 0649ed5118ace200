// Closed-form validation of the renderer's light transport, measured with estimateIrradiance (the
// path tracer's own NEE + MIS code): a uniform rectangular area light against Lambert's polygon
// formula, a disc on its axis, point-light inverse-square and cosine laws, a directional light and
// the uniform sky.
#include <cmath>
#include <cstdio>
#include <numbers>
#include <vector>

#include <gtest/gtest.h>

#include "mocks/sim/embree_scene.h"
#include "mocks/sim/path_tracer.h"

namespace commonlight::mocks::sim {
namespace {

using Eigen::Vector3d;

Light makeLight(const std::string& name, LightShape shape, const Rigid3d& pose, double value) {
    Light light;
    light.name = name;
    light.shape = shape;
    light.world_from_object = pose;
    light.emission = RgbOrEstimate::constant(Vector3d::Constant(value));
    return light;
}

SimScene buildScene(const Scene& scene) {
    auto built = SimScene::build(scene);
    EXPECT_TRUE(built) << built.error().message;
    return std::move(*built);
}

// Irradiance from a uniform Lambertian polygon of radiance L at point x with unit normal n
// (Lambert 1760): E = L/2 sum_i theta_i n.(v_i x v_{i+1}) / |v_i x v_{i+1}|, v_i the unit vectors
// from x to the vertices, theta_i the angle between v_i and v_{i+1}. The polygon is first clipped to
// the receiver's upper half-space (the part below the horizon sends it nothing).
double lambertIrradiance(std::vector<Vector3d> polygon, const Vector3d& x, const Vector3d& n, double radiance) {
    // Sutherland-Hodgman against the plane n.(p - x) = 0.
    std::vector<Vector3d> clipped;
    for (std::size_t i = 0; i < polygon.size(); ++i) {
        const Vector3d& a = polygon[i];
        const Vector3d& b = polygon[(i + 1) % polygon.size()];
        const double da = n.dot(a - x);
        const double db = n.dot(b - x);
        if (da >= 0) clipped.push_back(a);
        if ((da >= 0) != (db >= 0)) clipped.push_back(a + (b - a) * (da / (da - db)));
    }
    double sum = 0.0;
    for (std::size_t i = 0; i < clipped.size(); ++i) {
        const Vector3d v0 = (clipped[i] - x).normalized();
        const Vector3d v1 = (clipped[(i + 1) % clipped.size()] - x).normalized();
        const Vector3d c = v0.cross(v1);
        if (c.norm() < 1e-15) continue;
        const double theta = std::atan2(c.norm(), v0.dot(v1));
        sum += theta * n.dot(c.normalized());
    }
    return 0.5 * radiance * std::abs(sum);
}

struct Stats {
    double mean = 0.0;
    double sigma = 0.0;      // standard deviation of one estimate (across seeds)
    double max_error = 0.0;  // largest relative error of one estimate
};

// Runs estimateIrradiance with `seeds` independent seeds: the spread across seeds is the standard
// error of one estimate (the stratified sampler makes the per-sample variance useless for that).
Stats measure(const SimScene& scene, const Vector3d& x, const Vector3d& n, int samples, double expected,
              int seeds = 8) {
    std::vector<double> values;
    for (int s = 0; s < seeds; ++s) values.push_back(estimateIrradiance(scene, x, n, samples, 1000 + s).x());
    Stats stats;
    for (double v : values) stats.mean += v / seeds;
    for (double v : values) {
        stats.sigma += (v - stats.mean) * (v - stats.mean) / (seeds - 1);
        stats.max_error = std::max(stats.max_error, std::abs(v - expected) / expected);
    }
    stats.sigma = std::sqrt(stats.sigma);
    return stats;
}

TEST(RenderIrradiance, RectangularAreaLightMatchesLambertsFormula) {
    // A 0.6 x 0.4 m panel 1 m above the origin, facing down, radiance 10 W/(m^2 sr).
    constexpr double kRadiance = 10.0;
    const Rigid3d pose = Rigid3d::fromRpyDeg({0.1, -0.05, 1.0}, {180, 0, 20});
    Scene scene;
    scene.lights.push_back(makeLight("panel", AreaLightShape{{0.6, 0.4}}, pose, kRadiance));
    const SimScene sim = buildScene(scene);
    std::vector<Vector3d> polygon;
    for (const auto& [sx, sy] : {std::pair{-1, -1}, {1, -1}, {1, 1}, {-1, 1}}) {
        polygon.push_back(pose * Vector3d(0.3 * sx, 0.2 * sy, 0.0));
    }
    struct Case {
        const char* what;
        Vector3d x;
        Vector3d n;
        int samples = 1024;
    };
    const Vector3d light_x = pose.rotation * Vector3d::UnitX();
    const Vector3d corner = pose * Vector3d(0.3, 0.2, 0.0);
    const std::vector<Case> cases = {
        {"under the centre", {0.1, -0.05, 0.0}, Vector3d::UnitZ()},
        {"close under the centre (10 cm)", {0.1, -0.05, 0.9}, Vector3d::UnitZ()},
        {"under the edge of the footprint", pose * Vector3d(0.3, 0.0, 1.0), Vector3d::UnitZ()},
        {"just outside the footprint's corner", corner + Vector3d(0.02, 0.02, -0.3), Vector3d::UnitZ()},
        {"far to the side", {2.0, 1.0, 0.0}, Vector3d::UnitZ()},
        {"tilted 50 degrees", {0.3, 0.2, 0.2}, Vector3d(std::sin(0.87), 0.0, std::cos(0.87))},
        {"vertical receiver, light cut by its horizon", {0.1, -0.05, 0.7}, light_x},
        // Beyond the cases: 5 cm from the light, tilted so that it sees only the far part
        // of the light at grazing angles. Solid-angle sampling spends most samples on the part
        // behind the receiver's horizon here, so this one needs 4096 samples for 4 sigma < 1%.
        {"grazing, 5 cm away, mostly behind its horizon", pose * Vector3d(0.25, 0.0, 0.05),
         Vector3d(-light_x + Vector3d(0, 0, -0.3)).normalized(), 4096},
    };
    constexpr double kTolerance = 0.01;
    for (const Case& c : cases) {
        const double expected = lambertIrradiance(polygon, c.x, c.n, kRadiance);
        ASSERT_GT(expected, 0.0) << c.what;
        const Stats stats = measure(sim, c.x, c.n, c.samples, expected);
        std::printf("  %-48s %4d spp: E = %8.5f W/m^2, worst rel. error %.5f, sigma %.5f (tolerance %.2f)\n", c.what,
                    c.samples, expected, stats.max_error, stats.sigma / expected, kTolerance);
        EXPECT_LT(stats.max_error, kTolerance) << c.what;
        // The tolerance must be more than 4 standard errors, or passing would be luck.
        EXPECT_LT(4.0 * stats.sigma / expected, kTolerance) << c.what;
    }
}

TEST(RenderIrradiance, DiscLightOnItsAxis) {
    // On the axis of a disc of radius r at distance h: E = pi L r^2 / (r^2 + h^2).
    constexpr double kRadiance = 3.0;
    constexpr double kRadius = 0.25;
    Scene scene;
    scene.lights.push_back(
        makeLight("disc", DiscLightShape{kRadius}, Rigid3d::fromRpyDeg({0, 0, 0.8}, {180, 0, 0}), kRadiance));
    const SimScene sim = buildScene(scene);
    for (const double h : {0.1, 0.4, 0.8}) {
        const double expected = std::numbers::pi * kRadiance * kRadius * kRadius / (kRadius * kRadius + h * h);
        const Stats stats = measure(sim, {0, 0, 0.8 - h}, Vector3d::UnitZ(), 1024, expected);
        std::printf("  disc at h = %.1f: worst rel. error %.5f, sigma %.5f\n", h, stats.max_error,
                    stats.sigma / expected);
        EXPECT_LT(stats.max_error, 0.01) << "h = " << h;
        EXPECT_LT(4.0 * stats.sigma / expected, 0.01) << "h = " << h;
    }
}

TEST(RenderIrradiance, PointLightInverseSquareAndCosineLaws) {
    constexpr double kIntensity = 7.0;  // W/sr
    const Vector3d light_position(0.2, -0.1, 1.5);
    Scene scene;
    scene.lights.push_back(makeLight("bulb", PointLightShape{}, Rigid3d({1, 0, 0, 0}, light_position), kIntensity));
    const SimScene sim = buildScene(scene);
    constexpr double kTolerance = 0.005;
    const Vector3d axis = Vector3d(0.3, 0.2, -1.0).normalized();  // from the light towards the receivers
    for (const double d : {0.5, 1.0}) {
        double e0_at_d = 0.0;
        for (const double angle_deg : {0.0, 30.0, 60.0}) {
            // Receiver normal tilted by angle from the direction towards the light.
            const double a = angle_deg * std::numbers::pi / 180.0;
            const Vector3d to_light = -axis;
            const Vector3d side = to_light.cross(Vector3d::UnitX()).normalized();
            const Vector3d n = std::cos(a) * to_light + std::sin(a) * side;
            for (const double distance : {d, 2 * d}) {
                const Vector3d x = light_position + distance * axis;
                const double expected = kIntensity * std::cos(a) / (distance * distance);
                const double e = estimateIrradiance(sim, x, n, 16, 7).x();
                EXPECT_NEAR(e, expected, kTolerance * expected) << "d = " << distance << " angle " << angle_deg;
                if (angle_deg == 0.0 && distance == d) e0_at_d = e;
                if (angle_deg == 0.0 && distance == 2 * d) {
                    EXPECT_NEAR(e0_at_d / e, 4.0, 4.0 * kTolerance) << "inverse square from " << d << " to " << 2 * d;
                }
                std::printf("  point light: d = %.1f m, %2.0f deg: rel. error %.2e\n", distance, angle_deg,
                            std::abs(e - expected) / expected);
            }
        }
    }
}

TEST(RenderIrradiance, DirectionalLightCosineLaw) {
    constexpr double kIrradiance = 500.0;
    const Vector3d direction = Vector3d(0.0, 1.0, -1.0).normalized();
    Scene scene;
    scene.lights.push_back(makeLight("sun", DirectionalLightShape{direction}, Rigid3d::identity(), kIrradiance));
    const SimScene sim = buildScene(scene);
    for (const double angle_deg : {0.0, 45.0, 80.0}) {
        const double a = angle_deg * std::numbers::pi / 180.0;
        const Vector3d n = std::cos(a) * -direction + std::sin(a) * Vector3d::UnitX();
        const double e = estimateIrradiance(sim, {0, 0, 0}, n, 4, 1).x();
        EXPECT_NEAR(e, kIrradiance * std::cos(a), 1e-6 * kIrradiance) << angle_deg;
    }
    // Facing away: nothing.
    EXPECT_EQ(estimateIrradiance(sim, {0, 0, 0}, direction, 4, 1).x(), 0.0);
}

TEST(RenderIrradiance, UniformSkyGivesPiLTimesViewFactor) {
    // A receiver tilted by theta sees the upper hemisphere (radiance L) and the black ground:
    // E = pi L (1 + cos theta) / 2. Found by BSDF sampling only.
    constexpr double kRadiance = 2.0;
    Scene scene;
    scene.lights.push_back(makeLight("sky", DistantLightShape{64}, Rigid3d::identity(), kRadiance));
    const SimScene sim = buildScene(scene);
    for (const double angle_deg : {0.0, 60.0, 120.0}) {
        const double a = angle_deg * std::numbers::pi / 180.0;
        const Vector3d n(std::sin(a), 0.0, std::cos(a));
        const double expected = std::numbers::pi * kRadiance * (1.0 + std::cos(a)) / 2.0;
        const Stats stats = measure(sim, {0, 0, 0}, n, 1024, expected);
        EXPECT_LT(stats.max_error, 0.01) << angle_deg;
        EXPECT_LT(4.0 * stats.sigma / expected, 0.01) << angle_deg;
    }
}

}  // namespace
}  // namespace commonlight::mocks::sim

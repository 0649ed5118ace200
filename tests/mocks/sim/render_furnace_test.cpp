// Furnace tests: a closed box of Lambertian walls with emitting faces. The renderer's radiosity
// (B = emitted exitance + albedo * irradiance, the irradiance from estimateIrradiance, i.e. the
// path tracer with NEE, MIS and Russian roulette) is compared with an independent solution of the
// radiosity equation.
//
// The reference: the classic radiosity linear system B_i = E_i + rho_i sum_j F_ij B_j with each
// face cut into n x n patches, point-to-patch form factors exact by Lambert's polygon formula at
// the patch centres (collocation), iterated to convergence, face means extrapolated from n = 8 and
// n = 16 (Richardson, error ~ h^2). With one patch per face (the "6-face system") the answer is
// off by several percent, because a face lit from one side is far from uniform; n = 8, 16 and the
// extrapolation agree with n = 32 to 0.05%.
#include <cmath>
#include <cstdio>
#include <numbers>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "mocks/sim/embree_scene.h"
#include "mocks/sim/path_tracer.h"

namespace commonlight::mocks::sim {
namespace {

using Eigen::Vector3d;

constexpr double kSizeX = 1.0;
constexpr double kSizeY = 0.8;
constexpr double kSizeZ = 0.6;

// A face of the box: centre, half-extent vectors along the plane's own x and y, inward normal (+z
// of the plane), and the plane's pose and size for the scene.
struct Face {
    const char* name;
    Rigid3d pose;
    Eigen::Vector2d size;

    Vector3d centre() const { return pose.translation; }
    Vector3d halfU() const { return pose.rotation * Vector3d(0.5 * size.x(), 0, 0); }
    Vector3d halfV() const { return pose.rotation * Vector3d(0, 0.5 * size.y(), 0); }
    Vector3d normal() const { return pose.rotation * Vector3d::UnitZ(); }
};

// The six faces of a box centred at the origin, each plane's front (+z) looking into the box.
// Face 1 (top) is the one that emits in the one-emitter cases.
std::vector<Face> boxFaces() {
    const double hx = kSizeX / 2, hy = kSizeY / 2, hz = kSizeZ / 2;
    return {
        {"bottom", Rigid3d::fromRpyDeg({0, 0, -hz}, {0, 0, 0}), {kSizeX, kSizeY}},
        {"top", Rigid3d::fromRpyDeg({0, 0, hz}, {180, 0, 0}), {kSizeX, kSizeY}},
        {"x-", Rigid3d::fromRpyDeg({-hx, 0, 0}, {0, 90, 0}), {kSizeZ, kSizeY}},
        {"x+", Rigid3d::fromRpyDeg({hx, 0, 0}, {0, -90, 0}), {kSizeZ, kSizeY}},
        {"y-", Rigid3d::fromRpyDeg({0, -hy, 0}, {-90, 0, 0}), {kSizeX, kSizeZ}},
        {"y+", Rigid3d::fromRpyDeg({0, hy, 0}, {90, 0, 0}), {kSizeX, kSizeZ}},
    };
}

// Form factor from the point x (unit normal n) to a polygon: (1 / 2 pi) sum_i theta_i n.gamma_i.
double pointToPolygonFormFactor(const std::vector<Vector3d>& polygon, const Vector3d& x, const Vector3d& n) {
    double sum = 0.0;
    for (std::size_t i = 0; i < polygon.size(); ++i) {
        const Vector3d a = (polygon[i] - x).normalized();
        const Vector3d b = (polygon[(i + 1) % polygon.size()] - x).normalized();
        const Vector3d c = a.cross(b);
        const double len = c.norm();
        if (len < 1e-15) continue;
        sum += std::atan2(len, a.dot(b)) * n.dot(c / len);
    }
    return std::abs(sum) / (2.0 * std::numbers::pi);
}

// Face-mean radiosities of the box with n x n patches per face (see the file comment).
std::vector<double> solveRadiosity(const std::vector<Face>& faces, const std::vector<double>& exitance,
                                   const std::vector<double>& albedo, int n) {
    const int patches = 6 * n * n;
    std::vector<Vector3d> centre(patches), normal(patches);
    std::vector<std::vector<Vector3d>> polygon(patches);
    std::vector<int> face_of(patches);
    for (int f = 0; f < 6; ++f) {
        for (int i = 0; i < n; ++i) {
            for (int j = 0; j < n; ++j) {
                const int id = (f * n + i) * n + j;
                const double a0 = -1.0 + 2.0 * i / n, a1 = -1.0 + 2.0 * (i + 1) / n;
                const double b0 = -1.0 + 2.0 * j / n, b1 = -1.0 + 2.0 * (j + 1) / n;
                const Face& face = faces[f];
                const auto at = [&](double a, double b) {
                    return Vector3d(face.centre() + a * face.halfU() + b * face.halfV());
                };
                polygon[id] = {at(a0, b0), at(a1, b0), at(a1, b1), at(a0, b1)};
                centre[id] = at(0.5 * (a0 + a1), 0.5 * (b0 + b1));
                normal[id] = face.normal();
                face_of[id] = f;
            }
        }
    }
    std::vector<double> form_factors(static_cast<std::size_t>(patches) * patches, 0.0);
    for (int a = 0; a < patches; ++a) {
        for (int b = 0; b < patches; ++b) {
            if (face_of[a] == face_of[b]) continue;  // coplanar patches do not see each other
            form_factors[static_cast<std::size_t>(a) * patches + b] =
                pointToPolygonFormFactor(polygon[b], centre[a], normal[a]);
        }
    }
    std::vector<double> b_values(patches), next(patches);
    for (int a = 0; a < patches; ++a) b_values[a] = exitance[face_of[a]];
    for (int iteration = 0; iteration < 200; ++iteration) {  // Jacobi; converges as rho^k
        double change = 0.0;
        for (int a = 0; a < patches; ++a) {
            double gathered = 0.0;
            for (int b = 0; b < patches; ++b)
                gathered += form_factors[static_cast<std::size_t>(a) * patches + b] * b_values[b];
            next[a] = exitance[face_of[a]] + albedo[face_of[a]] * gathered;
            change = std::max(change, std::abs(next[a] - b_values[a]));
        }
        b_values.swap(next);
        if (change < 1e-13) break;
    }
    std::vector<double> means(6, 0.0);
    for (int a = 0; a < patches; ++a) means[face_of[a]] += b_values[a] / (n * n);
    return means;
}

std::vector<double> referenceRadiosity(const std::vector<Face>& faces, const std::vector<double>& exitance,
                                       const std::vector<double>& albedo) {
    const std::vector<double> coarse = solveRadiosity(faces, exitance, albedo, 8);
    const std::vector<double> fine = solveRadiosity(faces, exitance, albedo, 16);
    const std::vector<double> six = solveRadiosity(faces, exitance, albedo, 1);
    std::vector<double> out(6);
    for (int f = 0; f < 6; ++f) {
        out[f] = fine[f] + (fine[f] - coarse[f]) / 3.0;
        std::printf("  reference %-6s B = %.5f (n=8 %.5f, n=16 %.5f; 6-face system %.5f, %+.1f%%)\n", faces[f].name,
                    out[f], coarse[f], fine[f], six[f], 100.0 * (six[f] - out[f]) / out[f]);
    }
    return out;
}

struct FaceMeasurement {
    double mean = 0.0;            // mean radiosity over the face
    double standard_error = 0.0;  // of `mean`, from the spread of independent replicates
};

// Mean radiosity of a face: exitance + albedo * irradiance, the irradiance from estimateIrradiance
// at k x k jittered-stratified points (an unbiased estimate of the face mean), `samples` each.
// Repeated with `replicates` independent seeds: their spread gives the standard error (the
// per-point spread would count the irradiance's variation over the face, which the stratification
// removes, and overstate it many times).
FaceMeasurement measureFace(const SimScene& scene, const Face& face, double exitance, double albedo, int k, int samples,
                            int replicates, const IntegratorOptions& options, std::uint64_t seed) {
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> uniform(0.0, 1.0);
    std::vector<double> estimates;
    for (int r = 0; r < replicates; ++r) {
        double sum = 0.0;
        for (int i = 0; i < k; ++i) {
            for (int j = 0; j < k; ++j) {
                const double a = -1.0 + 2.0 * (i + uniform(rng)) / k;
                const double b = -1.0 + 2.0 * (j + uniform(rng)) / k;
                const Vector3d x = face.centre() + a * face.halfU() + b * face.halfV();
                const std::uint64_t point_seed = ((seed * 64 + r) * k + i) * k + j;
                sum +=
                    exitance + albedo * estimateIrradiance(scene, x, face.normal(), samples, point_seed, options).x();
            }
        }
        estimates.push_back(sum / (k * k));
    }
    FaceMeasurement m;
    for (double v : estimates) m.mean += v / replicates;
    double var = 0.0;
    for (double v : estimates) var += (v - m.mean) * (v - m.mean) / (replicates - 1);
    m.standard_error = std::sqrt(var / replicates);
    return m;
}

RealObject wall(const Face& face, double albedo) {
    return {face.name, PlaneShape{face.size}, face.pose, RgbOrEstimate::constant(Vector3d::Constant(albedo))};
}

VirtualObject emissiveWall(const Face& face, double albedo, double radiance) {
    VirtualObject object;
    object.name = face.name;
    object.shape = PlaneShape{face.size};
    object.material.albedo = Vector3d::Constant(albedo);
    object.emission = Vector3d::Constant(radiance);
    object.placement = FixedPlacement{face.pose};
    return object;
}

// Compares each face with albedo > 0 with the reference; `samples` per point at 16 x 16 points,
// `replicates` times.
void expectFacesMatch(const SimScene& scene, const std::vector<Face>& faces, const std::vector<double>& exitance,
                      const std::vector<double>& albedo, const std::vector<double>& reference,
                      const IntegratorOptions& options, int samples, int replicates) {
    constexpr double kTolerance = 0.01;
    for (int f = 0; f < 6; ++f) {
        if (albedo[f] == 0.0) continue;  // a black emitter's radiosity is its exitance: nothing to measure
        const FaceMeasurement m =
            measureFace(scene, faces[f], exitance[f], albedo[f], 16, samples, replicates, options, 17 + f);
        const double error = (m.mean - reference[f]) / reference[f];
        std::printf("  rendered  %-6s B = %.5f, rel. error %+.5f, standard error %.5f (tolerance %.2f)\n",
                    faces[f].name, m.mean, error, m.standard_error / reference[f], kTolerance);
        EXPECT_LT(std::abs(error), kTolerance) << faces[f].name;
        EXPECT_LT(4.0 * m.standard_error / reference[f], kTolerance) << faces[f].name;
    }
}

TEST(RenderFurnace, BoxWithOneAreaLightFace) {
    // Five walls of albedo rho; the sixth face is an area light (radiance L, black surface).
    constexpr double kRho = 0.5;
    constexpr double kRadiance = 1.0;
    const std::vector<Face> faces = boxFaces();
    Scene scene;
    for (int f = 0; f < 6; ++f) {
        if (f == 1) continue;
        scene.real_objects.push_back(wall(faces[f], kRho));
    }
    Light light;
    light.name = "ceiling";
    light.shape = AreaLightShape{faces[1].size};
    light.world_from_object = faces[1].pose;
    light.emission = RgbOrEstimate::constant(Vector3d::Constant(kRadiance));
    scene.lights.push_back(light);
    auto sim = SimScene::build(scene);
    ASSERT_TRUE(sim) << sim.error().message;

    std::vector<double> exitance(6, 0.0), albedo(6, kRho);
    exitance[1] = std::numbers::pi * kRadiance;
    albedo[1] = 0.0;
    const std::vector<double> reference = referenceRadiosity(faces, exitance, albedo);
    IntegratorOptions options;
    options.max_depth = 64;  // 0.5^64: truncation far below the tolerance; Russian roulette from depth 3
    expectFacesMatch(*sim, faces, exitance, albedo, reference, options, 32, 8);
}

TEST(RenderFurnace, BoxWithOneEmissiveFaceOfTheSameAlbedo) {
    // All six faces albedo rho; the top one also emits (an emissive virtual plane: found by BSDF
    // sampling only, a different path through the integrator than the area light above).
    constexpr double kRho = 0.6;
    constexpr double kRadiance = 2.0;
    const std::vector<Face> faces = boxFaces();
    Scene scene;
    for (int f = 0; f < 6; ++f) {
        if (f == 1) continue;
        scene.real_objects.push_back(wall(faces[f], kRho));
    }
    scene.virtual_objects.push_back(emissiveWall(faces[1], kRho, kRadiance));
    SimSceneOptions scene_options;
    scene_options.include_virtual = true;
    auto sim = SimScene::build(scene, scene_options);
    ASSERT_TRUE(sim) << sim.error().message;

    std::vector<double> exitance(6, 0.0), albedo(6, kRho);
    exitance[1] = std::numbers::pi * kRadiance;
    const std::vector<double> reference = referenceRadiosity(faces, exitance, albedo);
    IntegratorOptions options;
    options.max_depth = 100;
    // The emitter is found by BSDF sampling alone: noisier, so more samples.
    expectFacesMatch(*sim, faces, exitance, albedo, reference, options, 64, 16);
}

TEST(RenderFurnace, UniformlyEmittingBoxReachesEOverOneMinusRho) {
    // Every face emits exitance E = pi L and reflects rho: B = E / (1 - rho) everywhere.
    constexpr double kRho = 0.8;
    constexpr double kRadiance = 1.0;
    const std::vector<Face> faces = boxFaces();
    Scene scene;
    for (const Face& face : faces) scene.virtual_objects.push_back(emissiveWall(face, kRho, kRadiance));
    SimSceneOptions scene_options;
    scene_options.include_virtual = true;
    auto sim = SimScene::build(scene, scene_options);
    ASSERT_TRUE(sim) << sim.error().message;

    const double exitance = std::numbers::pi * kRadiance;
    const double expected = exitance / (1.0 - kRho);
    IntegratorOptions options;
    options.max_depth = 200;  // 0.8^200 ~ 1e-19: only Russian roulette ends paths in practice
    constexpr double kTolerance = 0.01;
    // A path's value depends only on its Russian roulette decisions here (every bounce collects L
    // and carries rho), so the faces differ only by their seeds.
    for (std::size_t f = 0; f < faces.size(); ++f) {
        const Face& face = faces[f];
        const FaceMeasurement m = measureFace(*sim, face, exitance, kRho, 8, 128, 16, options, 5 + f);
        const double error = (m.mean - expected) / expected;
        std::printf("  %-6s B = %.5f (expected %.5f), rel. error %+.5f, standard error %.5f\n", face.name, m.mean,
                    expected, error, m.standard_error / expected);
        EXPECT_LT(std::abs(error), kTolerance) << face.name;
        EXPECT_LT(4.0 * m.standard_error / expected, kTolerance) << face.name;
    }
}

}  // namespace
}  // namespace commonlight::mocks::sim

// The radiosity solver against closed forms: the furnace (a closed room converges to
// Le / (1 - rho)), empty and furnished (visibility, a narrow gap, contact lines), the light of a
// partly covered element, and the sampling of visibility pairs.
#include "lighting/radiosity.h"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "core/scene_io.h"
#include "lighting/direct.h"
#include "lighting/form_factor.h"
#include "lighting/sampling.h"

namespace commonlight::lighting {
namespace {

using Eigen::Vector3d;

Scene boxRoom(const Vector3d& size) {
    Scene scene;
    RealObject room;
    room.name = "room";
    room.shape = BoxShape{size};
    scene.real_objects.push_back(room);
    return scene;
}

// A closed box whose walls (seen from inside: the faces' back sides) all emit Le with rho = 0.95.
// Inside a closed box the point form factors from any point sum to 1, so the exact solution is
// uniform: L = Le / (1 - rho) = 20 Le. The faces' normals point outwards, so the room is modelled
// as its inward copy: each face flipped.
TEST(Radiosity, FurnaceClosedRoomConvergesToLeOverOneMinusRho) {
    Scene scene = boxRoom(Vector3d(3.0, 2.0, 2.5));
    std::vector<Face> faces = *realFaces(scene);
    for (Face& f : faces) {  // inward: swap the edges, which flips the normal
        std::swap(f.edge_s, f.edge_t);
        f.normal = -f.normal;
    }
    RadiosityOptions options;
    options.link_epsilon = 0.002;
    options.min_element_size = 0.1;
    options.min_link_size = 0.1;
    options.residual = 1e-7;
    options.max_iterations = 5000;
    auto rays = *RayScene::build(faces, {}, {});
    Radiosity radiosity(faces, {}, {}, *rays, options);
    radiosity.subdivideTo(0.5, 1.0);
    // Every wall emits the same: sources need no splitting for their radiance's sake.
    radiosity.setSourceRadiance(std::vector<double>(radiosity.hierarchy().elements().size(), 1.0));
    radiosity.buildRealLinks();
    const std::size_t n = radiosity.hierarchy().elements().size();
    const double rho = 0.95;
    const Vector3d le(1.0, 2.0, 0.5);
    std::vector<Vector3d> rho_v(n, Vector3d::Constant(rho)), emission(n, le), direct(n, Vector3d::Zero());
    const Solution solution = radiosity.solve(Mode::kReal, rho_v, emission, direct);
    ASSERT_TRUE(solution.summary.converged) << solution.summary.residual;
    double worst = 0.0;
    for (int e : radiosity.leaves(Mode::kReal)) {
        const Vector3d expected = le / (1.0 - rho);
        worst = std::max(worst, ((solution.radiance[static_cast<std::size_t>(e)] - expected).cwiseQuotient(expected)).cwiseAbs().maxCoeff());
    }
    // The form factors of each leaf sum to 1 within the receiver quadrature's error (order 8 at
    // adjacent elements, 1e-4); 1/(1 - rho) = 20 amplifies that (measured: 0.11% at worst).
    EXPECT_LT(worst, 0.005) << "leaves " << radiosity.hierarchy().leafCount() << " links " << radiosity.linkCount(Mode::kReal);
    RecordProperty("furnace_worst_relative_error", std::to_string(worst));
    RecordProperty("iterations", solution.summary.iterations);
}

// A closed room with furniture (a cabinet 5 cm from a wall, a table with a box on it, a crate on
// the floor, a box touching the back wall), every surface emitting Le with reflectance rho: from
// any point the hemisphere meets only such surfaces, so the exact solution is uniform,
// L = Le / (1 - rho), whatever the occlusion. This checks visibility, the link hierarchy in a narrow
// gap and at contact lines, and energy conservation together (rho = 0.5: each 1% of form factor
// lost or gained is 0.5% of L). Tolerances: the area-weighted RMS deviation within 2%, its mean
// within 0.5%, and no element at least a quarter exposed off by more than 15% (small leaves at
// contact lines, whose few exposed quadrature points carry the most error).
TEST(Radiosity, FurnaceWithFurnitureStaysUniform) {
    auto scene = parseScene(R"(
real:
  - {name: floor, plane: {size: [3.0, 2.4]}, world_from_object: {t: [0, 0, 0]}}
  - {name: ceiling, plane: {size: [3.0, 2.4]}, world_from_object: {t: [0, 0, 2.2], rpy_deg: [180, 0, 0]}}
  - {name: north, plane: {size: [3.0, 2.2]}, world_from_object: {t: [0, 1.2, 1.1], rpy_deg: [90, 0, 0]}}
  - {name: south, plane: {size: [3.0, 2.2]}, world_from_object: {t: [0, -1.2, 1.1], rpy_deg: [-90, 0, 0]}}
  - {name: west, plane: {size: [2.2, 2.4]}, world_from_object: {t: [-1.5, 0, 1.1], rpy_deg: [0, 90, 0]}}
  - {name: east, plane: {size: [2.2, 2.4]}, world_from_object: {t: [1.5, 0, 1.1], rpy_deg: [0, -90, 0]}}
  - {name: cabinet, box: {size: [0.4, 0.6, 1.0]}, world_from_object: {t: [1.25, 0.4, 0.5]}}
  - {name: table, box: {size: [0.9, 0.6, 0.7]}, world_from_object: {t: [-0.5, 0.3, 0.35]}}
  - {name: box_on_table, box: {size: [0.2, 0.2, 0.2]}, world_from_object: {t: [-0.6, 0.3, 0.8]}}
  - {name: crate, box: {size: [0.3, 0.3, 0.3]}, world_from_object: {t: [0.3, -0.6, 0.15], rpy_deg: [0, 0, 30]}}
  - {name: against_wall, box: {size: [0.5, 0.2, 0.4]}, world_from_object: {t: [-0.8, 1.1, 0.2]}}
)", "furnace.yaml");
    ASSERT_TRUE(scene) << scene.error().message;
    const std::vector<Face> faces = *realFaces(*scene);
    auto rays = *RayScene::build(faces, {}, {});
    RadiosityOptions options;
    options.link_epsilon = 0.01;
    options.min_link_size = 0.3;
    options.min_element_size = 0.01;
    Radiosity radiosity(faces, {}, {}, *rays, options);
    radiosity.subdivideTo(0.6, 1.0);
    radiosity.markBuried();
    radiosity.setSourceRadiance(std::vector<double>(radiosity.hierarchy().elements().size(), 1.0));
    radiosity.buildRealLinks();
    radiosity.markBuried();
    const std::size_t n = radiosity.hierarchy().elements().size();
    const double rho = 0.5;
    const Vector3d le = Vector3d::Ones();
    std::vector<Vector3d> rho_v(n, Vector3d::Constant(rho)), emission(n, le), direct(n, Vector3d::Zero());
    const Solution solution = radiosity.solve(Mode::kReal, rho_v, emission, direct);
    ASSERT_TRUE(solution.summary.converged);
    const double expected = 1.0 / (1.0 - rho);
    double area = 0.0, sum = 0.0, sum_sq = 0.0, worst = 0.0;
    int buried_leg = 0, worst_element = -1;
    for (int e : radiosity.leaves(Mode::kReal)) {
        const double a = radiosity.hierarchy()[e].area * radiosity.exposure(e);
        const double d = solution.radiance[static_cast<std::size_t>(e)].x() / expected - 1.0;
        area += a;
        sum += a * d;
        sum_sq += a * d * d;
        // Slivers (a corner of a floor element sticking out from under the rotated crate, a few
        // per cent of it exposed) are estimated from the few quadrature points and pairs that land
        // on the exposed part; they carry no area to speak of and are left out of the worst case.
        if (radiosity.exposure(e) >= 0.25 && std::abs(d) > worst) {
            worst = std::abs(d);
            worst_element = e;
        }
    }
    const auto describe = [&](int e) {
        const Element& el = radiosity.hierarchy()[e];
        const Face& f = radiosity.face(el.face);
        const ElementGeometry g = radiosity.geometry(e);
        return scene->real_objects[static_cast<std::size_t>(f.object_index)].name + " face " + std::to_string(f.face_index) + " at (" +
               std::to_string(g.centroid.x()) + ", " + std::to_string(g.centroid.y()) + ", " + std::to_string(g.centroid.z()) + "), " +
               std::to_string(el.size_s) + " x " + std::to_string(el.size_t_) + " m, exposure " + std::to_string(radiosity.exposure(e));
    };
    // The cabinet's bottom on the floor plane is buried (pressed against another face), not a
    // black element that takes no light.
    for (std::size_t e = 0; e < n; ++e) {
        const Element& el = radiosity.hierarchy()[static_cast<int>(e)];
        const Face& f = radiosity.face(el.face);
        if (el.leaf() && f.object_index == 6 && f.face_index == 5) buried_leg += el.buried ? 1 : 0;
    }
    const double rms = std::sqrt(sum_sq / area), mean = sum / area;
    RecordProperty("rms", std::to_string(rms));
    RecordProperty("mean", std::to_string(mean));
    RecordProperty("worst", std::to_string(worst));
    EXPECT_LT(rms, 0.02) << "leaves " << radiosity.leaves(Mode::kReal).size() << " links " << radiosity.linkCount(Mode::kReal);
    EXPECT_LT(std::abs(mean), 0.005);
    EXPECT_LT(worst, 0.15) << describe(worst_element);
    EXPECT_GT(buried_leg, 0);
}

// A leaf partly under a box lying on it gets the light of its exposed part: a flat box (1 cm, it
// casts almost no shadow) covering a quarter of a floor leaf does not make the leaf 25% darker.
TEST(Radiosity, PartlyCoveredElementHasTheLightOfItsExposedPart) {
    auto scene = parseScene(R"(
real:
  - {name: floor, plane: {size: [1.0, 1.0]}}
  - {name: slab, box: {size: [0.5, 0.5, 0.01]}, world_from_object: {t: [0.25, 0.25, 0.005]}}
lights:
  - {name: panel, area: {size: [0.5, 0.5]}, world_from_object: {t: [0, 0, 3], rpy_deg: [180, 0, 0]}, radiance: [10, 10, 10]}
)", "exposure.yaml");
    ASSERT_TRUE(scene) << scene.error().message;
    const std::vector<Face> faces = *realFaces(*scene);
    const std::vector<LightGeometry> lights = *lightGeometry(*scene);
    auto rays = *RayScene::build(faces, lights, {});
    Radiosity radiosity(faces, {}, {}, *rays, {});
    radiosity.markBuried();
    const int floor = radiosity.hierarchy().root(0);
    EXPECT_NEAR(radiosity.exposure(floor), 0.75, 0.02);
    DirectSource source;
    source.light = 0;
    source.polygon = &lights[0];
    DirectColumn column;
    computeDirect(radiosity, source, {floor}, {}, column);
    // The unoccluded irradiance averaged over the exposed three quarters (dense grid).
    double open = 0.0;
    int count = 0;
    for (int j = 0; j < 64; ++j) {
        for (int i = 0; i < 64; ++i) {
            const Vector3d x(-0.5 + (i + 0.5) / 64, -0.5 + (j + 0.5) / 64, 0.0);
            if (x.x() > 0.0 && x.y() > 0.0) continue;
            open += std::numbers::pi * pointToPolygon(x, Vector3d::UnitZ(), lights[0].polygon, lights[0].normal);
            ++count;
        }
    }
    open /= count;
    EXPECT_NEAR(column.real[static_cast<std::size_t>(floor)], open, 0.02 * open);
}

// The two ends of a visibility pair are each stratified and paired by a keyed permutation: over
// many links the first and second points are uncorrelated (a fixed pairing k -> 7k + 3 mod 16
// gave a correlation of -1 along one axis, and a shadow cast along it went unseen).
TEST(Radiosity, VisibilityPairsAreUncorrelated) {
    for (int n : {4, 8, 16, 64, 256}) {
        double sxy = 0.0, sx = 0.0, sy = 0.0, sxx = 0.0, syy = 0.0;
        int count = 0;
        for (std::uint64_t seed = 0; seed < 400; ++seed) {
            std::vector<char> seen(static_cast<std::size_t>(n), 0);
            for (int k = 0; k < n; ++k) {
                const int p = permuted(k, n, seed);
                ASSERT_GE(p, 0);
                ASSERT_LT(p, n);
                EXPECT_FALSE(seen[static_cast<std::size_t>(p)]) << "not a permutation: n " << n << " seed " << seed;
                seen[static_cast<std::size_t>(p)] = 1;
                const SamplePair pair = stratifiedPair(seed, k, n);
                sxy += pair.first.x() * pair.second.x();
                sx += pair.first.x();
                sy += pair.second.x();
                sxx += pair.first.x() * pair.first.x();
                syy += pair.second.x() * pair.second.x();
                ++count;
            }
        }
        const double cov = sxy / count - sx / count * sy / count;
        const double corr = cov / std::sqrt((sxx / count - sx * sx / count / count) * (syy / count - sy * sy / count / count));
        EXPECT_LT(std::abs(corr), 0.05) << "n " << n;
    }
}

}  // namespace
}  // namespace commonlight::lighting

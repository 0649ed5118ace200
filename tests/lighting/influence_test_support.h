// What the influence tests share (tests/lighting/influence_test.cpp and influence_cluster_test.cpp):
// the table scene, small test meshes, configurations of the virtual objects, and the comparison of
// an incremental state with a fresh solve. "From scratch" is a second estimator on the same scene (the
// base is deterministic, so its elements are the same) whose influence is rebuilt from nothing for
// each configuration (VirtualInfluence::rebuild(): every shaft scanned, dense Jacobi sweeps), and, on
// the same elements, denseDifference(). The incremental solution stops when no unshot difference is
// above `residual` x the largest radiance; the tolerance of the comparisons is 20 times that (the
// unshot remainders of many elements reach a leaf through several links and bounces).
#pragma once

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <memory>
#include <numbers>
#include <optional>
#include <string>
#include <tuple>
#include <vector>

#include "core/scene_io.h"
#include "lighting/estimator.h"
#include "lighting/influence.h"

namespace commonlight::lighting::influence_test {

inline constexpr double kPi = std::numbers::pi;

// A table against a wall on a floor, under a panel and a small lamp; a ball and a cube on the table.
inline const char* const kScene = R"(
real:
  - {name: floor, plane: {size: [2, 2]}, albedo: [0.5, 0.5, 0.5]}
  - {name: table, box: {size: [0.8, 0.6, 0.5]}, world_from_object: {t: [0, 0, 0.25]}, albedo: [0.6, 0.5, 0.4]}
  - {name: wall, plane: {size: [2, 1.5]}, world_from_object: {t: [0, 1, 0.75], rpy_deg: [90, 0, 0]}, albedo: [0.7, 0.7, 0.7]}
lights:
  - {name: panel, area: {size: [0.4, 0.4]}, world_from_object: {t: [0, 0, 1.6], rpy_deg: [180, 0, 0]}, radiance: [20, 20, 20]}
  - {name: lamp, area: {size: [0.08, 0.08]}, world_from_object: {t: [0.3, -0.2, 0.9], rpy_deg: [180, 20, 0]}, radiance: [80, 80, 80]}
virtual:
  - {name: ball, sphere: {radius: 0.05}, material: {albedo: [0.8, 0.8, 0.8]}, world_from_object: {t: [0, 0, 0.56]}}
  - {name: cube, box: {size: [0.08, 0.08, 0.08]}, material: {albedo: [0.5, 0.5, 0.5]}, world_from_object: {t: [0.2, 0.1, 0.54]}}
lighting: {max_elements: 3000}
)";

inline Scene parse(const std::string& yaml) {
    auto scene = parseScene(yaml, "influence.yaml");
    EXPECT_TRUE(scene) << scene.error().message;
    return scene ? *scene : Scene{};
}

inline CameraModel camera() {
    CameraModel c;
    c.width = 64;
    c.height = 48;
    c.fx = c.fy = 51.2;
    c.cx = 31.5;
    c.cy = 23.5;
    return c;
}

// Small test meshes: a coarse base, elements of the influence down to 2 cm.
inline EstimatorOptions testOptions() {
    EstimatorOptions o;
    o.refine_unobserved = true;
    o.initial_element_size = 0.25;
    o.light_refinement_size = 0.08;
    o.influence.min_size = 0.02;
    o.influence.link_size = 0.08;
    return o;
}

inline std::unique_ptr<Estimator> make(const Scene& scene, EstimatorOptions options = testOptions()) {
    auto est = Estimator::create(scene, camera(), {}, options);
    EXPECT_TRUE(est) << est.error().message;
    std::vector<Eigen::Vector3d> emission, albedo;
    for (const Light& l : scene.lights) emission.push_back(*l.emission.value);
    for (const RealObject& r : scene.real_objects) albedo.push_back(r.albedo.value.value_or(Eigen::Vector3d::Constant(0.5)));
    auto solved = (*est)->solveWith(emission, albedo, SceneLighting::scenePoses(scene, 0.0));
    EXPECT_TRUE(solved) << solved.error().message;
    return std::move(*est);
}

// A configuration of the virtual objects.
struct Config {
    std::vector<Rigid3d> poses;
    std::vector<bool> present;
    std::vector<std::optional<Eigen::Vector3d>> emission;
};

inline std::vector<InfluenceObject> objectsOf(const Config& c) {
    std::vector<InfluenceObject> out(c.poses.size());
    for (std::size_t i = 0; i < c.poses.size(); ++i) {
        out[i].world_from_object = c.poses[i];
        out[i].present = c.present[i];
        out[i].emission = c.emission[i];
    }
    return out;
}

inline Result<LightingSnapshot> apply(Estimator& est, const Config& c) {
    for (std::size_t i = 0; i < c.poses.size(); ++i) {
        est.setVirtualPresent(static_cast<int>(i), c.present[i]);
        est.setVirtualEmission(static_cast<int>(i), c.emission[i]);
    }
    return est.update(c.poses);
}

// A leaf by its place: face and (s, t) rectangle (element indices differ between two estimators
// that refined in different orders; places do not).
using Place = std::tuple<int, long, long, long, long>;
inline Place placeOf(const Element& e) {
    const auto q = [](double v) { return std::lround(v * 1e7); };
    return {e.face, q(e.st.x()), q(e.st.y()), q(e.ds.x() + e.dt.x()), q(e.ds.y() + e.dt.y())};
}

inline std::map<Place, Eigen::Vector3d> differenceByPlace(const Estimator& est) {
    std::map<Place, Eigen::Vector3d> out;
    const Radiosity& rad = est.radiosity();
    for (int e : rad.leaves(Mode::kReal)) out[placeOf(rad.hierarchy()[e])] = est.influence().difference()[static_cast<std::size_t>(e)];
    return out;
}

inline double scaleOf(const Estimator& est) {
    double s = 0.0;
    for (int e : est.radiosity().leaves(Mode::kReal)) s = std::max(s, est.influence().original()[static_cast<std::size_t>(e)].maxCoeff());
    return s;
}

// The incremental state against the dense solve of its own system, and against a second
// estimator rebuilt from scratch for the same configuration: the same leaves, the same B - B~.
inline void expectEqualsFresh(Estimator& incremental, Estimator& fresh, const Config& config, const std::string& what) {
    const double scale = scaleOf(incremental);
    const double tolerance = 20.0 * incremental.influence().options().residual * scale;
    // Step 1: the propagation against Jacobi sweeps on the same elements.
    const std::vector<Eigen::Vector3d> dense = incremental.influence().denseDifference(1e-10);
    double worst_dense = 0.0;
    for (int e : incremental.radiosity().leaves(Mode::kReal)) {
        worst_dense = std::max(worst_dense, (dense[static_cast<std::size_t>(e)] - incremental.influence().difference()[static_cast<std::size_t>(e)]).cwiseAbs().maxCoeff());
    }
    EXPECT_LE(worst_dense, tolerance) << what << ": propagation against dense sweeps";
    // Step 2: against the from-scratch rebuild.
    std::optional<InfluenceViewer> none;
    auto rebuilt = fresh.influence().rebuild(objectsOf(config), none);
    ASSERT_TRUE(rebuilt) << rebuilt.error().message;
    const std::map<Place, Eigen::Vector3d> a = differenceByPlace(incremental);
    std::map<Place, Eigen::Vector3d> b;
    {
        const Radiosity& rad = fresh.radiosity();
        for (int e : rad.leaves(Mode::kReal)) {
            b[placeOf(rad.hierarchy()[e])] = fresh.influence().difference()[static_cast<std::size_t>(e)];
        }
    }
    ASSERT_EQ(a.size(), b.size()) << what << ": the same elements";
    double worst = 0.0;
    int missing = 0;
    for (const auto& [place, d] : a) {
        const auto it = b.find(place);
        if (it == b.end()) {
            ++missing;
            continue;
        }
        worst = std::max(worst, (d - it->second).cwiseAbs().maxCoeff());
    }
    EXPECT_EQ(missing, 0) << what << ": leaves the fresh solve does not have";
    EXPECT_LE(worst, tolerance) << what << ": incremental against from scratch (scale " << scale << ")";
}

inline Config sceneConfig(const Scene& s) {
    Config c;
    c.poses = SceneLighting::scenePoses(s, 0.0);
    c.present.assign(c.poses.size(), true);
    c.emission.assign(c.poses.size(), std::nullopt);
    return c;
}

}  // namespace commonlight::lighting::influence_test

// The real lights of a scene, as the path tracer samples them (next-event estimation).
//
// Radiometric meaning (per RGB channel, linear; docs/sim-rendering.md has the full story):
// - rectangle / disc: uniform radiance L in W/(m^2 sr) leaving the +z side of the light's plane
//   in every direction; the back side emits nothing. Irradiance at distance d straight in front
//   of a small light of area A: E = L A / d^2.
// - point: intensity I in W/sr, the same in every direction: E = I cos(theta) / d^2.
// - directional: irradiance E in W/m^2 on a surface facing it (perpendicular to `direction`);
//   a surface tilted by theta gets E cos(theta).
// - distant: an environment at infinity sending radiance L in W/(m^2 sr) from every direction
//   above the horizon (directions with world z > 0), none from below. An unoccluded surface facing
//   up receives E = pi L. The scene's `directions: N` is the resolution an estimator may use; the
//   true environment rendered here is continuous and uniform.
#pragma once

#include <limits>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/result.h"
#include "core/scene.h"

namespace commonlight::mocks::sim {

enum class LightKind { kRectangle, kDisc, kPoint, kDirectional };

// A light that next-event estimation samples. Distant environments are not in this list: rays
// that leave the scene find them (SimScene::environmentRadiance).
struct SimLight {
    LightKind kind = LightKind::kPoint;
    std::string name;
    int scene_index = -1;  // index in Scene::lights
    // Radiance W/(m^2 sr) (rectangle, disc), intensity W/sr (point), irradiance W/m^2 (directional).
    Eigen::Vector3d emission = Eigen::Vector3d::Zero();
    Eigen::Vector3d position = Eigen::Vector3d::Zero();     // centre (rectangle, disc), position (point)
    Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();      // emitting side (rectangle, disc), unit
    Eigen::Vector3d half_x = Eigen::Vector3d::Zero();       // rectangle: half extent along its x; disc: radius * x axis
    Eigen::Vector3d half_y = Eigen::Vector3d::Zero();       // rectangle: half extent along its y; disc: radius * y axis
    double area = 0.0;                                      // m^2 (rectangle, disc)
    Eigen::Vector3d direction = -Eigen::Vector3d::UnitZ();  // directional: unit direction of travel

    bool isDelta() const noexcept { return kind == LightKind::kPoint || kind == LightKind::kDirectional; }
};

// One light sample seen from a shading point.
struct LightSample {
    Eigen::Vector3d wi = Eigen::Vector3d::Zero();               // unit, from the shading point towards the light
    double distance = std::numeric_limits<double>::infinity();  // to the sampled point
    // Area lights: the radiance arriving along wi. Point: I / d^2. Directional: E. The estimate of
    // the reflected radiance is f * li * cos(theta_i) / pdf.
    Eigen::Vector3d li = Eigen::Vector3d::Zero();
    double pdf = 1.0;  // solid-angle density (area lights); 1 for delta lights
};

// Builds the lights of a scene. Fails (kBadInput, naming the light) when a light's emission is
// `estimate`: rendering needs the true value. Distant lights are skipped (see environmentRadiance);
// rectangles and discs of zero area are skipped too: they emit no power.
Result<std::vector<SimLight>> makeSimLights(const Scene& scene);
// The sum of the radiances of the scene's distant lights (W/(m^2 sr) per channel), the radiance a
// ray escaping upwards sees. Fails like makeSimLights for an `estimate`.
Result<Eigen::Vector3d> makeEnvironmentRadiance(const Scene& scene);

// Samples a point of the light for the shading point p: rectangles uniformly in the solid angle
// they subtend at p (uniformly by area when that is below 1e-5 sr, where the spherical
// parametrization loses precision), discs uniformly by area. nullopt when the sample carries
// nothing: p behind (or in) the light's emitting side, at the light's position, or a density too
// small to divide by (hard cases, all "no light" rather than an infinity).
std::optional<LightSample> sampleLight(const SimLight& light, const Eigen::Vector3d& p,
                                       const Eigen::Vector2d& u) noexcept;

// The solid-angle density with which sampleLight picks the point p_light of an area light (hit by a
// ray from p along unit wi), for the MIS weight of a BSDF-sampled hit. Zero for delta lights,
// points behind the light or degenerate configurations.
double areaLightPdf(const SimLight& light, const Eigen::Vector3d& p, const Eigen::Vector3d& p_light,
                    const Eigen::Vector3d& wi) noexcept;

}  // namespace commonlight::mocks::sim

// Reflectance models of the simulated scene: Lambertian (real surfaces, tags, virtual objects)
// and GGX microfacet reflection (virtual objects with `type: ggx`).
//
// Everything here works in a local shading frame whose z axis is the surface normal turned
// towards the outgoing direction: the caller flips the normal to the side the ray came from, so
// every surface reflects on both sides (a plane is a thin sheet with the same albedo on both faces).
// Directions point away from the surface: wo towards the viewer, wi towards the light.
#pragma once

#include <optional>

#include <Eigen/Core>

namespace commonlight::mocks::sim {

enum class BsdfKind { kLambertian, kGgx };

// A reflectance at one surface point.
//
// Lambertian: f = albedo / pi.
// GGX (Trowbridge-Reitz) metal-like reflection: f = D(h) G(wo, wi) F(wi . h) / (4 cos_o cos_i) with
//   D = alpha^2 / (pi ((n.h)^2 (alpha^2 - 1) + 1)^2), alpha = roughness^2 (clamped to >= 1e-3 so the
//   lobe never becomes a delta the light sampling cannot see),
//   G = G1(wo) G1(wi), Smith's separable masking-shadowing for GGX,
//   F = F0 + (1 - F0)(1 - wi.h)^5 (Schlick) with F0 = albedo per channel.
// There is no diffuse layer and no multiple scattering between microfacets, as in most real-time
// renderers: a rough GGX surface loses energy. Directional albedo with F0 = 1 at normal incidence:
// 1.00 at roughness 0.05, 0.99 at 0.3, 0.83 at 0.6, 0.31 (= 1 - ln 2) at roughness 1.
struct Bsdf {
    BsdfKind kind = BsdfKind::kLambertian;
    Eigen::Vector3d albedo = Eigen::Vector3d::Constant(0.5);  // in [0, 1] per channel
    double alpha = 0.25;                                      // GGX only

    static Bsdf lambertian(const Eigen::Vector3d& albedo) { return {BsdfKind::kLambertian, albedo, 0.0}; }
    static Bsdf ggx(const Eigen::Vector3d& f0, double roughness);

    // f(wo, wi) in 1/sr per channel; zero unless both directions are above the surface (z > 0).
    Eigen::Vector3d eval(const Eigen::Vector3d& wo, const Eigen::Vector3d& wi) const noexcept;
    // The solid-angle density with which sample() picks wi given wo.
    double pdf(const Eigen::Vector3d& wo, const Eigen::Vector3d& wi) const noexcept;

    struct Sample {
        Eigen::Vector3d wi;      // local frame, unit, wi.z > 0
        Eigen::Vector3d weight;  // f(wo, wi) cos(theta_i) / pdf
        double pdf = 0.0;        // solid angle, > 0
    };
    // Draws wi for the uniform point u; nullopt when the drawn direction is below the surface (GGX)
    // or its density is too small to divide by (the path is then absorbed: this is unbiased, the
    // estimator's value for that sample is zero).
    std::optional<Sample> sample(const Eigen::Vector3d& wo, const Eigen::Vector2d& u) const noexcept;

    // True when nothing is reflected (light surfaces): the path ends there.
    bool isBlack() const noexcept { return albedo.maxCoeff() <= 0.0; }
};

}  // namespace commonlight::mocks::sim

#include "mocks/sim/materials.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "mocks/sim/sampling.h"

namespace commonlight::mocks::sim {

namespace {

constexpr double kInvPi = std::numbers::inv_pi;
// Densities below this are treated as "cannot be sampled": dividing by them would turn rounding
// noise into fireflies or infinities.
constexpr double kMinPdf = 1e-12;
constexpr double kMinAlpha = 1e-3;

// GGX normal distribution D(h) for cos(theta_h) = cos_h.
double ggxD(double cos_h, double alpha) noexcept {
    if (cos_h <= 0.0) return 0.0;
    const double a2 = alpha * alpha;
    const double c2 = cos_h * cos_h;
    const double denom = c2 * (a2 - 1.0) + 1.0;  // >= min(1, a2) > 0
    return a2 / (std::numbers::pi * denom * denom);
}

// G1(v) / (2 cos_v) for Smith-GGX: 1 / (cos_v + sqrt(a^2 + (1 - a^2) cos_v^2)). Written without the
// division by cos_v, so grazing directions (cos_v -> 0) stay finite: the denominator is >= alpha.
double smithG1OverTwoCos(double cos_v, double alpha) noexcept {
    const double a2 = alpha * alpha;
    return 1.0 / (cos_v + std::sqrt(a2 + (1.0 - a2) * cos_v * cos_v));
}

Eigen::Vector3d schlick(const Eigen::Vector3d& f0, double cos_d) noexcept {
    const double m = std::clamp(1.0 - cos_d, 0.0, 1.0);
    const double m5 = (m * m) * (m * m) * m;
    return f0 + (Eigen::Vector3d::Ones() - f0) * m5;
}

}  // namespace

Bsdf Bsdf::ggx(const Eigen::Vector3d& f0, double roughness) {
    return {BsdfKind::kGgx, f0, std::max(roughness * roughness, kMinAlpha)};
}

Eigen::Vector3d Bsdf::eval(const Eigen::Vector3d& wo, const Eigen::Vector3d& wi) const noexcept {
    if (wo.z() <= 0.0 || wi.z() <= 0.0) return Eigen::Vector3d::Zero();
    if (kind == BsdfKind::kLambertian) return albedo * kInvPi;
    const Eigen::Vector3d sum = wo + wi;
    const double len = sum.norm();
    // Hard case: wo = -wi cannot happen with both above the surface; guard anyway.
    if (len <= 1e-12) return Eigen::Vector3d::Zero();
    const Eigen::Vector3d h = sum / len;
    const double d = ggxD(h.z(), alpha);
    // D G F / (4 cos_o cos_i) = D F (G1(wo) / 2 cos_o) (G1(wi) / 2 cos_i).
    const double g = smithG1OverTwoCos(wo.z(), alpha) * smithG1OverTwoCos(wi.z(), alpha);
    return schlick(albedo, wi.dot(h)) * (d * g);
}

double Bsdf::pdf(const Eigen::Vector3d& wo, const Eigen::Vector3d& wi) const noexcept {
    if (wo.z() <= 0.0 || wi.z() <= 0.0) return 0.0;
    if (kind == BsdfKind::kLambertian) return wi.z() * kInvPi;
    const Eigen::Vector3d sum = wo + wi;
    const double len = sum.norm();
    if (len <= 1e-12) return 0.0;
    const Eigen::Vector3d h = sum / len;
    const double wo_h = wo.dot(h);
    // Hard case: wo nearly perpendicular to h makes the Jacobian 1 / (4 wo.h) blow up.
    if (wo_h <= 1e-12) return 0.0;
    return ggxD(h.z(), alpha) * h.z() / (4.0 * wo_h);
}

std::optional<Bsdf::Sample> Bsdf::sample(const Eigen::Vector3d& wo, const Eigen::Vector2d& u) const noexcept {
    if (wo.z() <= 0.0) return std::nullopt;
    Sample s;
    if (kind == BsdfKind::kLambertian) {
        s.wi = cosineHemisphere(u);
        s.pdf = s.wi.z() * kInvPi;
        // Hard case: a direction at the horizon has zero density and contributes nothing.
        if (s.pdf <= kMinPdf) return std::nullopt;
        s.weight = albedo;  // (albedo / pi) cos / (cos / pi)
        return s;
    }
    // Sample h with density D(h) cos(theta_h): tan^2(theta) = alpha^2 u / (1 - u).
    const double u1 = std::min(u.x(), 1.0 - 1e-12);
    const double tan2 = alpha * alpha * u1 / (1.0 - u1);
    const double cos_h = 1.0 / std::sqrt(1.0 + tan2);
    const double sin_h = std::sqrt(std::max(0.0, 1.0 - cos_h * cos_h));
    const double phi = 2.0 * std::numbers::pi * u.y();
    const Eigen::Vector3d h(sin_h * std::cos(phi), sin_h * std::sin(phi), cos_h);
    const double wo_h = wo.dot(h);
    if (wo_h <= 1e-12) return std::nullopt;
    s.wi = 2.0 * wo_h * h - wo;
    if (s.wi.z() <= 0.0) return std::nullopt;  // reflected below the surface: absorbed
    s.pdf = pdf(wo, s.wi);
    if (s.pdf <= kMinPdf) return std::nullopt;
    s.weight = eval(wo, s.wi) * (s.wi.z() / s.pdf);
    return s;
}

}  // namespace commonlight::mocks::sim

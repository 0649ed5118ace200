#include "render/ggx_albedo.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numbers>

namespace commonlight::render {

namespace {

// Radical inverse in base 2: the second coordinate of the Hammersley point set.
double radicalInverse2(std::uint32_t bits) {
    bits = (bits << 16u) | (bits >> 16u);
    bits = ((bits & 0x55555555u) << 1u) | ((bits & 0xAAAAAAAAu) >> 1u);
    bits = ((bits & 0x33333333u) << 2u) | ((bits & 0xCCCCCCCCu) >> 2u);
    bits = ((bits & 0x0F0F0F0Fu) << 4u) | ((bits & 0xF0F0F0F0u) >> 4u);
    bits = ((bits & 0x00FF00FFu) << 8u) | ((bits & 0xFF00FF00u) >> 8u);
    return static_cast<double>(bits) * 2.3283064365386963e-10;  // / 2^32
}

// G1(v) for GGX (Smith): 2 cos_v / (cos_v + sqrt(a^2 + (1 - a^2) cos_v^2)); 0 at the horizon.
double smithG1(double cos_v, double a2) { return 2.0 * cos_v / (cos_v + std::sqrt(a2 + (1.0 - a2) * cos_v * cos_v)); }

}  // namespace

Eigen::Vector2d ggxAlbedoSplit(double cos_o, double roughness, int samples) {
    cos_o = std::clamp(cos_o, 1e-4, 1.0);
    roughness = std::clamp(roughness, 0.0, 1.0);
    samples = std::max(samples, 1);
    const double a = std::max(roughness * roughness, kGgxMinAlpha);
    const double a2 = a * a;
    const Eigen::Vector3d wo(std::sqrt(1.0 - cos_o * cos_o), 0.0, cos_o);
    // Half vectors drawn from the normals visible from wo (Heitz 2018, "Sampling the GGX
    // distribution of visible normals"): the density of wi is D G1(wo) (wo.h) / (4 cos_o (wo.h)),
    // so f cos_i / pdf = F G1(wi): bounded by 1, where drawing from D alone gives weights that
    // grow without bound at grazing views. In the lobe's stretched space (x, y scaled by 1 / a)
    // the visible normals are a uniform disc projected onto the hemisphere around wo.
    const Eigen::Vector3d v = Eigen::Vector3d(a * wo.x(), a * wo.y(), wo.z()).normalized();
    const double len_xy = std::hypot(v.x(), v.y());
    // Hard case: a view along the normal has no preferred direction in the plane.
    const Eigen::Vector3d t1 =
        len_xy > 1e-12 ? Eigen::Vector3d(-v.y() / len_xy, v.x() / len_xy, 0.0) : Eigen::Vector3d::UnitX();
    const Eigen::Vector3d t2 = v.cross(t1);
    const double squash = 0.5 * (1.0 + v.z());  // the disc's half hidden behind the lobe, folded away
    double sum_a = 0.0, sum_b = 0.0;
    for (int k = 0; k < samples; ++k) {
        const double r = std::sqrt((k + 0.5) / samples);
        const double phi = 2.0 * std::numbers::pi * radicalInverse2(static_cast<std::uint32_t>(k));
        const double p1 = r * std::cos(phi);
        const double p2 = (1.0 - squash) * std::sqrt(std::max(0.0, 1.0 - p1 * p1)) + squash * r * std::sin(phi);
        const Eigen::Vector3d nh = p1 * t1 + p2 * t2 + std::sqrt(std::max(0.0, 1.0 - p1 * p1 - p2 * p2)) * v;
        const Eigen::Vector3d h = Eigen::Vector3d(a * nh.x(), a * nh.y(), std::max(0.0, nh.z())).normalized();
        const double wo_h = wo.dot(h);
        if (wo_h <= 0.0) continue;  // hard case: rounding at the lobe's edge
        const Eigen::Vector3d wi = 2.0 * wo_h * h - wo;
        // Hard case: wi below the surface: the microfacet's reflection is shadowed (G1(wi) = 0).
        if (wi.z() <= 0.0) continue;
        const double weight = smithG1(wi.z(), a2);
        const double m = 1.0 - wo_h;  // wi.h = wo.h for a mirror about h
        const double m5 = (m * m) * (m * m) * m;
        sum_a += weight * (1.0 - m5);
        sum_b += weight * m5;
    }
    return Eigen::Vector2d(sum_a, sum_b) / samples;
}

std::vector<float> ggxAlbedoTable(int n, int samples) {
    n = std::max(n, 2);
    std::vector<float> table(static_cast<std::size_t>(2 * n * n));
    for (int r = 0; r < n; ++r) {
        for (int c = 0; c < n; ++c) {
            const Eigen::Vector2d ab =
                ggxAlbedoSplit(static_cast<double>(c) / (n - 1), static_cast<double>(r) / (n - 1), samples);
            table[static_cast<std::size_t>(2 * (r * n + c))] = static_cast<float>(ab.x());
            table[static_cast<std::size_t>(2 * (r * n + c) + 1)] = static_cast<float>(ab.y());
        }
    }
    return table;
}

}  // namespace commonlight::render

// The GGX lobe's directional albedo table (render/ggx_albedo.h) against an independent quadrature
// of the BRDF over the hemisphere, its convergence, and its hard cases.
#include "render/ggx_albedo.h"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

namespace commonlight::render {
namespace {

// f cos_i integrated over the hemisphere on a (theta_i, phi_i) midpoint grid, with the BRDF written
// here from its definition (D G F / (4 cos_o cos_i)): F0 = 1 gives A + B, F0 = 0 gives B.
double quadrature(double cos_o, double roughness, double f0) {
    const double a = std::max(roughness * roughness, kGgxMinAlpha);
    const double a2 = a * a;
    const double sin_o = std::sqrt(1.0 - cos_o * cos_o);
    const auto g1 = [&](double c) { return 2.0 * c / (c + std::sqrt(a2 + (1.0 - a2) * c * c)); };
    const int nt = 1200, np = 600;
    double sum = 0.0;
    for (int i = 0; i < nt; ++i) {
        const double theta = (i + 0.5) * (std::numbers::pi / 2) / nt;
        const double ci = std::cos(theta), si = std::sin(theta);
        for (int j = 0; j < np; ++j) {
            const double phi = (j + 0.5) * std::numbers::pi / np;  // symmetric about the plane of wo: half, doubled
            const double hx = si * std::cos(phi) + sin_o, hy = si * std::sin(phi), hz = ci + cos_o;
            const double len = std::sqrt(hx * hx + hy * hy + hz * hz);
            const double cos_h = hz / len;
            const double i_h = (si * std::cos(phi) * hx + si * std::sin(phi) * hy + ci * hz) / len;
            const double den = cos_h * cos_h * (a2 - 1.0) + 1.0;
            const double d = a2 / (std::numbers::pi * den * den);
            const double f = d * g1(cos_o) * g1(ci) * (f0 + (1.0 - f0) * std::pow(1.0 - i_h, 5)) / (4.0 * cos_o * ci);
            sum += f * ci * si;
        }
    }
    return 2.0 * sum * (std::numbers::pi / 2 / nt) * (std::numbers::pi / np);
}

TEST(GgxAlbedo, AgreesWithAQuadratureOfTheBrdf) {
    for (const double roughness : {0.4, 0.6, 1.0}) {
        for (const double cos_o : {1.0, 0.7, 0.3}) {
            const Eigen::Vector2d ab = ggxAlbedoSplit(cos_o, roughness, 4096);
            const double total = quadrature(cos_o, roughness, 1.0), b = quadrature(cos_o, roughness, 0.0);
            std::printf("  roughness %.1f cos_o %.1f: A + B %.4f (quadrature %.4f), B %.4f (%.4f)\n", roughness, cos_o,
                        ab.sum(), total, ab.y(), b);
            // The quadrature's own error (a grid over a peaked lobe) is below 0.1% here.
            EXPECT_NEAR(ab.sum(), total, 0.003 * total) << "roughness " << roughness << " cos_o " << cos_o;
            EXPECT_NEAR(ab.y(), b, 0.003 * total) << "roughness " << roughness << " cos_o " << cos_o;
        }
    }
}

TEST(GgxAlbedo, ASmoothLobeReflectsEverythingAndARoughOneLosesEnergy) {
    // F0 = 1, smooth, seen from above: a mirror.
    EXPECT_NEAR(ggxAlbedoSplit(1.0, 0.05, 4096).sum(), 1.0, 0.01);
    // No multiple scattering between microfacets: a rough lobe reflects less (1 - ln 2 would be
    // the rough limit of an isotropic Smith lobe at normal incidence for a = 1).
    const double rough = ggxAlbedoSplit(1.0, 1.0, 4096).sum();
    EXPECT_LT(rough, 0.9);
    EXPECT_GT(rough, 0.2);
    // Fresnel: at grazing view a share of what a dark F0 reflects comes from B.
    EXPECT_GT(ggxAlbedoSplit(0.1, 0.5, 4096).y(), ggxAlbedoSplit(1.0, 0.5, 4096).y());
}

TEST(GgxAlbedo, TheTableConvergesAtItsSampleCount) {
    // The compositor's table: 256 visible normals per entry, against 65 536, grazing views included.
    for (const double roughness : {0.05, 0.1, 0.4, 0.8, 1.0}) {
        for (const double cos_o : {0.0, 0.05, 0.5, 1.0}) {
            const Eigen::Vector2d few = ggxAlbedoSplit(cos_o, roughness, 256),
                                  many = ggxAlbedoSplit(cos_o, roughness, 65536);
            EXPECT_NEAR(few.sum(), many.sum(), 0.005 * many.sum()) << "roughness " << roughness << " cos_o " << cos_o;
            EXPECT_NEAR(few.y(), many.y(), 0.005 * many.sum()) << "roughness " << roughness << " cos_o " << cos_o;
        }
    }
    const std::vector<float> table = ggxAlbedoTable(8, 64);
    ASSERT_EQ(table.size(), 2u * 8 * 8);
    // Row r, column c: roughness r / 7, cos_o c / 7.
    const Eigen::Vector2d ab = ggxAlbedoSplit(3.0 / 7.0, 5.0 / 7.0, 64);
    EXPECT_FLOAT_EQ(table[2 * (5 * 8 + 3)], static_cast<float>(ab.x()));
    EXPECT_FLOAT_EQ(table[2 * (5 * 8 + 3) + 1], static_cast<float>(ab.y()));
}

// Hard cases: a grazing view (cos_o = 0) and a roughness of 0 (a delta lobe) stay finite and in [0, 1].
TEST(GgxAlbedo, GrazingViewsAndZeroRoughnessAreFinite) {
    for (const double cos_o : {0.0, 1e-9, -0.5}) {
        for (const double roughness : {0.0, 0.5, 1.0, 2.0}) {
            const Eigen::Vector2d ab = ggxAlbedoSplit(cos_o, roughness, 256);
            EXPECT_TRUE(ab.allFinite()) << cos_o << " " << roughness;
            EXPECT_GE(ab.minCoeff(), 0.0);
            EXPECT_LE(ab.sum(), 1.0 + 1e-9);
        }
    }
}

}  // namespace
}  // namespace commonlight::render

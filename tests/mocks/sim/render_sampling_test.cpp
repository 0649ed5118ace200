// Building blocks of the renderer: the sampler, the BSDFs, light sampling and the numerical
// guards (every division by a density is guarded: nothing may return NaN or infinity).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <random>
#include <set>
#include <vector>

#include <gtest/gtest.h>

#include "mocks/sim/lights.h"
#include "mocks/sim/materials.h"
#include "mocks/sim/sampling.h"
#include "mocks/sim/tag_texture.h"

namespace commonlight::mocks::sim {
namespace {

using Eigen::Vector2d;
using Eigen::Vector3d;

TEST(RenderSampler, PermutationIsABijection) {
    for (const std::uint32_t n : {1u, 2u, 3u, 7u, 64u, 100u, 1000u, 4097u}) {
        for (const std::uint64_t key : {0ull, 1ull, 0xdeadbeefcafef00dull}) {
            std::set<std::uint32_t> seen;
            for (std::uint32_t i = 0; i < n; ++i) {
                const std::uint32_t p = permuteIndex(i, n, key);
                ASSERT_LT(p, n);
                seen.insert(p);
            }
            EXPECT_EQ(seen.size(), n) << "n = " << n;
        }
    }
}

TEST(RenderSampler, EveryDimensionIsStratifiedAndDeterministic) {
    constexpr int kN = 64;
    const PixelSampler sampler(PixelSampler::pixelSeed(5, 2, 1234), kN);
    const PixelSampler same(PixelSampler::pixelSeed(5, 2, 1234), kN);
    const PixelSampler other(PixelSampler::pixelSeed(5, 2, 1235), kN);
    for (int dimension = 0; dimension < 20; ++dimension) {
        std::set<int> x_strata, y_strata;
        for (int i = 0; i < kN; ++i) {
            const Vector2d u = sampler.get2D(i, dimension);
            ASSERT_GE(u.minCoeff(), 0.0);
            ASSERT_LT(u.maxCoeff(), 1.0);
            EXPECT_EQ(u, same.get2D(i, dimension));
            EXPECT_NE(u, other.get2D(i, dimension));
            // N = 2^k: both coordinates of the shifted Hammersley set fill every 1/N interval once
            // (the shift moves the strata, so count them relative to it).
            x_strata.insert(static_cast<int>(std::floor(u.x() * kN)));
            y_strata.insert(static_cast<int>(std::floor(u.y() * kN)));
        }
        EXPECT_GE(x_strata.size(), kN - 1u) << "dimension " << dimension;
        EXPECT_GE(y_strata.size(), kN - 1u) << "dimension " << dimension;
    }
}

TEST(RenderSampler, ShadingFramesAreOrthonormal) {
    std::mt19937_64 rng(3);
    std::normal_distribution<double> normal;
    std::vector<Vector3d> normals = {Vector3d::UnitZ(), -Vector3d::UnitZ(), Vector3d::UnitX(),
                                     Vector3d(1e-9, 0, -1).normalized(), Vector3d(0, 1e-12, -1).normalized()};
    for (int i = 0; i < 100; ++i) normals.push_back(Vector3d(normal(rng), normal(rng), normal(rng)).normalized());
    for (const Vector3d& n : normals) {
        const ShadingFrame f = ShadingFrame::fromNormal(n);
        EXPECT_NEAR(f.t.norm(), 1.0, 1e-12);
        EXPECT_NEAR(f.b.norm(), 1.0, 1e-12);
        EXPECT_NEAR(f.t.dot(f.b), 0.0, 1e-12);
        EXPECT_NEAR(f.t.dot(n), 0.0, 1e-12);
        EXPECT_NEAR(f.b.dot(n), 0.0, 1e-12);
        EXPECT_NEAR(f.t.cross(f.b).dot(n), 1.0, 1e-12);  // right-handed
    }
}

TEST(RenderSampler, PowerHeuristicHardCases) {
    EXPECT_EQ(powerHeuristic(0.0, 0.0), 0.0);
    EXPECT_EQ(powerHeuristic(1e-300, 1e-300), 0.0);  // squares underflow: 0, not NaN
    EXPECT_EQ(powerHeuristic(1.0, 0.0), 1.0);
    EXPECT_DOUBLE_EQ(powerHeuristic(1.0, 1.0), 0.5);
    EXPECT_DOUBLE_EQ(powerHeuristic(2.0, 1.0) + powerHeuristic(1.0, 2.0), 1.0);
}

// Monte Carlo over the sampler: the mean BSDF weight (f cos / pdf) is the directional albedo.
double directionalAlbedo(const Bsdf& bsdf, const Vector3d& wo, int n = 65536) {
    const PixelSampler sampler(99, n);
    double sum = 0.0;
    for (int i = 0; i < n; ++i) {
        if (const auto s = bsdf.sample(wo, sampler.get2D(i, 0))) sum += s->weight.x();
    }
    return sum / n;
}

TEST(RenderBsdf, SamplesAgreeWithEvalAndPdf) {
    const std::vector<Bsdf> bsdfs = {Bsdf::lambertian(Vector3d(0.2, 0.5, 0.9)), Bsdf::ggx(Vector3d::Constant(0.9), 0.3),
                                     Bsdf::ggx(Vector3d(1.0, 0.7, 0.3), 1.0), Bsdf::ggx(Vector3d::Constant(0.5), 0.0)};
    const PixelSampler sampler(7, 256);
    for (const Bsdf& bsdf : bsdfs) {
        for (const double theta : {0.0, 0.7, 1.4, 1.5707}) {
            const Vector3d wo(std::sin(theta), 0.0, std::cos(theta));
            for (int i = 0; i < 256; ++i) {
                const auto s = bsdf.sample(wo, sampler.get2D(i, 1));
                if (!s) continue;
                ASSERT_TRUE(s->weight.allFinite());
                ASSERT_GT(s->pdf, 0.0);
                EXPECT_NEAR(s->pdf, bsdf.pdf(wo, s->wi), 1e-9 * s->pdf);
                const Vector3d expected = bsdf.eval(wo, s->wi) * s->wi.z() / s->pdf;
                EXPECT_LT((s->weight - expected).norm(), 1e-9 * (1.0 + expected.norm()));
                // Reciprocity.
                EXPECT_LT((bsdf.eval(wo, s->wi) - bsdf.eval(s->wi, wo)).norm(),
                          1e-9 * (1.0 + bsdf.eval(wo, s->wi).norm()));
            }
        }
    }
}

TEST(RenderBsdf, EnergyIsConserved) {
    // Lambertian: exactly its albedo. GGX with F0 = 1: at most 1 (no multiple scattering: less at
    // high roughness), close to 1 when smooth. At roughness 1 (alpha = 1, D = 1/pi) and normal
    // incidence the integral has a closed form: int_0^1 c / (1 + c) dc = 1 - ln 2.
    EXPECT_NEAR(directionalAlbedo(Bsdf::lambertian(Vector3d::Constant(0.7)), {0, 0, 1}), 0.7, 1e-9);
    EXPECT_NEAR(directionalAlbedo(Bsdf::ggx(Vector3d::Ones(), 1.0), {0, 0, 1}), 1.0 - std::log(2.0), 2e-3);
    for (const double roughness : {0.05, 0.3, 0.6, 1.0}) {
        for (const double theta : {0.0, 0.8, 1.4}) {
            const Vector3d wo(std::sin(theta), 0.0, std::cos(theta));
            const double a = directionalAlbedo(Bsdf::ggx(Vector3d::Ones(), roughness), wo);
            EXPECT_LE(a, 1.01) << "roughness " << roughness << " theta " << theta;
            if (roughness <= 0.3 && theta < 1.0) {
                EXPECT_GT(a, 0.93) << "roughness " << roughness << " theta " << theta;
            }
            std::printf("  GGX roughness %.2f, theta %.1f: directional albedo %.3f\n", roughness, theta, a);
        }
    }
}

TEST(RenderBsdf, DensityGuards) {
    const Bsdf lambert = Bsdf::lambertian(Vector3d::Ones());
    const Bsdf ggx = Bsdf::ggx(Vector3d::Ones(), 0.5);
    // A direction exactly at the horizon (u on the disc's edge) has density 0: no sample.
    EXPECT_FALSE(lambert.sample({0, 0, 1}, {1.0, 0.5}));
    // u.x -> 1 would make tan^2 infinite.
    for (const Bsdf& b : {lambert, ggx}) {
        for (const Vector2d& u :
             {Vector2d(std::nextafter(1.0, 0.0), 0.3), Vector2d(0.0, 0.0), Vector2d(0.5, 0.999999)}) {
            for (const Vector3d& wo : {Vector3d(0, 0, 1), Vector3d(1, 0, 1e-300).normalized(), Vector3d(1, 0, 1e-9)}) {
                if (const auto s = b.sample(wo.normalized(), u)) {
                    EXPECT_TRUE(s->weight.allFinite());
                    EXPECT_TRUE(std::isfinite(s->pdf));
                }
                EXPECT_TRUE(b.eval(wo.normalized(), {0, 0, 1}).allFinite());
                EXPECT_TRUE(std::isfinite(b.pdf(wo.normalized(), {0, 0, 1})));
            }
        }
    }
    // Below the surface: nothing.
    EXPECT_EQ(ggx.eval({0, 0, 1}, {0, 0, -1}), Vector3d::Zero());
    EXPECT_EQ(ggx.pdf({0, 0, -1}, {0, 0, 1}), 0.0);
}

SimLight rectangle(const Vector3d& centre, const Vector3d& half_x, const Vector3d& half_y) {
    SimLight light;
    light.kind = LightKind::kRectangle;
    light.emission = Vector3d::Ones();
    light.position = centre;
    light.half_x = half_x;
    light.half_y = half_y;
    light.normal = half_x.cross(half_y).normalized();
    light.area = 4.0 * half_x.norm() * half_y.norm();
    return light;
}

TEST(RenderLights, RectangleSamplesLieOnTheLightAndAgreeWithTheirPdf) {
    const SimLight light = rectangle({0.2, 0.1, 1.0}, {0.4, 0.0, 0.0}, {0.0, -0.25, 0.0});  // faces down
    const PixelSampler sampler(11, 1024);
    // Near (solid-angle sampling) and far (area sampling below 1e-5 sr).
    for (const Vector3d& p : {Vector3d(0, 0, 0.9), Vector3d(0.5, 0.3, 0.0), Vector3d(400, 0, -300)}) {
        double solid_angle = 0.0;
        for (int i = 0; i < 1024; ++i) {
            const auto s = sampleLight(light, p, sampler.get2D(i, 0));
            ASSERT_TRUE(s);
            const Vector3d q = p + s->distance * s->wi - light.position;
            EXPECT_NEAR(q.dot(light.normal), 0.0, 1e-9 * (1.0 + s->distance));
            EXPECT_LE(std::abs(q.dot(light.half_x.normalized())), light.half_x.norm() * (1 + 1e-9));
            EXPECT_LE(std::abs(q.dot(light.half_y.normalized())), light.half_y.norm() * (1 + 1e-9));
            EXPECT_NEAR(areaLightPdf(light, p, p + s->distance * s->wi, s->wi), s->pdf, 1e-6 * s->pdf);
            solid_angle += 1.0 / s->pdf / 1024;
        }
        // E[1 / pdf] is the solid angle: compare with A cos / d^2 integrated numerically.
        double reference = 0.0;
        constexpr int kGrid = 400;
        for (int a = 0; a < kGrid; ++a) {
            for (int b = 0; b < kGrid; ++b) {
                const Vector3d x = light.position + (2.0 * (a + 0.5) / kGrid - 1.0) * light.half_x +
                                   (2.0 * (b + 0.5) / kGrid - 1.0) * light.half_y;
                const Vector3d d = x - p;
                reference +=
                    light.area / (kGrid * kGrid) * std::abs(d.normalized().dot(light.normal)) / d.squaredNorm();
            }
        }
        EXPECT_NEAR(solid_angle, reference, 2e-3 * reference) << p.transpose();
    }
    // Behind the light and in its plane: nothing, and a zero density.
    EXPECT_FALSE(sampleLight(light, {0, 0, 2}, {0.5, 0.5}));
    EXPECT_FALSE(sampleLight(light, {3, 0, 1}, {0.5, 0.5}));
    EXPECT_EQ(areaLightPdf(light, {0, 0, 2}, {0.2, 0.1, 1.0}, {0, 0, -1}), 0.0);
}

TEST(RenderTagTexture, CellsFollowTheSceneConventions) {
    const auto texture = TagTexture::make("tag36h11", 3);
    ASSERT_TRUE(texture) << texture.error().message;
    EXPECT_EQ(texture->totalWidth(), 10);
    EXPECT_EQ(texture->widthAtBorder(), 8);
    PlacedTag tag;
    tag.texture = *texture;
    tag.size = 0.08;
    tag.half_extent = 0.05;  // 10 cells of 1 cm
    // The white border, then the black ring of the black square (tag36h11's layout).
    for (int i = 0; i < 10; ++i) {
        EXPECT_TRUE(texture->isWhite(i, 0) && texture->isWhite(0, i) && texture->isWhite(i, 9) &&
                    texture->isWhite(9, i));
        if (i >= 1 && i <= 8) {
            EXPECT_FALSE(texture->isWhite(i, 1) || texture->isWhite(1, i) || texture->isWhite(i, 8) ||
                         texture->isWhite(8, i));
        }
    }
    // Cell (column c, row r) of the image is at x = -0.05 + (c + 0.5) cm, y = 0.05 - (r + 0.5) cm:
    // the image's top row towards +y.
    for (int r = 0; r < 10; ++r) {
        for (int c = 0; c < 10; ++c) {
            const double x = -0.05 + (c + 0.5) * 0.01;
            const double y = 0.05 - (r + 0.5) * 0.01;
            EXPECT_EQ(tag.albedoAt(x, y), texture->isWhite(c, r) ? 0.8 : 0.04) << c << "," << r;
        }
    }
    EXPECT_FALSE(TagTexture::make("tag36h11", 587));
    EXPECT_FALSE(TagTexture::make("tag36h11", -1));
    // Ink spread: every black region grows (or shrinks) by the same distance along each
    // boundary's normal. Row 1 is black from column 1 to 8, row 0 (the border) white.
    for (const double spread : {0.1, -0.08}) {
        tag.ink_spread_cells = spread;
        const double cell = 0.01, eps = 1e-6;
        // The black square's left edge (between columns 0 and 1) on row 4: x = -0.04.
        const double y = 0.05 - 4.5 * cell;
        EXPECT_EQ(tag.albedoAt(-0.04 - spread * cell + eps, y), 0.04) << spread;
        EXPECT_EQ(tag.albedoAt(-0.04 - spread * cell - eps, y), 0.8) << spread;
        // The top edge (between rows 0 and 1) at column 4: y = 0.04, black below.
        const double x = -0.05 + 4.5 * cell;
        EXPECT_EQ(tag.albedoAt(x, 0.04 + spread * cell - eps), 0.04) << spread;
        EXPECT_EQ(tag.albedoAt(x, 0.04 + spread * cell + eps), 0.8) << spread;
        // Cell centres keep their colour.
        for (int r = 0; r < 10; ++r) {
            for (int c = 0; c < 10; ++c) {
                EXPECT_EQ(tag.albedoAt(-0.05 + (c + 0.5) * cell, 0.05 - (r + 0.5) * cell),
                          texture->isWhite(c, r) ? 0.8 : 0.04);
            }
        }
    }
    TagSet set;
    set.items.push_back({3, 0.08, Rigid3d()});
    EXPECT_FALSE(makePlacedTags(set, 0.3));
    auto placed = makePlacedTags(set, -0.05);
    ASSERT_TRUE(placed);
    EXPECT_EQ(placed->at(0).ink_spread_cells, -0.05);
    EXPECT_TRUE(TagTexture::make("tagStandard41h12", 2114));
}

}  // namespace
}  // namespace commonlight::mocks::sim

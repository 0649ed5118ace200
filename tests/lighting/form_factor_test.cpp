// Form factors against closed forms (Mitsuba-style: each with its tolerance and why).
#include "lighting/form_factor.h"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

namespace commonlight::lighting {
namespace {

using Eigen::Vector3d;

double areaAverage(const Vector3d& corner, const Vector3d& es, const Vector3d& et, const Vector3d& n,
                   const std::vector<Vector3d>& source, int order) {
    double f = 0.0;
    for (const QuadraturePoint& q : quadratureRule(corner, es, et, false, order)) {
        f += q.weight * pointToPolygon(q.x, n, source);
    }
    return f;
}

TEST(FormFactor, GaussRulesIntegratePolynomialsExactly) {
    for (int n = 1; n <= 8; ++n) {
        const auto x = gaussNodes(n);
        const auto w = gaussWeights(n);
        for (int degree = 0; degree <= 2 * n - 1; ++degree) {
            double sum = 0.0;
            for (int i = 0; i < n; ++i) sum += w[i] * std::pow(x[i], degree);
            EXPECT_NEAR(sum, 1.0 / (degree + 1), 1e-13) << "order " << n << " degree " << degree;
        }
    }
}

TEST(FormFactor, TriangleRuleWeightsSumToOneAndIntegrateLinearFunctions) {
    const Vector3d c(0, 0, 0), es(2, 0, 0), et(0, 1, 0);
    for (int n = 2; n <= 8; ++n) {
        double w = 0.0, sx = 0.0;
        for (const QuadraturePoint& q : quadratureRule(c, es, et, true, n)) {
            w += q.weight;
            sx += q.weight * q.x.x();
        }
        EXPECT_NEAR(w, 1.0, 1e-12);
        EXPECT_NEAR(sx, 2.0 / 3.0, 1e-12);  // centroid x of (0,0), (2,0), (0,1)
    }
}

// Point on the axis of a disc of radius r at height h: F = r^2 / (r^2 + h^2) (exact). The disc
// as a 256-gon: the polygon's area deficit is 1e-4, so 2e-4 relative.
TEST(FormFactor, PointUnderDiscMatchesClosedForm) {
    std::vector<Vector3d> disc;
    const double r = 0.3;
    for (int k = 0; k < 256; ++k) {
        const double a = 2.0 * std::numbers::pi * k / 256;
        disc.emplace_back(r * std::cos(a), r * std::sin(a), 0.0);
    }
    for (double h : {0.05, 0.4, 2.0}) {
        const double f = pointToPolygon(Vector3d(0, 0, -h), Vector3d::UnitZ(), disc);
        EXPECT_NEAR(f, r * r / (r * r + h * h), 2e-4 * f) << "h " << h;
    }
}

// A point to a sphere, against the integral of cos(theta) / pi over the directions of the sphere's
// cone above the point's horizon (a 400 x 400 midpoint rule in cos and azimuth): wholly above,
// crossing the horizon at several heights and distances (touching included), wholly below.
TEST(FormFactor, PointToSphereMatchesTheIntegralOverItsVisiblePart) {
    const auto integral = [](double h, double phi) {
        const double alpha = std::asin(1.0 / h);
        const Vector3d axis(std::sin(phi), 0.0, std::cos(phi)), u(std::cos(phi), 0.0, -std::sin(phi)), v(0.0, 1.0, 0.0);
        const int n = 400;
        double sum = 0.0;
        for (int i = 0; i < n; ++i) {
            const double ca = 1.0 - (1.0 - std::cos(alpha)) * (i + 0.5) / n, sa = std::sqrt(1.0 - ca * ca);
            for (int j = 0; j < n; ++j) {
                const double p = 2.0 * std::numbers::pi * (j + 0.5) / n;
                sum += std::max(0.0, (ca * axis + sa * (std::cos(p) * u + std::sin(p) * v)).z());
            }
        }
        return sum * 2.0 * std::numbers::pi * (1.0 - std::cos(alpha)) / (n * n) / std::numbers::pi;
    };
    int crossing = 0;
    for (double h : {1.0001, 1.05, 1.5, 3.0, 10.0}) {
        for (double phi : {0.0, 0.3, 1.0, 1.4, 1.5707, 1.8, 2.2, 3.0}) {
            const double f = pointToSphere(0.2 * h, 0.2, std::cos(phi));
            EXPECT_NEAR(f, integral(h, phi), 2e-5 + 1e-4 * f) << "H " << h << " phi " << phi;
            if (phi > std::acos(1.0 / h) && phi < std::numbers::pi / 2 + std::asin(1.0 / h)) ++crossing;
        }
    }
    EXPECT_GT(crossing, 10);
    EXPECT_DOUBLE_EQ(pointToSphere(1.0, 0.1, 1.0), 0.01);  // straight above: R^2 / d^2
    EXPECT_EQ(pointToSphere(1.0, 0.1, -1.0), 0.0);
    EXPECT_TRUE(std::isfinite(pointToSphere(0.05, 0.1, 0.0)));  // inside: on its surface
}

// Differential area parallel to a rectangle, under its corner (Howell's catalogue B-3):
// F = 1/(2 pi) [ X/sqrt(1+X^2) atan(Y/sqrt(1+X^2)) + Y/sqrt(1+Y^2) atan(X/sqrt(1+Y^2)) ].
TEST(FormFactor, PointUnderRectangleCornerMatchesHowell) {
    const double a = 0.7, b = 0.4, c = 0.5;
    const std::vector<Vector3d> rect{{0, 0, c}, {a, 0, c}, {a, b, c}, {0, b, c}};
    const double X = a / c, Y = b / c;
    const double expected = 1.0 / (2.0 * std::numbers::pi) *
                            (X / std::sqrt(1 + X * X) * std::atan(Y / std::sqrt(1 + X * X)) +
                             Y / std::sqrt(1 + Y * Y) * std::atan(X / std::sqrt(1 + Y * Y)));
    EXPECT_NEAR(pointToPolygon(Vector3d::Zero(), Vector3d::UnitZ(), rect), expected, 1e-12);
}

// Two unit squares sharing an edge at 90 degrees: F = 0.20004 (Howell C-14). The point form
// factor varies like log(distance to the shared edge), so the receiver rule needs order 8 here;
// the bound is 1%, the rule gets much closer.
TEST(FormFactor, AdjacentPerpendicularUnitSquares) {
    const std::vector<Vector3d> source{{0, 0, 0}, {1, 0, 0}, {1, 0, 1}, {0, 0, 1}};
    const int order = formFactorRule(std::sqrt(0.5), 1.0, 1.0);
    EXPECT_EQ(order, 8);
    const double f = areaAverage(Vector3d::Zero(), Vector3d::UnitX(), Vector3d::UnitY(), Vector3d::UnitZ(), source, order);
    EXPECT_NEAR(f, 0.20004, 0.01 * 0.20004) << "F = " << f;
    RecordProperty("F_adjacent", std::to_string(f));
}

// Parallel unit squares at distance 1 (Howell C-11): F = 0.19982.
TEST(FormFactor, ParallelUnitSquares) {
    const std::vector<Vector3d> source{{0, 0, 1}, {1, 0, 1}, {1, 1, 1}, {0, 1, 1}};
    const double f = areaAverage(Vector3d::Zero(), Vector3d::UnitX(), Vector3d::UnitY(), Vector3d::UnitZ(), source, 4);
    EXPECT_NEAR(f, 0.19982, 1e-3 * 0.19982);
}

TEST(FormFactor, SourceBehindReceiverOrFacingAwayGivesZero) {
    const std::vector<Vector3d> square{{-1, -1, 1}, {1, -1, 1}, {1, 1, 1}, {-1, 1, 1}};
    EXPECT_EQ(pointToPolygon(Vector3d::Zero(), -Vector3d::UnitZ(), square), 0.0);
    // The square emits towards +z only: a receiver below it sees its back.
    EXPECT_EQ(pointToPolygon(Vector3d::Zero(), Vector3d::UnitZ(), square, Vector3d::UnitZ()), 0.0);
    EXPECT_GT(pointToPolygon(Vector3d::Zero(), Vector3d::UnitZ(), square, -Vector3d::UnitZ()), 0.0);
}

TEST(FormFactor, SourceCrossingTheHorizonCountsOnlyItsUpperPart) {
    // A vertical square straddling the receiver's plane: half above, half below.
    const std::vector<Vector3d> straddling{{-1, 1, -1}, {1, 1, -1}, {1, 1, 1}, {-1, 1, 1}};
    const std::vector<Vector3d> upper{{-1, 1, 0}, {1, 1, 0}, {1, 1, 1}, {-1, 1, 1}};
    EXPECT_NEAR(pointToPolygon(Vector3d::Zero(), Vector3d::UnitZ(), straddling),
                pointToPolygon(Vector3d::Zero(), Vector3d::UnitZ(), upper), 1e-12);
}

TEST(FormFactor, DegenerateInputsGiveFiniteZeroes) {
    const std::vector<Vector3d> square{{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
    // Receiver on the source's plane, at a vertex, inside it.
    for (const Vector3d& x : {Vector3d(0, 0, 0), Vector3d(0.5, 0.5, 0), Vector3d(2, 2, 0)}) {
        const double f = pointToPolygon(x, Vector3d::UnitZ(), square);
        EXPECT_TRUE(std::isfinite(f));
        EXPECT_LE(f, 1e-12);
    }
    const std::vector<Vector3d> degenerate{{0, 0, 1}, {1, 0, 1}, {2, 0, 1}};
    EXPECT_EQ(pointToPolygon(Vector3d::Zero(), Vector3d::UnitZ(), degenerate), 0.0);
    EXPECT_EQ(pointToPolygon(Vector3d::Zero(), Vector3d::UnitZ(), std::vector<Vector3d>{}), 0.0);
}

// A closed unit cube: from any interior point of a face, the five other faces' point form
// factors sum to exactly 1 (they tile the hemisphere), the basis of the furnace test.
TEST(FormFactor, FacesOfAClosedCubeSumToOne) {
    const std::vector<std::vector<Vector3d>> faces{
        {{0, 0, 1}, {1, 0, 1}, {1, 1, 1}, {0, 1, 1}}, {{1, 0, 0}, {1, 1, 0}, {1, 1, 1}, {1, 0, 1}},
        {{0, 0, 0}, {0, 1, 0}, {0, 1, 1}, {0, 0, 1}}, {{0, 1, 0}, {1, 1, 0}, {1, 1, 1}, {0, 1, 1}},
        {{0, 0, 0}, {1, 0, 0}, {1, 0, 1}, {0, 0, 1}}};
    for (const Vector3d& x : {Vector3d(0.5, 0.5, 0), Vector3d(0.01, 0.3, 0), Vector3d(0.999, 0.999, 0)}) {
        double sum = 0.0;
        for (const auto& f : faces) sum += pointToPolygon(x, Vector3d::UnitZ(), f);
        EXPECT_NEAR(sum, 1.0, 1e-9) << x.transpose();
    }
}

}  // namespace
}  // namespace commonlight::lighting

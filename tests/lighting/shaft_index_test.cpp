// The shaft index (lighting/shaft_index.h) against a brute-force scan, and the cone of balls as a
// conservative bound of the hull of a shaft's two ends; the hierarchy's collapse and re-activation.
#include "lighting/shaft_index.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <span>
#include <vector>
#include <random>

#include "lighting/hierarchy.h"

namespace commonlight::lighting {
namespace {

TEST(ShaftIndex, QueryEqualsABruteForceScan) {
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u(-2.0, 2.0), r(0.0, 0.4);
    std::vector<Shaft> shafts;
    for (int i = 0; i < 5000; ++i) {
        Shaft s;
        s.a = {u(rng), u(rng), u(rng)};
        s.b = {u(rng), u(rng), u(rng)};
        s.ra = r(rng);
        s.rb = r(rng);
        shafts.push_back(s);
    }
    auto index = ShaftIndex::build(shafts);
    ASSERT_TRUE(index) << index.error().message;
    for (int q = 0; q < 200; ++q) {
        const Ball ball{{u(rng), u(rng), u(rng)}, 0.02 + 0.2 * r(rng)};
        std::vector<int> found;
        (*index)->query(ball, found);
        std::sort(found.begin(), found.end());
        std::vector<int> expected;
        for (std::size_t i = 0; i < shafts.size(); ++i) {
            if (shaftMeetsBall(shafts[i], ball)) expected.push_back(static_cast<int>(i));
        }
        ASSERT_EQ(found, expected) << "query " << q;
    }
    // No shafts: an empty index answers nothing.
    auto empty = ShaftIndex::build({});
    ASSERT_TRUE(empty);
    std::vector<int> none;
    (*empty)->query(Ball{{0, 0, 0}, 10.0}, none);
    EXPECT_TRUE(none.empty());
}

// shaftMeetsBall() against the minimum over the axis, sampled densely, of the distance to the
// centre of the cone's ball there minus that ball's radius: shafts whose ends' balls hold each
// other or nearly so, zero-length ones, and balls near the axis, near the surface and far.
TEST(ShaftIndex, ShaftTestEqualsTheSampledMinimum) {
    std::mt19937 rng(13);
    std::uniform_real_distribution<double> u(-1.0, 1.0), r(0.0, 0.5);
    int met = 0, missed = 0;
    for (int trial = 0; trial < 20000; ++trial) {
        Shaft s;
        s.a = {u(rng), u(rng), u(rng)};
        s.b = trial % 10 == 0 ? s.a : s.a + (trial % 7 == 0 ? 0.05 : 1.0) * Eigen::Vector3d(u(rng), u(rng), u(rng));
        s.ra = r(rng);
        s.rb = trial % 5 == 0 ? 0.0 : r(rng);
        const Ball ball{s.a + 0.5 * (s.b - s.a) + 0.5 * Eigen::Vector3d(u(rng), u(rng), u(rng)), trial % 3 == 0 ? 0.0 : 0.3 * r(rng)};
        double best = 1e300;
        constexpr int kSteps = 4000;
        for (int k = 0; k <= kSteps; ++k) {
            const double t = static_cast<double>(k) / kSteps;
            best = std::min(best, (ball.centre - (s.a + t * (s.b - s.a))).norm() - (s.ra + t * (s.rb - s.ra)));
        }
        // (The sampled minimum is within a step's slope of the true one: close calls are left out.)
        const double slack = 2.0 * ((s.b - s.a).norm() + std::abs(s.rb - s.ra)) / kSteps + 1e-9;
        if (std::abs(best - ball.radius) < slack) continue;
        const bool expected = best < ball.radius;
        ASSERT_EQ(shaftMeetsBall(s, ball), expected) << "trial " << trial;
        (expected ? met : missed)++;
    }
    EXPECT_GT(met, 3000);
    EXPECT_GT(missed, 3000);
}

// The calls the distance to the axis alone leaves open (the centre between the reach of the
// smaller and of the larger end's ball: a small element and a large source), decided by the
// bounds from the axis point nearest the centre: the same answer as the exact minimum of the
// convex g(u) (a golden-section search), met and missed, close calls left out.
TEST(ShaftIndex, ShaftTestBetweenTheEndsReachEqualsTheExactMinimum) {
    std::mt19937 rng(29);
    std::uniform_real_distribution<double> u(-1.0, 1.0), unit(0.0, 1.0);
    int met = 0, missed = 0;
    for (int trial = 0; trial < 20000; ++trial) {
        Shaft s;
        s.a = {u(rng), u(rng), u(rng)};
        s.b = s.a + (0.5 + 2.0 * unit(rng)) * Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized();
        s.ra = 0.02 * unit(rng);
        s.rb = 0.1 + 0.6 * unit(rng);
        if (trial % 2 == 0) std::swap(s.ra, s.rb), std::swap(s.a, s.b);
        const Eigen::Vector3d d = s.b - s.a;
        const Eigen::Vector3d side = d.unitOrthogonal();
        const Eigen::Vector3d other = d.normalized().cross(side);
        const double radius = trial % 3 == 0 ? 0.0 : 0.05 * unit(rng);
        const double near = std::min(s.ra, s.rb) + radius, far = std::max(s.ra, s.rb) + radius;
        const double off = near + unit(rng) * (far - near);
        const double turn = 6.283185307179586 * unit(rng);
        const Ball ball{s.a + unit(rng) * d + off * (std::cos(turn) * side + std::sin(turn) * other), radius};
        const auto g = [&](double t) { return (ball.centre - (s.a + t * d)).norm() - (s.ra + t * (s.rb - s.ra)); };
        double lo = 0.0, hi = 1.0;
        for (int k = 0; k < 200; ++k) {
            const double m1 = lo + (hi - lo) * 0.381966011250105, m2 = hi - (hi - lo) * 0.381966011250105;
            if (g(m1) < g(m2)) {
                hi = m2;
            } else {
                lo = m1;
            }
        }
        const double best = std::min({g(0.0), g(1.0), g(0.5 * (lo + hi))});
        if (std::abs(best - radius) < 1e-9) continue;
        const bool expected = best < radius;
        ASSERT_EQ(shaftMeetsBall(s, ball), expected) << "trial " << trial << " best " << best << " radius " << radius;
        (expected ? met : missed)++;
    }
    EXPECT_GT(met, 3000);
    EXPECT_GT(missed, 3000);
}

// Hard case of conservativeness: every point of the hull of two squares (random convex
// combinations of their points), with a tiny ball around it, is reported as meeting the shaft.
TEST(ShaftIndex, ConeOfBallsHoldsTheHullOfTheTwoEnds) {
    std::mt19937 rng(3);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    for (int trial = 0; trial < 50; ++trial) {
        // Two squares of different sizes, far apart and tilted, one much larger than the other.
        const Eigen::Vector3d ca(u(rng), u(rng), u(rng)), cb(3 + u(rng), u(rng), 2 * u(rng));
        const double ha = 0.05 + u(rng), hb = 0.01 + 0.1 * u(rng);
        const Eigen::Vector3d ea = Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized(), fa = ea.unitOrthogonal();
        const Eigen::Vector3d eb = Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized(), fb = eb.unitOrthogonal();
        const Shaft s{ca, cb, ha * std::sqrt(2.0), hb * std::sqrt(2.0)};
        for (int k = 0; k < 200; ++k) {
            const Eigen::Vector3d x = ca + ha * (2 * u(rng) - 1) * ea + ha * (2 * u(rng) - 1) * fa;
            const Eigen::Vector3d y = cb + hb * (2 * u(rng) - 1) * eb + hb * (2 * u(rng) - 1) * fb;
            const double t = u(rng);
            ASSERT_TRUE(shaftMeetsBall(s, Ball{(1 - t) * x + t * y, 1e-9})) << trial << " " << k;
        }
        // And a point well off the line between them is not.
        const Eigen::Vector3d off = 0.5 * (ca + cb) + 5.0 * (cb - ca).unitOrthogonal();
        EXPECT_FALSE(shaftMeetsBall(s, Ball{off, 0.1}));
        // The hull's face planes (both tests bound the hull; the influence asks both): every hull
        // point meets, the far point does not.
        const std::vector<Eigen::Vector3d> pa{ca - ha * ea - ha * fa, ca + ha * ea - ha * fa, ca + ha * ea + ha * fa, ca - ha * ea + ha * fa};
        const std::vector<Eigen::Vector3d> pb{cb - hb * eb - hb * fb, cb + hb * eb - hb * fb, cb + hb * eb + hb * fb, cb - hb * eb + hb * fb};
        for (int k = 0; k < 200; ++k) {
            const Eigen::Vector3d x = ca + ha * (2 * u(rng) - 1) * ea + ha * (2 * u(rng) - 1) * fa;
            const Eigen::Vector3d y = cb + hb * (2 * u(rng) - 1) * eb + hb * (2 * u(rng) - 1) * fb;
            const double t = u(rng);
            ASSERT_TRUE(hullMeetsBall(pa, pb, Ball{(1 - t) * x + t * y, 1e-9})) << trial << " " << k;
        }
        EXPECT_FALSE(hullMeetsBall(pa, pb, Ball{off, 0.1}));
        // A point light: the hull of a square and a point (a pyramid).
        const std::vector<Eigen::Vector3d> apex{cb};
        EXPECT_TRUE(hullMeetsBall(pa, apex, Ball{0.5 * (ca + cb), 1e-9}));
        EXPECT_FALSE(hullMeetsBall(pa, apex, Ball{off, 0.1}));
    }
}

// Two randomly placed and turned squares a little apart (the draws in a fixed order), and the
// second's centre alone (a square and a point).
struct SquarePair {
    std::vector<Eigen::Vector3d> pa, pb, apex;
};
SquarePair randomSquarePair(std::mt19937& rng, std::uniform_real_distribution<double>& u) {
    const Eigen::Vector3d ca(u(rng), u(rng), u(rng)), cb(1.5 + u(rng), u(rng), 2 * u(rng));
    const double ha = 0.05 + 0.3 * u(rng), hb = 0.01 + 0.3 * u(rng);
    const Eigen::Vector3d ea = Eigen::Vector3d(u(rng) - 0.5, u(rng) - 0.5, u(rng) - 0.5).normalized(), fa = ea.unitOrthogonal();
    const Eigen::Vector3d eb = Eigen::Vector3d(u(rng) - 0.5, u(rng) - 0.5, u(rng) - 0.5).normalized(), fb = eb.unitOrthogonal();
    return {{ca - ha * ea - ha * fa, ca + ha * ea - ha * fa, ca + ha * ea + ha * fa, ca - ha * ea + ha * fa},
            {cb - hb * eb - hb * fb, cb + hb * eb - hb * fb, cb + hb * eb + hb * fb, cb - hb * eb + hb * fb},
            {cb}};
}

// The hull's face planes found once answer as hullMeetsBall() does: on random pairs of squares
// (and a square and a point) against random balls, the same answer wherever the ball is not within
// the planes' slack of touching the hull; and never "misses" where hullMeetsBall() "meets".
TEST(ShaftIndex, HullPlanesAnswerAsTheHullTest) {
    std::mt19937 rng(31);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    int meets = 0, misses = 0;
    for (int trial = 0; trial < 200; ++trial) {
        const auto [pa, pb, apex] = randomSquarePair(rng, u);
        for (const auto& other : {pb, apex}) {
            const HullPlanes planes = HullPlanes::of(pa, other);
            ASSERT_GT(planes.count, 0);
            for (int k = 0; k < 100; ++k) {
                const Ball ball{Eigen::Vector3d(-0.5 + 3.5 * u(rng), -1.0 + 3.0 * u(rng), -1.0 + 4.0 * u(rng)), 0.2 * u(rng)};
                const bool exact = hullMeetsBall(pa, other, ball);
                EXPECT_TRUE(!exact || planes.meets(ball)) << trial << " " << k;  // conservative
                // Away from the boundary (the ball grown or shrunk by 1 mm gives the same answer): equal.
                const bool grown = hullMeetsBall(pa, other, Ball{ball.centre, ball.radius + 1e-3});
                const bool shrunk = ball.radius > 1e-3 && hullMeetsBall(pa, other, Ball{ball.centre, ball.radius - 1e-3});
                if (grown == exact && (ball.radius <= 1e-3 || shrunk == exact)) {
                    EXPECT_EQ(planes.meets(ball), exact) << trial << " " << k;
                }
                (exact ? meets : misses) += 1;
            }
        }
    }
    EXPECT_GT(meets, 500);
    EXPECT_GT(misses, 500);
}

// The hull found once (CachedHull: the influence's reach tests of a link at every move) answers
// exactly as hullMeetsBall(): random pairs of squares, and a square and a point, against random
// balls, many of them grazing the hull (a point of the hull's boundary region, the radius tiny).
TEST(ShaftIndex, CachedHullAnswersAsTheHullTest) {
    std::mt19937 rng(43);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    int meets = 0, misses = 0;
    for (int trial = 0; trial < 200; ++trial) {
        const auto [pa, pb, apex] = randomSquarePair(rng, u);
        for (const auto& other : {pb, apex}) {
            const CachedHull hull = CachedHull::of(pa, other);
            for (int k = 0; k < 200; ++k) {
                Ball ball{Eigen::Vector3d(-0.5 + 3.5 * u(rng), -1.0 + 3.0 * u(rng), -1.0 + 4.0 * u(rng)), 0.2 * u(rng)};
                if (k % 2 == 1) {
                    // Near a vertex of the hull, within a few millimetres.
                    const Eigen::Vector3d& v = k % 4 == 1 ? pa[static_cast<std::size_t>(k / 4) % 4] : other[static_cast<std::size_t>(k / 4) % other.size()];
                    ball = Ball{v + 0.004 * Eigen::Vector3d(u(rng) - 0.5, u(rng) - 0.5, u(rng) - 0.5), 0.002 * u(rng)};
                }
                const bool exact = hullMeetsBall(pa, other, ball);
                ASSERT_EQ(hull.meets(ball), exact) << trial << " " << k;
                (exact ? meets : misses) += 1;
            }
        }
    }
    EXPECT_GT(meets, 5000);
    EXPECT_GT(misses, 5000);
}

// A ball beyond a face plane by less than its round-off tolerance may still meet a segment between
// the ends (hullMeetsBall() tests the segments first): a square with a corner lifted within that
// tolerance (the plane of the other three is a face plane) and a point below it; a small ball over
// the lifted corner, its centre beyond the plane by its radius and a little more, meets the
// segment from that corner. The cached hull tests the segments there, and not for a ball well
// beyond the plane.
TEST(ShaftIndex, CachedHullTestsTheSegmentsOfABallJustBeyondAPlane) {
    for (const double lift : {2e-10, 5e-10, 8e-10}) {
        const std::vector<Eigen::Vector3d> pa{{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, lift}};
        const std::vector<Eigen::Vector3d> apex{{0.5, 0.5, -1.0}};
        const CachedHull hull = CachedHull::of(pa, apex);
        const double r = 0.01;
        const Ball touching{{0.0, 1.0, lift + r - 0.1 * lift}, r};  // beyond z = 0 by r + 0.9 lift
        ASSERT_TRUE(hullMeetsBall(pa, apex, touching)) << lift;
        EXPECT_TRUE(hull.meets(touching)) << lift;
        const Ball beyond{{0.0, 1.0, r + 1e-3}, r};
        ASSERT_FALSE(hullMeetsBall(pa, apex, beyond)) << lift;
        EXPECT_FALSE(hull.meets(beyond)) << lift;
    }
}

// The face planes CachedHull keeps are exactly those a plain enumeration finds: every candidate
// (each end's plane, every edge of one end with a vertex of the other), normalised, a face plane
// when no vertex lies beyond the round-off tolerance on both sides, in the same order and bit for
// bit. On random squares, squares that share an edge, coplanar squares and a square and a point:
// ends that touch leave vertices within round-off of a plane, where a test that ends early must
// still keep every face plane.
std::vector<std::array<double, 4>> referenceFacePlanes(std::span<const Eigen::Vector3d> a, std::span<const Eigen::Vector3d> b) {
    std::vector<std::array<double, 4>> out;
    const auto consider = [&](const Eigen::Vector3d& origin, Eigen::Vector3d n) {
        const double length2 = n.squaredNorm();
        if (!(length2 > 1e-30)) return;
        n /= std::sqrt(length2);
        double lo = 0.0, hi = 0.0;
        for (const auto& end : {a, b}) {
            for (const Eigen::Vector3d& x : end) {
                const double s = (x - origin).dot(n);
                lo = std::min(lo, s);
                hi = std::max(hi, s);
            }
        }
        const double tol = 1e-9 * std::max(1.0, hi - lo);
        if (hi > tol && lo < -tol) return;
        if (hi > tol) n = -n;
        out.push_back({n.x(), n.y(), n.z(), n.dot(origin)});
    };
    for (int pass = 0; pass < 2; ++pass) {
        const std::span<const Eigen::Vector3d> p = pass == 0 ? a : b, q = pass == 0 ? b : a;
        const std::size_t n = p.size();
        if (n >= 3) consider(p[0], (p[1] - p[0]).cross(p[2] - p[0]));
        if (n < 2) continue;
        for (std::size_t i = 0; i < (n == 2 ? 1 : n); ++i) {
            for (const Eigen::Vector3d& r : q) consider(p[i], (p[(i + 1) % n] - p[i]).cross(r - p[i]));
        }
    }
    return out;
}

TEST(ShaftIndex, CachedHullKeepsEveryFacePlane) {
    std::mt19937 rng(59);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    int touching_planes = 0;
    for (int trial = 0; trial < 300; ++trial) {
        auto [pa, pb, apex] = randomSquarePair(rng, u);
        if (trial % 3 == 1) {
            // pb turned about pa's first edge: they share it (a fold between neighbouring faces).
            const Eigen::Vector3d axis = (pa[1] - pa[0]).normalized();
            const Eigen::AngleAxisd turn(0.3 + 2.5 * u(rng), axis);
            pb = {pa[1], pa[0], pa[0] + turn * (pa[3] - pa[0]), pa[1] + turn * (pa[2] - pa[1])};
        } else if (trial % 3 == 2) {
            // pb in pa's plane, beside it (neighbouring elements of one face).
            const Eigen::Vector3d step = (pa[1] - pa[0]) * (1.0 + u(rng));
            pb = {pa[0] + step, pa[1] + step, pa[2] + step, pa[3] + step};
        }
        for (const auto& other : {pb, apex}) {
            const CachedHull hull = CachedHull::of(pa, other);
            const std::vector<std::array<double, 4>> expected = referenceFacePlanes(pa, other);
            ASSERT_EQ(hull.planeCount(), expected.size()) << trial;
            for (std::size_t i = 0; i < expected.size(); ++i) ASSERT_EQ(hull.plane(i), expected[i]) << trial << " " << i;
            if (trial % 3 != 0) touching_planes += static_cast<int>(expected.size());
        }
    }
    EXPECT_GT(touching_planes, 1000);
}

// The clearances by which an object's cached shafts are left alone while it moves
// (InfluenceOptions::idle_cached_pairs): shaftClearance() is the sampled minimum of the cone's
// distance less the ball's radius; a ball moved by less than a positive clearance (shaft, hull
// planes) still misses, and one moved by less than a segment's depth still meets it; moved by
// 1.5 times the clearance straight towards the nearest point, most meet.
TEST(ShaftIndex, ClearancesBoundHowFarABallMayMove) {
    std::mt19937 rng(17);
    std::uniform_real_distribution<double> u(-1.0, 1.0), r(0.0, 0.4), unit(0.0, 1.0);
    const auto towards = [&](double length) -> Eigen::Vector3d { return length * Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized(); };
    int shaft_clear = 0, shaft_reached = 0, hull_clear = 0, hull_reached = 0, deep = 0;
    for (int trial = 0; trial < 4000; ++trial) {
        Shaft s;
        s.a = {u(rng), u(rng), u(rng)};
        s.b = s.a + Eigen::Vector3d(u(rng), u(rng), u(rng));
        s.ra = r(rng);
        s.rb = r(rng);
        const Ball ball{s.a + 0.5 * (s.b - s.a) + 1.5 * Eigen::Vector3d(u(rng), u(rng), u(rng)), 0.2 * r(rng)};
        // The cone: the clearance is the sampled minimum's, and a move shorter keeps the miss.
        double best = 1e300;
        double best_t = 0.0;
        constexpr int kSteps = 4000;
        for (int k = 0; k <= kSteps; ++k) {
            const double t = static_cast<double>(k) / kSteps;
            const double g = (ball.centre - (s.a + t * (s.b - s.a))).norm() - (s.ra + t * (s.rb - s.ra));
            if (g < best) best = g, best_t = t;
        }
        const double clear = shaftClearance(s, ball);
        ASSERT_NEAR(clear, best - ball.radius, 2.0 * ((s.b - s.a).norm() + std::abs(s.rb - s.ra)) / kSteps + 1e-9) << trial;
        if (clear > 1e-6) {
            ASSERT_FALSE(shaftMeetsBall(s, ball)) << trial;
            for (int k = 0; k < 20; ++k) {
                ASSERT_FALSE(shaftMeetsBall(s, Ball{ball.centre + towards((clear - 1e-9) * unit(rng)), ball.radius})) << trial << " " << k;
            }
            const Eigen::Vector3d nearest = s.a + best_t * (s.b - s.a);
            if (shaftMeetsBall(s, Ball{ball.centre + 1.5 * clear * (nearest - ball.centre).normalized(), ball.radius})) ++shaft_reached;
            ++shaft_clear;
        }
        // The segment between the ends' centres: met, it stays met over a move shorter than its depth.
        const Ball near{s.a + unit(rng) * (s.b - s.a) + towards(0.1 * unit(rng)), 0.1 * unit(rng)};
        const double depth = -segmentClearance(s.a, s.b, near);
        if (depth > 1e-9) {
            ASSERT_TRUE(segmentMeetsBall(s.a, s.b, near)) << trial;
            for (int k = 0; k < 20; ++k) {
                ASSERT_TRUE(segmentMeetsBall(s.a, s.b, Ball{near.centre + towards((depth - 1e-9) * unit(rng)), near.radius})) << trial << " " << k;
            }
            ++deep;
        }
        // The hull of two squares: the planes' clearance.
        const Eigen::Vector3d ea = Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized(), fa = ea.unitOrthogonal();
        const double ha = s.ra / std::sqrt(2.0), hb = s.rb / std::sqrt(2.0);
        const std::vector<Eigen::Vector3d> pa{s.a - ha * ea - ha * fa, s.a + ha * ea - ha * fa, s.a + ha * ea + ha * fa, s.a - ha * ea + ha * fa};
        const std::vector<Eigen::Vector3d> pb{s.b - hb * fa - hb * ea, s.b + hb * fa - hb * ea, s.b + hb * fa + hb * ea, s.b - hb * fa + hb * ea};
        const HullPlanes planes = HullPlanes::of(pa, pb);
        const double hull = planes.clearance(ball);
        if (hull > 1e-6) {
            ASSERT_FALSE(planes.meets(ball)) << trial;
            for (int k = 0; k < 20; ++k) {
                ASSERT_FALSE(planes.meets(Ball{ball.centre + towards((hull - 1e-6) * unit(rng)), ball.radius})) << trial << " " << k;
            }
            // Straight towards the hull's centre by 1.5 times the clearance: the farthest plane is crossed.
            const Eigen::Vector3d middle = 0.5 * (s.a + s.b);
            if (planes.clearance(Ball{ball.centre + 1.5 * hull * (middle - ball.centre).normalized(), ball.radius}) < 0.6 * hull) ++hull_reached;
            ++hull_clear;
        }
    }
    EXPECT_GT(shaft_clear, 1000);
    EXPECT_GT(shaft_reached, shaft_clear / 2) << "the shaft's clearance is the distance, not far below it";
    EXPECT_GT(hull_clear, 500);
    EXPECT_GT(hull_reached, hull_clear / 2);
    EXPECT_GT(deep, 200);
}

// The sleeping cached pairs' queue (VirtualInfluence's candidates) wakes at every travel exactly
// the entries a scan of every key would: keys spread over many binary orders, keys equal to a
// later travel, keys not above the last travel, small steps and jumps of the travel, and a travel
// that goes back (every entry compared).
TEST(SleepQueue, WakesExactlyTheEntriesTheTravelHasReached) {
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    SleepQueue queue;
    std::vector<std::pair<double, int>> plain;  // (key, value) of every entry asleep
    double travel = 0.0;
    queue.reset(travel);
    int next = 0;
    long woken_total = 0;
    for (int step = 0; step < 400; ++step) {
        // New entries: most a little ahead, some far ahead, some exactly at a coming travel, a few not
        // ahead at all (woken by the next wake).
        for (int n = 0; n < 40; ++n) {
            double key = travel + std::pow(10.0, -6.0 + 7.0 * unit(rng));
            if (n % 13 == 0) key = travel;
            if (n % 17 == 0) key = 1e300;
            if (n % 7 == 0) key = travel + 0.004 * static_cast<double>(1 + n % 3);
            queue.push(key, next);
            plain.emplace_back(key, next);
            ++next;
        }
        ASSERT_EQ(queue.size(), plain.size());
        if (step == 250) {
            travel *= 0.5;  // back
        } else if (step % 50 == 49) {
            travel += 3.0 * unit(rng);  // a jump
        } else {
            travel += 0.004 * static_cast<double>(1 + step % 3);  // keys set above land here exactly
        }
        std::vector<int> woken;
        queue.wake(travel, woken);
        std::vector<int> expected;
        std::vector<std::pair<double, int>> left;
        for (const auto& [key, value] : plain) {
            if (!(travel < key)) {
                expected.push_back(value);
            } else {
                left.emplace_back(key, value);
            }
        }
        plain.swap(left);
        std::sort(woken.begin(), woken.end());
        ASSERT_EQ(woken, expected) << "step " << step << ", travel " << travel;
        ASSERT_EQ(queue.size(), plain.size()) << "step " << step;
        woken_total += static_cast<long>(woken.size());
    }
    EXPECT_GT(woken_total, 4000);
    EXPECT_GT(plain.size(), 400u);  // the far keys stay asleep
    queue.reset(0.0);
    EXPECT_EQ(queue.size(), 0u);
    std::vector<int> none;
    queue.wake(1e301, none);
    EXPECT_TRUE(none.empty());
    // A wake to the same travel again takes the keys pushed at or below it since (bucket 0).
    queue.reset(2.0);
    queue.push(2.0, 7);
    queue.push(1.5, 8);
    queue.push(2.5, 9);
    std::vector<int> again;
    queue.wake(2.0, again);
    std::sort(again.begin(), again.end());
    EXPECT_EQ(again, (std::vector<int>{7, 8}));
    EXPECT_EQ(queue.size(), 1u);
}

// wakeInOrder() leaves the awake list ascending, the woken values put among those that stayed
// awake (what a sort of the woken and a merge give): values over many 64-bit words, a list that
// grows and shrinks, moves that wake nothing.
TEST(SleepQueue, WakeInOrderKeepsTheAwakeListAscending) {
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    SleepQueue queue;
    queue.reset(0.0);
    std::vector<int> awake;
    double travel = 0.0;
    for (int step = 0; step < 300; ++step) {
        // Some awake values go to sleep (the others stay), at keys ahead of the travel.
        std::vector<int> stay;
        for (const int v : awake) {
            if (unit(rng) < 0.4) {
                queue.push(travel + 0.02 * unit(rng) + 1e-9, v);
            } else {
                stay.push_back(v);
            }
        }
        awake = stay;
        if (step % 10 == 0) {
            for (int n = 0; n < 30; ++n) queue.push(travel + 0.05 * unit(rng) + 1e-9, 5000 * step / 10 + 97 * n + step % 7);
        }
        const std::vector<int> before = awake;
        travel += step % 5 == 4 ? 0.0 : 0.004;
        std::vector<int> woken;
        SleepQueue copy = queue;
        copy.wake(travel, woken);
        queue.wakeInOrder(travel, awake);
        std::vector<int> expected = before;
        expected.insert(expected.end(), woken.begin(), woken.end());
        std::sort(expected.begin(), expected.end());
        ASSERT_EQ(awake, expected) << "step " << step;
        ASSERT_EQ(queue.size(), copy.size()) << "step " << step;
    }
    EXPECT_GT(awake.size(), 20u);
}

TEST(Hierarchy, CollapseRetiresAndSubdivideBringsTheSameChildrenBack) {
    Face f;
    f.edge_s = Eigen::Vector3d(1, 0, 0);
    f.edge_t = Eigen::Vector3d(0, 1, 0);
    Hierarchy h({f});
    ASSERT_TRUE(h.subdivide(0, 0.01));
    const int first = h[0].first_child;
    ASSERT_TRUE(h.subdivide(first, 0.01));
    ASSERT_TRUE(h.subdivide(h[first].first_child, 0.01));
    EXPECT_EQ(h.leafCount(), 10);
    const std::size_t stored = h.storedCount();
    EXPECT_EQ(h.collapse(0), 9);
    EXPECT_EQ(h.leafCount(), 1);
    EXPECT_TRUE(h[0].leaf());
    for (std::size_t e = 1; e < stored; ++e) {
        EXPECT_TRUE(h[static_cast<int>(e)].retired) << e;
        EXPECT_FALSE(h[static_cast<int>(e)].leaf()) << e;  // a retired element is no leaf
    }
    std::vector<int> leaves;
    h.leavesUnder(0, leaves);
    EXPECT_EQ(leaves, std::vector<int>{0});
    EXPECT_EQ(h.leafAt(0, Eigen::Vector2d(0.1, 0.1)), 0);
    // The same split brings the same elements back, one level at a time; nothing new is stored.
    ASSERT_TRUE(h.subdivide(0, 0.01));
    EXPECT_EQ(h[0].first_child, first);
    EXPECT_EQ(h.leafCount(), 4);
    EXPECT_TRUE(h[first].leaf());
    ASSERT_TRUE(h.subdivide(first, 0.01));
    EXPECT_EQ(h.storedCount(), stored);
    // Repeated collapse and refinement stores nothing more.
    for (int round = 0; round < 100; ++round) {
        h.collapse(0);
        h.subdivide(0, 0.01);
        h.subdivide(h[0].first_child + round % 4, 0.01);
    }
    EXPECT_EQ(h.storedCount(), stored + 4 * 3);  // the three other children's splits, once each
    // A different split (coarser minimum size: the long side only) makes new children.
    Face thin = f;
    thin.edge_t = Eigen::Vector3d(0, 0.7, 0);
    Hierarchy g({thin});
    ASSERT_TRUE(g.subdivide(0, 0.01));
    EXPECT_EQ(g[0].child_count, 4);
    g.collapse(0);
    ASSERT_TRUE(g.subdivide(0, 0.4));
    EXPECT_EQ(g[0].child_count, 2);
    EXPECT_EQ(g.leafCount(), 2);
}

// A skewed parallelogram and a triangle on the same edges (the leaf searches' faces).
std::vector<Face> skewedQuadAndTriangle() {
    Face quad;
    quad.edge_s = Eigen::Vector3d(1.3, 0.2, 0);
    quad.edge_t = Eigen::Vector3d(0.4, 0.7, 0);
    Face tri = quad;
    tri.triangle = true;
    return {quad, tri};
}

// leafAt() descends through inverses kept per element (made with the element, not per visit): after
// splits, collapses, re-activated children and a different split, it finds the leaf whose own
// (s, t) parallelogram or triangle holds the point, on a skewed parallelogram and a triangle.
TEST(Hierarchy, LeafAtFindsTheLeafHoldingThePointThroughSplitsAndCollapses) {
    Hierarchy h(skewedQuadAndTriangle());
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    const auto splitSome = [&](double min_size, int count) {
        for (int n = 0; n < count; ++n) {
            const int face = n % 2;
            h.subdivide(h.leafAt(face, Eigen::Vector2d(u(rng), u(rng))), min_size);
        }
    };
    // The leaf holding (s, t) from scratch: its own inverse, taken here.
    const auto holding = [&](int face, const Eigen::Vector2d& st, int& found) {
        std::vector<int> leaves;
        h.leavesUnder(h.root(face), leaves);
        int count = 0;
        for (int l : leaves) {
            Eigen::Matrix2d m;
            m.col(0) = h[l].ds;
            m.col(1) = h[l].dt;
            const Eigen::Vector2d ab = m.inverse() * (st - h[l].st);
            const double margin = 1e-6;  // away from the borders: one leaf holds the point
            if (ab.minCoeff() > margin && (h[l].triangle ? ab.sum() : ab.maxCoeff()) < 1.0 - margin) {
                found = l;
                ++count;
            }
        }
        return count;
    };
    const auto check = [&](const char* stage) {
        int checked = 0;
        for (int n = 0; n < 2000; ++n) {
            const int face = n % 2;
            Eigen::Vector2d st(u(rng), u(rng));
            if (face == 1 && st.sum() > 1.0) st = Eigen::Vector2d(1.0, 1.0) - st;
            int found = -1;
            if (holding(face, st, found) != 1) continue;  // on a border
            ++checked;
            ASSERT_EQ(h.leafAt(face, st), found) << stage << " face " << face << " at (" << st.x() << ", " << st.y() << ")";
        }
        EXPECT_GT(checked, 1900) << stage;
    };
    splitSome(0.01, 300);
    check("split");
    h.collapse(h.root(0));
    h.collapse(h[h.root(1)].first_child + 1);
    check("collapsed");
    splitSome(0.01, 300);  // some retired children come back
    check("split again");
    h.collapse(h.root(0));
    splitSome(0.3, 50);  // coarser: other splits, new children
    check("split otherwise");
}

// leafAtAgain() (the probes' hits found from last move's leaf): the leaf leafAt() finds, through
// splits under the last leaf, collapses above it, retired children brought back and other splits
// made instead, for points inside leaves, on their shared borders (the descent's rounding
// fallback) and outside the face (clamped), on a skewed parallelogram and a triangle.
TEST(Hierarchy, LeafAtAgainFindsWhatLeafAtFindsThroughSplitsAndCollapses) {
    Hierarchy h(skewedQuadAndTriangle());
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    std::uniform_int_distribution<int> grid(-1, 17);
    struct Point {
        int face;
        Eigen::Vector2d st;
        int last;
    };
    std::vector<Point> points;
    for (int n = 0; n < 3000; ++n) {
        const int face = n % 2;
        // A third on the grid of sixteenths (the elements' corners and borders), some outside the face.
        const Eigen::Vector2d st = n % 3 == 0 ? Eigen::Vector2d(grid(rng) / 16.0, grid(rng) / 16.0) : Eigen::Vector2d(u(rng), u(rng));
        points.push_back({face, st, h.leafAt(face, st)});
    }
    std::vector<int> non_leaves;
    int descended = 0, restarted = 0;
    for (int round = 0; round < 40; ++round) {
        // Split some leaves, finer or coarser (another split of a collapsed element: new children).
        const double min_size = round % 5 == 4 ? 0.25 : 0.02;
        for (int n = 0; n < 60; ++n) {
            const int face = n % 2;
            h.subdivide(h.leafAt(face, Eigen::Vector2d(u(rng), u(rng))), min_size);
        }
        // Collapse a few elements above leaves (their children retired, some brought back later).
        non_leaves.clear();
        for (std::size_t e = 0; e < h.elements().size(); ++e) {
            if (!h[static_cast<int>(e)].retired && h[static_cast<int>(e)].child_count > 0) non_leaves.push_back(static_cast<int>(e));
        }
        for (int n = 0; n < 3 && !non_leaves.empty(); ++n) {
            h.collapse(non_leaves[std::uniform_int_distribution<std::size_t>(0, non_leaves.size() - 1)(rng)]);
        }
        for (Point& p : points) {
            const int want = h.leafAt(p.face, p.st);
            if (h[p.last].retired) ++restarted;
            else if (p.last != want) ++descended;
            const int got = h.leafAtAgain(p.face, p.st, p.last);
            ASSERT_EQ(got, want) << "round " << round << " face " << p.face << " at (" << p.st.x() << ", " << p.st.y() << ") last " << p.last;
            p.last = got;
        }
    }
    // Both ways were taken many times: on from a split last leaf, and from the root past a retired one.
    EXPECT_GT(descended, 1000);
    EXPECT_GT(restarted, 1000);
    // A leaf of the other face, or none: from the root.
    EXPECT_EQ(h.leafAtAgain(0, Eigen::Vector2d(0.3, 0.6), h.leafAt(1, Eigen::Vector2d(0.3, 0.6))), h.leafAt(0, Eigen::Vector2d(0.3, 0.6)));
    EXPECT_EQ(h.leafAtAgain(1, Eigen::Vector2d(0.2, 0.1), -1), h.leafAt(1, Eigen::Vector2d(0.2, 0.1)));
}

}  // namespace
}  // namespace commonlight::lighting

// A spatial index over shafts: the volumes between two elements (a link), or between an element
// and a light, in which an object can change the light one sends the other (Haines and Wallace
// 1991; seed 000 sec. 4.4 keeps "a hierarchy of shaft structures associated with the links").
//
// A shaft is bounded conservatively by a truncated cone of balls: the centres `a` and `b` of the
// two ends, the radii `ra` and `rb` of balls that hold them (an element's centroid and its
// largest distance to a corner). Every point of the convex hull of the two ends is
// (1 - u) x + u y with x in the first and y in the second end, which lies within
// (1 - u) ra + u rb of (1 - u) a + u b: the hull is inside the cone of balls.
//
// The index is a bounding-volume hierarchy built by Embree's BVH builder (rtcBuildBVH) over the
// shafts' bounding boxes (its low-quality Morton build: shaft_index.cpp); a query with a ball (a virtual object's bounding sphere) walks it and
// keeps the shafts whose cone of balls meets the ball. Built once per link structure (tens of
// milliseconds for 300 000 shafts), queried on every move (microseconds per hit).
#pragma once

#include <algorithm>
#include <array>
#include <bit>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/result.h"

namespace commonlight::lighting {

struct Shaft {
    Eigen::Vector3d a = Eigen::Vector3d::Zero();  // centre of the first end, world, metres
    Eigen::Vector3d b = Eigen::Vector3d::Zero();  // centre of the second end
    double ra = 0.0;                              // radius of a ball around `a` holding the first end
    double rb = 0.0;
};

// A ball (a virtual object's bounds), world, metres.
struct Ball {
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    double radius = 0.0;
};

// Whether the shaft's cone of balls meets the ball (conservative for the shaft itself: a false
// "meets" costs a visibility computation, a false "misses" would lose a shadow, and cannot happen).
bool shaftMeetsBall(const Shaft& shaft, const Ball& ball);
// How far the ball misses the shaft's cone of balls: min over the cone of the distance to the
// ball's centre, less its radius (<= 0 where they meet). It is 1-Lipschitz in the centre: a ball
// whose centre moves by less than this still misses (an object's cached shafts left alone while
// it moves: VirtualInfluence's candidates).
double shaftClearance(const Shaft& shaft, const Ball& ball);
// The distance from the ball's centre to the segment from p to q, less the ball's radius (< 0:
// they meet, and still do after the centre moves by less than its absolute value).
double segmentClearance(const Eigen::Vector3d& p, const Eigen::Vector3d& q, const Ball& ball);

// Whether the ball meets the convex hull of two convex polygons (or a polygon and a point: `b`
// of one vertex), by the hull's face planes (Haines and Wallace's shaft planes): every plane
// through an edge of one end and a vertex of the other, or through an end itself, that has every
// vertex on one side is a face plane; the ball misses the hull when one of them leaves it wholly
// outside. Conservative near the hull's edges (a ball just off an edge may count as meeting it).
// The index's cones are far looser for a large end (a ceiling panel seen from the floor): this is
// the test that decides.
bool hullMeetsBall(std::span<const Eigen::Vector3d> a, std::span<const Eigen::Vector3d> b, const Ball& ball);
// Whether the segment from p to q meets the ball (a sure "yes" for a hull that holds the segment).
bool segmentMeetsBall(const Eigen::Vector3d& p, const Eigen::Vector3d& q, const Ball& ball);

// The face planes of the hull hullMeetsBall() tests, found once (a shaft tested against many
// balls: an object's cached shafts, at every move). A ball misses the hull when it lies wholly
// outside one of them: the same answer as hullMeetsBall() but for round-off (the planes are kept in
// single precision and every ball is taken `kPlaneSlack` larger, so it stays conservative).
struct HullPlanes {
    static constexpr int kMax = 24;           // more face planes than this: the first kMax (a looser, still conservative test)
    static constexpr double kPlaneSlack = 1e-5;  // metres
    // (The count first: it shares a cache line with the first planes, read at once after it.)
    std::uint8_t count = 0;
    std::array<std::array<float, 4>, kMax> planes{};  // unit outward normal, offset: inside is n.x <= offset
    static HullPlanes of(std::span<const Eigen::Vector3d> a, std::span<const Eigen::Vector3d> b);
    bool meets(const Ball& ball) const {
        const float cx = static_cast<float>(ball.centre.x()), cy = static_cast<float>(ball.centre.y()), cz = static_cast<float>(ball.centre.z());
        const float r = static_cast<float>(ball.radius + kPlaneSlack);
        for (int i = 0; i < count; ++i) {
            const auto& p = planes[static_cast<std::size_t>(i)];
            if (p[0] * cx + p[1] * cy + p[2] * cz - p[3] > r) return false;
        }
        return true;
    }
    // How far the ball lies outside the farthest of the planes, beyond the slack meets() adds, in
    // double precision (> 0 only where meets() is false; 1-Lipschitz in the centre, the normals
    // being unit length to single precision).
    double clearance(const Ball& ball) const {
        double best = -1e300;
        for (int i = 0; i < count; ++i) {
            const auto& p = planes[static_cast<std::size_t>(i)];
            best = std::max(best, static_cast<double>(p[0]) * ball.centre.x() + static_cast<double>(p[1]) * ball.centre.y() +
                                      static_cast<double>(p[2]) * ball.centre.z() - static_cast<double>(p[3]));
        }
        return best - (ball.radius + kPlaneSlack);
    }
    // How far inside every plane's reach (ball radius and slack) the centre lies: the smallest
    // margin, in double precision (>= 0 only where meets() is true; a move shorter keeps it true).
    double depth(const Ball& ball) const { return -clearance(ball); }
};

// hullMeetsBall() with everything that depends on the two ends alone found once (a link's shaft
// tested at every move: VirtualInfluence's reach tests): the ends' means, the segments' ends and
// the face planes in double precision. The same answer as hullMeetsBall() (the same segments, the
// same face planes, the same strict comparison; a plane's offset is folded in, which changes the
// signed distance by round-off only).
struct CachedHull {
    Eigen::Vector3d ca = Eigen::Vector3d::Zero(), cb = Eigen::Vector3d::Zero();
    static constexpr std::size_t kMaxEnds = 4;                  // polygons of at most 4 vertices
    std::array<Eigen::Vector3d, kMaxEnds> ends_a{}, ends_b{};  // the two polygons' vertices
    std::uint8_t count_a = 0, count_b = 0;
    // The face planes (unit outward normal, offset) by component: every plane's n.x, then n.y,
    // n.z and the offsets (the loop over them in meets() two planes to an instruction).
    std::vector<double> planes;
    // How far beyond a face plane a ball's reach must lie for no segment between the ends to meet
    // it (those segments lie within the planes' round-off tolerance, far below this): meets() then
    // answers "no" without them.
    double beyond = 0.0;
    std::size_t planeCount() const { return planes.size() / 4; }
    std::array<double, 4> plane(std::size_t i) const {
        const std::size_t n = planeCount();
        return {planes[i], planes[n + i], planes[2 * n + i], planes[3 * n + i]};
    }
    // (Both ends of at most kMaxEnds vertices.)
    static CachedHull of(std::span<const Eigen::Vector3d> a, std::span<const Eigen::Vector3d> b);
    bool meets(const Ball& ball) const;
};

// Values left asleep until a travel that only grows reaches their keys (an object's cached pairs
// left alone: VirtualInfluence's candidates): a radix heap over the keys' bit patterns (those of
// non-negative doubles order as the numbers do). An entry lies in the bucket of the highest bit in
// which its key differs from `last`, the travel of the last wake(): a wake to travel T takes every
// bucket below the highest bit in which T differs from last (their keys are below T), compares the
// keys of that bit's bucket alone, and spreads those still above T over the lower buckets; the
// buckets above it stay (their keys are above T). An entry moves down at most once per bit, so a
// push and its wake cost a few operations instead of a binary heap's two passes over its depth.
class SleepQueue {
public:
    // Empty, with `travel` (>= 0) as the last wake's.
    void reset(double travel) {
        for (auto& bucket : buckets_) bucket.clear();
        last_ = travel;
        size_ = 0;
    }
    // Asleep until a wake to a travel >= key (a key not above the last wake's travel: the next wake).
    void push(double key, int value) {
        buckets_[key > last_ ? bucketOf(bitsOf(key), bitsOf(last_)) : 0].emplace_back(key, value);
        ++size_;
    }
    // Appends to `out` the value of every entry whose key the travel has reached (!(travel < key)),
    // in no particular order, and takes them out. `travel` below the last wake's (or NaN): every
    // entry compared.
    void wake(double travel, std::vector<int>& out);
    // wake() into `awake`, ascending and of distinct values none of which is asleep, kept ascending:
    // the values marked in a bit set and read back in order (no sort, no merge).
    void wakeInOrder(double travel, std::vector<int>& awake);
    std::size_t size() const noexcept { return size_; }

private:
    static std::uint64_t bitsOf(double x) { return std::bit_cast<std::uint64_t>(x + 0.0); }  // (-0 as +0)
    // 0 for equal patterns, else one more than the highest bit in which they differ.
    static int bucketOf(std::uint64_t key, std::uint64_t last) { return 64 - std::countl_zero(key ^ last); }
    std::array<std::vector<std::pair<double, int>>, 65> buckets_;
    double last_ = 0.0;
    std::size_t size_ = 0;
    std::vector<std::uint64_t> marks_;  // wakeInOrder()'s bit set, all zero between calls
};

class ShaftIndex {
public:
    // Builds the hierarchy over `shafts` (ids are their positions). Errors: Embree failed
    // (kInternal, with Embree's message).
    static Result<std::unique_ptr<ShaftIndex>> build(std::vector<Shaft> shafts);
    ~ShaftIndex();
    ShaftIndex(const ShaftIndex&) = delete;
    ShaftIndex& operator=(const ShaftIndex&) = delete;

    // Appends the ids of the shafts that meet `ball` (each once, in no particular order).
    // Thread-safe (read only).
    void query(const Ball& ball, std::vector<int>& out) const;
    std::size_t size() const noexcept { return shafts_.size(); }
    const Shaft& shaft(int id) const { return shafts_[static_cast<std::size_t>(id)]; }

private:
    struct Impl;
    ShaftIndex(std::unique_ptr<Impl> impl, std::vector<Shaft> shafts);
    std::unique_ptr<Impl> impl_;
    std::vector<Shaft> shafts_;
};

}  // namespace commonlight::lighting

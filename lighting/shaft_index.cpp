#include "lighting/shaft_index.h"

#include <embree3/rtcore.h>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif
#include <tbb/parallel_invoke.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <mutex>
#include <string>

namespace commonlight::lighting {

bool shaftMeetsBall(const Shaft& shaft, const Ball& ball) {
    // g(u) = |c - p(u)| - r(u), p(u) = a + u (b - a), r(u) = ra + u (rb - ra): the ball meets the
    // cone of balls when min over u in [0, 1] of g(u) <= ball.radius. g is convex (a distance to a
    // line point minus a linear function): its minimum is at an end or where g'(u) = 0, i.e.
    // (A u - B) / |c - p(u)| = dr with A = |b - a|^2, B = (c - a).(b - a), C = |c - a|^2, which
    // gives u* = B / A + dr sqrt(A C - B^2) / (A sqrt(A - dr^2)) when A > dr^2 (otherwise one end's
    // ball holds the other's and g is monotone: the ends decide).
    const Eigen::Vector3d d = shaft.b - shaft.a;
    const Eigen::Vector3d q = ball.centre - shaft.a;
    const double dr = shaft.rb - shaft.ra;
    const double A = d.squaredNorm(), B = q.dot(d), C = q.squaredNorm();
    // Most calls are decided by the distance s from the centre to the axis segment, without a
    // square root: min g lies between s - max(ra, rb) and s - min(ra, rb). (Margins of 1e-9,
    // far above round-off, leave the close calls to the exact minimum below.)
    {
        const double u = A > 0.0 ? std::clamp(B / A, 0.0, 1.0) : 0.0;
        const double s2 = (q - u * d).squaredNorm();
        const double far = std::max(shaft.ra, shaft.rb) + ball.radius;
        if (s2 > far * far * (1.0 + 1e-9)) return false;
        const double near = std::min(shaft.ra, shaft.rb) + ball.radius;
        if (near > 0.0 && s2 < near * near * (1.0 - 1e-9)) return true;
        // Between the two (a cone whose ends' radii differ: a small element and a large source),
        // tighter bounds where the axis point nearest the centre, u0 = B / A, lies on the segment:
        // there |c - p(u)|^2 = s^2 + (u - u0)^2 A, so g(u0) = s - r(u0) bounds min g from above,
        // and min over every u of sqrt(s^2 + t^2 A) - t dr, s sqrt(1 - dr^2 / A), less r(u0),
        // bounds it from below. (The same margins; on the room 86 % of the calls left end here.)
        if (A > dr * dr && B >= 0.0 && B <= A) {
            const double reach = shaft.ra + u * dr + ball.radius;
            if (s2 * (A - dr * dr) > reach * reach * A * (1.0 + 1e-9)) return false;
            if (s2 < reach * reach * (1.0 - 1e-9)) return true;
        }
    }
    const auto g = [&](double u) { return (q - u * d).norm() - (shaft.ra + u * dr); };
    double best = std::min(g(0.0), g(1.0));
    if (A > dr * dr && A > 0.0) {
        const double u = B / A + dr * std::sqrt(std::max(0.0, A * C - B * B)) / (A * std::sqrt(A - dr * dr));
        if (u > 0.0 && u < 1.0) best = std::min(best, g(u));
    }
    return best <= ball.radius;
}

double shaftClearance(const Shaft& shaft, const Ball& ball) {
    // The exact minimum of g (shaftMeetsBall() above), always.
    const Eigen::Vector3d d = shaft.b - shaft.a;
    const Eigen::Vector3d q = ball.centre - shaft.a;
    const double dr = shaft.rb - shaft.ra;
    const double A = d.squaredNorm(), B = q.dot(d), C = q.squaredNorm();
    const auto g = [&](double u) { return (q - u * d).norm() - (shaft.ra + u * dr); };
    double best = std::min(g(0.0), g(1.0));
    if (A > dr * dr && A > 0.0) {
        const double u = B / A + dr * std::sqrt(std::max(0.0, A * C - B * B)) / (A * std::sqrt(A - dr * dr));
        if (u > 0.0 && u < 1.0) best = std::min(best, g(u));
    }
    return best - ball.radius;
}

double segmentClearance(const Eigen::Vector3d& p, const Eigen::Vector3d& q, const Ball& ball) {
    const Eigen::Vector3d pq = q - p;
    const double len2 = pq.squaredNorm();
    const double t = len2 > 0.0 ? std::clamp((ball.centre - p).dot(pq) / len2, 0.0, 1.0) : 0.0;
    return (p + t * pq - ball.centre).norm() - ball.radius;
}

namespace {

Eigen::Vector3d meanOf(std::span<const Eigen::Vector3d> points) {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    for (const Eigen::Vector3d& p : points) sum += p;
    return sum / static_cast<double>(points.size());
}

// The vertices' spread along any unit normal is at most this: twice their largest distance from
// their mean (and a relative margin for round-off).
double vertexSpread(std::span<const Eigen::Vector3d> a, std::span<const Eigen::Vector3d> b) {
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (const Eigen::Vector3d& x : a) mean += x;
    for (const Eigen::Vector3d& x : b) mean += x;
    mean /= static_cast<double>(std::max<std::size_t>(1, a.size() + b.size()));
    double far2 = 0.0;
    for (const Eigen::Vector3d& x : a) far2 = std::max(far2, (x - mean).squaredNorm());
    for (const Eigen::Vector3d& x : b) far2 = std::max(far2, (x - mean).squaredNorm());
    return 2.0 * std::sqrt(far2) * (1.0 + 1e-9);
}

}  // namespace

bool segmentMeetsBall(const Eigen::Vector3d& p, const Eigen::Vector3d& q, const Ball& ball) {
    const Eigen::Vector3d pq = q - p;
    const double len2 = pq.squaredNorm();
    const double t = len2 > 0.0 ? std::clamp((ball.centre - p).dot(pq) / len2, 0.0, 1.0) : 0.0;
    return (p + t * pq - ball.centre).squaredNorm() <= ball.radius * ball.radius;
}

bool hullMeetsBall(std::span<const Eigen::Vector3d> a, std::span<const Eigen::Vector3d> b, const Ball& ball) {
    // A sure "yes" first: a segment from a point of one end to a point of the other lies in the
    // hull (the centres, each vertex to the other end's centre). Most calls that meet end here
    // (about 5 in 6 on the room), without the 34 candidate planes.
    if (!a.empty() && !b.empty()) {
        const Eigen::Vector3d ca = meanOf(a), cb = meanOf(b);
        if (segmentMeetsBall(ca, cb, ball)) return true;
        for (const Eigen::Vector3d& x : a) {
            if (segmentMeetsBall(x, cb, ball)) return true;
        }
        for (const Eigen::Vector3d& y : b) {
            if (segmentMeetsBall(ca, y, ball)) return true;
        }
    }
    // A vertex beyond 1e-9 max(1, spread) on the ball's side of a plane shows at once that the
    // plane does not separate (the tolerance below is at most that).
    const double early = 1e-9 * std::max(1.0, vertexSpread(a, b));
    const auto separates = [&](const Eigen::Vector3d& origin, Eigen::Vector3d n) {
        const double length2 = n.squaredNorm();
        if (!(length2 > 1e-30)) return false;
        // A plane the ball straddles separates nothing, face plane or not (most planes: no need
        // to look at the vertices, nor to normalise).
        double c = (ball.centre - origin).dot(n);
        if (c * c <= ball.radius * ball.radius * length2) return false;
        const double length = std::sqrt(length2);
        n /= length;
        c /= length;
        // A face plane has every vertex on one side (a tolerance for round-off: ends that touch).
        // The ball is on the side of sign(c): a vertex clearly on that side ends the test.
        const double side = c > 0.0 ? 1.0 : -1.0;
        double lo = 0.0, hi = 0.0;
        for (const Eigen::Vector3d& x : a) {
            const double s = (x - origin).dot(n);
            if (side * s > early) return false;
            lo = std::min(lo, s);
            hi = std::max(hi, s);
        }
        for (const Eigen::Vector3d& x : b) {
            const double s = (x - origin).dot(n);
            if (side * s > early) return false;
            lo = std::min(lo, s);
            hi = std::max(hi, s);
        }
        const double tol = 1e-9 * std::max(1.0, hi - lo);
        if (hi <= tol) return c > ball.radius;   // every vertex below: outward is +n
        if (lo >= -tol) return -c > ball.radius;  // every vertex above: outward is -n
        return false;                             // not a face plane
    };
    for (int pass = 0; pass < 2; ++pass) {
        const std::span<const Eigen::Vector3d> p = pass == 0 ? a : b, q = pass == 0 ? b : a;
        const std::size_t n = p.size();
        if (n >= 3 && separates(p[0], (p[1] - p[0]).cross(p[2] - p[0]))) return false;
        if (n < 2) continue;
        for (std::size_t i = 0; i < (n == 2 ? 1 : n); ++i) {
            const Eigen::Vector3d& e0 = p[i];
            const Eigen::Vector3d& e1 = p[(i + 1) % n];
            for (const Eigen::Vector3d& r : q) {
                if (separates(e0, (e1 - e0).cross(r - e0))) return false;
            }
        }
    }
    return true;
}

namespace {

// The face planes of the convex hull of `a` and `b` among the candidates hullMeetsBall() tries
// (each end's plane, every plane through an edge of one end and a vertex of the other): a
// candidate is a face plane when every vertex is within a round-off tolerance of one side.
// `face(n, offset)` gets each with its outward unit normal n (n . x = offset on the plane).
template <class Face>
void forEachFacePlane(std::span<const Eigen::Vector3d> a, std::span<const Eigen::Vector3d> b, Face&& face) {
    // (A candidate with vertices beyond `early` on both sides is no face plane, whatever the
    // vertices not yet looked at: the tolerance below never exceeds it. Most candidates end there.)
    const double early = 1e-9 * std::max(1.0, vertexSpread(a, b));
    const auto consider = [&](const Eigen::Vector3d& origin, Eigen::Vector3d n) {
        const double length2 = n.squaredNorm();
        if (!(length2 > 1e-30)) return;
        n /= std::sqrt(length2);
        double lo = 0.0, hi = 0.0;
        for (const Eigen::Vector3d& x : a) {
            const double s = (x - origin).dot(n);
            lo = std::min(lo, s);
            hi = std::max(hi, s);
        }
        if (hi > early && lo < -early) return;
        for (const Eigen::Vector3d& x : b) {
            const double s = (x - origin).dot(n);
            lo = std::min(lo, s);
            hi = std::max(hi, s);
            if (hi > early && lo < -early) return;
        }
        const double tol = 1e-9 * std::max(1.0, hi - lo);
        if (hi > tol && lo < -tol) return;  // not a face plane
        if (hi > tol) n = -n;               // every vertex above: outward is -n
        face(n, n.dot(origin));
    };
    for (int pass = 0; pass < 2; ++pass) {
        const std::span<const Eigen::Vector3d> p = pass == 0 ? a : b, q = pass == 0 ? b : a;
        const std::size_t n = p.size();
        if (n >= 3) consider(p[0], (p[1] - p[0]).cross(p[2] - p[0]));
        if (n < 2) continue;
        for (std::size_t i = 0; i < (n == 2 ? 1 : n); ++i) {
            const Eigen::Vector3d& e0 = p[i];
            const Eigen::Vector3d& e1 = p[(i + 1) % n];
            for (const Eigen::Vector3d& r : q) consider(e0, (e1 - e0).cross(r - e0));
        }
    }
}

}  // namespace

CachedHull CachedHull::of(std::span<const Eigen::Vector3d> a, std::span<const Eigen::Vector3d> b) {
    CachedHull out;
    out.count_a = static_cast<std::uint8_t>(std::min(a.size(), kMaxEnds));
    out.count_b = static_cast<std::uint8_t>(std::min(b.size(), kMaxEnds));
    std::copy_n(a.begin(), out.count_a, out.ends_a.begin());
    std::copy_n(b.begin(), out.count_b, out.ends_b.begin());
    if (!a.empty()) out.ca = meanOf(a);
    if (!b.empty()) out.cb = meanOf(b);
    out.beyond = 1e-6 * std::max(1.0, vertexSpread(a, b));
    // (Gathered on the stack, then one allocation: at most 2 + 2 x 4 x 4 candidates for ends of
    // up to kMaxEnds vertices; the planes of larger ends, in their order, after them.)
    std::array<std::array<double, 4>, 2 + 2 * kMaxEnds * kMaxEnds> found;
    std::size_t count = 0;
    std::vector<std::array<double, 4>> more;
    forEachFacePlane(a, b, [&](const Eigen::Vector3d& n, double offset) {
        if (count < found.size()) {
            found[count++] = {n.x(), n.y(), n.z(), offset};
        } else {
            more.push_back({n.x(), n.y(), n.z(), offset});
        }
    });
    const std::size_t n = count + more.size();
    out.planes.resize(4 * n);
    for (std::size_t i = 0; i < n; ++i) {
        const std::array<double, 4>& p = i < count ? found[i] : more[i - count];
        for (std::size_t c = 0; c < 4; ++c) out.planes[c * n + i] = p[c];
    }
    return out;
}

bool CachedHull::meets(const Ball& ball) const {
    // hullMeetsBall()'s answer is "yes" when a segment meets the ball, else "no" when a face plane
    // leaves it outside, else "yes": where no plane leaves it outside, "yes" whatever the segments
    // say. The segment between the ends' means first (one test, where most balls that meet the
    // hull meet it), then the planes, then (the few balls a plane leaves outside, and only those
    // within `beyond` of the plane: a segment can meet no other) the other segments: the same
    // answer, without the other segments' tests for most balls (three in four meet a segment on
    // the room, and nearly all the others no plane leaves outside).
    const bool ends = count_a > 0 && count_b > 0;
    if (ends && segmentMeetsBall(ca, cb, ball)) return true;
    const std::size_t n = planeCount();
    const double* x = planes.data();
    const double* y = x + n;
    const double* z = y + n;
    const double* w = z + n;
    const double cx = ball.centre.x(), cy = ball.centre.y(), cz = ball.centre.z(), r = ball.radius;
    // The largest signed distance of the centre beyond a plane (a plane leaves the ball outside
    // where it exceeds the radius).
    double most = -std::numeric_limits<double>::infinity();
    std::size_t i = 0;
#if defined(__SSE2__)
    // (Two planes at a time: the same products, sums and differences in each lane.)
    {
        const __m128d vx = _mm_set1_pd(cx), vy = _mm_set1_pd(cy), vz = _mm_set1_pd(cz);
        __m128d far = _mm_set1_pd(most);
        for (; i + 2 <= n; i += 2) {
            const __m128d s = _mm_sub_pd(
                _mm_add_pd(_mm_add_pd(_mm_mul_pd(_mm_loadu_pd(x + i), vx), _mm_mul_pd(_mm_loadu_pd(y + i), vy)), _mm_mul_pd(_mm_loadu_pd(z + i), vz)),
                _mm_loadu_pd(w + i));
            far = _mm_max_pd(far, s);
        }
        most = std::max(_mm_cvtsd_f64(far), _mm_cvtsd_f64(_mm_unpackhi_pd(far, far)));
    }
#endif
    for (; i < n; ++i) most = std::max(most, x[i] * cx + y[i] * cy + z[i] * cz - w[i]);
    if (!(most > r)) return true;
    if (most > r + beyond) return false;
    if (ends) {
        for (std::size_t k = 0; k < count_a; ++k) {
            if (segmentMeetsBall(ends_a[k], cb, ball)) return true;
        }
        for (std::size_t k = 0; k < count_b; ++k) {
            if (segmentMeetsBall(ca, ends_b[k], ball)) return true;
        }
    }
    return false;
}

HullPlanes HullPlanes::of(std::span<const Eigen::Vector3d> a, std::span<const Eigen::Vector3d> b) {
    HullPlanes out;
    forEachFacePlane(a, b, [&](const Eigen::Vector3d& n, double offset) {
        if (out.count >= kMax) return;
        for (int i = 0; i < out.count; ++i) {
            const auto& p = out.planes[static_cast<std::size_t>(i)];
            if (std::abs(p[0] - n.x()) + std::abs(p[1] - n.y()) + std::abs(p[2] - n.z()) < 1e-6 && std::abs(p[3] - offset) < 1e-6) return;
        }
        out.planes[out.count++] = {static_cast<float>(n.x()), static_cast<float>(n.y()), static_cast<float>(n.z()), static_cast<float>(offset)};
    });
    return out;
}

void SleepQueue::wake(double travel, std::vector<int>& out) {
    if (size_ == 0) {
        if (!std::isnan(travel)) last_ = travel;
        return;
    }
    if (!(travel >= last_)) {
        // (Not a travel that grew: every entry compared, those left bucketed again from this one.)
        std::vector<std::pair<double, int>> all;
        for (auto& bucket : buckets_) {
            all.insert(all.end(), bucket.begin(), bucket.end());
            bucket.clear();
        }
        if (!std::isnan(travel)) last_ = travel;
        size_ = 0;
        for (const auto& [key, value] : all) {
            if (!(travel < key)) {
                out.push_back(value);
            } else {
                push(key, value);
            }
        }
        return;
    }
    const int top = bucketOf(bitsOf(travel), bitsOf(last_));
    // Below `top`, and bucket 0 (keys not above the last travel) even when the travel is the last
    // one again: every key below the travel.
    for (int b = 0; b < std::max(top, 1); ++b) {
        auto& bucket = buckets_[static_cast<std::size_t>(b)];
        for (const auto& entry : bucket) out.push_back(entry.second);
        size_ -= bucket.size();
        bucket.clear();
    }
    last_ = travel;
    if (top == 0) return;
    // Its keys agree with the travel above bit top - 1 and have that bit set as it has: each
    // compared, those above it into the buckets below (they differ from it lower down).
    auto& bucket = buckets_[static_cast<std::size_t>(top)];
    std::vector<std::pair<double, int>> spread;
    spread.swap(bucket);
    for (const auto& [key, value] : spread) {
        if (!(travel < key)) {
            out.push_back(value);
            --size_;
        } else {
            buckets_[static_cast<std::size_t>(bucketOf(bitsOf(key), bitsOf(travel)))].emplace_back(key, value);
        }
    }
    spread.clear();
    bucket.swap(spread);  // (its storage kept)
}

void SleepQueue::wakeInOrder(double travel, std::vector<int>& awake) {
    const std::size_t stayed = awake.size();
    wake(travel, awake);
    if (awake.size() == stayed) return;
    int most = 0;
    for (const int v : awake) most = std::max(most, v);
    const std::size_t words = static_cast<std::size_t>(most) / 64 + 1;
    if (marks_.size() < words) marks_.resize(words, 0);
    for (const int v : awake) marks_[static_cast<std::size_t>(v) / 64] |= std::uint64_t{1} << (static_cast<unsigned>(v) % 64);
    std::size_t k = 0;
    for (std::size_t w = 0; w < words; ++w) {
        std::uint64_t word = marks_[w];
        marks_[w] = 0;
        while (word != 0) {
            awake[k++] = static_cast<int>(64 * w + static_cast<std::size_t>(std::countr_zero(word)));
            word &= word - 1;
        }
    }
}

namespace {

// One node of the hierarchy, in memory of the BVH's allocator (freed with it). Inner nodes have
// two children with their boxes; leaves a list of shaft ids.
struct Node {
    bool leaf = false;
    float lo[2][3] = {};
    float hi[2][3] = {};
    Node* child[2] = {nullptr, nullptr};
    std::uint32_t count = 0;
    std::uint32_t* ids = nullptr;
};

void* createNode(RTCThreadLocalAllocator alloc, unsigned int child_count, void*) {
    (void)child_count;  // maxBranchingFactor is 2
    void* memory = rtcThreadLocalAlloc(alloc, sizeof(Node), alignof(Node));
    return new (memory) Node();
}

void setChildren(void* node, void** children, unsigned int count, void*) {
    auto* n = static_cast<Node*>(node);
    for (unsigned i = 0; i < count && i < 2; ++i) n->child[i] = static_cast<Node*>(children[i]);
}

void setBounds(void* node, const RTCBounds** bounds, unsigned int count, void*) {
    auto* n = static_cast<Node*>(node);
    for (unsigned i = 0; i < count && i < 2; ++i) {
        n->lo[i][0] = bounds[i]->lower_x;
        n->lo[i][1] = bounds[i]->lower_y;
        n->lo[i][2] = bounds[i]->lower_z;
        n->hi[i][0] = bounds[i]->upper_x;
        n->hi[i][1] = bounds[i]->upper_y;
        n->hi[i][2] = bounds[i]->upper_z;
    }
}

void* createLeaf(RTCThreadLocalAllocator alloc, const RTCBuildPrimitive* prims, size_t count, void*) {
    void* memory = rtcThreadLocalAlloc(alloc, sizeof(Node), alignof(Node));
    auto* n = new (memory) Node();
    n->leaf = true;
    n->count = static_cast<std::uint32_t>(count);
    n->ids = static_cast<std::uint32_t*>(rtcThreadLocalAlloc(alloc, std::max<std::size_t>(1, count) * sizeof(std::uint32_t),
                                                             alignof(std::uint32_t)));
    for (std::size_t i = 0; i < count; ++i) n->ids[i] = prims[i].primID;
    return n;
}

struct Errors {
    std::mutex mutex;
    std::string first;
    static void callback(void* user, RTCError code, const char* message) {
        auto* self = static_cast<Errors*>(user);
        const std::lock_guard lock(self->mutex);
        if (self->first.empty()) self->first = "Embree error " + std::to_string(static_cast<int>(code)) + ": " + message;
    }
};

}  // namespace

struct ShaftIndex::Impl {
    std::vector<std::array<float, 6>> boxes;  // each shaft's box (lo, hi), rounded outwards
    Errors errors;
    RTCDevice device = nullptr;
    RTCBVH bvh = nullptr;
    Node* root = nullptr;
    ~Impl() {
        if (bvh) rtcReleaseBVH(bvh);
        if (device) rtcReleaseDevice(device);
    }
};

ShaftIndex::ShaftIndex(std::unique_ptr<Impl> impl, std::vector<Shaft> shafts) : impl_(std::move(impl)), shafts_(std::move(shafts)) {}
ShaftIndex::~ShaftIndex() = default;

Result<std::unique_ptr<ShaftIndex>> ShaftIndex::build(std::vector<Shaft> shafts) {
    auto impl = std::make_unique<Impl>();
    impl->device = rtcNewDevice("verbose=0");
    if (!impl->device) return fail(ErrorCode::kInternal, "lighting: the shaft index could not create an Embree device");
    rtcSetDeviceErrorFunction(impl->device, &Errors::callback, &impl->errors);
    if (!shafts.empty()) {
        // Step 1: each shaft's bounding box (of its two end balls: the cone of balls lies in it).
        std::vector<RTCBuildPrimitive> prims(shafts.size());
        for (std::size_t i = 0; i < shafts.size(); ++i) {
            const Shaft& s = shafts[i];
            const Eigen::Vector3d lo = (s.a.array() - s.ra).min(s.b.array() - s.rb);
            const Eigen::Vector3d hi = (s.a.array() + s.ra).max(s.b.array() + s.rb);
            RTCBuildPrimitive& p = prims[i];
            // Rounded outwards to single precision.
            p.lower_x = std::nextafter(static_cast<float>(lo.x()), -std::numeric_limits<float>::infinity());
            p.lower_y = std::nextafter(static_cast<float>(lo.y()), -std::numeric_limits<float>::infinity());
            p.lower_z = std::nextafter(static_cast<float>(lo.z()), -std::numeric_limits<float>::infinity());
            p.upper_x = std::nextafter(static_cast<float>(hi.x()), std::numeric_limits<float>::infinity());
            p.upper_y = std::nextafter(static_cast<float>(hi.y()), std::numeric_limits<float>::infinity());
            p.upper_z = std::nextafter(static_cast<float>(hi.z()), std::numeric_limits<float>::infinity());
            p.geomID = 0;
            p.primID = static_cast<unsigned>(i);
            impl->boxes.push_back({p.lower_x, p.lower_y, p.lower_z, p.upper_x, p.upper_y, p.upper_z});
        }
        // Step 2: Embree's builder with our node layout (binary, up to 8 shafts per leaf), at low
        // quality (Morton codes instead of the SAH): every full update builds it anew, and on the
        // sample `play --sync` the SAH build was 23 % of the lighting's instructions (1.16 G of 5.0 G,
        // 6 builds); the low one takes 0.48 G, its queries cost 3.6 % more (the room's moves
        // 1,113 -> 1,126 M over 30 moves). The same shafts are found either way.
        impl->bvh = rtcNewBVH(impl->device);
        RTCBuildArguments args = rtcDefaultBuildArguments();
        args.buildQuality = RTC_BUILD_QUALITY_LOW;
        args.maxBranchingFactor = 2;
        args.maxDepth = 1024;
        args.minLeafSize = 1;
        args.maxLeafSize = 8;
        args.bvh = impl->bvh;
        args.primitives = prims.data();
        args.primitiveCount = prims.size();
        args.primitiveArrayCapacity = prims.size();
        args.createNode = createNode;
        args.setNodeChildren = setChildren;
        args.setNodeBounds = setBounds;
        args.createLeaf = createLeaf;
        impl->root = static_cast<Node*>(rtcBuildBVH(&args));
        if (!impl->root || !impl->errors.first.empty()) {
            return fail(ErrorCode::kInternal, "lighting: building the shaft index: " +
                                                  (impl->errors.first.empty() ? std::string("no hierarchy") : impl->errors.first));
        }
    }
    return std::unique_ptr<ShaftIndex>(new ShaftIndex(std::move(impl), std::move(shafts)));
}

namespace {

// The shafts under a node whose cone of balls meets the ball, in the hierarchy's order; the two
// children of the top levels in parallel.
void queryNode(const Node* n, const std::vector<Shaft>& shafts, const std::vector<std::array<float, 6>>& boxes, const Ball& ball,
               const float (&lo)[3], const float (&hi)[3], std::vector<int>& out, int depth) {
    if (n->leaf) {
        for (std::uint32_t i = 0; i < n->count; ++i) {
            const int id = static_cast<int>(n->ids[i]);
            // The shaft's own box first (a leaf's box holds up to 8 of them).
            const auto& b = boxes[static_cast<std::size_t>(id)];
            if (b[0] > hi[0] || b[3] < lo[0] || b[1] > hi[1] || b[4] < lo[1] || b[2] > hi[2] || b[5] < lo[2]) continue;
            if (shaftMeetsBall(shafts[static_cast<std::size_t>(id)], ball)) out.push_back(id);
        }
        return;
    }
    bool overlap[2] = {false, false};
    for (int c = 0; c < 2; ++c) {
        overlap[c] = n->child[c] && n->lo[c][0] <= hi[0] && n->hi[c][0] >= lo[0] && n->lo[c][1] <= hi[1] && n->hi[c][1] >= lo[1] &&
                     n->lo[c][2] <= hi[2] && n->hi[c][2] >= lo[2];
    }
    if (overlap[0] && overlap[1] && depth < 6) {
        std::vector<int> second;
        tbb::parallel_invoke([&] { queryNode(n->child[0], shafts, boxes, ball, lo, hi, out, depth + 1); },
                             [&] { queryNode(n->child[1], shafts, boxes, ball, lo, hi, second, depth + 1); });
        out.insert(out.end(), second.begin(), second.end());
        return;
    }
    for (int c = 0; c < 2; ++c) {
        if (overlap[c]) queryNode(n->child[c], shafts, boxes, ball, lo, hi, out, depth + 1);
    }
}

}  // namespace

void ShaftIndex::query(const Ball& ball, std::vector<int>& out) const {
    const Node* root = impl_->root;
    if (!root) return;
    const float lo[3] = {static_cast<float>(ball.centre.x() - ball.radius), static_cast<float>(ball.centre.y() - ball.radius),
                         static_cast<float>(ball.centre.z() - ball.radius)};
    const float hi[3] = {static_cast<float>(ball.centre.x() + ball.radius), static_cast<float>(ball.centre.y() + ball.radius),
                         static_cast<float>(ball.centre.z() + ball.radius)};
    // Depth first: a child is visited when its box meets the ball's box.
    queryNode(root, shafts_, impl_->boxes, ball, lo, hi, out, 0);
}

}  // namespace commonlight::lighting

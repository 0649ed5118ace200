#include "lighting/texel_direct.h"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstddef>
#include <memory>
#include <new>
#include <numbers>
#include <optional>
#include <type_traits>
#include <utility>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "lighting/form_factor.h"
#include "lighting/sampling.h"

namespace commonlight::lighting {

namespace {

// Room for `n` objects of T that are made (std::construct_at) before they are read: at()'s
// segments by pair, not initialised (PreparedSegment zeroes its members; zeroing 64 segments a
// light cost more than most of their traces).
template <class T, std::size_t n>
    requires std::is_trivially_destructible_v<T>
struct Slots {
    alignas(T) std::byte bytes[n * sizeof(T)];
    T* data() noexcept { return std::launder(reinterpret_cast<T*>(bytes)); }
    T& operator[](std::size_t i) noexcept { return data()[i]; }
};

}  // namespace

void TexelDirectCache::reset(std::vector<Light> lights, std::vector<Face> faces) {
    lights_ = std::move(lights);
    light_radius_.clear();
    for (const Light& l : lights_) {
        double radius = 0.0;
        for (const Eigen::Vector3d& c : l.polygon->polygon) radius = std::max(radius, (c - l.polygon->centre).norm());
        if (l.polygon->disc) radius = std::max(radius, l.polygon->radius);  // (sampled on the disc itself)
        light_radius_.push_back(radius);
    }
    faces_.assign(faces.size(), FaceState{});
    for (std::size_t f = 0; f < faces.size(); ++f) faces_[f].geometry = std::move(faces[f]);
    locks_.clear();
    locks_.resize(faces_.size());
    traced_ = 0;
    round_ = 1;
    prefetched_ = 0;
    prefetch_used_ = 0;
}

bool TexelDirectCache::sameGeometry(const std::vector<Light>& lights, const std::vector<Face>& faces) const {
    // (The polygons are the estimator's, made once and never changed: the same pointers are the
    // same lights.)
    if (lights.size() != lights_.size() || faces.size() != faces_.size()) return false;
    for (std::size_t k = 0; k < lights.size(); ++k) {
        if (lights[k].polygon != lights_[k].polygon) return false;
    }
    for (std::size_t f = 0; f < faces.size(); ++f) {
        const Face& a = faces[f];
        const Face& b = faces_[f].geometry;
        if (a.origin != b.origin || a.edge_s != b.edge_s || a.edge_t != b.edge_t || a.normal != b.normal || a.triangle != b.triangle) return false;
    }
    return true;
}

void TexelDirectCache::renew(std::vector<Light> lights) {
    constexpr double kPi = std::numbers::pi;
    lights_ = std::move(lights);
    const std::size_t nl = lights_.size();
    for (FaceState& f : faces_) {
        // (The forgotten lists stand: the textures that follow rebuild the texels on them; a face
        // whose layout changed rebuilds every texel and empties its list.)
        // at()'s sums (over the lights in order, each term as it adds it) from the kept fractions.
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, f.entries.size(), 1024), [&](const tbb::blocked_range<std::size_t>& r) {
            for (std::size_t t = r.begin(); t < r.end(); ++t) {
                Entry& e = f.entries[t];
                if (!e.real) continue;
                Eigen::Vector3d without = Eigen::Vector3d::Zero(), with = Eigen::Vector3d::Zero();
                for (std::size_t k = 0; k < nl; ++k) {
                    const RealPart& part = f.parts[t * nl + k];
                    if (!(part.form > 0.0) || !(part.all > 0.0)) continue;
                    without += kPi * part.form * (part.open / part.all) * lights_[k].emission;
                    with += kPi * part.form * (part.both / part.all) * lights_[k].emission;
                }
                e.without = without;
                if (e.valid) e.with = with;
            }
        });
    }
}

void TexelDirectCache::seen() {
    seen_stamp_ = rays_.virtualStamp();
    seen_balls_.assign(rays_.virtualCount(), std::nullopt);
    for (std::size_t v = 0; v < seen_balls_.size(); ++v) {
        Ball b;
        if (rays_.virtualBall(static_cast<int>(v), b.centre, b.radius)) seen_balls_[v] = b;
    }
}

std::vector<Ball> TexelDirectCache::movedSinceSeen() const {
    // (Bits are by index modulo 32: with more objects, or before the first seen(), every object.)
    const std::size_t count = rays_.virtualCount();
    const std::uint32_t changed = seen_stamp_ != 0 && count <= 32 && seen_balls_.size() == count ? rays_.virtualChangedSince(seen_stamp_) : ~0u;
    std::vector<Ball> out;
    for (std::size_t v = 0; v < count; ++v) {
        if ((changed & RayScene::virtualBit(static_cast<int>(v))) == 0) continue;
        if (v < seen_balls_.size() && seen_balls_[v]) out.push_back(*seen_balls_[v]);
        Ball now;
        if (rays_.virtualBall(static_cast<int>(v), now.centre, now.radius)) out.push_back(now);
    }
    return out;
}

void TexelDirectCache::forget(const std::vector<Ball>& moved) {
    ++round_;
    if (moved.empty()) return;
    // The (light, moved ball) pairs whose cone from a ball around `x` of radius `r` to a ball
    // holding light k's polygon (it holds every shaft from a point of the first ball to the
    // light) meets the moved ball, of the pairs `from`, into `to`. A smaller ball inside the first
    // has a cone inside its cone: a face's pairs are tested for its tiles, a tile's for its
    // texels (only those: most of a face is far from a move, and most pairs miss a tile).
    using Pairs = std::vector<std::pair<std::uint32_t, std::uint32_t>>;
    const auto reached = [&](const Eigen::Vector3d& x, double r, const Pairs& from, Pairs& to) {
        to.clear();
        for (const auto& [k, b] : from) {
            const Shaft shaft{x, lights_[k].polygon->centre, r, light_radius_[k]};
            if (shaftMeetsBall(shaft, moved[b])) to.emplace_back(k, b);
        }
        return !to.empty();
    };
    const auto any = [&](const Eigen::Vector3d& x, const Pairs& from) {
        return std::any_of(from.begin(), from.end(), [&](const auto& kb) {
            return shaftMeetsBall(Shaft{x, lights_[kb.first].polygon->centre, 0.0, light_radius_[kb.first]}, moved[kb.second]);
        });
    };
    Pairs every, of_face, of_tile;
    for (std::uint32_t k = 0; k < lights_.size(); ++k) {
        for (std::uint32_t b = 0; b < moved.size(); ++b) every.emplace_back(k, b);
    }
    // The ball around the part [s0, s1] x [t0, t1] of face g (it holds its texels' points).
    const auto ballOf = [](const lighting::Face& g, double s0, double s1, double t0, double t1, double& radius) {
        const Eigen::Vector3d ds = (s1 - s0) * g.edge_s, dt = (t1 - t0) * g.edge_t;
        radius = 0.5 * std::max((ds + dt).norm(), (ds - dt).norm()) * (1.0 + 1e-9) + 1e-12;
        return g.point(0.5 * (s0 + s1), 0.5 * (t0 + t1));
    };
    constexpr int kTile = 16;
    for (FaceState& f : faces_) {
        if (f.entries.empty()) continue;
        const lighting::Face& g = f.geometry;
        double face_radius = 0.0;
        const Eigen::Vector3d face_centre = ballOf(g, 0.0, 1.0, 0.0, 1.0, face_radius);
        if (!reached(face_centre, face_radius, every, of_face)) continue;
        for (int tj = 0; tj < f.height; tj += kTile) {
            for (int ti = 0; ti < f.width; ti += kTile) {
                const double s0 = static_cast<double>(ti) / f.width, s1 = static_cast<double>(std::min(f.width, ti + kTile)) / f.width;
                const double t0 = static_cast<double>(tj) / f.height, t1 = static_cast<double>(std::min(f.height, tj + kTile)) / f.height;
                double radius = 0.0;
                const Eigen::Vector3d centre = ballOf(g, s0, s1, t0, t1, radius);
                if (!reached(centre, radius, of_face, of_tile)) continue;
                for (int j = tj; j < std::min(f.height, tj + kTile); ++j) {
                    for (int i = ti; i < std::min(f.width, ti + kTile); ++i) {
                        const std::size_t k = static_cast<std::size_t>(j) * static_cast<std::size_t>(f.width) + static_cast<std::size_t>(i);
                        Entry& e = f.entries[k];
                        if (!e.valid || !any(e.x, of_tile)) continue;
                        e.valid = false;
                        if (e.prefetched) {  // (made ahead, never asked for: gone without it, not listed again)
                            e.prefetched = false;
                            continue;
                        }
                        if (!f.all_gone) f.gone.push_back(static_cast<std::uint32_t>(k));
                    }
                }
            }
        }
    }
}

void TexelDirectCache::prefetch() {
    // The texels forget() took whose answers the last update's textures asked for: answered again at
    // their kept points, as at() would answer them now (the virtual objects are committed).
    std::vector<std::pair<std::uint32_t, std::uint32_t>> todo;  // (face, texel)
    for (std::size_t fi = 0; fi < faces_.size(); ++fi) {
        const FaceState& f = faces_[fi];
        for (const std::uint32_t k : f.gone) {
            const Entry& e = f.entries[k];
            if (!e.valid && e.real && e.asked + 1 == round_) todo.emplace_back(static_cast<std::uint32_t>(fi), k);
        }
    }
    // (A texel forgotten twice before its face's textures took the list is listed twice.)
    std::sort(todo.begin(), todo.end());
    todo.erase(std::unique(todo.begin(), todo.end()), todo.end());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, todo.size(), 16), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t i = r.begin(); i < r.end(); ++i) {
            FaceState& f = faces_[todo[i].first];
            Entry& e = f.entries[todo[i].second];
            const std::uint32_t asked = e.asked;
            const Eigen::Vector3d x = e.x;
            Eigen::Vector3d without, with;
            at(static_cast<int>(todo[i].first), todo[i].second, f.width, f.height, x, f.geometry.normal, without, with);
            // Not asked for yet: at() counts it and marks it asked when the textures ask.
            e.asked = asked;
            e.prefetched = true;
            --traced_;
        }
    });
    prefetched_ += static_cast<long>(todo.size());
}

bool TexelDirectCache::takeForgotten(int face, std::vector<std::uint32_t>& texels) {
    if (face < 0 || static_cast<std::size_t>(face) >= faces_.size()) return false;
    FaceState& f = faces_[static_cast<std::size_t>(face)];
    const bool listed = !f.all_gone;
    if (listed) texels.insert(texels.end(), f.gone.begin(), f.gone.end());
    f.gone.clear();
    f.all_gone = false;
    return listed;
}

const TexelDirectCache::Balls& TexelDirectCache::virtualBalls() {
    const std::uint64_t stamp = rays_.virtualStamp();
    if (balls_stamp_.load(std::memory_order_acquire) == stamp) return balls_;
    const std::lock_guard lock(balls_lock_);
    if (balls_stamp_.load(std::memory_order_relaxed) == stamp) return balls_;
    balls_.count = 0;
    for (std::size_t v = 0; v < rays_.virtualCount() && balls_.count < balls_.balls.size(); ++v) {
        Ball b;
        if (!rays_.virtualBall(static_cast<int>(v), b.centre, b.radius)) continue;
        b.radius += 2.0 * rays_.epsilon() + 1e-6 * (1.0 + b.radius);
        balls_.balls[balls_.count++] = b;
    }
    balls_.all = rays_.virtualCount() <= balls_.balls.size();
    balls_stamp_.store(stamp, std::memory_order_release);
    return balls_;
}

void TexelDirectCache::at(int face, std::size_t texel, int width, int height, const Eigen::Vector3d& x, const Eigen::Vector3d& normal,
                          Eigen::Vector3d& without, Eigen::Vector3d& with) {
    FaceState& f = faces_[static_cast<std::size_t>(face)];
    const std::size_t nl = lights_.size();
    FaceLock& face_lock = locks_[static_cast<std::size_t>(face)];
    const std::uint64_t layout = static_cast<std::uint64_t>(static_cast<std::uint32_t>(width)) << 32 | static_cast<std::uint32_t>(height);
    if (face_lock.layout.load(std::memory_order_acquire) != layout) {
        const std::lock_guard lock(face_lock.lock);
        if (f.width != width || f.height != height) {
            f.width = width;
            f.height = height;
            f.entries.assign(static_cast<std::size_t>(width) * static_cast<std::size_t>(height), Entry{});
            f.parts.assign(f.entries.size() * nl, RealPart{});
            f.gone.clear();
            f.all_gone = true;
        }
        face_lock.layout.store(layout, std::memory_order_release);
    }
    Entry& e = f.entries[texel];
    const bool same_point = e.real && (e.x - x).squaredNorm() < 1e-18;
    e.asked = round_;
    if (e.valid && same_point) {
        if (e.prefetched) {  // made ahead by prefetch(): counted now, as if traced now
            e.prefetched = false;
            ++traced_;
            ++prefetch_used_;
        }
        without = e.without;
        with = e.with;
        return;
    }
    // Each light: its exact form factor at x times the kernel-weighted fraction of `pairs_`
    // stratified segments to it that the real scene (and the virtual objects) leave open. The
    // real part is traced once per point; a move traces the virtual rays of the open pairs.
    constexpr double kPi = std::numbers::pi;
    const int pairs = std::clamp(pairs_, 1, 64);
    const int side = stratifiedSide(pairs);  // (the pairs' grid on each light)
    // The virtual objects' balls, widened by both ends' lift and a margin for round-off: a light
    // whose cone from x (every segment from x to a point of its ball) meets none of them has
    // every pair open to them, so `with` takes the real answer (the same sum in the same order).
    const Balls& known = virtualBalls();
    const std::array<Ball, 32>& balls = known.balls;
    const std::size_t ball_count = known.count;
    const bool all_balls = known.all;
    std::optional<VirtualSet> set;  // occludedVirtual()'s objects, gathered at the first virtual ray
    if (!same_point) without.setZero();
    with.setZero();
    for (std::size_t k = 0; k < nl; ++k) {
        RealPart& part = f.parts[texel * nl + k];
        const LightGeometry& light = *lights_[k].polygon;
        const std::uint64_t seed = hashCombine(hashCombine(0x7e8e1ull, static_cast<std::uint64_t>(face)), hashCombine(texel, k));
        if (!same_point) {
            part = RealPart{};
            part.form = pointToPolygon(x, normal, light.polygon, light.normal);
        }
        if (!(part.form > 0.0)) continue;
        const Shaft cone{x, light.centre, 0.0, light_radius_[k] * (1.0 + 1e-9) + 1e-12};
        const bool clear = all_balls && std::none_of(balls.begin(), balls.begin() + static_cast<std::ptrdiff_t>(ball_count),
                                                     [&](const Ball& b) { return shaftMeetsBall(cone, b); });
        if (same_point && clear) {
            part.both = part.open;
            if (part.all > 0.0) with += kPi * part.form * (part.open / part.all) * lights_[k].emission;
            continue;
        }
        // The segments of the pairs to trace, prepared once (the virtual objects' rays of a
        // pair skip the lifting: occludedVirtual(prepareSegment(...), set) is occludedVirtual()'s
        // answer). A new point traces the real scene for every pair with weight, in packets
        // (occludedRealMany(): occludedReal()'s rays); a kept point only its open pairs.
        // A pair whose segment meets none of the widened balls is open to the virtual objects (the
        // cone's rule above, segment by segment): `near` holds the others (every pair when the balls
        // are not all known), and only they are prepared for and traced against the objects.
        // (By pair j: `weight` made for the pairs of `todo`, `segments` for those prepared.)
        Slots<PreparedSegment, 64> segments;
        std::array<double, 64> weight;  // (not initialised: made for the pairs of `todo`)
        const std::uint64_t every = pairs == 64 ? ~std::uint64_t{0} : (std::uint64_t{1} << pairs) - 1;
        const std::uint64_t todo = same_point ? every & ~part.blocked : every;
        std::uint64_t weighed = 0;  // pairs with weight > 0, of `todo`
        std::uint64_t near = all_balls ? 0 : ~std::uint64_t{0};
        for (std::uint64_t rest = todo; rest != 0; rest &= rest - 1) {
            const int j = std::countr_zero(rest);
            const Eigen::Vector3d q = sampleLight(light, stratified2dOnSide(seed, j, side));
            const Eigen::Vector3d dv = q - x;
            const double d2 = dv.squaredNorm();
            const double w = d2 > 0.0 ? std::max(0.0, normal.dot(dv)) * std::max(0.0, -light.normal.dot(dv)) / (d2 * d2) : 0.0;
            weight[static_cast<std::size_t>(j)] = w;
            if (!(w > 0.0)) continue;
            const std::uint64_t bit = std::uint64_t{1} << j;
            weighed |= bit;
            // (The segment's line against each ball, without a division: a line that misses a
            // ball has no segment of it meeting the ball.)
            if (!clear && all_balls && std::any_of(balls.begin(), balls.begin() + static_cast<std::ptrdiff_t>(ball_count), [&](const Ball& b) {
                    return dv.cross(b.centre - x).squaredNorm() <= b.radius * b.radius * d2;
                })) {
                near |= bit;
            }
            if (!same_point || (!clear && (near & bit) != 0)) std::construct_at(segments.data() + j, rays_.prepareSegment(x, normal, q, light.normal));
        }
        std::uint64_t blocked_real = 0;  // of `weighed` (a new point)
        if (!same_point && weighed != 0) {
            Slots<PreparedSegment, 64> packed;
            std::array<int, 64> index;  // (not initialised: the first n made)
            int n = 0;
            for (std::uint64_t rest = weighed; rest != 0; rest &= rest - 1) {
                const int j = std::countr_zero(rest);
                index[static_cast<std::size_t>(n)] = j;
                std::construct_at(packed.data() + n++, segments[static_cast<std::size_t>(j)]);
            }
            const std::uint64_t hit = rays_.occludedRealMany(packed.data(), n);
            for (int i = 0; i < n; ++i) {
                if ((hit >> i) & 1u) blocked_real |= std::uint64_t{1} << index[static_cast<std::size_t>(i)];
            }
        }
        double open_real = 0.0, open_both = 0.0;
        for (std::uint64_t rest = todo; rest != 0; rest &= rest - 1) {
            const int j = std::countr_zero(rest);
            const std::uint64_t bit = std::uint64_t{1} << j;
            const double w = weight[static_cast<std::size_t>(j)];
            if (!same_point) {
                if ((weighed & bit) == 0 || (blocked_real & bit) != 0) {
                    part.blocked |= bit;
                    part.all += w > 0.0 ? w : 0.0;
                    continue;
                }
                part.all += w;
            }
            open_real += w;
            if (clear || (weighed & bit) == 0 || (near & bit) == 0) {
                open_both += w;
                continue;
            }
            if (!set) set = rays_.virtualSet(~0u);
            if (!rays_.occludedVirtual(segments[static_cast<std::size_t>(j)], *set)) open_both += w;
        }
        if (!same_point) part.open = open_real;
        part.both = open_both;
        if (!(part.all > 0.0)) continue;
        if (!same_point) without += kPi * part.form * (open_real / part.all) * lights_[k].emission;
        with += kPi * part.form * (open_both / part.all) * lights_[k].emission;
    }
    if (same_point) without = e.without;
    ++traced_;
    e.valid = true;
    e.real = true;
    e.x = x;
    e.without = without;
    e.with = with;
}

}  // namespace commonlight::lighting

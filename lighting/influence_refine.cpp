// The refinement that follows the virtual objects (lighting/influence.h): what blocks the light of
// the elements under the touched base leaves (transmissions to the lights, corrections of the
// blocked base links, the objects' own light) and how finely they are split.
#include <tbb/parallel_for.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <numbers>
#include <optional>

#include "lighting/direct.h"
#include "lighting/influence_impl.h"
#include "lighting/sampling.h"

namespace commonlight::lighting {

namespace {

constexpr double kPi = std::numbers::pi;

}  // namespace

RealMask& VirtualInfluence::Impl::mask(int element, int key) {
    // (Sorted by key: found by bisection, tens of lights and sources per element.)
    auto& list = masks[static_cast<std::size_t>(element)];
    const auto it = std::lower_bound(list.begin(), list.end(), key, [](const RealMask& m, int k) { return m.key < k; });
    if (it != list.end() && it->key == key) return *it;
    return *list.insert(it, RealMask{key, 0, 0, 0, 0, 0, nullptr});
}

// Virtual transmission of the light between leaf c and light k: the kernel-weighted fraction of
// the pairs the real scene leaves open that the virtual objects leave open too (the same pairs'
// real answers are kept: a move costs virtual rays only). `mixed`: some blocked, some not (a
// penumbra or a shadow's edge across the leaf).
double VirtualInfluence::Impl::transmissionToLight(int c, int light, bool& mixed, std::uint32_t mask_bits, bool full_estimate) {
    const Radiosity& rad = self.radiosity_;
    const RayScene& rays = self.rays_;
    const DirectSource& s = *base.lights[static_cast<std::size_t>(light)].source;
    const ElementGeometry g = rad.geometry(c);
    const Element& el = rad.hierarchy()[c];
    const bool partial = rad.exposure(c) < 1.0;
    RealMask& m = mask(c, -1 - light);
    const std::uint64_t seed = hashCombine(hashCombine(self.options_.seed, rad.hierarchy().key(c)), 0x11ull + static_cast<std::uint64_t>(light));
    mixed = false;
    // One estimate over `n` samples: each sample a point of the leaf and a point of (or a
    // direction to) the light, its weight, and whether real and virtual occluders block it.
    const auto estimate = [&](int n, std::uint64_t sample_seed, bool full, double& open_real, double& open_all, bool& any_blocked,
                              bool& any_open) {
        std::uint64_t& bits = full ? m.full : m.pilot;
        std::uint64_t& hidden_bits = full ? m.full_hidden : m.pilot_hidden;
        const std::uint8_t flag = full ? 2 : 1;
        const bool known = (m.have & flag) != 0;
        std::uint64_t computed = 0, computed_hidden = 0;
        // A pair starting on the leaf's hidden part is none of its light (kept with the real answers).
        const auto hidden = [&](int k, const Eigen::Vector3d& x) {
            if (!partial) return false;
            if (known) return ((hidden_bits >> k) & 1u) != 0;
            if (!rad.hidden(c, x)) return false;
            computed_hidden |= std::uint64_t{1} << k;
            return true;
        };
        open_real = open_all = 0.0;
        any_blocked = any_open = false;
        // Known, a pair the real scene blocks or that starts on the hidden part adds nothing:
        // skipped before its points are made.
        const std::uint64_t skip = known ? bits | hidden_bits : 0;
        for (int k = 0; k < n && k < 64; ++k) {
            if ((skip >> k) & 1u) continue;
            Eigen::Vector3d x, y, w;
            double f = 0.0;
            bool to_point = true;
            switch (s.kind) {
                case DirectSource::Kind::kPolygon: {
                    const SamplePair u = stratifiedPair(sample_seed, k, n);
                    x = samplePolygon(g.corner, g.edge_s, g.edge_t, g.triangle, u.first.x(), u.first.y());
                    if (hidden(k, x)) continue;
                    y = sampleLight(*s.polygon, u.second);
                    const Eigen::Vector3d dv = y - x;
                    const double floor2 = std::pow(0.05 * std::sqrt(std::min(el.area, s.polygon->area)), 2);
                    const double d2 = std::max(dv.squaredNorm(), floor2);
                    f = std::max(0.0, g.normal.dot(dv)) * std::max(0.0, -s.polygon->normal.dot(dv)) / (d2 * d2);
                    break;
                }
                case DirectSource::Kind::kPoint: {
                    const Eigen::Vector2d u = stratified2d(sample_seed, k, n);
                    x = samplePolygon(g.corner, g.edge_s, g.edge_t, g.triangle, u.x(), u.y());
                    if (hidden(k, x)) continue;
                    y = s.position;
                    const Eigen::Vector3d dv = y - x;
                    const double d2 = dv.squaredNorm();
                    f = d2 > 1e-12 ? std::max(0.0, g.normal.dot(dv)) / (d2 * std::sqrt(d2)) : 0.0;
                    break;
                }
                case DirectSource::Kind::kDirection:
                case DirectSource::Kind::kCell: {
                    const SamplePair u = stratifiedPair(sample_seed, k, n);
                    x = samplePolygon(g.corner, g.edge_s, g.edge_t, g.triangle, u.first.x(), u.first.y());
                    if (hidden(k, x)) continue;
                    w = s.kind == DirectSource::Kind::kDirection ? Eigen::Vector3d(-s.direction.normalized()) : s.cellDirection(u.second);
                    f = std::max(0.0, g.normal.dot(w));
                    to_point = false;
                    break;
                }
            }
            if (!(f > 0.0)) continue;
            bool real_blocked;
            if (known) {
                real_blocked = (bits >> k) & 1u;
            } else {
                real_blocked = to_point ? rays.occludedReal(x, g.normal, y, s.kind == DirectSource::Kind::kPolygon ? s.polygon->normal
                                                                                                                     : Eigen::Vector3d::Zero())
                                        : rays.occludedRealRay(x, g.normal, w);
                if (real_blocked) computed |= std::uint64_t{1} << k;
            }
            if (real_blocked) continue;
            open_real += f;
            const bool blocked = to_point ? rays.occludedVirtual(x, g.normal, y,
                                                                 s.kind == DirectSource::Kind::kPolygon ? s.polygon->normal : Eigen::Vector3d::Zero(),
                                                                 mask_bits)
                                          : rays.occludedVirtualRay(x, g.normal, w, mask_bits);
            if (blocked) {
                any_blocked = true;
            } else {
                any_open = true;
                open_all += f;
            }
        }
        if (!known) {
            bits = computed;
            hidden_bits = computed_hidden;
            m.have = static_cast<std::uint8_t>(m.have | flag);
        }
    };
    const int pilot = std::clamp(self.options_.pilot_pairs, 1, 64);
    double open_real = 0.0, open_all = 0.0;
    bool blocked = false, open = false;
    estimate(pilot, hash64(seed), false, open_real, open_all, blocked, open);
    if (blocked && open) {
        mixed = true;
        if (!full_estimate) return open_real > 0.0 ? open_all / open_real : 1.0;
        estimate(std::clamp(self.options_.partial_pairs, 1, 64), seed, true, open_real, open_all, blocked, open);
    }
    return open_real > 0.0 ? open_all / open_real : 1.0;
}

namespace {

// The ball of a link's kept rays (their ends: the segments lie in it).
void boundRays(LinkPoints& lp) {
    Eigen::AlignedBox3d box;
    for (const LinkPoints::Pair& p : lp.pairs) {
        if (!(p.ray.tfar > 0.0)) continue;  // never blocked
        box.extend(p.ray.origin);
        box.extend(Eigen::Vector3d(p.ray.origin + p.ray.tfar * p.ray.direction));
    }
    lp.centre = box.isEmpty() ? Eigen::Vector3d(Eigen::Vector3d::Zero()) : Eigen::Vector3d(box.center());
    lp.radius = 0.0;
    for (const LinkPoints::Pair& p : lp.pairs) {
        if (!(p.ray.tfar > 0.0)) continue;
        lp.radius = std::max({lp.radius, (p.ray.origin - lp.centre).norm(),
                              (p.ray.origin + p.ray.tfar * p.ray.direction - lp.centre).norm()});
    }
}

// The objects in `mask` whose ball meets the ball of a link's rays: the others block none of them
// (an object's bit is kept if any object sharing it is near; a margin for the rounding).
std::uint32_t objectsNear(const RayScene& rays, const LinkPoints& lp, std::uint32_t mask) {
    std::uint32_t near = 0;
    const int n = static_cast<int>(rays.virtualCount());
    for (int v = 0; v < n; ++v) {
        const std::uint32_t bit = RayScene::virtualBit(v);
        if ((mask & bit) == 0u || (near & bit) != 0u) continue;
        Eigen::Vector3d centre;
        double radius = 0.0;
        if (!rays.virtualBall(v, centre, radius)) continue;  // disabled: blocks nothing
        const double reach = lp.radius + radius + 1e-7 * (1.0 + lp.centre.norm() + lp.radius + radius);
        if ((centre - lp.centre).squaredNorm() <= reach * reach) near |= bit;
    }
    return near;
}

}  // namespace

// The same for a base link's shaft from leaf c to the link's source s (pairs of points of the two
// elements, kernel-weighted as Radiosity::computeLink weighs them).
double VirtualInfluence::Impl::transmissionToSource(int c, int s, bool& mixed, std::uint32_t mask_bits) {
    const Radiosity& rad = self.radiosity_;
    const RayScene& rays = self.rays_;
    RealMask& m = mask(c, s);
    if (self.options_.cache_link_points && (m.have & 4u) != 0) {
        // The open pairs' points and weights kept from the first answer: the same sums in the same
        // order, the virtual rays alone traced again.
        const LinkPoints& lp = *m.points;
        const std::uint32_t near = objectsNear(rays, lp, mask_bits);
        // A pair is blocked when one of the near objects blocks it (each object's answer its own).
        // The answers of the near objects that did not move at the latest commit (`still`) are
        // kept (LinkPoints::kept_blocked) and used while none of them changes: then only the
        // other objects' rays are traced, and none for a pair the kept ones block. Kept for other
        // objects (one moved since, or left or joined the still ones): made again.
        const std::uint32_t still = near & ~rays.virtualChangedLast();
        const bool reuse = lp.keptHold(still, rays);
        const std::uint32_t traced = near & ~still;
        // (The objects gathered once for all the pairs: RayScene::VirtualSet; the still ones' only
        // when traced.)
        const VirtualSet set = rays.virtualSet(traced);
        std::optional<VirtualSet> still_set;
        if (!reuse && still != 0u) still_set.emplace(rays.virtualSet(still));
        std::uint64_t kept_blocked = reuse ? lp.kept_blocked : 0;
        // (The open pairs' weights summed in their order when they were kept: LinkPoints::open_real.)
        const double open_real = lp.open_real;
        double open_all = 0.0;
        bool any_blocked = false, any_open = false;
        for (std::size_t i = 0; i < lp.pairs.size(); ++i) {
            const LinkPoints::Pair& p = lp.pairs[i];
            bool blocked;
            if (reuse) {
                blocked = ((kept_blocked >> i) & 1u) != 0;
            } else {
                blocked = still_set && rays.occludedVirtual(p.ray, *still_set);
                if (blocked) kept_blocked |= std::uint64_t{1} << i;
            }
            if (!blocked) blocked = traced != 0u && rays.occludedVirtual(p.ray, set);
            if (blocked) {
                any_blocked = true;
            } else {
                any_open = true;
                open_all += p.w;
            }
        }
        if (!reuse) {
            lp.kept_blocked = kept_blocked;
            lp.kept_objects = still;
            lp.kept_at = rays.virtualStamp();
        }
        mixed = any_blocked && any_open;
        return open_real > 0.0 ? open_all / open_real : 1.0;
    }
    const ElementGeometry gr = rad.geometry(c), gs = rad.geometry(s);
    const double floor2 = std::pow(0.05 * std::sqrt(std::min(rad.hierarchy()[c].area, rad.hierarchy()[s].area)), 2);
    const bool partial = rad.exposure(c) < 1.0;
    const bool known = (m.have & 1u) != 0;
    const bool keep_points = self.options_.cache_link_points;
    const VirtualSet set = keep_points ? rays.virtualSet(mask_bits) : VirtualSet{};
    auto points = std::make_shared<LinkPoints>();
    std::uint64_t computed = 0;
    const int n = std::clamp(self.options_.direct_per_texel ? self.options_.texel_link_pairs : self.options_.link_pairs, 1, 64);
    const std::uint64_t seed = hashCombine(hashCombine(self.options_.seed ^ 0x5eedull, rad.hierarchy().key(c)), rad.hierarchy().key(s));
    double open_real = 0.0, open_all = 0.0;
    bool any_blocked = false, any_open = false;
    std::uint64_t computed_hidden = 0;
    // Known, a pair the real scene blocks or that starts on the hidden part is skipped before its
    // points are made (it adds nothing either way: the same sums).
    const std::uint64_t skip = known ? m.pilot | m.pilot_hidden : 0;
    // Step 1: the pairs' points, weights and segments (the real and the virtual rays trace the
    // same segment: RayScene::prepareSegment()).
    struct Candidate {
        int k = 0;
        double w = 0.0;
        Eigen::Vector3d xr, xs;
    };
    std::array<Candidate, 64> cand;
    std::array<PreparedSegment, 64> segments;
    int count = 0;
    for (int k = 0; k < n; ++k) {
        if ((skip >> k) & 1u) continue;
        const SamplePair pair = stratifiedPair(seed, k, n);
        const Eigen::Vector3d xr = rad.surfacePoint(c, gr, pair.first.x(), pair.first.y());
        if (partial) {
            // A pair starting on the leaf's hidden part (under a box) is none of its light.
            if (known ? ((m.pilot_hidden >> k) & 1u) != 0 : rad.hidden(c, xr)) {
                if (!known) computed_hidden |= std::uint64_t{1} << k;
                continue;
            }
        }
        const Eigen::Vector3d xs = rad.surfacePoint(s, gs, pair.second.x(), pair.second.y());
        const Eigen::Vector3d dv = xs - xr;
        const double d2 = std::max(dv.squaredNorm(), floor2);
        const double w = std::max(0.0, gr.normal.dot(dv)) * std::max(0.0, -gs.normal.dot(dv)) / (d2 * d2);
        if (!(w > 0.0)) continue;
        const auto i = static_cast<std::size_t>(count++);
        cand[i] = Candidate{k, w, xr, xs};
        segments[i] = rays.prepareSegment(xr, gr.normal, xs, gs.normal);
    }
    // Step 2: their real rays (unless known) as packets, occludedReal()'s answers.
    const std::uint64_t real = known ? 0 : rays.occludedRealMany(segments.data(), count);
    // The pairs the real scene leaves open are kept: room for them at once (one allocation, not
    // one per doubling; known, the blocked ones were skipped above).
    if (keep_points) points->pairs.reserve(static_cast<std::size_t>(count - std::popcount(real)));
    // Step 3: in the pairs' order, the sums and the virtual rays of the pairs left open.
    for (int i = 0; i < count; ++i) {
        const Candidate& p = cand[static_cast<std::size_t>(i)];
        const int k = p.k;
        const double w = p.w;
        bool real_blocked;
        if (known) {
            real_blocked = (m.pilot >> k) & 1u;
        } else {
            real_blocked = (real >> i) & 1u;
            if (real_blocked) computed |= std::uint64_t{1} << k;
        }
        if (real_blocked) continue;
        open_real += w;
        bool blocked;
        if (keep_points) {
            points->pairs.push_back(LinkPoints::Pair{segments[static_cast<std::size_t>(i)], w});
            blocked = rays.occludedVirtual(points->pairs.back().ray, set);
        } else {
            blocked = rays.occludedVirtual(p.xr, gr.normal, p.xs, gs.normal, mask_bits);
        }
        if (blocked) {
            any_blocked = true;
        } else {
            any_open = true;
            open_all += w;
        }
    }
    if (!known) {
        m.pilot = computed;
        m.pilot_hidden = computed_hidden;
        m.have = static_cast<std::uint8_t>(m.have | 1u);
    }
    if (keep_points) {
        boundRays(*points);
        points->open_real = open_real;
        m.points = std::move(points);
        m.have = static_cast<std::uint8_t>(m.have | 4u);
    }
    mixed = any_blocked && any_open;
    return open_real > 0.0 ? open_all / open_real : 1.0;
}


double VirtualInfluence::Impl::linkSize(int b) const {
    return std::max(self.options_.link_size, 2.0 * boundSize(bound_level[static_cast<std::size_t>(b)]));
}

namespace {

template <typename T>
const T* findAnswer(const std::vector<T>& list, int key, int T::*field) {
    const auto it = std::lower_bound(list.begin(), list.end(), key, [&](const T& a, int k) { return a.*field < k; });
    return it != list.end() && (*it).*field == key ? &*it : nullptr;
}

bool contains(const std::vector<int>& sorted, int key) { return std::binary_search(sorted.begin(), sorted.end(), key); }

// Each thread's answer lists under construction (computeTerms(), computeLinks()): once made, a list
// is swapped into the element's Answers and the element's old list becomes the thread's room for
// the next element (no allocation once the lists have grown).
struct AnswerScratch {
    std::vector<LightAnswer> lights;
    std::vector<LinkAnswer> links;
    std::vector<ClusterAnswer> clusters;
};

AnswerScratch& answerScratch() {
    thread_local AnswerScratch scratch;
    return scratch;
}

}  // namespace

// Element c under base leaf b: its terms (transmissions of the selected lights, the objects' light
// at leaf level), and how much B/B~ may vary across it (the oracle). Each answer is the last one's
// when no object that moved had its old or new bounds in that item's shaft (`reach`: the items
// whose shaft at c's parent met them; `met`: those whose shaft at c does): the rays in a shaft no
// moved object was or is in give what they gave.
VirtualInfluence::Impl::LeafResult VirtualInfluence::Impl::computeTerms(int c, int b, bool links_open, const Reach& reach, Reach& met) {
    LeafTerms& t = terms[static_cast<std::size_t>(c)];
    t.clear();
    LeafResult out;
    const Selection& sel = selection[static_cast<std::size_t>(b)];
    const Eigen::Vector3d& rho = self.rho_[static_cast<std::size_t>(c)];
    const double den = denominator(c);
    // Only the objects significant at b block here (the same rays whichever object moved last:
    // a fresh solve and the incremental one trace the same).
    const std::uint32_t mask = objectMask(b);
    const auto meets = [&](auto test) {
        for (const auto& [object, link] : entries[static_cast<std::size_t>(b)]) {
            if (link < 0 && test(objects[static_cast<std::size_t>(object)].ball)) return true;
        }
        return false;
    };
    Answers& ans = answers[static_cast<std::size_t>(c)];
    const bool have = ans.valid;
    AnswerScratch& scratch = answerScratch();
    // Step 1: direct light the objects block.
    std::vector<LightAnswer>& lights = scratch.lights;
    lights.clear();
    for (int k : sel.lights) {
        const InfluenceLight& l = base.lights[static_cast<std::size_t>(k)];
        const double col = l.column->real[static_cast<std::size_t>(c)];
        // (The reach first: a child may see a light its parent's estimate missed.)
        const bool reached = contains(reach.lights, k) && reachedByMove([&](const Ball& ball) { return lightMeetsBall(c, k, ball); });
        if (reached) met.lights.push_back(k);
        if (!(col > 0.0)) continue;
        const LightAnswer* old = have && !reached ? findAnswer(ans.lights, k, &LightAnswer::light) : nullptr;
        LightAnswer a;
        if (old) {
            a = *old;
            ++out.reused;
        } else {
            ++out.computed;
            a.light = k;
            a.blocked = meets([&](const Ball& ball) { return lightMeetsBall(c, k, ball); });
            if (a.blocked) a.pilot = transmissionToLight(c, k, a.mixed, mask, false);
        }
        lights.push_back(a);
        if (!a.blocked) continue;
        t.direct += (a.pilot - 1.0) * col * l.emission;
        // A penumbra across c: split c while it may vary by more than refine_epsilon, and the
        // full estimate once c stays a leaf. Not where the direct light is drawn per texel
        // (InfluenceOptions::direct_per_texel): c's transmission then only feeds the light D
        // sends on, which the pilot's estimate gives well enough at c's size.
        if (a.mixed && !self.options_.direct_per_texel) {
            out.variation += lumaOf(rho.cwiseProduct(l.emission)) * col / kPi / den;
            out.deferred.emplace_back(k, a.pilot);
        }
    }
    // The blocked base links' reach, for c and its children (their corrections: computeLinks()),
    // where corrections may be made (`links_open`; below them no element has any: their answers
    // go). An answer whose shaft the move reached, or whose link is no longer selected, is dropped.
    if (links_open) {
        for (int li : reach.links) {
            if (!contains(sel.links, li)) continue;
            if (const ClusterNode* node = sharedNode(li)) {
                // (A shared answer: reached when it changed.)
                if (node->changed) met.links.push_back(li);
                continue;
            }
            const int source = links[static_cast<std::size_t>(li)].source;
            if (reachedByMove([&](const Ball& ball) { return linkMeetsBall(c, source, ball); })) met.links.push_back(li);
        }
        if (ans.links_valid) {
            std::erase_if(ans.links, [&](const LinkAnswer& a) { return !contains(sel.links, a.link) || contains(met.links, a.link); });
        }
    } else {
        ans.links.clear();
        ans.links_valid = false;
    }
    // Step 2: light from the objects that reach b at leaf level (an object that moved or changed
    // its emission: always again).
    std::vector<ClusterAnswer>& clusters = scratch.clusters;
    clusters.clear();
    for (int o : sel.objects) {
        const ObjectState& obj = objects[static_cast<std::size_t>(o)];
        const ElementShape& es = shape[static_cast<std::size_t>(c)];
        const bool reached = contains(reach.objects, o) && reachedByMove([&](const Ball& ball) {
                                 return shaftMeetsBall(Shaft{es.centroid, obj.ball.centre, es.radius, obj.radius}, ball);
                             });
        if (reached) met.objects.push_back(o);
        const ClusterAnswer* old = have && !reached && !object_changed[static_cast<std::size_t>(o)] ? findAnswer(ans.clusters, o, &ClusterAnswer::object) : nullptr;
        ClusterAnswer a;
        if (old) {
            a = *old;
            ++out.reused;
        } else {
            ++out.computed;
            a.object = o;
            a.irradiance = clusterAt(o, c, &a.variation, mask & ~RayScene::virtualBit(o));
        }
        clusters.push_back(a);
        t.cluster += a.irradiance;
        out.variation += a.variation;
    }
    ans.lights.swap(lights);
    ans.clusters.swap(clusters);
    ans.valid = true;
    return out;
}

// The full estimates computeTerms() left for later, now that c stays a leaf: the same estimate the
// pilot would have been followed by at once (a split element's terms are not used: its full
// estimates wait until it is a leaf). Kept with the answer while the move does not reach its shaft.
void VirtualInfluence::Impl::finishDeferred(int c, int b, const LeafResult& r) {
    if (r.deferred.empty()) return;
    LeafTerms& t = terms[static_cast<std::size_t>(c)];
    const std::uint32_t mask = objectMask(b);
    std::vector<LightAnswer>& lights = answers[static_cast<std::size_t>(c)].lights;
    for (const auto& [k, pilot] : r.deferred) {
        const InfluenceLight& l = base.lights[static_cast<std::size_t>(k)];
        const double col = l.column->real[static_cast<std::size_t>(c)];
        auto it = std::lower_bound(lights.begin(), lights.end(), k, [](const LightAnswer& a, int key) { return a.light < key; });
        double full = -1.0;
        if (it != lights.end() && it->light == k && it->full >= 0.0) {
            full = it->full;
        } else {
            bool mixed = false;
            full = transmissionToLight(c, k, mixed, mask, true);
            if (it != lights.end() && it->light == k) it->full = full;
        }
        t.direct += (full - pilot) * col * l.emission;
    }
}

// Element c's corrections of the base links the objects block (lighting/influence.h C), and how
// much they may vary across it. Answers kept as computeTerms() keeps them (`met`: the links whose
// shaft at c the move reached).
double VirtualInfluence::Impl::computeLinks(int c, int b, const Reach& met, LeafResult& out) {
    LeafTerms& t = terms[static_cast<std::size_t>(c)];
    t.corrections.clear();
    const Selection& sel = selection[static_cast<std::size_t>(b)];
    const Eigen::Vector3d& rho = self.rho_[static_cast<std::size_t>(c)];
    const double den = denominator(c);
    const std::uint32_t mask = objectMask(b);
    const Hierarchy& h = self.radiosity_.hierarchy();
    Answers& ans = answers[static_cast<std::size_t>(c)];
    std::vector<LinkAnswer>& fresh = answerScratch().links;
    fresh.clear();
    double variation = 0.0;
    for (int li : sel.links) {
        const Link& l = links[static_cast<std::size_t>(li)];
        const ClusterNode* node = sharedNode(li);
        const LinkAnswer* old = ans.links_valid && !contains(met.links, li) ? findAnswer(ans.links, li, &LinkAnswer::link) : nullptr;
        if (old && node && old->version != node->version) old = nullptr;
        LinkAnswer a;
        if (old) {
            a = *old;
            ++out.reused;
        } else if (node) {
            // A face of a clustered proxy through a cluster link: the link's shared answer.
            ++out.computed;
            a.link = li;
            a.version = node->version;
            const auto it = std::lower_bound(node->blocked_faces.begin(), node->blocked_faces.end(), std::make_pair(h[c].face, -1));
            a.blocked = node->mask != 0 && it != node->blocked_faces.end() && it->first == h[c].face;
            if (a.blocked) {
                a.transmission = node->transmission[static_cast<std::size_t>(it->second)];
                a.mixed = node->mixed[static_cast<std::size_t>(it->second)];
            }
        } else {
            ++out.computed;
            a.link = li;
            for (const auto& [object, link] : entries[static_cast<std::size_t>(b)]) {
                if (link < 0 && linkMeetsBall(c, l.source, objects[static_cast<std::size_t>(object)].ball)) {
                    a.blocked = true;
                    break;
                }
            }
            if (a.blocked) a.transmission = transmissionToSource(c, l.source, a.mixed, mask);
        }
        fresh.push_back(a);
        if (!a.blocked) continue;
        const double w = kPi * static_cast<double>(l.form_factor) * static_cast<double>(l.vis_real);
        if (a.transmission < 1.0) t.corrections.push_back(Correction{l.source, w * (a.transmission - 1.0)});
        if (a.mixed) variation += lumaOf(rho) / kPi * w * lumaOf(base.radiance[static_cast<std::size_t>(l.source)]) / den;
    }
    ans.links.swap(fresh);
    ans.links_valid = true;
    return variation;
}

// Recomputes the touched base leaves: level by level over the elements standing under them
// (parallel over a level, splits and collapses in between on this thread), each element's terms
// from its answers (computeTerms()), the oracle, and the split the oracle asks for. An element
// whose answers the move does not reach gets the same terms and the same split: the walk goes on
// to its children; new elements get everything computed.
void VirtualInfluence::Impl::refine(const std::vector<int>& touched) {
    Radiosity& rad = self.radiosity_;
    Hierarchy& h = rad.hierarchy();
    const InfluenceOptions& opt = self.options_;
    // Step 1: select, and the footprint bound.
    std::vector<Eigen::Vector3d> old_d(touched.size());
    for (std::size_t i = 0; i < touched.size(); ++i) {
        const int b = touched[i];
        old_d[i] = self.d_[static_cast<std::size_t>(b)];
        face_dirty[static_cast<std::size_t>(h[b].face)] = 1;
        bound_level[static_cast<std::size_t>(b)] = boundLevel(b);
    }
    tbb::parallel_for(std::size_t{0}, touched.size(), [&](std::size_t i) { select(touched[i]); });
    // Step 2: level by level. `links_open`: no element above has the corrections yet; they go to
    // the first element no larger than the link size, or to a leaf larger than that. `reach`: the
    // selected items whose shaft at the parent met a moved object's bounds (at a base leaf: all):
    // element i's is reach[reach_of[i]], its parent's `met` (shared by the siblings, not copied).
    // `met` is made in the lists of the level before last (cleared: no allocation once grown).
    std::vector<int> frontier = touched;
    std::vector<int> base_of(frontier.begin(), frontier.end());
    std::vector<char> links_open(frontier.size(), 1);
    std::vector<Reach> reach(frontier.size()), met;
    std::vector<std::size_t> reach_of(frontier.size());
    for (std::size_t i = 0; i < touched.size(); ++i) {
        const Selection& sel = selection[static_cast<std::size_t>(touched[i])];
        reach[i] = Reach{sel.lights, sel.links, sel.objects};
        reach_of[i] = i;
    }
    std::vector<int> done;  // elements whose terms stand (leaves and link-level elements)
    evaluated = link_evaluated = 0;
    items_computed = items_reused = 0;
    while (!frontier.empty()) {
        evaluated += static_cast<int>(frontier.size());
        std::vector<LeafResult> results(frontier.size());
        met.resize(frontier.size());
        for (Reach& r : met) {
            r.lights.clear();
            r.links.clear();
            r.objects.clear();
        }
        tbb::parallel_for(std::size_t{0}, frontier.size(), [&](std::size_t i) {
            const int c = frontier[i];
            if (h[c].buried) {
                terms[static_cast<std::size_t>(c)].clear();
                return;
            }
            const int b = base_of[i];
            results[i] = computeTerms(c, b, links_open[i] != 0, reach[reach_of[i]], met[i]);
            // The corrections where they stay: at the link level, or on an element larger than
            // that which its direct light and the objects' light do not split (where the blocked
            // links' own variation may still split it).
            const Element& el = h[c];
            const double size = std::max(el.size_s, el.size_t_);
            const bool split_anyway = results[i].variation > opt.refine_epsilon && size > boundSize(bound_level[static_cast<std::size_t>(b)]);
            if (links_open[i] && (size <= linkSize(b) || !split_anyway)) {
                results[i].link_variation = computeLinks(c, b, met[i], results[i]);
                results[i].links = true;
            }
        });
        for (const LeafResult& r : results) {
            link_evaluated += r.links ? 1 : 0;
            items_computed += r.computed;
            items_reused += r.reused;
        }
        std::vector<int> next, next_base, made, made_base;  // (an element made before the base reads as base: not baseLeafOf())
        std::vector<char> next_open;
        std::vector<std::size_t> next_reach_of;
        std::vector<std::size_t> stays;  // elements that stay leaves with full estimates to finish
        // The leaf budget counts as if the touched base leaves had been collapsed and made again
        // level by level (what a fresh solve sees): the leaves under this level's elements that
        // still stand from the last update are not counted.
        long excess = 0;
        std::vector<int> under;
        for (int c : frontier) {
            if (h[c].child_count == 0) continue;
            under.clear();
            h.leavesUnder(c, under);
            excess += static_cast<long>(under.size()) - 1;
        }
        for (std::size_t i = 0; i < frontier.size(); ++i) {
            const int c = frontier[i];
            const int b = base_of[i];
            const bool buried = h[c].buried;
            const double size = std::max(h[c].size_s, h[c].size_t_);
            const bool had_children = h[c].child_count > 0;
            const bool link_level = links_open[i] && size <= linkSize(b);
            // Split while the light may vary across the element by more than refine_epsilon (the
            // blocked links only down to the link size), to the camera's resolution.
            const double variation = results[i].variation + (links_open[i] && !link_level ? results[i].link_variation : 0.0);
            const bool wants = !buried && variation > opt.refine_epsilon && size > boundSize(bound_level[static_cast<std::size_t>(b)]) &&
                               h.leafCount() - excess + 4 <= opt.max_leaves;
            long stood = 0;  // leaves under c from the last update
            if (had_children) {
                under.clear();
                h.leavesUnder(c, under);
                stood = static_cast<long>(under.size());
            }
            if (wants && (had_children || h.subdivide(c, opt.min_size))) {
                if (had_children) excess -= h[c].child_count - 1;
                LeafTerms& t = terms[static_cast<std::size_t>(c)];
                t.direct.setZero();
                t.cluster.setZero();
                if (!link_level) t.corrections.clear();
                if (link_level) done.push_back(c);
                const Element& parent = h[c];
                for (int k = 0; k < parent.child_count; ++k) {
                    next.push_back(parent.first_child + k);
                    next_base.push_back(b);
                    next_open.push_back(links_open[i] && !link_level ? 1 : 0);
                    next_reach_of.push_back(i);
                    if (!had_children) {
                        made.push_back(parent.first_child + k);
                        made_base.push_back(b);
                    }
                }
                continue;
            }
            if (had_children) {
                h.collapse(c);
                excess -= stood - 1;
            }
            done.push_back(c);
            if (!results[i].deferred.empty()) stays.push_back(i);
        }
        tbb::parallel_for(std::size_t{0}, stays.size(), [&](std::size_t j) {
            const std::size_t i = stays[j];
            finishDeferred(frontier[i], base_of[i], results[i]);
        });
        if (next.empty()) break;
        // The new children (made or brought back): no answers yet, exposure, pull weights, real
        // columns, B~.
        grow();
        std::vector<int> fresh;
        for (int c : made) {
            answers[static_cast<std::size_t>(c)] = Answers{};
            rad.measureExposure(c);
            if (!column_known[static_cast<std::size_t>(c)]) fresh.push_back(c);
        }
        for (int c : made) {
            const int p = h[c].parent;
            double total = 0.0;
            for (int k = 0; k < h[p].child_count; ++k) {
                const Element& ch = h[h[p].first_child + k];
                if (!ch.buried) total += ch.area * rad.exposure(h[p].first_child + k);
            }
            up[static_cast<std::size_t>(c)] = total > 0.0 && !h[c].buried ? h[c].area * rad.exposure(c) / total : 0.0;
        }
        if (!fresh.empty()) {
            for (const InfluenceLight& l : base.lights) computeDirect(rad, *l.source, fresh, base.direct, *l.column);
            for (int c : fresh) column_known[static_cast<std::size_t>(c)] = 1;
        }
        for (std::size_t i = 0; i < made.size(); ++i) {
            const int c = made[i];
            const int b = made_base[i];
            self.rho_[static_cast<std::size_t>(c)] = base.rho[static_cast<std::size_t>(b)];
            probe_radiance[static_cast<std::size_t>(c)] = base.radiance[static_cast<std::size_t>(b)];
            Eigen::Vector3d direct = Eigen::Vector3d::Zero();
            for (const InfluenceLight& l : base.lights) direct += static_cast<double>(l.column->real[static_cast<std::size_t>(c)]) * l.emission;
            self.tilde_[static_cast<std::size_t>(c)] =
                h[c].buried ? Eigen::Vector3d(Eigen::Vector3d::Zero())
                            : Eigen::Vector3d(base.emission[static_cast<std::size_t>(b)] +
                                              base.rho[static_cast<std::size_t>(b)].cwiseProduct(direct + base.indirect[static_cast<std::size_t>(b)]) / kPi);
        }
        frontier = std::move(next);
        base_of = std::move(next_base);
        links_open = std::move(next_open);
        reach.swap(met);
        reach_of = std::move(next_reach_of);
    }
    // Step 3: the corrections' current sums, the leaves' values, pulled up to each base leaf.
    for (int c : done) {
        LeafTerms& t = terms[static_cast<std::size_t>(c)];
        t.cl.setZero();
        for (const Correction& k : t.corrections) {
            const auto s = static_cast<std::size_t>(k.source);
            t.cl += k.coef * (base.radiance[s] + self.d_[s] - U[s]);
        }
        has_terms[static_cast<std::size_t>(c)] = !t.corrections.empty() || !t.direct.isZero() || !t.cluster.isZero();
    }
    for (int c : done) {
        if (h[c].child_count == 0) self.d_[static_cast<std::size_t>(c)] = h[c].buried ? Eigen::Vector3d::Zero() : value(c);
    }
    for (std::size_t i = 0; i < touched.size(); ++i) {
        const int b = touched[i];
        pullSubtree(b);
        const Eigen::Vector3d delta = self.d_[static_cast<std::size_t>(b)] - old_d[i];
        addUnshot(b, delta);
        propagateUp(b, delta);
    }
    rebuildCorrectionIndex();
}

void VirtualInfluence::Impl::rebuildCorrectionIndex() {
    const Hierarchy& h = self.radiosity_.hierarchy();
    const std::size_t n = h.elements().size();
    // By source, in order of receiver and index (a counting sort: two passes, no comparison sort).
    corr_offsets.assign(n + 1, 0);
    const auto each = [&](auto visit) {
        for (std::size_t c = 0; c < n && c < has_terms.size(); ++c) {
            if (!has_terms[c] || h[static_cast<int>(c)].retired) continue;
            const auto& corr = terms[c].corrections;
            for (std::size_t k = 0; k < corr.size(); ++k) visit(corr[k].source, static_cast<int>(c), static_cast<int>(k));
        }
    };
    each([&](int source, int, int) { ++corr_offsets[static_cast<std::size_t>(source) + 1]; });
    for (std::size_t i = 1; i <= n; ++i) corr_offsets[i] += corr_offsets[i - 1];
    corr_by_source.resize(static_cast<std::size_t>(corr_offsets[n]));
    std::vector<int> next(corr_offsets.begin(), corr_offsets.end() - 1);
    each([&](int source, int receiver, int k) { corr_by_source[static_cast<std::size_t>(next[static_cast<std::size_t>(source)]++)] = {receiver, k}; });
}


}  // namespace commonlight::lighting

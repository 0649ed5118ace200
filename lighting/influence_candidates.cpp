// The candidates of the virtual objects' influence (lighting/influence.h): which (base leaf, link or
// light) pairs an object's bounds reach, from the shaft index into the object's cache, and at every
// move the cached pairs it is significant at (those it cannot have come close to since their last
// answer left alone).
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <numbers>

#include "lighting/influence_impl.h"

namespace commonlight::lighting {

namespace {

constexpr double kPi = std::numbers::pi;

// Solid angle (sr) of a ball of radius r seen from distance d (capped at the hemisphere).
double ballSolidAngle(double r, double d) {
    if (d <= r) return 2.0 * kPi;
    return 2.0 * kPi * (1.0 - std::sqrt(std::max(0.0, 1.0 - r * r / (d * d))));
}

// A cached pair's answers are trusted this much less far than the distances say (metres): far
// above the round-off of the tests (the hull's planes are in single precision), far below a move.
constexpr double kClearanceMargin = 1e-4;

// How far the object's centre may come closer to a base leaf's centroid, now `d` away, before the
// significance share x min(1, ballSolidAngle(radius, d') / max(omega, 1e-12)) of a pair through it
// can reach `item` (d' = d less the travel: a bound the triangle inequality gives). It reaches it
// at the distance d* where the ball's solid angle is item / share x omega (share >= item here).
// Where that angle is too small for a precise d*, 0 (tested again at the next move).
double significanceClearance(double share, double omega, double item, double d, double radius) {
    const double theta = item / share * std::max(omega, 1e-12);
    if (theta > 2.0 * kPi * (1.0 + 1e-9)) return 1e300;  // not even a ball around the centroid reaches it
    const double f = theta / (2.0 * kPi);
    if (!(f > 1e-8)) return 0.0;
    // ballSolidAngle(r, d) >= theta  <=>  sqrt(1 - r^2 / d^2) <= 1 - f  <=>  d <= r / sqrt(f (2 - f)).
    const double dstar = radius / std::sqrt(f * (2.0 - f));
    return std::max(0.0, d - dstar * (1.0 + 1e-6) - kClearanceMargin);
}

}  // namespace

// The (base leaf, link or light) pairs whose shaft meets the ball `query` and whose effect there
// could reach a tenth of link_epsilon for an object anywhere inside it: the shaft index's
// candidates (cones), links followed from their receivers down to the base leaves (pruned by a bound
// on that effect). The hull of a pair's two ends is tested later, by candidates(), and only for
// the pairs whose significance asks for it (cache_hull_in: a fifth of them). `scan`: every shaft instead
// of the index (the from-scratch baseline). Directional lights and distant cells by a scan of the
// base leaves.
void VirtualInfluence::Impl::collectPairs(int object, const Ball& query, bool scan, std::vector<std::pair<int, int>>& pairs) {
    const Radiosity& rad = self.radiosity_;
    const Hierarchy& h = rad.hierarchy();
    const double item = 0.1 * self.options_.link_epsilon;
    (void)object;
    pairs.clear();
    std::vector<int> ids;
    if (scan) {
        for (std::size_t i = 0; i < index->size(); ++i) {
            if (shaftMeetsBall(index->shaft(static_cast<int>(i)), query)) ids.push_back(static_cast<int>(i));
        }
    } else {
        index->query(query, ids);
    }
        // In parallel over blocks of the shafts found, gathered in their order.
    constexpr std::size_t kBlock = 64;
    std::vector<std::vector<std::pair<int, int>>> found((ids.size() + kBlock - 1) / kBlock);
    tbb::parallel_for(std::size_t{0}, found.size(), [&](std::size_t block) {
        std::vector<std::pair<int, int>>& out = found[block];
        std::vector<int> stack;
        for (std::size_t j = block * kBlock; j < std::min(ids.size(), (block + 1) * kBlock); ++j) {
            const int id = ids[j];
            if (id >= link_shafts) {
                const auto [b, k] = light_shafts[static_cast<std::size_t>(id - link_shafts)];
                out.emplace_back(b, -1 - k);
                continue;
            }
            const int link = shaft_link[static_cast<std::size_t>(id)];
            const Link& l = links[static_cast<std::size_t>(link)];
            const double w = kPi * static_cast<double>(l.form_factor) * static_cast<double>(l.vis_real);
            const double source = lumaOf(base.radiance[static_cast<std::size_t>(l.source)]);
            const ElementShape& src = shape[static_cast<std::size_t>(l.source)];
            const double source_area = h[l.source].area;
            stack.assign(1, l.receiver);
            while (!stack.empty()) {
                const int e = stack.back();
                stack.pop_back();
                const Element& el = h[e];
                if (el.buried) continue;
                const ElementShape& es = shape[static_cast<std::size_t>(e)];
                // Above the base leaves every test uses twice the element's radius, which holds every
                // element under it: a test passed by a base leaf is passed by its ancestors, so the pairs
                // found do not depend on the ball the search started from (the cache's or the object's).
                const bool leaf = base_leaf[static_cast<std::size_t>(e)];
                const double radius = leaf ? es.radius : 2.0 * es.radius;
                if (e != l.receiver && !shaftMeetsBall(Shaft{es.centroid, src.centroid, radius, src.radius}, query)) continue;
                // Bound of the effect anywhere under e of anything inside the query ball: the most it
                // can cover over the least the source can subtend (its cosine floored as in
                // linkSignificance()).
                const double near = std::max((query.centre - es.centroid).norm() - radius, query.radius);
                const double far = (src.centroid - es.centroid).norm() + radius + src.radius;
                const double beta = std::min(1.0, ballSolidAngle(query.radius, near) / std::max(source_area * 0.05 / (far * far), 1e-12));
                if (rho_max[static_cast<std::size_t>(e)] / kPi * w * source * beta / den_min[static_cast<std::size_t>(e)] < item) continue;
                if (leaf) {
                    out.emplace_back(e, link);
                    continue;
                }
                for (int c = 0; c < el.child_count; ++c) stack.push_back(el.first_child + c);
            }
        }
    });
    for (const auto& f : found) pairs.insert(pairs.end(), f.begin(), f.end());
    if (!far_lights.empty()) {
        for (int e : rad.leaves(Mode::kReal)) {
            if (!base_leaf[static_cast<std::size_t>(e)]) continue;
            for (int k : far_lights) {
                if (farLightMeetsBall(e, k, query)) pairs.emplace_back(e, -1 - k);
            }
        }
    }
}

// The base leaves where object o (at `ball`) is significant: the sum of its largest effects on
// B/B~ there, through each light and base link whose shaft it meets, reaches link_epsilon (each
// effect below a tenth of that is not counted: under a box standing on the floor every link is
// blocked, and many small ones add up). Recorded per base leaf: the object, and the links through
// which it matters. The pairs come from the object's cache while it stays inside its cache ball
// (the same pairs the index would give: the cache holds a superset, filtered here), else from the
// index again.
void VirtualInfluence::Impl::candidates(int object, const Ball& ball, bool scan, std::vector<int>& touched, bool record_links) {
    const double item = 0.1 * self.options_.link_epsilon;
    ObjectState& obj = objects[static_cast<std::size_t>(object)];
    bool refreshed = true;
    std::vector<std::pair<int, int>> old_pairs;
    std::vector<std::unique_ptr<HullPlanes>> old_hulls;
    if (!scan) {
        old_pairs.swap(obj.cache_pairs);
        old_hulls.swap(obj.cache_hulls);
    }
    if (scan) {
        obj.cache_valid = false;
        collectPairs(object, ball, true, obj.cache_pairs);
    } else if (!obj.cache_valid || (ball.centre - obj.cache_ball.centre).norm() + ball.radius > obj.cache_ball.radius) {
        obj.cache_ball = Ball{ball.centre, ball.radius + self.options_.shaft_margin};
        collectPairs(object, obj.cache_ball, false, obj.cache_pairs);
        obj.cache_valid = true;
    } else {
        refreshed = false;
        obj.cache_pairs.swap(old_pairs);
        obj.cache_hulls.swap(old_hulls);
    }
    // How far the ball has moved since the last move (a pair's answers known up to a travel).
    // The rebuild's scan, or a ball of another size, starts again.
    const bool track = !scan && self.options_.idle_cached_pairs && obj.travel_known && obj.travel_ball.radius == ball.radius && ball.centre == obj.ball.centre;
    std::vector<double> old_idle, old_meets;
    std::vector<std::array<double, 2>> old_sig;
    std::vector<ObjectState::PairShaft> old_shafts;
    if (!scan) {
        old_idle.swap(obj.cache_idle);
        old_meets.swap(obj.cache_meets);
        if (refreshed) {
            old_sig.swap(obj.cache_sig);
            old_shafts.swap(obj.cache_shafts);
        }
    }
    if (track) {
        obj.travel += (ball.centre - obj.travel_ball.centre).norm();
    } else {
        old_idle.assign(old_idle.size(), 0.0);
        old_meets.assign(old_meets.size(), 0.0);
    }
    obj.travel_known = !scan && ball.centre == obj.ball.centre;
    obj.travel_ball = ball;
    if (refreshed) {
        // Sorted; the hull planes and the known answers of the pairs the last cache had, kept
        // (both lists sorted).
        std::sort(obj.cache_pairs.begin(), obj.cache_pairs.end());
        obj.cache_hulls.clear();
        obj.cache_hulls.resize(obj.cache_pairs.size());
        obj.cache_sig.assign(obj.cache_pairs.size(), {0.0, -1.0});
        obj.cache_shafts.resize(obj.cache_pairs.size());
        obj.cache_idle.assign(obj.cache_pairs.size(), 0.0);
        obj.cache_meets.assign(obj.cache_pairs.size(), 0.0);
        obj.cache_hull_in.assign(obj.cache_pairs.size(), 0);
        obj.cache_query = scan ? ball : obj.cache_ball;
        std::size_t j = 0;
        for (std::size_t i = 0; i < obj.cache_pairs.size() && j < old_pairs.size(); ++i) {
            while (j < old_pairs.size() && old_pairs[j] < obj.cache_pairs[i]) ++j;
            if (j < old_pairs.size() && old_pairs[j] == obj.cache_pairs[i]) {
                if (j < old_sig.size() && old_sig[j][1] >= 0.0) {
                    obj.cache_sig[i] = old_sig[j];
                    obj.cache_shafts[i] = old_shafts[j];
                }
                if (j < old_hulls.size() && old_hulls[j]) obj.cache_hulls[i] = std::move(old_hulls[j]);
                if (j < old_idle.size()) {
                    obj.cache_idle[i] = old_idle[j];
                    obj.cache_meets[i] = old_meets[j];
                }
            }
        }
        // The first cache under a new base: the hulls the last base's cache held (setBase()).
        if (!obj.carried_hulls.empty()) {
            auto& carried = obj.carried_hulls;
            for (std::size_t i = 0; i < obj.cache_pairs.size(); ++i) {
                if (obj.cache_hulls[i]) continue;
                const auto [element, what] = obj.cache_pairs[i];
                const int source = what >= 0 ? links[static_cast<std::size_t>(what)].source : what;
                auto it = std::lower_bound(carried.begin(), carried.end(), std::pair(element, source),
                                           [](const ObjectState::CarriedHull& c, const std::pair<int, int>& key) { return std::pair(c.element, c.source) < key; });
                for (; it != carried.end() && it->element == element && it->source == source; ++it) {
                    if (!it->hull) continue;
                    obj.cache_hulls[i] = std::move(it->hull);
                    break;
                }
            }
            obj.carried_hulls.clear();
        }
    } else {
        obj.cache_idle.swap(old_idle);
        obj.cache_meets.swap(old_meets);
        obj.cache_idle.resize(obj.cache_pairs.size(), 0.0);
        obj.cache_meets.resize(obj.cache_pairs.size(), 0.0);
    }
    const double travel = obj.travel;
    // The pairs this move looks at: those awake after the last move, and those whose idle travel
    // the ball has now covered; all of them again where the cache was made or the travel restarted.
    // (A pair's answer below is what it would be if every pair were looked at: a pair left out is
    // one the loop would skip, by its share or by `travel < cache_idle`.)
    std::vector<int>& awake = obj.cache_awake;
    SleepQueue& asleep = obj.cache_asleep;
    if (refreshed || !track) {
        awake.clear();
        asleep.reset(travel);
        for (std::size_t i = 0; i < obj.cache_pairs.size(); ++i) {
            const auto& parts = obj.cache_sig[i];
            if (parts[1] >= 0.0 && std::max(parts[0], 0.0) < item) continue;
            if (obj.cache_idle[i] > travel) {
                asleep.push(obj.cache_idle[i], static_cast<int>(i));
            } else {
                awake.push_back(static_cast<int>(i));
            }
        }
    } else {
        // (Kept in ascending position: the pairs woken now put in order among them, so that the
        // pairs kept below come in cache_pairs' order, by base leaf then link, with no sort of their own.)
        asleep.wakeInOrder(travel, awake);
    }
    std::vector<std::pair<int, double>> sums;       // base leaf, significance (by base leaf)
    std::vector<std::pair<int, int>> link_entries;  // base leaf, link (sorted)
    // (The significance first: it is cheaper than the shaft tests.) In parallel over the pairs
    // awake (a few thousand of the room's 29 000), gathered in their order: cache_pairs' (each base
    // leaf's significances summed below in ascending order, as a sort of them all would). `next`:
    // 0 awake at the next move, 1 asleep until `travel` reaches its cache_idle, 2 never significant.
    std::vector<double> kept(awake.size(), -1.0);
    std::vector<std::uint8_t> next(awake.size(), 0);
    std::atomic<long> pairs_tested{0};
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, awake.size(), 256), [&](const tbb::blocked_range<std::size_t>& r) {
        long tested = 0;
        struct Count {
            std::atomic<long>& total;
            long& n;
            ~Count() { total += n; }
        } count{pairs_tested, tested};
        for (std::size_t k = r.begin(); k < r.end(); ++k) {
            const std::size_t i = static_cast<std::size_t>(awake[k]);
            const auto [b, what] = obj.cache_pairs[i];
            // (A face's transfer through a shared cluster link: its node found whether the object
            // meets the shaft of the face's root, which holds the base leaf's. A "no" there is read
            // first: most of a clustered proxy's transfers near an object are not blocked.)
            const ClusterNode* node = what >= 0 ? sharedNode(what) : nullptr;
            if (node && (node->transfer_objects[static_cast<std::size_t>(link_position[static_cast<std::size_t>(what)])] & RayScene::virtualBit(object)) == 0) continue;
            // (What does not depend on where the object is, found once per pair.)
            auto& parts = obj.cache_sig[i];
            if (!(parts[1] >= 0.0)) {
                if (what < 0) {
                    lightSignificanceParts(b, -1 - what, parts[0], parts[1]);
                } else {
                    linkSignificanceParts(b, what, parts[0], parts[1]);
                }
                obj.cache_shafts[i] = pairShaft(b, what);
            }
            // (objectBlocks() at b's centroid, the shaft's first end: no look-up of b's shape. It is
            // at most 1, so a share below `item` is never significant: not computed, nor looked at again.)
            if (std::max(parts[0], 0.0) < item) {
                next[k] = 2;
                continue;
            }
            // (Not kept at a move whose ball stays as far as it was: left alone, asleep until
            // `travel` reaches its cache_idle. A shared cluster link's answer may change with its
            // node's: always tested.)
            const auto sleep = [&] {
                const bool idle = !node && travel < obj.cache_idle[i];
                if (idle) next[k] = 1;
                return idle;
            };
            if (sleep()) continue;
            ++tested;
            const Eigen::Vector3d& centroid = obj.cache_shafts[i].shaft.a;
            const double sig = parts[0] > 0.0 ? parts[0] * objectBlocksFrom(object, centroid, parts[1]) : 0.0;
            if (!(sig >= item)) {
                if (!node) obj.cache_idle[i] = travel + significanceClearance(parts[0], parts[1], item, (obj.ball.centre - centroid).norm(), obj.radius);
                sleep();
                continue;
            }
            // (The node's answer when the base leaf is the face's root, else the leaf's own shaft.)
            bool meets;
            if (node) {
                meets = links[static_cast<std::size_t>(what)].receiver == b || cachedPairMeets(obj, i, ball);
            } else if (travel < obj.cache_meets[i]) {
                meets = true;
            } else {
                double clear = 0.0;
                meets = cachedPairMeets(obj, i, ball, &clear);
                if (meets) {
                    obj.cache_meets[i] = travel + clear - kClearanceMargin;
                } else {
                    obj.cache_idle[i] = travel + clear - kClearanceMargin;
                    sleep();
                }
            }
            if (!meets) continue;
            // (A pair the hull of whose ends misses the ball it was collected with is not one of the
            // cache's: never kept, nor looked at again. Asked once the ball meets the pair's shaft:
            // most significant pairs it does not, and a pair not met is not kept whatever this says.)
            if (!obj.cache_shafts[i].far && obj.cache_hull_in[i] == 0) {
                const std::span<const Eigen::Vector3d> other =
                    what < 0 ? lightPolygon(-1 - what) : shape[static_cast<std::size_t>(links[static_cast<std::size_t>(what)].source)].polygon();
                obj.cache_hull_in[i] = hullMeetsBall(shape[static_cast<std::size_t>(b)].polygon(), other, obj.cache_query) ? 1 : 2;
            }
            if (obj.cache_hull_in[i] == 2) {
                next[k] = 2;
                continue;
            }
            kept[k] = sig;
        }
    });
    if (!scan) self.stats_.pairs_tested += pairs_tested.load();
    std::size_t stay = 0;
    for (std::size_t k = 0; k < awake.size(); ++k) {
        const int i = awake[k];
        if (next[k] == 0) awake[stay++] = i;
        if (next[k] == 1) asleep.push(obj.cache_idle[static_cast<std::size_t>(i)], i);
        if (!(kept[k] >= 0.0)) continue;
        const auto [b, what] = obj.cache_pairs[static_cast<std::size_t>(i)];
        sums.emplace_back(b, kept[k]);
        if (what >= 0) link_entries.emplace_back(b, what);
    }
    awake.resize(stay);
    // Significant where the sum reaches link_epsilon.
    std::size_t j = 0;
    for (std::size_t i = 0; i < sums.size();) {
        const int b = sums[i].first;
        std::size_t end = i;
        while (end < sums.size() && sums[end].first == b) ++end;
        std::sort(sums.begin() + static_cast<std::ptrdiff_t>(i), sums.begin() + static_cast<std::ptrdiff_t>(end));
        double total = 0.0;
        for (; i < end; ++i) total += sums[i].second;
        while (j < link_entries.size() && link_entries[j].first < b) ++j;
        if (total < self.options_.link_epsilon) continue;
        touched.push_back(b);
        if (!record_links) continue;
        auto& list = entries[static_cast<std::size_t>(b)];
        list.emplace_back(object, -1);
        for (std::size_t k = j; k < link_entries.size() && link_entries[k].first == b; ++k) {
            if (list.empty() || list.back() != std::make_pair(object, link_entries[k].second)) list.emplace_back(object, link_entries[k].second);
        }
    }
}

}  // namespace commonlight::lighting

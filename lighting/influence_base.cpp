// The base of the virtual objects' influence (lighting/influence.h): the per-element state, the
// shaft index over the base links and the light shafts, every influence forgotten.
#include "lighting/influence.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <numbers>

#include "lighting/form_factor.h"
#include "lighting/influence_impl.h"
#include "lighting/sampling.h"

namespace commonlight::lighting {

namespace {

constexpr double kPi = std::numbers::pi;

}  // namespace

Result<void> VirtualInfluence::setBase(InfluenceBase b) {
    Impl& d = *impl_;
    const Hierarchy& h = radiosity_.hierarchy();
    const std::size_t n = h.elements().size();
    // Step 0: the hulls the objects' caches hold, by element and source (the source element of the
    // pair's link, or -1 - light): kept below where both shapes stand. A hull is the two polygons'
    // alone, and a full update rarely moves them (new emissions, B~), so the first caches under the
    // new base find most of them made.
    std::vector<std::vector<ObjectState::CarriedHull>> carried(d.objects.size());
    for (std::size_t o = 0; o < d.objects.size(); ++o) {
        ObjectState& obj = d.objects[o];
        for (std::size_t i = 0; i < obj.cache_hulls.size() && i < obj.cache_pairs.size(); ++i) {
            const auto [element, what] = obj.cache_pairs[i];
            if (!obj.cache_hulls[i] || (what >= 0 && static_cast<std::size_t>(what) >= d.links.size())) continue;
            const int source = what >= 0 ? d.links[static_cast<std::size_t>(what)].source : what;
            carried[o].push_back({element, source, std::move(obj.cache_hulls[i])});
        }
    }
    const std::vector<ElementShape> old_shape = std::move(d.shape);
    const std::vector<std::vector<Eigen::Vector3d>> old_lights = std::move(d.light_polygons);
    // Step 1: the per-element state, all of it the base's.
    d.base = std::move(b);
    d.base.rho.resize(n, Eigen::Vector3d::Constant(0.5));
    d.base.emission.resize(n, Eigen::Vector3d::Zero());
    d.base.radiance.resize(n, Eigen::Vector3d::Zero());
    d.base.indirect.resize(n, Eigen::Vector3d::Zero());
    d.sub.assign(n, 0);
    d.base_leaf.assign(n, 0);
    d.up.assign(n, 0.0);
    d.G.assign(n, Eigen::Vector3d::Zero());
    d.V.assign(n, Eigen::Vector3d::Zero());
    d.U.assign(n, Eigen::Vector3d::Zero());
    d.pending.assign(n, Eigen::Vector3d::Zero());
    d.queued.assign(n, 0);
    d.pending_flag.assign(n, 0);
    d.column_known.assign(n, 1);
    d.terms.assign(n, LeafTerms{});
    d.answers.assign(n, Answers{});
    d.has_terms.assign(n, 0);
    d.masks.assign(n, {});
    d.selection.assign(n, Selection{});
    d.entries.assign(n, {});
    d.bound_level.assign(n, -1);
    d.corr_source.assign(n, 0);
    d.shape.assign(n, ElementShape{});
    for (std::size_t e = 0; e < n; ++e) {
        if (!radiosity_.isVirtualElement(static_cast<int>(e))) d.cacheShape(static_cast<int>(e));
    }
    // Whose shape stands (the same corners to the bit as under the last base), and which lights'.
    // (A real element's place never changes: Hierarchy keeps a collapsed element's children
    // retired and brings them back, so an index is never another element's. The check keeps the
    // hulls right should that change.)
    const auto sameShape = [&](int e) {
        const auto u = static_cast<std::size_t>(e);
        if (e < 0 || u >= old_shape.size() || u >= n) return false;
        const ElementShape& a = old_shape[u];
        const ElementShape& s = d.shape[u];
        if (a.count == 0 || a.count != s.count) return false;
        for (int i = 0; i < a.count; ++i) {
            if (a.corners[static_cast<std::size_t>(i)] != s.corners[static_cast<std::size_t>(i)]) return false;
        }
        return true;
    };
    d.light_polygons.clear();
    for (std::size_t k = 0; k < d.base.lights.size(); ++k) {
        const std::span<const Eigen::Vector3d> p = d.lightPolygon(static_cast<int>(k));
        d.light_polygons.emplace_back(p.begin(), p.end());
    }
    const auto sameLight = [&](int k) {
        const auto u = static_cast<std::size_t>(k);
        return k >= 0 && u < old_lights.size() && u < d.light_polygons.size() && old_lights[u] == d.light_polygons[u];
    };
    // The links' hulls of the elements whose shape and whose source's stand are kept.
    d.link_hulls.resize(n);
    for (std::size_t e = 0; e < n; ++e) {
        auto& list = d.link_hulls[e];
        if (list.empty()) continue;
        if (!sameShape(static_cast<int>(e))) {
            list.clear();
            continue;
        }
        std::erase_if(list, [&](const auto& entry) { return !sameShape(entry.first); });
    }
    d_.assign(n, Eigen::Vector3d::Zero());
    tilde_ = d.base.radiance;
    rho_ = d.base.rho;
    d.probe_radiance = d.base.radiance;
    for (std::size_t e = 0; e < n; ++e) {
        if (radiosity_.isVirtualElement(static_cast<int>(e))) d.probe_radiance[e].setZero();
    }
    radiance_ = tilde_;
    d.face_dirty.assign(h.faceCount(), 1);
    d.worklist.clear();
    d.pending_list.clear();
    d.scale = 0.0;
    d.luma_scale = 0.0;
    for (int e : radiosity_.leaves(Mode::kReal)) {
        d.base_leaf[static_cast<std::size_t>(e)] = 1;
        d.scale = std::max(d.scale, d.base.radiance[static_cast<std::size_t>(e)].maxCoeff());
        d.luma_scale = std::max(d.luma_scale, lumaOf(d.base.radiance[static_cast<std::size_t>(e)]));
    }
    if (!(d.scale > 0.0)) d.scale = d.luma_scale = 1.0;
    {
        // Each face's mean B~ (luminance, area-weighted over its exposed leaves): a twentieth of it
        // floors the B~ changes are measured against.
        std::vector<double> sum(h.faceCount(), 0.0), area(h.faceCount(), 0.0);
        for (int e : radiosity_.leaves(Mode::kReal)) {
            const auto f = static_cast<std::size_t>(h[e].face);
            const double a = h[e].area * radiosity_.exposure(e);
            sum[f] += a * lumaOf(d.base.radiance[static_cast<std::size_t>(e)]);
            area[f] += a;
        }
        double total = 0.0, total_area = 0.0;
        for (std::size_t f = 0; f < h.faceCount(); ++f) {
            total += sum[f];
            total_area += area[f];
        }
        d.mean_luma = total_area > 0.0 ? total / total_area : 0.0;
        d.face_floor.assign(h.faceCount(), 0.0);
        for (std::size_t f = 0; f < h.faceCount(); ++f) d.face_floor[f] = area[f] > 0.0 ? 0.05 * sum[f] / area[f] : 0.0;
    }
    // Pull weights: a child's exposed area over its siblings' (Radiosity::pull's).
    for (std::size_t e = 0; e < n; ++e) {
        const Element& el = h[static_cast<int>(e)];
        if (el.child_count == 0) continue;
        double total = 0.0;
        for (int c = 0; c < el.child_count; ++c) {
            const Element& ch = h[el.first_child + c];
            if (!ch.buried) total += ch.area * radiosity_.exposure(el.first_child + c);
        }
        for (int c = 0; c < el.child_count; ++c) {
            const Element& ch = h[el.first_child + c];
            d.up[static_cast<std::size_t>(el.first_child + c)] =
                total > 0.0 && !ch.buried ? ch.area * radiosity_.exposure(el.first_child + c) / total : 0.0;
        }
    }
    // Bounds over each base element's leaves, for pruning the candidates' descent.
    d.rho_max.assign(n, 0.0);
    d.rho_mean.assign(n, 0.0);
    d.den_min.assign(n, 1e300);
    std::vector<double> area(n, 0.0);
    for (std::size_t i = n; i-- > 0;) {
        const Element& el = h[static_cast<int>(i)];
        if (el.retired || radiosity_.isVirtualFace(el.face)) continue;
        if (el.child_count == 0) {
            d.rho_max[i] = d.rho_mean[i] = lumaOf(d.base.rho[i]);
            d.den_min[i] = d.denominator(static_cast<int>(i));
            area[i] = el.area;
            continue;
        }
        for (int c = 0; c < el.child_count; ++c) {
            const auto k = static_cast<std::size_t>(el.first_child + c);
            d.rho_max[i] = std::max(d.rho_max[i], d.rho_max[k]);
            d.den_min[i] = std::min(d.den_min[i], d.den_min[k]);
            d.rho_mean[i] += area[k] * d.rho_mean[k];
            area[i] += area[k];
        }
        d.rho_mean[i] = area[i] > 0.0 ? d.rho_mean[i] / area[i] : 0.5;
    }
    // Step 2: base links by source.
    d.links = radiosity_.links();
    const std::size_t first_transfer = d.links.size();
    std::vector<int> transfer_origin;
    {
        std::vector<Link> through_clusters = radiosity_.clusterTransfers(&transfer_origin);
        d.links.insert(d.links.end(), through_clusters.begin(), through_clusters.end());
    }
    d.buildNodes(transfer_origin, first_transfer);
    const std::vector<Link>& links = d.links;
    d.link_offsets.assign(n + 1, 0);
    for (const Link& l : links) ++d.link_offsets[static_cast<std::size_t>(l.source) + 1];
    for (std::size_t i = 1; i <= n; ++i) d.link_offsets[i] += d.link_offsets[i - 1];
    d.link_by_source.assign(links.size(), 0);
    {
        std::vector<int> fill(d.link_offsets.begin(), d.link_offsets.end() - 1);
        for (std::size_t i = 0; i < links.size(); ++i) d.link_by_source[static_cast<std::size_t>(fill[static_cast<std::size_t>(links[i].source)]++)] = static_cast<int>(i);
    }
    d.corr_offsets.assign(n + 1, 0);
    d.corr_by_source.clear();
    // Step 3: the shaft index over the base links and the light shafts of the base leaves.
    std::vector<Shaft> shafts;
    shafts.reserve(links.size());
    // A link no object can make significant (its whole transfer, to the brightest leaf under its
    // receiver, below a twentieth of link_epsilon: a link to a small or dim source) is not indexed.
    d.shaft_link.clear();
    for (std::size_t i = 0; i < links.size(); ++i) {
        const Link& l = links[i];
        const double w = kPi * static_cast<double>(l.form_factor) * static_cast<double>(l.vis_real);
        const double strength = d.rho_max[static_cast<std::size_t>(l.receiver)] / kPi * w *
                                lumaOf(d.base.radiance[static_cast<std::size_t>(l.source)]) / d.den_min[static_cast<std::size_t>(l.receiver)];
        if (strength < 0.1 * options_.link_epsilon) continue;
        // Above the base leaves, twice the receiver's radius: the shaft of every element under it
        // lies inside (a descendant's ball is within 2 r of the centroid), so the index misses no
        // base leaf whose own shaft meets a ball.
        Shaft shaft = d.elementShaft(l.receiver, l.source);
        if (!d.base_leaf[static_cast<std::size_t>(l.receiver)]) shaft.ra *= 2.0;
        shafts.push_back(shaft);
        d.shaft_link.push_back(static_cast<int>(i));
    }
    d.link_shafts = static_cast<int>(shafts.size());
    d.light_shafts.clear();
    d.far_lights.clear();
    for (std::size_t k = 0; k < d.base.lights.size(); ++k) {
        const DirectSource& s = *d.base.lights[k].source;
        if (s.kind != DirectSource::Kind::kPolygon && s.kind != DirectSource::Kind::kPoint) {
            d.far_lights.push_back(static_cast<int>(k));
            continue;
        }
        const DirectColumn& col = *d.base.lights[k].column;
        for (int e : radiosity_.leaves(Mode::kReal)) {
            if (static_cast<std::size_t>(e) >= col.real.size() || !(col.real[static_cast<std::size_t>(e)] > 0.0f)) continue;
            d.light_shafts.emplace_back(e, static_cast<int>(k));
            shafts.push_back(d.lightShaft(e, static_cast<int>(k)));
        }
    }
    CL_TRY(d.index, ShaftIndex::build(std::move(shafts)));
    // Step 4: the virtual objects: their faces and local bounds; nothing placed yet.
    const std::size_t count = rays_.virtualCount();
    d.objects.clear();
    d.objects.resize(count);
    for (std::size_t o = 0; o < count && o < carried.size(); ++o) {
        std::vector<ObjectState::CarriedHull>& list = carried[o];
        std::erase_if(list, [&](const ObjectState::CarriedHull& c) {
            return !sameShape(c.element) || (c.source >= 0 ? !sameShape(c.source) : !sameLight(-1 - c.source));
        });
        std::sort(list.begin(), list.end(), [](const auto& x, const auto& y) { return std::pair(x.element, x.source) < std::pair(y.element, y.source); });
        d.objects[o].carried_hulls = std::move(list);
    }
    for (std::size_t f = radiosity_.realFaceCount(); f < h.faceCount(); ++f) {
        const int o = radiosity_.virtualObjectOfFace(static_cast<int>(f));
        if (o >= 0 && static_cast<std::size_t>(o) < count) d.objects[static_cast<std::size_t>(o)].faces.push_back(static_cast<int>(f));
    }
    for (std::size_t o = 0; o < count; ++o) {
        ObjectState& obj = d.objects[o];
        const Rigid3d object_from_world = radiosity_.virtualPoses()[o].inverse();
        Eigen::AlignedBox3d box;
        std::vector<Eigen::Vector3d> corners;
        for (int f : obj.faces) {
            for (const Eigen::Vector3d& c : radiosity_.face(f).corners()) {
                corners.push_back(object_from_world * c);
                box.extend(corners.back());
            }
        }
        obj.centre_local = box.isEmpty() ? Eigen::Vector3d(Eigen::Vector3d::Zero()) : Eigen::Vector3d(box.center());
        obj.sphere = radiosity_.sphereRadius(static_cast<int>(o)) > 0.0;
        obj.sphere_radius = radiosity_.sphereRadius(static_cast<int>(o));
        for (const Eigen::Vector3d& c : corners) obj.radius = std::max(obj.radius, (c - obj.centre_local).norm());
        // Rays are lifted off surfaces by the scene's epsilon: a little margin on the ball.
        obj.radius += 4.0 * rays_.epsilon();
    }
    // Fibonacci directions of the objects' exitance tables.
    d.table.clear();
    constexpr int kTable = 64;
    const double golden = kPi * (3.0 - std::sqrt(5.0));
    for (int i = 0; i < kTable; ++i) {
        const double z = 1.0 - 2.0 * (i + 0.5) / kTable;
        const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
        d.table.emplace_back(r * std::cos(golden * i), r * std::sin(golden * i), z);
    }
    d.table_lookup.assign(static_cast<std::size_t>(6 * Impl::kLookup * Impl::kLookup), 0);
    for (int face = 0; face < 6; ++face) {
        for (int j = 0; j < Impl::kLookup; ++j) {
            for (int i = 0; i < Impl::kLookup; ++i) {
                // The cell's centre on the cube's face, as a direction.
                const double u = 2.0 * (i + 0.5) / Impl::kLookup - 1.0, v = 2.0 * (j + 0.5) / Impl::kLookup - 1.0;
                Eigen::Vector3d w;
                const int axis = face / 2;
                const double sign = face % 2 == 0 ? 1.0 : -1.0;
                w[axis] = sign;
                w[(axis + 1) % 3] = u;
                w[(axis + 2) % 3] = v;
                w.normalize();
                std::size_t best = 0;
                for (std::size_t k = 1; k < d.table.size(); ++k) {
                    if (d.table[k].dot(w) > d.table[best].dot(w)) best = k;
                }
                d.table_lookup[static_cast<std::size_t>((face * Impl::kLookup + j) * Impl::kLookup + i)] = static_cast<std::uint8_t>(best);
            }
        }
    }
    has_base_ = true;
    return {};
}

}  // namespace commonlight::lighting

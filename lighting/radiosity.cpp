#include "lighting/radiosity.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <numbers>

#include "lighting/form_factor.h"
#include "lighting/sampling.h"

namespace commonlight::lighting {

namespace {

constexpr double kPi = std::numbers::pi;

std::vector<Face> concat(std::vector<Face> a, const std::vector<Face>& b) {
    a.insert(a.end(), b.begin(), b.end());
    return a;
}

double maxComponent(const Eigen::Vector3d& v) { return v.cwiseAbs().maxCoeff(); }

}  // namespace

Radiosity::Radiosity(std::vector<Face> real_faces, std::vector<Face> virtual_faces, std::vector<double> sphere_radius,
                     const RayScene& rays, RadiosityOptions options)
    : faces_(concat(std::move(real_faces), virtual_faces)),
      posed_(faces_),
      sphere_radius_(std::move(sphere_radius)),
      real_count_(faces_.size() - virtual_faces.size()),
      rays_(&rays),
      options_(options),
      hierarchy_(faces_),
      poses_(sphere_radius_.size(), Rigid3d::identity()) {
    link_offsets_.assign(hierarchy_.elements().size() + 1, 0);
}

void Radiosity::setVirtualPoses(const std::vector<Rigid3d>& world_from_object) {
    poses_ = world_from_object;
    poses_.resize(sphere_radius_.size(), Rigid3d::identity());
    for (std::size_t f = real_count_; f < faces_.size(); ++f) {
        posed_[f] = transformed(faces_[f], poses_[static_cast<std::size_t>(faces_[f].object_index)]);
    }
    virtual_links_dirty_ = true;
}

Eigen::Vector3d Radiosity::surfacePoint(int element, double a, double b) const {
    const ElementGeometry g = geometry(element);
    // Hard case: a sample on the element's border may lie on the plane of a touching face (a wall
    // corner, a box standing on a table), where a ray grazes that face. Keep samples 0.1% inside.
    constexpr double kMargin = 1e-3;
    a = kMargin + (1.0 - 2.0 * kMargin) * a;
    b = kMargin + (1.0 - 2.0 * kMargin) * b;
    if (g.triangle && a + b > 1.0) {
        a = 1.0 - a;
        b = 1.0 - b;
    }
    return onSurface(element, g.corner + a * g.edge_s + b * g.edge_t);
}

Eigen::Vector3d Radiosity::onSurface(int element, const Eigen::Vector3d& x) const {
    const int f = hierarchy_[element].face;
    if (!isVirtualFace(f)) return x;
    const auto object = static_cast<std::size_t>(faces_[static_cast<std::size_t>(f)].object_index);
    const double r = sphere_radius_[object];
    if (!(r > 0.0)) return x;
    // The flat facet lies inside the exact sphere Embree traces: use the sphere's surface.
    const Eigen::Vector3d c = poses_[object].translation;
    const Eigen::Vector3d d = x - c;
    return d.norm() > 0.0 ? Eigen::Vector3d(c + d.normalized() * r) : x;
}

void Radiosity::subdivideTo(double size, double virtual_size) {
    // Breadth-first so the budget, if it binds, leaves a uniform mesh rather than one deep corner.
    std::vector<int> queue;
    for (std::size_t f = 0; f < faces_.size(); ++f) queue.push_back(hierarchy_.root(static_cast<int>(f)));
    for (std::size_t q = 0; q < queue.size(); ++q) {
        const int e = queue[q];
        const Element& el = hierarchy_[e];
        const double target = isVirtualFace(el.face) ? virtual_size : size;
        if (std::max(el.size_s, el.size_t_) <= target) continue;
        if (hierarchy_.leafCount() >= options_.max_elements) break;
        if (hierarchy_.subdivide(e, std::min(options_.min_element_size, target))) {
            const Element& parent = hierarchy_[e];
            for (int c = 0; c < parent.child_count; ++c) queue.push_back(parent.first_child + c);
        }
    }
}

void Radiosity::markBuried() {
    // Boxes: real objects with six parallelogram faces (lighting/proxy_geometry.h numbering).
    std::map<int, std::vector<const Face*>> boxes;
    for (std::size_t f = 0; f < real_count_; ++f) boxes[faces_[f].object_index].push_back(&faces_[f]);
    std::erase_if(boxes, [](const auto& kv) {
        return kv.second.size() != 6 || std::any_of(kv.second.begin(), kv.second.end(), [](const Face* f) { return f->triangle; });
    });
    const double lift = 4.0 * rays_->epsilon();
    const auto inside = [&](const Eigen::Vector3d& p, int own_object) {
        for (const auto& [object, box_faces] : boxes) {
            if (object == own_object) continue;
            bool in = true;
            for (const Face* f : box_faces) {
                if ((p - f->origin).dot(f->normal) >= 0.0) {
                    in = false;
                    break;
                }
            }
            if (in) return true;
        }
        return false;
    };
    // A leaf partly inside a box (a floor element under a cabinet's edge) is split until its parts
    // are in or out (down to 4 x min_element_size): the buried part would otherwise count as lit surface.
    const double split_size = 4.0 * options_.min_element_size;
    for (std::size_t e = 0; e < hierarchy_.elements().size(); ++e) {
        const Element& el = hierarchy_.elements()[e];
        if (!el.leaf() || isVirtualFace(el.face) || el.buried) continue;
        const ElementGeometry g = geometry(static_cast<int>(e));
        const Face& f = faces_[static_cast<std::size_t>(el.face)];
        // A 5 x 5 grid of probes: a small box resting inside the element (books on a desk) is
        // caught, not only one across its corners.
        int inside_count = 0, probes = 0;
        for (int j = 0; j < 5; ++j) {
            for (int i = 0; i < 5; ++i) {
                double a = (i + 0.5) / 5.0, b = (j + 0.5) / 5.0;
                if (g.triangle && a + b > 1.0) continue;
                inside_count += inside(g.corner + a * g.edge_s + b * g.edge_t + lift * g.normal, f.object_index) ? 1 : 0;
                ++probes;
            }
        }
        const bool centre_in = inside(g.centroid + lift * g.normal, f.object_index);
        if (inside_count > 0 && inside_count < probes && hierarchy_.leafCount() + 4 < options_.max_elements &&
            hierarchy_.subdivide(static_cast<int>(e), split_size)) {
            continue;  // its children come later in the loop
        }
        if (centre_in) hierarchy_.setBuried(static_cast<int>(e), true);
    }
}

bool Radiosity::facing(int a, int b) const {
    const ElementGeometry ga = geometry(a), gb = geometry(b);
    const double tol = rays_->epsilon();
    const auto above = [&](const ElementGeometry& plane, const ElementGeometry& other) {
        for (const Eigen::Vector3d& c : other.polygon()) {
            if ((c - plane.corner).dot(plane.normal) > tol) return true;
        }
        return false;
    };
    return above(ga, gb) && above(gb, ga);
}

void Radiosity::refine(int r, int s, int depth) {
    if (!facing(r, s)) return;
    const ElementGeometry gr = geometry(r), gs = geometry(s);
    const auto source = gs.polygon();
    // The oracle (directed: r gathers from s). The point form factor to the whole source polygon is
    // exact, so what a link gets wrong is (1) the variation of F over the receiver (the gathered
    // irradiance is pushed down as uniform) and (2) visibility: a partly hidden source seen through
    // a few rays. Step 1: F at the receiver's corners and centre; refine the receiver where it varies.
    std::vector<Eigen::Vector3d> probes = gr.polygon();
    probes.push_back(gr.centroid);
    // The receiver's point nearest the source's centre: where F peaks when the source is close to
    // one side of a large receiver (a floor beside a table), which corner and centre probes miss.
    {
        Eigen::Matrix<double, 3, 2> b;
        b.col(0) = gr.edge_s;
        b.col(1) = gr.edge_t;
        Eigen::Vector2d ab = (b.transpose() * b).inverse() * (b.transpose() * (gs.centroid - gr.corner));
        ab = ab.cwiseMax(0.0).cwiseMin(1.0);
        if (gr.triangle && ab.sum() > 1.0) ab /= ab.sum();
        probes.push_back(gr.corner + ab.x() * gr.edge_s + ab.y() * gr.edge_t);
    }
    // Distance from the source's centre to the receiver, and the form factor a point that close
    // would see at most (A_s / (pi d^2), capped at 1): a source close to a large receiver makes F
    // peak somewhere the probes may not be (a table's side is seen edge-on from its own foot).
    const double nearest = (probes.back() - gs.centroid).norm();
    const double receiver_size = std::sqrt(hierarchy_[r].area);
    const double peak = std::min(1.0, hierarchy_[s].area / (std::numbers::pi * std::max(nearest * nearest, 1e-12)));
    double f_min = 1e300, f_max = 0.0;
    for (std::size_t i = 0; i < probes.size(); ++i) {
        // Probes pulled 1% towards the centre: a point on the shared edge of adjacent faces has no defined F.
        const Eigen::Vector3d x = probes[i] + 0.01 * (gr.centroid - probes[i]);
        const double f = pointToPolygon(x, gr.normal, source, gs.normal);
        f_min = std::min(f_min, f);
        f_max = std::max(f_max, f);
    }
    const double f_centre = f_max;
    const bool budget = hierarchy_.leafCount() + 3 < options_.max_elements;
    const double min_size = std::max(options_.min_element_size, options_.min_link_size);
    const auto can_descend = [&](int e) {
        return !hierarchy_[e].leaf() || (budget && hierarchy_.canSubdivide(e, min_size));
    };
    const bool close = nearest < receiver_size && peak > options_.link_epsilon;
    if (depth < 40 && (f_max - f_min > options_.link_epsilon || close) && can_descend(r)) {
        if (hierarchy_[r].leaf()) hierarchy_.subdivide(r, min_size);
        const int first = hierarchy_[r].first_child, count = hierarchy_[r].child_count;
        for (int c = 0; c < count; ++c) refine(first + c, s, depth + 1);
        return;
    }
    // Step 2 (the BF oracle on the source side): a source whose radiance varies over it (a floor
    // bright under a lamp and dark in a shadow) is split while F times that variation is more than
    // source_epsilon of the scene's largest radiance: the link would spread its mean.
    const double variation = static_cast<std::size_t>(s) < source_range_.size() ? source_range_[static_cast<std::size_t>(s)] : 1.0;
    if (depth < 40 && f_centre * variation > options_.source_epsilon && can_descend(s)) {
        if (hierarchy_[s].leaf()) hierarchy_.subdivide(s, min_size);
        const int first = hierarchy_[s].first_child, count = hierarchy_[s].child_count;
        for (int c = 0; c < count; ++c) refine(r, first + c, depth + 1);
        return;
    }
    // Step 3: a source seen in part (a shadow boundary across the link) is split so that
    // visibility is resolved where it matters.
    if (depth < 40 && f_centre > options_.link_epsilon * options_.partial_visibility_factor && (can_descend(s) || can_descend(r))) {
        constexpr int kProbeRays = 8;
        const std::uint64_t seed = hashCombine(options_.seed ^ 0x5bd1e995ull,
                                               hashCombine(static_cast<std::uint64_t>(r), static_cast<std::uint64_t>(s)));
        int visible = 0;
        for (int k = 0; k < kProbeRays; ++k) {
            const Eigen::Vector2d ur = stratified2d(seed, k, kProbeRays);
            const Eigen::Vector2d us = stratified2d(hash64(seed), (k * 3 + 1) % kProbeRays, kProbeRays);
            if (!rays_->occludedReal(surfacePoint(r, ur.x(), ur.y()), gr.normal, surfacePoint(s, us.x(), us.y()), gs.normal)) {
                ++visible;
            }
        }
        if (visible > 0 && visible < kProbeRays) {
            // Split the larger of the two: a receiver partly behind an occluder (a wall behind a
            // cabinet) must not share one visibility, nor must a source partly hidden from it.
            const bool split_receiver = can_descend(r) && (hierarchy_[r].area >= hierarchy_[s].area || !can_descend(s));
            if (split_receiver) {
                if (hierarchy_[r].leaf()) hierarchy_.subdivide(r, min_size);
                const int first = hierarchy_[r].first_child, count = hierarchy_[r].child_count;
                for (int c = 0; c < count; ++c) refine(first + c, s, depth + 1);
                return;
            }
            if (hierarchy_[s].leaf()) hierarchy_.subdivide(s, min_size);
            const int first = hierarchy_[s].first_child, count = hierarchy_[s].child_count;
            for (int c = 0; c < count; ++c) refine(r, first + c, depth + 1);
            return;
        }
    }
    addLink(r, s);
}

void Radiosity::setSourceRadiance(const std::vector<double>& radiance) {
    const auto& elements = hierarchy_.elements();
    std::vector<double> lo(elements.size(), 1e300), hi(elements.size(), -1e300);
    double scale = 0.0;
    for (std::size_t i = 0; i < elements.size(); ++i) {
        if (elements[i].leaf() && i < radiance.size() && !elements[i].buried) {
            lo[i] = hi[i] = radiance[i];
            scale = std::max(scale, radiance[i]);
        }
    }
    // Children follow parents: a backward sweep gathers each node's range.
    for (std::size_t i = elements.size(); i-- > 0;) {
        const Element& e = elements[i];
        for (int c = 0; c < e.child_count; ++c) {
            lo[i] = std::min(lo[i], lo[static_cast<std::size_t>(e.first_child + c)]);
            hi[i] = std::max(hi[i], hi[static_cast<std::size_t>(e.first_child + c)]);
        }
    }
    source_range_.assign(elements.size(), 0.0);
    for (std::size_t i = 0; i < elements.size(); ++i) {
        if (hi[i] >= lo[i] && scale > 0.0) source_range_[i] = (hi[i] - lo[i]) / scale;
    }
}

void Radiosity::addLink(int receiver, int source) { pending_pairs_.emplace_back(receiver, source); }

void Radiosity::computeLink(Link& link, bool virtual_only) const {
    const int r = link.receiver, s = link.source;
    const ElementGeometry gr = geometry(r), gs = geometry(s);
    const Element& er = hierarchy_[r];
    const Element& es = hierarchy_[s];
    const double rsize = std::sqrt(er.area), ssize = std::sqrt(es.area);
    const double distance = (gr.centroid - gs.centroid).norm();
    if (!virtual_only) {
        // F: Gauss rule over the receiver, exact point form factor to the source polygon.
        const int order = formFactorRule(distance, rsize, ssize);
        const auto poly = gs.polygon();
        double f = 0.0;
        for (const QuadraturePoint& q : quadratureRule(gr.corner, gr.edge_s, gr.edge_t, gr.triangle, order)) {
            f += q.weight * pointToPolygon(q.x, gr.normal, poly, gs.normal);
        }
        link.form_factor = static_cast<float>(f);
    }
    // V: jittered pairs of points, the same pairs for both worlds. Four pairs first; a link seen in
    // part gets sixteen (the largest a link keeps: its real occlusion is remembered per pair, so
    // that the virtual objects' part can be recomputed alone when they move).
    const std::uint64_t seed =
        hashCombine(options_.seed, hashCombine(static_cast<std::uint64_t>(r), static_cast<std::uint64_t>(s)));
    const bool touches_virtual = isVirtualElement(r) || isVirtualElement(s);
    const auto trace = [&](int n, int& unblocked_real, int& unblocked_all, std::uint16_t& blocked_mask) {
        unblocked_real = unblocked_all = 0;
        if (!virtual_only) blocked_mask = 0;
        for (int k = 0; k < n; ++k) {
            const Eigen::Vector2d ur = stratified2d(seed, k, n);
            const Eigen::Vector2d us = stratified2d(hash64(seed), (k * 7 + 3) % n, n);
            const Eigen::Vector3d xr = surfacePoint(r, ur.x(), ur.y());
            const Eigen::Vector3d xs = surfacePoint(s, us.x(), us.y());
            bool blocked_real;
            if (virtual_only) {
                blocked_real = (blocked_mask >> k) & 1u;
            } else {
                blocked_real = rays_->occludedReal(xr, gr.normal, xs, gs.normal);
                if (blocked_real) blocked_mask = static_cast<std::uint16_t>(blocked_mask | (1u << k));
            }
            if (!blocked_real) {
                ++unblocked_real;
                if (!rays_->occludedVirtual(xr, gr.normal, xs, gs.normal)) ++unblocked_all;
            }
        }
    };
    int unblocked_real = 0, unblocked_all = 0;
    std::uint16_t blocked_mask = virtual_only ? link.real_blocked : 0;
    int n = virtual_only ? link.samples : std::clamp(options_.visibility_rays, 1, 16);
    trace(n, unblocked_real, unblocked_all, blocked_mask);
    const bool partial = (unblocked_real > 0 && unblocked_real < n) || (unblocked_all > 0 && unblocked_all < n);
    if (!virtual_only && partial && n < 16) {
        n = 16;
        trace(n, unblocked_real, unblocked_all, blocked_mask);
    }
    link.samples = static_cast<std::uint8_t>(n);
    link.real_blocked = blocked_mask;
    link.vis_real = static_cast<float>(unblocked_real) / static_cast<float>(n);
    link.vis_all = static_cast<float>(unblocked_all) / static_cast<float>(n);
    link.touches_virtual = touches_virtual;
}

std::vector<Link> Radiosity::takePendingLinks() {
    std::vector<Link> out;
    out.reserve(pending_pairs_.size());
    for (const auto& [r, s] : pending_pairs_) {
        if (hierarchy_[r].buried || hierarchy_[s].buried) continue;
        Link l;
        l.receiver = r;
        l.source = s;
        out.push_back(l);
    }
    pending_pairs_.clear();
    tbb::parallel_for(std::size_t{0}, out.size(), [&](std::size_t i) { computeLink(out[i], false); });
    std::erase_if(out, [](const Link& l) { return l.form_factor <= 0.0f || l.vis_real + l.vis_all <= 0.0f; });
    return out;
}

void Radiosity::buildRealLinks() {
    links_.clear();
    pending_pairs_.clear();
    if (options_.hierarchical) {
        for (std::size_t fr = 0; fr < real_count_; ++fr) {
            for (std::size_t fs = 0; fs < real_count_; ++fs) {
                if (fr != fs) refine(hierarchy_.root(static_cast<int>(fr)), hierarchy_.root(static_cast<int>(fs)), 0);
            }
        }
    } else {
        // The baseline: every ordered pair of (unburied) leaves on different faces, no hierarchy.
        const std::vector<int> leaves_real = leaves(Mode::kReal);
        for (int r : leaves_real) {
            for (int s : leaves_real) {
                if (hierarchy_[r].face != hierarchy_[s].face && facing(r, s)) pending_pairs_.emplace_back(r, s);
            }
        }
    }
    links_ = takePendingLinks();
    virtual_links_dirty_ = true;
    sortLinks();
}

void Radiosity::updateVirtualLinks() {
    if (!virtual_links_dirty_) return;
    // Step 1: drop the links touching virtual elements; recompute the real links' virtual part.
    std::erase_if(links_, [](const Link& l) { return l.touches_virtual; });
    tbb::parallel_for(std::size_t{0}, links_.size(), [&](std::size_t i) { computeLink(links_[i], true); });
    // Step 2 (against the spread shadow, seed 000 sec. 6.2): a real link that a virtual object
    // blocks in part would darken its whole receiver, however coarse. Such links are replaced by
    // links from each leaf under the receiver, each with its own visibility.
    pending_pairs_.clear();
    {
        std::vector<Link> kept;
        kept.reserve(links_.size());
        std::vector<int> leaves_under;
        for (const Link& l : links_) {
            const bool shadowed = l.vis_all < l.vis_real - 1e-6f;
            if (!shadowed || hierarchy_[l.receiver].leaf()) {
                kept.push_back(l);
                continue;
            }
            leaves_under.clear();
            hierarchy_.leavesUnder(l.receiver, leaves_under);
            for (int leaf : leaves_under) {
                if (!hierarchy_[leaf].buried) pending_pairs_.emplace_back(leaf, l.source);
            }
        }
        links_ = std::move(kept);
        std::vector<Link> pushed = takePendingLinks();
        links_.insert(links_.end(), pushed.begin(), pushed.end());
    }
    // Step 3: links between virtual elements and everything else, by the same oracle, both ways.
    pending_pairs_.clear();
    for (std::size_t fv = real_count_; fv < faces_.size(); ++fv) {
        for (std::size_t f = 0; f < faces_.size(); ++f) {
            if (f == fv) continue;
            const int rv = hierarchy_.root(static_cast<int>(fv)), rf = hierarchy_.root(static_cast<int>(f));
            if (f >= real_count_) {
                // Between virtual faces: each ordered pair once (from the loop over fv), other objects only.
                if (faces_[f].object_index != faces_[fv].object_index) refine(rv, rf, 0);
                continue;
            }
            refine(rv, rf, 0);
            refine(rf, rv, 0);
        }
    }
    std::vector<Link> added = takePendingLinks();
    links_.insert(links_.end(), added.begin(), added.end());
    sortLinks();
    virtual_links_dirty_ = false;
}

void Radiosity::sortLinks() {
    std::stable_sort(links_.begin(), links_.end(), [](const Link& x, const Link& y) { return x.receiver < y.receiver; });
    link_offsets_.assign(hierarchy_.elements().size() + 1, 0);
    for (const Link& l : links_) ++link_offsets_[static_cast<std::size_t>(l.receiver) + 1];
    for (std::size_t i = 1; i < link_offsets_.size(); ++i) link_offsets_[i] += link_offsets_[i - 1];
}

int Radiosity::linkCount(Mode mode) const {
    if (mode == Mode::kAll) return static_cast<int>(links_.size());
    return static_cast<int>(std::count_if(links_.begin(), links_.end(), [](const Link& l) { return !l.touches_virtual; }));
}

std::vector<int> Radiosity::leaves(Mode mode) const {
    std::vector<int> out;
    const auto& elements = hierarchy_.elements();
    for (std::size_t e = 0; e < elements.size(); ++e) {
        if (!elements[e].leaf() || elements[e].buried) continue;
        if (mode == Mode::kReal && isVirtualFace(elements[e].face)) continue;
        out.push_back(static_cast<int>(e));
    }
    return out;
}

void Radiosity::pull(std::vector<Eigen::Vector3d>& radiance) const {
    const auto& elements = hierarchy_.elements();
    // Children always have larger indices than their parent: one backward sweep pulls everything.
    for (std::size_t i = elements.size(); i-- > 0;) {
        const Element& e = elements[i];
        if (e.leaf()) continue;
        Eigen::Vector3d sum = Eigen::Vector3d::Zero();
        double area = 0.0;
        for (int c = 0; c < e.child_count; ++c) {
            const Element& child = elements[static_cast<std::size_t>(e.first_child + c)];
            if (child.buried) continue;
            sum += child.area * radiance[static_cast<std::size_t>(e.first_child + c)];
            area += child.area;
        }
        radiance[i] = area > 0.0 ? Eigen::Vector3d(sum / area) : Eigen::Vector3d::Zero();
    }
}

std::vector<Eigen::Vector3d> Radiosity::gatherIndirect(Mode mode, const std::vector<Eigen::Vector3d>& radiance) const {
    const auto& elements = hierarchy_.elements();
    std::vector<Eigen::Vector3d> gathered(elements.size(), Eigen::Vector3d::Zero());
    for (const Link& l : links_) {
        if (mode == Mode::kReal && l.touches_virtual) continue;
        const double fv = l.form_factor * (mode == Mode::kReal ? l.vis_real : l.vis_all);
        gathered[static_cast<std::size_t>(l.receiver)] += kPi * fv * radiance[static_cast<std::size_t>(l.source)];
    }
    // Push: every leaf receives what its ancestors gathered (parents precede children).
    for (std::size_t i = 0; i < elements.size(); ++i) {
        const Element& e = elements[i];
        for (int c = 0; c < e.child_count; ++c) gathered[static_cast<std::size_t>(e.first_child + c)] += gathered[i];
    }
    for (std::size_t i = 0; i < elements.size(); ++i) {
        if (!elements[i].leaf()) gathered[i].setZero();
    }
    return gathered;
}

Solution Radiosity::solve(Mode mode, const std::vector<Eigen::Vector3d>& rho, const std::vector<Eigen::Vector3d>& emission,
                          const std::vector<Eigen::Vector3d>& direct) const {
    const auto& elements = hierarchy_.elements();
    const std::size_t n = elements.size();
    Solution out;
    out.radiance.assign(n, Eigen::Vector3d::Zero());
    out.irradiance.assign(n, Eigen::Vector3d::Zero());
    out.indirect.assign(n, Eigen::Vector3d::Zero());
    const std::vector<int> active = leaves(mode);
    std::vector<char> in_mode(n, 0);
    for (int e : active) in_mode[static_cast<std::size_t>(e)] = 1;
    // Step 1: the first estimate: emission plus reflected direct light.
    for (int e : active) {
        const auto i = static_cast<std::size_t>(e);
        out.radiance[i] = emission[i] + rho[i].cwiseProduct(direct[i]) / kPi;
    }
    pull(out.radiance);
    // Step 2: Jacobi iterations of gather + push-pull until the largest change is small.
    std::vector<Eigen::Vector3d> next(n);
    double scale = 0.0;
    for (int e : active) scale = std::max(scale, maxComponent(out.radiance[static_cast<std::size_t>(e)]));
    int iteration = 0;
    double residual = scale > 0.0 ? 1.0 : 0.0;
    while (residual > options_.residual && iteration < options_.max_iterations) {
        ++iteration;
        const std::vector<Eigen::Vector3d> gathered = gatherIndirect(mode, out.radiance);
        double change = 0.0;
        for (int e : active) {
            const auto i = static_cast<std::size_t>(e);
            next[i] = emission[i] + rho[i].cwiseProduct(direct[i] + gathered[i]) / kPi;
            change = std::max(change, maxComponent(next[i] - out.radiance[i]));
            out.indirect[i] = gathered[i];
        }
        for (int e : active) out.radiance[static_cast<std::size_t>(e)] = next[static_cast<std::size_t>(e)];
        pull(out.radiance);
        for (int e : active) scale = std::max(scale, maxComponent(out.radiance[static_cast<std::size_t>(e)]));
        residual = scale > 0.0 ? change / scale : 0.0;
    }
    for (int e : active) {
        const auto i = static_cast<std::size_t>(e);
        out.irradiance[i] = direct[i] + out.indirect[i];
    }
    out.summary.iterations = iteration;
    out.summary.residual = residual;
    out.summary.converged = residual <= options_.residual;
    out.summary.elements = static_cast<int>(active.size());
    out.summary.links = linkCount(mode);
    return out;
}

}  // namespace commonlight::lighting

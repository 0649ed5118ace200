#include "lighting/radiosity.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
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
    // Boxes: real objects with six parallelogram faces (lighting/proxy_geometry.h numbering).
    std::map<int, std::vector<const Face*>> boxes;
    for (std::size_t f = 0; f < real_count_; ++f) boxes[faces_[f].object_index].push_back(&faces_[f]);
    for (const auto& [object, box_faces] : boxes) {
        if (box_faces.size() != 6 || std::any_of(box_faces.begin(), box_faces.end(), [](const Face* f) { return f->triangle; })) continue;
        BoxPlanes b;
        b.object = object;
        for (std::size_t i = 0; i < 6; ++i) {
            b.origin[i] = box_faces[i]->origin;
            b.normal[i] = box_faces[i]->normal;
        }
        boxes_.push_back(b);
    }
    for (std::size_t f = 0; f < real_count_; ++f) {
        const Face& face = faces_[f];
        Eigen::Matrix<double, 3, 2> basis;
        basis.col(0) = face.edge_s;
        basis.col(1) = face.edge_t;
        ContactFace c;
        c.object = face.object_index;
        c.origin = face.origin;
        c.normal = face.normal;
        c.dual = (basis.transpose() * basis).inverse() * basis.transpose();
        c.triangle = face.triangle;
        contact_faces_.push_back(c);
    }
}

bool Radiosity::insideOtherBox(const Eigen::Vector3d& x, const Eigen::Vector3d& normal, int own_object) const {
    for (const BoxPlanes& b : boxes_) {
        if (b.object == own_object) continue;
        bool in = true;
        for (std::size_t i = 0; i < 6 && in; ++i) in = (x - b.origin[i]).dot(b.normal[i]) < 0.0;
        if (in) return true;
    }
    // Pressed against another proxy's face (a cabinet standing on the floor plane, its bottom on
    // the floor and the floor under it): the two faces look at each other from no distance. `x` is
    // lifted 4 epsilon off its own surface, so it lies just behind the face it touches.
    const double contact = 8.0 * rays_->epsilon();
    for (const ContactFace& c : contact_faces_) {
        if (c.object == own_object || normal.dot(c.normal) > -0.9) continue;
        const double height = (x - c.origin).dot(c.normal);
        if (height > 0.0 || height < -contact) continue;
        const Eigen::Vector2d ab = c.dual * (x - c.origin);
        if (insideUnit(ab.x(), ab.y(), c.triangle, 0.0)) return true;
    }
    return false;
}

bool Radiosity::hidden(int element, const Eigen::Vector3d& x) const {
    const Element& el = hierarchy_[element];
    if (!(el.exposed >= 0.0f && el.exposed < 1.0f) || isVirtualFace(el.face)) return false;
    // Lifted off the surface: a point of the floor under a cabinet lies on the cabinet's bottom plane.
    const Face& f = faces_[static_cast<std::size_t>(el.face)];
    return insideOtherBox(x + 4.0 * rays_->epsilon() * f.normal, f.normal, f.object_index);
}

double Radiosity::exposure(int element) const {
    const float e = hierarchy_[element].exposed;
    return e >= 0.0f ? static_cast<double>(e) : 1.0;
}

std::vector<QuadraturePoint> Radiosity::exposedRule(int element, int order) const {
    const ElementGeometry g = geometry(element);
    if (exposure(element) >= 1.0) return quadratureRule(g.corner, g.edge_s, g.edge_t, g.triangle, order);
    // A rule cut by a box's outline is no longer a Gauss rule of its order: the finest one, cut.
    std::vector<QuadraturePoint> rule = quadratureRule(g.corner, g.edge_s, g.edge_t, g.triangle, 8);
    std::vector<QuadraturePoint> kept;
    double total = 0.0;
    for (const QuadraturePoint& q : rule) {
        if (hidden(element, q.x)) continue;
        kept.push_back(q);
        total += q.weight;
    }
    if (!(total > 0.0)) return rule;
    for (QuadraturePoint& q : kept) q.weight /= total;
    return kept;
}

void Radiosity::setVirtualPoses(const std::vector<Rigid3d>& world_from_object) {
    poses_ = world_from_object;
    poses_.resize(sphere_radius_.size(), Rigid3d::identity());
    for (std::size_t f = real_count_; f < faces_.size(); ++f) {
        posed_[f] = transformed(faces_[f], poses_[static_cast<std::size_t>(faces_[f].object_index)]);
    }
}

Eigen::Vector3d Radiosity::surfacePoint(int element, double a, double b) const { return surfacePoint(element, geometry(element), a, b); }

Eigen::Vector3d Radiosity::surfacePoint(int element, const ElementGeometry& g, double a, double b) const {
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

void Radiosity::measureExposure(int e) {
    const Element& el = hierarchy_[e];
    if (!el.leaf() || el.exposed >= 0.0f) return;
    if (isVirtualFace(el.face) || el.buried || (boxes_.empty() && contact_faces_.size() < 2)) {
        hierarchy_.setExposed(e, el.buried ? 0.0f : 1.0f);
        return;
    }
    const double lift = 4.0 * rays_->epsilon();
    const ElementGeometry g = geometry(e);
    const Face& f = faces_[static_cast<std::size_t>(el.face)];
    // The grid's points below are convex combinations of the element's corners lifted like them.
    // Where every other box has a plane with every lifted corner outside it, and every contact
    // face it could touch has them all above it or all beyond its reach, no point is inside:
    // fully exposed, as the grid would find, without it (most new leaves of a move lie far from
    // any box). A corner within `margin` of a plane (rounding) leaves the answer to the grid.
    const Eigen::Vector3d up = lift * g.normal;
    const std::array<Eigen::Vector3d, 4> corners = {g.corner + up, g.corner + g.edge_s + up, g.corner + g.edge_t + up,
                                                    g.corner + g.edge_s + g.edge_t + up};
    const std::size_t corner_count = g.triangle ? 3 : 4;
    constexpr double margin = 1e-9;
    const auto clear = [&] {
        for (const BoxPlanes& b : boxes_) {
            if (b.object == f.object_index) continue;
            bool separated = false;
            for (std::size_t i = 0; i < 6 && !separated; ++i) {
                separated = true;
                for (std::size_t k = 0; k < corner_count && separated; ++k) {
                    separated = (corners[k] - b.origin[i]).dot(b.normal[i]) >= margin;
                }
            }
            if (!separated) return false;
        }
        const double contact = 8.0 * rays_->epsilon();
        for (const ContactFace& c : contact_faces_) {
            if (c.object == f.object_index || g.normal.dot(c.normal) > -0.9) continue;
            bool above = true, beyond = true;
            for (std::size_t k = 0; k < corner_count; ++k) {
                const double height = (corners[k] - c.origin).dot(c.normal);
                above = above && height > margin;
                beyond = beyond && height < -contact - margin;
            }
            if (!above && !beyond) return false;
        }
        return true;
    };
    if (clear()) {
        hierarchy_.setExposed(e, 1.0f);
        return;
    }
    // An 8 x 8 grid of probes: a small box resting inside the element (books on a desk) is
    // caught, not only one across its corners. A leaf partly inside is not split along the
    // box's outline: its light is that of its exposed part (hidden(), exposedRule()), which
    // is what a camera sees of it (measured: splitting to 4 cm along contact lines made the
    // room 35% more elements for no gain in element radiance against the path tracer).
    constexpr int kGrid = 8;
    int inside_count = 0, probes = 0;
    for (int j = 0; j < kGrid; ++j) {
        for (int i = 0; i < kGrid; ++i) {
            const double a = (i + 0.5) / kGrid, b = (j + 0.5) / kGrid;
            if (g.triangle && a + b > 1.0) continue;
            inside_count += insideOtherBox(g.corner + a * g.edge_s + b * g.edge_t + lift * g.normal, g.normal, f.object_index) ? 1 : 0;
            ++probes;
        }
    }
    const float exposed = probes > 0 ? static_cast<float>(probes - inside_count) / static_cast<float>(probes) : 1.0f;
    hierarchy_.setExposed(e, exposed);
    if (inside_count == probes) hierarchy_.setBuried(e, true);
}

void Radiosity::markBuried() {
    // Geometry never changes, so each element is measured once.
    for (std::size_t e = 0; e < hierarchy_.elements().size(); ++e) measureExposure(static_cast<int>(e));
    // Parents: the area-weighted exposure of their children (children follow their parents).
    const auto& elements = hierarchy_.elements();
    for (std::size_t i = elements.size(); i-- > 0;) {
        const Element& el = elements[i];
        if (el.child_count == 0) continue;  // leaves, and retired elements (kept as they were)
        double sum = 0.0;
        for (int c = 0; c < el.child_count; ++c) {
            const Element& child = elements[static_cast<std::size_t>(el.first_child + c)];
            sum += child.buried ? 0.0 : child.area * std::max(0.0f, child.exposed);
        }
        hierarchy_.setExposed(static_cast<int>(i), static_cast<float>(std::clamp(sum / el.area, 0.0, 1.0)));
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

Radiosity::Shelter Radiosity::measureShelter(int element) const {
    // 16 stratified points of the element's exposed part, 8 cosine-weighted directions each (the
    // fractions are cosine-weighted like the light a point gathers).
    constexpr int kPoints = 16, kRays = 8;
    const ElementGeometry g = geometry(element);
    const Eigen::Vector3d n = g.normal;
    const Eigen::Vector3d u = (std::abs(n.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY()).cross(n).normalized();
    const Eigen::Vector3d v = n.cross(u);
    const std::uint64_t seed = hashCombine(options_.seed ^ 0x51e17e5ull, static_cast<std::uint64_t>(element));
    Shelter out;
    double sum = 0.0, hits = 0.0;
    int points = 0;
    float lo = 1.0f, hi = 0.0f;
    for (int p = 0; p < kPoints; ++p) {
        const Eigen::Vector2d ab = stratified2d(seed, p, kPoints);
        const Eigen::Vector3d x = surfacePoint(element, ab.x(), ab.y());
        if (hidden(element, x)) continue;
        const Eigen::Vector3d origin = x + 4.0 * rays_->epsilon() * n;
        int sheltered = 0;
        for (int k = 0; k < kRays; ++k) {
            // Malley: a uniform point on the disc lifted to the hemisphere is cosine-distributed.
            const Eigen::Vector2d w = stratified2d(hashCombine(seed, static_cast<std::uint64_t>(p)), k, kRays);
            const double r = std::sqrt(w.x()), phi = 2.0 * kPi * w.y();
            const Eigen::Vector3d d = r * std::cos(phi) * u + r * std::sin(phi) * v + std::sqrt(std::max(0.0, 1.0 - w.x())) * n;
            const RayHit h = rays_->intersectReal(origin, d);
            if (h.kind != HitKind::kNone && h.distance < options_.shelter_distance) ++sheltered;
            if (h.kind == HitKind::kRealFace) hits += 1.0;
        }
        const float f = static_cast<float>(sheltered) / kRays;
        lo = std::min(lo, f);
        hi = std::max(hi, f);
        sum += f;
        ++points;
    }
    if (points == 0) return {0.0f, 0.0f, 0.0f, -1.0f};  // hit unknown: nothing of it is exposed where probed
    out.mean = static_cast<float>(sum / points);
    out.lo = lo;
    out.hi = hi;
    out.hit = static_cast<float>(hits / (points * kRays));
    return out;
}

void Radiosity::enforceConsistency() {
    const auto& elements = hierarchy_.elements();
    for (int round = 0; round < options_.consistency_rounds; ++round) {
        // Step 1: every leaf's F x V summed over its links and its ancestors'.
        std::vector<double> own(elements.size(), 0.0);
        for (const Link& l : links_) {
            own[static_cast<std::size_t>(l.receiver)] += l.form_factor * l.vis_real;
        }
        clusterFormFactors(own);
        for (std::size_t i = 0; i < elements.size(); ++i) {
            for (int c = 0; c < elements[i].child_count; ++c) own[static_cast<std::size_t>(elements[i].first_child + c)] += own[i];
        }
        // Step 2: the ancestors of the leaves where that sum is not what the leaf sees.
        measureShelters();
        std::vector<char> push(elements.size(), 0);
        int bad = 0;
        for (int e : leaves(Mode::kReal)) {
            const Shelter sh = shelter(e);
            if (sh.hit < 0.0f || std::abs(own[static_cast<std::size_t>(e)] - sh.hit) <= options_.consistency_tolerance) continue;
            ++bad;
            for (int a = elements[static_cast<std::size_t>(e)].parent; a >= 0; a = elements[static_cast<std::size_t>(a)].parent) {
                push[static_cast<std::size_t>(a)] = 1;
            }
        }
        if (bad == 0) break;
        // Step 3: their links move one level down, to each child with its own F and V.
        std::vector<Link> kept;
        kept.reserve(links_.size());
        pending_pairs_.clear();
        for (const Link& l : links_) {
            if (!push[static_cast<std::size_t>(l.receiver)]) {
                kept.push_back(l);
                continue;
            }
            const Element& r = elements[static_cast<std::size_t>(l.receiver)];
            for (int c = 0; c < r.child_count; ++c) {
                if (!elements[static_cast<std::size_t>(r.first_child + c)].buried) pending_pairs_.emplace_back(r.first_child + c, l.source);
            }
        }
        if (pending_pairs_.empty()) break;
        links_ = std::move(kept);
        std::vector<Link> pushed = takePendingLinks();
        links_.insert(links_.end(), pushed.begin(), pushed.end());
        finishClusterLinks();
    }
}

void Radiosity::measureShelters() {
    shelter_.resize(hierarchy_.elements().size());
    std::vector<int> todo;
    for (int e : leaves(Mode::kReal)) {
        if (!shelter_[static_cast<std::size_t>(e)].known()) todo.push_back(e);
    }
    tbb::parallel_for(std::size_t{0}, todo.size(), [&](std::size_t i) {
        shelter_[static_cast<std::size_t>(todo[i])] = measureShelter(todo[i]);
    });
}

Radiosity::Shelter Radiosity::shelter(int element) {
    if (shelter_.size() < hierarchy_.elements().size()) shelter_.resize(hierarchy_.elements().size());
    Shelter& s = shelter_[static_cast<std::size_t>(element)];
    if (s.known()) return s;
    const Element& e = hierarchy_[element];
    if (isVirtualFace(e.face) || e.buried) {
        s = {0.0f, 0.0f, 0.0f, 0.0f};
    } else if (e.leaf()) {
        s = measureShelter(element);
    } else {
        Shelter agg{0.0f, 1.0f, 0.0f, 0.0f};
        double area = 0.0, sum = 0.0, hit = 0.0;
        for (int c = 0; c < e.child_count; ++c) {
            const Shelter cs = shelter(e.first_child + c);
            const Element& child = hierarchy_[e.first_child + c];
            if (child.buried) continue;
            agg.lo = std::min(agg.lo, cs.lo);
            agg.hi = std::max(agg.hi, cs.hi);
            sum += child.area * cs.mean;
            hit += child.area * cs.hit;
            area += child.area;
        }
        agg.mean = area > 0.0 ? static_cast<float>(sum / area) : 0.0f;
        agg.hit = area > 0.0 ? static_cast<float>(hit / area) : 0.0f;
        if (agg.lo > agg.hi) agg.lo = agg.hi = agg.mean;
        shelter_[static_cast<std::size_t>(element)] = agg;
        return agg;
    }
    return s;
}

double Radiosity::sourceStat(const std::vector<double>& stat, int element) const {
    // Elements made after setSourceRadiance() take their nearest measured ancestor's value (a
    // child's peak and spread are at most its parent's); without any, they count fully.
    for (int e = element; e >= 0; e = hierarchy_[e].parent) {
        if (static_cast<std::size_t>(e) < stat.size()) return stat[static_cast<std::size_t>(e)];
    }
    return 1.0;
}

void Radiosity::refine(int r, int s, int depth) {
    if (hierarchy_[r].buried || hierarchy_[s].buried || !facing(r, s)) return;
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
    double min_size = std::max(options_.min_element_size, options_.min_link_size);
    // Narrow gaps (a cabinet 5 cm from a wall): facing parallel elements closer than min_link_size
    // exchange their light over the scale of their separation, so links between them may descend
    // to gap_resolution x that separation.
    // (Between real proxies only: links to virtual objects are rebuilt as they move, and their
    // shadows are refined by the estimator where they fall.)
    if (!isVirtualElement(r) && !isVirtualElement(s) && gr.normal.dot(gs.normal) < -0.9) {
        const double separation = (gs.centroid - gr.centroid).dot(gr.normal);
        // Only a gap deeper than a few times its width keeps light out: a thin face (a shelf's
        // 3 cm edge 5 cm from the wall, a monitor's underside) is not one.
        const Face& fr = face(hierarchy_[r].face);
        const Face& fs = face(hierarchy_[s].face);
        const double gap_depth = std::min({fr.lengthS(), fr.lengthT(), fs.lengthS(), fs.lengthT()});
        if (separation > 0.0 && gap_depth > 3.0 * separation && options_.gap_resolution * separation < min_size) {
            min_size = std::max(options_.min_element_size, options_.gap_resolution * separation);
        }
    }
    const auto can_descend = [&](int e) {
        return !hierarchy_[e].leaf() || (budget && hierarchy_.canSubdivide(e, min_size));
    };
    // The BF oracle on the receiver side: the variation of F over the receiver times the source's
    // radiance (its largest, relative to the scene's largest) is the error in the radiance the link
    // pushes down as uniform; dim sources need coarser links than a lamp-lit desk does.
    const double weight = sourceStat(source_peak_, s);
    // Near field (a receiver larger than its distance to the source: a wall 5 cm behind a cabinet,
    // a floor along a wall): the radiance estimate knows nothing at that scale, so the source's
    // weight is not trusted there.
    const bool close = nearest < receiver_size && peak > options_.link_epsilon;
    // A receiver partly sheltered (a wall partly behind a cabinet) is split whatever the source.
    const Shelter shelter_r = isVirtualElement(r) ? Shelter{0.0f, 0.0f, 0.0f, 0.0f} : shelter(r);
    const bool uneven = shelter_r.hi - shelter_r.lo > options_.shelter_epsilon;
    // ... down to shelter_resolution, below min_link_size: the outline of what shelters it (the
    // ceiling panel's outline 1 cm under the ceiling, a cabinet's edge) is a visibility edge for
    // every source at once.
    const double shelter_size = std::max(options_.min_element_size, std::min(min_size, options_.shelter_resolution));
    // (Real sources only: links to virtual objects are rebuilt as they move.)
    const bool split_uneven = uneven && !isVirtualElement(s) && (!hierarchy_[r].leaf() || (budget && hierarchy_.canSubdivide(r, shelter_size)));
    if (depth < 40 && ((((f_max - f_min) * weight > options_.link_epsilon || close) && can_descend(r)) || split_uneven)) {
        if (hierarchy_[r].leaf()) hierarchy_.subdivide(r, split_uneven && !can_descend(r) ? shelter_size : min_size);
        const int first = hierarchy_[r].first_child, count = hierarchy_[r].child_count;
        for (int c = 0; c < count; ++c) refine(first + c, s, depth + 1);
        return;
    }
    // Step 2 (the BF oracle on the source side): a source whose radiance varies over it (a floor
    // bright under a lamp and dark in a shadow) is split while F times that variation is more than
    // source_epsilon of the scene's largest radiance: the link would spread its mean.
    const double variation = sourceStat(source_range_, s);
    // Near field: a source much larger than its distance to the receiver (the cabinet's side 5 cm
    // from the wall behind it) is seen through a small part of it, not through its mean radiance.
    const double source_size = std::sqrt(hierarchy_[s].area);
    const bool near_field = f_centre > options_.link_epsilon && source_size > 2.0 * gs.distanceTo(gr.centroid);
    if (depth < 40 && (f_centre * variation > options_.source_epsilon || near_field) && can_descend(s)) {
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
            const SamplePair pair = stratifiedPair(seed, k, kProbeRays);
            if (!rays_->occludedReal(surfacePoint(r, pair.first.x(), pair.first.y()), gr.normal,
                                     surfacePoint(s, pair.second.x(), pair.second.y()), gs.normal)) {
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
    source_peak_.assign(elements.size(), 0.0);
    for (std::size_t i = 0; i < elements.size(); ++i) {
        if (hi[i] >= lo[i] && scale > 0.0) {
            source_range_[i] = (hi[i] - lo[i]) / scale;
            source_peak_[i] = hi[i] / scale;
        }
        // Virtual elements are not in the estimate (and may glow): they count as the brightest;
        // so does everything when there is no estimate (a scene without lights).
        if (isVirtualFace(elements[i].face) || !(scale > 0.0)) source_peak_[i] = 1.0;
    }
}

void Radiosity::addLink(int receiver, int source) { pending_pairs_.emplace_back(receiver, source); }

void Radiosity::computeLink(Link& link) const {
    const int r = link.receiver, s = link.source;
    const ElementGeometry gr = geometry(r), gs = geometry(s);
    const Element& er = hierarchy_[r];
    const Element& es = hierarchy_[s];
    const double rsize = std::sqrt(er.area), ssize = std::sqrt(es.area);
    const double distance = (gr.centroid - gs.centroid).norm();
    {
        // F: Gauss rule over the receiver, exact point form factor to the source polygon.
        const int order = formFactorRule(distance, rsize, ssize);
        const auto poly = gs.polygon();
        double f = 0.0;
        for (const QuadraturePoint& q : exposedRule(r, order)) {
            f += q.weight * pointToPolygon(q.x, gr.normal, poly, gs.normal);
        }
        link.form_factor = static_cast<float>(f);
    }
    // V: jittered pairs of points. Four pairs first; a link seen in part gets sixteen (the
    // largest a link keeps: its occlusion is remembered per pair). Each pair counts by its kernel
    // cos_r cos_s / d^2 (V = sum of the unblocked pairs' kernels over the sum of all): a pair that
    // squeezes through a narrow gap at a grazing angle (a wall behind a cabinet seeing the
    // ceiling) carries almost none of the form factor, and a plain fraction of unblocked pairs
    // would count it fully. Hard case: the kernel diverges where two elements touch; the distance
    // is floored at 5% of the smaller element's size (the weights only rank pairs within a link).
    const std::uint64_t seed =
        hashCombine(options_.seed, hashCombine(static_cast<std::uint64_t>(r), static_cast<std::uint64_t>(s)));
    const double floor2 = std::pow(0.05 * std::min(rsize, ssize), 2);
    const bool receiver_partial = exposure(r) < 1.0;
    struct Tally {
        int valid = 0, unblocked = 0;
        double total = 0.0, open = 0.0;
    };
    const auto trace = [&](int n, Tally& tally, std::uint16_t& blocked_mask, std::uint64_t pair_seed) {
        tally = {};
        blocked_mask = 0;
        for (int k = 0; k < n; ++k) {
            const SamplePair pair = stratifiedPair(pair_seed, k, n);
            const Eigen::Vector3d xr = surfacePoint(r, gr, pair.first.x(), pair.first.y());
            const Eigen::Vector3d xs = surfacePoint(s, gs, pair.second.x(), pair.second.y());
            // The receiver's light is that of its exposed part: a pair starting under a box is
            // no part of it (a source point under a box is blocked by the box, which is right).
            if (receiver_partial && hidden(r, xr)) {
                blocked_mask = static_cast<std::uint16_t>(blocked_mask | (1u << k));
                continue;
            }
            ++tally.valid;
            const Eigen::Vector3d d = xs - xr;
            const double d2 = std::max(d.squaredNorm(), floor2);
            const double w = std::max(0.0, gr.normal.dot(d)) * std::max(0.0, -gs.normal.dot(d)) / (d2 * d2);
            tally.total += w;
            if (rays_->occludedReal(xr, gr.normal, xs, gs.normal)) {
                blocked_mask = static_cast<std::uint16_t>(blocked_mask | (1u << k));
            } else {
                ++tally.unblocked;
                tally.open += w;
            }
        }
    };
    // How many pairs a link gets is decided by a pilot of its own, not by the pairs that then
    // estimate V: stopping at four clear pairs would read a link 20% blocked as clear 41% of the
    // time (0.8^4), and every partly blocked link would come out too visible (measured: +8% of
    // the light a desk element under the monitor gathered).
    int n = std::clamp(options_.visibility_rays, 1, 16);
    Tally pilot;
    std::uint16_t pilot_mask = 0;
    trace(n, pilot, pilot_mask, hash64(seed ^ 0x9f1e7ull));
    const bool partial = pilot.unblocked > 0 && pilot.unblocked < pilot.valid;
    // A receiver partly under a box loses the pairs that start there: it always gets sixteen.
    if (partial || receiver_partial) n = 16;
    Tally tally;
    std::uint16_t blocked_mask = 0;
    trace(n, tally, blocked_mask, seed);
    link.samples = static_cast<std::uint8_t>(n);
    link.real_blocked = blocked_mask;
    // Hard case: every pair lies beyond one end's horizon (a source crossing the receiver's
    // plane, sampled on its hidden part only): the plain fraction of unblocked pairs.
    link.vis_real = tally.total > 0.0 ? static_cast<float>(tally.open / tally.total)
                                      : static_cast<float>(tally.unblocked) / static_cast<float>(std::max(1, tally.valid));
}

std::vector<Link> Radiosity::takePendingLinks() {
    // Elements that link refinement made have not been measured: their exposed part first.
    markBuried();
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
    tbb::parallel_for(std::size_t{0}, out.size(), [&](std::size_t i) { computeLink(out[i]); });
    std::erase_if(out, [](const Link& l) { return l.form_factor <= 0.0f || l.vis_real <= 0.0f; });
    return out;
}

void Radiosity::buildRealLinks() {
    links_.clear();
    pending_pairs_.clear();
    measureShelters();
    cluster_links_.clear();
    pending_cluster_links_.clear();
    makeClusters();
    if (options_.hierarchical) {
        // Pairs of faces, of a face and a cluster, or of two clusters (lighting/radiosity_cluster.cpp);
        // a cluster's own faces are linked among themselves as faces.
        const auto first_of = [&](std::size_t f, int cluster) {
            return clusters_[static_cast<std::size_t>(cluster)].faces.front() == static_cast<int>(f);
        };
        for (std::size_t fr = 0; fr < real_count_; ++fr) {
            const int cr = clusterOfFace(static_cast<int>(fr));
            for (std::size_t fs = 0; fs < real_count_; ++fs) {
                if (fr == fs) continue;
                const int cs = clusterOfFace(static_cast<int>(fs));
                const int r = hierarchy_.root(static_cast<int>(fr)), s = hierarchy_.root(static_cast<int>(fs));
                if (cr == cs) {
                    refine(r, s, 0);
                } else if (cs >= 0 && first_of(fs, cs)) {
                    refineFromCluster(r, cs, 0);  // a face, or a face of another cluster, from a cluster
                } else if (cr >= 0 && cs < 0 && first_of(fr, cr)) {
                    refineToCluster(cr, s, 0);
                }
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
    finishClusterLinks();
    if (options_.hierarchical) enforceConsistency();
    sortLinks();
}

void Radiosity::sortLinks() {
    std::stable_sort(links_.begin(), links_.end(), [](const Link& x, const Link& y) { return x.receiver < y.receiver; });
    link_offsets_.assign(hierarchy_.elements().size() + 1, 0);
    for (const Link& l : links_) ++link_offsets_[static_cast<std::size_t>(l.receiver) + 1];
    for (std::size_t i = 1; i < link_offsets_.size(); ++i) link_offsets_[i] += link_offsets_[i - 1];
}

int Radiosity::linkCount(Mode) const { return static_cast<int>(links_.size() + cluster_links_.size()); }

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
            const double a = child.area * exposure(e.first_child + c);
            sum += a * radiance[static_cast<std::size_t>(e.first_child + c)];
            area += a;
        }
        radiance[i] = area > 0.0 ? Eigen::Vector3d(sum / area) : Eigen::Vector3d::Zero();
    }
}

}  // namespace commonlight::lighting

// The structure of the virtual objects' influence (lighting/influence.h): which base leaves a
// change touches (shaft index), what blocks their light (transmissions, corrections) and how finely
// (refinement under the base leaves).
#include "lighting/influence.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <numbers>

#include "lighting/form_factor.h"
#include "lighting/influence_impl.h"
#include "lighting/sampling.h"

namespace commonlight::lighting {

namespace {

constexpr double kPi = std::numbers::pi;
constexpr int kOutOfView = 1000;  // footprint level of an element the camera does not see

double msSince(std::chrono::steady_clock::time_point t0) {
    return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

// Solid angle (sr) of a ball of radius r seen from distance d (capped at the hemisphere).
double ballSolidAngle(double r, double d) {
    if (d <= r) return 2.0 * kPi;
    return 2.0 * kPi * (1.0 - std::sqrt(std::max(0.0, 1.0 - r * r / (d * d))));
}

}  // namespace

VirtualInfluence::VirtualInfluence(Radiosity& radiosity, RayScene& rays, const InfluenceOptions& options)
    : radiosity_(radiosity), rays_(rays), options_(options), impl_(std::make_unique<Impl>(*this)) {}

VirtualInfluence::~VirtualInfluence() = default;

bool VirtualInfluence::refinedElement(int element) const {
    return element >= 0 && static_cast<std::size_t>(element) < impl_->sub.size() && impl_->sub[static_cast<std::size_t>(element)];
}

VirtualInfluence::LeafInfo VirtualInfluence::leafInfo(int leaf) const {
    LeafInfo out;
    const auto i = static_cast<std::size_t>(leaf);
    if (i >= impl_->has_terms.size() || !impl_->has_terms[i]) return out;
    const LeafTerms& t = impl_->terms[i];
    out.direct = t.direct;
    out.cluster = t.cluster;
    out.corrections = static_cast<int>(t.corrections.size());
    for (const Correction& c : t.corrections) out.correction_sum += c.coef;
    return out;
}

std::vector<Ball> VirtualInfluence::objectBalls() const {
    std::vector<Ball> out;
    for (const ObjectState& o : impl_->objects) {
        if (o.present) out.push_back(o.ball);
    }
    return out;
}

void VirtualInfluence::collapseAll() {
    Impl& d = *impl_;
    Hierarchy& h = radiosity_.hierarchy();
    for (std::size_t e = 0; e < d.base_leaf.size() && e < h.elements().size(); ++e) {
        if (d.base_leaf[e] && h[static_cast<int>(e)].child_count > 0) h.collapse(static_cast<int>(e));
    }
    has_base_ = false;
}

void VirtualInfluence::Impl::grow() {
    const std::size_t n = self.radiosity_.hierarchy().elements().size();
    if (sub.size() >= n) return;
    const std::size_t old = sub.size();
    shape.resize(n);
    for (std::size_t e = old; e < n; ++e) {
        if (!self.radiosity_.isVirtualElement(static_cast<int>(e))) cacheShape(static_cast<int>(e));
    }
    probe_radiance.resize(n, Eigen::Vector3d::Zero());
    sub.resize(n, 1);  // every element made after the base is the influence's
    base_leaf.resize(n, 0);
    up.resize(n, 0.0);
    G.resize(n, Eigen::Vector3d::Zero());
    V.resize(n, Eigen::Vector3d::Zero());
    U.resize(n, Eigen::Vector3d::Zero());
    pending.resize(n, Eigen::Vector3d::Zero());
    queued.resize(n, 0);
    pending_flag.resize(n, 0);
    column_known.resize(n, 0);
    terms.resize(n);
    has_terms.resize(n, 0);
    masks.resize(n);
    corr_source.resize(n, 0);
    self.d_.resize(n, Eigen::Vector3d::Zero());
    self.tilde_.resize(n, Eigen::Vector3d::Zero());
    self.rho_.resize(n, Eigen::Vector3d::Zero());
    self.radiance_.resize(n, Eigen::Vector3d::Zero());
}

int VirtualInfluence::Impl::baseLeafOf(int element) const {
    const Hierarchy& h = self.radiosity_.hierarchy();
    int e = element;
    while (e >= 0 && sub[static_cast<std::size_t>(e)]) e = h[e].parent;
    return e;
}

void VirtualInfluence::Impl::cacheShape(int element) {
    if (shape.size() <= static_cast<std::size_t>(element)) shape.resize(self.radiosity_.hierarchy().elements().size());
    const ElementGeometry g = self.radiosity_.geometry(element);
    ElementShape& es = shape[static_cast<std::size_t>(element)];
    es.centroid = g.centroid;
    es.count = g.triangle ? 3 : 4;
    es.corners[0] = g.corner;
    es.corners[1] = g.corner + g.edge_s;
    es.corners[2] = g.triangle ? Eigen::Vector3d(g.corner + g.edge_t) : Eigen::Vector3d(g.corner + g.edge_s + g.edge_t);
    es.corners[3] = g.corner + g.edge_t;
    es.radius = 0.0;
    for (int i = 0; i < es.count; ++i) es.radius = std::max(es.radius, (es.corners[static_cast<std::size_t>(i)] - g.centroid).norm());
}

Shaft VirtualInfluence::Impl::elementShaft(int element, int other) const {
    const ElementShape& a = shape[static_cast<std::size_t>(element)];
    const ElementShape& b = shape[static_cast<std::size_t>(other)];
    return Shaft{a.centroid, b.centroid, a.radius, b.radius};
}

std::span<const Eigen::Vector3d> VirtualInfluence::Impl::lightPolygon(int light) const {
    const DirectSource& s = *base.lights[static_cast<std::size_t>(light)].source;
    if (s.kind == DirectSource::Kind::kPolygon) return s.polygon->polygon;
    return {&s.position, 1};
}

Shaft VirtualInfluence::Impl::lightShaft(int element, int light) const {
    const ElementShape& a = shape[static_cast<std::size_t>(element)];
    const DirectSource& s = *base.lights[static_cast<std::size_t>(light)].source;
    Shaft shaft{a.centroid, a.centroid, a.radius, 0.0};
    if (s.kind == DirectSource::Kind::kPolygon) {
        shaft.b = s.polygon->centre;
        for (const Eigen::Vector3d& c : s.polygon->polygon) shaft.rb = std::max(shaft.rb, (c - s.polygon->centre).norm());
    } else if (s.kind == DirectSource::Kind::kPoint) {
        shaft.b = s.position;
    }
    return shaft;
}

namespace {

// Whether the segment from a to b meets the ball: a sure "yes" for the hull of two convex polygons
// whose points a and b are (their centroids), before the hull's planes are tried.
bool segmentMeetsBall(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Ball& ball) {
    const Eigen::Vector3d ab = b - a;
    const double len2 = ab.squaredNorm();
    const double t = len2 > 0.0 ? std::clamp((ball.centre - a).dot(ab) / len2, 0.0, 1.0) : 0.0;
    return (a + t * ab - ball.centre).squaredNorm() <= ball.radius * ball.radius;
}

}  // namespace

bool VirtualInfluence::Impl::linkMeetsBall(int element, int source, const Ball& ball) const {
    const ElementShape& e = shape[static_cast<std::size_t>(element)];
    const ElementShape& s = shape[static_cast<std::size_t>(source)];
    if (!shaftMeetsBall(elementShaft(element, source), ball)) return false;
    // The segment between the centroids lies in the hull: meeting it decides (most shafts in a
    // shadow), the hull's planes only for the rest.
    return segmentMeetsBall(e.centroid, s.centroid, ball) || hullMeetsBall(e.polygon(), s.polygon(), ball);
}

bool VirtualInfluence::Impl::lightMeetsBall(int element, int light, const Ball& ball) const {
    const DirectSource& s = *base.lights[static_cast<std::size_t>(light)].source;
    if (s.kind != DirectSource::Kind::kPolygon && s.kind != DirectSource::Kind::kPoint) return farLightMeetsBall(element, light, ball);
    const ElementShape& e = shape[static_cast<std::size_t>(element)];
    if (!shaftMeetsBall(lightShaft(element, light), ball)) return false;
    // (A light polygon is convex: its centre is in it.)
    const Eigen::Vector3d& target = s.kind == DirectSource::Kind::kPolygon ? s.polygon->centre : s.position;
    return segmentMeetsBall(e.centroid, target, ball) || hullMeetsBall(e.polygon(), lightPolygon(light), ball);
}

// A directional light or a distant cell: the element swept towards the light (a cone of the
// cell's directions) meets the ball. Conservative: the direction from the element's centre to the
// ball's is within the cone widened by the angle the ball and the element subtend.
bool VirtualInfluence::Impl::farLightMeetsBall(int element, int light, const Ball& ball) const {
    const DirectSource& s = *base.lights[static_cast<std::size_t>(light)].source;
    const ElementShape& es = shape[static_cast<std::size_t>(element)];
    const Eigen::Vector3d normal = self.radiosity_.face(self.radiosity_.hierarchy()[element].face).normal;
    const Eigen::Vector3d v = ball.centre - es.centroid;
    const double d = v.norm();
    const double reach = ball.radius + radiusOf(element);
    if (d <= reach) return true;
    const Eigen::Vector3d w = v / d;
    if (normal.dot(w) < -reach / d) return false;  // wholly below the element's horizon
    const double widen = std::asin(std::min(1.0, reach / d));
    if (s.kind == DirectSource::Kind::kDirection) {
        const Eigen::Vector3d towards = -s.direction.normalized();
        return std::acos(std::clamp(towards.dot(w), -1.0, 1.0)) <= widen;
    }
    // A cell: cos(theta) in [cos0, cos1], phi in [phi0, phi1): the angular distance from w to the
    // cell is at most the distance to its centre minus the cell's own radius.
    const Eigen::Vector3d c = s.cellCentre();
    double cell_radius = 0.0;
    for (double a : {0.0, 1.0}) {
        for (double b : {0.0, 1.0}) {
            cell_radius = std::max(cell_radius, std::acos(std::clamp(c.dot(s.cellDirection(Eigen::Vector2d(a, b * 0.999999))), -1.0, 1.0)));
        }
    }
    return std::acos(std::clamp(c.dot(w), -1.0, 1.0)) <= widen + cell_radius;
}

int VirtualInfluence::Impl::boundLevel(int element) const {
    // Without a camera: down to min_size.
    if (!viewer) return 0;
    const Eigen::Vector3d p = viewer->cam_from_world * shape[static_cast<std::size_t>(element)].centroid;
    const double r = radiusOf(element);
    if (p.z() <= -r) return kOutOfView;  // behind the camera
    const CameraModel& cam = viewer->camera;
    const double f = std::max(cam.fx, cam.fy);
    const double z = std::max(p.z(), 0.05);
    // In view when the element's ball, projected, meets the image (pinhole centre; distortion is
    // mild at the borders the margin covers).
    const double u = cam.fx * p.x() / z + cam.cx, v = cam.fy * p.y() / z + cam.cy;
    const double margin = f * r / z + 0.05 * cam.width;
    if (u < -margin || v < -margin || u > cam.width - 1 + margin || v > cam.height - 1 + self.options_.footprint_pixels + margin) {
        return kOutOfView;
    }
    // The pixel's footprint at the element's nearest point (metres per pixel), times the pixels.
    const double nearest = std::max(0.05, p.norm() - r);
    const double bound = self.options_.footprint_pixels * nearest / f;
    return std::max(0, static_cast<int>(std::ceil(std::log2(std::max(1.0, bound / self.options_.min_size)))));
}

double VirtualInfluence::Impl::boundSize(int level) const {
    if (level >= kOutOfView) return 1e300;
    return self.options_.min_size * std::ldexp(1.0, level);
}

Result<void> VirtualInfluence::setBase(InfluenceBase b) {
    Impl& d = *impl_;
    const Hierarchy& h = radiosity_.hierarchy();
    const std::size_t n = h.elements().size();
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
    const std::vector<Link>& links = radiosity_.links();
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
    d.objects.assign(count, ObjectState{});
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
    has_base_ = true;
    return {};
}

RealMask& VirtualInfluence::Impl::mask(int element, int key) {
    auto& list = masks[static_cast<std::size_t>(element)];
    for (RealMask& m : list) {
        if (m.key == key) return m;
    }
    list.push_back(RealMask{key, 0, 0, 0});
    return list.back();
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
        for (int k = 0; k < n && k < 64; ++k) {
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

// The same for a base link's shaft from leaf c to the link's source s (pairs of points of the two
// elements, kernel-weighted as Radiosity::computeLink weighs them).
double VirtualInfluence::Impl::transmissionToSource(int c, int s, bool& mixed, std::uint32_t mask_bits) {
    const Radiosity& rad = self.radiosity_;
    const RayScene& rays = self.rays_;
    const ElementGeometry gr = rad.geometry(c), gs = rad.geometry(s);
    const double floor2 = std::pow(0.05 * std::sqrt(std::min(rad.hierarchy()[c].area, rad.hierarchy()[s].area)), 2);
    const bool partial = rad.exposure(c) < 1.0;
    RealMask& m = mask(c, s);
    const bool known = (m.have & 1u) != 0;
    std::uint64_t computed = 0;
    const int n = std::clamp(self.options_.link_pairs, 1, 64);
    const std::uint64_t seed = hashCombine(hashCombine(self.options_.seed ^ 0x5eedull, rad.hierarchy().key(c)), rad.hierarchy().key(s));
    double open_real = 0.0, open_all = 0.0;
    bool any_blocked = false, any_open = false;
    std::uint64_t computed_hidden = 0;
    for (int k = 0; k < n; ++k) {
        const SamplePair pair = stratifiedPair(seed, k, n);
        const Eigen::Vector3d xr = rad.surfacePoint(c, pair.first.x(), pair.first.y());
        if (partial) {
            // A pair starting on the leaf's hidden part (under a box) is none of its light.
            if (known ? ((m.pilot_hidden >> k) & 1u) != 0 : rad.hidden(c, xr)) {
                if (!known) computed_hidden |= std::uint64_t{1} << k;
                continue;
            }
        }
        const Eigen::Vector3d xs = rad.surfacePoint(s, pair.second.x(), pair.second.y());
        const Eigen::Vector3d dv = xs - xr;
        const double d2 = std::max(dv.squaredNorm(), floor2);
        const double w = std::max(0.0, gr.normal.dot(dv)) * std::max(0.0, -gs.normal.dot(dv)) / (d2 * d2);
        if (!(w > 0.0)) continue;
        bool real_blocked;
        if (known) {
            real_blocked = (m.pilot >> k) & 1u;
        } else {
            real_blocked = rays.occludedReal(xr, gr.normal, xs, gs.normal);
            if (real_blocked) computed |= std::uint64_t{1} << k;
        }
        if (real_blocked) continue;
        open_real += w;
        if (rays.occludedVirtual(xr, gr.normal, xs, gs.normal, mask_bits)) {
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
    mixed = any_blocked && any_open;
    return open_real > 0.0 ? open_all / open_real : 1.0;
}

double VirtualInfluence::Impl::floorLuma(int element) const {
    const int face = self.radiosity_.hierarchy()[element].face;
    return std::max(1e-3 * luma_scale, static_cast<std::size_t>(face) < face_floor.size() ? face_floor[static_cast<std::size_t>(face)] : 0.0);
}

double VirtualInfluence::Impl::denominator(int element) const {
    return std::max(lumaOf(self.tilde_[static_cast<std::size_t>(element)]), floorLuma(element));
}

// The largest fraction of a solid angle `omega` seen from `element` that object o can cover.
double VirtualInfluence::Impl::objectBlocks(int object, int element, double omega) const {
    const ObjectState& o = objects[static_cast<std::size_t>(object)];
    const double covered = ballSolidAngle(o.radius, (o.ball.centre - shape[static_cast<std::size_t>(element)].centroid).norm());
    return std::min(1.0, covered / std::max(omega, 1e-12));
}

// Object o's largest effect on B/B~ at base leaf b through light k (its share of b's light, times
// the fraction of the light the object can hide) or through base link l.
double VirtualInfluence::Impl::lightSignificance(int b, int light, int object) const {
    const InfluenceLight& l = base.lights[static_cast<std::size_t>(light)];
    const auto i = static_cast<std::size_t>(b);
    const double col = i < l.column->real.size() ? l.column->real[i] : 0.0;
    if (!(col > 0.0)) return 0.0;
    const DirectSource& s = *l.source;
    double omega = 1e-12;  // a point or a direction: all of it can be hidden
    if (s.kind == DirectSource::Kind::kPolygon) {
        const Eigen::Vector3d v = shape[i].centroid - s.polygon->centre;
        const double dist = v.norm();
        omega = std::min(2.0 * kPi, s.polygon->area * std::max(0.05, std::abs(s.polygon->normal.dot(v / std::max(dist, 1e-12)))) /
                                        std::max(dist * dist, 1e-12));
    } else if (s.kind == DirectSource::Kind::kCell) {
        omega = s.solidAngle();
    }
    const double share = lumaOf(base.rho[i].cwiseProduct(l.emission)) * col / kPi / denominator(b);
    return share * objectBlocks(object, b, omega);
}

double VirtualInfluence::Impl::linkSignificance(int b, int link, int object) const {
    const Link& l = self.radiosity_.links()[static_cast<std::size_t>(link)];
    const auto i = static_cast<std::size_t>(b);
    const ElementShape& src = shape[static_cast<std::size_t>(l.source)];
    const Eigen::Vector3d v = shape[i].centroid - src.centroid;
    const double dist = v.norm();
    const Eigen::Vector3d ns = self.radiosity_.face(self.radiosity_.hierarchy()[l.source].face).normal;
    const double omega = std::min(2.0 * kPi, self.radiosity_.hierarchy()[l.source].area * std::max(0.05, std::abs(ns.dot(v / std::max(dist, 1e-12)))) /
                                                 std::max(dist * dist, 1e-12));
    const double w = kPi * static_cast<double>(l.form_factor) * static_cast<double>(l.vis_real);
    const double share = lumaOf(base.rho[i]) / kPi * w * lumaOf(base.radiance[static_cast<std::size_t>(l.source)]) / denominator(b);
    return share * objectBlocks(object, b, omega);
}

std::uint32_t VirtualInfluence::Impl::objectMask(int b) const {
    std::uint32_t m = 0;
    for (const auto& [object, link] : entries[static_cast<std::size_t>(b)]) {
        if (link < 0) m |= RayScene::virtualBit(object);
    }
    return m;
}

// The base links and lights worth correcting at base leaf b, against the objects significant
// there: each candidate's largest effect on B/B~, the weakest left out while their sum stays
// below link_epsilon. And the objects whose light reaches b at leaf level.
void VirtualInfluence::Impl::select(int b) {
    Selection& sel = selection[static_cast<std::size_t>(b)];
    sel = Selection{};
    struct Candidate {
        double significance;
        int light;  // >= 0: a light
        int link;   // >= 0: a base link
    };
    std::vector<Candidate> cand;
    std::vector<int> significant;
    for (const auto& [object, link] : entries[static_cast<std::size_t>(b)]) {
        if (link < 0) significant.push_back(object);
    }
    for (std::size_t k = 0; k < base.lights.size(); ++k) {
        double best = 0.0;
        for (int o : significant) {
            if (lightMeetsBall(b, static_cast<int>(k), objects[static_cast<std::size_t>(o)].ball)) {
                best = std::max(best, lightSignificance(b, static_cast<int>(k), o));
            }
        }
        if (best > 0.0) cand.push_back({best, static_cast<int>(k), -1});
    }
    std::vector<std::pair<int, double>> links;  // link, best significance
    for (const auto& [object, link] : entries[static_cast<std::size_t>(b)]) {
        if (link < 0) continue;
        const double sig = linkSignificance(b, link, object);
        auto it = std::find_if(links.begin(), links.end(), [&](const auto& x) { return x.first == link; });
        if (it == links.end()) {
            links.emplace_back(link, sig);
        } else {
            it->second = std::max(it->second, sig);
        }
    }
    for (const auto& [link, sig] : links) cand.push_back({sig, -1, link});
    // Keep the strongest; leave out the weakest while their sum stays below link_epsilon.
    std::sort(cand.begin(), cand.end(), [](const Candidate& x, const Candidate& y) {
        return x.significance != y.significance ? x.significance > y.significance : (x.light != y.light ? x.light < y.light : x.link < y.link);
    });
    double tail = 0.0;
    std::size_t keep = cand.size();
    while (keep > 0 && tail + cand[keep - 1].significance < self.options_.link_epsilon) tail += cand[--keep].significance;
    for (std::size_t i = 0; i < keep; ++i) {
        if (cand[i].light >= 0) sel.lights.push_back(cand[i].light);
        if (cand[i].link >= 0) sel.links.push_back(cand[i].link);
    }
    std::sort(sel.lights.begin(), sel.lights.end());
    std::sort(sel.links.begin(), sel.links.end());
    for (std::size_t o = 0; o < objects.size(); ++o) {
        const auto& leaves = objects[o].cluster_leaves;
        if (objects[o].present && std::binary_search(leaves.begin(), leaves.end(), b)) sel.objects.push_back(static_cast<int>(o));
    }
}

double VirtualInfluence::Impl::linkSize(int b) const {
    return std::max(self.options_.link_size, 2.0 * boundSize(bound_level[static_cast<std::size_t>(b)]));
}

// Element c under base leaf b: its terms (transmissions of the selected lights and links, cluster
// light), and how much B/B~ may vary across it (the oracle).
VirtualInfluence::Impl::LeafResult VirtualInfluence::Impl::computeTerms(int c, int b) {
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
    // Step 1: direct light the objects block.
    for (int k : sel.lights) {
        const InfluenceLight& l = base.lights[static_cast<std::size_t>(k)];
        const double col = l.column->real[static_cast<std::size_t>(c)];
        if (!(col > 0.0) || !meets([&](const Ball& ball) { return lightMeetsBall(c, k, ball); })) continue;
        bool mixed = false;
        const double tr = transmissionToLight(c, k, mixed, mask, false);
        t.direct += (tr - 1.0) * col * l.emission;
        if (mixed) {
            out.variation += lumaOf(rho.cwiseProduct(l.emission)) * col / kPi / den;
            out.deferred.emplace_back(k, tr);
        }
    }
    // Step 2: light from the objects that reach b at leaf level.
    for (int o : sel.objects) {
        double variation = 0.0;
        t.cluster += clusterAt(o, c, &variation, mask & ~RayScene::virtualBit(o));
        out.variation += variation;
    }
    return out;
}

// The full estimates computeTerms() left for later, now that c stays a leaf: the same estimate the
// pilot would have been followed by at once (the split elements' were thrown away with their terms).
void VirtualInfluence::Impl::finishDeferred(int c, int b, const LeafResult& r) {
    if (r.deferred.empty()) return;
    LeafTerms& t = terms[static_cast<std::size_t>(c)];
    const std::uint32_t mask = objectMask(b);
    for (const auto& [k, pilot] : r.deferred) {
        const InfluenceLight& l = base.lights[static_cast<std::size_t>(k)];
        const double col = l.column->real[static_cast<std::size_t>(c)];
        bool mixed = false;
        const double tr = transmissionToLight(c, k, mixed, mask, true);
        t.direct += (tr - pilot) * col * l.emission;
    }
}

// Element c's corrections of the base links the objects block (lighting/influence.h C), and how
// much they may vary across it.
double VirtualInfluence::Impl::computeLinks(int c, int b) {
    const Radiosity& rad = self.radiosity_;
    LeafTerms& t = terms[static_cast<std::size_t>(c)];
    t.corrections.clear();
    const Selection& sel = selection[static_cast<std::size_t>(b)];
    const Eigen::Vector3d& rho = self.rho_[static_cast<std::size_t>(c)];
    const double den = denominator(c);
    const std::uint32_t mask = objectMask(b);
    const std::vector<Link>& links = rad.links();
    double variation = 0.0;
    for (int li : sel.links) {
        const Link& l = links[static_cast<std::size_t>(li)];
        bool meets = false;
        for (const auto& [object, link] : entries[static_cast<std::size_t>(b)]) {
            if (link < 0 && linkMeetsBall(c, l.source, objects[static_cast<std::size_t>(object)].ball)) {
                meets = true;
                break;
            }
        }
        if (!meets) continue;
        bool mixed = false;
        const double tr = transmissionToSource(c, l.source, mixed, mask);
        const double w = kPi * static_cast<double>(l.form_factor) * static_cast<double>(l.vis_real);
        if (tr < 1.0) t.corrections.push_back(Correction{l.source, w * (tr - 1.0)});
        if (mixed) variation += lumaOf(rho) / kPi * w * lumaOf(base.radiance[static_cast<std::size_t>(l.source)]) / den;
    }
    return variation;
}

// The (base leaf, link or light) pairs whose shaft meets the ball `query` and whose effect there
// could reach a tenth of link_epsilon for an object anywhere inside it: the shaft index's
// candidates (cones), links followed from their receivers down to the base leaves (pruned by a bound
// on that effect), the hull of the two ends tested at the base leaves. `scan`: every shaft instead
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
    const std::vector<Link>& links = rad.links();
    std::vector<int> stack;
    for (int id : ids) {
        if (id >= link_shafts) {
            const auto [b, k] = light_shafts[static_cast<std::size_t>(id - link_shafts)];
            const DirectSource& ls = *base.lights[static_cast<std::size_t>(k)].source;
            const Eigen::Vector3d& target = ls.kind == DirectSource::Kind::kPolygon ? ls.polygon->centre : ls.position;
            if (segmentMeetsBall(shape[static_cast<std::size_t>(b)].centroid, target, query) ||
                hullMeetsBall(shape[static_cast<std::size_t>(b)].polygon(), lightPolygon(k), query)) {
                pairs.emplace_back(b, -1 - k);
            }
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
                if (segmentMeetsBall(es.centroid, src.centroid, query) || hullMeetsBall(es.polygon(), src.polygon(), query)) pairs.emplace_back(e, link);
                continue;
            }
            for (int c = 0; c < el.child_count; ++c) stack.push_back(el.first_child + c);
        }
    }
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
    if (scan) {
        obj.cache_valid = false;
        collectPairs(object, ball, true, obj.cache_pairs);
    } else if (!obj.cache_valid || (ball.centre - obj.cache_ball.centre).norm() + ball.radius > obj.cache_ball.radius) {
        obj.cache_ball = Ball{ball.centre, ball.radius + self.options_.shaft_margin};
        collectPairs(object, obj.cache_ball, false, obj.cache_pairs);
        obj.cache_valid = true;
    }
    const std::vector<Link>& links = self.radiosity_.links();
    std::vector<std::pair<int, double>> sums;       // base leaf, significance
    std::vector<std::pair<int, int>> link_entries;  // base leaf, link
    // (The significance first: it is cheaper than the shaft tests.) In parallel over the pairs
    // (thousands on the room), gathered in their order.
    std::vector<double> kept(obj.cache_pairs.size(), -1.0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, obj.cache_pairs.size(), 256), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t i = r.begin(); i < r.end(); ++i) {
            const auto [b, what] = obj.cache_pairs[i];
            if (what < 0) {
                const int k = -1 - what;
                const double sig = lightSignificance(b, k, object);
                if (sig >= item && lightMeetsBall(b, k, ball)) kept[i] = sig;
                continue;
            }
            const double sig = linkSignificance(b, what, object);
            if (sig >= item && linkMeetsBall(b, links[static_cast<std::size_t>(what)].source, ball)) kept[i] = sig;
        }
    });
    for (std::size_t i = 0; i < obj.cache_pairs.size(); ++i) {
        if (!(kept[i] >= 0.0)) continue;
        const auto [b, what] = obj.cache_pairs[i];
        sums.emplace_back(b, kept[i]);
        if (what >= 0) link_entries.emplace_back(b, what);
    }
    // Significant where the sum reaches link_epsilon.
    std::sort(sums.begin(), sums.end());
    std::sort(link_entries.begin(), link_entries.end());
    std::size_t j = 0;
    for (std::size_t i = 0; i < sums.size();) {
        const int b = sums[i].first;
        double total = 0.0;
        for (; i < sums.size() && sums[i].first == b; ++i) total += sums[i].second;
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

// Recomputes the touched base leaves: collapse, then level by level (parallel over the leaves of
// a level, splits in between on this thread): terms, oracle, split.
void VirtualInfluence::Impl::refine(const std::vector<int>& touched) {
    Radiosity& rad = self.radiosity_;
    Hierarchy& h = rad.hierarchy();
    const InfluenceOptions& opt = self.options_;
    // Step 1: collapse and select.
    std::vector<Eigen::Vector3d> old_d(touched.size());
    for (std::size_t i = 0; i < touched.size(); ++i) {
        const int b = touched[i];
        old_d[i] = self.d_[static_cast<std::size_t>(b)];
        if (h[b].child_count > 0) h.collapse(b);
        face_dirty[static_cast<std::size_t>(h[b].face)] = 1;
        bound_level[static_cast<std::size_t>(b)] = boundLevel(b);
    }
    tbb::parallel_for(std::size_t{0}, touched.size(), [&](std::size_t i) { select(touched[i]); });
    // Step 2: level by level. `links_open`: no element above has the corrections yet; they go to
    // the first element no larger than the link size, or to a leaf larger than that.
    std::vector<int> frontier = touched;
    std::vector<int> base_of(frontier.begin(), frontier.end());
    std::vector<char> links_open(frontier.size(), 1);
    std::vector<int> done;  // elements whose terms stand (leaves and link-level elements)
    evaluated = link_evaluated = 0;
    while (!frontier.empty()) {
        evaluated += static_cast<int>(frontier.size());
        std::vector<LeafResult> results(frontier.size());
        tbb::parallel_for(std::size_t{0}, frontier.size(), [&](std::size_t i) {
            const int c = frontier[i];
            if (h[c].buried) {
                terms[static_cast<std::size_t>(c)].clear();
                return;
            }
            const int b = base_of[i];
            results[i] = computeTerms(c, b);
            // The corrections where they stay: at the link level, or on an element larger than
            // that which its direct light and the objects' light do not split (where the blocked
            // links' own variation may still split it).
            const Element& el = h[c];
            const double size = std::max(el.size_s, el.size_t_);
            const bool split_anyway = results[i].variation > opt.refine_epsilon && size > boundSize(bound_level[static_cast<std::size_t>(b)]);
            if (links_open[i] && (size <= linkSize(b) || !split_anyway)) {
                results[i].link_variation = computeLinks(c, b);
                results[i].links = true;
            }
        });
        for (const LeafResult& r : results) link_evaluated += r.links ? 1 : 0;
        std::vector<int> next, next_base, fresh;
        std::vector<char> next_open;
        std::vector<std::size_t> stays;  // elements that stay leaves with full estimates to finish
        for (std::size_t i = 0; i < frontier.size(); ++i) {
            const int c = frontier[i];
            const Element& el = h[c];
            const int b = base_of[i];
            const double size = std::max(el.size_s, el.size_t_);
            const bool link_level = links_open[i] && size <= linkSize(b);
            // Split while the light may vary across the element by more than refine_epsilon (the
            // blocked links only down to the link size), to the camera's resolution.
            const double variation = results[i].variation + (links_open[i] && !link_level ? results[i].link_variation : 0.0);
            const bool wants = !el.buried && variation > opt.refine_epsilon && size > boundSize(bound_level[static_cast<std::size_t>(b)]) &&
                               h.leafCount() + 4 <= opt.max_leaves;
            if (wants && h.subdivide(c, opt.min_size)) {
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
                }
                continue;
            }
            done.push_back(c);
            if (!results[i].deferred.empty()) stays.push_back(i);
        }
        tbb::parallel_for(std::size_t{0}, stays.size(), [&](std::size_t j) {
            const std::size_t i = stays[j];
            finishDeferred(frontier[i], base_of[i], results[i]);
        });
        if (next.empty()) break;
        // The new children: state, exposure, pull weights, real columns, B~.
        grow();
        for (int c : next) {
            rad.measureExposure(c);
            if (!column_known[static_cast<std::size_t>(c)]) fresh.push_back(c);
        }
        for (int c : next) {
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
        for (std::size_t i = 0; i < next.size(); ++i) {
            const int c = next[i];
            const int b = next_base[i];
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
    corr_offsets.assign(n + 1, 0);
    corr_by_source.clear();
    std::vector<std::pair<int, std::pair<int, int>>> all;  // source, (receiver, index)
    for (std::size_t c = 0; c < n && c < has_terms.size(); ++c) {
        if (!has_terms[c] || h[static_cast<int>(c)].retired) continue;
        const auto& corr = terms[c].corrections;
        for (std::size_t k = 0; k < corr.size(); ++k) all.push_back({corr[k].source, {static_cast<int>(c), static_cast<int>(k)}});
    }
    std::sort(all.begin(), all.end());
    for (const auto& a : all) ++corr_offsets[static_cast<std::size_t>(a.first) + 1];
    for (std::size_t i = 1; i <= n; ++i) corr_offsets[i] += corr_offsets[i - 1];
    corr_by_source.reserve(all.size());
    for (const auto& a : all) corr_by_source.push_back(a.second);
}

Result<InfluenceStats> VirtualInfluence::update(const std::vector<InfluenceObject>& objects,
                                                const std::optional<InfluenceViewer>& viewer) {
    Impl& d = *impl_;
    if (!has_base_) return fail(ErrorCode::kInternal, "lighting: the influence has no base solution (setBase() first)");
    const auto t0 = std::chrono::steady_clock::now();
    stats_ = {};
    std::fill(d.face_dirty.begin(), d.face_dirty.end(), 0);
    d.shots = 0;
    // Step 1: what changed. An object moved, appeared, disappeared or changed emission; the
    // camera's footprint changes what resolution the influenced leaves need.
    const bool viewer_changed = viewer.has_value() != d.viewer.has_value() ||
                                (viewer && ((viewer->cam_from_world.translation - d.viewer->cam_from_world.translation).norm() > 1e-6 ||
                                            viewer->cam_from_world.rotation.angularDistance(d.viewer->cam_from_world.rotation) > 1e-6));
    d.viewer = viewer;
    std::vector<int> moved;
    for (std::size_t o = 0; o < d.objects.size() && o < objects.size(); ++o) {
        const ObjectState& s = d.objects[o];
        const InfluenceObject& in = objects[o];
        const bool present = in.present && in.world_from_object.isValid();
        Eigen::Vector3d emission = Eigen::Vector3d::Zero();
        if (in.emission) emission = *in.emission * d.base.radiance_scale;
        const bool changed = !s.known || present != s.present ||
                             (present && ((in.world_from_object.translation - s.pose.translation).norm() > 1e-9 ||
                                          in.world_from_object.rotation.angularDistance(s.pose.rotation) > 1e-9)) ||
                             in.emission.has_value() != s.emission_given || (in.emission && (emission - s.emission).norm() > 1e-12);
        if (changed) moved.push_back(static_cast<int>(o));
    }
    stats_.moved = static_cast<int>(moved.size());
    // Step 2: the objects' old effects out, new positions in, candidates from the shaft index.
    std::vector<int> touched;
    const auto tc = std::chrono::steady_clock::now();
    for (int o : moved) {
        ObjectState& s = d.objects[static_cast<std::size_t>(o)];
        touched.insert(touched.end(), s.touched.begin(), s.touched.end());
        for (int b : s.touched) std::erase_if(d.entries[static_cast<std::size_t>(b)], [&](const auto& e) { return e.first == o; });
        d.removeClusterLinks(o);
    }
    for (int o : moved) d.placeObject(o, objects[static_cast<std::size_t>(o)]);
    CL_TRY_VOID(rays_.commitVirtual());
    {
        std::vector<Rigid3d> poses = radiosity_.virtualPoses();
        for (int o : moved) poses[static_cast<std::size_t>(o)] = d.objects[static_cast<std::size_t>(o)].pose;
        radiosity_.setVirtualPoses(poses);
    }
    for (int o : moved) {
        ObjectState& s = d.objects[static_cast<std::size_t>(o)];
        s.touched.clear();
        if (!s.present) continue;
        d.candidates(o, s.ball, false, s.touched, true);
        d.objectRadiance(o);
        d.clusterLinks(o, s.touched);
        std::sort(s.touched.begin(), s.touched.end());
        s.touched.erase(std::unique(s.touched.begin(), s.touched.end()), s.touched.end());
        touched.insert(touched.end(), s.touched.begin(), s.touched.end());
    }
    if (viewer_changed) {
        // The camera changes no link: only the resolution the influenced leaves need.
        for (const ObjectState& s : d.objects) {
            for (int b : s.touched) {
                if (d.bound_level[static_cast<std::size_t>(b)] != d.boundLevel(b)) touched.push_back(b);
            }
        }
    }
    std::sort(touched.begin(), touched.end());
    touched.erase(std::unique(touched.begin(), touched.end()), touched.end());
    stats_.ms_candidates = msSince(tc);
    // Step 3: the touched base leaves again, then the change propagated.
    const auto tr = std::chrono::steady_clock::now();
    d.refine(touched);
    stats_.ms_refine = msSince(tr);
    stats_.touched = static_cast<int>(touched.size());
    stats_.evaluated = d.evaluated;
    stats_.link_evaluated = d.link_evaluated;
    const auto ts = std::chrono::steady_clock::now();
    d.propagate(stats_);
    stats_.ms_solve = msSince(ts);
    d.finish();
    stats_.ms_total = msSince(t0);
    return stats_;
}

Result<InfluenceStats> VirtualInfluence::rebuild(const std::vector<InfluenceObject>& objects,
                                                 const std::optional<InfluenceViewer>& viewer) {
    Impl& d = *impl_;
    if (!has_base_) return fail(ErrorCode::kInternal, "lighting: the influence has no base solution (setBase() first)");
    const auto t0 = std::chrono::steady_clock::now();
    stats_ = {};
    // Step 1: forget everything: no refinement, no difference, no object placed.
    Hierarchy& h = radiosity_.hierarchy();
    for (std::size_t e = 0; e < d.base_leaf.size(); ++e) {
        if (d.base_leaf[e] && h[static_cast<int>(e)].child_count > 0) h.collapse(static_cast<int>(e));
    }
    std::fill(d_.begin(), d_.end(), Eigen::Vector3d::Zero());
    std::fill(d.G.begin(), d.G.end(), Eigen::Vector3d::Zero());
    std::fill(d.V.begin(), d.V.end(), Eigen::Vector3d::Zero());
    std::fill(d.U.begin(), d.U.end(), Eigen::Vector3d::Zero());
    std::fill(d.has_terms.begin(), d.has_terms.end(), 0);
    for (auto& e : d.entries) e.clear();
    d.worklist.clear();
    std::fill(d.queued.begin(), d.queued.end(), 0);
    std::fill(d.face_dirty.begin(), d.face_dirty.end(), 1);
    for (ObjectState& s : d.objects) {
        s.known = false;
        s.present = false;
        s.touched.clear();
        s.cluster_leaves.clear();
        s.cluster_links.clear();
    }
    d.viewer = viewer;
    // Step 2: every object from scratch, candidates by scanning every shaft.
    const auto tc = std::chrono::steady_clock::now();
    std::vector<int> touched;
    for (std::size_t o = 0; o < d.objects.size() && o < objects.size(); ++o) d.placeObject(static_cast<int>(o), objects[o]);
    CL_TRY_VOID(rays_.commitVirtual());
    {
        std::vector<Rigid3d> poses = radiosity_.virtualPoses();
        for (std::size_t o = 0; o < d.objects.size(); ++o) poses[o] = d.objects[o].pose;
        radiosity_.setVirtualPoses(poses);
    }
    for (std::size_t o = 0; o < d.objects.size(); ++o) {
        ObjectState& s = d.objects[o];
        if (!s.present) continue;
        d.candidates(static_cast<int>(o), s.ball, true, s.touched, true);
        d.objectRadiance(static_cast<int>(o));
        d.clusterLinks(static_cast<int>(o), s.touched);
        std::sort(s.touched.begin(), s.touched.end());
        s.touched.erase(std::unique(s.touched.begin(), s.touched.end()), s.touched.end());
        touched.insert(touched.end(), s.touched.begin(), s.touched.end());
    }
    std::sort(touched.begin(), touched.end());
    touched.erase(std::unique(touched.begin(), touched.end()), touched.end());
    stats_.ms_candidates = msSince(tc);
    // Step 3: refinement, then B by dense Jacobi sweeps.
    const auto tr = std::chrono::steady_clock::now();
    d.refine(touched);
    stats_.ms_refine = msSince(tr);
    stats_.touched = static_cast<int>(touched.size());
    const auto ts = std::chrono::steady_clock::now();
    d_ = denseDifference(options_.residual * 1e-2);
    d.resync();
    stats_.ms_solve = msSince(ts);
    d.finish();
    stats_.ms_total = msSince(t0);
    return stats_;
}

}  // namespace commonlight::lighting

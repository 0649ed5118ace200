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

Eigen::Vector3d VirtualInfluence::leafDirect(int leaf) const {
    const auto i = static_cast<std::size_t>(leaf);
    if (i >= impl_->has_terms.size() || !impl_->has_terms[i]) return Eigen::Vector3d::Zero();
    return impl_->terms[i].direct;
}

std::vector<Ball> VirtualInfluence::objectBalls() const {
    std::vector<Ball> out;
    for (const ObjectState& o : impl_->objects) {
        if (o.present) out.push_back(o.ball);
    }
    return out;
}

const std::vector<Ball>& VirtualInfluence::movedBalls() const { return impl_->moved_balls; }

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
    answers.resize(n);
    has_terms.resize(n, 0);
    masks.resize(n);
    link_hulls.resize(n);
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

bool VirtualInfluence::Impl::linkMeetsBall(int element, int source, const Ball& ball) const {
    if (!shaftMeetsBall(elementShaft(element, source), ball)) return false;
    // (The segments between the ends first: most shafts in a shadow. Then the hull's planes, found
    // once per element and source: hullMeetsBall()'s answer.)
    return linkHull(element, source).meets(ball);
}

const CachedHull& VirtualInfluence::Impl::linkHull(int element, int source) const {
    // (Sorted by source: found by bisection, tens of sources per element.)
    auto& list = link_hulls[static_cast<std::size_t>(element)];
    const auto it = std::lower_bound(list.begin(), list.end(), source, [](const auto& entry, int key) { return entry.first < key; });
    if (it != list.end() && it->first == source) return it->second;
    hulls_made.fetch_add(1, std::memory_order_relaxed);
    return list.emplace(it, source, CachedHull::of(shape[static_cast<std::size_t>(element)].polygon(), shape[static_cast<std::size_t>(source)].polygon()))->second;
}

bool VirtualInfluence::Impl::lightMeetsBall(int element, int light, const Ball& ball) const {
    const DirectSource& s = *base.lights[static_cast<std::size_t>(light)].source;
    if (s.kind != DirectSource::Kind::kPolygon && s.kind != DirectSource::Kind::kPoint) return farLightMeetsBall(element, light, ball);
    const ElementShape& e = shape[static_cast<std::size_t>(element)];
    if (!shaftMeetsBall(lightShaft(element, light), ball)) return false;
    return hullMeetsBall(e.polygon(), lightPolygon(light), ball);
}

ObjectState::PairShaft VirtualInfluence::Impl::pairShaft(int element, int what) const {
    ObjectState::PairShaft out;
    if (what < 0) {
        const int light = -1 - what;
        const DirectSource& s = *base.lights[static_cast<std::size_t>(light)].source;
        out.far = s.kind != DirectSource::Kind::kPolygon && s.kind != DirectSource::Kind::kPoint;
        out.shaft = out.far ? Shaft{shape[static_cast<std::size_t>(element)].centroid} : lightShaft(element, light);
    } else {
        out.shaft = elementShaft(element, links[static_cast<std::size_t>(what)].source);
    }
    return out;
}

// (The pair's shaft from obj.cache_shafts: its ends are the segment that decides most shafts in a
// shadow, the base leaf's centroid to the light's centre or the source's centroid.)
bool VirtualInfluence::Impl::cachedPairMeets(ObjectState& obj, std::size_t i, const Ball& ball, double* clearance) const {
    // (`clearance`: how far the ball's centre may move with the same answer, or 0 when not known.)
    if (clearance) *clearance = 0.0;
    const auto [element, what] = obj.cache_pairs[i];
    const ObjectState::PairShaft& ps = obj.cache_shafts[i];
    if (ps.far) return farLightMeetsBall(element, -1 - what, ball);
    if (!shaftMeetsBall(ps.shaft, ball)) {
        if (clearance) *clearance = std::max(0.0, shaftClearance(ps.shaft, ball));
        return false;
    }
    if (segmentMeetsBall(ps.shaft.a, ps.shaft.b, ball)) {
        if (clearance) *clearance = std::max(0.0, -segmentClearance(ps.shaft.a, ps.shaft.b, ball));
        return true;
    }
    if (!obj.cache_hulls[i]) {
        const std::span<const Eigen::Vector3d> other =
            what < 0 ? lightPolygon(-1 - what) : shape[static_cast<std::size_t>(links[static_cast<std::size_t>(what)].source)].polygon();
        hulls_made.fetch_add(1, std::memory_order_relaxed);
        obj.cache_hulls[i] = std::make_unique<HullPlanes>(HullPlanes::of(shape[static_cast<std::size_t>(element)].polygon(), other));
    }
    const HullPlanes& hull = *obj.cache_hulls[i];
    if (hull.meets(ball)) {
        // (Met by the planes: while the centre stays inside both the cone's and the planes' reach.)
        if (clearance) *clearance = std::max(0.0, std::min(-shaftClearance(ps.shaft, ball), hull.depth(ball)));
        return true;
    }
    if (clearance) *clearance = std::max(0.0, hull.clearance(ball));
    return false;
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

int VirtualInfluence::Impl::tableIndex(const Eigen::Vector3d& w) const {
    int axis = 0;
    if (std::abs(w.y()) > std::abs(w[axis])) axis = 1;
    if (std::abs(w.z()) > std::abs(w[axis])) axis = 2;
    const double m = std::abs(w[axis]);
    if (!(m > 0.0)) return 0;
    const int face = 2 * axis + (w[axis] < 0.0 ? 1 : 0);
    const auto cell = [&](double x) { return std::clamp(static_cast<int>((x / m + 1.0) * 0.5 * kLookup), 0, kLookup - 1); };
    const int i = cell(w[(axis + 1) % 3]), j = cell(w[(axis + 2) % 3]);
    return table_lookup[static_cast<std::size_t>((face * kLookup + j) * kLookup + i)];
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

double VirtualInfluence::Impl::floorLuma(int element) const {
    const int face = self.radiosity_.hierarchy()[element].face;
    return std::max(1e-3 * luma_scale, static_cast<std::size_t>(face) < face_floor.size() ? face_floor[static_cast<std::size_t>(face)] : 0.0);
}

double VirtualInfluence::Impl::denominator(int element) const {
    return std::max(lumaOf(self.tilde_[static_cast<std::size_t>(element)]), floorLuma(element));
}

// The largest fraction of a solid angle `omega` seen from `element` that object o can cover.
double VirtualInfluence::Impl::objectBlocks(int object, int element, double omega) const {
    return objectBlocksFrom(object, shape[static_cast<std::size_t>(element)].centroid, omega);
}

double VirtualInfluence::Impl::objectBlocksFrom(int object, const Eigen::Vector3d& centroid, double omega) const {
    const ObjectState& o = objects[static_cast<std::size_t>(object)];
    const double covered = ballSolidAngle(o.radius, (o.ball.centre - centroid).norm());
    return std::min(1.0, covered / std::max(omega, 1e-12));
}

// Object o's largest effect on B/B~ at base leaf b through light k (its share of b's light, times
// the fraction of the light the object can hide) or through base link l.
void VirtualInfluence::Impl::lightSignificanceParts(int b, int light, double& share, double& omega) const {
    const InfluenceLight& l = base.lights[static_cast<std::size_t>(light)];
    const auto i = static_cast<std::size_t>(b);
    const double col = i < l.column->real.size() ? l.column->real[i] : 0.0;
    share = omega = 0.0;
    if (!(col > 0.0)) return;
    const DirectSource& s = *l.source;
    omega = 1e-12;  // a point or a direction: all of it can be hidden
    if (s.kind == DirectSource::Kind::kPolygon) {
        const Eigen::Vector3d v = shape[i].centroid - s.polygon->centre;
        const double dist = v.norm();
        omega = std::min(2.0 * kPi, s.polygon->area * std::max(0.05, std::abs(s.polygon->normal.dot(v / std::max(dist, 1e-12)))) /
                                        std::max(dist * dist, 1e-12));
    } else if (s.kind == DirectSource::Kind::kCell) {
        omega = s.solidAngle();
    }
    share = lumaOf(base.rho[i].cwiseProduct(l.emission)) * col / kPi / denominator(b);
}

void VirtualInfluence::Impl::linkSignificanceParts(int b, int link, double& share, double& omega) const {
    const Link& l = links[static_cast<std::size_t>(link)];
    const auto i = static_cast<std::size_t>(b);
    const ElementShape& src = shape[static_cast<std::size_t>(l.source)];
    const Eigen::Vector3d v = shape[i].centroid - src.centroid;
    const double dist = v.norm();
    const Eigen::Vector3d ns = self.radiosity_.face(self.radiosity_.hierarchy()[l.source].face).normal;
    omega = std::min(2.0 * kPi, self.radiosity_.hierarchy()[l.source].area * std::max(0.05, std::abs(ns.dot(v / std::max(dist, 1e-12)))) /
                                    std::max(dist * dist, 1e-12));
    const double w = kPi * static_cast<double>(l.form_factor) * static_cast<double>(l.vis_real);
    share = lumaOf(base.rho[i]) / kPi * w * lumaOf(base.radiance[static_cast<std::size_t>(l.source)]) / denominator(b);
}

double VirtualInfluence::Impl::lightSignificance(int b, int light, int object) const {
    double share = 0.0, omega = 0.0;
    lightSignificanceParts(b, light, share, omega);
    return share > 0.0 ? share * objectBlocks(object, b, omega) : 0.0;
}

double VirtualInfluence::Impl::linkSignificance(int b, int link, int object) const {
    double share = 0.0, omega = 0.0;
    linkSignificanceParts(b, link, share, omega);
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
    // Each blocked link once, at its best significance over the objects (sorted by link: a base
    // leaf beside a clustered proxy has a link per face of it, so no linear search per entry).
    std::vector<std::pair<int, double>> blocked;  // link, significance
    for (const auto& [object, link] : entries[static_cast<std::size_t>(b)]) {
        if (link >= 0) blocked.emplace_back(link, linkSignificance(b, link, object));
    }
    std::sort(blocked.begin(), blocked.end());
    for (std::size_t i = 0; i < blocked.size(); ++i) {
        if (i + 1 < blocked.size() && blocked[i + 1].first == blocked[i].first) continue;  // the last of a link is its largest
        cand.push_back({blocked[i].second, -1, blocked[i].first});
    }
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


Result<InfluenceStats> VirtualInfluence::update(const std::vector<InfluenceObject>& objects,
                                                const std::optional<InfluenceViewer>& viewer, const std::function<void()>& committed) {
    Impl& d = *impl_;
    if (!has_base_) return fail(ErrorCode::kInternal, "lighting: the influence has no base solution (setBase() first)");
    const auto t0 = std::chrono::steady_clock::now();
    stats_ = {};
    d.hulls_made.store(0, std::memory_order_relaxed);
    std::fill(d.face_dirty.begin(), d.face_dirty.end(), 0);
    d.shots = 0;
    // Step 1: what changed. An object moved, appeared, disappeared or changed emission; the
    // camera's footprint changes what resolution the influenced leaves need.
    const bool viewer_changed = viewer.has_value() != d.viewer.has_value() ||
                                (viewer && ((viewer->cam_from_world.translation - d.viewer->cam_from_world.translation).norm() > 1e-6 ||
                                            viewer->cam_from_world.rotation.angularDistance(d.viewer->cam_from_world.rotation) > 1e-6));
    d.viewer = viewer;
    std::vector<int> moved;
    d.moved_balls.clear();
    d.object_changed.assign(d.objects.size(), 0);
    for (std::size_t o = 0; o < d.objects.size() && o < objects.size(); ++o) {
        const ObjectState& s = d.objects[o];
        const InfluenceObject& in = objects[o];
        const bool present = in.present && in.world_from_object.isValid();
        Eigen::Vector3d emission = Eigen::Vector3d::Zero();
        if (in.emission) emission = *in.emission * d.base.radiance_scale;
        const bool placed = !s.known || present != s.present ||
                            (present && ((in.world_from_object.translation - s.pose.translation).norm() > 1e-9 ||
                                         in.world_from_object.rotation.angularDistance(s.pose.rotation) > 1e-9));
        const bool changed = placed || in.emission.has_value() != s.emission_given || (in.emission && (emission - s.emission).norm() > 1e-12);
        if (!changed) continue;
        moved.push_back(static_cast<int>(o));
        d.object_changed[o] = 1;
        // Where it blocked and where it will block: the shafts these meet are answered again (a
        // short move: one ball holding both, one test per shaft instead of two).
        if (!placed) continue;
        const bool was = s.known && s.present;
        const Ball now{in.world_from_object * s.centre_local, s.radius};
        const double step = was && present ? (now.centre - s.ball.centre).norm() : 1e300;
        if (step <= s.radius) {
            d.moved_balls.push_back(Ball{0.5 * (now.centre + s.ball.centre), s.radius + 0.5 * step});
            continue;
        }
        if (was) d.moved_balls.push_back(s.ball);
        if (present) d.moved_balls.push_back(now);
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
    if (committed) committed();
    // The cluster links' shared answers the move reached: their blocked faces (the candidates read
    // which faces' shafts each object meets from them); their transmissions after the candidates
    // (answerNodes(): only where a base leaf selects a transfer; faces walked again if they changed).
    d.refreshNodes(false);
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
    d.answerNodes(touched);
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
    stats_.answers_computed = d.items_computed;
    stats_.answers_kept = d.items_reused;
    const auto ts = std::chrono::steady_clock::now();
    d.propagate(stats_);
    stats_.ms_solve = msSince(ts);
    d.finish();
    stats_.hulls_made = d.hulls_made.load(std::memory_order_relaxed);
    stats_.ms_total = msSince(t0);
    return stats_;
}

Result<InfluenceStats> VirtualInfluence::rebuild(const std::vector<InfluenceObject>& objects,
                                                 const std::optional<InfluenceViewer>& viewer) {
    Impl& d = *impl_;
    if (!has_base_) return fail(ErrorCode::kInternal, "lighting: the influence has no base solution (setBase() first)");
    const auto t0 = std::chrono::steady_clock::now();
    stats_ = {};
    d.hulls_made.store(0, std::memory_order_relaxed);
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
    std::fill(d.answers.begin(), d.answers.end(), Answers{});
    d.moved_balls.clear();
    d.object_changed.assign(d.objects.size(), 1);
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
    for (ClusterNode& node : d.nodes) {
        node.valid = false;
        node.known = false;
        node.blocked_faces.clear();
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
    d.refreshNodes(true);
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
    d.answerNodes(touched);
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
    stats_.hulls_made = d.hulls_made.load(std::memory_order_relaxed);
    stats_.ms_total = msSince(t0);
    return stats_;
}

}  // namespace commonlight::lighting

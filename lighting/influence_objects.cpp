// The virtual objects as clusters (lighting/influence.h): each object's faces lit by the order-2 SH
// irradiance at its centre (from B~ and the lights), its radiance towards a receiver as the
// projected-area mean of the faces facing it, and its links to real elements refined like any
// other (Hanrahan et al. 1991's oracle on the form factor's variation, here from the object's
// largest radiance; Sillion 1995 and Smits et al. 1994 for clusters).
#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>

#include "lighting/form_factor.h"
#include "lighting/influence_impl.h"
#include "lighting/sampling.h"

namespace commonlight::lighting {

namespace {

constexpr double kPi = std::numbers::pi;

// The seed of an element's cluster visibility pairs towards object o.
std::uint64_t clusterPairSeed(std::uint64_t seed, std::uint64_t element_key, int o) {
    return hashCombine(hashCombine(seed ^ 0xc1u, element_key), static_cast<std::uint64_t>(o));
}

// The object's end of a cluster visibility pair: a point on the disc through the object's centre
// (radius 0.9 of its ball) that faces the element point x, at the sample u.
Eigen::Vector3d discPointFacing(const Ball& ball, double radius, const Eigen::Vector3d& x, const Eigen::Vector2d& u) {
    const Eigen::Vector3d axis = (x - ball.centre).normalized();
    const Eigen::Vector3d e1 = axis.unitOrthogonal(), e2 = axis.cross(e1);
    const double r = 0.9 * radius * std::sqrt(u.x()), phi = 2.0 * kPi * u.y();
    return ball.centre + r * std::cos(phi) * e1 + r * std::sin(phi) * e2;
}

}  // namespace

void VirtualInfluence::Impl::placeObject(int o, const InfluenceObject& in) {
    ObjectState& s = objects[static_cast<std::size_t>(o)];
    s.known = true;
    s.present = in.present && in.world_from_object.isValid();
    if (in.world_from_object.isValid()) s.pose = in.world_from_object;
    s.emission_given = in.emission.has_value();
    s.emission = in.emission ? Eigen::Vector3d(*in.emission * base.radiance_scale) : Eigen::Vector3d::Zero();
    s.ball = Ball{s.pose * s.centre_local, s.radius};
    self.rays_.setVirtualPose(o, s.pose);
    self.rays_.setVirtualEnabled(o, s.present);
    s.cluster_leaves.clear();
}

// The object's faces' radiance (emission plus reflected SH irradiance at its centre: direct from
// the lights, indirect from B~ and the other objects' emission) and its exitance table.
void VirtualInfluence::Impl::objectRadiance(int o) {
    ObjectState& s = objects[static_cast<std::size_t>(o)];
    const Radiosity& rad = self.radiosity_;
    // The other virtual objects are left out here (neither seen nor shading it): a higher-order
    // term for the real surfaces, and with it an object's light would depend on where the others
    // were when it last moved (the snapshot's probes, for drawing the objects, see every object).
    // Real surfaces read as their base leaf's B~.
    std::vector<ProbeLight> lights;
    for (const InfluenceLight& l : base.lights) {
        ProbeLight p;
        p.source = *l.source;
        p.emission = l.emission;
        p.indirect = l.source->kind == DirectSource::Kind::kCell;
        lights.push_back(p);
    }
    const ProbeIrradiance e = probeIrradiance(rad, s.ball.centre, o, probe_radiance, lights, std::max(16, self.options_.object_directions),
                                              hashCombine(self.options_.seed, 0x0b1ec7ull + static_cast<std::uint64_t>(o)), false);
    IrradianceSh sum;
    for (int k = 0; k < 9; ++k) sum[static_cast<std::size_t>(k)] = e.indirect[static_cast<std::size_t>(k)] + e.direct[static_cast<std::size_t>(k)];
    s.face_radiance.assign(s.faces.size(), Eigen::Vector3d::Zero());
    s.face_shape.assign(s.faces.size(), ElementShape{});
    s.face_normal.assign(s.faces.size(), Eigen::Vector3d::Zero());
    s.face_area.assign(s.faces.size(), 0.0);
    s.luma_max = 0.0;
    for (std::size_t i = 0; i < s.faces.size(); ++i) {
        const Face& f = rad.face(s.faces[i]);
        const auto corners = f.corners();
        ElementShape& fs = s.face_shape[i];
        fs.count = static_cast<int>(std::min<std::size_t>(4, corners.size()));
        for (int k = 0; k < fs.count; ++k) fs.corners[static_cast<std::size_t>(k)] = corners[static_cast<std::size_t>(k)];
        fs.centroid.setZero();
        for (int k = 0; k < fs.count; ++k) fs.centroid += fs.corners[static_cast<std::size_t>(k)] / fs.count;
        fs.radius = 0.0;
        for (int k = 0; k < fs.count; ++k) fs.radius = std::max(fs.radius, (fs.corners[static_cast<std::size_t>(k)] - fs.centroid).norm());
        s.face_normal[i] = f.normal;
        s.face_area[i] = f.area;
        const Eigen::Vector3d le = s.emission_given ? s.emission : Eigen::Vector3d(f.emission * base.radiance_scale);
        const Eigen::Vector3d irradiance = evaluateIrradiance(sum, f.normal.cast<float>()).cast<double>();
        s.face_radiance[i] = le + f.albedo.cwiseProduct(irradiance) / kPi;
        s.luma_max = std::max(s.luma_max, lumaOf(s.face_radiance[i]));
    }
    // Exitance table: per direction the projected area and the projected-area mean radiance of the
    // faces facing it (exact for a convex object seen from afar).
    s.exitance.assign(table.size(), Eigen::Vector3d::Zero());
    s.projected.assign(table.size(), 0.0);
    s.projected_max = 0.0;
    for (std::size_t k = 0; k < table.size(); ++k) {
        Eigen::Vector3d num = Eigen::Vector3d::Zero();
        double den = 0.0;
        for (std::size_t i = 0; i < s.faces.size(); ++i) {
            const Face& f = rad.face(s.faces[i]);
            const double a = f.area * std::max(0.0, f.normal.dot(table[k]));
            num += a * s.face_radiance[i];
            den += a;
        }
        s.projected[k] = den;
        s.exitance[k] = den > 0.0 ? Eigen::Vector3d(num / den) : Eigen::Vector3d::Zero();
        s.projected_max = std::max(s.projected_max, den);
    }
}

// F from a point (facing n) to the object, and the radiance it sees of it: the projected area in
// that direction over pi d^2 (the cluster) and its mean radiance; close by or across the point's
// horizon, the exact point-to-polygon form factors of the faces facing the point.
double VirtualInfluence::Impl::pointFormFactor(int o, const Eigen::Vector3d& x, const Eigen::Vector3d& n,
                                               Eigen::Vector3d* radiance) const {
    const ObjectState& s = objects[static_cast<std::size_t>(o)];
    const Eigen::Vector3d v = s.ball.centre - x;
    const double d = v.norm();
    if (s.sphere && d >= 1.5 * s.radius) {
        // A sphere not too close: its exact form factor, the part below the point's horizon
        // hidden (pointToSphere(); its 320 faces one by one cost 50 us a point); its radiance,
        // the table's towards the point.
        const double f = d > 0.0 ? pointToSphere(d, s.sphere_radius, n.dot(v) / d) : 0.0;
        if (radiance) *radiance = f > 0.0 ? s.exitance[static_cast<std::size_t>(tableIndex(-v / d))] : Eigen::Vector3d(Eigen::Vector3d::Zero());
        return f;
    }
    // The cluster's projected area over pi d^2 is close for a convex object a few radii away (and
    // exact for a sphere wholly above the horizon); the faces one by one where the object crosses
    // the horizon or (not a sphere) nearly touches the point.
    if ((!s.sphere && d < 1.5 * s.radius) || n.dot(v) < 0.9 * s.radius) {
        double total = 0.0;
        Eigen::Vector3d sum = Eigen::Vector3d::Zero();
        for (std::size_t i = 0; i < s.faces.size(); ++i) {
            const ElementShape& fs = s.face_shape[i];
            if (s.face_normal[i].dot(x - fs.corners[0]) <= 0.0) continue;  // facing away
            // A face more than 8 of its radii away and wholly above the point's horizon: its
            // point form factor (within about 1% of the exact one there); nearer, or across the
            // horizon (clipped), the exact one.
            const Eigen::Vector3d r = fs.centroid - x;
            const double d2 = r.squaredNorm(), above = n.dot(r);
            double ff;
            if (d2 > 64.0 * fs.radius * fs.radius && above > fs.radius) {
                ff = s.face_area[i] * above * std::max(0.0, -s.face_normal[i].dot(r)) / (kPi * d2 * d2);
            } else {
                ff = pointToPolygon(x, n, fs.polygon(), s.face_normal[i]);
            }
            total += ff;
            sum += ff * s.face_radiance[i];
        }
        if (radiance) *radiance = total > 0.0 ? Eigen::Vector3d(sum / total) : Eigen::Vector3d::Zero();
        return total;
    }
    const double cos_r = n.dot(v) / d;
    if (cos_r <= 0.0) {
        if (radiance) radiance->setZero();
        return 0.0;
    }
    // The table's direction nearest the one towards the point (a cube map's cell: O(1)).
    const auto best = static_cast<std::size_t>(tableIndex(-v / d));
    if (radiance) *radiance = s.exitance[best];
    return cos_r * s.projected[best] / (kPi * d * d);
}

// Fraction of (element point, object point) pairs that the real scene and the other virtual
// objects leave open; object points on the disc through its centre facing the element point.
// `keep` (may be null): the element's RealMask for object o (clusterMaskKey(o)), where which of the
// element's points are hidden is kept for 4 and 16 pairs (pilot_hidden, full_hidden): they do not
// move with the object.
double VirtualInfluence::Impl::clusterVisibility(int o, int element, int pairs, bool& mixed, std::uint32_t mask, RealMask* keep) const {
    const ObjectState& s = objects[static_cast<std::size_t>(o)];
    const Radiosity& rad = self.radiosity_;
    const RayScene& rays = self.rays_;
    const ElementGeometry g = rad.geometry(element);
    const bool partial = rad.exposure(element) < 1.0;
    const std::uint64_t seed = clusterPairSeed(self.options_.seed, rad.hierarchy().key(element), o);
    const std::uint8_t flag = pairs == 4 ? 1 : pairs == 16 ? 2 : 0;
    std::uint64_t* hidden_bits = keep && flag ? (flag == 1 ? &keep->pilot_hidden : &keep->full_hidden) : nullptr;
    const bool known = hidden_bits && (keep->have & flag) != 0;
    std::uint64_t computed_hidden = 0;
    // Batch by batch: the valid pairs' segments first, their real rays as packets
    // (RayScene::occludedRealMany()), then the virtual rays of those the real scene leaves open.
    constexpr int kBatch = 16;
    std::array<PreparedSegment, kBatch> segments;
    const VirtualSet set = rays.virtualSet(mask);
    int valid = 0, open = 0;
    for (int k0 = 0; k0 < pairs; k0 += kBatch) {
        int batch = 0;
        for (int k = k0; k < std::min(pairs, k0 + kBatch); ++k) {
            const SamplePair u = stratifiedPair(seed, k, pairs);
            const Eigen::Vector3d x = rad.surfacePoint(element, g, u.first.x(), u.first.y());
            if (partial) {
                if (known ? ((*hidden_bits >> k) & 1u) != 0 : rad.hidden(element, x)) {
                    if (hidden_bits && !known) computed_hidden |= std::uint64_t{1} << k;
                    continue;
                }
            }
            const Eigen::Vector3d y = discPointFacing(s.ball, s.radius, x, u.second);
            if (g.normal.dot(y - x) <= 0.0) continue;
            const auto i = static_cast<std::size_t>(batch++);
            segments[i] = rays.prepareSegment(x, g.normal, y, Eigen::Vector3d::Zero());
        }
        valid += batch;
        const std::uint64_t real_blocked = rays.occludedRealMany(segments.data(), batch);
        // The virtual rays through the same prepared segments (occludedVirtual(segment, set) ==
        // occludedVirtual(x, normal, y, 0, mask): the same segment, lifted once).
        for (int i = 0; i < batch; ++i) {
            if ((real_blocked >> i) & 1u) continue;
            if (rays.occludedVirtual(segments[static_cast<std::size_t>(i)], set)) continue;
            ++open;
        }
    }
    if (hidden_bits && !known) {
        *hidden_bits = computed_hidden;
        keep->have = static_cast<std::uint8_t>(keep->have | flag);
    }
    mixed = open > 0 && open < valid;
    return valid > 0 ? static_cast<double>(open) / valid : 0.0;
}

// The irradiance an element gets from object o (pi F V L), and how much rho F L / B~ varies across
// it (the form factor between its corners and centre, and a partly hidden object).
Eigen::Vector3d VirtualInfluence::Impl::clusterAt(int o, int element, double* variation, std::uint32_t mask) {
    const ObjectState& s = objects[static_cast<std::size_t>(o)];
    const Radiosity& rad = self.radiosity_;
    const ElementGeometry g = rad.geometry(element);
    const double size = std::sqrt(rad.hierarchy()[element].area);
    const double distance = std::max((s.ball.centre - g.centroid).norm(), 1e-9);
    const int order = std::min(2, formFactorRule(distance, size, 2.0 * s.radius));  // finer where it varies: by refinement
    // (Over the whole element, not its exposed part alone: a leaf partly under a box sees the
    // object's light on its open part as the whole; the exposed rule costs 64 hidden tests.)
    double f = 0.0;
    for (const QuadraturePoint& q : quadratureRule(g.corner, g.edge_s, g.edge_t, g.triangle, order)) f += q.weight * pointFormFactor(o, q.x, g.normal, nullptr);
    Eigen::Vector3d l = Eigen::Vector3d::Zero();
    double f_lo = pointFormFactor(o, g.centroid, g.normal, &l), f_hi = f_lo;
    for (const Eigen::Vector3d& c : g.polygon()) {
        const double fc = pointFormFactor(o, c + 0.01 * (g.centroid - c), g.normal, nullptr);
        f_lo = std::min(f_lo, fc);
        f_hi = std::max(f_hi, fc);
    }
    if (!(f > 0.0) && !(f_hi > 0.0)) {
        if (variation) *variation = 0.0;
        return Eigen::Vector3d::Zero();
    }
    bool mixed = false;
    // (A partly hidden element's hidden points kept with its masks: mask(), this thread's element.)
    RealMask* keep = rad.exposure(element) < 1.0 ? &this->mask(element, clusterMaskKey(o)) : nullptr;
    double vis = clusterVisibility(o, element, 4, mixed, mask, keep);
    if (mixed) vis = clusterVisibility(o, element, 16, mixed, mask, keep);
    if (variation) {
        const double den = denominator(element);
        const double rho = lumaOf(self.rho_[static_cast<std::size_t>(element)]);
        // What varies is the object's light net of the light it hides (about the scene's mean
        // radiance): a grey ball beside a grey wall changes little, a lamp a lot.
        *variation = rho * ((f_hi - f_lo) + (mixed ? f : 0.0)) * std::abs(lumaOf(l) - mean_luma) / den;
    }
    return kPi * f * vis * l;
}

// The object's links to real elements above the base leaves, by descent from each real face:
// none where its light cannot matter, a link where the form factor is even enough, and the base
// leaves where it is not (they get the object's light leaf by leaf, refined: `leaf_level`).
void VirtualInfluence::Impl::clusterLinks(int o, std::vector<int>& leaf_level) {
    ObjectState& s = objects[static_cast<std::size_t>(o)];
    const Radiosity& rad = self.radiosity_;
    const Hierarchy& h = rad.hierarchy();
    const InfluenceOptions& opt = self.options_;
    s.cluster_leaves.clear();
    s.cluster_links.clear();
    if (!s.present || !(s.luma_max > 0.0)) return;
    std::vector<int> stack;
    for (std::size_t f = 0; f < rad.realFaceCount(); ++f) stack.push_back(h.root(static_cast<int>(f)));
    while (!stack.empty()) {
        const int a = stack.back();
        stack.pop_back();
        const Element& el = h[a];
        if (el.buried) continue;
        const ElementGeometry g = rad.geometry(a);
        if (g.normal.dot(s.ball.centre - g.centroid) < -s.radius) continue;  // behind the element
        // Step 1: can its light matter here? The largest form factor any point could have.
        const double dmin = std::max(g.distanceTo(s.ball.centre) - s.radius, 0.25 * s.radius);
        const double f_max = std::min(1.0, s.projected_max / (kPi * dmin * dmin));
        const double den = std::max(lumaOf(base.radiance[static_cast<std::size_t>(a)]), floorLuma(a));
        const double rho = rho_mean[static_cast<std::size_t>(a)];
        if (rho * f_max * s.luma_max / den < opt.link_epsilon) continue;
        // Step 2: is the form factor even over it (and the object not too close)?
        double f_lo = 1e300, f_hi = 0.0;
        for (const Eigen::Vector3d& c : g.polygon()) {
            const double fc = pointFormFactor(o, c + 0.01 * (g.centroid - c), g.normal, nullptr);
            f_lo = std::min(f_lo, fc);
            f_hi = std::max(f_hi, fc);
        }
        const double fc = pointFormFactor(o, g.centroid, g.normal, nullptr);
        f_lo = std::min(f_lo, fc);
        f_hi = std::max(f_hi, fc);
        const bool near = dmin < std::max(el.size_s, el.size_t_);
        if (near || rho * (f_hi - f_lo) * std::abs(s.luma_max - mean_luma) / den > opt.refine_epsilon) {
            if (base_leaf[static_cast<std::size_t>(a)]) {
                s.cluster_leaves.push_back(a);
                leaf_level.push_back(a);
            } else {
                for (int c = 0; c < el.child_count; ++c) stack.push_back(el.first_child + c);
            }
            continue;
        }
        // Step 3: a link here.
        // (Other objects do not shade this link: it is kept while they move.)
        const Eigen::Vector3d contribution = clusterAt(o, a, nullptr, 0u);
        if (contribution.isZero()) continue;
        V[static_cast<std::size_t>(a)] += contribution;
        s.cluster_links.emplace_back(a, contribution);
        const Eigen::Vector3d delta = pushDown(a, contribution);
        propagateUp(a, delta);
    }
    std::sort(s.cluster_leaves.begin(), s.cluster_leaves.end());
}

void VirtualInfluence::Impl::removeClusterLinks(int o) {
    ObjectState& s = objects[static_cast<std::size_t>(o)];
    for (const auto& [a, contribution] : s.cluster_links) {
        V[static_cast<std::size_t>(a)] -= contribution;
        const Eigen::Vector3d delta = pushDown(a, -contribution);
        propagateUp(a, delta);
    }
    s.cluster_links.clear();
    s.cluster_leaves.clear();
}

}  // namespace commonlight::lighting

#include "lighting/snapshot_builder.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <numbers>

#include "lighting/sampling.h"

namespace commonlight::lighting {

namespace {

constexpr double kPi = std::numbers::pi;

Rgb toRgb(const Eigen::Vector3d& v) { return v.cast<float>(); }

// Box filter of the piecewise-constant leaf field around (s, t), over the local leaf's extent.
struct FaceField {
    const Radiosity& radiosity;
    int face;
    double len_s, len_t;

    int leafAt(double s, double t) const { return radiosity.hierarchy().leafAt(face, Eigen::Vector2d(s, t)); }

    template <typename Sample>
    Eigen::Vector3d filtered(double s, double t, Sample sample) const {
        const int centre = leafAt(s, t);
        const Element& e = radiosity.hierarchy()[centre];
        // Half the leaf's extent in (s, t): the leaf's own parameter extents.
        const double hs = 0.5 * std::max(std::abs(e.ds.x()), std::abs(e.dt.x()));
        const double ht = 0.5 * std::max(std::abs(e.ds.y()), std::abs(e.dt.y()));
        Eigen::Vector3d sum = Eigen::Vector3d::Zero();
        int n = 0;
        for (int dj = -1; dj <= 1; dj += 2) {
            for (int di = -1; di <= 1; di += 2) {
                const double ss = std::clamp(s + 0.5 * di * hs, 0.0, 1.0);
                const double tt = std::clamp(t + 0.5 * dj * ht, 0.0, 1.0);
                const int leaf = leafAt(ss, tt);
                if (radiosity.hierarchy()[leaf].buried) continue;
                sum += sample(leaf);
                ++n;
            }
        }
        if (n == 0) return sample(centre);
        return sum / n;
    }
};

// Fibonacci directions on the sphere: deterministic, near-uniform.
std::vector<Eigen::Vector3d> sphereDirections(int n) {
    std::vector<Eigen::Vector3d> dirs;
    dirs.reserve(static_cast<std::size_t>(n));
    const double golden = kPi * (3.0 - std::sqrt(5.0));
    for (int i = 0; i < n; ++i) {
        const double z = 1.0 - 2.0 * (i + 0.5) / n;
        const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
        const double phi = golden * i;
        dirs.emplace_back(r * std::cos(phi), r * std::sin(phi), z);
    }
    return dirs;
}

std::array<double, 9> basis(const Eigen::Vector3d& n) {
    const auto y = shBasis(n.cast<float>());
    std::array<double, 9> out{};
    for (int k = 0; k < 9; ++k) out[static_cast<std::size_t>(k)] = y[static_cast<std::size_t>(k)];
    return out;
}

// Cosine-lobe convolution of radiance SH into irradiance SH (Ramamoorthi and Hanrahan 2001).
constexpr double kBand[9] = {kPi, 2.0 * kPi / 3.0, 2.0 * kPi / 3.0, 2.0 * kPi / 3.0, kPi / 4.0,
                             kPi / 4.0, kPi / 4.0, kPi / 4.0, kPi / 4.0};

// (s, t) of a world point on a (posed) face.
Eigen::Vector2d faceCoordinates(const Face& f, const Eigen::Vector3d& p) {
    Eigen::Matrix<double, 3, 2> b;
    b.col(0) = f.edge_s;
    b.col(1) = f.edge_t;
    const Eigen::Matrix2d gram = b.transpose() * b;
    return gram.inverse() * (b.transpose() * (p - f.origin));
}

}  // namespace

std::vector<FaceModulation> buildFaceModulations(const Radiosity& radiosity, const Scene& scene, const Solution& without,
                                                 const Solution& with, const std::vector<Eigen::Vector3d>& rho,
                                                 int max_texels) {
    std::vector<FaceModulation> out;
    const Hierarchy& h = radiosity.hierarchy();
    std::vector<int> leaves;
    for (std::size_t f = 0; f < radiosity.realFaceCount(); ++f) {
        const Face& face = radiosity.face(static_cast<int>(f));
        leaves.clear();
        h.leavesUnder(h.root(static_cast<int>(f)), leaves);
        double finest = 1e300, area = 0.0, lum = 0.0;
        bool any = false;
        for (int l : leaves) {
            const Element& e = h[l];
            if (e.buried) continue;
            any = true;
            finest = std::min(finest, std::min(e.size_s, e.size_t_));
            area += e.area;
            lum += e.area * luminance(toRgb(without.radiance[static_cast<std::size_t>(l)]));
        }
        if (!any) continue;
        FaceModulation m;
        m.object_index = face.object_index;
        m.object = scene.real_objects[static_cast<std::size_t>(face.object_index)].name;
        m.face = face.face_index;
        m.corners = face.corners();
        m.normal = face.normal;
        m.width = std::clamp(static_cast<int>(std::ceil(face.lengthS() / finest)), 2, max_texels);
        m.height = std::clamp(static_cast<int>(std::ceil(face.lengthT() / finest)), 2, max_texels);
        m.mean_original = area > 0.0 ? static_cast<float>(lum / area) : 0.0f;
        const std::size_t texels = static_cast<std::size_t>(m.width) * static_cast<std::size_t>(m.height);
        m.ratio.resize(texels);
        m.difference.resize(texels);
        m.original.resize(texels);
        m.reflectance.resize(texels);
        const FaceField field{radiosity, static_cast<int>(f), face.lengthS(), face.lengthT()};
        tbb::parallel_for(0, m.height, [&](int j) {
            for (int i = 0; i < m.width; ++i) {
                const double s = (i + 0.5) / m.width, t = (j + 0.5) / m.height;
                const std::size_t k = m.texel(i, j);
                const Eigen::Vector3d b0 = field.filtered(s, t, [&](int l) { return without.radiance[static_cast<std::size_t>(l)]; });
                const Eigen::Vector3d b1 = field.filtered(s, t, [&](int l) { return with.radiance[static_cast<std::size_t>(l)]; });
                const Eigen::Vector3d r = field.filtered(s, t, [&](int l) { return rho[static_cast<std::size_t>(l)]; });
                Rgb ratio;
                for (int c = 0; c < 3; ++c) {
                    // Hard case: B~ near zero (an unlit corner): the ratio is capped and the
                    // difference, beside it, carries the light (ratioWeight() chooses).
                    const double den = b0[c];
                    const double q = den > 1e-12 ? b1[c] / den : (b1[c] > 1e-12 ? kMaxRatio : 1.0);
                    ratio[c] = static_cast<float>(std::clamp(q, 0.0, static_cast<double>(kMaxRatio)));
                }
                m.ratio[k] = ratio;
                m.difference[k] = toRgb(b1 - b0);
                m.original[k] = toRgb(b0);
                m.reflectance[k] = toRgb(r.cwiseMax(0.0).cwiseMin(1.0));
            }
        });
        for (int l : leaves) {
            const Element& e = h[l];
            if (e.buried) continue;
            const Eigen::Vector2d a = e.st, b = e.st + e.ds + e.dt;
            m.elements.emplace_back(static_cast<float>(std::min(a.x(), b.x())), static_cast<float>(std::min(a.y(), b.y())),
                                    static_cast<float>(std::max(a.x(), b.x())), static_cast<float>(std::max(a.y(), b.y())));
        }
        out.push_back(std::move(m));
    }
    return out;
}

std::vector<VirtualIrradiance> buildProbes(const Radiosity& radiosity, const Scene& scene, const Solution& with,
                                           const std::vector<ProbeLight>& lights, int directions) {
    std::vector<VirtualIrradiance> out;
    const RayScene& rays = radiosity.rays();
    const std::vector<Eigen::Vector3d> dirs = sphereDirections(directions);
    const Hierarchy& h = radiosity.hierarchy();
    // Faces of each virtual object (global face index of its first face).
    std::vector<int> first_face(scene.virtual_objects.size(), -1);
    for (std::size_t f = radiosity.realFaceCount(); f < h.faceCount(); ++f) {
        const int v = radiosity.virtualObjectOfFace(static_cast<int>(f));
        if (first_face[static_cast<std::size_t>(v)] < 0) first_face[static_cast<std::size_t>(v)] = static_cast<int>(f);
    }
    for (std::size_t v = 0; v < scene.virtual_objects.size(); ++v) {
        VirtualIrradiance probe;
        probe.object = scene.virtual_objects[v].name;
        probe.object_index = static_cast<int>(v);
        // Bounds from the object's posed faces.
        Eigen::AlignedBox3d box;
        for (std::size_t f = radiosity.realFaceCount(); f < h.faceCount(); ++f) {
            if (radiosity.virtualObjectOfFace(static_cast<int>(f)) != static_cast<int>(v)) continue;
            for (const Eigen::Vector3d& c : radiosity.face(static_cast<int>(f)).corners()) box.extend(c);
        }
        if (box.isEmpty()) box.extend(radiosity.virtualPoses()[v].translation);
        probe.bounds_min = box.min();
        probe.bounds_max = box.max();
        const Eigen::Vector3d extent = box.sizes();
        for (int a = 0; a < 3; ++a) probe.dims[a] = extent[a] > 0.3 ? 3 : (extent[a] > 0.12 ? 2 : 1);
        const int count = probe.dims.prod();
        probe.indirect.assign(static_cast<std::size_t>(count), IrradianceSh{});
        probe.direct.assign(static_cast<std::size_t>(count), IrradianceSh{});
        for (auto& sh : probe.indirect) sh.fill(Rgb::Zero());
        for (auto& sh : probe.direct) sh.fill(Rgb::Zero());
        tbb::parallel_for(0, count, [&](int index) {
            const int ix = index % probe.dims.x(), iy = (index / probe.dims.x()) % probe.dims.y(), iz = index / (probe.dims.x() * probe.dims.y());
            const Eigen::Vector3d frac((probe.dims.x() > 1 ? static_cast<double>(ix) / (probe.dims.x() - 1) : 0.5),
                                       (probe.dims.y() > 1 ? static_cast<double>(iy) / (probe.dims.y() - 1) : 0.5),
                                       (probe.dims.z() > 1 ? static_cast<double>(iz) / (probe.dims.z() - 1) : 0.5));
            const Eigen::Vector3d p = box.min() + frac.cwiseProduct(extent);
            std::array<Eigen::Vector3d, 9> ind{}, dir{};
            for (auto& c : ind) c.setZero();
            for (auto& c : dir) c.setZero();
            // Step 1: radiance from every direction (surfaces and the environment's residual).
            const double d_omega = 4.0 * kPi / static_cast<double>(dirs.size());
            for (const Eigen::Vector3d& w : dirs) {
                const RayHit real = rays.intersectReal(p, w);
                const RayHit other = rays.intersectVirtualExcept(p, w, static_cast<int>(v));
                Eigen::Vector3d radiance = Eigen::Vector3d::Zero();
                if (other.kind == HitKind::kVirtual && (real.kind == HitKind::kNone || other.distance < real.distance)) {
                    const Eigen::Vector3d hit_point = p + other.distance * w;
                    int f = first_face[static_cast<std::size_t>(other.index)] + std::max(other.primitive, 0);
                    if (other.primitive < 0) {
                        // An exact sphere: the facet in the hit's direction from the centre.
                        const Eigen::Vector3d c = radiosity.virtualPoses()[static_cast<std::size_t>(other.index)].translation;
                        double best = -2.0;
                        for (std::size_t g = radiosity.realFaceCount(); g < h.faceCount(); ++g) {
                            if (radiosity.virtualObjectOfFace(static_cast<int>(g)) != other.index) continue;
                            const double d = radiosity.face(static_cast<int>(g)).normal.dot((hit_point - c).normalized());
                            if (d > best) {
                                best = d;
                                f = static_cast<int>(g);
                            }
                        }
                    }
                    const Face& face = radiosity.face(f);
                    const int leaf = h.leafAt(f, faceCoordinates(face, hit_point));
                    if (face.normal.dot(-w) > 0.0) radiance = with.radiance[static_cast<std::size_t>(leaf)];
                } else if (real.kind == HitKind::kRealFace) {
                    const Face& face = radiosity.face(real.index);
                    const int leaf = h.leafAt(real.index, faceCoordinates(face, p + real.distance * w));
                    if (!h[leaf].buried) radiance = with.radiance[static_cast<std::size_t>(leaf)];
                } else if (real.kind == HitKind::kNone && w.z() > 0.0) {
                    for (const ProbeLight& l : lights) {
                        if (!l.indirect || l.source.kind != DirectSource::Kind::kCell) continue;
                        const double phi = std::atan2(w.y(), w.x()) < 0.0 ? std::atan2(w.y(), w.x()) + 2.0 * kPi : std::atan2(w.y(), w.x());
                        if (w.z() >= l.source.cos0 && w.z() < l.source.cos1 && phi >= l.source.phi0 && phi < l.source.phi1) {
                            radiance += l.emission;
                        }
                    }
                }
                if (radiance.isZero()) continue;
                const auto y = basis(w);
                for (int k = 0; k < 9; ++k) ind[static_cast<std::size_t>(k)] += d_omega * y[static_cast<std::size_t>(k)] * radiance;
            }
            // Step 2: the lights the renderer draws, sampled on their own geometry.
            const std::uint64_t seed = hashCombine(0xfeedull, static_cast<std::uint64_t>(v * 1000 + index));
            for (std::size_t li = 0; li < lights.size(); ++li) {
                const ProbeLight& l = lights[li];
                if (l.indirect) continue;
                const auto add = [&](const Eigen::Vector3d& towards, const Eigen::Vector3d& radiance_times_omega) {
                    const auto y = basis(towards);
                    for (int k = 0; k < 9; ++k) dir[static_cast<std::size_t>(k)] += y[static_cast<std::size_t>(k)] * radiance_times_omega;
                };
                const auto visible = [&](const Eigen::Vector3d& target, const Eigen::Vector3d& target_normal) {
                    if (rays.occludedReal(p, Eigen::Vector3d::Zero(), target, target_normal)) return false;
                    const Eigen::Vector3d d = target - p;
                    const RayHit hv = rays.intersectVirtualExcept(p, d.normalized(), static_cast<int>(v), d.norm() - rays.epsilon());
                    return hv.kind == HitKind::kNone;
                };
                switch (l.source.kind) {
                    case DirectSource::Kind::kPolygon: {
                        const LightGeometry& g = *l.source.polygon;
                        constexpr int kSamples = 16;
                        for (int s = 0; s < kSamples; ++s) {
                            const Eigen::Vector2d u = stratified2d(hashCombine(seed, li), s, kSamples);
                            const Eigen::Vector3d y = g.disc ? g.world_from_object * Eigen::Vector3d(g.radius * std::sqrt(u.x()) * std::cos(2 * kPi * u.y()), g.radius * std::sqrt(u.x()) * std::sin(2 * kPi * u.y()), 0.0)
                                                             : g.world_from_object * Eigen::Vector3d((u.x() - 0.5) * g.size.x(), (u.y() - 0.5) * g.size.y(), 0.0);
                            const Eigen::Vector3d d = y - p;
                            const double d2 = d.squaredNorm();
                            const double cos_l = g.normal.dot(-d) / std::sqrt(d2);
                            if (cos_l <= 0.0 || !(d2 > 1e-12) || !visible(y, g.normal)) continue;
                            add(d.normalized(), l.emission * (g.area * cos_l / d2 / kSamples));
                        }
                        break;
                    }
                    case DirectSource::Kind::kPoint: {
                        const Eigen::Vector3d d = l.source.position - p;
                        const double d2 = d.squaredNorm();
                        if (d2 > 1e-12 && visible(l.source.position, Eigen::Vector3d::Zero())) add(d.normalized(), l.emission / d2);
                        break;
                    }
                    case DirectSource::Kind::kDirection: {
                        const Eigen::Vector3d towards = -l.source.direction.normalized();
                        if (!rays.occludedRealRay(p, Eigen::Vector3d::Zero(), towards) &&
                            rays.intersectVirtualExcept(p, towards, static_cast<int>(v)).kind == HitKind::kNone) {
                            add(towards, l.emission);
                        }
                        break;
                    }
                    case DirectSource::Kind::kCell:
                        break;
                }
            }
            for (int k = 0; k < 9; ++k) {
                probe.indirect[static_cast<std::size_t>(index)][static_cast<std::size_t>(k)] = (kBand[k] * ind[static_cast<std::size_t>(k)]).cast<float>();
                probe.direct[static_cast<std::size_t>(index)][static_cast<std::size_t>(k)] = (kBand[k] * dir[static_cast<std::size_t>(k)]).cast<float>();
            }
        });
        out.push_back(std::move(probe));
    }
    return out;
}

}  // namespace commonlight::lighting

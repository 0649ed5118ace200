#include "lighting/snapshot_builder.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>
#include <optional>

#include "lighting/sampling.h"

namespace commonlight::lighting {

namespace {

constexpr double kPi = std::numbers::pi;

Rgb toRgb(const Eigen::Vector3d& v) { return v.cast<float>(); }

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

std::optional<FaceModulation> buildFaceModulation(const Radiosity& radiosity, const Scene& scene, int f,
                                                  const std::vector<Eigen::Vector3d>& without, const std::vector<Eigen::Vector3d>& with,
                                                  const std::vector<Eigen::Vector3d>& rho, int max_texels, const TexelDirect* texel_direct) {
    const Hierarchy& h = radiosity.hierarchy();
    const Face& face = radiosity.face(f);
    std::vector<int> leaves;
    h.leavesUnder(h.root(f), leaves);
    double finest = 1e300, area = 0.0, lum = 0.0;
    bool any = false;
    for (int l : leaves) {
        const Element& e = h[l];
        if (e.buried) continue;
        any = true;
        finest = std::min(finest, std::min(e.size_s, e.size_t_));
        area += e.area;
        lum += e.area * luminance(toRgb(without[static_cast<std::size_t>(l)]));
    }
    if (!any) return std::nullopt;
    FaceModulation m;
    m.object_index = face.object_index;
    m.object = scene.real_objects[static_cast<std::size_t>(face.object_index)].name;
    m.face = face.face_index;
    m.corners = face.corners();
    m.normal = face.normal;
    // (Texels of per-texel direct light: `oversample` per finest leaf along each side.)
    const double texel_size = finest / (texel_direct && !face.triangle ? std::max(1, texel_direct->oversample) : 1);
    m.width = std::clamp(static_cast<int>(std::ceil(face.lengthS() / texel_size)), 2, max_texels);
    m.height = std::clamp(static_cast<int>(std::ceil(face.lengthT() / texel_size)), 2, max_texels);
    m.mean_original = area > 0.0 ? static_cast<float>(lum / area) : 0.0f;
    const std::size_t texels = static_cast<std::size_t>(m.width) * static_cast<std::size_t>(m.height);
    m.ratio.resize(texels);
    m.difference.resize(texels);
    m.original.resize(texels);
    m.reflectance.resize(texels);
    // The leaf under every texel centre: a parallelogram face's leaves are rectangles in (s, t),
    // rasterised; a triangle's found by descent. Lookups between texel centres take the nearest.
    std::vector<int> leaf_of(texels, -1);
    if (!face.triangle) {
        for (int l : leaves) {
            const Element& e = h[l];
            const Eigen::Vector2d a = e.st, b = e.st + e.ds + e.dt;
            const int i0 = std::max(0, static_cast<int>(std::ceil(std::min(a.x(), b.x()) * m.width - 0.5)));
            const int i1 = std::min(m.width - 1, static_cast<int>(std::ceil(std::max(a.x(), b.x()) * m.width - 0.5)) - 1);
            const int j0 = std::max(0, static_cast<int>(std::ceil(std::min(a.y(), b.y()) * m.height - 0.5)));
            const int j1 = std::min(m.height - 1, static_cast<int>(std::ceil(std::max(a.y(), b.y()) * m.height - 0.5)) - 1);
            for (int j = j0; j <= j1; ++j) {
                for (int i = i0; i <= i1; ++i) leaf_of[m.texel(i, j)] = l;
            }
        }
    }
    const auto leafAt = [&](double s, double t) {
        const int i = std::clamp(static_cast<int>(s * m.width), 0, m.width - 1);
        const int j = std::clamp(static_cast<int>(t * m.height), 0, m.height - 1);
        int& l = leaf_of[m.texel(i, j)];
        return l >= 0 ? l : h.leafAt(f, Eigen::Vector2d((i + 0.5) / m.width, (j + 0.5) / m.height));
    };
    if (face.triangle) {
        for (int j = 0; j < m.height; ++j) {
            for (int i = 0; i < m.width; ++i) leaf_of[m.texel(i, j)] = h.leafAt(f, Eigen::Vector2d((i + 0.5) / m.width, (j + 0.5) / m.height));
        }
    }
    // Box filter of the piecewise-constant leaf field around (s, t), over the local leaf's extent:
    // linear between element centres, no steps at element borders. The leaves it averages (the
    // four corners of the box, those not buried; the centre's when all are) are found once per
    // texel and read for every field.
    struct Stencil {
        std::array<int, 4> leaf{};
        int n = 0;
    };
    const auto stencil = [&](double s, double t) {
        const int centre = leafAt(s, t);
        const Element& e = h[centre];
        const double hs = 0.5 * std::max(std::abs(e.ds.x()), std::abs(e.dt.x()));
        const double ht = 0.5 * std::max(std::abs(e.ds.y()), std::abs(e.dt.y()));
        Stencil st;
        for (int dj = -1; dj <= 1; dj += 2) {
            for (int di = -1; di <= 1; di += 2) {
                const int leaf = leafAt(std::clamp(s + 0.5 * di * hs, 0.0, 1.0), std::clamp(t + 0.5 * dj * ht, 0.0, 1.0));
                if (h[leaf].buried) continue;
                st.leaf[static_cast<std::size_t>(st.n++)] = leaf;
            }
        }
        if (st.n == 0) st.leaf[static_cast<std::size_t>(st.n++)] = centre;
        return st;
    };
    const auto filtered = [](const Stencil& st, const std::vector<Eigen::Vector3d>& field) {
        Eigen::Vector3d sum = Eigen::Vector3d::Zero();
        for (int q = 0; q < st.n; ++q) sum += field[static_cast<std::size_t>(st.leaf[static_cast<std::size_t>(q)])];
        return Eigen::Vector3d(sum / st.n);
    };
    tbb::parallel_for(0, m.height, [&](int j) {
        for (int i = 0; i < m.width; ++i) {
            const double s = (i + 0.5) / m.width, t = (j + 0.5) / m.height;
            const std::size_t k = m.texel(i, j);
            const Stencil st = stencil(s, t);
            Eigen::Vector3d b0 = filtered(st, without);
            Eigen::Vector3d b1 = filtered(st, with);
            const Eigen::Vector3d r = filtered(st, rho);
            if (texel_direct && !face.triangle) {
                // The area lights' direct light at the texel's point instead of the elements' where
                // the objects change it.
                const Eigen::Vector3d e0 = filtered(st, *texel_direct->without);
                const Eigen::Vector3d e1 = filtered(st, *texel_direct->with);
                if ((e1 - e0).cwiseAbs().maxCoeff() > texel_direct->threshold) {
                    Eigen::Vector3d d0 = Eigen::Vector3d::Zero(), d1 = Eigen::Vector3d::Zero();
                    texel_direct->at(f, k, m.width, m.height, face.origin + s * face.edge_s + t * face.edge_t, d0, d1);
                    b0 += r.cwiseProduct(d0 - e0) / kPi;
                    b1 += r.cwiseProduct(d1 - e1) / kPi;
                }
            }
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
    return m;
}

std::vector<std::optional<FaceModulation>> buildFaceModulations(const Radiosity& radiosity, const Scene& scene,
                                                                const std::vector<Eigen::Vector3d>& without,
                                                                const std::vector<Eigen::Vector3d>& with,
                                                                const std::vector<Eigen::Vector3d>& rho, const std::vector<int>& faces,
                                                                int max_texels, const TexelDirect* texel_direct) {
    std::vector<std::optional<FaceModulation>> out(faces.size());
    for (std::size_t i = 0; i < faces.size(); ++i) out[i] = buildFaceModulation(radiosity, scene, faces[i], without, with, rho, max_texels, texel_direct);
    return out;
}

ProbeIrradiance probeIrradiance(const Radiosity& radiosity, const Eigen::Vector3d& p, int object,
                                const std::vector<Eigen::Vector3d>& radiance, const std::vector<ProbeLight>& lights,
                                int directions, std::uint64_t seed, bool other_objects) {
    const RayScene& rays = radiosity.rays();
    const Hierarchy& h = radiosity.hierarchy();
    const std::vector<Eigen::Vector3d> dirs = sphereDirections(directions);
    std::array<Eigen::Vector3d, 9> ind{}, dir{};
    for (auto& c : ind) c.setZero();
    for (auto& c : dir) c.setZero();
    // Step 1: radiance from every direction (surfaces and the environment's residual).
    const double d_omega = 4.0 * kPi / static_cast<double>(dirs.size());
    for (const Eigen::Vector3d& w : dirs) {
        const RayHit real = rays.intersectReal(p, w);
        const RayHit other = other_objects ? rays.intersectVirtualExcept(p, w, object) : RayHit{};
        Eigen::Vector3d l = Eigen::Vector3d::Zero();
        if (other.kind == HitKind::kVirtual && (real.kind == HitKind::kNone || other.distance < real.distance)) {
            const Eigen::Vector3d hit_point = p + other.distance * w;
            // The other object's face the ray met (an exact sphere: the facet in the hit's
            // direction from its centre).
            int f = -1, k = 0;
            double best = -2.0;
            const Eigen::Vector3d c = radiosity.virtualPoses()[static_cast<std::size_t>(other.index)].translation;
            for (std::size_t g = radiosity.realFaceCount(); g < h.faceCount(); ++g) {
                if (radiosity.virtualObjectOfFace(static_cast<int>(g)) != other.index) continue;
                if (other.primitive >= 0) {
                    if (k++ == other.primitive) f = static_cast<int>(g);
                    continue;
                }
                const double d = radiosity.face(static_cast<int>(g)).normal.dot((hit_point - c).normalized());
                if (d > best) {
                    best = d;
                    f = static_cast<int>(g);
                }
            }
            if (f >= 0) {
                const Face& face = radiosity.face(f);
                const int leaf = h.leafAt(f, faceCoordinates(face, hit_point));
                if (face.normal.dot(-w) > 0.0) l = radiance[static_cast<std::size_t>(leaf)];
            }
        } else if (real.kind == HitKind::kRealFace) {
            const Face& face = radiosity.face(real.index);
            const int leaf = h.leafAt(real.index, faceCoordinates(face, p + real.distance * w));
            if (!h[leaf].buried) l = radiance[static_cast<std::size_t>(leaf)];
        } else if (real.kind == HitKind::kNone && w.z() > 0.0) {
            for (const ProbeLight& pl : lights) {
                if (!pl.indirect || pl.source.kind != DirectSource::Kind::kCell) continue;
                const double phi = std::atan2(w.y(), w.x()) < 0.0 ? std::atan2(w.y(), w.x()) + 2.0 * kPi : std::atan2(w.y(), w.x());
                if (w.z() >= pl.source.cos0 && w.z() < pl.source.cos1 && phi >= pl.source.phi0 && phi < pl.source.phi1) {
                    l += pl.emission;
                }
            }
        }
        if (l.isZero()) continue;
        const auto y = basis(w);
        for (int k = 0; k < 9; ++k) ind[static_cast<std::size_t>(k)] += d_omega * y[static_cast<std::size_t>(k)] * l;
    }
    // Step 2: the lights the renderer draws, sampled on their own geometry.
    for (std::size_t li = 0; li < lights.size(); ++li) {
        const ProbeLight& pl = lights[li];
        if (pl.indirect) continue;
        const auto add = [&](const Eigen::Vector3d& towards, const Eigen::Vector3d& radiance_times_omega) {
            const auto y = basis(towards);
            for (int k = 0; k < 9; ++k) dir[static_cast<std::size_t>(k)] += y[static_cast<std::size_t>(k)] * radiance_times_omega;
        };
        const auto visible = [&](const Eigen::Vector3d& target, const Eigen::Vector3d& target_normal) {
            if (rays.occludedReal(p, Eigen::Vector3d::Zero(), target, target_normal)) return false;
            if (!other_objects) return true;
            const Eigen::Vector3d d = target - p;
            const RayHit hv = rays.intersectVirtualExcept(p, d.normalized(), object, d.norm() - rays.epsilon());
            return hv.kind == HitKind::kNone;
        };
        switch (pl.source.kind) {
            case DirectSource::Kind::kPolygon: {
                const LightGeometry& g = *pl.source.polygon;
                constexpr int kSamples = 16;
                for (int s = 0; s < kSamples; ++s) {
                    const Eigen::Vector2d u = stratified2d(hashCombine(seed, li), s, kSamples);
                    const Eigen::Vector3d y = sampleLight(g, u);
                    const Eigen::Vector3d d = y - p;
                    const double d2 = d.squaredNorm();
                    const double cos_l = g.normal.dot(-d) / std::sqrt(d2);
                    if (cos_l <= 0.0 || !(d2 > 1e-12) || !visible(y, g.normal)) continue;
                    add(d.normalized(), pl.emission * (g.area * cos_l / d2 / kSamples));
                }
                break;
            }
            case DirectSource::Kind::kPoint: {
                const Eigen::Vector3d d = pl.source.position - p;
                const double d2 = d.squaredNorm();
                if (d2 > 1e-12 && visible(pl.source.position, Eigen::Vector3d::Zero())) add(d.normalized(), pl.emission / d2);
                break;
            }
            case DirectSource::Kind::kDirection: {
                const Eigen::Vector3d towards = -pl.source.direction.normalized();
                if (!rays.occludedRealRay(p, Eigen::Vector3d::Zero(), towards) &&
                    (!other_objects || rays.intersectVirtualExcept(p, towards, object).kind == HitKind::kNone)) {
                    add(towards, pl.emission);
                }
                break;
            }
            case DirectSource::Kind::kCell:
                break;
        }
    }
    ProbeIrradiance out;
    for (int k = 0; k < 9; ++k) {
        out.indirect[static_cast<std::size_t>(k)] = (kBand[k] * ind[static_cast<std::size_t>(k)]).cast<float>();
        out.direct[static_cast<std::size_t>(k)] = (kBand[k] * dir[static_cast<std::size_t>(k)]).cast<float>();
    }
    return out;
}

std::vector<VirtualIrradiance> buildProbes(const Radiosity& radiosity, const Scene& scene, const std::vector<Eigen::Vector3d>& radiance,
                                           const std::vector<ProbeLight>& lights, int directions) {
    std::vector<VirtualIrradiance> out;
    const Hierarchy& h = radiosity.hierarchy();
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
        tbb::parallel_for(0, count, [&](int index) {
            const int ix = index % probe.dims.x(), iy = (index / probe.dims.x()) % probe.dims.y(), iz = index / (probe.dims.x() * probe.dims.y());
            const Eigen::Vector3d frac((probe.dims.x() > 1 ? static_cast<double>(ix) / (probe.dims.x() - 1) : 0.5),
                                       (probe.dims.y() > 1 ? static_cast<double>(iy) / (probe.dims.y() - 1) : 0.5),
                                       (probe.dims.z() > 1 ? static_cast<double>(iz) / (probe.dims.z() - 1) : 0.5));
            const Eigen::Vector3d p = box.min() + frac.cwiseProduct(extent);
            const ProbeIrradiance e = probeIrradiance(radiosity, p, static_cast<int>(v), radiance, lights, directions,
                                                      hashCombine(0xfeedull, static_cast<std::uint64_t>(v * 1000 + index)));
            probe.indirect[static_cast<std::size_t>(index)] = e.indirect;
            probe.direct[static_cast<std::size_t>(index)] = e.direct;
        });
        out.push_back(std::move(probe));
    }
    return out;
}

}  // namespace commonlight::lighting

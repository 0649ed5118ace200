#include "lighting/direct.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <numbers>

#include "lighting/form_factor.h"
#include "lighting/sampling.h"

namespace commonlight::lighting {

namespace {

constexpr double kPi = std::numbers::pi;

}  // namespace

// Rectangles directly, discs by the concentric map (Shirley and Chiu 1997).
Eigen::Vector3d sampleLight(const LightGeometry& g, const Eigen::Vector2d& u) {
    if (!g.disc) {
        return g.world_from_object * Eigen::Vector3d((u.x() - 0.5) * g.size.x(), (u.y() - 0.5) * g.size.y(), 0.0);
    }
    const double a = 2.0 * u.x() - 1.0, b = 2.0 * u.y() - 1.0;
    double r = 0.0, phi = 0.0;
    if (a == 0.0 && b == 0.0) {
        r = 0.0;
    } else if (std::abs(a) > std::abs(b)) {
        r = a;
        phi = (kPi / 4.0) * (b / a);
    } else {
        r = b;
        phi = kPi / 2.0 - (kPi / 4.0) * (a / b);
    }
    return g.world_from_object * Eigen::Vector3d(g.radius * r * std::cos(phi), g.radius * r * std::sin(phi), 0.0);
}

std::uint64_t directSeed(const DirectSource& source, std::uint64_t seed) {
    return hashCombine(seed, static_cast<std::uint64_t>(source.light) * 1000003ull +
                                 static_cast<std::uint64_t>(std::llround(1e4 * (source.phi0 + 7.0 * source.cos0))));
}

Eigen::Vector3d DirectSource::cellDirection(const Eigen::Vector2d& u) const {
    const double c = cos0 + u.x() * (cos1 - cos0);
    const double s = std::sqrt(std::max(0.0, 1.0 - c * c));
    const double phi = phi0 + u.y() * (phi1 - phi0);
    return {s * std::cos(phi), s * std::sin(phi), c};
}

Eigen::Vector3d DirectSource::cellCentre() const {
    const double c = 0.5 * (cos0 + cos1);
    const double s = std::sqrt(std::max(0.0, 1.0 - c * c));
    const double phi = 0.5 * (phi0 + phi1);
    return {s * std::cos(phi), s * std::sin(phi), c};
}

std::vector<DirectSource> distantCells(int light, int n) {
    n = std::max(n, 2);
    int n_theta = std::max(1, static_cast<int>(std::lround(std::sqrt(n / 2.0))));
    int n_phi = std::max(1, n / n_theta);
    std::vector<DirectSource> cells;
    for (int i = 0; i < n_theta; ++i) {
        for (int j = 0; j < n_phi; ++j) {
            DirectSource s;
            s.kind = DirectSource::Kind::kCell;
            s.light = light;
            s.cos0 = static_cast<double>(i) / n_theta;
            s.cos1 = static_cast<double>(i + 1) / n_theta;
            s.phi0 = 2.0 * kPi * j / n_phi;
            s.phi1 = 2.0 * kPi * (j + 1) / n_phi;
            cells.push_back(s);
        }
    }
    return cells;
}

void computeDirect(const Radiosity& radiosity, const DirectSource& source, const std::vector<int>& leaves,
                   const DirectOptions& options, DirectColumn& column) {
    const std::size_t n = radiosity.hierarchy().elements().size();
    column.real.resize(n, 0.0f);
    const RayScene& rays = radiosity.rays();
    const std::uint64_t source_seed = directSeed(source, options.seed);
    tbb::parallel_for(std::size_t{0}, leaves.size(), [&](std::size_t k) {
        const int e = leaves[k];
        const ElementGeometry g = radiosity.geometry(e);
        const Element& el = radiosity.hierarchy()[e];
        const std::uint64_t seed = hashCombine(source_seed, radiosity.hierarchy().key(e));
        const bool is_virtual = radiosity.isVirtualElement(e);
        double real_sum = 0.0;
        switch (source.kind) {
            case DirectSource::Kind::kPolygon: {
                const LightGeometry& light = *source.polygon;
                const double distance = (g.centroid - light.centre).norm();
                const int order = std::min(4, formFactorRule(distance, std::sqrt(el.area), std::sqrt(light.area)));
                // Over the leaf's exposed part (a desk element partly under the books).
                const auto points = radiosity.exposedRule(e, order);
                const bool partial = radiosity.exposure(e) < 1.0;
                // The unoccluded irradiance by Gauss quadrature of the exact point form factor,
                // times the visible fraction: over stratified (leaf point, light point) pairs spread
                // over the whole leaf, so a shadow boundary anywhere in it is seen, each pair
                // weighted by its kernel cos_x cos_y / d^2 (the ratio of the occluded to the
                // unoccluded double integral). A penumbra (some pairs blocked, some not) gets
                // sixteen times the pairs.
                double open = 0.0;
                for (const QuadraturePoint& q : points) open += q.weight * kPi * pointToPolygon(q.x, g.normal, light.polygon, light.normal);
                if (!(open > 0.0)) break;
                const double floor2 = std::pow(0.05 * std::sqrt(std::min(el.area, light.area)), 2);
                const auto visible_fraction = [&](int pairs, std::uint64_t pair_seed) {
                    double f_sum = 0.0, f_real = 0.0;
                    for (int pair = 0; pair < pairs; ++pair) {
                        const SamplePair u = stratifiedPair(pair_seed, pair, pairs);
                        Eigen::Vector3d x = samplePolygon(g.corner, g.edge_s, g.edge_t, g.triangle, u.first.x(), u.first.y());
                        if (partial && radiosity.hidden(e, x)) continue;
                        if (is_virtual) x = radiosity.onSurface(e, x);
                        const Eigen::Vector3d y = sampleLight(light, u.second);
                        const Eigen::Vector3d d = y - x;
                        // Hard case: the kernel diverges where the light touches the leaf; the
                        // distance is floored at 5% of the smaller of the two (the weights only
                        // rank the pairs).
                        const double d2 = std::max(d.squaredNorm(), floor2);
                        const double f = std::max(0.0, g.normal.dot(d)) * std::max(0.0, -light.normal.dot(d)) / (d2 * d2);
                        if (f <= 0.0) continue;
                        f_sum += f;
                        if (!rays.occludedReal(x, g.normal, y, light.normal)) f_real += f;
                    }
                    return f_sum > 0.0 ? f_real / f_sum : 1.0;
                };
                const int pairs = std::max(4, options.rays);
                // A pilot decides how many pairs the estimate gets; the estimate uses pairs of its
                // own (stopping at a clear pilot would read a leaf barely touched by a shadow as
                // clear: biased high). A penumbra across the leaf: sixteen times the pairs (a large
                // leaf half in a shadow needs many to know which half: 1.5% noise). Real occluders
                // only: what the virtual objects block is lighting/influence.h's (B~ must not
                // depend on where they are).
                const auto penumbra = [](double r) { return r > 0.0 && r < 1.0; };
                double vr = visible_fraction(pairs, hash64(seed ^ 0x9f1e7ull));
                if (penumbra(vr)) {
                    vr = visible_fraction(16 * pairs, seed);
                } else if (vr == 0.0) {
                    vr = visible_fraction(4 * pairs, hash64(seed ^ 0x51ce1ull));  // a sliver of light the pilot missed
                    if (penumbra(vr)) vr = visible_fraction(16 * pairs, seed);
                } else {
                    vr = visible_fraction(pairs, seed);
                }
                real_sum = open * vr;
                break;
            }
            case DirectSource::Kind::kPoint: {
                const auto points = radiosity.exposedRule(e, 2);
                for (std::size_t q = 0; q < points.size(); ++q) {
                    const Eigen::Vector3d xq = is_virtual ? radiosity.onSurface(e, points[q].x) : points[q].x;
                    const Eigen::Vector3d d = source.position - xq;
                    const double d2 = d.squaredNorm();
                    // Hard case: a point light on the receiver gives no finite irradiance; count none.
                    if (!(d2 > 1e-12)) continue;
                    const double cos_theta = g.normal.dot(d) / std::sqrt(d2);
                    if (cos_theta <= 0.0) continue;
                    if (!rays.occludedReal(xq, g.normal, source.position)) real_sum += points[q].weight * cos_theta / d2;
                }
                break;
            }
            case DirectSource::Kind::kDirection: {
                const Eigen::Vector3d towards = -source.direction.normalized();
                const double cos_theta = g.normal.dot(towards);
                if (cos_theta <= 0.0) break;
                const auto points = radiosity.exposedRule(e, 2);
                for (std::size_t q = 0; q < points.size(); ++q) {
                    const Eigen::Vector3d xq = is_virtual ? radiosity.onSurface(e, points[q].x) : points[q].x;
                    if (!rays.occludedRealRay(xq, g.normal, towards)) real_sum += points[q].weight * cos_theta;
                }
                break;
            }
            case DirectSource::Kind::kCell: {
                const double omega = source.solidAngle();
                const int m = std::max(1, options.cell_rays);
                const bool partial = radiosity.exposure(e) < 1.0;
                int valid = 0;
                for (int r = 0; r < m; ++r) {
                    const Eigen::Vector2d u = stratified2d(seed, r, m);
                    const Eigen::Vector3d w = source.cellDirection(u);
                    // One point per direction, spread over the leaf's exposed part.
                    const Eigen::Vector2d p = stratified2d(hash64(seed), permuted(r, m, hash64(seed + 1)), m);
                    Eigen::Vector3d x = samplePolygon(g.corner, g.edge_s, g.edge_t, g.triangle, p.x(), p.y());
                    if (partial && radiosity.hidden(e, x)) continue;
                    ++valid;
                    const double cos_theta = g.normal.dot(w);
                    if (cos_theta <= 0.0) continue;
                    if (is_virtual) x = radiosity.onSurface(e, x);
                    if (!rays.occludedRealRay(x, g.normal, w)) real_sum += omega * cos_theta;
                }
                // Hard case: every point of a mostly hidden leaf fell under the box: nothing known, none counted.
                real_sum /= std::max(1, valid);
                break;
            }
        }
        column.real[static_cast<std::size_t>(e)] = static_cast<float>(real_sum);
    });
}

double directAtPoint(const RayScene& rays, const DirectSource& source, const Eigen::Vector3d& x,
                     const Eigen::Vector3d& normal, int samples, std::uint64_t seed) {
    samples = std::max(1, samples);
    switch (source.kind) {
        case DirectSource::Kind::kPolygon: {
            const LightGeometry& light = *source.polygon;
            const double f = pointToPolygon(x, normal, light.polygon, light.normal);
            if (f <= 0.0) return 0.0;
            int visible = 0;
            for (int r = 0; r < samples; ++r) {
                if (!rays.occludedReal(x, normal, sampleLight(light, stratified2d(seed, r, samples)), light.normal)) ++visible;
            }
            return kPi * f * visible / samples;
        }
        case DirectSource::Kind::kPoint: {
            const Eigen::Vector3d d = source.position - x;
            const double d2 = d.squaredNorm();
            if (!(d2 > 1e-12)) return 0.0;
            const double c = normal.dot(d) / std::sqrt(d2);
            if (c <= 0.0 || rays.occludedReal(x, normal, source.position)) return 0.0;
            return c / d2;
        }
        case DirectSource::Kind::kDirection: {
            const Eigen::Vector3d towards = -source.direction.normalized();
            const double c = normal.dot(towards);
            if (c <= 0.0 || rays.occludedRealRay(x, normal, towards)) return 0.0;
            return c;
        }
        case DirectSource::Kind::kCell: {
            double sum = 0.0;
            for (int r = 0; r < samples; ++r) {
                const Eigen::Vector2d u = stratified2d(seed, r, samples);
                const double c = source.cos0 + u.x() * (source.cos1 - source.cos0);
                const double s = std::sqrt(std::max(0.0, 1.0 - c * c));
                const double phi = source.phi0 + u.y() * (source.phi1 - source.phi0);
                const Eigen::Vector3d w(s * std::cos(phi), s * std::sin(phi), c);
                const double cos_theta = normal.dot(w);
                if (cos_theta <= 0.0 || rays.occludedRealRay(x, normal, w)) continue;
                sum += cos_theta;
            }
            return source.solidAngle() * sum / samples;
        }
    }
    return 0.0;
}

}  // namespace commonlight::lighting

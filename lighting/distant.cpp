#include "lighting/distant.h"

#include <tbb/parallel_for.h>

#include <cmath>

#include <Eigen/Geometry>

namespace commonlight::lighting {

namespace {

// E and the residual for one direction.
std::pair<double, double> evaluate(const RayScene& rays, const DirectionRows& rows, const Eigen::Vector3d& d) {
    std::vector<double> a(rows.target.size(), 0.0);
    tbb::parallel_for(std::size_t{0}, rows.target.size(), [&](std::size_t i) {
        const double c = rows.normals[i].dot(d);
        if (c <= 0.0 || rows.points[i].empty()) return;
        int visible = 0;
        for (const Eigen::Vector3d& x : rows.points[i]) {
            if (!rays.occludedRealRay(x, rows.normals[i], d)) ++visible;
        }
        a[i] = rows.scale[i] * c * visible / static_cast<double>(rows.points[i].size());
    });
    double aa = 0.0, ay = 0.0, yy = 0.0;
    for (std::size_t i = 0; i < a.size(); ++i) {
        aa += rows.weight[i] * a[i] * a[i];
        ay += rows.weight[i] * a[i] * rows.target[i];
        yy += rows.weight[i] * rows.target[i] * rows.target[i];
    }
    // Hard case: a direction that lights no observed row explains nothing (E = 0).
    const double e = aa > 0.0 ? std::max(0.0, ay / aa) : 0.0;
    return {e, yy - 2.0 * e * ay + e * e * aa};
}

}  // namespace

DirectionFit refineDirection(const RayScene& rays, const DirectionRows& rows, const Eigen::Vector3d& start,
                             double start_step_rad, double min_step_rad) {
    DirectionFit best;
    best.direction = start.normalized();
    auto [e0, r0] = evaluate(rays, rows, best.direction);
    best.irradiance = e0;
    best.residual = r0;
    best.evaluations = 1;
    double step = start_step_rad;
    while (step >= min_step_rad && best.evaluations < 400) {
        // A tangent frame at the current direction; neighbours at angle `step`.
        const Eigen::Vector3d u = best.direction.unitOrthogonal();
        const Eigen::Vector3d v = best.direction.cross(u);
        bool moved = false;
        DirectionFit candidate = best;
        for (int k = 0; k < 8; ++k) {
            const double phi = k * (M_PI / 4.0);
            const Eigen::Vector3d axis = std::cos(phi) * u + std::sin(phi) * v;
            const Eigen::Vector3d d = (std::cos(step) * best.direction + std::sin(step) * axis).normalized();
            auto [e, r] = evaluate(rays, rows, d);
            ++best.evaluations;
            if (r < candidate.residual) {
                candidate.direction = d;
                candidate.irradiance = e;
                candidate.residual = r;
                moved = true;
            }
        }
        if (moved) {
            const int evaluations = best.evaluations;
            best = candidate;
            best.evaluations = evaluations;
        } else {
            step *= 0.5;
        }
    }
    return best;
}

}  // namespace commonlight::lighting

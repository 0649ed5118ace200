// The dominant direction of an unknown distant light, refined continuously (a lamp or the sun
// rarely sits on one of the N grid directions of the cell fit; issue 10, case 2).
//
// Given per observation row (a leaf or a tag's ring) the radiance left to explain once every other
// column of the model is accounted for, find the direction d (towards the light) and irradiance
// E >= 0 of a directional light that explain it best:
//     min_{d, E >= 0}  sum_i W_i (y_i - E a_i(d))^2,   a_i(d) = s_i * mean over the row's points of
//                                                       max(0, n_i . d) V(x, d)
// with s_i = rho_i / pi. For a fixed d the best E is closed-form (variable projection), so the
// search is over d alone: a pattern search on the sphere (8 neighbours at step h; move to the
// best; halve h when the centre is best) from the dominant cell's centre down to `min_step`.
// Visibility through the real occluders is what places the direction (the shadows' positions).
#pragma once

#include <vector>

#include <Eigen/Core>

#include "lighting/ray_scene.h"

namespace commonlight::lighting {

struct DirectionRows {
    std::vector<std::vector<Eigen::Vector3d>> points;  // per row: world points (a leaf's stratified samples)
    std::vector<Eigen::Vector3d> normals;              // per row
    std::vector<double> scale;                         // s_i
    std::vector<double> target;                        // y_i
    std::vector<double> weight;                        // W_i
};

struct DirectionFit {
    Eigen::Vector3d direction = Eigen::Vector3d::UnitZ();  // unit, towards the light
    double irradiance = 0.0;  // E, on a surface facing it
    double residual = 0.0;    // sum W (y - E a)^2 at the optimum
    int evaluations = 0;
};

DirectionFit refineDirection(const RayScene& rays, const DirectionRows& rows, const Eigen::Vector3d& start,
                             double start_step_rad, double min_step_rad = 1e-4);

}  // namespace commonlight::lighting

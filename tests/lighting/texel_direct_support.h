// Geometry shared by the texel cache's tests (texel_direct_test.cpp, texel_direct_renew_test.cpp).
#pragma once

#include <utility>

#include <Eigen/Core>

#include "core/pose.h"
#include "lighting/proxy_geometry.h"

namespace commonlight::lighting {

// A square floor of side 2 h about the origin (z = 0, facing up), and a square lamp of side `side`
// facing down, centred at `centre`.
inline Face squareFloor(double h) {
    Face floor;
    floor.origin = {-h, -h, 0.0};
    floor.edge_s = {2 * h, 0, 0};
    floor.edge_t = {0, 2 * h, 0};
    floor.normal = {0, 0, 1};
    floor.area = 4 * h * h;
    return floor;
}

inline LightGeometry squareLamp(const Eigen::Vector3d& centre, double side) {
    LightGeometry lamp;
    lamp.world_from_object = Rigid3d::fromRpyDeg(centre, Eigen::Vector3d(180, 0, 0));
    lamp.size = {side, side};
    lamp.centre = centre;
    lamp.normal = {0, 0, -1};
    lamp.area = side * side;
    const double h = 0.5 * side;
    for (const auto& [x, y] : {std::pair{-h, -h}, {h, -h}, {h, h}, {-h, h}}) lamp.polygon.push_back(lamp.world_from_object * Eigen::Vector3d(x, y, 0));
    return lamp;
}

}  // namespace commonlight::lighting

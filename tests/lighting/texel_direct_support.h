// Geometry shared by the texel cache's tests (texel_direct_test.cpp, texel_direct_renew_test.cpp).
#pragma once

#include <memory>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "core/pose.h"
#include "lighting/proxy_geometry.h"
#include "lighting/ray_scene.h"

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

// The centres of a side x side layout of texels on `face` (texel (i, j) at s = (i + 0.5) / side,
// t = (j + 0.5) / side, row by row: TexelDirectCache's texel numbering).
inline std::vector<Eigen::Vector3d> texelCentres(const Face& face, int side) {
    std::vector<Eigen::Vector3d> points;
    for (int j = 0; j < side; ++j) {
        for (int i = 0; i < side; ++i) points.push_back(face.point((i + 0.5) / side, (j + 0.5) / side));
    }
    return points;
}

// A floor of half-side 0.4 m under two square lamps, with one virtual sphere of `radius` (object 0,
// at the origin until moved) in its ray scene; `rays` null when the scene could not be built.
struct FloorUnderTwoLamps {
    Face floor = squareFloor(0.4);
    LightGeometry lamp = squareLamp({0.05, 0.0, 0.7}, 0.15);
    LightGeometry lamp2 = squareLamp({-0.3, 0.2, 0.6}, 0.1);
    std::unique_ptr<RayScene> rays;
    explicit FloorUnderTwoLamps(double radius) {
        VirtualShape sphere;
        sphere.sphere_radius = radius;
        if (auto built = RayScene::build({floor}, {}, {sphere})) rays = std::move(*built);
    }
};

}  // namespace commonlight::lighting

// Direct irradiance from the lights at the leaves of the radiosity hierarchy, at unit emission:
// one "column" per light (or per direction cell of an unknown distant light), so that the direct
// irradiance of any emissions is a linear combination of columns (the light fit of
// lighting/light_fit.h solves for those coefficients).
//
// Per leaf and source, through the real occluders only: B~'s direct light. What the virtual
// objects block is lighting/influence.h's (a transmission per leaf and light). Units: W/m^2 of irradiance per unit of the source's emission quantity:
//   area / disc light   per unit radiance W/(m^2 sr):  E = pi * integral over the leaf of F(x -> light) V(x)
//   point light         per unit intensity W/sr:       E = cos(theta) / d^2 * V
//   directional light   per unit irradiance W/m^2:     E = max(0, cos(theta)) * V
//   distant cell        per unit radiance W/(m^2 sr):  E = integral over the cell's solid angle of max(0, n.w) V(w) dw
// each averaged over the leaf (Gauss points) with jittered visibility rays.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "lighting/proxy_geometry.h"
#include "lighting/radiosity.h"

namespace commonlight::lighting {

struct DirectSource {
    enum class Kind : std::uint8_t { kPolygon, kPoint, kDirection, kCell };
    Kind kind = Kind::kPolygon;
    int light = -1;          // Scene::lights index
    const LightGeometry* polygon = nullptr;  // kPolygon
    Eigen::Vector3d position = Eigen::Vector3d::Zero();   // kPoint
    Eigen::Vector3d direction = -Eigen::Vector3d::UnitZ();  // kDirection: the direction light travels
    // kCell: the world directions w (towards the sky) with cos(theta_world) in [cos0, cos1] and
    // azimuth in [phi0, phi1): an equal-solid-angle cell of the upper hemisphere.
    double cos0 = 0.0, cos1 = 1.0, phi0 = 0.0, phi1 = 0.0;
    double solidAngle() const { return (cos1 - cos0) * (phi1 - phi0); }
    Eigen::Vector3d cellCentre() const;  // unit, towards the sky
    Eigen::Vector3d cellDirection(const Eigen::Vector2d& u) const;  // u in [0,1)^2 -> uniform over the cell's solid angle
};

struct DirectColumn {
    std::vector<float> real;  // by element index (leaves only), irradiance per unit emission
};

struct DirectOptions {
    int rays = 16;       // visibility rays per leaf and source (split over the Gauss points)
    int cell_rays = 4;   // directions per leaf and distant cell
    std::uint64_t seed = 7;
};

// Computes a source's column for the given leaves (others left as they are; the column is resized
// to the element count).
void computeDirect(const Radiosity& radiosity, const DirectSource& source, const std::vector<int>& leaves,
                   const DirectOptions& options, DirectColumn& column);

// A uniform point of an area light from u in [0, 1)^2 (rectangles directly, discs by the concentric
// map, so that stratification survives).
Eigen::Vector3d sampleLight(const LightGeometry& light, const Eigen::Vector2d& u);

// The sample stream of a source for computeDirect()'s seed (`DirectOptions::seed`).
std::uint64_t directSeed(const DirectSource& source, std::uint64_t seed);

// Irradiance per unit emission at one point facing `normal` through the real occluders (a tag's
// white border, a probe): the same estimators as computeDirect with `rays` visibility samples.
double directAtPoint(const RayScene& rays, const DirectSource& source, const Eigen::Vector3d& x,
                     const Eigen::Vector3d& normal, int samples, std::uint64_t seed);

// The N equal-solid-angle cells of the upper hemisphere (seed 003 sec. 5.3: theta = acos(u0),
// phi = 2 pi u1 on a uniform partition): n_theta x n_phi with n_phi = 2 n_theta as near as N allows.
std::vector<DirectSource> distantCells(int light, int n);

}  // namespace commonlight::lighting

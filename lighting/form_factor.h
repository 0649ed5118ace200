// Form factors between a receiver and a polygon, and the quadrature over receivers.
//
// The point-to-polygon form factor (Lambert 1760; Baum, Rushmeier and Winget 1989, eq. 3) is
// exact for an unoccluded polygon:
//     F(x -> P) = 1/(2 pi) sum_i gamma_i (n . (r_i x r_{i+1}) / |r_i x r_{i+1}|)
// with r_i the unit vectors from x to the polygon's vertices and gamma_i the angle between r_i
// and r_{i+1}. It is the irradiance at x from P at unit radiance, divided by pi: a receiver at x
// facing n gets E = pi L F from a Lambertian emitter of radiance L (W/(m^2 sr) -> W/m^2). The
// polygon is first clipped to the receiver's upper half-space, so a source that crosses the
// receiver's plane counts only its visible part (the centre-to-centre approximation is 59% wrong
// for adjacent squares; this is exact pointwise).
//
// An element-to-element form factor is the area average of the point form factor over the
// receiver: Gauss-Legendre product rules on the receiver, more points for near pairs
// (formFactorRule()).
#pragma once

#include <span>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace commonlight::lighting {

// F(x -> polygon) for a receiver at x facing n (unit). The polygon is planar (3 or more vertices,
// either orientation) and emits towards x only if x is on its front side: pass `source_normal`
// (unit; the emitting side) to get 0 from behind, or a zero vector to ignore the side.
// Hard cases: x on the polygon's plane or a vertex at x (zero-length r_i) contribute nothing.
double pointToPolygon(const Eigen::Vector3d& x, const Eigen::Vector3d& n, std::span<const Eigen::Vector3d> polygon,
                      const Eigen::Vector3d& source_normal = Eigen::Vector3d::Zero());

// F from a point to a sphere of radius `radius` whose centre is `distance` away, `cos_phi` the
// cosine between the point's normal and the direction to the centre; the part of the sphere below
// the point's horizon hidden (Howell's catalogue, "differential planar element to sphere"):
// cos(phi) / H^2 (H = distance / radius) while the whole sphere is above the horizon, 0 when it is
// wholly below, and in between
//   1/2 - asin(sqrt(H^2 - 1) / (H sin phi)) / pi
//       + (cos phi acos(-sqrt(H^2 - 1) cot phi) - sqrt(H^2 - 1) sqrt(1 - H^2 cos^2 phi)) / (pi H^2).
// A point inside the sphere is taken on its surface (H = 1).
double pointToSphere(double distance, double radius, double cos_phi);

// A point of a quadrature rule on a receiver: position (world) and weight (weights sum to 1).
struct QuadraturePoint {
    Eigen::Vector3d x;
    double weight;
};

// Gauss-Legendre product rule of order n x n on a parallelogram (corner, edge_s, edge_t), or on a
// triangle (corner, corner + edge_s, corner + edge_t) through the collapsed square (Duffy).
std::vector<QuadraturePoint> quadratureRule(const Eigen::Vector3d& corner, const Eigen::Vector3d& edge_s,
                                            const Eigen::Vector3d& edge_t, bool triangle, int n);

// Order of the receiver rule for a pair whose centres are `distance` apart, receiver and source of
// sizes (sqrt of area) `receiver_size` and `source_size`: 1 far away, up to 8 for adjacent
// elements (where the point form factor varies like log(distance to the shared edge)).
int formFactorRule(double distance, double receiver_size, double source_size);

// Uniform point on a parallelogram or triangle from (u, v) in [0, 1)^2.
Eigen::Vector3d samplePolygon(const Eigen::Vector3d& corner, const Eigen::Vector3d& edge_s,
                              const Eigen::Vector3d& edge_t, bool triangle, double u, double v);

// Gauss-Legendre nodes on [0, 1] and weights summing to 1, orders 1..8.
std::span<const double> gaussNodes(int n);
std::span<const double> gaussWeights(int n);

}  // namespace commonlight::lighting

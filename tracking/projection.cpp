#include "tracking/projection.h"

#include <cmath>

namespace commonlight::tracking {

namespace {

// d(pixel)/d(p) at a point in front of the camera.
inline Eigen::Matrix<double, 2, 3> pointJacobian(const CameraModel& camera, const Eigen::Vector3d& p) {
    const double inv_z = 1.0 / p.z();
    const Eigen::Vector2d xy(p.x() * inv_z, p.y() * inv_z);
    // d(xy)/d(p): the pinhole.
    Eigen::Matrix<double, 2, 3> d_xy_d_p;
    d_xy_d_p << inv_z, 0, -xy.x() * inv_z, 0, inv_z, -xy.y() * inv_z;
    // d(distorted xy)/d(xy), analytic: the derivative of CameraModel::distortNormalized's
    // polynomial (it replaced central differences, four evaluations of the model, exact to
    // ~1e-10; docs/history/tracking-passes-5.md, pass 11).
    Eigen::Matrix2d d_dist;
    if (camera.distortion.isZero()) {
        d_dist.setIdentity();
    } else {
        const Distortion& d = camera.distortion;
        const double x = xy.x(), y = xy.y();
        const double r2 = x * x + y * y;
        const double radial = 1.0 + r2 * (d.k1 + r2 * (d.k2 + r2 * d.k3));
        const double dradial_dr2 = d.k1 + r2 * (2.0 * d.k2 + 3.0 * r2 * d.k3);
        const double cross = 2.0 * x * y * dradial_dr2 + 2.0 * d.p1 * x + 2.0 * d.p2 * y;
        d_dist << radial + 2.0 * x * x * dradial_dr2 + 2.0 * d.p1 * y + 6.0 * d.p2 * x, cross,  //
            cross, radial + 2.0 * y * y * dradial_dr2 + 6.0 * d.p1 * y + 2.0 * d.p2 * x;
    }
    const Eigen::Matrix2d d_pix_d_dist = Eigen::Vector2d(camera.fx, camera.fy).asDiagonal();
    return d_pix_d_dist * d_dist * d_xy_d_p;
}

// The Jacobian at a point in front of the camera whose pixel is known.
inline ProjectionWithJacobian withJacobian(const CameraModel& camera, const Eigen::Vector3d& p,
                                           const Eigen::Vector2d& pixel) {
    // d(p)/d(xi) = [ -[p]x | I ].
    Eigen::Matrix<double, 3, 6> d_p_d_xi;
    d_p_d_xi << 0, p.z(), -p.y(), 1, 0, 0,  //
        -p.z(), 0, p.x(), 0, 1, 0,          //
        p.y(), -p.x(), 0, 0, 0, 1;
    ProjectionWithJacobian out;
    out.pixel = pixel;
    out.d_pixel_d_p = pointJacobian(camera, p);
    out.d_pixel_d_xi = out.d_pixel_d_p * d_p_d_xi;
    return out;
}

}  // namespace

std::optional<ProjectionWithJacobian> projectWithJacobian(const CameraModel& camera, const Eigen::Vector3d& p) {
    if (!(p.z() > 1e-9) || !p.allFinite()) return std::nullopt;
    const auto pixel = camera.project(p);
    if (!pixel) return std::nullopt;
    return withJacobian(camera, p, *pixel);
}

std::optional<Eigen::Matrix<double, 2, 3>> pixelJacobianOfPoint(const CameraModel& camera, const Eigen::Vector3d& p) {
    if (!(p.z() > 1e-9) || !p.allFinite()) return std::nullopt;
    return pointJacobian(camera, p);
}

std::optional<ProjectionWithJacobian> projectWithJacobian(const CameraModel& camera, const Eigen::Vector3d& p,
                                                          const Eigen::Vector2d& pixel) {
    if (!(p.z() > 1e-9) || !p.allFinite()) return std::nullopt;
    return withJacobian(camera, p, pixel);
}

}  // namespace commonlight::tracking

// Projection of camera-frame points through the lens model with the Jacobian that pose solvers
// need: d(pixel) / d(xi) for the left perturbation p_in_cam' = expSe3(xi) * p_in_cam, xi = (omega, v).
#pragma once

#include <optional>

#include <Eigen/Core>

#include "core/camera_model.h"

namespace commonlight::tracking {

using Matrix26d = Eigen::Matrix<double, 2, 6>;

struct ProjectionWithJacobian {
    Eigen::Vector2d pixel;  // distorted, OpenCV convention
    Matrix26d d_pixel_d_xi;
    Eigen::Matrix<double, 2, 3> d_pixel_d_p;  // d(pixel) / d(p_in_cam)
};

// nullopt when the point is behind the camera (z <= 1e-9 m) or beyond the lens model's valid
// radius. The distortion's 2x2 Jacobian is analytic.
std::optional<ProjectionWithJacobian> projectWithJacobian(const CameraModel& camera, const Eigen::Vector3d& p_in_cam);
// The same with `pixel` = camera.project(p_in_cam) already known (it must be, and not nullopt):
// the projection is not repeated.
std::optional<ProjectionWithJacobian> projectWithJacobian(const CameraModel& camera, const Eigen::Vector3d& p_in_cam,
                                                          const Eigen::Vector2d& pixel);
// d_pixel_d_p alone, bit for bit projectWithJacobian's, without the projection itself (so without
// its lens-model radius check): nullopt when the point is behind the camera or not finite. For a
// test on the image's scale that may make the projection unnecessary (tag_align.cpp).
std::optional<Eigen::Matrix<double, 2, 3>> pixelJacobianOfPoint(const CameraModel& camera, const Eigen::Vector3d& p_in_cam);

}  // namespace commonlight::tracking

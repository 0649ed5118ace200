// Jacobians of SE(3) in the (omega, v) tangent ordering of core/pose.h, for the left-perturbation
// convention of tracking/pose_types.h (T_true = expSe3(xi) * T_estimate).
#pragma once

#include <Eigen/Core>

#include "core/pose.h"
#include "tracking/pose_types.h"

namespace commonlight::tracking {

// Skew-symmetric matrix of w: hat(w) * x = w.cross(x).
Eigen::Matrix3d hat3(const Eigen::Vector3d& w);

// Adjoint of T: T * expSe3(xi) * T^-1 = expSe3(adjointSe3(T) * xi).
//     [ R      0 ]
//     [ t^ R   R ]
Matrix6d adjointSe3(const Rigid3d& pose);

// The small adjoint ad(xi) = d/dt Ad(exp(t xi)) at t = 0: [[w^, 0], [v^, w^]].
Matrix6d smallAdjointSe3(const Vector6d& xi);

// Left Jacobian of SE(3): expSe3(xi + d) ~= expSe3(leftJacobianSe3(xi) * d) * expSe3(xi) for small d.
// Evaluated by its power series sum_k ad(xi)^k / (k + 1)!, which converges for every xi; the
// series is summed until its terms fall below 1e-15 (about 30 terms at |omega| = pi).
Matrix6d leftJacobianSe3(const Vector6d& xi);

}  // namespace commonlight::tracking

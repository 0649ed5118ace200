// Poses with uncertainty, shared by the pose solvers, the temporal filter and model-edge
// refinement.
//
// Covariance convention: a 6x6 covariance is that of the tangent vector xi = (omega, v) (rotation
// vector in radians first, then translation in metres; core/pose.h's Vector6d) of the LEFT
// perturbation of cam_from_world:
//     cam_from_world_true = expSe3(xi) * cam_from_world_estimate
// so it is expressed in the camera frame (omega about the camera axes, v in camera metres).
#pragma once

#include <cstdint>

#include <Eigen/Core>

#include "core/pose.h"

namespace commonlight::tracking {

using Matrix6d = Eigen::Matrix<double, 6, 6>;

struct PoseMeasurement {
    std::int64_t timestamp_ns = 0;  // the frame's timestamp (CLOCK_MONOTONIC or the sequence's clock)
    Rigid3d cam_from_world;
    Matrix6d covariance = Matrix6d::Identity();  // see above
};

}  // namespace commonlight::tracking

// Camera rays of the simulated camera: the same CameraModel (pinhole + Brown-Conrady) as the rest
// of the system, so a 3D point renders at the pixel CameraModel::project gives.
//
// A pixel (u, v) covers the distorted-image square [u - 0.5, u + 0.5] x [v - 0.5, v + 0.5]
// (OpenCV's convention: the centre of the top-left pixel is (0, 0)). Each sample picks a position
// in that square and follows the ray CameraModel::unproject gives for it, so the pixel value is
// the box-filtered radiance of the distorted image and lens distortion is exact (no resampling).
// Positions beyond the fold of the lens model (where unproject has no answer) see nothing.
//
// Time: t is seconds since the start of the exposure of row 0 of the frame. Row v starts its
// exposure at v * row_time_s (rolling shutter; 0 for a global shutter) and integrates for
// exposure_s (motion blur; 0 for an instantaneous exposure).
#pragma once

#include <functional>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "core/camera_model.h"
#include "core/pose.h"

namespace commonlight::mocks::sim {

// world_from_cam at time t (see above). Called concurrently from the render threads: it must be
// thread-safe and should be cheap (an interpolation).
using CameraPoseFunction = std::function<Rigid3d(double t_s)>;

struct Ray {
    Eigen::Vector3d origin = Eigen::Vector3d::Zero();
    Eigen::Vector3d dir = Eigen::Vector3d::UnitZ();  // unit
};

class CameraRays {
public:
    // `pose_at` may be empty: the camera then stays at `world_from_cam`. Poses are evaluated
    // once per row when exposure_s is 0, once per sample otherwise.
    CameraRays(const CameraModel& camera, const Rigid3d& world_from_cam, CameraPoseFunction pose_at, double exposure_s,
               double row_time_s);

    // The time of a sample in row `row` for a uniform u in [0, 1).
    double sampleTime(int row, double u) const noexcept { return row * row_time_s_ + u * exposure_s_; }
    // The world ray through the distorted pixel position `pixel` at time t (a time from
    // sampleTime for that row); nullopt beyond the lens model's fold.
    std::optional<Ray> ray(const Eigen::Vector2d& pixel, int row, double t) const;
    // The ray through the centre of pixel (column, row) at the start of the row's exposure.
    std::optional<Ray> centreRay(int column, int row) const;

private:
    const CameraModel& camera_;
    CameraPoseFunction pose_at_;
    double exposure_s_;
    double row_time_s_;
    std::vector<Rigid3d> row_poses_;  // per row when the pose does not change within a row's exposure
};

}  // namespace commonlight::mocks::sim

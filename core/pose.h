// Rigid transforms named target_from_source (COLMAP's convention): `cam_from_world * p_in_world`
// gives p_in_cam, and composition reads left to right:
//     cam_from_tag = cam_from_world * world_from_tag
// Units are metres.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/result.h"

namespace commonlight {

struct Rigid3d {
    Eigen::Quaterniond rotation = Eigen::Quaterniond::Identity();  // unit quaternion
    Eigen::Vector3d translation = Eigen::Vector3d::Zero();

    Rigid3d() = default;
    Rigid3d(const Eigen::Quaterniond& r, const Eigen::Vector3d& t) : rotation(r.normalized()), translation(t) {}

    static Rigid3d identity() { return {}; }
    // R = Rz(yaw) * Ry(pitch) * Rx(roll), angles in degrees (the scene file's rpy_deg).
    static Rigid3d fromRpyDeg(const Eigen::Vector3d& t, const Eigen::Vector3d& rpy_deg);
    // From a 4x4 rigid matrix; fails when the rotation block is not orthonormal with det +1
    // (within `tolerance`) or the last row is not [0 0 0 1].
    static Result<Rigid3d> fromMatrix(const Eigen::Matrix4d& m, double tolerance = 1e-6);

    Eigen::Matrix3d rotationMatrix() const { return rotation.toRotationMatrix(); }
    Eigen::Matrix4d matrix() const;
    // Roll, pitch, yaw in degrees, inverse of fromRpyDeg.
    Eigen::Vector3d rpyDeg() const;

    Rigid3d inverse() const;
    Eigen::Vector3d operator*(const Eigen::Vector3d& p) const { return rotation * p + translation; }
    Rigid3d operator*(const Rigid3d& other) const {
        return {rotation * other.rotation, rotation * other.translation + translation};
    }

    // False when any component is NaN or infinite, or the quaternion is far from unit length.
    bool isValid() const;
};

// Angle of the relative rotation between two poses, in degrees.
double rotationErrorDeg(const Rigid3d& a, const Rigid3d& b);
// Distance between the two translations, in metres.
double translationError(const Rigid3d& a, const Rigid3d& b);
// Geodesic interpolation: slerp for rotation, linear for translation; t in [0, 1].
Rigid3d interpolate(const Rigid3d& a, const Rigid3d& b, double t);

// The pose of a camera (OpenCV axes: x right, y down, z forward) at `eye` looking at `target`,
// with image "up" towards `up` (world z by default). Fails when eye == target or the view
// direction is parallel to `up` (the roll is undefined there).
Result<Rigid3d> worldFromCamLookingAt(const Eigen::Vector3d& eye, const Eigen::Vector3d& target,
                                      const Eigen::Vector3d& up = Eigen::Vector3d::UnitZ());

// se(3) tangent vectors: (omega, v), rotation vector (radians) first, then translation part.
using Vector6d = Eigen::Matrix<double, 6, 1>;
// Exponential and logarithm maps of SE(3). Exact near the identity (Taylor terms below 1e-6 rad)
// and at rotations of pi (the rotation vector is taken from the quaternion with w >= 0).
Rigid3d expSe3(const Vector6d& xi);
Vector6d logSe3(const Rigid3d& pose);
// Interpolation on SE(3) along the screw motion from a to b: a * exp(t * log(a^-1 * b)).
// t outside [0, 1] extrapolates along the same screw.
Rigid3d interpolateSe3(const Rigid3d& a, const Rigid3d& b, double t);

}  // namespace commonlight

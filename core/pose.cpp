#include "core/pose.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <sstream>

namespace commonlight {

namespace {
constexpr double kDegToRad = std::numbers::pi / 180.0;
}

Rigid3d Rigid3d::fromRpyDeg(const Eigen::Vector3d& t, const Eigen::Vector3d& rpy_deg) {
    const Eigen::Vector3d rpy = rpy_deg * kDegToRad;
    const Eigen::Quaterniond q = Eigen::AngleAxisd(rpy.z(), Eigen::Vector3d::UnitZ()) *
                                 Eigen::AngleAxisd(rpy.y(), Eigen::Vector3d::UnitY()) *
                                 Eigen::AngleAxisd(rpy.x(), Eigen::Vector3d::UnitX());
    return {q, t};
}

Result<Rigid3d> Rigid3d::fromMatrix(const Eigen::Matrix4d& m, double tolerance) {
    if (!m.allFinite()) return fail(ErrorCode::kBadInput, "matrix has non-finite entries");
    const Eigen::RowVector4d last = m.row(3);
    if ((last - Eigen::RowVector4d(0, 0, 0, 1)).cwiseAbs().maxCoeff() > tolerance) {
        return fail(ErrorCode::kBadInput, "last row of a rigid transform must be [0, 0, 0, 1]");
    }
    const Eigen::Matrix3d r = m.topLeftCorner<3, 3>();
    const double orthogonality = (r.transpose() * r - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
    if (orthogonality > tolerance || std::abs(r.determinant() - 1.0) > tolerance) {
        std::ostringstream msg;
        msg << "rotation block is not a rotation (|R^T R - I| = " << orthogonality
            << ", det = " << r.determinant() << ")";
        return fail(ErrorCode::kBadInput, msg.str());
    }
    return Rigid3d(Eigen::Quaterniond(r), m.topRightCorner<3, 1>());
}

Eigen::Matrix4d Rigid3d::matrix() const {
    Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
    m.topLeftCorner<3, 3>() = rotationMatrix();
    m.topRightCorner<3, 1>() = translation;
    return m;
}

Eigen::Vector3d Rigid3d::rpyDeg() const {
    // R = Rz(yaw) Ry(pitch) Rx(roll): R20 = -sin(pitch), R21 = cos(pitch) sin(roll), ...
    const Eigen::Matrix3d r = rotationMatrix();
    const double pitch = std::asin(std::clamp(-r(2, 0), -1.0, 1.0));
    double roll = 0.0;
    double yaw = 0.0;
    // Hard case: gimbal lock at pitch = +-90 degrees, where roll and yaw share one axis.
    // Put all of the rotation about that axis into yaw.
    if (std::abs(r(2, 0)) < 1.0 - 1e-12) {
        roll = std::atan2(r(2, 1), r(2, 2));
        yaw = std::atan2(r(1, 0), r(0, 0));
    } else {
        yaw = std::atan2(-r(0, 1), r(1, 1));
    }
    return Eigen::Vector3d(roll, pitch, yaw) / kDegToRad;
}

Rigid3d Rigid3d::inverse() const {
    const Eigen::Quaterniond r_inv = rotation.conjugate();
    return {r_inv, -(r_inv * translation)};
}

bool Rigid3d::isValid() const {
    return rotation.coeffs().allFinite() && translation.allFinite() &&
           std::abs(rotation.squaredNorm() - 1.0) < 1e-6;
}

double rotationErrorDeg(const Rigid3d& a, const Rigid3d& b) {
    return a.rotation.angularDistance(b.rotation) / kDegToRad;
}

double translationError(const Rigid3d& a, const Rigid3d& b) { return (a.translation - b.translation).norm(); }

Rigid3d interpolate(const Rigid3d& a, const Rigid3d& b, double t) {
    return {a.rotation.slerp(t, b.rotation), (1.0 - t) * a.translation + t * b.translation};
}

}  // namespace commonlight

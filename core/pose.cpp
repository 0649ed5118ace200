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

Result<Rigid3d> worldFromCamLookingAt(const Eigen::Vector3d& eye, const Eigen::Vector3d& target,
                                      const Eigen::Vector3d& up) {
    const Eigen::Vector3d forward = target - eye;
    if (!forward.allFinite() || forward.norm() < 1e-12) {
        return fail(ErrorCode::kBadInput, "look-at: eye and target coincide");
    }
    const Eigen::Vector3d z = forward.normalized();
    const Eigen::Vector3d x_unnormalised = z.cross(up);
    // Hard case: looking straight along `up` leaves the roll undefined.
    if (x_unnormalised.norm() < 1e-9 * std::max(1.0, up.norm())) {
        return fail(ErrorCode::kBadInput, "look-at: the view direction is parallel to the up vector");
    }
    const Eigen::Vector3d x = x_unnormalised.normalized();
    Eigen::Matrix3d r;
    r.col(0) = x;
    r.col(1) = z.cross(x);  // image down
    r.col(2) = z;
    return Rigid3d(Eigen::Quaterniond(r), eye);
}

namespace {

Eigen::Matrix3d hat(const Eigen::Vector3d& w) {
    Eigen::Matrix3d m;
    m << 0, -w.z(), w.y(), w.z(), 0, -w.x(), -w.y(), w.x(), 0;
    return m;
}

// Rotation vector of a unit quaternion; the w >= 0 hemisphere gives angles in [0, pi].
Eigen::Vector3d rotationVector(Eigen::Quaterniond q) {
    if (q.w() < 0) q.coeffs() = -q.coeffs();
    const Eigen::Vector3d xyz = q.vec();
    const double s = xyz.norm();
    // Hard case: near the identity angle/s -> 2/w; atan2 keeps full precision there too.
    if (s < 1e-12) return 2.0 * xyz / q.w();
    const double angle = 2.0 * std::atan2(s, q.w());
    return xyz * (angle / s);
}

}  // namespace

Rigid3d expSe3(const Vector6d& xi) {
    const Eigen::Vector3d w = xi.head<3>();
    const Eigen::Vector3d v = xi.tail<3>();
    const double theta = w.norm();
    const Eigen::Matrix3d w_hat = hat(w);
    double a = 0.0;  // (1 - cos theta) / theta^2
    double b = 0.0;  // (theta - sin theta) / theta^3
    Eigen::Quaterniond q;
    // Hard case: small angles, where both coefficients are 0/0; use their Taylor series.
    if (theta < 1e-6) {
        const double t2 = theta * theta;
        a = 0.5 - t2 / 24.0;
        b = 1.0 / 6.0 - t2 / 120.0;
        q = Eigen::Quaterniond(1.0, 0.5 * w.x(), 0.5 * w.y(), 0.5 * w.z()).normalized();
    } else {
        a = (1.0 - std::cos(theta)) / (theta * theta);
        b = (theta - std::sin(theta)) / (theta * theta * theta);
        q = Eigen::Quaterniond(Eigen::AngleAxisd(theta, w / theta));
    }
    const Eigen::Matrix3d v_matrix = Eigen::Matrix3d::Identity() + a * w_hat + b * w_hat * w_hat;
    return {q, v_matrix * v};
}

Vector6d logSe3(const Rigid3d& pose) {
    const Eigen::Vector3d w = rotationVector(pose.rotation);
    const double theta = w.norm();
    const Eigen::Matrix3d w_hat = hat(w);
    // V^-1 = I - 1/2 w^ + c w^2 with c = (1 - theta sin(theta) / (2 (1 - cos theta))) / theta^2.
    double c = 0.0;
    if (theta < 1e-6) {
        c = 1.0 / 12.0 + theta * theta / 720.0;  // Taylor series of the 0/0 above
    } else {
        c = (1.0 - theta * std::sin(theta) / (2.0 * (1.0 - std::cos(theta)))) / (theta * theta);
    }
    const Eigen::Matrix3d v_inverse = Eigen::Matrix3d::Identity() - 0.5 * w_hat + c * w_hat * w_hat;
    Vector6d xi;
    xi.head<3>() = w;
    xi.tail<3>() = v_inverse * pose.translation;
    return xi;
}

Rigid3d interpolateSe3(const Rigid3d& a, const Rigid3d& b, double t) {
    return a * expSe3(t * logSe3(a.inverse() * b));
}

}  // namespace commonlight

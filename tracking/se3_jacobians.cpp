#include "tracking/se3_jacobians.h"

namespace commonlight::tracking {

Eigen::Matrix3d hat3(const Eigen::Vector3d& w) {
    Eigen::Matrix3d m;
    m << 0, -w.z(), w.y(), w.z(), 0, -w.x(), -w.y(), w.x(), 0;
    return m;
}

Matrix6d adjointSe3(const Rigid3d& pose) {
    const Eigen::Matrix3d r = pose.rotationMatrix();
    Matrix6d ad = Matrix6d::Zero();
    ad.topLeftCorner<3, 3>() = r;
    ad.bottomLeftCorner<3, 3>() = hat3(pose.translation) * r;
    ad.bottomRightCorner<3, 3>() = r;
    return ad;
}

Matrix6d smallAdjointSe3(const Vector6d& xi) {
    Matrix6d ad = Matrix6d::Zero();
    const Eigen::Matrix3d w_hat = hat3(xi.head<3>());
    ad.topLeftCorner<3, 3>() = w_hat;
    ad.bottomLeftCorner<3, 3>() = hat3(xi.tail<3>());
    ad.bottomRightCorner<3, 3>() = w_hat;
    return ad;
}

Matrix6d leftJacobianSe3(const Vector6d& xi) {
    // Hard case: large rotations (up to and beyond pi). The closed form divides by powers of the
    // angle; the series has no division and converges for every argument (its k-th term is
    // bounded by |ad|^k / (k + 1)!).
    const Matrix6d ad = smallAdjointSe3(xi);
    Matrix6d sum = Matrix6d::Identity();
    Matrix6d term = Matrix6d::Identity();
    for (int k = 1; k < 60; ++k) {
        term = term * ad / static_cast<double>(k + 1);
        sum += term;
        if (term.cwiseAbs().maxCoeff() < 1e-15 * (1.0 + sum.cwiseAbs().maxCoeff())) break;
    }
    return sum;
}

}  // namespace commonlight::tracking

#include "tracking/pose_filter.h"

#include <cassert>
#include <cmath>
#include <sstream>
#include <string>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>

#include "tracking/se3_jacobians.h"
#include "tracking/option_checks.h"

namespace commonlight::tracking {
namespace {

using Matrix12d = PoseFilter::Matrix12d;
using Matrix12x6d = Eigen::Matrix<double, 12, 6>;
using Vector12d = Eigen::Matrix<double, 12, 1>;


// Checks a measurement covariance and regularises it.
//
// Hard case: a near-singular covariance (variances of 1e-12, or a rank-deficient matrix from a
// solver that claims perfect knowledge of some direction). Fused as is, it would freeze the
// filter in that direction forever and make every later innovation an outlier. Its eigenvalues
// are raised to the floors (min_rotation_sigma^2, min_translation_sigma^2), computed in units
// scaled by the floors so that radians and metres compare.
Result<Matrix6d> regularisedCovariance(const Matrix6d& covariance, const PoseFilterOptions& options) {
    if (!covariance.allFinite()) return fail(ErrorCode::kBadInput, "pose covariance has non-finite entries");
    const double scale = covariance.cwiseAbs().maxCoeff();
    const double asymmetry = (covariance - covariance.transpose()).cwiseAbs().maxCoeff();
    if (asymmetry > 1e-9 * scale) {
        std::ostringstream msg;
        msg << "pose covariance is not symmetric (largest |C - C^T| = " << asymmetry << ")";
        return fail(ErrorCode::kBadInput, msg.str());
    }
    Vector6d floors;
    floors << Eigen::Vector3d::Constant(options.min_rotation_sigma),
        Eigen::Vector3d::Constant(options.min_translation_sigma);
    const Eigen::DiagonalMatrix<double, 6> to_scaled(floors.cwiseInverse());
    const Matrix6d symmetric = 0.5 * (covariance + covariance.transpose());
    const Matrix6d scaled = to_scaled * symmetric * to_scaled;
    const Eigen::SelfAdjointEigenSolver<Matrix6d> eigen(scaled);
    if (eigen.info() != Eigen::Success)
        return fail(ErrorCode::kBadInput, "pose covariance: eigen decomposition failed");
    const Vector6d values = eigen.eigenvalues();
    // Positive variances, and no direction with a negative variance beyond rounding: a matrix that
    // is singular only by rounding (a solver's rank-deficient output) is regularised, not refused.
    if (!(covariance.diagonal().minCoeff() > 0.0) || !(values.minCoeff() > -1e-12 * values.maxCoeff())) {
        std::ostringstream msg;
        msg << "pose covariance is not positive definite (eigenvalues in units of the noise floors: "
            << values.transpose() << ")";
        return fail(ErrorCode::kBadInput, msg.str());
    }
    const Vector6d clamped = values.cwiseMax(1.0);
    const Matrix6d regularised_scaled = eigen.eigenvectors() * clamped.asDiagonal() * eigen.eigenvectors().transpose();
    const Eigen::DiagonalMatrix<double, 6> from_scaled(floors);
    Matrix6d out = from_scaled * regularised_scaled * from_scaled;
    return Matrix6d(0.5 * (out + out.transpose()));
}

}  // namespace

Result<void> PoseFilterOptions::validate() const {
    CL_TRY_VOID(requirePositive(angular_accel_sigma, "PoseFilterOptions", "angular_accel_sigma"));
    CL_TRY_VOID(requirePositive(linear_accel_sigma, "PoseFilterOptions", "linear_accel_sigma"));
    CL_TRY_VOID(requirePositive(initial_angular_velocity_sigma, "PoseFilterOptions", "initial_angular_velocity_sigma"));
    CL_TRY_VOID(requirePositive(initial_linear_velocity_sigma, "PoseFilterOptions", "initial_linear_velocity_sigma"));
    CL_TRY_VOID(requirePositive(gate_chi2, "PoseFilterOptions", "gate_chi2"));
    CL_TRY_VOID(requirePositive(min_rotation_sigma, "PoseFilterOptions", "min_rotation_sigma"));
    CL_TRY_VOID(requirePositive(min_translation_sigma, "PoseFilterOptions", "min_translation_sigma"));
    if (max_consecutive_rejections < 0) {
        return fail(ErrorCode::kUsage, "PoseFilterOptions.max_consecutive_rejections must be >= 0, got " +
                                           std::to_string(max_consecutive_rejections));
    }
    if (max_gap_ns <= 0) {
        return fail(ErrorCode::kUsage, "PoseFilterOptions.max_gap_ns must be > 0, got " + std::to_string(max_gap_ns));
    }
    return {};
}

PoseFilter::PoseFilter(PoseFilterOptions options) : options_(options) {
    assert(options_.validate().has_value() && "invalid PoseFilterOptions");
}

void PoseFilter::reset() noexcept {
    initialized_ = false;
    state_ns_ = 0;
    last_input_ns_ = 0;
    pose_ = Rigid3d();
    velocity_ = Vector6d::Zero();
    covariance_ = Matrix12d::Identity();
    rejections_ = 0;
    last_mahalanobis2_ = 0.0;
}

void PoseFilter::initialize(const PoseMeasurement& measurement, const Matrix6d& covariance) {
    initialized_ = true;
    state_ns_ = measurement.timestamp_ns;
    last_input_ns_ = measurement.timestamp_ns;
    pose_ = measurement.cam_from_world;
    velocity_ = Vector6d::Zero();
    covariance_ = Matrix12d::Zero();
    covariance_.topLeftCorner<6, 6>() = covariance;
    const double w0 = options_.initial_angular_velocity_sigma;
    const double v0 = options_.initial_linear_velocity_sigma;
    covariance_.diagonal().segment<3>(6).setConstant(w0 * w0);
    covariance_.diagonal().segment<3>(9).setConstant(v0 * v0);
    rejections_ = 0;
    last_mahalanobis2_ = 0.0;
}

void PoseFilter::propagate(double dt, Rigid3d& pose, Matrix12d& covariance) const {
    // Hard case: dt = 0 (two measurements of one frame) leaves the state as it is.
    if (dt == 0.0) return;
    const Vector6d step = dt * velocity_;
    const Rigid3d motion = expSe3(step);
    pose = motion * pose;
    // Error propagation: T_true' = exp(dt (nu + dnu)) exp(dxi) T
    //                           ~= exp(J_l(dt nu) dt dnu) exp(Ad(exp(dt nu)) dxi) T'
    Matrix12d f = Matrix12d::Identity();
    f.topLeftCorner<6, 6>() = adjointSe3(motion);
    f.topRightCorner<6, 6>() = dt * leftJacobianSe3(step);
    // White-noise acceleration, integrated over |dt| (for every axis: [dt^3/3, dt^2/2; dt^2/2, dt] q^2).
    const double a = std::abs(dt);
    Vector6d q2;
    q2 << Eigen::Vector3d::Constant(options_.angular_accel_sigma * options_.angular_accel_sigma),
        Eigen::Vector3d::Constant(options_.linear_accel_sigma * options_.linear_accel_sigma);
    Matrix12d q = Matrix12d::Zero();
    q.topLeftCorner<6, 6>().diagonal() = q2 * (a * a * a / 3.0);
    q.topRightCorner<6, 6>().diagonal() = q2 * (dt * a / 2.0);
    q.bottomLeftCorner<6, 6>().diagonal() = q2 * (dt * a / 2.0);
    q.bottomRightCorner<6, 6>().diagonal() = q2 * a;
    covariance = f * covariance * f.transpose() + q;
    covariance = (0.5 * (covariance + covariance.transpose())).eval();  // eval: the transpose aliases it
}

Result<PoseFilter::UpdateResult> PoseFilter::update(const PoseMeasurement& measurement) {
    // Step 1: check the input; on any error the state is left as it was.
    if (!measurement.cam_from_world.isValid()) {
        return fail(ErrorCode::kBadInput, "pose measurement at " + std::to_string(measurement.timestamp_ns) +
                                              " ns: the pose is not finite or its quaternion is not unit");
    }
    auto covariance = regularisedCovariance(measurement.covariance, options_);
    if (!covariance) {
        return fail(std::move(covariance.error())
                        .prepend("pose measurement at " + std::to_string(measurement.timestamp_ns) + " ns"));
    }
    if (initialized_ && measurement.timestamp_ns < last_input_ns_) {
        return fail(ErrorCode::kBadInput, "pose measurement at " + std::to_string(measurement.timestamp_ns) +
                                              " ns is earlier than the last update at " +
                                              std::to_string(last_input_ns_) + " ns");
    }

    // Step 2: (re-)initialise on the first measurement or after a long gap.
    if (!initialized_ || measurement.timestamp_ns - state_ns_ > options_.max_gap_ns) {
        initialize(measurement, *covariance);
        return UpdateResult::kInitialized;
    }

    // Step 3: predict to the measurement's time.
    const double dt = 1e-9 * static_cast<double>(measurement.timestamp_ns - state_ns_);
    Rigid3d pose = pose_;
    Matrix12d p = covariance_;
    propagate(dt, pose, p);

    // Step 4: innovation y = log(z * T_pred^-1). With z = exp(n) exp(dxi) T_pred,
    // y ~= dxi + J_l(y)^-1 n: the measurement noise seen in innovation coordinates is
    // J_l(y)^-1 R J_l(y)^-T. Hard case: rotations near pi between prediction and measurement
    // (fast spins, low rates), where that factor differs from identity; logSe3 is exact there.
    const Vector6d y = logSe3(measurement.cam_from_world * pose.inverse());
    const Matrix6d j_inverse = leftJacobianSe3(y).inverse();
    const Matrix6d r = j_inverse * *covariance * j_inverse.transpose();
    Matrix6d s = p.topLeftCorner<6, 6>() + r;
    s = (0.5 * (s + s.transpose())).eval();  // eval: the transpose aliases s
    const Eigen::LLT<Matrix6d> s_llt(s);
    if (s_llt.info() != Eigen::Success) {
        return fail(ErrorCode::kInternal, "pose filter: innovation covariance is not positive definite");
    }
    last_mahalanobis2_ = y.dot(s_llt.solve(y));
    last_input_ns_ = measurement.timestamp_ns;

    // Step 5: gate. An outlier leaves the state alone; a run of them means the tracker jumped.
    if (!(last_mahalanobis2_ <= options_.gate_chi2)) {
        ++rejections_;
        if (rejections_ > options_.max_consecutive_rejections) {
            initialize(measurement, *covariance);
            return UpdateResult::kInitialized;
        }
        return UpdateResult::kRejected;
    }

    // Step 6: Kalman update with H = [I 0], Joseph form for a covariance that stays symmetric
    // positive definite.
    const Matrix12x6d k = s_llt.solve(p.leftCols<6>().transpose()).transpose();
    const Vector12d dx = k * y;
    Matrix12d i_kh = Matrix12d::Identity();
    i_kh.leftCols<6>() -= k;
    p = i_kh * p * i_kh.transpose() + k * r * k.transpose();
    pose_ = expSe3(dx.head<6>()) * pose;
    velocity_ += dx.tail<6>();
    covariance_ = 0.5 * (p + p.transpose());
    state_ns_ = measurement.timestamp_ns;
    rejections_ = 0;
    return UpdateResult::kAccepted;
}

std::optional<PoseMeasurement> PoseFilter::predict(std::int64_t timestamp_ns) const {
    if (!initialized_) return std::nullopt;
    Rigid3d pose = pose_;
    Matrix12d p = covariance_;
    propagate(1e-9 * static_cast<double>(timestamp_ns - state_ns_), pose, p);
    PoseMeasurement out;
    out.timestamp_ns = timestamp_ns;
    out.cam_from_world = pose;
    out.covariance = p.topLeftCorner<6, 6>();
    return out;
}

}  // namespace commonlight::tracking

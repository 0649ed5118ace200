// Temporal filter of the camera pose: a constant-velocity Kalman filter on SE(3) (an error-state
// EKF). docs/pose-filter.md has the model and the parameters.
//
// State: the pose T = cam_from_world and the camera's velocity nu, a twist (omega, v) in the
// left-perturbation convention of tracking/pose_types.h, so that the constant-velocity motion is
//     T(t + dt) = expSe3(dt * nu) * T(t)
// (a constant twist in the camera's own frame: a screw motion). The 12-dim error state is
// (dxi, dnu) with T_true = expSe3(dxi) * T and nu_true = nu + dnu; its covariance P is 12 x 12,
// and the pose block P[0:6, 0:6] follows the convention of pose_types.h.
//
// Measurements are poses with their 6x6 covariance (same convention). A measurement whose
// Mahalanobis distance to the prediction exceeds the gate is rejected as an outlier; after
// `max_consecutive_rejections` rejections in a row the next one beyond the gate re-initialises the
// filter (the tracker jumped, or the filter lost it). Not thread-safe: one owner (the tracking
// stage) calls update() and predict().
#pragma once

#include <cstdint>
#include <optional>

#include <Eigen/Core>

#include "core/pose.h"
#include "core/result.h"
#include "tracking/pose_types.h"

namespace commonlight::tracking {

struct PoseFilterOptions {
    // White-noise acceleration of the constant-velocity model (its spectral density is sigma^2: the
    // velocity drifts by sigma * sqrt(t) in t seconds). Larger follows changes of motion sooner,
    // smaller smooths more. The defaults suit a hand-held camera moved slowly; at 30 Hz they
    // lower the noise of 0.2 degree / 2 mm measurements by about 10 %. A camera on a tripod or a
    // robot arm can use a tenth of them (about 30 % less noise).
    double angular_accel_sigma = 1.0;  // rad/s^2
    double linear_accel_sigma = 0.3;   // m/s^2
    // Velocity uncertainty at (re-)initialisation: how fast the camera may be moving when first seen.
    double initial_angular_velocity_sigma = 4.0;  // rad/s
    double initial_linear_velocity_sigma = 2.0;   // m/s
    double gate_chi2 = 22.46;                     // Mahalanobis gate (6 dof, 99.9%); measurements beyond are rejected
    int max_consecutive_rejections = 3;           // rejections tolerated in a row; the next one re-initialises
    std::int64_t max_gap_ns = 500'000'000;        // a longer gap since the last accepted update re-initialises
    // Floors of the measurement noise: a covariance claiming more precision than this is
    // regularised up to it (a near-singular covariance would freeze the filter).
    double min_rotation_sigma = 1e-5;     // rad
    double min_translation_sigma = 1e-5;  // m

    // Finite positive values, gate > 0, rejections >= 0, gap > 0; names the bad field.
    Result<void> validate() const;
};

class PoseFilter {
public:
    // `options` must be valid (asserted); check them with validate() first when they come from a user.
    explicit PoseFilter(PoseFilterOptions options = {});

    enum class UpdateResult {
        kInitialized,  // first measurement, or re-initialised (gap, reset, repeated rejections)
        kAccepted,     // fused
        kRejected,     // beyond the gate: an outlier, the state is unchanged
    };

    // Fuses one measurement. Errors (kBadInput) on a non-finite pose or covariance, a covariance
    // that is not symmetric positive definite, or a timestamp earlier than the last update's; the
    // state is unchanged then. Two measurements with the same timestamp are both fused (two
    // independent looks at the same pose).
    Result<UpdateResult> update(const PoseMeasurement& measurement);

    // Pose and covariance (pose_types.h convention) at any timestamp, extrapolated along the
    // constant-velocity model from the last accepted update (backwards too); nullopt before the
    // first update.
    std::optional<PoseMeasurement> predict(std::int64_t timestamp_ns) const;

    bool initialized() const noexcept { return initialized_; }
    void reset() noexcept;

    // The velocity twist (omega rad/s, v m/s) in the convention above; zero before initialisation.
    const Vector6d& velocity() const noexcept { return velocity_; }
    // Consecutive rejections so far.
    int consecutiveRejections() const noexcept { return rejections_; }
    // Squared Mahalanobis distance of the last measurement to the prediction (0 after initialising).
    double lastMahalanobis2() const noexcept { return last_mahalanobis2_; }
    const PoseFilterOptions& options() const noexcept { return options_; }

    using Matrix12d = Eigen::Matrix<double, 12, 12>;

private:
    void initialize(const PoseMeasurement& measurement, const Matrix6d& covariance);
    // State propagated by dt seconds (negative extrapolates backwards).
    void propagate(double dt, Rigid3d& pose, Matrix12d& covariance) const;

    PoseFilterOptions options_;
    bool initialized_ = false;
    std::int64_t state_ns_ = 0;       // time of the state (last accepted update)
    std::int64_t last_input_ns_ = 0;  // time of the last measurement (accepted or not)
    Rigid3d pose_;
    Vector6d velocity_ = Vector6d::Zero();
    Matrix12d covariance_ = Matrix12d::Identity();
    int rejections_ = 0;
    double last_mahalanobis2_ = 0.0;
};

}  // namespace commonlight::tracking

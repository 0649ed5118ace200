#include "tracking/tag_pose.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <string>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>
#include <unsupported/Eigen/LevenbergMarquardt>

#include "tracking/option_checks.h"
#include "tracking/projection.h"
#include "tracking/se3_jacobians.h"

namespace commonlight::tracking {
namespace {

std::string px(const Eigen::Vector2d& p) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "(%.2f, %.2f)", p.x(), p.y());
    return buf;
}

double cross2(const Eigen::Vector2d& a, const Eigen::Vector2d& b) { return a.x() * b.y() - a.y() * b.x(); }

Rigid3d fromRvecTvec(const cv::Mat& rvec, const cv::Mat& tvec) {
    cv::Mat rmat;
    cv::Rodrigues(rvec, rmat);
    Eigen::Matrix3d r;
    cv::cv2eigen(rmat, r);
    Eigen::Vector3d t;
    cv::cv2eigen(tvec, t);
    return {Eigen::Quaterniond(r), t};
}

void toRvecTvec(const Rigid3d& pose, cv::Mat& rvec, cv::Mat& tvec) {
    cv::Mat rmat;
    cv::eigen2cv(Eigen::Matrix3d(pose.rotationMatrix()), rmat);
    cv::Rodrigues(rmat, rvec);
    cv::eigen2cv(Eigen::Vector3d(pose.translation), tvec);
}

bool finiteMat(const cv::Mat& m) { return cv::checkRange(m, true, nullptr, -1e12, 1e12); }

// The four corners' reprojection error in the distorted image as a function of the pose's
// (rvec, tvec), the parameters cv::solvePnPRefineLM refines, for Eigen's Levenberg-Marquardt
// (MINPACK's lmder): residuals through our lens model, the Jacobian analytic (projectWithJacobian
// for the camera-frame point, the left Jacobian of SO(3) for the rotation vector). A corner that
// leaves the lens model's valid radius stops the solver (the caller then runs OpenCV's).
// Dynamic sizes: the module's QR solve does not compile for a fixed-size Jacobian (Eigen 3.4).
struct CornerReprojection : Eigen::DenseFunctor<double> {
    CornerReprojection() : Eigen::DenseFunctor<double>(6, 8) {}
    const std::array<Eigen::Vector3d, 4>* object = nullptr;
    const std::array<Eigen::Vector2d, 4>* corners = nullptr;
    const CameraModel* camera = nullptr;

    static Eigen::Matrix3d rotation(const Eigen::VectorXd& x) {
        const Eigen::Vector3d r = x.head<3>();
        const double angle = r.norm();
        return angle > 0 ? Eigen::AngleAxisd(angle, r / angle).toRotationMatrix() : Eigen::Matrix3d::Identity();
    }
    int operator()(const Eigen::VectorXd& x, Eigen::VectorXd& residuals) const {
        const Eigen::Matrix3d r = rotation(x);
        for (std::size_t i = 0; i < 4; ++i) {
            const auto p = camera->project(r * (*object)[i] + x.tail<3>());
            if (!p) return -1;
            residuals.segment<2>(2 * static_cast<Eigen::Index>(i)) = *p - (*corners)[i];
        }
        return 0;
    }
    int df(const Eigen::VectorXd& x, JacobianType& jacobian) const {
        const Eigen::Vector3d rv = x.head<3>();
        const Eigen::Matrix3d r = rotation(x);
        // R(r + d) ~= exp(J_l(r) d) R(r): J_l = I + (1 - cos a)/a^2 [r]x + (a - sin a)/a^3 [r]x^2.
        const double a = rv.norm();
        const double c1 = a > 1e-6 ? (1.0 - std::cos(a)) / (a * a) : 0.5;
        const double c2 = a > 1e-6 ? (a - std::sin(a)) / (a * a * a) : 1.0 / 6.0;
        const Eigen::Matrix3d k = hat3(rv);
        const Eigen::Matrix3d left = Eigen::Matrix3d::Identity() + c1 * k + c2 * k * k;
        for (std::size_t i = 0; i < 4; ++i) {
            const Eigen::Vector3d rotated = r * (*object)[i];
            const auto proj = projectWithJacobian(*camera, rotated + x.tail<3>());
            if (!proj) return -1;
            const auto row = 2 * static_cast<Eigen::Index>(i);
            jacobian.block<2, 3>(row, 0) = proj->d_pixel_d_p * (-hat3(rotated) * left);
            jacobian.block<2, 3>(row, 3) = proj->d_pixel_d_p;
        }
        return 0;
    }
};

// Levenberg-Marquardt on the corners from `start` by Eigen's module (cv::solvePnPRefineLM costs
// about 0.5 M instructions a call through cv::Mat: docs/tracking.md, "Speed (issue 13)").
// nullopt when a corner leaves the lens model's valid radius or the result is not finite.
std::optional<Rigid3d> refineCornersLm(const std::array<Eigen::Vector3d, 4>& object,
                                       const std::array<Eigen::Vector2d, 4>& corners, const CameraModel& camera,
                                       const Rigid3d& start) {
    CornerReprojection f;
    f.object = &object;
    f.corners = &corners;
    f.camera = &camera;
    const Eigen::AngleAxisd aa(start.rotation.normalized());
    Eigen::VectorXd x(6);
    x << aa.angle() * aa.axis(), start.translation;
    Eigen::LevenbergMarquardt<CornerReprojection> lm(f);
    // As the OpenCV call: stops when a step changes the parameters by under 1e-9 relative (1 nm at
    // 1 m), after at most 30 accepted steps; no stop on the cost's relative reduction.
    lm.setXtol(1e-9);
    lm.setFtol(0.0);
    lm.setMaxfev(400);
    auto status = lm.minimizeInit(x);
    if (status == Eigen::LevenbergMarquardtSpace::UserAsked) return std::nullopt;
    do {
        status = lm.minimizeOneStep(x);
    } while (status == Eigen::LevenbergMarquardtSpace::Running && lm.iterations() <= 30);
    if (status == Eigen::LevenbergMarquardtSpace::UserAsked || !x.allFinite()) return std::nullopt;
    const Eigen::Vector3d rv = x.head<3>();
    const double angle = rv.norm();
    const Eigen::Quaterniond q = angle > 0 ? Eigen::Quaterniond(Eigen::AngleAxisd(angle, rv / angle))
                                           : Eigen::Quaterniond::Identity();
    return Rigid3d(q, x.tail<3>());
}

// Quad size in pixels (longest side).
double quadScale(const std::array<Eigen::Vector2d, 4>& c) {
    double scale = 0.0;
    for (int i = 0; i < 4; ++i) scale = std::max(scale, (c[i] - c[(i + 1) % 4]).norm());
    return scale;
}

// Reprojection RMS of the object points through the ideal pinhole (no distortion).
double idealRms(const std::vector<cv::Point3d>& object, const std::vector<cv::Point2d>& ideal, const CameraModel& camera,
                const Rigid3d& pose) {
    double sum = 0.0;
    for (std::size_t k = 0; k < object.size(); ++k) {
        const Eigen::Vector3d p = pose * Eigen::Vector3d(object[k].x, object[k].y, object[k].z);
        if (!(p.z() > 0)) return std::numeric_limits<double>::infinity();
        const double u = camera.fx * p.x() / p.z() + camera.cx - ideal[k].x;
        const double v = camera.fy * p.y() / p.z() + camera.cy - ideal[k].y;
        sum += u * u + v * v;
    }
    return std::sqrt(sum / static_cast<double>(object.size()));
}

}  // namespace

const char* poseChoiceName(PoseChoice choice) noexcept {
    switch (choice) {
        case PoseChoice::kOnlyCandidate: return "only_candidate";
        case PoseChoice::kResidual: return "residual";
        case PoseChoice::kPrediction: return "prediction";
        case PoseChoice::kPattern: return "pattern";
        case PoseChoice::kScene: return "scene";
        case PoseChoice::kEdges: return "edges";
    }
    return "?";
}

Result<void> TagPoseOptions::validate() const {
    CL_TRY_VOID(requirePositive(corner_sigma_px, "TagPoseOptions", "corner_sigma_px"));
    if (!(prediction_gate_deg > 0) || !(prediction_gate_deg <= 180)) {
        return fail(ErrorCode::kUsage, "prediction_gate_deg must be in (0, 180]");
    }
    for (const double r : {ambiguous_corner_ratio, ambiguous_pattern_ratio}) {
        if (!(r >= 0) || !(r <= 1)) {
            return fail(ErrorCode::kUsage, "TagPoseOptions: ambiguous_corner_ratio and ambiguous_pattern_ratio must be in [0, 1]");
        }
    }
    CL_TRY_VOID(requirePositive(ambiguous_rotation_sigma_deg, "TagPoseOptions", "ambiguous_rotation_sigma_deg"));
    return {};
}

double rotationSigmaDeg(const Matrix6d& covariance) {
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen(covariance.topLeftCorner<3, 3>());
    return std::sqrt(std::max(0.0, eigen.eigenvalues().maxCoeff())) * 180.0 / M_PI;
}

Rigid3d planarMirror(const Rigid3d& cam_from_tag) {
    const Eigen::Vector3d v = cam_from_tag.translation.normalized();
    const Eigen::Vector3d n = cam_from_tag.rotation * Eigen::Vector3d::UnitZ();
    const Eigen::Vector3d mirrored = 2.0 * n.dot(v) * v - n;
    // Hard case: a tag seen exactly along its normal is its own mirror (FromTwoVectors of equal
    // vectors is the identity).
    const Eigen::Quaterniond turn = Eigen::Quaterniond::FromTwoVectors(n, mirrored);
    return Rigid3d(turn * cam_from_tag.rotation, cam_from_tag.translation);
}

Result<void> checkQuadCorners(const std::array<Eigen::Vector2d, 4>& c, double min_separation_px) {
    for (int i = 0; i < 4; ++i) {
        if (!c[i].allFinite()) return fail(ErrorCode::kBadInput, "corner " + std::to_string(i) + " is not finite");
    }
    for (int i = 0; i < 4; ++i) {
        for (int j = i + 1; j < 4; ++j) {
            if ((c[i] - c[j]).norm() < min_separation_px) {
                return fail(ErrorCode::kBadInput, "corners " + std::to_string(i) + " and " + std::to_string(j) +
                                                      " coincide at " + px(c[i]));
            }
        }
    }
    // Convex and not self-crossing: the turn at every corner has the same sign, and no three
    // corners are (nearly) collinear: each turn's triangle has an area above a tiny fraction of
    // the quad's scale squared.
    const double scale = quadScale(c);
    int sign = 0;
    for (int i = 0; i < 4; ++i) {
        const Eigen::Vector2d& a = c[i];
        const Eigen::Vector2d& b = c[(i + 1) % 4];
        const Eigen::Vector2d& d = c[(i + 2) % 4];
        const double turn = cross2(b - a, d - b);
        if (std::abs(turn) < 1e-3 * scale * scale) {
            return fail(ErrorCode::kBadInput, "corners " + std::to_string(i) + ", " + std::to_string((i + 1) % 4) +
                                                  " and " + std::to_string((i + 2) % 4) + " are collinear");
        }
        const int s = turn > 0 ? 1 : -1;
        if (sign != 0 && s != sign) return fail(ErrorCode::kBadInput, "the corners do not form a convex quad");
        sign = s;
    }
    return {};
}

double tagReprojectionRms(const std::array<Eigen::Vector2d, 4>& corners, double size, const CameraModel& camera,
                          const Rigid3d& cam_from_tag) {
    double sum = 0.0;
    for (int i = 0; i < 4; ++i) {
        const auto p = camera.project(cam_from_tag * tagCornerInTag(i, size));
        if (!p) return std::numeric_limits<double>::infinity();
        sum += (*p - corners[i]).squaredNorm();
    }
    return std::sqrt(sum / 4.0);
}

Result<TagPose> solveTagPose(int id, const std::array<Eigen::Vector2d, 4>& corners, double size,
                             const CameraModel& camera, const std::optional<Rigid3d>& predicted,
                             const TagPoseOptions& options) {
    const std::string what = "tag " + std::to_string(id);
    if (!(size > 0) || !std::isfinite(size)) {
        return fail(ErrorCode::kBadInput, what + ": tag size must be a positive number of metres");
    }
    if (auto ok = checkQuadCorners(corners); !ok) return fail(std::move(ok).error().prepend(what));
    if (predicted && !predicted->isValid()) return fail(ErrorCode::kBadInput, what + ": the predicted pose is not finite");

    // Step 1: undistort the corners (accurately: our damped Newton, not OpenCV's fixed 5 steps).
    // IPPE_SQUARE's object points are (-s/2, s/2), (s/2, s/2), (s/2, -s/2), (-s/2, -s/2): our
    // corners 3, 2, 1, 0 (tag frame of docs/formats-scene.md; the same axes).
    constexpr int kIppeOrder[4] = {3, 2, 1, 0};
    std::vector<cv::Point3d> object(4);
    std::vector<cv::Point2d> ideal(4), distorted(4);
    for (int k = 0; k < 4; ++k) {
        const int i = kIppeOrder[k];
        const Eigen::Vector3d o = tagCornerInTag(i, size);
        object[k] = {o.x(), o.y(), o.z()};
        const auto u = camera.undistortPixel(corners[i]);
        if (!u) {
            return fail(ErrorCode::kBadInput, what + ": corner " + std::to_string(i) + " at " + px(corners[i]) +
                                                  " lies beyond the lens model's valid radius");
        }
        ideal[k] = {u->x(), u->y()};
        distorted[k] = {corners[i].x(), corners[i].y()};
    }
    cv::Mat k_mat;
    cv::eigen2cv(camera.K(), k_mat);
    const cv::Mat dist = (cv::Mat_<double>(1, 5) << camera.distortion.k1, camera.distortion.k2, camera.distortion.p1,
                          camera.distortion.p2, camera.distortion.k3);

    // Step 3: refine each with Levenberg-Marquardt on the reprojection error in the distorted image.
    std::vector<TagPoseCandidate> candidates;
    std::array<Eigen::Vector3d, 4> object_in_tag;
    for (int i = 0; i < 4; ++i) object_in_tag[static_cast<std::size_t>(i)] = tagCornerInTag(i, size);
    const auto refineStart = [&](const Rigid3d& start) {
        Rigid3d refined = start;
        if (const auto lm = refineCornersLm(object_in_tag, corners, camera, start); lm && lm->isValid()) {
            refined = *lm;
        } else {
            try {
                cv::Mat rvec, tvec;
                toRvecTvec(start, rvec, tvec);
                // Stops when a step changes the parameters by under 1e-9 relative (1 nm at 1 m):
                // 1e-12 bought nothing but iterations (wide's solve step 0.64 -> 0.54 ms per frame).
                cv::solvePnPRefineLM(object, distorted, k_mat, dist, rvec, tvec,
                                     cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 30, 1e-9));
                if (!finiteMat(rvec) || !finiteMat(tvec)) return;  // never an unrefined pose as a result
                refined = fromRvecTvec(rvec, tvec);
            } catch (const cv::Exception&) {
                return;
            }
        }
        // LM stops where it cannot improve; a start that is already the minimum (exact corners)
        // may then reproject marginally better than LM's last step: keep the better of the two.
        const double rms_start = tagReprojectionRms(corners, size, camera, start);
        const double rms_refined = tagReprojectionRms(corners, size, camera, refined);
        TagPoseCandidate c{rms_refined <= rms_start ? refined : start, std::min(rms_refined, rms_start)};
        if (!c.cam_from_tag.isValid() || !std::isfinite(c.rms_px) || c.cam_from_tag.translation.z() <= 0) return;
        // Both starts can converge to the same minimum: keep one.
        const bool duplicate = std::any_of(candidates.begin(), candidates.end(), [&](const TagPoseCandidate& o) {
            return rotationErrorDeg(o.cam_from_tag, c.cam_from_tag) < 1e-4 &&
                   translationError(o.cam_from_tag, c.cam_from_tag) < 1e-7 * (1.0 + c.cam_from_tag.translation.norm());
        });
        if (!duplicate) candidates.push_back(c);
    };
    // Corners from the prediction itself (start_at_prediction): LM from the prediction, without
    // IPPE, where the refined pose stays near the prediction. A prediction nearly head-on (its
    // mirror within twice the gate) is refined alone as well, since corners made from it cannot
    // tell its two sides apart and it chooses (docs/tracking.md, "Speed (issue 13)", change 21),
    // unless its mirror is within half the gate (the two sides one flat valley, where LM from the
    // prediction stops elsewhere than from IPPE's starts: up to 0.04 degrees on `tiny`) or the
    // refined pose's own mirror (the other side, approximately) is less than twice as far from
    // the prediction as the refined pose (LM crossed over: the prediction would choose the mirror).
    bool from_prediction = false;
    const double gate = options.prediction_gate_deg;
    const double mirror_gap = options.start_at_prediction && predicted && predicted->translation.z() > 0
                                  ? rotationErrorDeg(planarMirror(*predicted), *predicted)
                                  : 0.0;
    if (mirror_gap > 0.5 * gate) {
        refineStart(*predicted);
        bool near = candidates.size() == 1;
        const double d_refined = near ? rotationErrorDeg(candidates[0].cam_from_tag, *predicted) : 0.0;
        near = near && d_refined < 0.5 * gate;
        const Rigid3d mirror = near ? planarMirror(candidates[0].cam_from_tag) : Rigid3d();
        if (near && (mirror_gap > 2.0 * gate || 2.0 * d_refined < rotationErrorDeg(mirror, *predicted))) {
            from_prediction = true;
            const double rms = tagReprojectionRms(corners, size, camera, mirror);
            if (mirror.isValid() && std::isfinite(rms) && mirror.translation.z() > 0) {
                candidates.push_back({mirror, rms});
            }
        } else {
            candidates.clear();
        }
    }
    bool refined = true;
    if (!from_prediction) {
        // Step 2: both planar candidates from IPPE.
        std::vector<Rigid3d> initial;
        try {
            std::vector<cv::Mat> rvecs, tvecs;
            cv::solvePnPGeneric(object, ideal, k_mat, cv::noArray(), rvecs, tvecs, false, cv::SOLVEPNP_IPPE_SQUARE);
            for (std::size_t s = 0; s < rvecs.size(); ++s) {
                // OpenCV 4.6's IPPE can return NaN (or garbage) on exactly fronto-parallel, noise-free
                // corners: drop what is not finite or puts the tag behind the camera.
                if (!finiteMat(rvecs[s]) || !finiteMat(tvecs[s])) continue;
                const Rigid3d pose = fromRvecTvec(rvecs[s], tvecs[s]);
                if (pose.isValid() && pose.translation.z() > 0) initial.push_back(pose);
            }
            // Exactly fronto-parallel, noise-free corners can also give finite garbage (metres off):
            // judge the candidates by their reprojection of the ideal corners.
            double best_rms = std::numeric_limits<double>::infinity();
            for (const Rigid3d& pose : initial) best_rms = std::min(best_rms, idealRms(object, ideal, camera, pose));
            if (!(best_rms < 1.0 + 0.05 * quadScale(corners))) {
                initial.clear();
                // Fallback: SQPnP (globally optimal, no planar special case) on the same points.
                cv::Mat rvec, tvec;
                if (cv::solvePnP(object, ideal, k_mat, cv::noArray(), rvec, tvec, false, cv::SOLVEPNP_SQPNP) &&
                    finiteMat(rvec) && finiteMat(tvec)) {
                    const Rigid3d pose = fromRvecTvec(rvec, tvec);
                    if (pose.isValid() && pose.translation.z() > 0) initial.push_back(pose);
                }
            }
        } catch (const cv::Exception& e) {
            return fail(ErrorCode::kInternal, what + ": OpenCV's pose solver failed: " + e.what());
        }
        if (initial.empty()) return fail(ErrorCode::kBadInput, what + ": no pose explains the corners");

        // With a prediction that clearly tells the two IPPE starts apart, the one far from it is not
        // refined: the prediction chooses the other whatever LM does to it (LM moves a start by far
        // less than the gap), and it stays as the alternative with its corner residual. This halves
        // the Levenberg-Marquardt work of a tracked tag (docs/tracking.md, "Speed (issue 13)").
        std::optional<Rigid3d> unrefined_far;
        if (predicted && predicted->translation.z() > 0 && initial.size() == 2) {
            const double d[2] = {rotationErrorDeg(initial[0], *predicted), rotationErrorDeg(initial[1], *predicted)};
            const int far = d[1] > d[0] ? 1 : 0;
            if (d[1 - far] < 0.5 * options.prediction_gate_deg && d[far] > 2.0 * options.prediction_gate_deg) {
                unrefined_far = initial[static_cast<std::size_t>(far)];
                initial.erase(initial.begin() + far);
            }
        }
        // Kept unrefined only when the near start stays near the prediction and the far one would
        // survive the plausibility cut below as it is (refined, its residual is smaller still).
        const auto shortcutHolds = [&](double far_rms) {
            return candidates.size() == 1 && std::isfinite(far_rms) && far_rms <= 3.0 * candidates[0].rms_px + 2.0 &&
                   rotationErrorDeg(candidates[0].cam_from_tag, *predicted) < 0.5 * options.prediction_gate_deg;
        };
        if (unrefined_far && !options.refine_predicted_start) {
            // The caller refines the near start itself: it stays as IPPE gave it, with its corner
            // residual, when the shortcut holds for it as it is; otherwise as with the option on.
            const Rigid3d& near = initial[0];
            const double near_rms = tagReprojectionRms(corners, size, camera, near);
            if (near.isValid() && std::isfinite(near_rms) && near.translation.z() > 0) {
                candidates.push_back({near, near_rms});
                const double far_rms = tagReprojectionRms(corners, size, camera, *unrefined_far);
                if (shortcutHolds(far_rms)) {
                    candidates.push_back({*unrefined_far, far_rms});
                    unrefined_far.reset();
                    refined = false;
                } else {
                    candidates.clear();
                }
            }
        }
        if (refined) {
            for (const Rigid3d& start : initial) refineStart(start);
            if (unrefined_far) {
                const double rms = tagReprojectionRms(corners, size, camera, *unrefined_far);
                if (shortcutHolds(rms)) {
                    candidates.push_back({*unrefined_far, rms});
                } else {
                    refineStart(*unrefined_far);  // the shortcut does not hold: as without it
                }
            }
        }
        // The prediction is a third start: with noise, both IPPE starts can fall into the mirrored
        // minimum while the true one is still a minimum near the prediction. When they found two
        // distinct minima, the prediction's start ends on one of them (on every tag of bench
        // tracking's cases: 1187 of 1187), and is not run.
        if (predicted && predicted->translation.z() > 0 && candidates.size() < 2) refineStart(*predicted);
    }
    if (candidates.empty()) return fail(ErrorCode::kBadInput, what + ": no pose candidate reprojects its corners");
    // Only plausible alternatives stay: a candidate far worse than the best is not the other
    // side of an ambiguity but a failed start.
    {
        double best = std::numeric_limits<double>::infinity();
        for (const auto& c : candidates) best = std::min(best, c.rms_px);
        std::erase_if(candidates, [&](const TagPoseCandidate& c) { return c.rms_px > 3.0 * best + 2.0; });
    }
    if (candidates.size() > 2) {
        // Three starts, three minima (rare): keep the best by residual and, of the rest, the one
        // nearest the prediction (the third start exists only with a prediction).
        std::sort(candidates.begin(), candidates.end(),
                  [](const TagPoseCandidate& a, const TagPoseCandidate& b) { return a.rms_px < b.rms_px; });
        auto nearest = std::min_element(candidates.begin() + 1, candidates.end(), [&](const auto& a, const auto& b) {
            return rotationErrorDeg(a.cam_from_tag, *predicted) < rotationErrorDeg(b.cam_from_tag, *predicted);
        });
        std::iter_swap(candidates.begin() + 1, nearest);
        candidates.resize(2);
    }

    // Step 4: choose.
    std::sort(candidates.begin(), candidates.end(),
              [](const TagPoseCandidate& a, const TagPoseCandidate& b) { return a.rms_px < b.rms_px; });
    TagPose out;
    out.id = id;
    out.choice = candidates.size() == 1 ? PoseChoice::kOnlyCandidate : PoseChoice::kResidual;
    if (candidates.size() == 2 && predicted) {
        const Rigid3d& p = *predicted;
        const double d0 = rotationErrorDeg(candidates[0].cam_from_tag, p);
        const double d1 = rotationErrorDeg(candidates[1].cam_from_tag, p);
        if (d1 < d0 && d1 < options.prediction_gate_deg) {
            std::swap(candidates[0], candidates[1]);
            out.choice = PoseChoice::kPrediction;
        } else if (d0 < options.prediction_gate_deg) {
            out.choice = PoseChoice::kPrediction;
        }
    }
    constexpr double kFloor = 1e-6;
    const auto sq = [](double rms) { return 4.0 * rms * rms; };
    out.ambiguity_ratio = candidates.size() == 2 ? (sq(candidates[0].rms_px) + kFloor) / (sq(candidates[1].rms_px) + kFloor)
                                                 : 0.0;
    out.ambiguous = out.choice == PoseChoice::kResidual && out.ambiguity_ratio > options.ambiguous_corner_ratio;
    out.cam_from_tag = candidates[0].cam_from_tag;
    out.rms_px = candidates[0].rms_px;
    out.candidates = std::move(candidates);
    out.refined = refined;

    // Covariance: sigma^2 (J^T J)^-1 at the chosen pose; a (near-)singular information matrix
    // (it should not be with 4 corners of a proper quad) is regularised, never inverted blindly.
    Matrix6d info = Matrix6d::Zero();
    for (int i = 0; i < 4; ++i) {
        const auto proj = projectWithJacobian(camera, out.cam_from_tag * tagCornerInTag(i, size));
        if (!proj) return fail(ErrorCode::kBadInput, what + ": the chosen pose puts a corner outside the lens model");
        info += proj->d_pixel_d_xi.transpose() * proj->d_pixel_d_xi;
    }
    info += 1e-12 * info.trace() * Matrix6d::Identity();
    const double s2 = options.corner_sigma_px * options.corner_sigma_px;
    out.covariance = s2 * info.ldlt().solve(Matrix6d::Identity());
    out.covariance = 0.5 * (out.covariance + out.covariance.transpose()).eval();
    if (!out.covariance.allFinite() || !out.cam_from_tag.isValid()) {
        return fail(ErrorCode::kBadInput, what + ": the pose is not finite");
    }
    if (out.choice != PoseChoice::kPrediction && rotationSigmaDeg(out.covariance) > options.ambiguous_rotation_sigma_deg) {
        out.ambiguous = true;
    }
    return out;
}

}  // namespace commonlight::tracking

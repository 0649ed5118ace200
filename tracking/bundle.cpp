#include "tracking/bundle.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include <Eigen/Cholesky>

#include "tracking/option_checks.h"
#include "tracking/projection.h"

namespace commonlight::tracking {
namespace {

struct Point {
    Eigen::Vector3d p_in_local;  // world point minus the centroid
    Eigen::Vector2d observed;    // distorted pixel
    int tag = 0;                 // index into the used tags
    double weight = 1.0;         // BundleTag::weight
};

double huberWeight(double r, double k) { return r <= k ? 1.0 : k / r; }
double huberCost(double r, double k) { return r <= k ? 0.5 * r * r : k * (r - 0.5 * k); }

// Robust cost of a pose over every point; infinity when a point does not project. `pixels`, when
// given (sized as `points`), receives the projections (all of them when the cost is finite).
double robustCost(const std::vector<Point>& points, const CameraModel& camera, const Rigid3d& cam_from_local, double k,
                  std::vector<Eigen::Vector2d>* pixels = nullptr) {
    double cost = 0.0;
    for (std::size_t i = 0; i < points.size(); ++i) {
        const Point& pt = points[i];
        const auto px = camera.project(cam_from_local * pt.p_in_local);
        if (!px) return std::numeric_limits<double>::infinity();
        if (pixels) (*pixels)[i] = *px;
        cost += pt.weight * huberCost((*px - pt.observed).norm(), k);
    }
    return cost;
}

struct Fit {
    Rigid3d cam_from_local;
    Matrix6d information = Matrix6d::Zero();  // J^T W J
    double chi2 = 0.0;                        // sum of weighted squared residuals
    double cost = 0.0;                        // robustCost at cam_from_local
    int iterations = 0;
    bool abandoned = false;                   // given up (refine's RefineStop): information and chi2 not summed
};

// How many times the last accepted step's cost decrease every remaining step is allowed before a
// start is given up as unable to beat `to_beat` (below).
constexpr double kAbandonMargin = 4.0;

// Levenberg-Marquardt with Huber weights (iteratively reweighted). `to_beat`: the lowest final
// cost of the starts refined before this one. Once the damping is down to Gauss-Newton (lambda
// at most 1e-6: three accepted steps in a row from the start), a start whose cost stays above
// `to_beat` even if each of its remaining steps lowered it by kAbandonMargin times the last
// step's decrease is given up: its fit is returned with `abandoned` set and loses to the earlier
// one. A start in the other planar minimum of a board crawls to the iteration cap at a cost
// thousands of times the winner's (Huber's reweighting converges linearly there), and those
// steps were most of the bundle's (docs/history/tracking-passes-5.md, pass 11). A start heading
// for the winner's own minimum (within 1e-6 of its cost) runs on: it may end a rounding error
// below it.
struct RefineStop {
    double to_beat = std::numeric_limits<double>::infinity();
};

Fit refine(const std::vector<Point>& points, const CameraModel& camera, Rigid3d pose, const BundleOptions& options,
           const RefineStop& stop = {}) {
    Fit fit;
    double lambda = 1e-3;
    // The projections at `pose` (its cost is finite: every start's is, and only a lower cost is
    // accepted), reused by the Jacobians instead of projecting again; `trial` the candidate's.
    std::vector<Eigen::Vector2d> pixels(points.size()), trial(points.size());
    double cost = robustCost(points, camera, pose, options.huber_px, &pixels);
    // h and chi2 at `pose` when no step was accepted since they were summed: they are then the
    // fit's information and chi2 as the loop after this one would sum them again.
    bool normal_equations_at_pose = false;
    Matrix6d h;
    double chi2 = 0.0;
    for (int it = 0; it < options.max_iterations; ++it) {
        fit.iterations = it + 1;
        h.setZero();
        chi2 = 0.0;
        Vector6d g = Vector6d::Zero();
        for (std::size_t i = 0; i < points.size(); ++i) {
            const Point& pt = points[i];
            const auto proj = projectWithJacobian(camera, pose * pt.p_in_local, pixels[i]);
            if (!proj) continue;
            const Eigen::Vector2d r = proj->pixel - pt.observed;
            const double w = pt.weight * huberWeight(r.norm(), options.huber_px);
            h += w * proj->d_pixel_d_xi.transpose() * proj->d_pixel_d_xi;
            g += w * proj->d_pixel_d_xi.transpose() * r;
            chi2 += w * r.squaredNorm();
        }
        normal_equations_at_pose = true;
        bool improved = false;
        for (int attempt = 0; attempt < 10 && !improved; ++attempt) {
            Matrix6d damped = h;
            damped.diagonal() += lambda * h.diagonal().cwiseMax(1e-9);
            const Vector6d step = -damped.ldlt().solve(g);
            if (!step.allFinite()) break;
            const Rigid3d candidate = expSe3(step) * pose;
            const double new_cost = robustCost(points, camera, candidate, options.huber_px, &trial);
            if (new_cost < cost) {
                pixels.swap(trial);
                const bool converged = step.norm() < 1e-10 || (cost - new_cost) < 1e-14 * (1.0 + cost);
                const double remaining = options.max_iterations - 1 - it;
                const bool hopeless =
                    lambda <= 1e-6 &&
                    new_cost - kAbandonMargin * remaining * (cost - new_cost) > stop.to_beat + 1e-6 * (1.0 + stop.to_beat);
                pose = candidate;
                cost = new_cost;
                lambda = std::max(lambda / 10.0, 1e-9);
                improved = true;
                normal_equations_at_pose = false;
                if (hopeless) {
                    fit.cam_from_local = pose;
                    fit.cost = cost;
                    fit.abandoned = true;
                    return fit;
                }
                if (converged) it = options.max_iterations;
            } else {
                lambda *= 10.0;
            }
        }
        if (!improved) break;
    }
    fit.cam_from_local = pose;
    fit.cost = cost;
    if (normal_equations_at_pose) {
        fit.information = h;
        fit.chi2 = chi2;
        return fit;
    }
    for (std::size_t i = 0; i < points.size(); ++i) {
        const Point& pt = points[i];
        const auto proj = projectWithJacobian(camera, pose * pt.p_in_local, pixels[i]);
        if (!proj) continue;
        const Eigen::Vector2d r = proj->pixel - pt.observed;
        const double w = pt.weight * huberWeight(r.norm(), options.huber_px);
        fit.information += w * proj->d_pixel_d_xi.transpose() * proj->d_pixel_d_xi;
        fit.chi2 += w * r.squaredNorm();
    }
    return fit;
}

}  // namespace

Result<void> BundleOptions::validate() const {
    CL_TRY_VOID(requirePositive(huber_px, "BundleOptions", "huber_px"));
    CL_TRY_VOID(requirePositive(outlier_px, "BundleOptions", "outlier_px"));
    CL_TRY_VOID(requirePositive(corner_sigma_px, "BundleOptions", "corner_sigma_px"));
    if (max_iterations < 1) return fail(ErrorCode::kUsage, "bundle max_iterations must be >= 1");
    if (!(predicted_minimum_deg >= 0.0)) return fail(ErrorCode::kUsage, "bundle predicted_minimum_deg must be >= 0");
    return {};
}

Result<BundleResult> solveBundle(std::span<const BundleTag> tags, const TagSet& scene_tags, const CameraModel& camera,
                                 const std::optional<Rigid3d>& predicted, const BundleOptions& options) {
    CL_TRY_VOID(options.validate());
    if (predicted && !predicted->isValid()) return fail(ErrorCode::kBadInput, "bundle: the predicted pose is not finite");
    BundleResult result;

    // Step 1: the tags the scene places.
    struct Used {
        const BundleTag* tag;
        const TagItem* item;
    };
    std::vector<Used> used;
    for (const BundleTag& t : tags) {
        const TagItem* item = scene_tags.find(t.detection->id);
        if (!item) {
            result.tags_unknown.push_back(t.detection->id);
            continue;
        }
        const bool finite = std::all_of(t.detection->corners.begin(), t.detection->corners.end(),
                                        [](const Eigen::Vector2d& c) { return c.allFinite(); });
        if (!(t.weight > 0) || !std::isfinite(t.weight)) {
            return fail(ErrorCode::kBadInput, "bundle: tag " + std::to_string(t.detection->id) + " has a weight that is not positive");
        }
        if (finite) used.push_back({&t, item});
    }
    if (used.empty()) return fail(ErrorCode::kBadInput, "bundle: none of the detected tags is placed in the scene");

    // Solve about the centroid of the tags (world coordinates may be kilometres from the origin).
    Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
    for (const Used& u : used) centroid += u.item->world_from_tag.translation;
    centroid /= static_cast<double>(used.size());
    const Rigid3d world_from_local(Eigen::Quaterniond::Identity(), centroid);
    const Rigid3d local_from_world(Eigen::Quaterniond::Identity(), -centroid);

    std::vector<int> active(used.size());
    for (std::size_t i = 0; i < used.size(); ++i) active[i] = static_cast<int>(i);

    while (true) {
        std::vector<Point> points;
        for (int i : active) {
            const Used& u = used[static_cast<std::size_t>(i)];
            for (int c = 0; c < 4; ++c) {
                const Eigen::Vector3d p_world = u.item->world_from_tag * tagCornerInTag(c, u.item->size);
                points.push_back({p_world - centroid, u.tag->detection->corners[c], i, u.tag->weight});
            }
        }
        Fit fit;
        double fit_cost = std::numeric_limits<double>::infinity();
        int iterations_all_starts = 0;
        // With a prediction, its own start first: refined to within predicted_minimum_deg of it, it
        // is the minimum tracked, and no other start is ranked or refined
        // (BundleOptions::predicted_minimum_deg).
        bool settled = false;
        if (predicted && options.predicted_minimum_deg > 0.0) {
            const Rigid3d start = *predicted * world_from_local;
            if (std::isfinite(robustCost(points, camera, start, options.huber_px))) {
                Fit candidate = refine(points, camera, start, options, RefineStop{fit_cost});
                iterations_all_starts += candidate.iterations;
                if (!candidate.abandoned && std::isfinite(candidate.cost) &&
                    rotationErrorDeg(candidate.cam_from_local, start) < options.predicted_minimum_deg) {
                    fit_cost = candidate.cost;
                    fit = std::move(candidate);
                    settled = true;
                }
            }
        }
        if (!settled) {
            // Step 2: the best start.
            std::vector<Rigid3d> starts;
            if (predicted) starts.push_back(*predicted * world_from_local);
            for (int i : active) {
                const Used& u = used[static_cast<std::size_t>(i)];
                if (!u.tag->single) continue;
                // local_from_tag = local_from_world * world_from_tag, exact in double about the centroid.
                const Rigid3d tag_from_local = (local_from_world * u.item->world_from_tag).inverse();
                for (const TagPoseCandidate& c : u.tag->single->candidates) {
                    starts.push_back(c.cam_from_tag * tag_from_local);
                }
            }
            // The starts in order of their cost; distinct ones (more than 2 degrees apart) are each
            // refined, and the lowest final cost wins: a board of small coplanar tags has two minima
            // (the planar ambiguity of the whole board), and the start that is better before the
            // refinement is not always the one that is better after it.
            std::vector<std::pair<double, const Rigid3d*>> ranked;
            for (const Rigid3d& st : starts) {
                const double cost = robustCost(points, camera, st, options.huber_px);
                if (std::isfinite(cost)) ranked.emplace_back(cost, &st);
            }
            if (ranked.empty()) {
                return fail(ErrorCode::kBadInput, "bundle: no start pose puts the tags in front of the camera");
            }
            std::sort(ranked.begin(), ranked.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
            std::vector<const Rigid3d*> distinct;
            for (const auto& [cost, st] : ranked) {
                const bool seen = std::any_of(distinct.begin(), distinct.end(),
                                              [&](const Rigid3d* d) { return rotationErrorDeg(*d, *st) < 2.0; });
                if (!seen) distinct.push_back(st);
                if (distinct.size() == 3) break;
            }

            // Step 3: robust LM from each.
            for (const Rigid3d* st : distinct) {
                const double to_beat =
                    options.give_up_hopeless_starts ? fit_cost : std::numeric_limits<double>::infinity();
                Fit candidate = refine(points, camera, *st, options, RefineStop{to_beat});
                iterations_all_starts += candidate.iterations;
                const double cost = candidate.cost;
                if (cost < fit_cost && !candidate.abandoned) {
                    fit_cost = cost;
                    fit = std::move(candidate);
                    // Near the prediction: the minimum tracked (BundleOptions::predicted_minimum_deg).
                    if (predicted && rotationErrorDeg(fit.cam_from_local, *predicted * world_from_local) <
                                         options.predicted_minimum_deg) {
                        break;
                    }
                }
            }
        }
        if (!std::isfinite(fit_cost)) {
            return fail(ErrorCode::kBadInput, "bundle: the solution does not reproject the corners");
        }

        // Step 4: the worst tag, rejected while it is an outlier and others remain.
        std::vector<double> sum(used.size(), 0.0);
        for (const Point& pt : points) {
            const auto px = camera.project(fit.cam_from_local * pt.p_in_local);
            sum[static_cast<std::size_t>(pt.tag)] +=
                px ? (*px - pt.observed).squaredNorm() : std::numeric_limits<double>::infinity();
        }
        int worst = -1;
        double worst_rms = 0.0;
        double total = 0.0;
        for (int i : active) {
            const double rms = std::sqrt(sum[static_cast<std::size_t>(i)] / 4.0);
            total += sum[static_cast<std::size_t>(i)];
            if (rms > worst_rms) {
                worst_rms = rms;
                worst = i;
            }
        }
        if (worst_rms > options.outlier_px && active.size() > 1) {
            result.tags_rejected.push_back(used[static_cast<std::size_t>(worst)].tag->detection->id);
            std::erase(active, worst);
            continue;
        }
        if (!std::isfinite(total) || !fit.cam_from_local.isValid()) {
            return fail(ErrorCode::kBadInput, "bundle: the solution does not reproject the corners");
        }
        result.cam_from_world = fit.cam_from_local * local_from_world;
        result.iterations = fit.iterations;
        result.iterations_all_starts = iterations_all_starts;
        const auto n = static_cast<double>(points.size());
        result.rms_px = std::sqrt(total / n);
        for (int i : active) result.tags_used.push_back(used[static_cast<std::size_t>(i)].tag->detection->id);
        // Corner noise: the assumed sigma, or more when the residuals say so (2n - 6 dof).
        const double dof = std::max(1.0, 2.0 * n - 6.0);
        const double s2 = std::max(options.corner_sigma_px * options.corner_sigma_px, fit.chi2 / dof);
        Matrix6d info = fit.information;
        info += 1e-12 * info.trace() * Matrix6d::Identity();
        result.covariance = s2 * info.ldlt().solve(Matrix6d::Identity());
        result.covariance = (0.5 * (result.covariance + result.covariance.transpose())).eval();
        if (!result.covariance.allFinite()) return fail(ErrorCode::kBadInput, "bundle: the covariance is not finite");
        return result;
    }
}

}  // namespace commonlight::tracking

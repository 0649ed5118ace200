#include "lighting/light_fit.h"

#include <ceres/ceres.h>

#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

namespace commonlight::lighting {

namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kMinAlbedo = 0.005;
constexpr double kMaxAlbedo = 0.98;

// r = sqrt(W) (A x - b) for one row, linear in x: analytic Jacobian.
class LinearRow final : public ceres::CostFunction {
public:
    LinearRow(std::vector<double> row, double target, double sqrt_weight)
        : row_(std::move(row)), target_(target), sqrt_weight_(sqrt_weight) {
        set_num_residuals(1);
        mutable_parameter_block_sizes()->push_back(static_cast<int>(row_.size()));
    }
    bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override {
        double v = -target_;
        for (std::size_t k = 0; k < row_.size(); ++k) v += row_[k] * parameters[0][k];
        residuals[0] = sqrt_weight_ * v;
        if (jacobians && jacobians[0]) {
            for (std::size_t k = 0; k < row_.size(); ++k) jacobians[0][k] = sqrt_weight_ * row_[k];
        }
        return true;
    }

private:
    std::vector<double> row_;
    double target_;
    double sqrt_weight_;
};

// r = sqrt(W) (rho / pi (sum_k E_k D_k + C) - L): bilinear in (E, rho).
class ObservationResidual final : public ceres::CostFunction {
public:
    ObservationResidual(const FitObservation& o, bool known_albedo) : o_(&o), known_(known_albedo) {
        set_num_residuals(1);
        mutable_parameter_block_sizes()->push_back(static_cast<int>(o.columns.size()));
        if (!known_) mutable_parameter_block_sizes()->push_back(1);
    }
    bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override {
        const double* e = parameters[0];
        const double rho = known_ ? o_->albedo : parameters[1][0];
        double irradiance = o_->constant;
        for (std::size_t k = 0; k < o_->columns.size(); ++k) irradiance += e[k] * o_->columns[k];
        const double w = std::sqrt(o_->weight);
        residuals[0] = w * (rho / kPi * irradiance - o_->radiance);
        if (jacobians) {
            if (jacobians[0]) {
                for (std::size_t k = 0; k < o_->columns.size(); ++k) jacobians[0][k] = w * rho / kPi * o_->columns[k];
            }
            if (!known_ && jacobians[1]) jacobians[1][0] = w * irradiance / kPi;
        }
        return true;
    }

private:
    const FitObservation* o_;
    bool known_;
};

// A weak prior on the area-weighted mean of the group albedos (only when nothing anchors the scale).
class MeanAlbedoPrior final : public ceres::CostFunction {
public:
    MeanAlbedoPrior(std::vector<double> group_area, double target, double weight)
        : area_(std::move(group_area)), target_(target), weight_(weight) {
        set_num_residuals(1);
        for (std::size_t g = 0; g < area_.size(); ++g) mutable_parameter_block_sizes()->push_back(1);
        total_ = 0.0;
        for (double a : area_) total_ += a;
    }
    bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override {
        double mean = 0.0;
        for (std::size_t g = 0; g < area_.size(); ++g) mean += area_[g] * parameters[g][0];
        mean /= total_;
        residuals[0] = weight_ * (mean - target_);
        if (jacobians) {
            for (std::size_t g = 0; g < area_.size(); ++g) {
                if (jacobians[g]) jacobians[g][0] = weight_ * area_[g] / total_;
            }
        }
        return true;
    }

private:
    std::vector<double> area_;
    double target_;
    double weight_;
    double total_ = 1.0;
};

ceres::Solver::Options solverOptions(int max_iterations) {
    ceres::Solver::Options options;
    options.linear_solver_type = ceres::DENSE_QR;
    options.max_num_iterations = max_iterations;
    options.function_tolerance = 1e-12;
    options.gradient_tolerance = 1e-14;
    options.parameter_tolerance = 1e-12;
    options.num_threads = 1;  // deterministic; the lighting thread already has the machine's other core busy
    options.logging_type = ceres::SILENT;
    options.minimizer_progress_to_stdout = false;
    return options;
}

}  // namespace

double conditionNumber(const Eigen::MatrixXd& a) {
    if (a.rows() == 0 || a.cols() == 0) return std::numeric_limits<double>::infinity();
    const Eigen::JacobiSVD<Eigen::MatrixXd> svd(a);
    const auto& s = svd.singularValues();
    const double smin = s(s.size() - 1), smax = s(0);
    // Hard case: fewer rows than columns or a zero column: rank deficient.
    if (a.rows() < a.cols() || !(smin > 0.0)) return std::numeric_limits<double>::infinity();
    return smax / smin;
}

Result<Eigen::VectorXd> nnls(const Eigen::MatrixXd& a, const Eigen::VectorXd& b, const Eigen::VectorXd& weights,
                             double lambda) {
    if (a.rows() != b.size() || a.rows() != weights.size() || a.cols() == 0) {
        return fail(ErrorCode::kBadInput, "nnls: sizes do not match");
    }
    if (!a.allFinite() || !b.allFinite() || !weights.allFinite() || !std::isfinite(lambda)) {
        return fail(ErrorCode::kBadInput, "nnls: non-finite input");
    }
    const auto n = static_cast<int>(a.cols());
    std::vector<double> x(static_cast<std::size_t>(n), 0.0);
    ceres::Problem problem;
    for (Eigen::Index i = 0; i < a.rows(); ++i) {
        if (!(weights(i) > 0.0)) continue;
        std::vector<double> row(static_cast<std::size_t>(n));
        for (int k = 0; k < n; ++k) row[static_cast<std::size_t>(k)] = a(i, k);
        problem.AddResidualBlock(new LinearRow(std::move(row), b(i), std::sqrt(weights(i))), nullptr, x.data());
    }
    if (lambda > 0.0) {
        for (int k = 0; k < n; ++k) {
            std::vector<double> row(static_cast<std::size_t>(n), 0.0);
            row[static_cast<std::size_t>(k)] = 1.0;
            problem.AddResidualBlock(new LinearRow(std::move(row), 0.0, std::sqrt(lambda)), nullptr, x.data());
        }
    }
    if (problem.NumResidualBlocks() == 0) return fail(ErrorCode::kBadInput, "nnls: no row has a positive weight");
    for (int k = 0; k < n; ++k) problem.SetParameterLowerBound(x.data(), k, 0.0);
    ceres::Solver::Summary summary;
    ceres::Solve(solverOptions(200), &problem, &summary);
    if (!summary.IsSolutionUsable()) return fail(ErrorCode::kInternal, "nnls: Ceres failed: " + summary.message);
    Eigen::VectorXd out(n);
    for (int k = 0; k < n; ++k) out(k) = std::max(0.0, x[static_cast<std::size_t>(k)]);
    return out;
}

Result<FitResult> fitChannel(const FitProblem& p) {
    const int k_sources = p.sources;
    if (p.observations.empty()) return fail(ErrorCode::kBadInput, "light fit: nothing observed");
    bool anchored = false;
    for (const FitObservation& o : p.observations) {
        if (static_cast<int>(o.columns.size()) != k_sources || o.group >= p.groups || o.group < -1) {
            return fail(ErrorCode::kBadInput, "light fit: an observation does not match the problem's sizes");
        }
        if (!std::isfinite(o.radiance) || !std::isfinite(o.weight) || !std::isfinite(o.constant) || o.weight < 0.0) {
            return fail(ErrorCode::kBadInput, "light fit: non-finite observation");
        }
        for (double c : o.columns) {
            if (!std::isfinite(c)) return fail(ErrorCode::kBadInput, "light fit: non-finite column");
        }
        if (o.group < 0 && o.weight > 0.0) anchored = true;
    }
    FitResult result;
    result.scale_from_prior = !anchored;
    std::vector<double> rho(static_cast<std::size_t>(p.groups), 0.5);
    if (static_cast<int>(p.initial_group_albedo.size()) == p.groups) {
        for (int g = 0; g < p.groups; ++g) {
            rho[static_cast<std::size_t>(g)] = std::clamp(p.initial_group_albedo[static_cast<std::size_t>(g)], kMinAlbedo, kMaxAlbedo);
        }
    }
    const auto albedo_of = [&](const FitObservation& o) { return o.group < 0 ? o.albedo : rho[static_cast<std::size_t>(o.group)]; };

    // The design matrix at the current albedos: rows sqrt(W) rho/pi D, targets sqrt(W) (L - rho/pi C).
    const auto rows = static_cast<Eigen::Index>(p.observations.size());
    const auto design = [&](Eigen::MatrixXd& a, Eigen::VectorXd& b, Eigen::VectorXd& w) {
        a.resize(rows, k_sources);
        b.resize(rows);
        w.resize(rows);
        for (Eigen::Index i = 0; i < rows; ++i) {
            const FitObservation& o = p.observations[static_cast<std::size_t>(i)];
            const double r = albedo_of(o);
            for (int k = 0; k < k_sources; ++k) a(i, k) = r / kPi * o.columns[static_cast<std::size_t>(k)];
            b(i) = o.radiance - r / kPi * o.constant;
            w(i) = o.weight;
        }
    };
    Eigen::MatrixXd a;
    Eigen::VectorXd b, w;
    design(a, b, w);
    const Eigen::VectorXd sw = w.cwiseSqrt();
    const Eigen::MatrixXd aw = sw.asDiagonal() * a;
    double mean_diag = 0.0;
    for (int k = 0; k < k_sources; ++k) mean_diag += aw.col(k).squaredNorm();
    mean_diag = k_sources > 0 ? mean_diag / k_sources : 0.0;
    const double lambda = p.tikhonov * mean_diag;

    // Step 1: the linear start: NNLS at the initial albedos (and, as a diagnostic, the plain least
    // squares solution's negative entries).
    std::vector<double> e(static_cast<std::size_t>(k_sources), 0.0);
    if (k_sources > 0) {
        if (aw.rows() >= k_sources) {
            const Eigen::VectorXd plain = aw.colPivHouseholderQr().solve(sw.cwiseProduct(b));
            for (int k = 0; k < k_sources; ++k) result.negative_in_plain_least_squares += plain(k) < 0.0 ? 1 : 0;
        }
        CL_TRY(Eigen::VectorXd start, nnls(a, b, w, lambda));
        for (int k = 0; k < k_sources; ++k) e[static_cast<std::size_t>(k)] = start(k);
    }

    // Step 2: the joint bilinear problem.
    if (p.groups > 0 || k_sources > 0) {
        ceres::Problem problem;
        double* e_block = k_sources > 0 ? e.data() : nullptr;
        std::vector<double> group_area(static_cast<std::size_t>(p.groups), 0.0);
        std::vector<bool> group_seen(static_cast<std::size_t>(p.groups), false);
        for (const FitObservation& o : p.observations) {
            if (!(o.weight > 0.0)) continue;
            if (k_sources == 0) break;
            if (o.group < 0) {
                problem.AddResidualBlock(new ObservationResidual(o, true), nullptr, e_block);
            } else {
                problem.AddResidualBlock(new ObservationResidual(o, false), nullptr, e_block,
                                         &rho[static_cast<std::size_t>(o.group)]);
                group_area[static_cast<std::size_t>(o.group)] += o.area;
                group_seen[static_cast<std::size_t>(o.group)] = true;
            }
        }
        if (k_sources > 0 && lambda > 0.0) {
            for (int k = 0; k < k_sources; ++k) {
                std::vector<double> row(static_cast<std::size_t>(k_sources), 0.0);
                row[static_cast<std::size_t>(k)] = 1.0;
                problem.AddResidualBlock(new LinearRow(std::move(row), 0.0, std::sqrt(lambda)), nullptr, e_block);
            }
        }
        std::vector<double*> seen_blocks;
        std::vector<double> seen_area;
        for (int g = 0; g < p.groups; ++g) {
            if (!group_seen[static_cast<std::size_t>(g)]) continue;
            seen_blocks.push_back(&rho[static_cast<std::size_t>(g)]);
            seen_area.push_back(group_area[static_cast<std::size_t>(g)]);
        }
        if (!anchored && !seen_blocks.empty()) {
            // Weak: as strong as one average observation.
            double total_w = 0.0, total_l = 0.0;
            for (const FitObservation& o : p.observations) {
                total_w += o.weight;
                total_l += o.weight * o.radiance * o.radiance;
            }
            const double typical = std::sqrt(total_l / std::max(total_w, 1e-300)) * std::sqrt(total_w / p.observations.size());
            problem.AddResidualBlock(new MeanAlbedoPrior(seen_area, p.prior_albedo, typical / p.prior_albedo), nullptr,
                                     seen_blocks);
        }
        if (k_sources > 0) {
            for (int k = 0; k < k_sources; ++k) problem.SetParameterLowerBound(e_block, k, 0.0);
        }
        for (double* block : seen_blocks) {
            problem.SetParameterLowerBound(block, 0, kMinAlbedo);
            problem.SetParameterUpperBound(block, 0, kMaxAlbedo);
        }
        if (problem.NumResidualBlocks() > 0) {
            ceres::Solver::Summary summary;
            ceres::Solve(solverOptions(p.max_iterations), &problem, &summary);
            if (!summary.IsSolutionUsable()) return fail(ErrorCode::kInternal, "light fit: Ceres failed: " + summary.message);
            result.iterations = static_cast<int>(summary.iterations.size());
        }
    }
    for (double& v : e) v = std::max(0.0, v);
    result.emission = e;
    result.group_albedo = rho;

    // Step 3: diagnostics at the solution: residual, conditioning, standard errors.
    design(a, b, w);
    const Eigen::VectorXd sw2 = w.cwiseSqrt();
    const Eigen::MatrixXd aw2 = sw2.asDiagonal() * a;
    Eigen::VectorXd ev(k_sources);
    for (int k = 0; k < k_sources; ++k) ev(k) = e[static_cast<std::size_t>(k)];
    const Eigen::VectorXd r = k_sources > 0 ? Eigen::VectorXd(aw2 * ev - sw2.cwiseProduct(b)) : Eigen::VectorXd(-sw2.cwiseProduct(b));
    const double wsum = w.sum();
    result.residual_rms = wsum > 0.0 ? std::sqrt(r.squaredNorm() / wsum) : 0.0;
    double lsum = 0.0;
    for (Eigen::Index i = 0; i < rows; ++i) lsum += w(i) * p.observations[static_cast<std::size_t>(i)].radiance * p.observations[static_cast<std::size_t>(i)].radiance;
    result.relative_residual = lsum > 0.0 ? result.residual_rms / std::sqrt(lsum / wsum) : 0.0;
    result.condition_number = k_sources > 0 ? conditionNumber(aw2) : 0.0;
    result.relative_error.assign(static_cast<std::size_t>(k_sources), std::numeric_limits<double>::infinity());
    result.column_weight.assign(static_cast<std::size_t>(k_sources), 0.0);
    if (k_sources > 0) {
        const double dof = std::max<double>(1.0, static_cast<double>(rows - k_sources));
        const double sigma2 = r.squaredNorm() / dof;
        Eigen::MatrixXd normal = aw2.transpose() * aw2;
        normal.diagonal().array() += lambda;
        const Eigen::MatrixXd cov = sigma2 * normal.completeOrthogonalDecomposition().pseudoInverse();
        for (int k = 0; k < k_sources; ++k) {
            result.column_weight[static_cast<std::size_t>(k)] = aw2.col(k).norm();
            const double se = std::sqrt(std::max(0.0, cov(k, k)));
            if (e[static_cast<std::size_t>(k)] > 0.0) result.relative_error[static_cast<std::size_t>(k)] = se / e[static_cast<std::size_t>(k)];
        }
    }
    return result;
}

}  // namespace commonlight::lighting

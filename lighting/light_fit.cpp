#include "lighting/light_fit.h"

#include <ceres/ceres.h>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <cstdio>
#include <cstdlib>

namespace commonlight::lighting {

namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kMinAlbedo = 0.005;
constexpr double kMaxAlbedo = 0.98;

// r = R x - c, all rows at once: the normal equations' Cholesky factor (n residuals).
class TriangularResidual final : public ceres::CostFunction {
public:
    TriangularResidual(Eigen::MatrixXd r, Eigen::VectorXd c) : r_(std::move(r)), c_(std::move(c)) {
        set_num_residuals(static_cast<int>(c_.size()));
        mutable_parameter_block_sizes()->push_back(static_cast<int>(c_.size()));
    }
    bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override {
        const auto n = c_.size();
        const Eigen::Map<const Eigen::VectorXd> x(parameters[0], n);
        Eigen::Map<Eigen::VectorXd>(residuals, n) = r_ * x - c_;
        if (jacobians && jacobians[0]) {
            Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(jacobians[0], n, n) = r_;
        }
        return true;
    }

private:
    Eigen::MatrixXd r_;
    Eigen::VectorXd c_;
};

// One group's rows at once: sum_i W_i (s D_i.E + s C_i - L_i)^2 = |U (s E, s, -1)|^2 with
// U^T U = sum_i W_i Z_i Z_i^T, Z_i = (D_i, C_i, L_i), s = rho / pi (or 1 for the known-albedo rows,
// whose albedo is folded into D and C). Parameters: E, and rho unless `fixed_scale`.
class GroupResidual final : public ceres::CostFunction {
public:
    GroupResidual(Eigen::MatrixXd u, bool fixed_scale) : u_(std::move(u)), fixed_(fixed_scale) {
        const auto m = static_cast<int>(u_.cols());  // n + 2
        set_num_residuals(m);
        mutable_parameter_block_sizes()->push_back(m - 2);
        if (!fixed_) mutable_parameter_block_sizes()->push_back(1);
    }
    bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override {
        const auto m = u_.cols();
        const auto n = m - 2;
        const double s = fixed_ ? 1.0 : parameters[1][0] / kPi;
        Eigen::VectorXd z(m);
        z.head(n) = s * Eigen::Map<const Eigen::VectorXd>(parameters[0], n);
        z(n) = s;
        z(n + 1) = -1.0;
        Eigen::Map<Eigen::VectorXd>(residuals, m) = u_ * z;
        if (jacobians) {
            using RowMajor = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
            if (jacobians[0]) Eigen::Map<RowMajor>(jacobians[0], m, n) = s * u_.leftCols(n);
            if (!fixed_ && jacobians[1]) {
                Eigen::VectorXd dz = Eigen::VectorXd::Zero(m);
                dz.head(n) = Eigen::Map<const Eigen::VectorXd>(parameters[0], n) / kPi;
                dz(n) = 1.0 / kPi;
                Eigen::Map<Eigen::VectorXd>(jacobians[1], m) = u_ * dz;
            }
        }
        return true;
    }

private:
    Eigen::MatrixXd u_;
    bool fixed_;
};

// sqrt(lambda) E.
class TikhonovResidual final : public ceres::CostFunction {
public:
    TikhonovResidual(int n, double lambda) : n_(n), w_(std::sqrt(lambda)) {
        set_num_residuals(n);
        mutable_parameter_block_sizes()->push_back(n);
    }
    bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override {
        for (int k = 0; k < n_; ++k) residuals[k] = w_ * parameters[0][k];
        if (jacobians && jacobians[0]) {
            Eigen::Map<Eigen::MatrixXd>(jacobians[0], n_, n_) = w_ * Eigen::MatrixXd::Identity(n_, n_);
        }
        return true;
    }

private:
    int n_;
    double w_;
};

// The area-weighted mean of the groups' reflectances held near a prior (when nothing of known
// albedo anchors the scale).
class MeanAlbedoPrior final : public ceres::CostFunction {
public:
    MeanAlbedoPrior(std::vector<double> area, double target, double weight)
        : area_(std::move(area)), target_(target), weight_(weight) {
        set_num_residuals(1);
        for (std::size_t g = 0; g < area_.size(); ++g) mutable_parameter_block_sizes()->push_back(1);
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
    double total_ = 0.0;
};

ceres::Solver::Options solverOptions() {
    ceres::Solver::Options options;
    options.linear_solver_type = ceres::DENSE_QR;
    options.max_num_iterations = 200;
    options.function_tolerance = 1e-14;
    options.gradient_tolerance = 1e-16;
    options.parameter_tolerance = 1e-14;
    options.num_threads = 1;  // deterministic
    options.logging_type = ceres::SILENT;
    options.minimizer_progress_to_stdout = false;
    return options;
}

// Per reflectance group (and one for the known albedos), the sums the fit needs:
//   G = sum W D D^T, p = sum W L D, q = sum W C D, and scalars sum W L^2, sum W L C, sum W C^2.
// Known-albedo rows fold their albedo in (D -> a D, C -> a C) into group "known".
struct GroupSums {
    Eigen::MatrixXd zz;  // sum W Z Z^T, Z = (D, C, L)
    Eigen::MatrixXd g;
    Eigen::VectorXd p, q;
    double ll = 0.0, lc = 0.0, cc = 0.0, weight = 0.0, area = 0.0;
    bool used = false;
    explicit GroupSums(int n = 0)
        : zz(Eigen::MatrixXd::Zero(n + 2, n + 2)), g(Eigen::MatrixXd::Zero(n, n)), p(Eigen::VectorXd::Zero(n)), q(Eigen::VectorXd::Zero(n)) {}
};

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

Result<Eigen::VectorXd> nnlsNormal(const Eigen::MatrixXd& normal, const Eigen::VectorXd& v, double lambda,
                                   const Eigen::VectorXd* start) {
    const auto n = v.size();
    if (normal.rows() != n || normal.cols() != n || n == 0) return fail(ErrorCode::kBadInput, "nnls: sizes do not match");
    if (!normal.allFinite() || !v.allFinite() || !std::isfinite(lambda) || lambda < 0.0) {
        return fail(ErrorCode::kBadInput, "nnls: non-finite input");
    }
    Eigen::MatrixXd m = normal;
    m.diagonal().array() += lambda;
    // Hard case: a singular normal matrix (a column nobody sees, and no Tikhonov): a jitter of
    // 1e-12 of its trace makes the factor exist without changing any well-determined value.
    const double jitter = 1e-12 * std::max(m.trace(), 1e-300);
    Eigen::LLT<Eigen::MatrixXd> llt(m);
    if (llt.info() != Eigen::Success) {
        m.diagonal().array() += jitter;
        llt.compute(m);
        if (llt.info() != Eigen::Success) return fail(ErrorCode::kInternal, "nnls: the normal matrix is not positive definite");
    }
    const Eigen::MatrixXd r = llt.matrixU();
    const Eigen::VectorXd c = llt.matrixL().solve(v);  // R^T c = v
    std::vector<double> x(static_cast<std::size_t>(n), 0.0);
    if (start && start->size() == n) {
        for (Eigen::Index k = 0; k < n; ++k) x[static_cast<std::size_t>(k)] = std::max(0.0, (*start)(k));
    }
    ceres::Problem problem;
    problem.AddResidualBlock(new TriangularResidual(r, c), nullptr, x.data());
    for (Eigen::Index k = 0; k < n; ++k) problem.SetParameterLowerBound(x.data(), static_cast<int>(k), 0.0);
    ceres::Solver::Summary summary;
    ceres::Solve(solverOptions(), &problem, &summary);
    if (!summary.IsSolutionUsable()) return fail(ErrorCode::kInternal, "nnls: Ceres failed: " + summary.message);
    Eigen::VectorXd out(n);
    for (Eigen::Index k = 0; k < n; ++k) out(k) = std::max(0.0, x[static_cast<std::size_t>(k)]);
    // Polish: Ceres's projected trust-region steps stop a little short of the bound-constrained
    // optimum (1e-3 relative is typical). On the active set it found (the entries held at 0) the
    // optimum is an equality-constrained least-squares problem: solve it exactly, keep it if it
    // stays non-negative.
    std::vector<Eigen::Index> free;
    for (Eigen::Index k = 0; k < n; ++k) {
        if (out(k) > 1e-12 * std::max(1.0, out.cwiseAbs().maxCoeff())) free.push_back(k);
    }
    if (!free.empty()) {
        const auto f = static_cast<Eigen::Index>(free.size());
        Eigen::MatrixXd mf(f, f);
        Eigen::VectorXd vf(f);
        for (Eigen::Index i = 0; i < f; ++i) {
            vf(i) = v(free[static_cast<std::size_t>(i)]);
            for (Eigen::Index j = 0; j < f; ++j) mf(i, j) = m(free[static_cast<std::size_t>(i)], free[static_cast<std::size_t>(j)]);
        }
        const Eigen::VectorXd xf = mf.ldlt().solve(vf);
        if (xf.allFinite() && xf.minCoeff() >= 0.0) {
            Eigen::VectorXd polished = Eigen::VectorXd::Zero(n);
            for (Eigen::Index i = 0; i < f; ++i) polished(free[static_cast<std::size_t>(i)]) = xf(i);
            // Keep it only if it is no worse (it cannot be, unless the system is singular).
            const auto objective = [&](const Eigen::VectorXd& y) { return y.dot(m * y) - 2.0 * y.dot(v); };
            if (objective(polished) <= objective(out)) out = polished;
        }
    }
    return out;
}

Result<Eigen::VectorXd> nnls(const Eigen::MatrixXd& a, const Eigen::VectorXd& b, const Eigen::VectorXd& weights,
                             double lambda) {
    if (a.rows() != b.size() || a.rows() != weights.size() || a.cols() == 0) {
        return fail(ErrorCode::kBadInput, "nnls: sizes do not match");
    }
    if (!a.allFinite() || !b.allFinite() || !weights.allFinite() || !std::isfinite(lambda)) {
        return fail(ErrorCode::kBadInput, "nnls: non-finite input");
    }
    const Eigen::MatrixXd wa = weights.cwiseMax(0.0).asDiagonal() * a;
    return nnlsNormal(a.transpose() * wa, wa.transpose() * b, lambda);
}

Result<FitResult> fitChannel(const FitProblem& p) {
    const int n = p.sources;
    if (p.observations.empty()) return fail(ErrorCode::kBadInput, "light fit: nothing observed");
    if (n < 0 || p.groups < 0) return fail(ErrorCode::kBadInput, "light fit: negative sizes");
    // Step 1: per-group sums (one pass over the rows; everything after works on n x n matrices).
    std::vector<GroupSums> groups(static_cast<std::size_t>(p.groups), GroupSums(n));
    GroupSums known(n);
    for (const FitObservation& o : p.observations) {
        if (static_cast<int>(o.columns.size()) != n || o.group >= p.groups || o.group < -1) {
            return fail(ErrorCode::kBadInput, "light fit: an observation does not match the problem's sizes");
        }
        if (!std::isfinite(o.radiance) || !std::isfinite(o.weight) || !std::isfinite(o.constant) || o.weight < 0.0 ||
            !std::isfinite(o.albedo)) {
            return fail(ErrorCode::kBadInput, "light fit: non-finite observation");
        }
        Eigen::VectorXd d(n);
        for (int k = 0; k < n; ++k) {
            d(k) = o.columns[static_cast<std::size_t>(k)];
            if (!std::isfinite(d(k))) return fail(ErrorCode::kBadInput, "light fit: non-finite column");
        }
        if (!(o.weight > 0.0)) continue;
        const double w = o.weight;
        // Model: L = rho/pi (D.E + C). Known rows: fold rho/pi in now.
        const double fold = o.group < 0 ? o.albedo / kPi : 1.0;
        GroupSums& g = o.group < 0 ? known : groups[static_cast<std::size_t>(o.group)];
        const Eigen::VectorXd df = fold * d;
        const double cf = fold * o.constant;
        g.g.noalias() += w * df * df.transpose();
        Eigen::VectorXd z(n + 2);
        z.head(n) = df;
        z(n) = cf;
        z(n + 1) = o.radiance;
        g.zz.noalias() += w * z * z.transpose();
        g.p += w * o.radiance * df;
        g.q += w * cf * df;
        g.ll += w * o.radiance * o.radiance;
        g.lc += w * o.radiance * cf;
        g.cc += w * cf * cf;
        g.weight += w;
        g.area += o.area;
        g.used = true;
    }
    FitResult result;
    result.scale_from_prior = !known.used && p.groups > 0;
    std::vector<double> rho(static_cast<std::size_t>(p.groups), 0.5);
    if (static_cast<int>(p.initial_group_albedo.size()) == p.groups) {
        for (int g = 0; g < p.groups; ++g) {
            rho[static_cast<std::size_t>(g)] = std::clamp(p.initial_group_albedo[static_cast<std::size_t>(g)], kMinAlbedo, kMaxAlbedo);
        }
    }
    // The normal equations of E at given reflectances: N = sum_g s_g^2 G_g + G_known,
    // v = sum_g (s_g p_g - s_g^2 q_g) + (p_known - q_known), s_g = rho_g / pi.
    const auto normal = [&](Eigen::MatrixXd& m, Eigen::VectorXd& v) {
        m = known.g;
        v = known.p - known.q;
        for (int g = 0; g < p.groups; ++g) {
            const GroupSums& s = groups[static_cast<std::size_t>(g)];
            if (!s.used) continue;
            const double sg = rho[static_cast<std::size_t>(g)] / kPi;
            m += sg * sg * s.g;
            v += sg * s.p - sg * sg * s.q;
        }
    };
    // Weighted squared residual at (E, rho).
    const auto residual2 = [&](const Eigen::VectorXd& e) {
        double r2 = 0.0;
        const auto add = [&](const GroupSums& s, double sg) {
            if (!s.used) return;
            // sum W (L - sg (D.E + C))^2
            const double de_de = e.dot(s.g * e), de_c = e.dot(s.q), de_l = e.dot(s.p);
            r2 += s.ll - 2.0 * sg * (de_l + s.lc) + sg * sg * (de_de + 2.0 * de_c + s.cc);
        };
        add(known, 1.0);
        for (int g = 0; g < p.groups; ++g) add(groups[static_cast<std::size_t>(g)], rho[static_cast<std::size_t>(g)] / kPi);
        return std::max(0.0, r2);
    };

    Eigen::MatrixXd m;
    Eigen::VectorXd v;
    normal(m, v);
    const double mean_diag = n > 0 ? m.trace() / n : 0.0;
    const double lambda = p.tikhonov * mean_diag;
    Eigen::VectorXd e = Eigen::VectorXd::Zero(n);

    // Step 2: a start by alternating exact steps (an E-step at the initial reflectances, a
    // reflectance step, the scale step), then the joint problem by Ceres with bounds.
    const auto rho_step = [&]() {
        for (int g = 0; g < p.groups; ++g) {
            const GroupSums& s = groups[static_cast<std::size_t>(g)];
            if (!s.used) continue;
            const double hh = e.dot(s.g * e) + 2.0 * e.dot(s.q) + s.cc;  // sum W H^2
            const double lh = e.dot(s.p) + s.lc;                           // sum W L H
            // Hard case: no light reaches the group in the model: keep its reflectance.
            if (hh > 0.0) rho[static_cast<std::size_t>(g)] = std::clamp(kPi * lh / hh, kMinAlbedo, kMaxAlbedo);
        }
    };
    for (int it = 0; it < 2; ++it) {
        if (n > 0) {
            normal(m, v);
            const Eigen::VectorXd warm = e;
            CL_TRY(e, nnlsNormal(m, v, lambda, it > 0 ? &warm : nullptr));
        }
        rho_step();
    }
    std::vector<double*> seen_blocks;
    std::vector<double> seen_area;
    if (n > 0 || p.groups > 0) {
        ceres::Problem problem;
        std::vector<double> ev(e.data(), e.data() + n);
        if (n == 0) ev.push_back(0.0);  // Ceres needs a block; unused
        const auto factor = [](const Eigen::MatrixXd& zz) {
            // U with U^T U = zz (zz is PSD; a jitter of 1e-12 of its trace where it is singular).
            Eigen::MatrixXd a = zz;
            Eigen::LLT<Eigen::MatrixXd> llt(a);
            if (llt.info() != Eigen::Success) {
                a.diagonal().array() += 1e-12 * std::max(a.trace(), 1e-300);
                llt.compute(a);
            }
            return Eigen::MatrixXd(llt.matrixU());
        };
        if (n > 0) {
            if (known.used) problem.AddResidualBlock(new GroupResidual(factor(known.zz), true), nullptr, ev.data());
            for (int g = 0; g < p.groups; ++g) {
                GroupSums& s = groups[static_cast<std::size_t>(g)];
                if (!s.used) continue;
                problem.AddResidualBlock(new GroupResidual(factor(s.zz), false), nullptr, ev.data(), &rho[static_cast<std::size_t>(g)]);
                seen_blocks.push_back(&rho[static_cast<std::size_t>(g)]);
                seen_area.push_back(s.area);
            }
            if (lambda > 0.0) problem.AddResidualBlock(new TikhonovResidual(n, lambda), nullptr, ev.data());
            for (int k = 0; k < n; ++k) problem.SetParameterLowerBound(ev.data(), k, 0.0);
        }
        if (result.scale_from_prior && !seen_blocks.empty()) {
            // As strong as a typical group's residual scale.
            double lsum = 0.0;
            for (const GroupSums& s : groups) lsum += s.ll;
            problem.AddResidualBlock(new MeanAlbedoPrior(seen_area, p.prior_albedo, std::sqrt(std::max(lsum, 1e-300)) / p.prior_albedo),
                                     nullptr, seen_blocks);
        }
        for (double* block : seen_blocks) {
            problem.SetParameterLowerBound(block, 0, kMinAlbedo);
            problem.SetParameterUpperBound(block, 0, kMaxAlbedo);
        }
        if (problem.NumResidualBlocks() > 0) {
            ceres::Solver::Options options = solverOptions();
            options.max_num_iterations = 100;
            ceres::Solver::Summary summary;
            ceres::Solve(options, &problem, &summary);
            if (!summary.IsSolutionUsable()) return fail(ErrorCode::kInternal, "light fit: Ceres failed: " + summary.message);
            result.iterations = static_cast<int>(summary.iterations.size());
        }
        for (int k = 0; k < n; ++k) e(k) = std::max(0.0, ev[static_cast<std::size_t>(k)]);
    }
    // Step 3: the scale from the rows of known albedo alone. The other rows are nearly
    // indifferent to it (E -> t E, rho -> rho / t changes only how they weigh the interreflection
    // constants), and with thousands of them against a few tag rings they would otherwise set it
    // through any small bias of those constants.
    if (known.used && n > 0 && p.groups > 0) {
        const double ege = e.dot(known.g * e);
        if (ege > 0.0) {
            const double t = (e.dot(known.p) - e.dot(known.q)) / ege;
            if (t > 0.0 && std::isfinite(t)) {
                e *= t;
                for (double& r : rho) r = std::clamp(r / t, kMinAlbedo, kMaxAlbedo);
            }
        }
    }
    if (std::getenv("CL_FIT_DEBUG")) std::fprintf(stderr, "fit: n %d groups %d iterations %d\n", n, p.groups, result.iterations);
    result.emission.assign(e.data(), e.data() + n);
    result.group_albedo = rho;

    // Step 3: diagnostics at the solution.
    normal(m, v);
    double wsum = known.weight, lsum = known.ll;
    for (const GroupSums& s : groups) {
        wsum += s.weight;
        lsum += s.ll;
    }
    const double r2 = residual2(e);
    result.residual_rms = wsum > 0.0 ? std::sqrt(r2 / wsum) : 0.0;
    result.relative_residual = lsum > 0.0 ? std::sqrt(r2 / lsum) : 0.0;
    result.relative_error.assign(static_cast<std::size_t>(n), std::numeric_limits<double>::infinity());
    result.column_weight.assign(static_cast<std::size_t>(n), 0.0);
    result.indistinguishable_from.assign(static_cast<std::size_t>(n), -1);
    if (n > 0) {
        // Nearly parallel columns: cos = N_ij / sqrt(N_ii N_jj) of the weighted normal matrix.
        for (int a = 0; a < n; ++a) {
            double best = kIndistinguishableCosine;
            for (int b = 0; b < n; ++b) {
                if (a == b || !(m(a, a) > 0.0) || !(m(b, b) > 0.0)) continue;
                const double cosine = m(a, b) / std::sqrt(m(a, a) * m(b, b));
                if (cosine > best) {
                    best = cosine;
                    result.indistinguishable_from[static_cast<std::size_t>(a)] = b;
                }
            }
        }
        // cond(sqrt(W) A) = sqrt(cond(A^T W A)).
        const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(m);
        const double lmin = eig.eigenvalues().minCoeff(), lmax = eig.eigenvalues().maxCoeff();
        result.condition_number = lmin > 0.0 ? std::sqrt(lmax / lmin) : std::numeric_limits<double>::infinity();
        // The plain least-squares solution (no bound, no Tikhonov): its negative entries.
        const Eigen::VectorXd plain = m.completeOrthogonalDecomposition().solve(v);
        for (Eigen::Index k = 0; k < n; ++k) result.negative_in_plain_least_squares += plain(k) < 0.0 ? 1 : 0;
        const double dof = std::max(1.0, static_cast<double>(p.observations.size()) - n);
        Eigen::MatrixXd reg = m;
        reg.diagonal().array() += lambda;
        const Eigen::MatrixXd cov = (r2 / dof) * reg.completeOrthogonalDecomposition().pseudoInverse();
        for (int k = 0; k < n; ++k) {
            result.column_weight[static_cast<std::size_t>(k)] = std::sqrt(std::max(0.0, m(k, k)));
            if (e(k) > 0.0) result.relative_error[static_cast<std::size_t>(k)] = std::sqrt(std::max(0.0, cov(k, k))) / e(k);
        }
    }
    return result;
}

}  // namespace commonlight::lighting

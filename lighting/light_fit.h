// Fitting light emissions and reflectances to what the frames show (seed 001 sec. 4.3, seed 003
// sec. 5.3), one colour channel at a time.
//
// Each observation is a surface patch (a leaf element, or a tag's white border) with observed
// radiance L (relative units) and weight W (pixel weights). Its model, linear in the emissions
// E_k of the unknown sources and in its reflectance rho:
//     L = rho / pi * (sum_k E_k D_k + C)
// D_k the direct irradiance of source k at unit emission (lighting/direct.h), C the irradiance that
// does not depend on the unknowns: known lights' direct light and the indirect light gathered
// from the observed radiance of the other surfaces (inverse radiosity, seed 003 sec. 5.2: the
// interreflection is removed before the fit). Reflectances are one per group (a proxy object, per
// channel: a uniform material) or known (tags, albedos the scene gives).
//
// The problem is bilinear (rho x E). It is solved by alternating exact steps, each lowering the
// weighted squared residual: for fixed reflectances the emissions are a non-negative least
// squares problem with a small Tikhonov term (Ceres with lower bounds, on the n x n normal
// equations: the rows only enter through per-group sums, so thousands of observations cost no more
// than a handful); for fixed emissions each group's reflectance is a one-dimensional least squares
// problem, clamped to [0.005, 0.98]. Known albedos (tags) fix the overall scale that rho and E
// otherwise share; without any, the area-weighted mean of the groups' reflectances is held at
// `prior_albedo` and the result says so.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/result.h"

namespace commonlight::lighting {

struct FitObservation {
    double radiance = 0.0;        // L, relative radiance (one channel)
    double weight = 0.0;          // W > 0
    int group = -1;               // reflectance group; -1: `albedo` is known
    double albedo = 0.5;          // known reflectance (group -1)
    double area = 0.0;            // m^2 (the prior's area weighting)
    std::vector<double> columns;  // D_k, one per source
    double constant = 0.0;        // C
};

struct FitProblem {
    int sources = 0;
    int groups = 0;
    std::vector<FitObservation> observations;
    // Tikhonov weight relative to the mean diagonal of the weighted normal matrix: the fit minimises
    // sum W r^2 + tikhonov * mean(diag(A^T W A)) * |E|^2.
    double tikhonov = 1e-4;
    double prior_albedo = 0.5;
    std::vector<double> initial_group_albedo;  // optional start (size groups), else 0.5
    int max_iterations = 30;   // alternating steps (each exact); stops earlier when the residual settles
};

// Two light columns whose weighted cosine exceeds this are reported as indistinguishable.
inline constexpr double kIndistinguishableCosine = 0.999;

struct FitResult {
    std::vector<double> emission;        // per source, >= 0
    std::vector<double> group_albedo;    // per group, in [0.005, 0.98]
    std::vector<double> relative_error;  // per source: standard error / emission (from the residual; inf when 0)
    std::vector<double> column_weight;   // per source: sqrt of its column's weighted energy (how much it is seen)
    // Per source: another source whose weighted column is nearly parallel to its own (cosine above
    // kIndistinguishableCosine), so that what was observed fixes only their sum; -1 when none.
    std::vector<int> indistinguishable_from;
    double condition_number = 0.0;       // of the weighted design matrix at the solution's albedos
    double residual_rms = 0.0;           // weighted RMS of L - model, relative radiance
    double relative_residual = 0.0;      // residual_rms / weighted RMS of L
    int negative_in_plain_least_squares = 0;  // unconstrained LS solution's negative entries (diagnostic)
    bool scale_from_prior = false;       // no known albedo anchored the scale
    int iterations = 0;
};

// Solves one channel. Errors (kBadInput): no observation, sizes that do not match, non-finite input.
Result<FitResult> fitChannel(const FitProblem& problem);

// Non-negative least squares with Tikhonov regularisation: min |sqrt(W)(A x - b)|^2 + lambda |x|^2,
// x >= 0, by Ceres with lower bounds (Eigen 3.4 has no NNLS). Errors: sizes, non-finite input.
Result<Eigen::VectorXd> nnls(const Eigen::MatrixXd& a, const Eigen::VectorXd& b, const Eigen::VectorXd& weights,
                             double lambda);
// The same from the normal equations: min x^T (N + lambda I) x - 2 x^T v, x >= 0, with N = A^T W A
// (symmetric positive semi-definite) and v = A^T W b.
// `start` (optional, non-negative) warm-starts the solver.
Result<Eigen::VectorXd> nnlsNormal(const Eigen::MatrixXd& normal, const Eigen::VectorXd& v, double lambda,
                                   const Eigen::VectorXd* start = nullptr);

// sigma_max / sigma_min of a matrix (infinity when singular).
double conditionNumber(const Eigen::MatrixXd& a);

}  // namespace commonlight::lighting

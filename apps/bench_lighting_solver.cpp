// Case `solver` of `commonlight bench lighting`: the radiosity solve alone, with the true lights and
// albedos, on the room and the desk: element radiance against the path tracer, hierarchical against
// the uniform-grid gather, and the plot of solve time against error.
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <numbers>
#include <random>

#include "apps/bench_lighting.h"
#include "apps/bench_lighting_common.h"
#include "bench/lighting_eval.h"
#include "core/log.h"
#include "core/scene_io.h"
#include "lighting/estimator.h"
#include "mocks/sim/render.h"

namespace commonlight::apps {

namespace fs = std::filesystem;

namespace {

using namespace bench_common;
using lighting::Estimator;
using lighting::EstimatorOptions;
using lighting::Mode;

// One configuration of the solver case: the mesh and the link oracle.
struct SolverConfig {
    const char* scene;
    bool hierarchical;
    double size;            // initial element size, metres (uniform: the grid)
    double link_epsilon;    // RadiosityOptions::link_epsilon
    double min_link_size;   // RadiosityOptions::min_link_size
    double source_epsilon;  // RadiosityOptions::source_epsilon
};

struct SolverPoint {
    SolverConfig config;
    std::string scene;
    bool hierarchical = true;
    int leaves = 0;
    int links = 0;
    int iterations = 0;
    double setup_ms = 0.0;  // direct-light columns, link refinement, form factors and visibility
    double solve_ms = 0.0;  // the solve alone (links built): Jacobi gathers to the residual, best of 3
    double rms_pct = 0.0;   // element radiance against the path tracer
    double max_pct = 0.0;
    double mean_pct = 0.0;  // area-weighted mean signed error over the mean truth
    double truth_noise_pct = 0.0;  // the truth's own RMS noise, same normalisation
    double net_rms_pct = 0.0;      // sqrt(rms^2 - truth noise^2)
};

Result<SolverPoint> solverPoint(const Scene& truth, const CameraModel& camera, const SolverConfig& c, const fs::path& csv_dir) {
    EstimatorOptions eo;
    eo.refine_unobserved = true;
    eo.refine_by_light = false;  // element averages are what is compared: no texture detail needed
    eo.initial_element_size = c.size;
    eo.radiosity.hierarchical = c.hierarchical;
    eo.radiosity.link_epsilon = c.link_epsilon;
    eo.radiosity.min_link_size = c.hierarchical ? c.min_link_size : c.size;
    eo.radiosity.source_epsilon = c.source_epsilon;
    // The real scene alone (what the path tracer's truth below is of): with the scene's virtual
    // objects the influence would split leaves under them that the base solution does not cover.
    Scene real = truth;
    real.virtual_objects.clear();
    CL_TRY(std::unique_ptr<Estimator> est, Estimator::create(real, camera, {}, eo));
    std::vector<Eigen::Vector3d> emission, albedo;
    for (const Light& l : real.lights) emission.push_back(*l.emission.value);
    for (const RealObject& r : real.real_objects) albedo.push_back(*r.albedo.value);
    CL_TRY_VOID(est->solveWith(emission, albedo, lighting::SceneLighting::scenePoses(real, 0.0)));
    SolverPoint p;
    p.config = c;
    p.scene = c.scene;
    p.hierarchical = c.hierarchical;
    const auto& rad = est->radiosity();
    const std::vector<int> leaves = rad.leaves(Mode::kReal);
    p.leaves = static_cast<int>(leaves.size());
    p.links = rad.linkCount(Mode::kReal);
    p.setup_ms = est->stats().ms_links + est->stats().ms_columns;
    {
        // The solve alone: the real scene's system again, from the first estimate (emission and
        // reflected direct light) to the residual, as a full update solves it. Best of three.
        const auto n = rad.hierarchy().elements().size();
        std::vector<Eigen::Vector3d> rho(n, Eigen::Vector3d::Zero()), le(n, Eigen::Vector3d::Zero());
        // (The solution's vectors cover the elements it was solved for; the hierarchy may hold more
        // since, made by the influence: they take no direct light here.)
        std::vector<Eigen::Vector3d> direct = est->without().irradiance;
        direct.resize(n, Eigen::Vector3d::Zero());
        const std::vector<Eigen::Vector3d>& indirect = est->without().indirect;
        for (std::size_t e = 0; e < n; ++e) {
            rho[e] = est->reflectance().size() == n ? est->reflectance()[e] : Eigen::Vector3d::Constant(0.5);
            if (e < indirect.size()) direct[e] -= indirect[e];
        }
        p.solve_ms = 1e300;
        for (int k = 0; k < 3; ++k) {
            const auto t0 = std::chrono::steady_clock::now();
            const lighting::Solution again = rad.solve(Mode::kReal, rho, le, direct);
            p.solve_ms = std::min(p.solve_ms, std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
            p.iterations = again.summary.iterations;
        }
    }
    // The truth on every leaf up to 1000 (else a deterministic subset of about 1000, every k-th),
    // area-weighted: 32 stratified points per element, 128 paths each (the truth's own noise is
    // about 0.7% RMS). Fewer leaves made the figure depend on which few dark elements in a gap or
    // behind the ceiling panel happened to be picked (measured: 1.5% and 1.9% for meshes of 952
    // and 944 leaves of the same configuration with 300 picked).
    std::vector<int> pick;
    const std::size_t step = std::max<std::size_t>(1, (leaves.size() + 999) / 1000);
    for (std::size_t i = 0; i < leaves.size(); i += step) pick.push_back(leaves[i]);
    // Two independent halves (64 points x 32 paths each, other seeds): their mean is the truth, and
    // half their difference is the truth's own noise (spatial as well as Monte Carlo: an element in
    // a lamp's pool next to a shadow needs many points).
    CL_TRY(std::vector<Eigen::Vector3d> truth_a, bench::truthOfLeaves(truth, *est, pick, false, 64, 32, 11));
    CL_TRY(std::vector<Eigen::Vector3d> truth_b, bench::truthOfLeaves(truth, *est, pick, false, 64, 32, 23));
    std::vector<Eigen::Vector3d> truth_l(pick.size());
    for (std::size_t k = 0; k < pick.size(); ++k) truth_l[k] = 0.5 * (truth_a[k] + truth_b[k]);
    // RMS of the difference over RMS of the truth (area-weighted): the relative error of the
    // solution as a whole, not dominated by nearly black elements; the max relative error over
    // elements brighter than a tenth of the mean.
    double se = 0.0, st = 0.0, area = 0.0, mean = 0.0, signed_sum = 0.0, noise = 0.0;
    for (std::size_t k = 0; k < pick.size(); ++k) {
        const double a = rad.hierarchy()[pick[k]].area * rad.exposure(pick[k]);
        mean += a * luma(truth_l[k]);
        area += a;
    }
    mean = area > 0.0 ? mean / area : 0.0;
    for (std::size_t k = 0; k < pick.size(); ++k) {
        const double t = luma(truth_l[k]);
        const double d = luma(est->without().radiance[static_cast<std::size_t>(pick[k])]) - t;
        const double a = rad.hierarchy()[pick[k]].area * rad.exposure(pick[k]);
        se += a * d * d;
        st += a * t * t;
        signed_sum += a * d;
        const double half = 0.5 * (luma(truth_a[k]) - luma(truth_b[k]));
        noise += a * half * half;
        if (t > 0.1 * mean) p.max_pct = std::max(p.max_pct, 100.0 * std::abs(d) / t);
    }
    p.rms_pct = st > 0.0 ? 100.0 * std::sqrt(se / st) : 0.0;
    p.truth_noise_pct = st > 0.0 ? 100.0 * std::sqrt(noise / st) : 0.0;
    // The model's own error: the truth's noise is independent of it and adds in quadrature.
    p.net_rms_pct = std::sqrt(std::max(0.0, p.rms_pct * p.rms_pct - p.truth_noise_pct * p.truth_noise_pct));
    p.mean_pct = area > 0.0 && mean > 0.0 ? 100.0 * signed_sum / area / mean : 0.0;
    if (!csv_dir.empty()) {
        // Per element, for finding where the error sits: the truth again with direct light only
        // (max_depth 1), and the model's direct part (reflectance x direct irradiance / pi).
        CL_TRY(std::vector<Eigen::Vector3d> truth_direct, bench::truthOfLeaves(truth, *est, pick, false, 32, 32, 12, 1));
        std::error_code ec;
        fs::create_directories(csv_dir, ec);
        const fs::path file = csv_dir / ("solver-" + p.scene + "-" + (p.hierarchical ? "hierarchical" : "uniform") + "-" +
                                         std::to_string(p.leaves) + ".csv");
        FILE* f = std::fopen(file.c_str(), "w");
        if (!f) return fail(ErrorCode::kBadInput, file.string() + ": cannot write");
        std::fprintf(f, "element,object,face,cx,cy,cz,size_s,size_t,area,exposure,truth,model,truth_direct,model_direct\n");
        for (std::size_t k = 0; k < pick.size(); ++k) {
            const auto i = static_cast<std::size_t>(pick[k]);
            const lighting::Element& el = rad.hierarchy()[pick[k]];
            const lighting::Face& face = rad.face(el.face);
            const lighting::ElementGeometry g = rad.geometry(pick[k]);
            const Eigen::Vector3d model_direct =
                est->reflectance()[i].cwiseProduct(est->without().irradiance[i] - est->without().indirect[i]) / M_PI;
            std::fprintf(f, "%d,%s,%d,%.4f,%.4f,%.4f,%.4f,%.4f,%.6f,%.3f,%.6f,%.6f,%.6f,%.6f\n", pick[k],
                         truth.real_objects[static_cast<std::size_t>(face.object_index)].name.c_str(), face.face_index, g.centroid.x(),
                         g.centroid.y(), g.centroid.z(), el.size_s, el.size_t_, el.area, rad.exposure(pick[k]), luma(truth_l[k]),
                         luma(est->without().radiance[i]), luma(truth_direct[k]), luma(model_direct));
        }
        std::fclose(f);
    }
    return p;
}

void drawSolverPlot(const std::vector<SolverPoint>& points, const fs::path& file) {
    const int w = 900, h = 560, left = 80, right = 30, top = 40, bottom = 60;
    cv::Mat img(h, w, CV_8UC3, cv::Scalar(255, 255, 255));
    double max_ms = 1.0, max_err = 1.0;
    for (const auto& p : points) {
        max_ms = std::max(max_ms, p.solve_ms);
        max_err = std::max(max_err, p.rms_pct);
    }
    max_ms *= 1.5;
    max_err *= 1.15;
    // Log scale in time: the baseline is orders of magnitude slower.
    const double lmin = std::log10(0.5), lmax = std::log10(max_ms);
    const auto X = [&](double ms) { return left + static_cast<int>((w - left - right) * (std::log10(std::max(ms, 0.5)) - lmin) / (lmax - lmin)); };
    const auto Y = [&](double e) { return h - bottom - static_cast<int>((h - top - bottom) * e / max_err); };
    const cv::Scalar black(0, 0, 0), grey(210, 210, 210), red(40, 40, 200);
    for (double ms = 1.0; ms <= max_ms; ms *= 10.0) {
        cv::line(img, {X(ms), top}, {X(ms), h - bottom}, grey);
        cv::putText(img, fmt(ms, "%.0f"), {X(ms) - 10, h - bottom + 20}, cv::FONT_HERSHEY_SIMPLEX, 0.45, black);
    }
    for (int k = 0; k <= 5; ++k) {
        const double e = max_err * k / 5;
        cv::line(img, {left, Y(e)}, {w - right, Y(e)}, grey);
        cv::putText(img, fmt(e, "%.1f"), {10, Y(e) + 5}, cv::FONT_HERSHEY_SIMPLEX, 0.45, black);
    }
    // The targets: 2% RMS, 50 ms.
    if (2.0 < max_err) cv::line(img, {left, Y(2.0)}, {w - right, Y(2.0)}, red);
    if (50.0 < max_ms) cv::line(img, {X(50.0), top}, {X(50.0), h - bottom}, red);
    cv::rectangle(img, {left, top}, {w - right, h - bottom}, black);
    cv::putText(img, "solve ms (links built; log scale)   red: 2% RMS and 50 ms targets", {left + 120, h - 15},
                cv::FONT_HERSHEY_SIMPLEX, 0.55, black);
    cv::putText(img, "element radiance vs path tracer, RMS %   (circle: hierarchical, square: uniform gather)", {left, 25},
                cv::FONT_HERSHEY_SIMPLEX, 0.5, black);
    const cv::Scalar colours[] = {{200, 60, 20}, {20, 120, 220}};
    std::map<std::string, int> scene_colour;
    for (const auto& p : points) {
        const int ci = scene_colour.emplace(p.scene, static_cast<int>(scene_colour.size())).first->second % 2;
        const cv::Point at(X(p.solve_ms), Y(p.rms_pct));
        if (p.hierarchical) {
            cv::circle(img, at, 6, colours[ci], cv::FILLED);
        } else {
            cv::rectangle(img, at - cv::Point(5, 5), at + cv::Point(5, 5), colours[ci], cv::FILLED);
        }
        // Labels to the left of points near the right edge, so that none is cut off.
        const std::string label = p.scene + " " + std::to_string(p.leaves);
        const int width = cv::getTextSize(label, cv::FONT_HERSHEY_SIMPLEX, 0.4, 1, nullptr).width;
        const cv::Point offset = at.x + 8 + width > w - right ? cv::Point(-8 - width, -6) : cv::Point(8, -6);
        cv::putText(img, label, at + offset, cv::FONT_HERSHEY_SIMPLEX, 0.4, colours[ci]);
    }
    cv::imwrite(file.string(), img);
}

Result<nlohmann::json> caseSolver(const BenchLightingOptions& o, std::vector<SolverPoint>& points) {
    const fs::path scenes = o.source_dir / "data/scenes";
    std::printf("\nradiosity solve with the true lights and albedos: element radiance against the path tracer\n"
                "  (RMS %%: area-weighted RMS of the difference over RMS of the truth, every element up to 1000; net: less the\n"
                "   truth's own noise in quadrature; mean %%: signed, over the mean truth;\n"
                "   max %%: over elements brighter than a tenth of the mean; setup: direct light, links, form factors,\n"
                "   visibility; solve: the iterations alone, best of 3)\n");
    std::printf("  %-6s %-13s %-6s %-7s %-6s %-8s %-9s %-9s %-6s %-10s %-9s %s\n", "scene", "method", "size", "eps", "minlk", "src eps",
                "elements", "links", "iter", "setup ms", "solve ms", "RMS % (net of truth noise) / mean % / max % / truth noise %");
    nlohmann::json rows = nlohmann::json::array();
    const std::vector<SolverConfig> configs{
        {"room", true, 1.0, 0.01, 0.3, 0.0005},    {"room", true, 0.63, 0.01, 0.3, 0.0005}, {"room", true, 0.63, 0.01, 0.3, 0.0002},
        {"room", true, 0.63, 0.005, 0.15, 0.0005}, {"room", false, 0.63, 0, 0, 0},          {"room", false, 0.4, 0, 0, 0},
        {"room", false, 0.3, 0, 0, 0},             {"desk", true, 0.5, 0.01, 0.3, 0.0005},  {"desk", true, 0.5, 0.005, 0.15, 0.0005},
        {"desk", false, 0.5, 0, 0, 0},             {"desk", false, 0.3, 0, 0, 0},
    };
    for (const SolverConfig& c : configs) {
        CL_TRY(Scene truth, readScene(scenes / c.scene / "scene.yaml"));
        const CameraModel camera = truth.camera->scaledTo(160, 120);
        CL_TRY(SolverPoint p, solverPoint(truth, camera, c, o.solver_csv));
        const auto eps = [&](double v, const char* f) { return c.hierarchical ? fmt(v, f) : std::string("-"); };
        std::printf("  %-6s %-13s %-6s %-7s %-6s %-8s %-9d %-9d %-6d %-10s %-9s %s (%s) / %s / %s / %s\n", c.scene,
                    c.hierarchical ? "hierarchical" : "uniform", fmt(c.size).c_str(), eps(c.link_epsilon, "%.3f").c_str(),
                    eps(c.min_link_size, "%.2f").c_str(), eps(c.source_epsilon, "%.4f").c_str(), p.leaves, p.links, p.iterations,
                    fmt(p.setup_ms, "%.0f").c_str(), fmt(p.solve_ms, "%.1f").c_str(), fmt(p.rms_pct).c_str(), fmt(p.net_rms_pct).c_str(),
                    fmt(p.mean_pct, "%+.2f").c_str(), fmt(p.max_pct, "%.1f").c_str(), fmt(p.truth_noise_pct).c_str());
        std::fflush(stdout);
        nlohmann::json row{{"scene", p.scene}, {"method", p.hierarchical ? "hierarchical" : "uniform"}, {"element_size", c.size},
                           {"elements", p.leaves}, {"links", p.links}, {"iterations", p.iterations}, {"setup_ms", p.setup_ms},
                           {"solve_ms", p.solve_ms}, {"rms_pct", p.rms_pct}, {"net_rms_pct", p.net_rms_pct}, {"truth_noise_pct", p.truth_noise_pct}, {"mean_signed_pct", p.mean_pct}, {"max_pct", p.max_pct}};
        if (c.hierarchical) {
            row["link_epsilon"] = c.link_epsilon;
            row["min_link_size"] = c.min_link_size;
            row["source_epsilon"] = c.source_epsilon;
        }
        rows.push_back(row);
        points.push_back(p);
    }
    // The comparison, hierarchical against the uniform gather at equal error: the uniform
    // grids whose errors bracket the hierarchical one's. Against the one with a larger error the
    // speed-up is a lower bound (the uniform gather is both less accurate and slower); where both
    // exist, the uniform gather's time at exactly that error is interpolated (log time against error).
    nlohmann::json comparison = nlohmann::json::array();
    for (const SolverPoint& h : points) {
        if (!h.hierarchical) continue;
        const SolverPoint *worse = nullptr, *better = nullptr;
        for (const SolverPoint& q : points) {
            if (q.hierarchical || q.scene != h.scene) continue;
            if (q.rms_pct >= h.rms_pct && (!worse || q.rms_pct < worse->rms_pct)) worse = &q;
            if (q.rms_pct < h.rms_pct && (!better || q.rms_pct > better->rms_pct)) better = &q;
        }
        if (!worse) {
            std::printf("  %s hierarchical %d elements (%.2f%%): every uniform gather measured is more accurate\n", h.scene.c_str(), h.leaves,
                        h.rms_pct);
            continue;
        }
        const double solve_x = worse->solve_ms / h.solve_ms, total_x = (worse->setup_ms + worse->solve_ms) / (h.setup_ms + h.solve_ms);
        nlohmann::json row{{"scene", h.scene}, {"hierarchical_elements", h.leaves}, {"hierarchical_rms_pct", h.rms_pct},
                           {"uniform_elements", worse->leaves}, {"uniform_rms_pct", worse->rms_pct}, {"solve_speedup_at_least", solve_x},
                           {"setup_and_solve_speedup_at_least", total_x}};
        std::string line = fmt(solve_x, "%.1f") + "x faster solve, " + fmt(total_x, "%.1f") + "x setup + solve, than uniform " +
                           std::to_string(worse->leaves) + " (" + fmt(worse->rms_pct) + "%)";
        if (better && worse->rms_pct > better->rms_pct) {
            const double t = (worse->rms_pct - h.rms_pct) / (worse->rms_pct - better->rms_pct);
            const auto at = [&](double a, double b) { return std::exp(std::log(a) + t * (std::log(b) - std::log(a))); };
            const double solve_i = at(worse->solve_ms, better->solve_ms) / h.solve_ms;
            const double total_i = at(worse->setup_ms + worse->solve_ms, better->setup_ms + better->solve_ms) / (h.setup_ms + h.solve_ms);
            row["solve_speedup_interpolated"] = solve_i;
            row["setup_and_solve_speedup_interpolated"] = total_i;
            line += "; at equal error (interpolated with uniform " + std::to_string(better->leaves) + "): " + fmt(solve_i, "%.0f") +
                    "x solve, " + fmt(total_i, "%.1f") + "x setup + solve";
        }
        std::printf("  %s hierarchical %d elements (%.2f%%): %s\n", h.scene.c_str(), h.leaves, h.rms_pct, line.c_str());
        comparison.push_back(row);
    }
    return nlohmann::json{{"rows", rows}, {"hierarchical_vs_uniform", comparison}};
}


}  // namespace

Result<nlohmann::json> runSolverCase(const BenchLightingOptions& options, const std::string& plot) {
    std::vector<SolverPoint> points;
    CL_TRY(nlohmann::json result, caseSolver(options, points));
    if (!plot.empty() && !points.empty()) {
        drawSolverPlot(points, plot);
        std::printf("\nplot: %s\n", plot.c_str());
    }
    return result;
}

}  // namespace commonlight::apps

#include "tracking/edge_refine.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <limits>
#include <sstream>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "tracking/se3_jacobians.h"
#include "tracking/option_checks.h"

namespace commonlight::tracking {
namespace {

using Eigen::Vector2d;
using Eigen::Vector3d;
using RowVector6d = Eigen::Matrix<double, 1, 6>;

constexpr double kNearZ = 0.02;  // metres: edges are clipped to points at least this far in front of the camera

// One level of the image pyramid: the gradient of the blurred image, in grey levels per pixel of
// this level.
struct Level {
    // CV_32F each, d/dx and d/dy as cv::Sobel writes them: interleaving them for the bilinear
    // samples cost a pass over 2.4 MB per frame at 640x480 and another buffer that evicted the
    // detector's data from the caches (docs/tracking.md, "Speed (issue 13)").
    cv::Mat gx, gy;
    double scale = 1.0;  // this level's pixels per full-resolution pixel (2^-level)
};

// Bilinear sample of both gradient components at (x, y) (pixel centres at integers); false outside.
bool sampleGradient(const Level& level, double x, double y, double& gx, double& gy) {
    if (!(x >= 0.0 && y >= 0.0 && x <= level.gx.cols - 1.0 && y <= level.gx.rows - 1.0)) return false;
    const int x0 = std::min(static_cast<int>(x), level.gx.cols - 2);
    const int y0 = std::min(static_cast<int>(y), level.gx.rows - 2);
    const double ax = x - x0;
    const double ay = y - y0;
    const auto lerp = [&](const cv::Mat& g) {
        const float* r0 = g.ptr<float>(y0) + x0;
        const float* r1 = g.ptr<float>(y0 + 1) + x0;
        const double top = (1.0 - ax) * r0[0] + ax * r0[1];
        const double bottom = (1.0 - ax) * r1[0] + ax * r1[1];
        return (1.0 - ay) * top + ay * bottom;
    };
    gx = lerp(level.gx);
    gy = lerp(level.gy);
    return true;
}

// How many levels buildPyramid makes for an image of this size.
int pyramidLevelCount(int width, int height, const EdgeRefineOptions& options) {
    int levels = 0;
    for (int l = 0; l < options.pyramid_levels; ++l) {
        if (l > 0 && std::min(width, height) < 64) break;
        ++levels;
        width = (width + 1) / 2;  // cv::pyrDown's size
        height = (height + 1) / 2;
    }
    return levels;
}

// The pyramid's buffers, kept between calls on a thread: allocated afresh, a 640x480 pyramid is
// megabytes of new pages per call, whose page faults and unmapping cost about as much as the
// filters (desk: the refinement 6.8 -> 4.4 ms CPU per frame; docs/tracking.md, "Speed").
struct PyramidBuffers {
    std::vector<cv::Mat> images;  // the blurred image per level (level 0: converted to float, blurred in place)
    std::vector<Level> levels;
};

// The levels 0..max_level (those the refinement will use). Valid until the next call on the
// same thread.
const std::vector<Level>& buildPyramid(const ImageView& gray8, const EdgeRefineOptions& options, int max_level) {
    thread_local PyramidBuffers b;
    // The view's rows may be padded: wrap them without copying (OpenCV does not write to it).
    const cv::Mat view(gray8.height, gray8.width, CV_8UC1, const_cast<std::uint8_t*>(gray8.data), gray8.stride);
    // Hard case: a small image; no level too small to hold an edge profile (pyramidLevelCount).
    const auto count =
        static_cast<std::size_t>(std::min(max_level + 1, pyramidLevelCount(gray8.width, gray8.height, options)));
    b.images.resize(count);
    b.levels.resize(count);
    view.convertTo(b.images[0], CV_32F);
    // In place (OpenCV's separable filters support it): one float image less to keep in the caches.
    if (options.blur_sigma_px > 0.0) cv::GaussianBlur(b.images[0], b.images[0], cv::Size(0, 0), options.blur_sigma_px);
    for (std::size_t l = 0; l < count; ++l) {
        // pyrDown keeps the even pixels of the blurred image: level pixel i is centred on pixel
        // 2i of the level below, so coordinates simply halve in the OpenCV pixel convention.
        if (l > 0) cv::pyrDown(b.images[l - 1], b.images[l]);
        Level& level = b.levels[l];
        level.scale = std::ldexp(1.0, -static_cast<int>(l));
        cv::Sobel(b.images[l], level.gx, CV_32F, 1, 0, 3, 1.0 / 8.0);
        cv::Sobel(b.images[l], level.gy, CV_32F, 0, 1, 3, 1.0 / 8.0);
    }
    return b.levels;
}

// Jacobian of CameraModel::project (distorted pixels) with respect to the point in the camera frame.
Eigen::Matrix<double, 2, 3> projectionJacobian(const CameraModel& camera, const Vector3d& p) {
    const double inv_z = 1.0 / p.z();
    const double x = p.x() * inv_z;
    const double y = p.y() * inv_z;
    const Distortion& d = camera.distortion;
    const double r2 = x * x + y * y;
    const double radial = 1.0 + r2 * (d.k1 + r2 * (d.k2 + r2 * d.k3));
    const double dradial = d.k1 + r2 * (2.0 * d.k2 + 3.0 * r2 * d.k3);  // d radial / d r2
    Eigen::Matrix2d jd;
    jd(0, 0) = radial + 2.0 * x * x * dradial + 2.0 * d.p1 * y + 6.0 * d.p2 * x;
    jd(0, 1) = 2.0 * x * y * dradial + 2.0 * d.p1 * x + 2.0 * d.p2 * y;
    jd(1, 0) = 2.0 * x * y * dradial + 2.0 * d.p1 * x + 2.0 * d.p2 * y;
    jd(1, 1) = radial + 2.0 * y * y * dradial + 6.0 * d.p1 * y + 2.0 * d.p2 * x;
    Eigen::Matrix<double, 2, 3> jn;
    jn << inv_z, 0.0, -x * inv_z, 0.0, inv_z, -y * inv_z;
    const Eigen::Matrix2d f = Eigen::Vector2d(camera.fx, camera.fy).asDiagonal();
    return f * jd * jn;
}

// The undistorted (normalised) field of view: a box that holds the rays of every pixel on the
// image border, grown by 5 %. Used to clip edges before sampling them.
struct FieldOfView {
    double x_min = -1, x_max = 1, y_min = -1, y_max = 1;
};

FieldOfView fieldOfView(const CameraModel& camera) {
    FieldOfView fov{std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity(),
                    std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity()};
    const auto add = [&](double u, double v) {
        const auto ray = camera.unproject({u, v});
        if (!ray) return;
        fov.x_min = std::min(fov.x_min, ray->x());
        fov.x_max = std::max(fov.x_max, ray->x());
        fov.y_min = std::min(fov.y_min, ray->y());
        fov.y_max = std::max(fov.y_max, ray->y());
    };
    const double right = camera.width - 0.5;
    const double bottom = camera.height - 0.5;
    for (double u = -0.5; u <= right; u += 8.0) {
        add(u, -0.5);
        add(u, bottom);
    }
    for (double v = -0.5; v <= bottom; v += 8.0) {
        add(-0.5, v);
        add(right, v);
    }
    add(right, bottom);
    // Hard case: a lens model that cannot unproject its own border (beyond the fold): fall back to
    // a 160-degree field; points are still checked one by one against the image.
    if (!(fov.x_min < fov.x_max && fov.y_min < fov.y_max)) return {-6, 6, -6, 6};
    const double gx = 0.05 * (fov.x_max - fov.x_min);
    const double gy = 0.05 * (fov.y_max - fov.y_min);
    return {fov.x_min - gx, fov.x_max + gx, fov.y_min - gy, fov.y_max + gy};
}

// Clips the segment a-b (camera frame) to the field of view and z >= kNearZ (Liang-Barsky on the
// half-spaces m . p + c >= 0). Returns the parameter range [t0, t1] of a + t (b - a).
std::optional<std::pair<double, double>> clipToView(const Vector3d& a, const Vector3d& b, const FieldOfView& fov) {
    struct HalfSpace {
        Vector3d m;
        double c;
    };
    const std::array<HalfSpace, 5> planes = {HalfSpace{{0, 0, 1}, -kNearZ}, HalfSpace{{1, 0, -fov.x_min}, 0},
                                             HalfSpace{{-1, 0, fov.x_max}, 0}, HalfSpace{{0, 1, -fov.y_min}, 0},
                                             HalfSpace{{0, -1, fov.y_max}, 0}};
    double t0 = 0.0;
    double t1 = 1.0;
    for (const HalfSpace& h : planes) {
        const double fa = h.m.dot(a) + h.c;
        const double fb = h.m.dot(b) + h.c;
        if (fa < 0.0 && fb < 0.0) return std::nullopt;
        if (fa < 0.0) t0 = std::max(t0, fa / (fa - fb));
        if (fb < 0.0) t1 = std::min(t1, fa / (fa - fb));
        if (t0 >= t1) return std::nullopt;
    }
    return std::make_pair(t0, t1);
}

// A point on a model edge, with what the search and the solver need.
struct Sample {
    Vector3d p_in_world = Vector3d::Zero();
    Vector2d pixel = Vector2d::Zero();    // projection at the pose it was sampled with, full-resolution pixels
    Vector2d normal = Vector2d::UnitX();  // unit normal of the projected edge there
    int edge = -1;
    int object = -1;
    double depth = 0.0;
    // Search results.
    double best_positive = 0.0, t_positive = 0.0;  // strongest gradient along +normal and its offset
    double best_negative = 0.0, t_negative = 0.0;  // strongest along -normal (as a positive value)
    bool matched = false;
    Vector2d match = Vector2d::Zero();  // full-resolution pixels
    double strength = 0.0;              // gradient at the match
};

// Step 1: visible sample points along the edges.
void sampleEdges(const EdgeModel& model, const CameraModel& camera, const FieldOfView& fov,
                 const Rigid3d& cam_from_world, const EdgeRefineOptions& options, std::vector<Sample>& samples) {
    samples.clear();
    const Vector3d centre = cam_from_world.inverse().translation;
    const auto edges = model.edges();
    // Hard case: a plane seen exactly edge-on (sin of 1 degree) shows no edge.
    constexpr double kEdgeOnSine = 0.017;
    for (std::size_t e = 0; e < edges.size(); ++e) {
        const ModelEdge& edge = edges[e];
        const Vector3d a = cam_from_world * edge.a_in_world;
        const Vector3d b = cam_from_world * edge.b_in_world;
        const auto clipped = clipToView(a, b, fov);
        if (!clipped) continue;
        const Vector3d a_cam = a + clipped->first * (b - a);
        const Vector3d b_cam = a + clipped->second * (b - a);
        const Vector3d a_world = edge.a_in_world + clipped->first * (edge.b_in_world - edge.a_in_world);
        const Vector3d b_world = edge.a_in_world + clipped->second * (edge.b_in_world - edge.a_in_world);
        // Pinhole length of the clipped segment: enough to choose the number of samples.
        const Vector2d pa(camera.fx * a_cam.x() / a_cam.z(), camera.fy * a_cam.y() / a_cam.z());
        const Vector2d pb(camera.fx * b_cam.x() / b_cam.z(), camera.fy * b_cam.y() / b_cam.z());
        const double length_px = (pb - pa).norm();
        if (!(length_px >= 2.0)) continue;
        const int n = std::clamp(static_cast<int>(length_px / options.sample_spacing_px), 1, 4000);
        const Vector3d direction_cam = (b_cam - a_cam).normalized();
        for (int k = 0; k < n; ++k) {
            // Evenly spaced in the image: perspective-correct parameter along the 3D segment.
            const double s = (k + 0.5) / n;
            const double t = s * a_cam.z() / ((1.0 - s) * b_cam.z() + s * a_cam.z());
            const Vector3d p_world = a_world + t * (b_world - a_world);
            const Vector3d p_cam = a_cam + t * (b_cam - a_cam);
            // Facing: an edge is seen when one of its faces looks at the camera (a silhouette
            // edge has one front and one back face). A boundary edge of a plane or an open mesh
            // is a sheet's edge, seen from either side unless exactly edge-on.
            const Vector3d view = (centre - p_world).normalized();
            const double f0 = edge.normal0.dot(view);
            if (edge.hasTwoFaces()) {
                if (f0 <= 0.0 && edge.normal1.dot(view) <= 0.0) continue;
            } else if (std::abs(f0) < kEdgeOnSine) {
                continue;
            }
            const auto pixel = camera.project(p_cam);
            if (!pixel || !camera.inImage(*pixel, options.image_margin_px)) continue;
            const auto ahead = camera.project(p_cam + 1e-3 * p_cam.z() * direction_cam);
            if (!ahead) continue;
            const Vector2d d = *ahead - *pixel;
            if (!(d.norm() > 1e-9)) continue;  // the edge points at the camera
            if (model.occluded(centre, p_world, options.occlusion_epsilon)) continue;
            Sample sample;
            sample.p_in_world = p_world;
            sample.pixel = *pixel;
            sample.normal = Vector2d(-d.y(), d.x()).normalized();
            sample.edge = static_cast<int>(e);
            sample.object = edge.object;
            sample.depth = p_cam.z();
            samples.push_back(sample);
        }
    }
}

// Step 2: the strongest gradient along each sample's normal, one polarity per edge.
void searchEdges(const Level& level, const EdgeRefineOptions& options, std::vector<Sample>& samples) {
    constexpr double kStep = 0.5;  // level pixels between profile samples
    const int half = static_cast<int>(std::floor(options.search_px / kStep));
    std::vector<double> profile(static_cast<std::size_t>(2 * half + 1));
    // Sub-pixel peak of the profile (sign +1 or -1) at index i by a parabola through i-1, i, i+1.
    const auto refine = [&](int i, double sign) {
        const double gm = sign * profile[static_cast<std::size_t>(i - 1)];
        const double g0 = sign * profile[static_cast<std::size_t>(i)];
        const double gp = sign * profile[static_cast<std::size_t>(i + 1)];
        const double denominator = gm - 2.0 * g0 + gp;
        const double offset = denominator < 0.0 ? std::clamp(0.5 * (gm - gp) / denominator, -0.5, 0.5) : 0.0;
        return ((i - half) + offset) * kStep;
    };
    for (Sample& s : samples) {
        s.best_positive = s.best_negative = 0.0;
        s.matched = false;
        const Vector2d q0 = s.pixel * level.scale;
        for (int i = -half; i <= half; ++i) {
            const double t = i * kStep;
            double gx = 0.0, gy = 0.0;
            const bool inside = sampleGradient(level, q0.x() + t * s.normal.x(), q0.y() + t * s.normal.y(), gx, gy);
            profile[static_cast<std::size_t>(i + half)] = inside ? gx * s.normal.x() + gy * s.normal.y() : 0.0;
        }
        // Maxima on the ends of the range are cut-off slopes, not edges: interior ones only.
        int best_p = -1;
        int best_n = -1;
        for (int i = 1; i < 2 * half; ++i) {
            const double g = profile[static_cast<std::size_t>(i)];
            if (g > profile[static_cast<std::size_t>(i - 1)] && g >= profile[static_cast<std::size_t>(i + 1)] &&
                (best_p < 0 || g > profile[static_cast<std::size_t>(best_p)])) {
                best_p = i;
            }
            if (g < profile[static_cast<std::size_t>(i - 1)] && g <= profile[static_cast<std::size_t>(i + 1)] &&
                (best_n < 0 || g < profile[static_cast<std::size_t>(best_n)])) {
                best_n = i;
            }
        }
        if (best_p >= 0) {
            s.best_positive = profile[static_cast<std::size_t>(best_p)];
            s.t_positive = refine(best_p, 1.0);
        }
        if (best_n >= 0) {
            s.best_negative = -profile[static_cast<std::size_t>(best_n)];
            s.t_negative = refine(best_n, -1.0);
        }
    }
    // Polarity: the edge's brighter side is the same along the whole edge (one surface against
    // another); take the sign whose strongest gradients add up to more over the edge.
    int edges = 0;
    for (const Sample& s : samples) edges = std::max(edges, s.edge + 1);
    std::vector<double> vote(static_cast<std::size_t>(edges), 0.0);
    for (const Sample& s : samples) {
        const double signed_best = s.best_positive >= s.best_negative ? s.best_positive : -s.best_negative;
        vote[static_cast<std::size_t>(s.edge)] += signed_best;
    }
    for (Sample& s : samples) {
        const bool positive = vote[static_cast<std::size_t>(s.edge)] >= 0.0;
        const double strength = positive ? s.best_positive : s.best_negative;
        if (strength < options.min_gradient) continue;
        const double t = positive ? s.t_positive : s.t_negative;
        s.matched = true;
        s.strength = strength;
        s.match = s.pixel + (t / level.scale) * s.normal;
    }
}

double tukeyWeight(double r, double c) {
    if (std::abs(r) >= c) return 0.0;
    const double u = 1.0 - (r / c) * (r / c);
    return u * u;
}

double tukeyRho(double r, double c) {
    const double c2 = c * c / 6.0;
    if (std::abs(r) >= c) return c2;
    const double u = 1.0 - (r / c) * (r / c);
    return c2 * (1.0 - u * u * u);
}

double median(std::vector<double> values) {
    if (values.empty()) return 0.0;
    const auto mid = values.begin() + static_cast<std::ptrdiff_t>(values.size() / 2);
    std::nth_element(values.begin(), mid, values.end());
    return *mid;
}

// The prior as a Gaussian term: e = log(T * prior^-1), cost e^T I e, de/dxi = J_l(e)^-1.
struct PriorTerm {
    Rigid3d prior_from;    // the prior's cam_from_world, inverted
    Matrix6d information;  // the prior's covariance, inverted
};

struct LinearSystem {
    Matrix6d h = Matrix6d::Zero();  // sum w J^T J (edges only, unscaled)
    Vector6d b = Vector6d::Zero();  // sum w J^T r
    double weighted_r2 = 0.0;       // sum w r^2
    double weight_sum = 0.0;
    double cost = 0.0;  // sum rho(r) (edges only)
    int used = 0;       // points with w > 0
};

// Residuals of the matched samples at `pose`, their Jacobians and robust weights. With
// `per_edge`, also sum w J^T r by edge (sized to the number of edges).
LinearSystem linearise(const std::vector<Sample>& samples, const CameraModel& camera, const Rigid3d& pose, double c,
                       bool with_jacobians, std::vector<Vector6d>* per_edge = nullptr) {
    LinearSystem sys;
    for (const Sample& s : samples) {
        if (!s.matched) continue;
        const Vector3d p = pose * s.p_in_world;
        if (p.z() <= kNearZ) continue;
        const auto pixel = camera.project(p);
        if (!pixel) continue;
        const double r = s.normal.dot(*pixel - s.match);
        sys.cost += tukeyRho(r, c);
        const double w = tukeyWeight(r, c);
        if (w <= 0.0) continue;
        ++sys.used;
        sys.weighted_r2 += w * r * r;
        sys.weight_sum += w;
        if (!with_jacobians) continue;
        // d p / d xi for the left perturbation p -> exp(xi) p: [-p^, I].
        Eigen::Matrix<double, 3, 6> dp;
        dp.leftCols<3>() = -hat3(p);
        dp.rightCols<3>().setIdentity();
        const RowVector6d j = s.normal.transpose() * projectionJacobian(camera, p) * dp;
        sys.h += w * j.transpose() * j;
        sys.b += w * j.transpose() * r;
        if (per_edge) (*per_edge)[static_cast<std::size_t>(s.edge)] += w * r * j.transpose();
    }
    return sys;
}

double residualVariance(const LinearSystem& sys, double min_sigma) {
    const double dof = std::max(sys.weight_sum - 6.0, 1.0);
    return std::max(sys.weighted_r2 / dof, min_sigma * min_sigma);
}

// Covariance of the edge term alone. Points along one edge are not independent (a shading
// gradient or a slightly misplaced proxy shifts all of them together), so sigma^2 H^-1 alone is
// over-confident (measured: by a factor of 2 to 3 in standard deviation on the rendered desk).
// The cluster-robust ("sandwich") estimate with the edges as clusters,
//     H^-1 (sum_e g_e g_e^T) H^-1 * E / (E - 6),   g_e = sum over the edge's points of w r J^T,
// captures that; with few edges it is itself unreliable, so sigma^2 H^-1 is added (conservative).
// nullopt when H is not invertible.
std::optional<Matrix6d> edgeCovariance(const LinearSystem& sys, const std::vector<Vector6d>& per_edge, double sigma2) {
    const Eigen::LDLT<Matrix6d> ldlt(sys.h);
    if (ldlt.info() != Eigen::Success || !(ldlt.vectorD().minCoeff() > 0.0)) return std::nullopt;
    const Matrix6d h_inv = ldlt.solve(Matrix6d::Identity());
    Matrix6d b = Matrix6d::Zero();
    int clusters = 0;
    for (const Vector6d& g : per_edge) {
        if (g.isZero()) continue;
        b += g * g.transpose();
        ++clusters;
    }
    const double correction = clusters > 6 ? clusters / (clusters - 6.0) : 1.0;
    Matrix6d c = h_inv * b * h_inv * correction + sigma2 * h_inv;
    c = (0.5 * (c + c.transpose())).eval();  // eval: the transpose aliases c
    if (!c.allFinite()) return std::nullopt;
    return c;
}

double priorCost(const std::optional<PriorTerm>& prior, const Rigid3d& pose) {
    if (!prior) return 0.0;
    const Vector6d e = logSe3(pose * prior->prior_from);
    return e.dot(prior->information * e);
}

std::string axisName(int i) {
    static const char* const kNames[] = {"rotation about the camera x axis",    "rotation about the camera y axis",
                                         "rotation about the camera z axis",    "translation along the camera x axis",
                                         "translation along the camera y axis", "translation along the camera z axis"};
    return kNames[i];
}


}  // namespace

Result<void> EdgeRefineOptions::validate() const {
    CL_TRY_VOID(requirePositive(search_px, "EdgeRefineOptions", "search_px"));
    CL_TRY_VOID(requirePositive(sample_spacing_px, "EdgeRefineOptions", "sample_spacing_px"));
    CL_TRY_VOID(requirePositive(min_gradient, "EdgeRefineOptions", "min_gradient"));
    CL_TRY_VOID(requirePositive(tukey_px, "EdgeRefineOptions", "tukey_px"));
    CL_TRY_VOID(requirePositive(occlusion_epsilon, "EdgeRefineOptions", "occlusion_epsilon"));
    CL_TRY_VOID(requirePositive(min_sigma_px, "EdgeRefineOptions", "min_sigma_px"));
    CL_TRY_VOID(requirePositive(min_information_ratio, "EdgeRefineOptions", "min_information_ratio"));
    CL_TRY_VOID(requirePositive(max_rms_px, "EdgeRefineOptions", "max_rms_px"));
    if (search_px < 1.0 || search_px > 64.0) {
        return fail(ErrorCode::kUsage,
                    "EdgeRefineOptions.search_px must be in [1, 64], got " + std::to_string(search_px));
    }
    if (!(blur_sigma_px >= 0.0) || !std::isfinite(blur_sigma_px)) {
        return fail(ErrorCode::kUsage, "EdgeRefineOptions.blur_sigma_px must be >= 0");
    }
    if (!(image_margin_px >= 0.0) || !std::isfinite(image_margin_px)) {
        return fail(ErrorCode::kUsage, "EdgeRefineOptions.image_margin_px must be >= 0");
    }
    if (iterations < 1 || iterations > 100) {
        return fail(ErrorCode::kUsage,
                    "EdgeRefineOptions.iterations must be in 1..100, got " + std::to_string(iterations));
    }
    if (pyramid_levels < 1 || pyramid_levels > 6) {
        return fail(ErrorCode::kUsage,
                    "EdgeRefineOptions.pyramid_levels must be in 1..6, got " + std::to_string(pyramid_levels));
    }
    if (!(coarse_converged_px >= 0.0) || !std::isfinite(coarse_converged_px)) {
        return fail(ErrorCode::kUsage, "EdgeRefineOptions.coarse_converged_px must be a finite number >= 0");
    }
    if (!(prior_sigmas >= 0.0) || !std::isfinite(prior_sigmas)) {
        return fail(ErrorCode::kUsage, "EdgeRefineOptions.prior_sigmas must be a finite number >= 0");
    }
    if (!(min_inlier_fraction >= 0.0 && min_inlier_fraction <= 1.0)) {
        return fail(ErrorCode::kUsage, "EdgeRefineOptions.min_inlier_fraction must be in [0, 1]");
    }
    if (min_points < 6) {
        return fail(ErrorCode::kUsage, "EdgeRefineOptions.min_points must be >= 6, got " + std::to_string(min_points));
    }
    if (min_edges < 1) {
        return fail(ErrorCode::kUsage, "EdgeRefineOptions.min_edges must be >= 1, got " + std::to_string(min_edges));
    }
    return {};
}

Result<EdgeRefineResult> refinePoseWithEdges(const ImageView& gray8, const CameraModel& camera, const EdgeModel& model,
                                             const Rigid3d& cam_from_world_initial, const EdgeRefineOptions& options,
                                             const std::optional<PoseMeasurement>& prior) {
    const auto start = std::chrono::steady_clock::now();
    // Step 0: check the input.
    CL_TRY_VOID(options.validate());
    if (gray8.format != PixelFormat::kGray8) {
        return fail(ErrorCode::kBadInput,
                    "edge refinement needs a gray8 image, got " + std::string(pixelFormatName(gray8.format)));
    }
    if (gray8.empty() || gray8.stride < static_cast<std::size_t>(gray8.width) ||
        gray8.size_bytes < imageBytes(gray8.format, gray8.width, gray8.height, gray8.stride)) {
        return fail(ErrorCode::kBadInput, "edge refinement: the image view is empty or smaller than its size says");
    }
    CL_TRY_VOID(camera.validate());
    CL_TRY_VOID(camera.checkImageSize(gray8.width, gray8.height));
    if (!cam_from_world_initial.isValid()) {
        return fail(ErrorCode::kBadInput, "edge refinement: the initial pose is not finite or not a rotation");
    }
    std::optional<PriorTerm> prior_term;
    if (prior) {
        if (!prior->cam_from_world.isValid() || !prior->covariance.allFinite()) {
            return fail(ErrorCode::kBadInput, "edge refinement: the prior pose or covariance is not finite");
        }
        const Matrix6d symmetric = 0.5 * (prior->covariance + prior->covariance.transpose());
        const Eigen::LLT<Matrix6d> llt(symmetric);
        if (llt.info() != Eigen::Success) {
            return fail(ErrorCode::kBadInput, "edge refinement: the prior covariance is not positive definite");
        }
        prior_term = PriorTerm{prior->cam_from_world.inverse(), llt.solve(Matrix6d::Identity())};
    }

    EdgeRefineResult result;
    result.cam_from_world = cam_from_world_initial;
    result.points_per_object.assign(static_cast<std::size_t>(model.objectCount()), 0);
    const auto finish = [&](EdgeRefineResult out, std::string reason) {
        if (!reason.empty()) {
            out.ok = false;
            out.reason = std::move(reason);
            out.cam_from_world = cam_from_world_initial;
            out.covariance.setZero();
        }
        out.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        return out;
    };
    if (model.edges().empty()) return finish(result, "the model has no edges");

    using Clock = std::chrono::steady_clock;
    const auto since = [](Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); };
    auto t0 = Clock::now();
    const FieldOfView fov = fieldOfView(camera);
    result.step_seconds.pyramid = since(t0);
    std::vector<Sample> samples;
    Rigid3d pose = cam_from_world_initial;

    // Counts of visible samples and of their distinct edges; fails when there are too few.
    const auto checkVisible = [&](const std::vector<Sample>& s) -> std::string {
        std::vector<char> seen(model.edges().size(), 0);
        int edges = 0;
        for (const Sample& x : s) edges += seen[static_cast<std::size_t>(x.edge)]++ == 0;
        if (edges < options.min_edges) {
            return std::to_string(edges) + " edges visible, need " + std::to_string(options.min_edges);
        }
        if (static_cast<int>(s.size()) < options.min_points) {
            return std::to_string(s.size()) + " edge points visible, need " + std::to_string(options.min_points);
        }
        return {};
    };
    const auto countMatched = [](const std::vector<Sample>& s) {
        return static_cast<int>(std::count_if(s.begin(), s.end(), [](const Sample& x) { return x.matched; }));
    };

    // The level to start at: the coarsest, unless the prior says the pose is near enough for a
    // finer one (EdgeRefineOptions::prior_sigmas): how far each sample point may be from where the
    // initial pose puts it, along its normal (the search's direction), is the image motion of the
    // initial pose's offset from the prior's plus prior_sigmas of the prior's standard deviation
    // there (J Sigma J^T, linearised: the rotation and translation uncertainties of a pose from
    // tags are strongly correlated, and largely cancel in the image).
    int first_level = pyramidLevelCount(gray8.width, gray8.height, options) - 1;
    bool sampled = false;  // the samples at the initial pose are already there
    if (prior_term && options.prior_sigmas > 0.0 && first_level > 0) {
        t0 = Clock::now();
        sampleEdges(model, camera, fov, pose, options, samples);
        result.step_seconds.sampling += since(t0);
        sampled = true;
        const Matrix6d cov = 0.5 * (prior->covariance + prior->covariance.transpose());
        const Vector6d offset = logSe3(pose * prior_term->prior_from);
        double motion_px = 0.0;
        for (const Sample& x : samples) {
            const Vector3d p = pose * x.p_in_world;
            Eigen::Matrix<double, 3, 6> dp;
            dp.leftCols<3>() = -hat3(p);
            dp.rightCols<3>().setIdentity();
            const RowVector6d j = x.normal.transpose() * projectionJacobian(camera, p) * dp;
            const double sigma = std::sqrt(std::max(j.dot(cov * j.transpose()), 0.0));
            motion_px = std::max(motion_px, std::abs(j.dot(offset)) + options.prior_sigmas * sigma);
        }
        if (!std::isfinite(motion_px)) motion_px = std::numeric_limits<double>::infinity();
        while (first_level > 0 && motion_px <= 0.5 * options.search_px * std::ldexp(1.0, first_level - 1)) {
            --first_level;
        }
    }
    result.first_level = first_level;
    // Only the levels used: from full resolution up to the first.
    t0 = Clock::now();
    const std::vector<Level>& levels = buildPyramid(gray8, options, first_level);
    result.step_seconds.pyramid += since(t0);

    // Steps 1-3 per level, coarse to fine.
    for (int l = first_level; l >= 0; --l) {
        const Level& level = levels[static_cast<std::size_t>(l)];
        const double level_px = 1.0 / level.scale;  // full-resolution pixels per level pixel
        for (int it = 0; it < options.iterations; ++it) {
            // Step 1: sample the visible edges at the current pose.
            if (!sampled) {
                t0 = Clock::now();
                sampleEdges(model, camera, fov, pose, options, samples);
                result.step_seconds.sampling += since(t0);
            }
            sampled = false;
            result.points_visible = static_cast<int>(samples.size());
            if (std::string why = checkVisible(samples); !why.empty()) return finish(result, why);
            // Step 2: search along the normals.
            t0 = Clock::now();
            searchEdges(level, options, samples);
            result.step_seconds.search += since(t0);
            const int matched = countMatched(samples);
            if (matched < options.min_points) {
                return finish(result, "only " + std::to_string(matched) + " of " + std::to_string(samples.size()) +
                                          " visible edge points found an image gradient above min_gradient");
            }
            // Step 3: one robust Gauss-Newton step (Levenberg-Marquardt damped). The Tukey cut-off
            // follows the residuals while they are large (far from the solution every match is an
            // inlier) and settles at tukey_px (scaled to the level) when they are small.
            t0 = Clock::now();
            std::vector<double> abs_r;
            for (const Sample& s : samples) {
                if (s.matched) abs_r.push_back(std::abs(s.normal.dot(s.pixel - s.match)));
            }
            const double c = std::max(options.tukey_px * level_px, 4.685 * 1.4826 * median(abs_r));
            std::vector<Vector6d> per_edge(model.edges().size(), Vector6d::Zero());
            const LinearSystem sys = linearise(samples, camera, pose, c, true, &per_edge);
            if (sys.used < 6) {
                return finish(result, "only " + std::to_string(sys.used) + " edge points agree with the model");
            }
            // The edges' weight against the prior: sigma^2 scaled by how much larger the honest
            // edge covariance is than sigma^2 H^-1 (a scalar, so the cost stays a proper one).
            double sigma2 = residualVariance(sys, options.min_sigma_px * level_px);
            if (prior_term) {
                if (const auto cov = edgeCovariance(sys, per_edge, sigma2)) {
                    sigma2 *= std::clamp((*cov * sys.h).trace() / (6.0 * sigma2), 1.0, 100.0);
                }
            }
            Matrix6d a = sys.h / sigma2;
            Vector6d g = sys.b / sigma2;
            if (prior_term) {
                const Vector6d e = logSe3(pose * prior_term->prior_from);
                const Matrix6d je = leftJacobianSe3(e).inverse();
                a += je.transpose() * prior_term->information * je;
                g += je.transpose() * prior_term->information * e;
            }
            const double cost0 = sys.cost / sigma2 + priorCost(prior_term, pose);
            double lambda = 1e-6;
            bool stepped = false;
            Vector6d delta = Vector6d::Zero();
            for (int attempt = 0; attempt < 8 && !stepped; ++attempt, lambda *= 10.0) {
                Matrix6d damped = a;
                damped.diagonal() += lambda * a.diagonal().cwiseMax(1e-12);
                delta = -damped.ldlt().solve(g);
                if (!delta.allFinite()) break;
                const Rigid3d candidate = expSe3(delta) * pose;
                const double cost1 =
                    linearise(samples, camera, candidate, c, false).cost / sigma2 + priorCost(prior_term, candidate);
                if (cost1 <= cost0) {
                    pose = candidate;
                    stepped = true;
                }
            }
            ++result.iterations;
            result.step_seconds.solve += since(t0);
            // Converged at this level when the step moves no point by more than a hundredth of a pixel.
            const double median_depth = median([&] {
                std::vector<double> d;
                for (const Sample& s : samples) d.push_back(s.depth);
                return d;
            }());
            const double motion_px = camera.fx * (delta.head<3>().norm() + delta.tail<3>().norm() / median_depth);
            // A coarser level only has to bring the pose within the next level's reach: it stops
            // once a step moves points by less than coarse_converged_px of its own pixels.
            const double converged_px = l > 0 ? std::max(0.01, options.coarse_converged_px * level_px) : 0.01;
            if (!stepped || motion_px < converged_px) break;
        }
    }

    // Step 4: the final matches at the refined pose (full resolution), the covariance and the checks.
    t0 = Clock::now();
    sampleEdges(model, camera, fov, pose, options, samples);
    result.step_seconds.sampling += since(t0);
    result.points_visible = static_cast<int>(samples.size());
    if (std::string why = checkVisible(samples); !why.empty()) return finish(result, why);
    t0 = Clock::now();
    searchEdges(levels.front(), options, samples);
    result.step_seconds.search += since(t0);
    t0 = Clock::now();
    const double c = options.tukey_px;
    std::vector<Vector6d> per_edge(model.edges().size(), Vector6d::Zero());
    const LinearSystem sys = linearise(samples, camera, pose, c, true, &per_edge);
    result.points_used = sys.used;
    std::vector<char> edge_used(model.edges().size(), 0);
    for (const Sample& s : samples) {
        if (!s.matched) continue;
        const Vector3d p = pose * s.p_in_world;
        const auto pixel = camera.project(p);
        if (!pixel || tukeyWeight(s.normal.dot(*pixel - s.match), c) <= 0.0) continue;
        edge_used[static_cast<std::size_t>(s.edge)] = 1;
        ++result.points_per_object[static_cast<std::size_t>(s.object)];
    }
    result.edges_used = static_cast<int>(std::count(edge_used.begin(), edge_used.end(), 1));
    result.rms_px = sys.weight_sum > 0.0 ? std::sqrt(sys.weighted_r2 / sys.weight_sum) : 0.0;
    result.cam_from_world = pose;
    if (result.points_used < options.min_points) {
        return finish(result, "only " + std::to_string(result.points_used) + " of " +
                                  std::to_string(result.points_visible) +
                                  " visible edge points match an image edge at the refined pose, need " +
                                  std::to_string(options.min_points));
    }
    if (result.edges_used < options.min_edges) {
        return finish(result, "only " + std::to_string(result.edges_used) + " edges match the image, need " +
                                  std::to_string(options.min_edges));
    }
    const double inliers = static_cast<double>(result.points_used) / std::max(result.points_visible, 1);
    if (inliers < options.min_inlier_fraction) {
        std::ostringstream msg;
        msg << "only " << result.points_used << " of " << result.points_visible
            << " visible edge points agree with the image (" << static_cast<int>(100 * inliers) << " %, need "
            << static_cast<int>(100 * options.min_inlier_fraction) << " %): probably a wrong pose";
        return finish(result, msg.str());
    }
    if (result.rms_px > options.max_rms_px) {
        std::ostringstream msg;
        msg << "did not converge: rms edge distance " << result.rms_px << " px > max_rms_px " << options.max_rms_px;
        return finish(result, msg.str());
    }
    const double sigma2 = residualVariance(sys, options.min_sigma_px);
    Matrix6d information = sys.h / sigma2;
    Matrix6d prior_information = Matrix6d::Zero();
    if (prior_term) {
        const Matrix6d je = leftJacobianSe3(logSe3(pose * prior_term->prior_from)).inverse();
        prior_information = je.transpose() * prior_term->information * je;
        information += prior_information;
    }
    // Poorly constrained: compare eigenvalues with translations in units of the median depth
    // (a translation of one depth moves points about as much as a rotation of one radian).
    std::vector<double> depths;
    for (const Sample& s : samples) depths.push_back(s.depth);
    const double depth = std::max(median(depths), 1e-3);
    Vector6d to_scaled;
    to_scaled << 1, 1, 1, depth, depth, depth;
    const Matrix6d scaled = to_scaled.asDiagonal() * information * to_scaled.asDiagonal();
    const Eigen::SelfAdjointEigenSolver<Matrix6d> eigen(scaled);
    const double ratio = eigen.eigenvalues()(0) / std::max(eigen.eigenvalues()(5), 1e-300);
    if (!(ratio >= options.min_information_ratio)) {
        int axis = 0;
        eigen.eigenvectors().col(0).cwiseAbs().maxCoeff(&axis);
        std::ostringstream msg;
        msg << "poorly constrained: the edges hardly fix the " << axisName(axis) << " (information ratio " << ratio
            << " < " << options.min_information_ratio << ")";
        return finish(result, msg.str());
    }
    // The covariance: the edges' (cluster-robust) covariance, fused with the prior's information.
    const auto edge_covariance = edgeCovariance(sys, per_edge, sigma2);
    if (!edge_covariance) {
        if (!prior_term) return finish(result, "poorly constrained: the edges' information matrix is singular");
        result.covariance = (information).inverse();
    } else if (prior_term) {
        result.covariance = (edge_covariance->inverse() + prior_information).inverse();
    } else {
        result.covariance = *edge_covariance;
    }
    result.covariance = (0.5 * (result.covariance + result.covariance.transpose())).eval();  // eval: aliasing
    // Hard case: a nearly degenerate system (a wall seen 75-80 degrees off its normal) whose
    // inverted covariance comes out indefinite by rounding; the filter would refuse it and stop
    // the frame's tracking. Not ok: the tags' pose stands.
    if (result.covariance.llt().info() != Eigen::Success || !result.covariance.allFinite()) {
        return finish(result, "poorly constrained: the covariance is not positive definite");
    }
    result.step_seconds.solve += since(t0);
    result.ok = true;
    return finish(result, {});
}

}  // namespace commonlight::tracking

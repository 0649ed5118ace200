#include "lighting/shading_direction.h"

#include <ceres/ceres.h>
#include <ceres/sphere_manifold.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <numbers>

namespace commonlight::lighting {

namespace {

constexpr double kDeg = 180.0 / std::numbers::pi;

// Mean directional derivatives of the image along 8 directions (x right, y up), over pairs of
// object pixels one step apart.
struct Derivatives {
    double mean[8] = {};
    double mean_sq[8] = {};
    int count[8] = {};
};

Derivatives directionalDerivatives(const std::vector<float>& lum, const std::vector<std::uint8_t>& mask, int w, int h) {
    Derivatives d;
    const int dx[8] = {1, 1, 0, -1, -1, -1, 0, 1};
    const int dy_up[8] = {0, 1, 1, 1, 0, -1, -1, -1};  // image y up: row decreases
    for (int k = 0; k < 8; ++k) {
        const double step = std::hypot(dx[k], dy_up[k]);
        double s = 0.0, s2 = 0.0;
        int n = 0;
        for (int y = 0; y < h; ++y) {
            const int y2 = y - dy_up[k];
            if (y2 < 0 || y2 >= h) continue;
            for (int x = 0; x < w; ++x) {
                const int x2 = x + dx[k];
                if (x2 < 0 || x2 >= w) continue;
                const std::size_t a = static_cast<std::size_t>(y) * w + x, b = static_cast<std::size_t>(y2) * w + x2;
                if (!mask[a] || !mask[b]) continue;
                const double di = (lum[b] - lum[a]) / step;
                s += di;
                s2 += di * di;
                ++n;
            }
        }
        d.count[k] = n;
        d.mean[k] = n > 0 ? s / n : 0.0;
        d.mean_sq[k] = n > 0 ? s2 / n : 0.0;
    }
    return d;
}

Result<void> checkImage(const std::vector<float>& lum, const std::vector<std::uint8_t>& mask, int w, int h) {
    if (w <= 0 || h <= 0 || lum.size() != static_cast<std::size_t>(w) * h || mask.size() != lum.size()) {
        return fail(ErrorCode::kBadInput, "shading: image and mask sizes do not match");
    }
    int n = 0;
    for (std::size_t i = 0; i < lum.size(); ++i) {
        if (!mask[i]) continue;
        if (!std::isfinite(lum[i])) return fail(ErrorCode::kBadInput, "shading: non-finite intensity on the object");
        ++n;
    }
    if (n < 50) return fail(ErrorCode::kBadInput, "shading: fewer than 50 object pixels");
    return {};
}

double wrap360(double deg) {
    double t = std::fmod(deg, 360.0);
    return t < 0.0 ? t + 360.0 : t;
}

}  // namespace

TiltSlant tiltSlantOf(const Eigen::Vector3d& l) {
    const Eigen::Vector3d u = l.normalized();
    TiltSlant ts;
    ts.slant_deg = std::acos(std::clamp(u.z(), -1.0, 1.0)) * kDeg;
    // Hard case: at slant 0 the tilt is undefined (atan2(0, 0) = 0 is reported).
    ts.tilt_deg = wrap360(std::atan2(u.y(), u.x()) * kDeg);
    return ts;
}

Eigen::Vector3d directionOf(const TiltSlant& ts) {
    const double t = ts.tilt_deg / kDeg, s = ts.slant_deg / kDeg;
    return {std::sin(s) * std::cos(t), std::sin(s) * std::sin(t), std::cos(s)};
}

Result<TiltSlant> estimatePentland(const std::vector<float>& lum, const std::vector<std::uint8_t>& mask, int w, int h) {
    CL_TRY_VOID(checkImage(lum, mask, w, h));
    // Step 1: E[dI_k] = x' cos(theta_k) + y' sin(theta_k), by least squares over the 8 directions.
    const Derivatives d = directionalDerivatives(lum, mask, w, h);
    Eigen::Matrix<double, 8, 2> b;
    Eigen::Matrix<double, 8, 1> m;
    double variance = 0.0;
    for (int k = 0; k < 8; ++k) {
        const double theta = k * std::numbers::pi / 4.0;
        b(k, 0) = std::cos(theta);
        b(k, 1) = std::sin(theta);
        m(k) = d.mean[k];
        variance += d.mean_sq[k] - d.mean[k] * d.mean[k];
    }
    const Eigen::Vector2d xy = b.colPivHouseholderQr().solve(m);
    // Step 2: the in-plane component's size from the spread of the derivatives (Pentland's k).
    const double k = std::sqrt(std::max(variance / 8.0, 1e-300));
    if (!(k > 0.0)) return fail(ErrorCode::kBadInput, "shading: no shading on the object");
    Eigen::Vector2d in_plane = xy / k;
    if (in_plane.norm() > 1.0) in_plane.normalize();
    const double z = std::sqrt(std::max(0.0, 1.0 - in_plane.squaredNorm()));
    return tiltSlantOf(Eigen::Vector3d(in_plane.x(), in_plane.y(), z));
}

Result<TiltSlant> estimateLeeRosenfeld(const std::vector<float>& lum, const std::vector<std::uint8_t>& mask, int w, int h) {
    CL_TRY_VOID(checkImage(lum, mask, w, h));
    // Tilt: the mean directional derivative's direction (as Pentland's).
    const Derivatives d = directionalDerivatives(lum, mask, w, h);
    double gx = 0.0, gy = 0.0;
    for (int k = 0; k < 8; ++k) {
        const double theta = k * std::numbers::pi / 4.0;
        gx += d.mean[k] * std::cos(theta);
        gy += d.mean[k] * std::sin(theta);
    }
    // Slant: E[I] = 2/3 rho lambda cos s and E[I^2] = rho^2 lambda^2 (1 + cos^2 s) / 4 over a sphere's
    // disc (orthographic, no attached shadow), so rho lambda = sqrt(4 E[I^2] - 2.25 E[I]^2).
    double s = 0.0, s2 = 0.0;
    int n = 0;
    for (std::size_t i = 0; i < lum.size(); ++i) {
        if (!mask[i]) continue;
        s += lum[i];
        s2 += static_cast<double>(lum[i]) * lum[i];
        ++n;
    }
    const double ei = s / n, ei2 = s2 / n;
    const double rho_lambda = std::sqrt(std::max(4.0 * ei2 - 2.25 * ei * ei, 1e-300));
    const double cos_s = std::clamp(1.5 * ei / rho_lambda, 0.0, 1.0);
    TiltSlant ts;
    ts.tilt_deg = wrap360(std::atan2(gy, gx) * kDeg);
    ts.slant_deg = std::acos(cos_s) * kDeg;
    return ts;
}

namespace {

// r = w (a max(0, n . l) + b - L): l on the unit sphere (a manifold), a and b bounded below by 0.
struct LambertResidual {
    LambertResidual(const Eigen::Vector3d& n, double observed) : n_(n), observed_(observed) {}
    template <typename T>
    bool operator()(const T* l, const T* a, const T* b, T* r) const {
        const T cos_i = T(n_.x()) * l[0] + T(n_.y()) * l[1] + T(n_.z()) * l[2];
        const T lit = cos_i > T(0) ? cos_i : T(0);
        r[0] = a[0] * lit + b[0] - T(observed_);
        return true;
    }
    Eigen::Vector3d n_;
    double observed_;
};

}  // namespace

Result<ShadingFit> fitSphereLight(const ImageView& radiance, const CameraModel& camera, const Rigid3d& cam_from_world,
                                  const Eigen::Vector3d& centre, double radius, const ShadingFitOptions& options) {
    if (radiance.format != PixelFormat::kRgbF32 || radiance.width != camera.width || radiance.height != camera.height) {
        return fail(ErrorCode::kBadInput, "shading: radiance must be RGB float at the camera's size");
    }
    if (!(radius > 0.0) || !centre.allFinite() || !cam_from_world.isValid()) {
        return fail(ErrorCode::kBadInput, "shading: the sphere or the pose is not finite");
    }
    // Step 1: the sphere's pixels and their normals (ray-sphere, exact).
    const Rigid3d world_from_cam = cam_from_world.inverse();
    const Eigen::Vector3d eye = world_from_cam.translation;
    std::vector<Eigen::Vector3d> normals;
    std::vector<double> values;
    double max_value = 0.0;
    for (int y = 0; y < radiance.height; ++y) {
        const auto* row = reinterpret_cast<const float*>(radiance.row(y));
        for (int x = 0; x < radiance.width; ++x) {
            const auto ray = camera.unproject(Eigen::Vector2d(x, y));
            if (!ray) continue;
            const Eigen::Vector3d dir = (world_from_cam.rotationMatrix() * *ray).normalized();
            const Eigen::Vector3d oc = eye - centre;
            const double bq = oc.dot(dir), cq = oc.squaredNorm() - radius * radius;
            const double disc = bq * bq - cq;
            // Hard case: a ray grazing the limb; its pixel mixes the sphere and the background.
            if (disc <= 0.02 * radius * radius) continue;
            const double t = -bq - std::sqrt(disc);
            if (t <= 0.0) continue;
            const Eigen::Vector3d n = (eye + t * dir - centre) / radius;
            const double l = 0.2126 * row[3 * x] + 0.7152 * row[3 * x + 1] + 0.0722 * row[3 * x + 2];
            if (!std::isfinite(l)) return fail(ErrorCode::kBadInput, "shading: non-finite radiance on the sphere");
            normals.push_back(n);
            values.push_back(l);
            max_value = std::max(max_value, l);
        }
    }
    // Saturated pixels carry no shading.
    std::vector<Eigen::Vector3d> kept_n;
    std::vector<double> kept_v;
    for (std::size_t i = 0; i < values.size(); ++i) {
        if (values[i] >= options.saturation * max_value && options.saturation < 1.0) continue;
        kept_n.push_back(normals[i]);
        kept_v.push_back(values[i]);
    }
    if (static_cast<int>(kept_v.size()) < options.min_pixels) {
        return fail(ErrorCode::kBadInput, "shading: fewer than " + std::to_string(options.min_pixels) + " usable sphere pixels");
    }
    // Step 2: the start: L = g . n + b on the clearly lit pixels (g = a l), linear least squares.
    double lit_threshold = 0.0;
    {
        std::vector<double> sorted = kept_v;
        std::sort(sorted.begin(), sorted.end());
        lit_threshold = sorted[sorted.size() / 2];  // the brighter half is lit for any light not far behind
    }
    std::vector<int> lit;
    for (std::size_t i = 0; i < kept_v.size(); ++i) {
        if (kept_v[i] > lit_threshold) lit.push_back(static_cast<int>(i));
    }
    if (lit.size() < 10) return fail(ErrorCode::kBadInput, "shading: too few lit pixels (a light from behind the sphere?)");
    Eigen::MatrixXd a(static_cast<Eigen::Index>(lit.size()), 4);
    Eigen::VectorXd rhs(static_cast<Eigen::Index>(lit.size()));
    for (std::size_t k = 0; k < lit.size(); ++k) {
        const Eigen::Vector3d& n = kept_n[static_cast<std::size_t>(lit[k])];
        a.row(static_cast<Eigen::Index>(k)) << n.x(), n.y(), n.z(), 1.0;
        rhs(static_cast<Eigen::Index>(k)) = kept_v[static_cast<std::size_t>(lit[k])];
    }
    const Eigen::Vector4d start = a.colPivHouseholderQr().solve(rhs);
    Eigen::Vector3d l = start.head<3>();
    if (!(l.norm() > 0.0)) return fail(ErrorCode::kBadInput, "shading: the object shows no shading");
    double scale = l.norm(), ambient = std::max(0.0, start(3));
    l.normalize();
    // Step 3: the whole object, with the attached shadow, by Ceres.
    ceres::Problem problem;
    for (std::size_t i = 0; i < kept_v.size(); ++i) {
        problem.AddResidualBlock(new ceres::AutoDiffCostFunction<LambertResidual, 1, 3, 1, 1>(new LambertResidual(kept_n[i], kept_v[i])),
                                 new ceres::SoftLOneLoss(0.02 * max_value), l.data(), &scale, &ambient);
    }
    problem.SetManifold(l.data(), new ceres::SphereManifold<3>());
    problem.SetParameterLowerBound(&scale, 0, 0.0);
    problem.SetParameterLowerBound(&ambient, 0, 0.0);
    ceres::Solver::Options so;
    so.linear_solver_type = ceres::DENSE_QR;
    so.max_num_iterations = 100;
    so.num_threads = 1;
    so.logging_type = ceres::SILENT;
    ceres::Solver::Summary summary;
    ceres::Solve(so, &problem, &summary);
    if (!summary.IsSolutionUsable()) return fail(ErrorCode::kInternal, "shading: Ceres failed: " + summary.message);
    l.normalize();
    ShadingFit out;
    out.towards_light_world = l;
    out.scale = scale;
    out.ambient = ambient;
    out.pixels = static_cast<int>(kept_v.size());
    double se = 0.0, mean = 0.0;
    for (std::size_t i = 0; i < kept_v.size(); ++i) {
        const double model = scale * std::max(0.0, kept_n[i].dot(l)) + ambient;
        se += (model - kept_v[i]) * (model - kept_v[i]);
        mean += kept_v[i];
    }
    mean /= static_cast<double>(kept_v.size());
    out.rms = mean > 0.0 ? std::sqrt(se / kept_v.size()) / mean : 0.0;
    // The direction's standard error: from the lit pixels' sensitivity, sigma^2 (J^T J)^-1 on the
    // tangent plane (two angles).
    {
        const Eigen::Vector3d u = l.unitOrthogonal(), v = l.cross(u);
        Eigen::Matrix2d jtj = Eigen::Matrix2d::Zero();
        for (std::size_t i = 0; i < kept_v.size(); ++i) {
            if (kept_n[i].dot(l) <= 0.0) continue;
            const Eigen::Vector2d g(scale * kept_n[i].dot(u), scale * kept_n[i].dot(v));
            jtj += g * g.transpose();
        }
        const double sigma2 = se / std::max<double>(1.0, static_cast<double>(kept_v.size()) - 5.0);
        const Eigen::Matrix2d cov = sigma2 * jtj.inverse();
        out.uncertainty_deg = std::sqrt(std::max(0.0, cov.trace())) * kDeg;
    }
    // The viewer's frame: OpenCV camera axes (x right, y down, z forward) -> x right, y up, z to the viewer.
    const Eigen::Vector3d in_cam = cam_from_world.rotationMatrix() * l;
    out.view = tiltSlantOf(Eigen::Vector3d(in_cam.x(), -in_cam.y(), -in_cam.z()));
    return out;
}

}  // namespace commonlight::lighting

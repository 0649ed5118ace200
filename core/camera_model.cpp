#include "core/camera_model.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include <Eigen/LU>

namespace commonlight {

Result<void> CameraModel::validate() const {
    std::ostringstream msg;
    if (width <= 0 || height <= 0) {
        msg << "image size must be positive, got " << width << "x" << height;
    } else if (!(std::isfinite(fx) && std::isfinite(fy) && fx > 0 && fy > 0)) {
        msg << "focal lengths must be positive and finite, got fx=" << fx << " fy=" << fy;
    } else if (!(std::isfinite(cx) && std::isfinite(cy)) || cx < -0.5 || cy < -0.5 || cx > width - 0.5 ||
               cy > height - 0.5) {
        msg << "principal point (" << cx << ", " << cy << ") is outside the " << width << "x" << height
            << " image";
    } else if (!(std::isfinite(distortion.k1) && std::isfinite(distortion.k2) && std::isfinite(distortion.p1) &&
                 std::isfinite(distortion.p2) && std::isfinite(distortion.k3))) {
        msg << "distortion coefficients must be finite";
    } else {
        return {};
    }
    return fail(ErrorCode::kBadInput, msg.str());
}

Result<void> CameraModel::checkImageSize(int image_width, int image_height) const {
    if (image_width == width && image_height == height) return {};
    std::ostringstream msg;
    msg << "image is " << image_width << "x" << image_height << " but the calibration is for " << width << "x"
        << height;
    return fail(ErrorCode::kBadInput, msg.str());
}

CameraModel CameraModel::scaledTo(int new_width, int new_height) const {
    CameraModel out = *this;
    const double sx = static_cast<double>(new_width) / width;
    const double sy = static_cast<double>(new_height) / height;
    out.width = new_width;
    out.height = new_height;
    out.fx = fx * sx;
    out.fy = fy * sy;
    // Pixel centres: continuous coordinate u + 0.5 scales.
    out.cx = (cx + 0.5) * sx - 0.5;
    out.cy = (cy + 0.5) * sy - 0.5;
    return out;
}

Eigen::Vector2d CameraModel::distortNormalized(const Eigen::Vector2d& xy) const {
    const auto& d = distortion;
    const double x = xy.x();
    const double y = xy.y();
    const double r2 = x * x + y * y;
    const double radial = 1.0 + r2 * (d.k1 + r2 * (d.k2 + r2 * d.k3));
    return {x * radial + 2.0 * d.p1 * x * y + d.p2 * (r2 + 2.0 * x * x),
            y * radial + d.p1 * (r2 + 2.0 * y * y) + 2.0 * d.p2 * x * y};
}

namespace {

// Jacobian of distortNormalized at (x, y).
Eigen::Matrix2d distortionJacobian(const Distortion& d, double x, double y) {
    const double r2 = x * x + y * y;
    const double radial = 1.0 + r2 * (d.k1 + r2 * (d.k2 + r2 * d.k3));
    const double dradial_dr2 = d.k1 + r2 * (2.0 * d.k2 + 3.0 * r2 * d.k3);
    Eigen::Matrix2d j;
    j(0, 0) = radial + 2.0 * x * x * dradial_dr2 + 2.0 * d.p1 * y + 6.0 * d.p2 * x;
    j(0, 1) = 2.0 * x * y * dradial_dr2 + 2.0 * d.p1 * x + 2.0 * d.p2 * y;
    j(1, 0) = 2.0 * x * y * dradial_dr2 + 2.0 * d.p1 * x + 2.0 * d.p2 * y;
    j(1, 1) = radial + 2.0 * y * y * dradial_dr2 + 6.0 * d.p1 * y + 2.0 * d.p2 * x;
    return j;
}

}  // namespace

double CameraModel::maxValidRadius() const {
    // d/dr [r (1 + k1 r^2 + k2 r^4 + k3 r^6)] = 1 + 3 k1 r^2 + 5 k2 r^4 + 7 k3 r^6 must stay > 0.
    // Scan in r^2 for the first root; the tangential terms are small and ignored here.
    const auto& d = distortion;
    if (d.k1 >= 0 && d.k2 >= 0 && d.k3 >= 0) return std::numeric_limits<double>::infinity();
    constexpr double kMaxR2 = 100.0;  // 84 degrees off-axis at r = 10; wider is not a pinhole lens
    constexpr int kSteps = 20000;
    double prev_r2 = 0.0;
    for (int i = 1; i <= kSteps; ++i) {
        const double r2 = kMaxR2 * i / kSteps;
        const double slope = 1.0 + r2 * (3.0 * d.k1 + r2 * (5.0 * d.k2 + r2 * 7.0 * d.k3));
        if (slope <= 0.0) {
            // Bisect between prev_r2 and r2.
            double lo = prev_r2;
            double hi = r2;
            for (int k = 0; k < 60; ++k) {
                const double mid = 0.5 * (lo + hi);
                const double s = 1.0 + mid * (3.0 * d.k1 + mid * (5.0 * d.k2 + mid * 7.0 * d.k3));
                (s > 0.0 ? lo : hi) = mid;
            }
            return std::sqrt(lo);
        }
        prev_r2 = r2;
    }
    return std::numeric_limits<double>::infinity();
}

namespace {

// The largest squared radius (a multiple of kMaxR2 / kCells, at most kMaxR2) up to which the
// slope 1 + 3 k1 s + 5 k2 s^2 + 7 k3 s^3 is proved positive, with a margin over the rounding of
// its evaluation: on each cell [a, b] of [0, kMaxR2], every term c s^j is monotonic in s >= 0,
// so the sum of their smaller ends is a lower bound of the slope there. A sample of [0, r2] with
// r2 at most this radius is then positive in floating point too (Horner's rounding is a few
// ulps of the terms' magnitudes, far under the 1e-9 margin): radialMonotonicUpTo answers true
// exactly where its sampling would.
double provedMonotonicR2(const Distortion& d) {
    constexpr double kMaxR2 = 100.0;  // as maxValidRadius
    constexpr int kCells = 4096;
    const double c1 = 3.0 * d.k1, c2 = 5.0 * d.k2, c3 = 7.0 * d.k3;
    double proved = 0.0;
    for (int i = 0; i < kCells; ++i) {
        const double a = kMaxR2 * i / kCells, b = kMaxR2 * (i + 1) / kCells;
        const double low = 1.0 + std::min(c1 * a, c1 * b) + std::min(c2 * a * a, c2 * b * b) +
                           std::min(c3 * a * a * a, c3 * b * b * b);
        const double magnitude = 1.0 + std::abs(c1) * b + std::abs(c2) * b * b + std::abs(c3) * b * b * b;
        if (!(low > 1e-9 * magnitude)) break;
        proved = b;
    }
    return proved;
}

}  // namespace

std::optional<double> CameraModel::MonotonicCache::find(const Distortion& d) const noexcept {
    const std::uint64_t before = version_.load(std::memory_order_acquire);
    if (before == 0 || before % 2 != 0) return std::nullopt;
    const double k1 = k1_.load(std::memory_order_acquire), k2 = k2_.load(std::memory_order_acquire),
                 k3 = k3_.load(std::memory_order_acquire), r2 = r2_.load(std::memory_order_acquire);
    // A writer that started meanwhile changed the version: the values may be mixed.
    if (version_.load(std::memory_order_acquire) != before) return std::nullopt;
    if (k1 != d.k1 || k2 != d.k2 || k3 != d.k3) return std::nullopt;
    return r2;
}

void CameraModel::MonotonicCache::store(const Distortion& d, double r2) const noexcept {
    std::uint64_t version = version_.load(std::memory_order_acquire);
    // Another writer at work: leave it to that one.
    if (version % 2 != 0 || !version_.compare_exchange_strong(version, version + 1, std::memory_order_acq_rel)) return;
    k1_.store(d.k1, std::memory_order_release);
    k2_.store(d.k2, std::memory_order_release);
    k3_.store(d.k3, std::memory_order_release);
    r2_.store(r2, std::memory_order_release);
    version_.store(version + 2, std::memory_order_release);
}

void CameraModel::MonotonicCache::copyFrom(const MonotonicCache& other) noexcept {
    const Distortion key{other.k1_.load(std::memory_order_acquire), other.k2_.load(std::memory_order_acquire), 0.0, 0.0,
                         other.k3_.load(std::memory_order_acquire)};
    const auto r2 = other.find(key);
    // Nothing (consistent) to copy: coefficients that match no distortion (NaN), so that the
    // version only grows.
    constexpr double kNone = std::numeric_limits<double>::quiet_NaN();
    store(r2 ? key : Distortion{kNone, kNone, 0.0, 0.0, kNone}, r2.value_or(0.0));
}

bool CameraModel::radialMonotonicUpTo(double r2) const {
    const auto& d = distortion;
    if (d.k1 >= 0 && d.k2 >= 0 && d.k3 >= 0) return true;
    // Every projection asks this: first a bound that needs no sampling. On [0, r2] each negative
    // term of the slope is at its most negative at s = r2 and the positive ones are >= 0, so when
    // the negative terms alone at r2 leave the slope positive, every sample below is positive too
    // (the same answer, without the 64 evaluations).
    const double k1 = std::min(d.k1, 0.0), k2 = std::min(d.k2, 0.0), k3 = std::min(d.k3, 0.0);
    if (r2 >= 0 && 1.0 + r2 * (3.0 * k1 + r2 * (5.0 * k2 + r2 * 7.0 * k3)) > 0.0) return true;
    // Then the squared radius up to which the slope is proved positive (k2 or k3 > 0 lifts it
    // past the bound: the wide lens, k1 = -0.4 and k2 = 0.12, is monotonic everywhere), computed
    // once for these coefficients.
    std::optional<double> proved = monotonic_cache_.find(d);
    if (!proved) {
        proved = provedMonotonicR2(d);
        monotonic_cache_.store(d, *proved);
    }
    if (r2 >= 0 && r2 <= *proved) return true;
    // The slope 1 + 3 k1 s + 5 k2 s^2 + 7 k3 s^3 (s = r^2) is 1 at s = 0; sample it up to r2.
    // A cubic that dips below zero and recovers between two of 64 samples would need a root
    // pair closer than r2 / 64; no calibrated lens has that.
    constexpr int kSamples = 64;
    for (int i = 1; i <= kSamples; ++i) {
        const double s = r2 * i / kSamples;
        if (1.0 + s * (3.0 * d.k1 + s * (5.0 * d.k2 + s * 7.0 * d.k3)) <= 0.0) return false;
    }
    return true;
}

std::optional<Eigen::Vector2d> CameraModel::undistortNormalized(const Eigen::Vector2d& xy_distorted) const {
    if (!xy_distorted.allFinite()) return std::nullopt;
    if (distortion.isZero()) return xy_distorted;
    // Damped Newton on f(x) = distort(x) - x_d. The fixed-point iteration OpenCV uses
    // (x = (x_d - tangential) / radial) diverges for strong barrel distortion (k1 = -0.4 near the
    // image corners); Newton with step halving converges there in a handful of iterations.
    Eigen::Vector2d x = xy_distorted;
    Eigen::Vector2d residual = distortNormalized(x) - xy_distorted;
    constexpr double kTolerance = 1e-12;
    for (int iteration = 0; iteration < 50 && residual.norm() > kTolerance; ++iteration) {
        const Eigen::Matrix2d j = distortionJacobian(distortion, x.x(), x.y());
        const double det = j.determinant();
        // Hard case: a singular Jacobian means we reached the fold of the lens model.
        if (!std::isfinite(det) || std::abs(det) < 1e-12) return std::nullopt;
        const Eigen::Vector2d step = j.inverse() * residual;
        double scale = 1.0;
        bool improved = false;
        for (int halving = 0; halving < 30; ++halving) {
            const Eigen::Vector2d candidate = x - scale * step;
            const Eigen::Vector2d candidate_residual = distortNormalized(candidate) - xy_distorted;
            if (candidate_residual.norm() < residual.norm()) {
                x = candidate;
                residual = candidate_residual;
                improved = true;
                break;
            }
            scale *= 0.5;
        }
        if (!improved) break;
    }
    // Converged relative to the size of the point (tolerance scales for points far off-axis).
    if (!(residual.norm() <= 1e-9 * std::max(1.0, xy_distorted.norm()))) return std::nullopt;
    // Past the fold, a second preimage exists; it is not the one a real ray took.
    if (!radialMonotonicUpTo(x.squaredNorm())) return std::nullopt;
    return x;
}

std::optional<Eigen::Vector2d> CameraModel::project(const Eigen::Vector3d& p_in_cam) const {
    // Hard case: points on or behind the image plane have no image.
    if (!p_in_cam.allFinite() || p_in_cam.z() <= 1e-12) return std::nullopt;
    const Eigen::Vector2d xy = p_in_cam.head<2>() / p_in_cam.z();
    if (!radialMonotonicUpTo(xy.squaredNorm())) return std::nullopt;
    const Eigen::Vector2d d = distortNormalized(xy);
    return Eigen::Vector2d(fx * d.x() + cx, fy * d.y() + cy);
}

std::optional<Eigen::Vector3d> CameraModel::unproject(const Eigen::Vector2d& pixel) const {
    const Eigen::Vector2d xd((pixel.x() - cx) / fx, (pixel.y() - cy) / fy);
    const auto xy = undistortNormalized(xd);
    if (!xy) return std::nullopt;
    return Eigen::Vector3d(xy->x(), xy->y(), 1.0);
}

std::optional<Eigen::Vector2d> CameraModel::undistortPixel(const Eigen::Vector2d& pixel) const {
    const auto ray = unproject(pixel);
    if (!ray) return std::nullopt;
    return Eigen::Vector2d(fx * ray->x() + cx, fy * ray->y() + cy);
}

Eigen::Vector2d CameraModel::distortPixel(const Eigen::Vector2d& ideal_pixel) const {
    const Eigen::Vector2d xy((ideal_pixel.x() - cx) / fx, (ideal_pixel.y() - cy) / fy);
    const Eigen::Vector2d d = distortNormalized(xy);
    return {fx * d.x() + cx, fy * d.y() + cy};
}

Eigen::Matrix3d CameraModel::K() const {
    Eigen::Matrix3d k;
    k << fx, 0, cx, 0, fy, cy, 0, 0, 1;
    return k;
}

Eigen::Matrix4d CameraModel::glProjection(double near_m, double far_m) const {
    // Pixel u (centre convention) covers NDC x = 2 (u + 0.5) / width - 1. With x_ndc = x_clip / w_clip
    // and w_clip = -z_gl = z_cam: x_ndc = (2 (fx x/z + cx + 0.5)) / width - 1.
    Eigen::Matrix4d p = Eigen::Matrix4d::Zero();
    p(0, 0) = 2.0 * fx / width;
    p(0, 2) = 1.0 - 2.0 * (cx + 0.5) / width;
    // GL's y points up while image rows go down: y_ndc = 1 - 2 (v + 0.5) / height.
    p(1, 1) = 2.0 * fy / height;
    p(1, 2) = 2.0 * (cy + 0.5) / height - 1.0;
    p(2, 2) = -(far_m + near_m) / (far_m - near_m);
    p(2, 3) = -2.0 * far_m * near_m / (far_m - near_m);
    p(3, 2) = -1.0;
    return p;
}

}  // namespace commonlight

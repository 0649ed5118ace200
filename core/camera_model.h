// Pinhole intrinsics with Brown-Conrady distortion (OpenCV's k1 k2 p1 p2 k3 model).
//
// Pixel coordinates follow OpenCV: the centre of the top-left pixel is (0, 0). libapriltag puts
// that centre at (0.5, 0.5); subtract 0.5 from its corners before using them here.
#pragma once

#include <atomic>
#include <cstdint>
#include <optional>

#include <Eigen/Core>

#include "core/result.h"

namespace commonlight {

struct Distortion {
    double k1 = 0.0, k2 = 0.0, p1 = 0.0, p2 = 0.0, k3 = 0.0;
    bool isZero() const noexcept { return k1 == 0 && k2 == 0 && p1 == 0 && p2 == 0 && k3 == 0; }
    bool operator==(const Distortion&) const = default;
};

class CameraModel {
public:
    int width = 0;   // pixels
    int height = 0;  // pixels
    double fx = 0.0, fy = 0.0;  // focal lengths, pixels
    double cx = 0.0, cy = 0.0;  // principal point, pixels (OpenCV convention)
    Distortion distortion;

    bool operator==(const CameraModel&) const = default;

    // Positive focal lengths and size, finite values, principal point inside the image.
    Result<void> validate() const;
    // Fails with a message naming both sizes when an image does not match the calibration.
    Result<void> checkImageSize(int image_width, int image_height) const;
    // The same camera for an image resized to new_width x new_height (distortion unchanged).
    CameraModel scaledTo(int new_width, int new_height) const;

    // Normalised image plane (x/z, y/z) <-> distorted normalised coordinates.
    Eigen::Vector2d distortNormalized(const Eigen::Vector2d& xy) const;
    // Inverts distortNormalized by damped Newton iteration. Returns nullopt when no solution
    // inside the monotonic part of the lens model exists (beyond the fold of strong barrel
    // distortion) or the iteration does not converge; never returns an unconverged point.
    std::optional<Eigen::Vector2d> undistortNormalized(const Eigen::Vector2d& xy_distorted) const;

    // 3D point in the camera frame (z forward) to a distorted pixel; nullopt behind the camera
    // or beyond the lens model's valid radius.
    std::optional<Eigen::Vector2d> project(const Eigen::Vector3d& p_in_cam) const;
    // Distorted pixel to the ray (x, y, 1) in the camera frame.
    std::optional<Eigen::Vector3d> unproject(const Eigen::Vector2d& pixel) const;
    // Distorted pixel to the pixel an ideal pinhole camera with the same fx fy cx cy would see.
    std::optional<Eigen::Vector2d> undistortPixel(const Eigen::Vector2d& pixel) const;
    // Ideal pinhole pixel to the distorted pixel.
    Eigen::Vector2d distortPixel(const Eigen::Vector2d& ideal_pixel) const;

    // Largest undistorted radius (in normalised coordinates) up to which the radial part of the
    // model is monotonic; infinity when it is monotonic everywhere.
    double maxValidRadius() const;
    // True when the radial part is monotonic for every squared radius in [0, r2]: its slope is
    // positive at 64 samples of [0, r2]. Answered without sampling below a bound, and below the
    // squared radius up to which the slope is proved positive (computed once per set of
    // coefficients, cached; the same answers).
    bool radialMonotonicUpTo(double r2) const;

    bool inImage(const Eigen::Vector2d& pixel, double margin = 0.0) const {
        return pixel.x() >= -0.5 + margin && pixel.y() >= -0.5 + margin && pixel.x() <= width - 0.5 - margin &&
               pixel.y() <= height - 0.5 - margin;
    }

    Eigen::Matrix3d K() const;

    // OpenGL projection matrix (column vectors, clip = P * p_in_gl_cam) for the undistorted
    // pinhole with this camera's fx fy cx cy, where the GL camera looks along -z with y up
    // (p_in_gl_cam = diag(1, -1, -1) * p_in_cam). Pixel centres land on the same pixels as
    // project() with zero distortion, for a viewport of width x height.
    Eigen::Matrix4d glProjection(double near_m, double far_m) const;

private:
    // radialMonotonicUpTo's squared radius for the radial coefficients it was computed for: read
    // and filled by any thread (a sequence lock over atomics: a reader that overlaps a writer
    // computes the value itself). The fields above are public, so it is keyed by the coefficients
    // and follows a changed distortion. Not part of the camera: copied with it, ignored by ==.
    class MonotonicCache {
    public:
        MonotonicCache() = default;
        MonotonicCache(const MonotonicCache& other) noexcept { copyFrom(other); }
        MonotonicCache& operator=(const MonotonicCache& other) noexcept {
            if (this != &other) copyFrom(other);
            return *this;
        }
        bool operator==(const MonotonicCache&) const noexcept { return true; }
        std::optional<double> find(const Distortion& d) const noexcept;
        void store(const Distortion& d, double r2) const noexcept;

    private:
        void copyFrom(const MonotonicCache& other) noexcept;
        mutable std::atomic<std::uint64_t> version_{0};  // 0: empty; odd: being written
        mutable std::atomic<double> k1_{0.0}, k2_{0.0}, k3_{0.0}, r2_{0.0};
    };
    MonotonicCache monotonic_cache_;
};

}  // namespace commonlight

// A distant light's direction from the shading of a known convex proxy (seed 002 sec. 5): a check
// of the light estimate and a fallback when shadows say little.
//
// Angles follow seed 002: the light direction L (towards the light) in the viewer's frame (x right,
// y up in the image, z towards the viewer); tilt = atan2(L_y, L_x) in degrees in [0, 360), slant =
// acos(L_z) in degrees (0: light from the viewer; tilt is undefined there).
//
// Three classic estimators work on the image alone, assuming the surface normals are isotropically
// distributed (a sphere seen orthographically): Pentland (1982), tilt and slant from the mean
// directional derivatives of intensity and their spread; Lee and Rosenfeld (1985), slant from the
// mean and mean square of intensity over the object (for a Lambertian sphere without attached
// shadow E[I] = 2/3 rho lambda cos(slant), E[I^2] = rho^2 lambda^2 (1 + cos^2(slant)) / 4). Seed 002's
// "improved" estimator (Liu 1994) is described in one paragraph, not enough to reproduce; its
// published Table 3 is compared as printed. Ours uses what the system knows: the proxy's geometry and pose give each pixel's
// normal, and the Lambertian model radiance = a max(0, n . l) + b is fitted over the object's
// pixels by Ceres (l on the unit sphere, a, b >= 0, a soft-L1 loss against the terminator),
// started from a linear least-squares fit on the clearly lit pixels.
#pragma once

#include <optional>

#include <Eigen/Core>

#include "core/camera_model.h"
#include "core/image.h"
#include "core/pose.h"
#include "core/result.h"

namespace commonlight::lighting {

struct TiltSlant {
    double tilt_deg = 0.0;
    double slant_deg = 0.0;
};

// Tilt and slant of a direction given in the viewer's frame (x right, y up, z towards the viewer).
TiltSlant tiltSlantOf(const Eigen::Vector3d& towards_light_view);
// The direction (unit, viewer's frame) of a tilt and slant.
Eigen::Vector3d directionOf(const TiltSlant& ts);

// The image-only estimators, on a luminance image (row-major, width x height, linear) and a mask of
// the object's pixels (non-zero = object). Errors: fewer than 50 object pixels, no shading.
Result<TiltSlant> estimatePentland(const std::vector<float>& luminance, const std::vector<std::uint8_t>& mask, int width,
                                   int height);
Result<TiltSlant> estimateLeeRosenfeld(const std::vector<float>& luminance, const std::vector<std::uint8_t>& mask,
                                       int width, int height);

struct ShadingFit {
    Eigen::Vector3d towards_light_world = Eigen::Vector3d::UnitZ();  // unit
    TiltSlant view;            // in the camera's viewer frame
    double scale = 0.0;        // a: radiance of a surface facing the light, relative units
    double ambient = 0.0;      // b
    double rms = 0.0;          // residual RMS / mean radiance over the object's pixels
    double uncertainty_deg = 0.0;  // one standard error of the direction (from the fit's covariance)
    int pixels = 0;
};

struct ShadingFitOptions {
    double saturation = 0.98;   // pixels at or above this fraction of the image's maximum are left out
    int min_pixels = 50;
};

// Our estimator: a sphere (centre, radius, world) seen by `camera` at `cam_from_world`;
// `radiance` is RGB float (kRgbF32) linear radiance. Errors (kBadInput): a non-finite input, fewer
// than min_pixels usable pixels, a light from behind that lights too few of them to fit.
Result<ShadingFit> fitSphereLight(const ImageView& radiance, const CameraModel& camera, const Rigid3d& cam_from_world,
                                  const Eigen::Vector3d& centre, double radius, const ShadingFitOptions& options = {});

}  // namespace commonlight::lighting

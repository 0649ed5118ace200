// Camera matching (Klein and Murray, "Compositing for small cameras", ISMAR 2008): measure the
// frame's sensor noise and blur, so the compositor can give the virtual layer the same (off by
// default: CompositorOptions::camera_matching). CPU, OpenCV.
//
// Noise: the residual of Immerkaer's mask (1996), [1 -2 1; -2 4 -2; 1 -2 1], which cancels
// locally planar (and most curved) image structure; pure noise of standard deviation s gives a
// residual of standard deviation 6 s. Per channel and per bin of the local mean code (the noise of
// a sensor grows with the signal, and the response curve reshapes it), s = 1.4826 median|residual|
// / 6 over the flattest half of the bin's pixels (by the local gradient), so edges and texture do
// not count as noise; a quarter of the pixels (every other one of every other row) are used.
//
// Blur: the Gaussian PSF (standard deviation in pixels) of step edges. At strong, isolated
// Canny edges the pixels in a strip across the edge, in linear light (the camera's response
// inverted), are fitted with a + b Phi((d - d0) / sigma) (d: signed distance to the edge line;
// OpenCV's Levenberg-Marquardt; about 400 edge points); the median sigma of the fits whose
// residual is small. It is the
// whole image PSF, the pixel's own integration included (a sharp edge sampled by square pixels
// gives about 0.3 px).
#pragma once

#include <array>
#include <cstdint>

#include <Eigen/Core>

#include "core/image.h"
#include "core/response.h"
#include "core/result.h"

namespace commonlight::render {

struct NoiseProfile {
    static constexpr int kBins = 16;  // local mean code 0..255, 16 codes per bin
    // Standard deviation in 8-bit codes per bin and channel; a bin with too few pixels takes its
    // nearest measured neighbours' (interpolated), none measured: `overall`.
    std::array<Eigen::Vector3f, kBins> sigma{};
    std::array<int, kBins> pixels{};                  // pixels that measured each bin (all channels)
    Eigen::Vector3f overall = Eigen::Vector3f::Zero();  // every flat pixel, one value per channel

    // Interpolated between bin centres (codes 8, 24, ... 248), held beyond them.
    float at(int channel, float code) const;
};

struct BlurEstimate {
    double sigma_px = 0.0;  // median of the accepted edges' Gaussian sigma (pixels); 0 when none was accepted
    int edges = 0;          // edges accepted
    double spread = 0.0;    // 1.4826 x their median absolute deviation (pixels)
};

// `rgb` is kRgb8. kBadInput: another format, or an image smaller than 16 x 16.
Result<NoiseProfile> estimateNoise(const ImageView& rgb);
Result<BlurEstimate> estimateBlur(const ImageView& rgb, const ResponseCurve& response);

}  // namespace commonlight::render

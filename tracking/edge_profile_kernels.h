// The sampling loop of edgeOffset (edge_profile.h), one function per instruction set, so that the
// tests can hold each against the plain loop. Internal to tracking/.
#pragma once

#include <Eigen/Core>

#include "core/image.h"

namespace commonlight::tracking::detail {

// values[i], i in [0, 2 steps + 3): the mean of three bilinear samples of `lut`[pixel] at
// p + (i - steps - 1) 0.25 n + {-0.5, 0, 0.5} along (every sample inside the image, with the
// one-pixel margin edgeOffset checks). Every kernel gives the plain loop's values bit for bit:
// each lane does its operations in its order, and none is fused.
void sampleProfilePlain(const ImageView& img, const double* lut, const Eigen::Vector2d& p, const Eigen::Vector2d& n,
                        const Eigen::Vector2d& along, int steps, double* values);
// Two steps per SSE2 vector (x86-64); elsewhere the plain loop.
void sampleProfileSse2(const ImageView& img, const double* lut, const Eigen::Vector2d& p, const Eigen::Vector2d& n,
                       const Eigen::Vector2d& along, int steps, double* values);
// Four steps per AVX2 vector: only where avx2Available() and the image's bytes fit an int. The
// pixels and their `lut` values are read by gathers, except on profiles that reach the image's
// last rows (a pixel's 4-byte read there could leave the buffer).
bool avx2Available();
void sampleProfileAvx2(const ImageView& img, const double* lut, const Eigen::Vector2d& p, const Eigen::Vector2d& n,
                       const Eigen::Vector2d& along, int steps, double* values);

}  // namespace commonlight::tracking::detail

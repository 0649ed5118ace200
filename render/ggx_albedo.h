// The directional albedo of the GGX microfacet reflection the compositor draws virtual objects
// with (`material: {type: ggx}`), split for Schlick's Fresnel term: the fraction of the light
// arriving uniformly from the whole hemisphere that a surface of reflectance F0 at normal incidence
// reflects towards a viewer at cos_o is  F0 A(cos_o, roughness) + B(cos_o, roughness).
// The compositor uses it for the light reflected from the snapshot's indirect irradiance, which
// has no direction finer than its spherical harmonics (docs/rendering.md, "GGX").
//
// The BRDF (radiance per irradiance, 1/sr): f = D(h) G(wo, wi) F(wi.h) / (4 cos_o cos_i),
//   D = a^2 / (pi ((n.h)^2 (a^2 - 1) + 1)^2), a = roughness^2 (at least kGgxMinAlpha),
//   G = G1(wo) G1(wi) (Smith, separable), G1(v) = 2 cos_v / (cos_v + sqrt(a^2 + (1 - a^2) cos_v^2)),
//   F = F0 + (1 - F0) (1 - wi.h)^5.
// No diffuse layer (a metal-like lobe) and no multiple scattering between microfacets: a rough
// surface loses energy (A + B < 1).
#pragma once

#include <Eigen/Core>
#include <vector>

namespace commonlight::render {

constexpr double kGgxMinAlpha = 1e-3;

// A and B at one point, by `samples` (>= 1) half vectors drawn from D(h) (n.h) along a
// Hammersley sequence (deterministic). cos_o is clamped to [1e-4, 1], roughness to [0, 1].
Eigen::Vector2d ggxAlbedoSplit(double cos_o, double roughness, int samples);

// The table the shader reads: `n` x `n` (A, B) pairs, row-major with cos_o along a row and the
// roughness down the rows, both from 0 to 1 at the texel centres (texel k at k / (n - 1)).
std::vector<float> ggxAlbedoTable(int n, int samples);

}  // namespace commonlight::render

// Unidirectional path tracing with next-event estimation (NEE) and multiple importance sampling.
//
// At every scattering vertex:
// - every light of SimScene::lights() is sampled once (NEE) with a shadow ray: rectangles and
//   discs uniformly by area, point and directional lights exactly (they are deltas);
// - the BSDF is sampled once to continue the path (cosine-weighted for Lambertian, the GGX
//   normal distribution for GGX).
// Area lights are therefore found by two techniques; their contributions are weighted with Veach's
// power heuristic (one sample per technique). The distant environment is sampled by NEE (uniform
// directions over the upper hemisphere) at Lambertian vertices and found by BSDF sampling at GGX
// vertices, one technique per vertex. Emissive virtual objects are found by BSDF sampling only
// (weight 1): unbiased, but noisier for small bright emitters. Light surfaces absorb: a path ends
// on a light.
//
// Depth: a path of depth d has d scattering events; max_depth = 1 is direct lighting only, 0 shows
// emitters alone. From rr_start_depth scattering events on, Russian roulette ends a path with
// probability 1 - q, q = min(0.95, largest channel of the throughput), and divides survivors by q:
// unbiased, and cheap for deep paths in bright closed rooms.
#pragma once

#include <cstdint>

#include <Eigen/Core>

#include "mocks/sim/camera_rays.h"
#include "mocks/sim/embree_scene.h"
#include "mocks/sim/sampling.h"

namespace commonlight::mocks::sim {

struct IntegratorOptions {
    int max_depth = 32;      // largest number of scattering events on a path, >= 0
    int rr_start_depth = 3;  // Russian roulette from this many scattering events on, >= 1
};

// The first surface a camera ray met.
struct PrimaryHit {
    int object = -1;  // index into SimScene::objects(), -1 when the ray left the scene
    bool is_virtual = false;
};

// Sampler dimensions used by the renderer for the camera (the integrator uses those after them).
inline constexpr int kDimensionPixel = 0;  // 2D: position in the pixel
inline constexpr int kDimensionTime = 1;   // 1D: time in the exposure

class PathTracer {
public:
    // Borrows the scene for its lifetime. Thread-safe: const methods only, no shared state.
    PathTracer(const SimScene& scene, const IntegratorOptions& options);

    // Radiance (W/(m^2 sr)) arriving at ray.origin along -ray.dir, one sample: sample `sample` of
    // `sampler`. May be non-finite only through a bug; callers drop such samples and count them.
    Eigen::Vector3d radiance(const Ray& ray, const PixelSampler& sampler, int sample, PrimaryHit* primary) const;

    // Radiance leaving a white Lambertian receiver (albedo 1, not part of the scene) at `point`
    // with unit normal `normal`, towards +normal; pi times its mean is the irradiance there.
    // Rays leave from point + rayEpsilon() * normal.
    Eigen::Vector3d probeRadiance(const Eigen::Vector3d& point, const Eigen::Vector3d& normal,
                                  const PixelSampler& sampler, int sample) const;

private:
    Eigen::Vector3d trace(Ray ray, const SurfaceHit* first_hit, const PixelSampler& sampler, int sample,
                          PrimaryHit* primary) const;
    Eigen::Vector3d directLight(const SurfaceHit& hit, const ShadingFrame& frame, const Eigen::Vector3d& wo,
                                const PixelSampler& sampler, int sample, int vertex) const;
    int dimension(int vertex, int slot) const noexcept { return 2 + (vertex - 1) * dims_per_vertex_ + slot; }

    const SimScene& scene_;
    IntegratorOptions options_;
    int dims_per_vertex_;
};

// Irradiance (W/m^2 per channel) at `point` on a receiver facing `normal` (unit), estimated with
// `samples` samples (>= 1) of the renderer's own light transport (PathTracer::probeRadiance):
// direct light by NEE + MIS and indirect light by path tracing. Deterministic for a seed.
Eigen::Vector3d estimateIrradiance(const SimScene& scene, const Eigen::Vector3d& point, const Eigen::Vector3d& normal,
                                   int samples, std::uint64_t seed, const IntegratorOptions& options = {});

}  // namespace commonlight::mocks::sim

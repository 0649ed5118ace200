// From a radiosity solution to what the renderer draws (lighting/snapshot.h): per real face the
// modulation textures, per virtual object the irradiance probes.
#pragma once

#include <functional>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "lighting/direct.h"
#include "lighting/radiosity.h"
#include "lighting/snapshot.h"

namespace commonlight::lighting {

// Modulation textures of the real faces `faces` (real face indices), in that order; nullopt for a
// face that takes no part in transport (every leaf buried). `without` is B~ (real scene alone),
// `with` is B, `rho` the reflectance, all by element. Texels are as fine as the face's finest leaf
// (at most `max_texels` per side); values are box-filtered over the local leaf size, which
// interpolates linearly between element centres (smooth across element borders).
//
// `texel_direct` (optional): the direct light of the area lights per texel where the virtual
// objects change it (issue 12: per-texel shadow rays measured better than the elements' for the
// direct term, docs/lighting.md). By element, that direct light without and with the objects
// (irradiance); at a texel where they differ (box-filtered), the filtered one is swapped for what
// `at` gives at the texel's point: its direct light without and with the objects.
struct TexelDirect {
    const std::vector<Eigen::Vector3d>* without = nullptr;
    const std::vector<Eigen::Vector3d>* with = nullptr;
    // (face, texel, layout width x height, point) -> direct without, direct with. Called in parallel.
    std::function<void(int, std::size_t, int, int, const Eigen::Vector3d&, Eigen::Vector3d&, Eigen::Vector3d&)> at;
    double threshold = 0.0;  // |with - without| (irradiance, largest channel) below this: no change
    int oversample = 1;      // texels per finest leaf along each side (the faces of a parallelogram)
};
std::vector<std::optional<FaceModulation>> buildFaceModulations(const Radiosity& radiosity, const Scene& scene,
                                                                const std::vector<Eigen::Vector3d>& without,
                                                                const std::vector<Eigen::Vector3d>& with,
                                                                const std::vector<Eigen::Vector3d>& rho, const std::vector<int>& faces,
                                                                int max_texels = 256, const TexelDirect* texel_direct = nullptr);

// A light as the probes see it: its unit-emission source and its emission (relative units, RGB).
// `indirect`: counted in the probes' indirect part (an unknown environment's residual, which the
// renderer does not draw as a light).
struct ProbeLight {
    DirectSource source;
    Eigen::Vector3d emission = Eigen::Vector3d::Zero();
    bool indirect = false;
};

// The irradiance arriving at point `p` (world) as order-2 SH (lighting/snapshot.h IrradianceSh):
// `indirect` from every surface a ray from `p` meets (the leaf's value in `radiance`, by element:
// real leaves and the other virtual objects' faces), and the environment's residual (distant
// cells flagged `indirect`); `direct` from the other `lights`, sampled on their geometry, through
// real and virtual occluders. Virtual object `object` itself is transparent to these rays (the
// point lies inside it); -1: none. `directions`: sampled directions (Fibonacci sphere).
// `other_objects` false: the other virtual objects are not there at all (neither seen nor blocking).
struct ProbeIrradiance {
    IrradianceSh indirect;
    IrradianceSh direct;
};
ProbeIrradiance probeIrradiance(const Radiosity& radiosity, const Eigen::Vector3d& p, int object,
                                const std::vector<Eigen::Vector3d>& radiance, const std::vector<ProbeLight>& lights,
                                int directions, std::uint64_t seed, bool other_objects = true);

// Irradiance probes over each virtual object's bounds (lighting/snapshot.h VirtualIrradiance),
// each probeIrradiance() with `radiance` the solution with the virtual objects (B).
std::vector<VirtualIrradiance> buildProbes(const Radiosity& radiosity, const Scene& scene, const std::vector<Eigen::Vector3d>& radiance,
                                           const std::vector<ProbeLight>& lights, int directions = 256);

}  // namespace commonlight::lighting

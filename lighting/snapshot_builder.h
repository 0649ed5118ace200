// From a radiosity solution to what the renderer draws (lighting/snapshot.h): per real face the
// modulation textures, per virtual object the irradiance probes.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "lighting/direct.h"
#include "lighting/radiosity.h"
#include "lighting/snapshot.h"

namespace commonlight::lighting {

// Modulation textures of every real face that takes part in transport. `without` is B~ (real scene
// alone), `with` is B; `rho` per element. Texels are as fine as the face's finest leaf (at most
// `max_texels` per side); values are box-filtered over the local leaf size, which interpolates
// linearly between element centres (smooth across element borders).
std::vector<FaceModulation> buildFaceModulations(const Radiosity& radiosity, const Scene& scene, const Solution& without,
                                                 const Solution& with, const std::vector<Eigen::Vector3d>& rho,
                                                 int max_texels = 256);

// A light as the probes see it: its unit-emission source and its emission (relative units, RGB).
// `indirect`: counted in the probes' indirect part (an unknown environment's residual, which the
// renderer does not draw as a light).
struct ProbeLight {
    DirectSource source;
    Eigen::Vector3d emission = Eigen::Vector3d::Zero();
    bool indirect = false;
};

// Irradiance probes over each virtual object's bounds (lighting/snapshot.h VirtualIrradiance):
// `indirect` from every surface the probe sees (leaf radiances of `with`, other virtual objects,
// the environment's residual), `direct` from `lights`, through real and virtual occluders except
// the object itself. `directions`: sampled directions per probe.
std::vector<VirtualIrradiance> buildProbes(const Radiosity& radiosity, const Scene& scene, const Solution& with,
                                           const std::vector<ProbeLight>& lights, int directions = 256);

}  // namespace commonlight::lighting

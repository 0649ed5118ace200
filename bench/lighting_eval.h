// The measuring harness of the lighting module: frames and ground truth from the simulated camera
// (mocks/sim, path tracing), fed to the estimator (lighting/), compared with what the simulator
// knows. It links both and shares no light transport between them: lighting/ is measured, mocks/sim
// is the truth (DESIGN.md section 6). Used by `commonlight bench lighting` and the lighting tests.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/camera_model.h"
#include "core/image.h"
#include "core/pose.h"
#include "core/result.h"
#include "core/scene.h"
#include "lighting/estimator.h"
#include "mocks/sim/sensor_params.h"

namespace commonlight::bench {

// One simulated frame through the sensor.
struct SimFrame {
    Image rgb8;
    Rigid3d cam_from_world;
    double exposure_s = 0.01;
    double gain = 1.0;
    Image radiance;  // kRgbF32, W/(m^2 sr): the path-traced truth before the sensor (optional)
};

struct RenderSettings {
    int spp = 64;
    int max_depth = 8;
    std::uint64_t seed = 1;
    bool include_virtual = false;  // render the virtual objects too (the composite)
    bool keep_radiance = false;
    mocks::sim::SensorParams sensor;
};

// Renders `truth` (every light's emission and every albedo given) from each pose.
Result<std::vector<SimFrame>> renderFrames(const Scene& truth, const CameraModel& camera,
                                           const std::vector<Rigid3d>& world_from_cam, const RenderSettings& settings);

// The relative radiance per W/(m^2 sr) of the simulated sensor: what its frames read as, through
// the inverse response and divided by exposure x gain, for one unit of radiance (black level and
// dark current aside).
double radianceScale(const mocks::sim::SensorParams& sensor);

// Path-traced radiance (W/(m^2 sr)) of real leaves of the estimator's hierarchy: the mean over
// `points` stratified points of albedo / pi x irradiance, each irradiance from the simulator's
// estimateIrradiance with `samples` paths. `with_virtual`: the virtual objects in the scene too.
Result<std::vector<Eigen::Vector3d>> truthOfLeaves(const Scene& truth, const lighting::Estimator& estimator,
                                                   const std::vector<int>& leaves, bool with_virtual, int points,
                                                   int samples, std::uint64_t seed, int max_depth = 32);

// Camera poses on an orbit around `target` (the sim's orbit convention: azimuth 0 on the -y side).
std::vector<Rigid3d> orbitPoses(const Eigen::Vector3d& target, double radius, double height, double from_deg,
                                double to_deg, int count);

// The true scene with its lights and albedos set to `estimate` (what the estimator gets).
Scene asEstimated(const Scene& truth, bool lights, bool albedos);

}  // namespace commonlight::bench

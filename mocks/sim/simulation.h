// `commonlight sim`: renders a sequence (docs/formats-sequence.md) of a scene along a camera
// trajectory, with its ground truth beside it (docs/sim.md):
//
//   SEQ/cam0/            frames through the sensor model (PNG, or JPEG as an MJPEG camera sends
//                        them), data.csv, sensor.yaml (true intrinsics), meta.csv (exposure, gain)
//   SEQ/scene.yaml       the scene as the estimator gets it: real albedos and lights `estimate`
//   SEQ/groundtruth/     cam_poses.csv (world_from_cam at each frame's timestamp, the start of
//                        its exposure), cam_poses_mid_exposure.csv (at the middle of its exposure,
//                        the instant the frame was rendered for), scene.yaml (the true scene),
//                        lights.yaml (the true lights), sensor.yaml (the sensor parameters),
//                        composite/ (the same frames with the virtual objects really there, same
//                        sample and noise seeds), masks/virtual/ (virtual-object coverage),
//                        masks/changed/ (where the virtual objects change real-surface radiance
//                        by more than 1%), radiance/ and radiance_composite/ (linear radiance,
//                        OpenEXR float, W/(m^2 sr))
//
// Every file of a frame is written (atomically) before the frame's data.csv row, so a stop at
// any moment leaves a readable sequence of the completed frames with their ground truth.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <optional>
#include <stop_token>

#include "core/camera_model.h"
#include "core/result.h"
#include "core/scene.h"
#include "mocks/sim/sensor_params.h"
#include "mocks/sim/trajectory.h"

namespace commonlight::mocks::sim {

enum class FrameFileFormat { kPng, kJpeg };

struct SimulationOptions {
    std::filesystem::path out;          // the sequence folder to create
    int frames = 0;                     // 0: the whole trajectory at its rate
    int spp = 64;                       // samples per pixel
    int max_depth = 8;                  // scattering events per path
    std::uint64_t seed = 1;             // sample seed; frame i uses (seed, i); sensor noise likewise
    SensorParams sensor;                // exposure, gain, noise, bit depth, response
    std::optional<CameraModel> camera;  // default: the scene's camera
    bool motion_blur = false;           // average the camera's motion over the exposure
    double rolling_shutter_row_time_s = 0.0;  // > 0: row v starts v * this after row 0
    // Rendering conditions that break tracking's assumptions (docs/tracking.md, "Benchmark"):
    // a slight defocus, the image convolved with a uniform disc of this radius in pixels (the
    // circle of confusion, the same over the image: a scene at one depth), 0 for none, at most 20;
    double defocus_radius_px = 0.0;
    // tags printed with ink spread: black regions grown (> 0) or shrunk (< 0) by this many
    // cells, in [-0.25, 0.25] (PlacedTag::ink_spread_cells).
    double tag_ink_spread_cells = 0.0;
    FrameFileFormat frame_format = FrameFileFormat::kPng;
    int jpeg_quality = 95;
    bool write_composite = true;
    bool write_masks = true;
    bool write_radiance = true;
    double changed_threshold = 0.01;    // masks/changed: relative radiance change that counts

    Result<void> validate() const;  // kUsage naming the option
};

struct SimulationSummary {
    int frames_written = 0;
    double render_seconds = 0.0;   // wall clock spent rendering (both renders of every frame)
    std::int64_t samples = 0;      // camera samples traced
    std::int64_t nonfinite_samples = 0;
    bool stopped = false;          // a stop was requested before the last frame
};

// Called after every frame, on the calling thread: (frames done, frames in total).
using SimulationProgress = std::function<void(int done, int total)>;

// Renders the sequence. `scene` must be the true scene (every light's emission known; real
// albedos default to 0.5 where `estimate`); `scene_file` is where it was read from (for the
// copies written into the sequence). Stops between frames when `stop` is requested (the
// sequence then holds the frames done so far).
Result<SimulationSummary> simulate(const Scene& scene, const Trajectory& trajectory, const SimulationOptions& options,
                                   const SimulationProgress& progress = {}, std::stop_token stop = {});

// The scene as the estimator gets it: real albedos and light emissions replaced by `estimate`.
Scene estimatorScene(const Scene& truth);

}  // namespace commonlight::mocks::sim

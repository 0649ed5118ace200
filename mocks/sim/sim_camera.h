// sim:<scene.yaml>?trajectory=<file>[&spp=16&seed=1&max_depth=8&rate=realtime|max|step&loop=0|1]
//
// The simulated camera as a live camera: its thread renders each frame of the trajectory (the
// real scene only, without the virtual objects) through the sensor model and delivers RGB8 frames
// stamped with the simulated time (TimestampSource::kSimulated), exposure and gain. Rendering
// takes longer than a frame interval at any useful sample count, so `realtime` paces no faster
// than the trajectory's rate and usually runs slower; `step` renders one frame per trigger().
// For sequences with ground truth, use `commonlight sim` (mocks/sim/simulation.h).
#pragma once

#include <memory>
#include <mutex>
#include <optional>

#include "core/clock.h"
#include "core/scene.h"
#include "hal/camera.h"
#include "hal/camera_uri.h"
#include "hal/registry.h"
#include "mocks/pacer.h"
#include "mocks/paced_camera.h"
#include "mocks/sim/embree_scene.h"
#include "mocks/sim/sensor.h"
#include "mocks/sim/trajectory.h"

namespace commonlight::mocks::sim {

struct SimCameraOptions {
    int spp = 16;
    std::uint64_t seed = 1;
    int max_depth = 8;
    PlaybackOptions playback;
    SensorParams sensor;
};

class SimCamera final : public PacedCamera {
public:
    // The scene must have a camera; its lights must be known. `clock` stamps arrival_ns and paces
    // (borrowed, outlives the camera).
    static Result<std::unique_ptr<SimCamera>> open(std::string id, const Scene& scene, Trajectory trajectory,
                                                   const SimCameraOptions& options, Clock& clock);
    static Result<std::unique_ptr<SimCamera>> open(const hal::CameraUri& uri, Clock& clock);
    ~SimCamera() override;

private:
    SimCamera(std::string id, SimScene scene, CameraModel camera, Trajectory trajectory, SensorModel sensor,
              const SimCameraOptions& options, Clock& clock);
    std::vector<hal::StreamFormat> doFormats() const override;
    Result<hal::StreamFormat> doConfigure(const hal::StreamConfig& config) override;
    std::vector<hal::ControlInfo> doControls() const override;
    // Exposure and gain change the sensor model for the next frame (any thread but the camera's).
    Result<void> doSetControl(hal::Control control, double value) override;
    Result<double> doGetControl(hal::Control control) const override;
    std::string doResponseSpec() const override;
    std::optional<CameraModel> doCalibration() const override { return camera_; }
    std::shared_ptr<const SensorModel> currentSensor() const;
    void run(std::stop_token stop) override;  // the camera thread

    SimScene scene_;
    CameraModel camera_;
    Trajectory trajectory_;
    mutable std::mutex sensor_mutex_;                 // guards sensor_ and options_.sensor
    std::shared_ptr<const SensorModel> sensor_;      // replaced (never modified) when a control changes
    SimCameraOptions options_;
};

// The URI options sim: accepts besides the common ones.
inline constexpr const char* kSimOptionNames[] = {"trajectory", "spp", "seed", "max_depth", "rate", "loop", "speed"};

// Registers sim: (borrowing `clock`, which must outlive every camera opened).
void registerSimBackend(hal::CameraRegistry& registry, Clock& clock = SteadyClock::instance());

}  // namespace commonlight::mocks::sim

// Camera trajectories for the simulated camera (docs/sim.md): keyframes interpolated on SE(3),
// or a named generator (orbit, pan) evaluated exactly at any time.
//
//   rate_hz: 30                              # frames per second of the rendered sequence
//   keyframes:                               # times in seconds, strictly increasing
//     - {t: 0.0, eye: [0.6, -0.9, 1.3], target: [0, 0, 0.75]}          # look-at, z up
//     - {t: 2.0, world_from_cam: {t: [...], q_wxyz: [...]}}              # or any transform
//
//   orbit: {target: [0, 0, 0.75], radius: 1.0, height: 0.5, from_deg: -20, to_deg: 20, duration: 2}
//   pan:   {eye: [0, -1, 1.3], from: [-0.3, 0, 0.75], to: [0.3, 0, 0.75], duration: 2}
//
// Exactly one of keyframes, orbit or pan. world_from_cam uses OpenCV camera axes.
#pragma once

#include <filesystem>
#include <string>
#include <variant>
#include <vector>

#include <Eigen/Core>

#include "core/pose.h"
#include "core/result.h"

namespace commonlight::mocks::sim {

struct CameraKeyframe {
    double t_s = 0.0;
    Rigid3d world_from_cam;
};

// Circle around `target` at `height` above it, from azimuth from_deg to to_deg (0 = looking
// along +y from -y), at constant angular speed.
struct OrbitTrajectory {
    Eigen::Vector3d target = Eigen::Vector3d::Zero();
    double radius = 1.0;
    double height = 0.5;
    double from_deg = 0.0;
    double to_deg = 0.0;
    double duration_s = 1.0;
};

// A fixed eye whose look-at target moves on a straight line from `from` to `to`.
struct PanTrajectory {
    Eigen::Vector3d eye = Eigen::Vector3d::Zero();
    Eigen::Vector3d from = Eigen::Vector3d::UnitY();
    Eigen::Vector3d to = Eigen::Vector3d::UnitY();
    double duration_s = 1.0;
};

class Trajectory {
public:
    static Result<Trajectory> read(const std::filesystem::path& file);
    static Result<Trajectory> parse(const std::string& text, const std::string& name);
    static Result<Trajectory> fromKeyframes(std::vector<CameraKeyframe> keyframes, double rate_hz = 30.0);

    // The pose at time t (seconds): keyframes are interpolated on SE(3) (screw motion) and held
    // before the first and after the last; generators are evaluated exactly.
    Rigid3d worldFromCam(double t_s) const;
    double startTime() const noexcept;
    double endTime() const noexcept;
    double rateHz() const noexcept { return rate_hz_; }
    // Frames covering [start, end] at rateHz(): floor(duration * rate) + 1.
    int frameCount() const noexcept;

private:
    std::variant<std::vector<CameraKeyframe>, OrbitTrajectory, PanTrajectory> path_;
    double rate_hz_ = 30.0;
};

}  // namespace commonlight::mocks::sim

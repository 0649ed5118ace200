#include "mocks/sim/camera_rays.h"

#include <algorithm>
#include <cmath>
#include <utility>

namespace commonlight::mocks::sim {

CameraRays::CameraRays(const CameraModel& camera, const Rigid3d& world_from_cam, CameraPoseFunction pose_at,
                       double exposure_s, double row_time_s)
    : camera_(camera), pose_at_(std::move(pose_at)), exposure_s_(exposure_s), row_time_s_(row_time_s) {
    // Without motion blur a row sees one pose: evaluate it once per row here, on one thread.
    if (!pose_at_ || exposure_s_ == 0.0) {
        row_poses_.reserve(static_cast<std::size_t>(std::max(camera.height, 0)));
        for (int row = 0; row < camera.height; ++row) {
            row_poses_.push_back(pose_at_ ? pose_at_(sampleTime(row, 0.0)) : world_from_cam);
        }
    }
}

std::optional<Ray> CameraRays::ray(const Eigen::Vector2d& pixel, int row, double t) const {
    const std::optional<Eigen::Vector3d> xy1 = camera_.unproject(pixel);
    if (!xy1) return std::nullopt;  // beyond the fold of strong barrel distortion: no ray
    const Rigid3d pose = row_poses_.empty() ? pose_at_(t) : row_poses_[static_cast<std::size_t>(row)];
    Ray out;
    out.origin = pose.translation;
    out.dir = (pose.rotation * xy1->normalized()).normalized();
    return out;
}

std::optional<Ray> CameraRays::centreRay(int column, int row) const {
    return ray(Eigen::Vector2d(column, row), row, sampleTime(row, 0.0));
}

}  // namespace commonlight::mocks::sim

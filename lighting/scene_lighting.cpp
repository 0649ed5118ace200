#include "lighting/scene_lighting.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numbers>
#include <variant>

#include "lighting/direct.h"
#include "lighting/estimator.h"
#include "lighting/light_fit.h"
#include "lighting/observations.h"
#include "lighting/radiosity.h"
#include "lighting/snapshot_builder.h"

namespace commonlight::lighting {

Result<std::unique_ptr<SceneLighting>> SceneLighting::create(const Scene& scene, const CameraModel& camera,
                                                             const SceneLightingOptions& options) {
    CL_TRY_VOID(camera.validate());
    CL_TRY(std::unique_ptr<Estimator> estimator, Estimator::create(scene, camera, options));
    return std::unique_ptr<SceneLighting>(std::move(estimator));
}

std::vector<Rigid3d> SceneLighting::scenePoses(const Scene& scene, double t_s) {
    std::vector<Rigid3d> poses;
    poses.reserve(scene.virtual_objects.size());
    for (const VirtualObject& object : scene.virtual_objects) {
        poses.push_back(worldFromObject(object, scene.tags, t_s).value_or(Rigid3d::identity()));
    }
    return poses;
}

}  // namespace commonlight::lighting

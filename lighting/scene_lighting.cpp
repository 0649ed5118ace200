#include "lighting/scene_lighting.h"

namespace commonlight::lighting {

namespace {

// Interim model while the estimator is being built: accepts observations and publishes a
// snapshot that changes nothing (every ratio 1, no light), which the renderer accepts.
class PassThroughLighting final : public SceneLighting {
public:
    Result<void> observe(const ImageView&, const Rigid3d&, double, double, std::int64_t) override { return {}; }
    Result<LightingSnapshot> update(const std::vector<Rigid3d>&) override { return LightingSnapshot{}; }
};

}  // namespace

Result<std::unique_ptr<SceneLighting>> SceneLighting::create(const Scene&, const CameraModel& camera,
                                                             const SceneLightingOptions&) {
    CL_TRY_VOID(camera.validate());
    return std::unique_ptr<SceneLighting>(new PassThroughLighting());
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

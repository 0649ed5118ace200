// SceneLighting: the lighting state of one scene, driven by the lighting thread
// (lighting/engine.h) or directly by tests and benchmarks.
//
// Step 1, observe(): a frame with its pose adds what it shows of each proxy element to the
// accumulated observations (lighting/observations.h).
// Step 2, update(): estimates lights and reflectances from everything observed so far, solves
// radiosity without (B~) and with (B) the virtual objects at the given poses, and returns the
// snapshot the renderer draws with.
#pragma once

#include <memory>
#include <vector>

#include "core/camera_model.h"
#include "core/image.h"
#include "core/pose.h"
#include "core/response.h"
#include "core/result.h"
#include "core/scene.h"
#include "lighting/snapshot.h"

namespace commonlight::lighting {

struct SceneLightingOptions {
    ResponseCurve response = ResponseCurve::srgb();
    std::optional<double> radiance_scale;  // relative radiance per W/(m^2 sr); nullopt: 1 assumed
    int observation_stride = 2;            // ray cast every n-th pixel in x and y
    int observation_interleave = 1;        // k: each frame casts one of k x k offsets in turn (observations.h)
    // A full update (lights and reflectances refitted when the observations have doubled) no
    // sooner than this many observations after the last one (0: whenever they double).
    int refit_min_frames = 0;
};

class SceneLighting {
public:
    // Errors: degenerate proxies (kBadInput naming the object), an invalid camera.
    static Result<std::unique_ptr<SceneLighting>> create(const Scene& scene, const CameraModel& camera,
                                                         const SceneLightingOptions& options);
    virtual ~SceneLighting() = default;

    // The virtual objects' poses for the next observe() (their pixels are left out) and update().
    virtual void setVirtualPoses(const std::vector<Rigid3d>& world_from_object) = 0;
    // Adds one frame's observations. `rgb8` is the distorted frame at the camera's size.
    // exposure_s x gain must be positive (the caller substitutes 1 when unknown).
    virtual Result<void> observe(const ImageView& rgb8, const Rigid3d& cam_from_world, double exposure_s,
                                 double analog_gain, std::int64_t timestamp_ns) = 0;
    // Estimates and solves for the virtual objects at these poses (by Scene::virtual_objects index).
    // The snapshot's version, timestamps and timing are left for the caller to fill in.
    virtual Result<LightingSnapshot> update(const std::vector<Rigid3d>& virtual_world_from_object) = 0;

    // Whether the last update() estimated and solved everything again (a full update: the light
    // fit, B~), or only brought the virtual objects' influence up to date (incremental).
    virtual bool lastUpdateFull() const { return true; }
    // Whether the next update() will be a full one, as far as the observations so far decide.
    virtual bool nextUpdateFull() const { return true; }

    // The ratio B/B~ a snapshot predicts for a view (lighting/estimator.h ratioImage()).
    // `through_virtual`: the real surface behind a virtual object too; it then reads only what no
    // update changes (the real scene's rays and faces) and the snapshot, so any thread may call it
    // while another updates.
    virtual Result<Image> ratioImage(const LightingSnapshot& snapshot, const Rigid3d& cam_from_world, int stride,
                                     bool through_virtual = false) const = 0;

    // The virtual objects' poses in the scene file at time t (keyframes, tags at their world
    // placement); identity for a tag-attached object whose tag is unknown.
    static std::vector<Rigid3d> scenePoses(const Scene& scene, double t_s);
};

}  // namespace commonlight::lighting

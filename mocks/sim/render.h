// Renders one frame of the simulated camera: linear radiance per pixel (before any sensor), plus
// the per-pixel facts the ground truth needs (which object is seen, how much of the pixel is
// covered by virtual objects).
//
// Determinism: the value of a pixel depends only on (seed, frame_index, pixel index) and the
// request, never on the number of threads or their scheduling: the same request gives the same
// bytes. Work is split into 16 x 16 tiles rendered in parallel with tbb::parallel_for (it honours
// an enclosing tbb::global_control or task_arena).
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include "core/camera_model.h"
#include "core/image.h"
#include "core/pose.h"
#include "core/result.h"
#include "mocks/sim/camera_rays.h"
#include "mocks/sim/embree_scene.h"
#include "mocks/sim/path_tracer.h"

namespace commonlight::mocks::sim {

// A rectangle of pixels: columns [x, x + width), rows [y, y + height).
struct PixelRect {
    int x = 0;
    int y = 0;
    int width = 0;
    int height = 0;
};

struct RenderRequest {
    const SimScene* scene = nullptr;  // borrowed for the call
    CameraModel camera;               // intrinsics and distortion; the image is camera.width x camera.height
    Rigid3d world_from_cam;           // the camera's pose when world_from_cam_at is empty
    // Optional time-dependent pose (motion blur, rolling shutter): t in seconds since the start of
    // the exposure of row 0. Called from the render threads concurrently.
    CameraPoseFunction world_from_cam_at;
    int spp = 16;            // samples per pixel, >= 1
    std::uint64_t seed = 0;  // with frame_index, determines every random decision
    std::uint64_t frame_index = 0;
    int max_depth = 32;                       // largest number of scattering events on a path (1: direct light only)
    double exposure_s = 0.0;                  // motion blur: each sample's time is uniform over the exposure
    double rolling_shutter_row_time_s = 0.0;  // row v starts its exposure v * this after row 0
    std::optional<PixelRect> region;          // render only these pixels (the others are 0 / -1); all when empty

    // A scene, a valid camera, spp >= 1, max_depth >= 0, finite non-negative times, a region inside the image.
    Result<void> validate() const;
};

struct RenderOutput {
    // Linear radiance, W/(m^2 sr) per RGB channel: the mean over the pixel's samples of the radiance
    // arriving at the camera along each sample's ray (a box filter over the pixel's square in the
    // distorted image). PixelFormat::kRgbF32.
    Image radiance;
    // Per pixel (row-major, width x height): the object (index into SimScene::objects()) hit by the
    // ray through the pixel centre at the start of its row's exposure; -1 for none.
    std::vector<std::int32_t> object_id;
    // Per pixel: the fraction of the samples whose first hit is a virtual object, in [0, 1].
    std::vector<float> virtual_coverage;
    int width = 0;
    int height = 0;
    std::int64_t samples = 0;            // camera samples traced
    std::int64_t nonfinite_samples = 0;  // samples dropped because their value was not finite (a bug if > 0)
    double seconds = 0.0;                // wall-clock time of the render
};

// Renders the request. Fails (kUsage) when the request is invalid.
Result<RenderOutput> render(const RenderRequest& request);

}  // namespace commonlight::mocks::sim

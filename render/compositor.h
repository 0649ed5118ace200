// The compositor: the camera frame with the virtual objects inserted, lit by the estimated light,
// and the real surfaces darkened or brightened by the lighting ratio (seed 000 sec. 4.3,
// Debevec's differential rendering). docs/rendering.md has the passes and their units.
//
// Passes, per frame:
//   1. shadow maps of the estimated lights (real proxies and virtual objects as occluders; an area
//      light gets one map per sample point, so its shadows are soft);
//   2. the 3D layer, in the undistorted pinhole image (MSAA): real proxies for depth, writing the
//      background's modulation M = w ratio + (1 - w) and D = (1 - w) (B - B~) (w: ratioWeight),
//      then the virtual objects, depth-tested against the proxies, shaded in linear relative
//      radiance: albedo / pi x (direct irradiance x shadow-map visibility + the snapshot's indirect
//      SH irradiance) + their emission;
//   3. the final pass at each camera pixel p: the frame's code at p linearised with the camera's
//      response, the layer sampled at undistort(p) (exact lens distortion), combined as
//      (bg M + D eg)(1 - a) + V eg with eg = exposure x gain, and encoded with the response. A pixel
//      nothing changes keeps its code exactly.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <vector>

#include "core/camera_model.h"
#include "core/image.h"
#include "core/pose.h"
#include "core/response.h"
#include "core/result.h"
#include "core/scene.h"
#include "lighting/snapshot.h"
#include "render/camera_matching.h"
#include "render/gl_context.h"

namespace commonlight::render {

enum class DebugView {
    kNone,
    kProxyWireframe,  // the proxies' edges over the frame
    kElements,        // real faces show the model's radiance of the real scene alone (B~), element outlines
    kRatio,           // the modulation M as grey (0.5 = ratio 1), the frame elsewhere
    kTags,            // the composite; the window's overlay draws the tag detections (render/overlay.h)
};
const char* debugViewName(DebugView view);
DebugView nextDebugView(DebugView view);

// Where the final pass runs its modulating program (elsewhere it copies the frame's codes, which is
// what the modulating program writes where the snapshot changes nothing: the composite is the same).
enum class ModulationRegion {
    kTiles,      // the camera tiles (16 px) that can show a texel the snapshot changes
    kRectangle,  // one rectangle around every face's changed texels (before session 41)
    kFrame,      // every camera pixel (the reference the others must equal)
};

struct CompositorOptions {
    int msaa_samples = 4;          // 1: none
    bool lighting = true;          // false: no background modulation; virtual objects lit by the snapshot's lights only
    DebugView debug = DebugView::kNone;
    ModulationRegion modulation_region = ModulationRegion::kTiles;
    int shadow_map_size = 512;     // texels per side of each shadow map (64..4096), at most: the virtual objects' maps cover only
                                   // their bounds, at twice their width in pixels (a power of two); the real proxies' use this
    int area_light_samples = 4;    // shadow maps per area or disc light (1..8)
    // Camera matching (Klein and Murray, ISMAR 2008; render/camera_matching.h): the frame's sensor
    // noise (per intensity) and blur are measured on the CPU every `matching_interval` frames, the
    // virtual layer is blurred to the frame's PSF and gets noise of the frame's deviation in codes.
    bool camera_matching = false;
    int matching_interval = 30;  // frames between measurements (>= 1; the first frame is always measured)
    // Benchmarks and profiling only: glFinish() after each pass and its wall time kept
    // (Compositor::passTimes()). It serialises the GL's pipelining: never in the live loop.
    bool profile = false;
};

// One pass's time in profiling mode (CompositorOptions::profile).
struct PassTime {
    const char* name;    // static string
    double ms = 0.0;     // wall time
    double cpu_ms = 0.0; // CPU time of the whole process (the GL's threads included) over the same span
};

struct FrameInput {
    ImageView image;                  // the camera frame at the camera's size: kRgb8, or kYuyv / kNv12 as the camera sent it (even sizes)
    double exposure_gain = 1.0;       // exposure (s) x analog gain; <= 0 or not finite: 1
    std::optional<Rigid3d> cam_from_world;              // nullopt (no pose): the frame unchanged
    std::vector<std::optional<Rigid3d>> virtual_poses;  // world_from_object per Scene::virtual_objects; nullopt: not drawn
};

// The camera pixels each program of the last draw()'s final pass ran over, and its draw calls.
struct FinalPassArea {
    long plain = 0;         // the frame's codes as they are
    long modulated = 0;     // the background modulated
    long with_virtual = 0;  // the modulation and the virtual layer
    int modulated_tiles = 0;  // camera tiles marked for the modulation (in the virtual layer's rectangle too)
    int draws = 0;
};

// What camera matching measured and applies (CompositorOptions::camera_matching).
struct CameraMatch {
    NoiseProfile noise;            // the frame's noise, codes per intensity bin
    BlurEstimate blur;             // the frame's PSF (its sigma includes the pixels' own integration)
    double layer_sigma_px = 0.0;   // the virtual layer's own PSF: square pixels (MSAA) and the lens warp's bilinear read
    double added_sigma_px = 0.0;   // the Gaussian given to the virtual layer: sqrt(max(0, blur^2 - layer^2)), at most 2.5
    std::uint64_t frame = 0;       // the draw() it was measured at (0: the first)
};

// Live GL objects of the render module (created minus deleted), for leak checks.
struct GlObjectCounts {
    long textures = 0, buffers = 0, framebuffers = 0, renderbuffers = 0, programs = 0, vertex_arrays = 0;
    bool operator==(const GlObjectCounts&) const = default;
};
GlObjectCounts liveGlObjects();

class Compositor {
public:
    // Builds the proxies' and virtual objects' meshes (MeshShape meshes must be loaded: readScene
    // does), the shaders and the render targets. Errors: a shader or framebuffer the GL cannot
    // make (kDevice), a camera of zero size (kBadInput).
    static Result<std::unique_ptr<Compositor>> create(GlContext& context, const Scene& scene, const CameraModel& camera,
                                                      const ResponseCurve& response, const CompositorOptions& options);
    ~Compositor();
    Compositor(const Compositor&) = delete;
    Compositor& operator=(const Compositor&) = delete;

    // Renders the composite of this frame with this snapshot (into the output framebuffer; in a
    // window also onto the screen, call GlContext::present()). kBadInput: a frame that is not
    // kRgb8, kYuyv or kNv12 at the camera's size (YUYV and NV12: even sizes), with fewer bytes than
    // its format needs, or a pose list of the wrong length.
    Result<void> draw(const FrameInput& frame, const lighting::LightingSnapshot& snapshot);
    // The last composite, kRgb8, top row first.
    Result<Image> read() const;

    // For tests of the registration: the world point (metres) of the real proxy or virtual object
    // seen at each camera pixel, row-major, top row first, through the same projection, layer and
    // lens warp as draw() (the layer's world positions read at each pixel's ideal position,
    // filtered as the composite's layer is); w = 1 where one surface covers the four layer pixels
    // the filter reads, 0.5 where several do (an edge: the point is a blend), 0 where there is none
    // or no pose. The frame's pixels are not used.
    Result<std::vector<Eigen::Vector4f>> surfacePoints(const FrameInput& frame);

    // The last measurement of camera matching; nullopt when it is off or nothing was measured yet.
    const std::optional<CameraMatch>& cameraMatch() const noexcept;

    // The passes of the last draw() and read() with their times (profiling mode; empty otherwise).
    const std::vector<PassTime>& passTimes() const noexcept;
    // Where the last draw()'s final pass ran each of its programs.
    const FinalPassArea& finalPassArea() const noexcept;

    void setOptions(const CompositorOptions& options);
    const CompositorOptions& options() const noexcept;

private:
    Compositor();
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

}  // namespace commonlight::render

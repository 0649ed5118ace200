// The simulated world as Embree 3 geometry: real proxies, tags, area lights and (optionally) the
// virtual objects, with the material of every surface, ready for many threads to trace.
//
// Geometry (world frame, metres; Embree stores float vertices, hits are refined in double):
// - planes, boxes and meshes are triangles (boxes: 12, outward-facing; meshes: world_from_object
//   applied, counter-clockwise = front); spheres are Embree's analytic spheres (SPHERE_POINT), so
//   their silhouettes and normals are exact;
// - area lights: rectangles as two triangles, discs as Embree's normal-oriented discs (exact);
//   a light's surface is black (absorbs everything) on both sides and emits from its +z side only;
// - tags: each is its own quad at exactly its pose (no offset) with libapriltag's texture. A tag
//   lying on a real surface is coplanar with it; instead of lifting the tag (a lift of 0.1 mm moves
//   its projected corners by up to 0.1 px at 30 cm), a ray that hits the surface under a tag is
//   given the tag's texture ("decal" lookup: the hit point lies within rayEpsilon() of the tag's
//   plane, inside its printed square, on its printed side). Which of the two coplanar surfaces
//   Embree reports first then does not matter: both shade the same.
// All surfaces reflect on both sides (the shading normal is turned towards the viewer). The back
// of a tag is blank paper (its white albedo). Emission (area lights, emissive virtual objects) is
// one-sided: from the front (+z of planes and lights, outward of boxes and spheres, the
// counter-clockwise side of mesh triangles).
//
// Threads: build() edits and commits the Embree scene on the calling thread, once. Afterwards the
// scene is immutable and intersect()/occluded() may be called from any number of threads.
#pragma once

#include <embree3/rtcore.h>

#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/result.h"
#include "core/scene.h"
#include "mocks/sim/lights.h"
#include "mocks/sim/materials.h"
#include "mocks/sim/tag_texture.h"

namespace commonlight::mocks::sim {

struct SimSceneOptions {
    bool include_virtual = false;  // add the virtual objects (the composite ground truth)
    double time_s = 0.0;           // where keyframed virtual objects are: seconds since the sequence start
    // Albedo of real objects whose albedo is `estimate` (the scene does not know their truth).
    Eigen::Vector3d default_albedo = Eigen::Vector3d::Constant(0.5);
    // How the tags were printed: black regions grown (> 0) or shrunk (< 0) by this many cells
    // (PlacedTag::ink_spread_cells).
    double tag_ink_spread_cells = 0.0;
};

enum class ObjectKind { kReal, kTag, kLight, kVirtual };

// Something a ray can hit. Ids (positions in SimScene::objects()) are assigned in this order:
// real objects, tags, area lights, virtual objects; so the ids of everything but the virtual
// objects are the same whether or not the virtual objects are included.
struct ObjectInfo {
    ObjectKind kind = ObjectKind::kReal;
    int index = -1;    // in Scene::real_objects, TagSet::items, Scene::lights or Scene::virtual_objects
    std::string name;  // the scene's name; "tag <id>" for tags
};

// A ray's nearest hit, with what shading needs there.
struct SurfaceHit {
    Eigen::Vector3d p = Eigen::Vector3d::Zero();   // world, metres
    Eigen::Vector3d n = Eigen::Vector3d::UnitZ();  // unit geometric normal on the surface's front side
    double t = 0.0;                                // distance along the (unit) ray direction, metres
    bool front = true;                             // the ray arrived on the front side (dir . n < 0)
    int object = -1;                               // index into SimScene::objects()
    bool is_virtual = false;
    int light = -1;  // index into SimScene::lights() when this is an area light's surface
    Bsdf bsdf;       // reflectance at p (black for lights)
    Eigen::Vector3d emission = Eigen::Vector3d::Zero();  // radiance leaving towards the ray (front side only)
};

class SimScene {
public:
    // Builds the Embree scene. Fails (kBadInput, naming the object or light) for a light whose
    // emission is `estimate`, a mesh that was not loaded, a virtual object attached to a missing
    // tag, an unknown tag family; kInternal when Embree reports an error.
    static Result<SimScene> build(const Scene& scene, const SimSceneOptions& options = {});

    SimScene(SimScene&&) noexcept;
    SimScene& operator=(SimScene&&) noexcept;
    SimScene(const SimScene&) = delete;
    SimScene& operator=(const SimScene&) = delete;
    ~SimScene();

    // Nearest hit along origin + t dir for t in (0, t_max]; `dir` must be unit length.
    std::optional<SurfaceHit> intersect(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir,
                                        double t_max = std::numeric_limits<double>::infinity()) const;
    // Whether anything lies along origin + t dir for t in (0, t_max].
    bool occluded(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir,
                  double t_max = std::numeric_limits<double>::infinity()) const;
    // Whether anything but the area light `light` (index into lights()) lies along origin + t dir
    // for t in (0, t_max]: the shadow test towards a point sampled on that light. The light's own
    // surface must not count as an occluder even where rounding puts it a little before t_max
    // (shadow rays leave from an offset origin and can meet the light's plane early at grazing
    // angles).
    bool occludedExceptLight(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir, double t_max, int light) const;

    // Radiance (W/(m^2 sr)) a ray leaving the scene in direction `dir` sees: the distant
    // environment above the horizon, nothing below it.
    Eigen::Vector3d escapedRadiance(const Eigen::Vector3d& dir) const noexcept {
        return dir.z() > 0.0 ? environment_ : Eigen::Vector3d::Zero();
    }
    const Eigen::Vector3d& environmentRadiance() const noexcept { return environment_; }

    const std::vector<SimLight>& lights() const noexcept { return lights_; }
    const std::vector<ObjectInfo>& objects() const noexcept { return objects_; }
    const std::vector<PlacedTag>& tags() const noexcept { return tags_; }
    // Offset (metres) of secondary ray origins from a surface, on the side they leave towards:
    // 1e-5 of the scene's extent, at least 1e-5 m. Also the decal tolerance of tags.
    double rayEpsilon() const noexcept { return ray_epsilon_; }
    const Eigen::AlignedBox3d& bounds() const noexcept { return bounds_; }

private:
    struct Geometry;
    struct EmbreeErrors;
    struct DeviceRelease {
        void operator()(RTCDevice device) const noexcept;
    };
    struct SceneRelease {
        void operator()(RTCScene scene) const noexcept;
    };
    class Builder;

    SimScene();
    SurfaceHit makeHit(const RTCRayHit& ray_hit, const Eigen::Vector3d& origin, const Eigen::Vector3d& dir) const;
    void applyDecal(const Geometry& geometry, SurfaceHit& hit, const Eigen::Vector3d& dir) const;

    // Heap-allocated so that its address, the error callback's user pointer, survives moves.
    // Declared first: destroyed last, after the device that may still call it.
    std::unique_ptr<EmbreeErrors> errors_;
    // Owns one reference to the device; released after the scene (members die in reverse order).
    std::unique_ptr<RTCDeviceTy, DeviceRelease> device_;
    // Owns one reference to the committed scene.
    std::unique_ptr<RTCSceneTy, SceneRelease> scene_;
    std::vector<Geometry> geometries_;  // by Embree geometry id
    std::vector<SimLight> lights_;
    std::vector<PlacedTag> tags_;
    std::vector<ObjectInfo> objects_;
    Eigen::Vector3d environment_ = Eigen::Vector3d::Zero();
    double ray_epsilon_ = 1e-5;
    Eigen::AlignedBox3d bounds_;
};

}  // namespace commonlight::mocks::sim

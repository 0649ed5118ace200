// The scene: fiducial tags with known placement, proxy geometry of the real scene, the real lights,
// the virtual objects to insert, and lighting options. The file format and its conventions are in
// docs/formats-scene.md (DESIGN.md section 4); core/scene_io.h reads and writes it.
//
// Conventions: world frame right-handed, metres, z up. Boxes and planes are centred on their
// object origin, `size` is the full extent along the object's x, y (, z); a plane's front face
// looks along +z. A tag is centred on its origin in its x-y plane, printed side towards +z, top
// edge towards +y, `size` is the edge of its black square. Area lights emit from their +z side.
#pragma once

#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include <Eigen/Core>

#include "core/camera_model.h"
#include "core/mesh_io.h"
#include "core/pose.h"

namespace commonlight {

// An RGB quantity (albedo, radiance, ...) that the file either gives or leaves to be estimated
// from the images (`estimate`).
struct RgbOrEstimate {
    std::optional<Eigen::Vector3d> value;  // nullopt: estimate

    static RgbOrEstimate estimate() { return {}; }
    static RgbOrEstimate constant(const Eigen::Vector3d& rgb) { return {rgb}; }
    bool isEstimate() const { return !value.has_value(); }
    bool operator==(const RgbOrEstimate&) const = default;
};

// Shapes, in the object's own frame (metres).
struct PlaneShape {
    Eigen::Vector2d size = Eigen::Vector2d::Zero();  // full extent along x, y; centred; front face +z
    bool operator==(const PlaneShape&) const = default;
};
struct BoxShape {
    Eigen::Vector3d size = Eigen::Vector3d::Zero();  // full extent along x, y, z; centred
    bool operator==(const BoxShape&) const = default;
};
struct SphereShape {
    double radius = 0.0;  // centred on the origin
    bool operator==(const SphereShape&) const = default;
};
struct MeshShape {
    std::filesystem::path path;        // resolved against the scene file's folder
    std::shared_ptr<const Mesh> mesh;  // loaded geometry (shared, immutable); null when not loaded
    bool operator==(const MeshShape& other) const { return path == other.path; }
};
using Shape = std::variant<PlaneShape, BoxShape, SphereShape, MeshShape>;

// The scene file's name for a shape: "plane", "box", "sphere", "mesh".
const char* shapeKey(const Shape& shape);

// A fiducial with known placement.
struct TagItem {
    int id = 0;
    double size = 0.0;  // edge of the black square, metres (apriltag's convention)
    Rigid3d world_from_tag;
    double albedo_black = 0.04;  // albedo of the black cells
    double albedo_white = 0.8;   // albedo of the white cells
};

struct TagSet {
    std::string family = "tag36h11";  // apriltag family name
    std::vector<TagItem> items;

    const TagItem* find(int id) const;
};

// Proxy geometry of the real scene. Its albedo is given or estimated (the default).
struct RealObject {
    std::string name;
    Shape shape;
    Rigid3d world_from_object;
    RgbOrEstimate albedo;  // Lambertian albedo in [0, 1] per channel
};

// Light shapes. Area lights (rectangle, disc) lie in their x-y plane and emit from the +z side.
struct AreaLightShape {
    Eigen::Vector2d size = Eigen::Vector2d::Zero();  // rectangle, full extent along x, y, centred
    bool operator==(const AreaLightShape&) const = default;
};
struct DiscLightShape {
    double radius = 0.0;
    bool operator==(const DiscLightShape&) const = default;
};
struct PointLightShape {  // at the object origin
    bool operator==(const PointLightShape&) const = default;
};
struct DirectionalLightShape {
    Eigen::Vector3d direction = -Eigen::Vector3d::UnitZ();  // unit; the direction the light travels in, world
    bool operator==(const DirectionalLightShape&) const = default;
};
struct DistantLightShape {  // an unknown environment: radiance from `directions` directions
    int directions = 0;
    bool operator==(const DistantLightShape&) const = default;
};
using LightShape =
    std::variant<AreaLightShape, DiscLightShape, PointLightShape, DirectionalLightShape, DistantLightShape>;

// The scene file's name for a light shape: "area", "disc", "point", "directional", "distant".
const char* lightKey(const LightShape& shape);
// The scene file's name for a light's emission: "radiance" (area, disc, distant), "intensity"
// (point) or "irradiance" (directional).
const char* emissionKey(const LightShape& shape);
// Whether a light of this shape has a pose (area, disc, point do; directional, distant do not).
bool lightHasPose(const LightShape& shape);

struct Light {
    std::string name;
    LightShape shape;
    Rigid3d world_from_object;  // identity for directional and distant lights
    // Radiance in W/(m^2 sr) (area, disc, distant), intensity in W/sr (point), irradiance in W/m^2
    // on a surface facing the light (directional); per RGB channel. Estimated by default.
    RgbOrEstimate emission;
};

enum class MaterialType { kLambertian, kGgx };

struct Material {
    MaterialType type = MaterialType::kLambertian;
    Eigen::Vector3d albedo = Eigen::Vector3d::Constant(0.5);  // in [0, 1] per channel
    double roughness = 0.5;                                   // GGX alpha = roughness^2; in (0, 1], ggx only
    bool operator==(const Material&) const = default;
};

// Where a virtual object is: fixed in the world, attached to a tag, or moving along keyframes.
struct FixedPlacement {
    Rigid3d world_from_object;
};
struct TagPlacement {
    int tag = 0;  // id of a tag in the scene's TagSet
    Rigid3d tag_from_object;
};
struct Keyframe {
    double t = 0.0;  // seconds since the start of the sequence
    Rigid3d world_from_object;
};
struct KeyframePlacement {
    std::vector<Keyframe> keyframes;  // at least one, times strictly increasing
};
using Placement = std::variant<FixedPlacement, TagPlacement, KeyframePlacement>;

struct VirtualObject {
    std::string name;
    Shape shape;
    Material material;
    std::optional<Eigen::Vector3d> emission;  // radiance W/(m^2 sr) per channel; a virtual light
    Placement placement = FixedPlacement{};
};

struct LightingOptions {
    int max_elements = 8000;  // largest number of radiosity elements
    double error = 0.01;      // refinement threshold (relative radiance error)
    // The area lights' direct light per texel where the virtual objects change it (lighting/
    // texel_direct.h): visibility pairs per texel and light (0: the elements' direct light), and
    // texels per two camera pixels along a side (no camera: per finest element). Unset: the
    // estimator's defaults (16, 1).
    std::optional<int> texel_pairs;
    std::optional<int> texel_oversample;
    bool operator==(const LightingOptions&) const = default;
};

struct Scene {
    std::filesystem::path file;                        // the scene file (absolute), empty when not read from one
    std::optional<std::filesystem::path> camera_path;  // calibration file, resolved against the scene's folder
    std::optional<CameraModel> camera;                 // loaded from camera_path
    TagSet tags;
    std::vector<RealObject> real_objects;
    std::vector<Light> lights;
    std::vector<VirtualObject> virtual_objects;
    LightingOptions lighting;
};

// Pose of a keyframed object at time t: slerp/lerp between the surrounding keyframes, held
// constant before the first and after the last. `keyframes` must not be empty.
Rigid3d poseAt(const std::vector<Keyframe>& keyframes, double t);

// world_from_object of a virtual object at time t (seconds). For a tag placement, the tag's
// world_from_tag comes from `tags`; nullopt when that tag is not in it.
std::optional<Rigid3d> worldFromObject(const VirtualObject& object, const TagSet& tags, double t);

// The number of tags in an apriltag family ("tag36h11": 587), or 0 for an unknown family.
int tagFamilySize(std::string_view family);

}  // namespace commonlight

#include "core/scene_io.h"

#include <cmath>
#include <initializer_list>
#include <limits>
#include <map>
#include <utility>

#include "core/calibration_io.h"
#include "core/file_util.h"
#include "core/scene_yaml.h"
#include "core/yaml_util.h"
#include "core/reader_guard.h"

namespace commonlight {

namespace {

using yaml::indexKey;
using yaml::joinKey;
using yaml::keyError;
using yaml::present;

constexpr double kInfinity = std::numeric_limits<double>::infinity();

// 1-based line of a node, 0 when unknown.
int lineOf(const YAML::Node& node) { return node.Mark().is_null() ? 0 : node.Mark().line + 1; }

// Reads one scene document. Steps follow the file's sections; tags come before the objects that
// may be attached to them.
class SceneParser {
public:
    SceneParser(std::string file, std::filesystem::path base_dir, const SceneReadOptions& options)
        : file_(std::move(file)), base_dir_(std::move(base_dir)), options_(options) {}

    Result<Scene> parse(const YAML::Node& root) {
        if (!root.IsDefined() || root.IsNull()) return fail(ErrorCode::kBadInput, file_ + ": the scene file is empty");
        // `sensor` belongs to the simulated camera (docs/sim-sensor.md): `commonlight sim` reads it
        // from the same file; the scene itself does not use it.
        CL_TRY_VOID(yaml::checkKeys(file_, root, "", {"camera", "tags", "real", "lights", "virtual", "lighting", "sensor"}));
        Scene scene;
        // Step 1: the camera.
        if (present(root, "camera")) CL_TRY_VOID(parseCamera(root, scene));
        // Step 2: tags, so that attachments can be checked against them.
        if (present(root, "tags")) CL_TRY_VOID(parseTags(root, scene.tags));
        // Step 3: real objects, lights, virtual objects; names are unique across all three.
        if (present(root, "real")) {
            CL_TRY(const YAML::Node list, yaml::getList(file_, root, "real"));
            for (std::size_t i = 0; i < list.size(); ++i) {
                CL_TRY(RealObject object, parseReal(list[i], indexKey("real", i)));
                scene.real_objects.push_back(std::move(object));
            }
        }
        if (present(root, "lights")) {
            CL_TRY(const YAML::Node list, yaml::getList(file_, root, "lights"));
            for (std::size_t i = 0; i < list.size(); ++i) {
                CL_TRY(Light light, parseLight(list[i], indexKey("lights", i)));
                scene.lights.push_back(std::move(light));
            }
        }
        if (present(root, "virtual")) {
            CL_TRY(const YAML::Node list, yaml::getList(file_, root, "virtual"));
            for (std::size_t i = 0; i < list.size(); ++i) {
                CL_TRY(VirtualObject object, parseVirtual(list[i], indexKey("virtual", i), scene.tags));
                scene.virtual_objects.push_back(std::move(object));
            }
        }
        // Step 4: lighting options.
        if (present(root, "lighting")) CL_TRY_VOID(parseLighting(root, scene.lighting));
        return scene;
    }

private:
    // An error from another reader (calibration, mesh), placed at the scene key that named the file.
    Error nested(const YAML::Node& node, std::string_view key, Error inner) const {
        inner.message = yaml::where(file_, node) + ": key '" + std::string(key) + "': " + inner.message;
        return inner;
    }

    Result<std::filesystem::path> parsePath(const YAML::Node& parent, std::string_view key) const {
        CL_TRY(const std::string text, yaml::getString(file_, parent, key));
        if (text.empty()) return fail(keyError(file_, parent, key, "must not be empty"));
        const std::filesystem::path path(text);
        return path.is_absolute() ? path : (base_dir_ / path).lexically_normal();
    }

    Result<void> parseCamera(const YAML::Node& root, Scene& scene) const {
        CL_TRY(scene.camera_path, parsePath(root, "camera"));
        if (!options_.load_camera) return {};
        auto model = readCalibration(*scene.camera_path);
        if (!model) return fail(nested(root["camera"], "camera", std::move(model).error()));
        scene.camera = *model;
        return {};
    }

    Result<void> parseTags(const YAML::Node& root, TagSet& tags) const {
        const YAML::Node node = root["tags"];
        CL_TRY_VOID(yaml::checkKeys(file_, node, "tags", {"family", "items"}));
        if (present(node, "family")) {
            CL_TRY(tags.family, yaml::getString(file_, node, "tags.family"));
            if (tagFamilySize(tags.family) == 0) {
                return fail(keyError(file_, node["family"], "tags.family",
                                     "unknown tag family '" + tags.family +
                                         "' (expected tag36h11, tag25h9, tag16h5, tagCircle21h7, tagCircle49h12, "
                                         "tagCustom48h12, tagStandard41h12 or tagStandard52h13)"));
            }
        }
        const int family_size = tagFamilySize(tags.family);
        CL_TRY(const YAML::Node items, yaml::getList(file_, node, "tags.items"));
        std::map<int, int> line_of_id;
        for (std::size_t i = 0; i < items.size(); ++i) {
            const YAML::Node item = items[i];
            const std::string key = indexKey("tags.items", i);
            CL_TRY_VOID(yaml::checkKeys(file_, item, key, {"id", "size", "world_from_tag", "albedo"}));
            TagItem tag;
            CL_TRY(tag.id, yaml::getInt(file_, item, joinKey(key, "id")));
            if (tag.id < 0 || tag.id >= family_size) {
                return fail(keyError(file_, item["id"], joinKey(key, "id"),
                                     "tag " + std::to_string(tag.id) + " is not in " + tags.family + " (ids 0 to " +
                                         std::to_string(family_size - 1) + ")"));
            }
            if (const auto [it, inserted] = line_of_id.emplace(tag.id, lineOf(item["id"])); !inserted) {
                return fail(keyError(file_, item["id"], joinKey(key, "id"),
                                     "tag " + std::to_string(tag.id) + " appears twice (first at line " +
                                         std::to_string(it->second) + ")"));
            }
            CL_TRY(tag.size, yaml::getPositive(file_, item, joinKey(key, "size")));
            CL_TRY(tag.world_from_tag, yaml::getTransform(file_, item, joinKey(key, "world_from_tag")));
            if (present(item, "albedo")) {
                const std::string albedo_key = joinKey(key, "albedo");
                CL_TRY(const std::vector<double> albedo, yaml::getDoubles(file_, item, albedo_key, 2));
                if (albedo[0] < 0.0 || albedo[1] > 1.0 || !(albedo[0] < albedo[1])) {
                    return fail(keyError(file_, item["albedo"], albedo_key,
                                         "expected [black, white] with 0 <= black < white <= 1"));
                }
                tag.albedo_black = albedo[0];
                tag.albedo_white = albedo[1];
            }
            tags.items.push_back(tag);
        }
        return {};
    }

    // A name, unique among real objects, lights and virtual objects.
    Result<std::string> parseName(const YAML::Node& node, const std::string& key) {
        CL_TRY(std::string name, yaml::getString(file_, node, joinKey(key, "name")));
        if (name.empty()) return fail(keyError(file_, node["name"], joinKey(key, "name"), "must not be empty"));
        if (const auto [it, inserted] = line_of_name_.emplace(name, lineOf(node["name"])); !inserted) {
            return fail(keyError(file_, node["name"], joinKey(key, "name"),
                                 "name '" + name + "' is already used (line " + std::to_string(it->second) + ")"));
        }
        return name;
    }

    // Exactly one of `choices` must be present; returns it.
    Result<std::string> oneOf(const YAML::Node& node, const std::string& key,
                              std::initializer_list<const char*> choices, std::string_view what) const {
        std::string found;
        std::string list;
        for (const char* choice : choices) {
            list += list.empty() ? "" : ", ";
            list += choice;
            if (!present(node, choice)) continue;
            if (!found.empty()) {
                return fail(keyError(file_, yaml::findKey(node, choice), joinKey(key, choice),
                                     "give one " + std::string(what) + ", found both " + found + " and " + choice));
            }
            found = choice;
        }
        if (found.empty())
            return fail(keyError(file_, node, key, "missing its " + std::string(what) + " (" + list + ")"));
        return found;
    }

    Result<Shape> parseShape(const YAML::Node& node, const std::string& key) {
        CL_TRY(const std::string kind, oneOf(node, key, {"plane", "box", "sphere", "mesh"}, "shape"));
        const std::string shape_key = joinKey(key, kind);
        const YAML::Node shape = node[kind];
        if (kind == "plane") {
            CL_TRY_VOID(yaml::checkKeys(file_, shape, shape_key, {"size"}));
            CL_TRY(const std::vector<double> size, yaml::getPositives(file_, shape, joinKey(shape_key, "size"), 2));
            return PlaneShape{{size[0], size[1]}};
        }
        if (kind == "box") {
            CL_TRY_VOID(yaml::checkKeys(file_, shape, shape_key, {"size"}));
            CL_TRY(const std::vector<double> size, yaml::getPositives(file_, shape, joinKey(shape_key, "size"), 3));
            return BoxShape{{size[0], size[1], size[2]}};
        }
        if (kind == "sphere") {
            CL_TRY_VOID(yaml::checkKeys(file_, shape, shape_key, {"radius"}));
            CL_TRY(const double radius, yaml::getPositive(file_, shape, joinKey(shape_key, "radius")));
            return SphereShape{radius};
        }
        MeshShape mesh;
        CL_TRY(mesh.path, parsePath(node, shape_key));
        if (options_.load_meshes) {
            auto& cached = meshes_[mesh.path];
            if (!cached) {
                auto loaded = readMesh(mesh.path);
                if (!loaded) return fail(nested(shape, shape_key, std::move(loaded).error()));
                cached = std::make_shared<const Mesh>(std::move(*loaded));
            }
            mesh.mesh = cached;
        }
        return mesh;
    }

    Result<RealObject> parseReal(const YAML::Node& node, const std::string& key) {
        CL_TRY_VOID(yaml::checkKeys(file_, node, key,
                                    {"name", "plane", "box", "sphere", "mesh", "world_from_object", "albedo"}));
        RealObject object;
        CL_TRY(object.name, parseName(node, key));
        CL_TRY(object.shape, parseShape(node, key));
        if (present(node, "world_from_object")) {
            CL_TRY(object.world_from_object, yaml::getTransform(file_, node, joinKey(key, "world_from_object")));
        }
        if (present(node, "albedo")) {
            CL_TRY(object.albedo, yaml::asRgbOrEstimate(file_, node["albedo"], joinKey(key, "albedo"), 1.0));
        }
        return object;
    }

    Result<LightShape> parseLightShape(const YAML::Node& node, const std::string& key) const {
        CL_TRY(const std::string kind, oneOf(node, key, {"area", "disc", "point", "directional", "distant"}, "type"));
        const std::string shape_key = joinKey(key, kind);
        const YAML::Node shape = node[kind];
        if (kind == "area") {
            CL_TRY_VOID(yaml::checkKeys(file_, shape, shape_key, {"size"}));
            CL_TRY(const std::vector<double> size, yaml::getPositives(file_, shape, joinKey(shape_key, "size"), 2));
            return AreaLightShape{{size[0], size[1]}};
        }
        if (kind == "disc") {
            CL_TRY_VOID(yaml::checkKeys(file_, shape, shape_key, {"radius"}));
            CL_TRY(const double radius, yaml::getPositive(file_, shape, joinKey(shape_key, "radius")));
            return DiscLightShape{radius};
        }
        if (kind == "point") {
            // `point: {}` or just `point:`; the position is world_from_object's translation.
            if (!shape.IsNull()) CL_TRY_VOID(yaml::checkKeys(file_, shape, shape_key, {}));
            return PointLightShape{};
        }
        if (kind == "directional") {
            CL_TRY_VOID(yaml::checkKeys(file_, shape, shape_key, {"direction"}));
            const std::string direction_key = joinKey(shape_key, "direction");
            CL_TRY(const std::vector<double> d, yaml::getDoubles(file_, shape, direction_key, 3));
            const Eigen::Vector3d direction(d[0], d[1], d[2]);
            if (!(direction.norm() > 0.0)) {
                return fail(keyError(file_, shape["direction"], direction_key, "must not be zero"));
            }
            // Normalise, but keep a direction that is already unit to rounding as it is, so that a
            // written scene reads back to the same bits.
            const double norm = direction.norm();
            const bool unit = std::abs(norm - 1.0) <= 4.0 * std::numeric_limits<double>::epsilon();
            return DirectionalLightShape{unit ? direction : Eigen::Vector3d(direction / norm)};
        }
        CL_TRY_VOID(yaml::checkKeys(file_, shape, shape_key, {"directions"}));
        CL_TRY(const int directions, yaml::getInt(file_, shape, joinKey(shape_key, "directions")));
        if (directions <= 0) {
            return fail(keyError(file_, shape["directions"], joinKey(shape_key, "directions"), "must be positive"));
        }
        return DistantLightShape{directions};
    }

    Result<Light> parseLight(const YAML::Node& node, const std::string& key) {
        CL_TRY_VOID(yaml::checkKeys(file_, node, key,
                                    {"name", "area", "disc", "point", "directional", "distant", "world_from_object",
                                     "radiance", "intensity", "irradiance"}));
        Light light;
        CL_TRY(light.name, parseName(node, key));
        CL_TRY(light.shape, parseLightShape(node, key));
        const std::string kind = lightKey(light.shape);
        if (present(node, "world_from_object")) {
            if (!lightHasPose(light.shape)) {
                return fail(keyError(
                    file_, yaml::findKey(node, "world_from_object"), joinKey(key, "world_from_object"),
                    "a " + kind + " light has no position" + (kind == "directional" ? " (give its direction)" : "")));
            }
            CL_TRY(light.world_from_object, yaml::getTransform(file_, node, joinKey(key, "world_from_object")));
        }
        const std::string emission = emissionKey(light.shape);
        for (const char* other : {"radiance", "intensity", "irradiance"}) {
            if (other != emission && present(node, other)) {
                return fail(keyError(file_, yaml::findKey(node, other), joinKey(key, other),
                                     "a " + kind + " light takes " + emission + ", not " + other));
            }
        }
        if (present(node, emission)) {
            CL_TRY(light.emission, yaml::asRgbOrEstimate(file_, node[emission], joinKey(key, emission), kInfinity));
        }
        return light;
    }

    Result<Material> parseMaterial(const YAML::Node& node, const std::string& key) const {
        CL_TRY_VOID(yaml::checkKeys(file_, node, key, {"type", "albedo", "roughness"}));
        Material material;
        if (present(node, "type")) {
            CL_TRY(const std::string type, yaml::getString(file_, node, joinKey(key, "type")));
            if (type == "ggx") {
                material.type = MaterialType::kGgx;
            } else if (type != "lambertian") {
                return fail(keyError(file_, node["type"], joinKey(key, "type"),
                                     "unknown material type '" + type + "' (expected lambertian or ggx)"));
            }
        }
        if (present(node, "albedo")) {
            CL_TRY(material.albedo, yaml::asRgb(file_, node["albedo"], joinKey(key, "albedo"), 1.0));
        }
        if (present(node, "roughness")) {
            const std::string roughness_key = joinKey(key, "roughness");
            if (material.type != MaterialType::kGgx) {
                return fail(keyError(file_, yaml::findKey(node, "roughness"), roughness_key,
                                     "only a ggx material has a roughness (add type: ggx)"));
            }
            CL_TRY(material.roughness, yaml::getPositive(file_, node, roughness_key));
            if (material.roughness > 1.0) {
                return fail(keyError(file_, node["roughness"], roughness_key, "must be in (0, 1]"));
            }
        }
        return material;
    }

    Result<Placement> parsePlacement(const YAML::Node& node, const std::string& key, const TagSet& tags) const {
        int count = 0;
        for (const char* k : {"world_from_object", "attach", "keyframes"}) count += present(node, k) ? 1 : 0;
        if (count > 1) {
            return fail(keyError(file_, node, key, "give one placement: world_from_object, attach or keyframes"));
        }
        if (present(node, "attach")) {
            const std::string attach_key = joinKey(key, "attach");
            const YAML::Node attach = node["attach"];
            CL_TRY_VOID(yaml::checkKeys(file_, attach, attach_key, {"tag", "tag_from_object"}));
            TagPlacement placement;
            CL_TRY(placement.tag, yaml::getInt(file_, attach, joinKey(attach_key, "tag")));
            if (tags.find(placement.tag) == nullptr) {
                return fail(keyError(file_, attach["tag"], joinKey(attach_key, "tag"),
                                     "tag " + std::to_string(placement.tag) + " is not in tags.items"));
            }
            if (present(attach, "tag_from_object")) {
                CL_TRY(placement.tag_from_object,
                       yaml::getTransform(file_, attach, joinKey(attach_key, "tag_from_object")));
            }
            return placement;
        }
        if (present(node, "keyframes")) {
            const std::string list_key = joinKey(key, "keyframes");
            CL_TRY(const YAML::Node list, yaml::getList(file_, node, list_key));
            if (list.size() == 0) return fail(keyError(file_, list, list_key, "needs at least one keyframe"));
            KeyframePlacement placement;
            for (std::size_t i = 0; i < list.size(); ++i) {
                const std::string frame_key = indexKey(list_key, i);
                const YAML::Node frame_node = list[i];
                CL_TRY_VOID(yaml::checkKeys(file_, frame_node, frame_key, {"t", "world_from_object"}));
                Keyframe frame;
                CL_TRY(frame.t, yaml::getDouble(file_, frame_node, joinKey(frame_key, "t")));
                if (!placement.keyframes.empty() && !(frame.t > placement.keyframes.back().t)) {
                    return fail(keyError(file_, frame_node["t"], joinKey(frame_key, "t"),
                                         "times must increase strictly: " + yaml::formatNumber(frame.t) + " after " +
                                             yaml::formatNumber(placement.keyframes.back().t)));
                }
                CL_TRY(frame.world_from_object,
                       yaml::getTransform(file_, frame_node, joinKey(frame_key, "world_from_object")));
                placement.keyframes.push_back(frame);
            }
            return placement;
        }
        FixedPlacement placement;
        if (present(node, "world_from_object")) {
            CL_TRY(placement.world_from_object, yaml::getTransform(file_, node, joinKey(key, "world_from_object")));
        }
        return placement;
    }

    Result<VirtualObject> parseVirtual(const YAML::Node& node, const std::string& key, const TagSet& tags) {
        CL_TRY_VOID(yaml::checkKeys(file_, node, key,
                                    {"name", "plane", "box", "sphere", "mesh", "material", "emission",
                                     "world_from_object", "attach", "keyframes"}));
        VirtualObject object;
        CL_TRY(object.name, parseName(node, key));
        CL_TRY(object.shape, parseShape(node, key));
        if (present(node, "material")) {
            CL_TRY(object.material, parseMaterial(node["material"], joinKey(key, "material")));
        }
        if (present(node, "emission")) {
            CL_TRY(object.emission, yaml::asRgb(file_, node["emission"], joinKey(key, "emission"), kInfinity));
        }
        CL_TRY(object.placement, parsePlacement(node, key, tags));
        return object;
    }

    Result<void> parseLighting(const YAML::Node& root, LightingOptions& lighting) const {
        const YAML::Node node = root["lighting"];
        CL_TRY_VOID(yaml::checkKeys(file_, node, "lighting", {"max_elements", "error", "texel_pairs", "texel_oversample"}));
        if (present(node, "max_elements")) {
            CL_TRY(lighting.max_elements, yaml::getInt(file_, node, "lighting.max_elements"));
            if (lighting.max_elements <= 0) {
                return fail(keyError(file_, node["max_elements"], "lighting.max_elements", "must be positive"));
            }
        }
        if (present(node, "error")) {
            CL_TRY(lighting.error, yaml::getPositive(file_, node, "lighting.error"));
        }
        // (At most 64 pairs: a bit mask per texel and light; at most 4 texels per element side.)
        for (const auto& [name, field, lo, hi] : {std::tuple{"texel_pairs", &lighting.texel_pairs, 0, 64},
                                                  std::tuple{"texel_oversample", &lighting.texel_oversample, 1, 4}}) {
            if (!present(node, name)) continue;
            const std::string key = std::string("lighting.") + name;
            CL_TRY(const int v, yaml::getInt(file_, node, key));
            if (v < lo || v > hi) {
                return fail(keyError(file_, node[name], key, "must be between " + std::to_string(lo) + " and " + std::to_string(hi)));
            }
            *field = v;
        }
        return {};
    }

    std::string file_;
    std::filesystem::path base_dir_;
    SceneReadOptions options_;
    std::map<std::string, int> line_of_name_;
    std::map<std::filesystem::path, std::shared_ptr<const Mesh>> meshes_;  // one load per mesh file
};

}  // namespace

Result<Scene> parseScene(const std::string& text, const std::filesystem::path& file, const SceneReadOptions& options) {
    return guardReader(file, [&]() -> Result<Scene> {
        CL_TRY(const YAML::Node root, yaml::loadString(text, file.string()));
        const std::filesystem::path absolute = std::filesystem::absolute(file).lexically_normal();
        CL_TRY(Scene scene, SceneParser(file.string(), absolute.parent_path(), options).parse(root));
        scene.file = absolute;
        return scene;
    });
}

Result<Scene> readScene(const std::filesystem::path& file, const SceneReadOptions& options) {
    CL_TRY(const std::string text, readTextFile(file));
    return parseScene(text, file, options);
}

}  // namespace commonlight

// The scene writer (declared in core/scene_io.h): block-style lists of flow-style items, numbers
// that round-trip exactly.
#include <sstream>

#include "core/file_util.h"
#include "core/scene_io.h"
#include "core/scene_yaml.h"
#include "core/yaml_util.h"

namespace commonlight {

namespace {

template <class... Ts>
struct Overloaded : Ts... {
    using Ts::operator()...;
};
// C++20 deduces this for aggregates by itself; clang 16 (the fuzz build) does not yet.
template <class... Ts>
Overloaded(Ts...) -> Overloaded<Ts...>;

std::string relativePath(const std::filesystem::path& path, const std::filesystem::path& base_dir) {
    if (!path.is_absolute() || base_dir.empty()) return path.generic_string();
    const std::filesystem::path relative = path.lexically_proximate(base_dir);
    return relative.generic_string();
}

class SceneFormatter {
public:
    explicit SceneFormatter(std::filesystem::path base_dir) : base_dir_(std::move(base_dir)) {}

    std::string format(const Scene& scene) {
        out_ << "# commonlight scene (docs/formats-scene.md): world z up, metres, rpy_deg = R = Rz(yaw) Ry(pitch) "
                "Rx(roll)\n";
        if (scene.camera_path) out_ << "camera: " << path(*scene.camera_path) << "\n";
        if (!scene.tags.items.empty()) {
            out_ << "tags:\n  family: " << yaml::quoteString(scene.tags.family) << "\n  items:\n";
            for (const TagItem& tag : scene.tags.items) {
                out_ << "    - {id: " << tag.id << ", size: " << yaml::formatNumber(tag.size)
                     << ", world_from_tag: " << yaml::formatTransform(tag.world_from_tag) << ", albedo: ["
                     << yaml::formatNumber(tag.albedo_black) << ", " << yaml::formatNumber(tag.albedo_white) << "]}\n";
            }
        }
        if (!scene.real_objects.empty()) {
            out_ << "real:\n";
            for (const RealObject& object : scene.real_objects) {
                out_ << "  - name: " << yaml::quoteString(object.name) << "\n";
                writeShape(object.shape);
                out_ << "    world_from_object: " << yaml::formatTransform(object.world_from_object) << "\n";
                out_ << "    albedo: " << yaml::formatRgbOrEstimate(object.albedo) << "\n";
            }
        }
        if (!scene.lights.empty()) {
            out_ << "lights:\n";
            for (const Light& light : scene.lights) writeLight(light);
        }
        if (!scene.virtual_objects.empty()) {
            out_ << "virtual:\n";
            for (const VirtualObject& object : scene.virtual_objects) writeVirtual(object);
        }
        out_ << "lighting: {max_elements: " << scene.lighting.max_elements
             << ", error: " << yaml::formatNumber(scene.lighting.error);
        if (scene.lighting.texel_pairs) out_ << ", texel_pairs: " << *scene.lighting.texel_pairs;
        if (scene.lighting.texel_oversample) out_ << ", texel_oversample: " << *scene.lighting.texel_oversample;
        out_ << "}\n";
        return out_.str();
    }

private:
    std::string path(const std::filesystem::path& p) const { return yaml::quoteString(relativePath(p, base_dir_)); }

    std::string vector(const double* values, int count) const { return yaml::formatList(values, count); }

    void writeShape(const Shape& s) {
        out_ << "    ";
        std::visit(Overloaded{[&](const PlaneShape& p) { out_ << "plane: {size: " << vector(p.size.data(), 2) << "}"; },
                              [&](const BoxShape& b) { out_ << "box: {size: " << vector(b.size.data(), 3) << "}"; },
                              [&](const SphereShape& sp) {
                                  out_ << "sphere: {radius: " << yaml::formatNumber(sp.radius) << "}";
                              },
                              [&](const MeshShape& m) { out_ << "mesh: " << path(m.path); }},
                   s);
        out_ << "\n";
    }

    void writeLight(const Light& light) {
        out_ << "  - name: " << yaml::quoteString(light.name) << "\n    ";
        std::visit(
            Overloaded{
                [&](const AreaLightShape& a) { out_ << "area: {size: " << vector(a.size.data(), 2) << "}"; },
                [&](const DiscLightShape& d) { out_ << "disc: {radius: " << yaml::formatNumber(d.radius) << "}"; },
                [&](const PointLightShape&) { out_ << "point: {}"; },
                [&](const DirectionalLightShape& d) {
                    out_ << "directional: {direction: " << vector(d.direction.data(), 3) << "}";
                },
                [&](const DistantLightShape& d) { out_ << "distant: {directions: " << d.directions << "}"; }},
            light.shape);
        out_ << "\n";
        if (lightHasPose(light.shape)) {
            out_ << "    world_from_object: " << yaml::formatTransform(light.world_from_object) << "\n";
        }
        out_ << "    " << emissionKey(light.shape) << ": " << yaml::formatRgbOrEstimate(light.emission) << "\n";
    }

    void writeVirtual(const VirtualObject& object) {
        out_ << "  - name: " << yaml::quoteString(object.name) << "\n";
        writeShape(object.shape);
        const Material& m = object.material;
        out_ << "    material: {type: " << (m.type == MaterialType::kGgx ? "ggx" : "lambertian")
             << ", albedo: " << yaml::formatRgb(m.albedo);
        if (m.type == MaterialType::kGgx) out_ << ", roughness: " << yaml::formatNumber(m.roughness);
        out_ << "}\n";
        if (object.emission) out_ << "    emission: " << yaml::formatRgb(*object.emission) << "\n";
        std::visit(
            Overloaded{[&](const FixedPlacement& p) {
                           out_ << "    world_from_object: " << yaml::formatTransform(p.world_from_object) << "\n";
                       },
                       [&](const TagPlacement& p) {
                           out_ << "    attach: {tag: " << p.tag
                                << ", tag_from_object: " << yaml::formatTransform(p.tag_from_object) << "}\n";
                       },
                       [&](const KeyframePlacement& p) {
                           out_ << "    keyframes:\n";
                           for (const Keyframe& k : p.keyframes) {
                               out_ << "      - {t: " << yaml::formatNumber(k.t)
                                    << ", world_from_object: " << yaml::formatTransform(k.world_from_object) << "}\n";
                           }
                       }},
            object.placement);
    }

    std::filesystem::path base_dir_;
    std::ostringstream out_;
};

}  // namespace

std::string formatScene(const Scene& scene, const std::filesystem::path& base_dir) {
    return SceneFormatter(base_dir).format(scene);
}

Result<void> writeScene(const std::filesystem::path& file, const Scene& scene) {
    const std::filesystem::path base_dir = std::filesystem::absolute(file).lexically_normal().parent_path();
    return writeTextFileAtomic(file, formatScene(scene, base_dir));
}

}  // namespace commonlight

#include "core/scene.h"

#include <algorithm>
#include <cassert>

namespace commonlight {

namespace {

template <class... Ts>
struct Overloaded : Ts... {
    using Ts::operator()...;
};
// C++20 deduces this for aggregates by itself; clang 16 (the fuzz build) does not yet.
template <class... Ts>
Overloaded(Ts...) -> Overloaded<Ts...>;

}  // namespace

const char* shapeKey(const Shape& shape) {
    return std::visit(Overloaded{[](const PlaneShape&) { return "plane"; }, [](const BoxShape&) { return "box"; },
                                 [](const SphereShape&) { return "sphere"; }, [](const MeshShape&) { return "mesh"; }},
                      shape);
}

const char* lightKey(const LightShape& shape) {
    return std::visit(
        Overloaded{[](const AreaLightShape&) { return "area"; }, [](const DiscLightShape&) { return "disc"; },
                   [](const PointLightShape&) { return "point"; },
                   [](const DirectionalLightShape&) { return "directional"; },
                   [](const DistantLightShape&) { return "distant"; }},
        shape);
}

const char* emissionKey(const LightShape& shape) {
    if (std::holds_alternative<PointLightShape>(shape)) return "intensity";
    if (std::holds_alternative<DirectionalLightShape>(shape)) return "irradiance";
    return "radiance";
}

bool lightHasPose(const LightShape& shape) {
    return !std::holds_alternative<DirectionalLightShape>(shape) && !std::holds_alternative<DistantLightShape>(shape);
}

const TagItem* TagSet::find(int id) const {
    const auto it = std::find_if(items.begin(), items.end(), [id](const TagItem& tag) { return tag.id == id; });
    return it == items.end() ? nullptr : &*it;
}

Rigid3d poseAt(const std::vector<Keyframe>& keyframes, double t) {
    assert(!keyframes.empty());
    if (t <= keyframes.front().t) return keyframes.front().world_from_object;
    if (t >= keyframes.back().t) return keyframes.back().world_from_object;
    // First keyframe after t; the one before it exists because t > front().t.
    const auto next = std::upper_bound(keyframes.begin(), keyframes.end(), t,
                                       [](double time, const Keyframe& k) { return time < k.t; });
    const auto prev = next - 1;
    const double alpha = (t - prev->t) / (next->t - prev->t);  // times strictly increase: no zero division
    return interpolate(prev->world_from_object, next->world_from_object, alpha);
}

std::optional<Rigid3d> worldFromObject(const VirtualObject& object, const TagSet& tags, double t) {
    return std::visit(Overloaded{[](const FixedPlacement& p) -> std::optional<Rigid3d> { return p.world_from_object; },
                                 [&tags](const TagPlacement& p) -> std::optional<Rigid3d> {
                                     const TagItem* tag = tags.find(p.tag);
                                     if (tag == nullptr) return std::nullopt;
                                     return tag->world_from_tag * p.tag_from_object;
                                 },
                                 [t](const KeyframePlacement& p) -> std::optional<Rigid3d> {
                                     if (p.keyframes.empty()) return std::nullopt;
                                     return poseAt(p.keyframes, t);
                                 }},
                      object.placement);
}

int tagFamilySize(std::string_view family) {
    // Code counts of apriltag 3's families.
    struct Family {
        std::string_view name;
        int size;
    };
    static constexpr Family kFamilies[] = {
        {"tag36h11", 587},
        {"tag25h9", 35},
        {"tag16h5", 30},
        {"tagCircle21h7", 38},
        {"tagCircle49h12", 65535},
        {"tagCustom48h12", 42211},
        {"tagStandard41h12", 2115},
        {"tagStandard52h13", 48714},
    };
    for (const Family& f : kFamilies) {
        if (f.name == family) return f.size;
    }
    return 0;
}

}  // namespace commonlight

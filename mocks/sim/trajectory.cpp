#include "mocks/sim/trajectory.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "core/file_util.h"
#include "core/scene_yaml.h"
#include "core/yaml_util.h"
#include "core/reader_guard.h"

namespace commonlight::mocks::sim {

namespace {

constexpr double kDegToRad = std::numbers::pi / 180.0;

Result<Eigen::Vector3d> getPoint(const std::string& file, const YAML::Node& map, const std::string& key) {
    CL_TRY(const auto v, yaml::getDoubles(file, map, key, 3));
    return Eigen::Vector3d(v[0], v[1], v[2]);
}

Result<Rigid3d> lookAtOrError(const std::string& file, const YAML::Node& node, const std::string& key,
                              const Eigen::Vector3d& eye, const Eigen::Vector3d& target) {
    auto pose = worldFromCamLookingAt(eye, target);
    if (!pose) return fail(yaml::keyError(file, node, key, pose.error().message));
    return *pose;
}

Result<std::vector<CameraKeyframe>> readKeyframes(const std::string& file, const YAML::Node& root) {
    CL_TRY(const YAML::Node list, yaml::getList(file, root, "keyframes"));
    std::vector<CameraKeyframe> keys;
    for (std::size_t i = 0; i < list.size(); ++i) {
        const std::string path = yaml::indexKey("keyframes", i);
        const YAML::Node item = list[i];
        CL_TRY_VOID(yaml::checkKeys(file, item, path, {"t", "eye", "target", "world_from_cam"}));
        CameraKeyframe key;
        CL_TRY(key.t_s, yaml::getDouble(file, item, yaml::joinKey(path, "t")));
        const bool look_at = yaml::has(item, "eye") || yaml::has(item, "target");
        if (look_at == yaml::has(item, "world_from_cam")) {
            return fail(yaml::keyError(file, item, path, "give either eye + target or world_from_cam"));
        }
        if (look_at) {
            CL_TRY(const Eigen::Vector3d eye, getPoint(file, item, yaml::joinKey(path, "eye")));
            CL_TRY(const Eigen::Vector3d target, getPoint(file, item, yaml::joinKey(path, "target")));
            CL_TRY(key.world_from_cam, lookAtOrError(file, item, path, eye, target));
        } else {
            CL_TRY(key.world_from_cam, yaml::getTransform(file, item, yaml::joinKey(path, "world_from_cam")));
        }
        if (!keys.empty() && key.t_s <= keys.back().t_s) {
            return fail(yaml::keyError(file, item, yaml::joinKey(path, "t"), "times must increase strictly"));
        }
        keys.push_back(key);
    }
    if (keys.empty()) return fail(yaml::keyError(file, list, "keyframes", "needs at least one keyframe"));
    return keys;
}

Result<OrbitTrajectory> readOrbit(const std::string& file, const YAML::Node& root) {
    CL_TRY(const YAML::Node map, yaml::getMap(file, root, "orbit"));
    CL_TRY_VOID(yaml::checkKeys(file, map, "orbit", {"target", "radius", "height", "from_deg", "to_deg", "duration"}));
    OrbitTrajectory orbit;
    CL_TRY(orbit.target, getPoint(file, map, "orbit.target"));
    CL_TRY(orbit.radius, yaml::getPositive(file, map, "orbit.radius"));
    CL_TRY(orbit.height, yaml::getDouble(file, map, "orbit.height"));
    CL_TRY(orbit.from_deg, yaml::getDouble(file, map, "orbit.from_deg"));
    CL_TRY(orbit.to_deg, yaml::getDouble(file, map, "orbit.to_deg"));
    CL_TRY(orbit.duration_s, yaml::getPositive(file, map, "orbit.duration"));
    return orbit;
}

Result<PanTrajectory> readPan(const std::string& file, const YAML::Node& root) {
    CL_TRY(const YAML::Node map, yaml::getMap(file, root, "pan"));
    CL_TRY_VOID(yaml::checkKeys(file, map, "pan", {"eye", "from", "to", "duration"}));
    PanTrajectory pan;
    CL_TRY(pan.eye, getPoint(file, map, "pan.eye"));
    CL_TRY(pan.from, getPoint(file, map, "pan.from"));
    CL_TRY(pan.to, getPoint(file, map, "pan.to"));
    CL_TRY(pan.duration_s, yaml::getPositive(file, map, "pan.duration"));
    // Every target on the way must give a defined look-at.
    for (int i = 0; i <= 8; ++i) {
        const Eigen::Vector3d target = pan.from + (pan.to - pan.from) * (i / 8.0);
        CL_TRY_VOID(lookAtOrError(file, map, "pan", pan.eye, target));
    }
    return pan;
}

}  // namespace

Result<Trajectory> Trajectory::fromKeyframes(std::vector<CameraKeyframe> keyframes, double rate_hz) {
    if (keyframes.empty()) return fail(ErrorCode::kBadInput, "a trajectory needs at least one keyframe");
    if (!(rate_hz > 0)) return fail(ErrorCode::kBadInput, "trajectory rate must be positive");
    for (std::size_t i = 1; i < keyframes.size(); ++i) {
        if (!(keyframes[i].t_s > keyframes[i - 1].t_s)) {
            return fail(ErrorCode::kBadInput, "trajectory keyframe times must increase strictly");
        }
    }
    Trajectory trajectory;
    trajectory.path_ = std::move(keyframes);
    trajectory.rate_hz_ = rate_hz;
    return trajectory;
}

Result<Trajectory> Trajectory::parse(const std::string& text, const std::string& name) {
    return guardReader(name, [&]() -> Result<Trajectory> {
        CL_TRY(const YAML::Node root, yaml::loadString(text, name));
        CL_TRY_VOID(yaml::checkKeys(name, root, "", {"rate_hz", "keyframes", "orbit", "pan"}));
        const int kinds = int(yaml::has(root, "keyframes")) + int(yaml::has(root, "orbit")) + int(yaml::has(root, "pan"));
        if (kinds != 1) {
            return fail(ErrorCode::kBadInput, name + ": a trajectory has exactly one of keyframes, orbit or pan");
        }
        Trajectory trajectory;
        if (yaml::has(root, "rate_hz")) {
            CL_TRY(trajectory.rate_hz_, yaml::getPositive(name, root, "rate_hz"));
        }
        if (yaml::has(root, "keyframes")) {
            CL_TRY(trajectory.path_, readKeyframes(name, root));
        } else if (yaml::has(root, "orbit")) {
            CL_TRY(trajectory.path_, readOrbit(name, root));
        } else {
            CL_TRY(trajectory.path_, readPan(name, root));
        }
        return trajectory;
    });
}

Result<Trajectory> Trajectory::read(const std::filesystem::path& file) {
    CL_TRY(const std::string text, readTextFile(file));
    return parse(text, file.string());
}

namespace {

Rigid3d lookAt(const Eigen::Vector3d& eye, const Eigen::Vector3d& target) {
    // Validated when read: defined everywhere on the path.
    return *worldFromCamLookingAt(eye, target);
}

}  // namespace

Rigid3d Trajectory::worldFromCam(double t_s) const {
    if (const auto* keys = std::get_if<std::vector<CameraKeyframe>>(&path_)) {
        if (t_s <= keys->front().t_s) return keys->front().world_from_cam;
        if (t_s >= keys->back().t_s) return keys->back().world_from_cam;
        const auto next = std::upper_bound(keys->begin(), keys->end(), t_s,
                                           [](double t, const CameraKeyframe& k) { return t < k.t_s; });
        const auto& a = *(next - 1);
        const auto& b = *next;
        return interpolateSe3(a.world_from_cam, b.world_from_cam, (t_s - a.t_s) / (b.t_s - a.t_s));
    }
    if (const auto* orbit = std::get_if<OrbitTrajectory>(&path_)) {
        const double s = std::clamp(t_s / orbit->duration_s, 0.0, 1.0);
        const double azimuth = (orbit->from_deg + (orbit->to_deg - orbit->from_deg) * s) * kDegToRad;
        const Eigen::Vector3d eye = orbit->target + Eigen::Vector3d(orbit->radius * std::sin(azimuth),
                                                                    -orbit->radius * std::cos(azimuth), orbit->height);
        return lookAt(eye, orbit->target);
    }
    const auto& pan = std::get<PanTrajectory>(path_);
    const double s = std::clamp(t_s / pan.duration_s, 0.0, 1.0);
    return lookAt(pan.eye, pan.from + (pan.to - pan.from) * s);
}

double Trajectory::startTime() const noexcept {
    if (const auto* keys = std::get_if<std::vector<CameraKeyframe>>(&path_)) return keys->front().t_s;
    return 0.0;
}

double Trajectory::endTime() const noexcept {
    if (const auto* keys = std::get_if<std::vector<CameraKeyframe>>(&path_)) return keys->back().t_s;
    if (const auto* orbit = std::get_if<OrbitTrajectory>(&path_)) return orbit->duration_s;
    return std::get<PanTrajectory>(path_).duration_s;
}

int Trajectory::frameCount() const noexcept {
    return static_cast<int>(std::floor((endTime() - startTime()) * rate_hz_ + 1e-9)) + 1;
}

}  // namespace commonlight::mocks::sim

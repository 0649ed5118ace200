#include "bench/lighting_eval.h"

#include <tbb/parallel_for.h>

#include <cmath>
#include <numbers>
#include <variant>

#include "lighting/sampling.h"
#include "mocks/sim/embree_scene.h"
#include "mocks/sim/path_tracer.h"
#include "mocks/sim/render.h"
#include "mocks/sim/sensor.h"

namespace commonlight::bench {

double radianceScale(const mocks::sim::SensorParams& s) {
    // DN above black per unit radiance per second: electrons_per_radiance_second x K x g; the
    // delivered linear value is that over the full scale (2^bits - 1 - black); relative radiance
    // divides by exposure x gain.
    const double full_scale = s.maxDn() - s.blackLevelDn();
    return s.electrons_per_radiance_second * s.systemGainDnPerE() / full_scale;
}

Result<std::vector<SimFrame>> renderFrames(const Scene& truth, const CameraModel& camera,
                                           const std::vector<Rigid3d>& world_from_cam, const RenderSettings& settings) {
    mocks::sim::SimSceneOptions scene_options;
    scene_options.include_virtual = settings.include_virtual;
    CL_TRY(mocks::sim::SimScene sim, mocks::sim::SimScene::build(truth, scene_options));
    CL_TRY(mocks::sim::SensorModel sensor, mocks::sim::SensorModel::create(settings.sensor, camera.width, camera.height));
    std::vector<SimFrame> frames;
    mocks::sim::RawFrame raw;
    for (std::size_t i = 0; i < world_from_cam.size(); ++i) {
        mocks::sim::RenderRequest request;
        request.scene = &sim;
        request.camera = camera;
        request.world_from_cam = world_from_cam[i];
        request.spp = settings.spp;
        request.seed = settings.seed;
        request.frame_index = i;
        request.max_depth = settings.max_depth;
        CL_TRY(mocks::sim::RenderOutput out, mocks::sim::render(request));
        CL_TRY_VOID(sensor.expose(out.radiance.view(), settings.seed * 1000 + i, raw));
        SimFrame frame;
        sensor.encode8(raw, frame.rgb8);
        frame.cam_from_world = world_from_cam[i].inverse();
        frame.exposure_s = settings.sensor.exposureS();
        frame.gain = settings.sensor.analog_gain;
        if (settings.keep_radiance) frame.radiance = std::move(out.radiance);
        frames.push_back(std::move(frame));
    }
    return frames;
}

namespace {

// Whether a point lies inside a real box other than `own` (the truth's own geometry).
bool insideOtherBox(const Scene& scene, int own, const Eigen::Vector3d& p) {
    for (std::size_t o = 0; o < scene.real_objects.size(); ++o) {
        if (static_cast<int>(o) == own) continue;
        const auto* box = std::get_if<BoxShape>(&scene.real_objects[o].shape);
        if (!box) continue;
        const Eigen::Vector3d q = scene.real_objects[o].world_from_object.inverse() * p;
        if ((q.cwiseAbs().array() < 0.5 * box->size.array()).all()) return true;
    }
    return false;
}

}  // namespace

Result<std::vector<Eigen::Vector3d>> truthOfLeaves(const Scene& truth, const lighting::Estimator& estimator,
                                                   const std::vector<int>& leaves, bool with_virtual, int points,
                                                   int samples, std::uint64_t seed, int max_depth) {
    mocks::sim::IntegratorOptions integrator;
    integrator.max_depth = max_depth;
    mocks::sim::SimSceneOptions scene_options;
    scene_options.include_virtual = with_virtual;
    CL_TRY(mocks::sim::SimScene sim, mocks::sim::SimScene::build(truth, scene_options));
    const lighting::Radiosity& rad = estimator.radiosity();
    std::vector<Eigen::Vector3d> out(leaves.size(), Eigen::Vector3d::Zero());
    tbb::parallel_for(std::size_t{0}, leaves.size(), [&](std::size_t k) {
        const int e = leaves[k];
        const lighting::ElementGeometry g = rad.geometry(e);
        const lighting::Face& face = rad.face(rad.hierarchy()[e].face);
        const Eigen::Vector3d albedo =
            truth.real_objects[static_cast<std::size_t>(face.object_index)].albedo.value.value_or(Eigen::Vector3d::Constant(0.5));
        Eigen::Vector3d sum = Eigen::Vector3d::Zero();
        int used = 0;
        for (int p = 0; p < points * 4 && used < points; ++p) {
            const Eigen::Vector2d u = lighting::stratified2d(lighting::hashCombine(seed, static_cast<std::uint64_t>(e)), p, points);
            double a = u.x(), b = u.y();
            if (g.triangle && a + b > 1.0) {
                a = 1.0 - a;
                b = 1.0 - b;
            }
            const Eigen::Vector3d x = g.corner + a * g.edge_s + b * g.edge_t;
            // Only the visible surface: a point inside another proxy (under a box resting on the
            // element) is no part of what a camera or the model sees.
            if (insideOtherBox(truth, face.object_index, x + 1e-4 * g.normal)) continue;
            sum += mocks::sim::estimateIrradiance(sim, x, g.normal, samples, lighting::hashCombine(seed, k * 131 + p), integrator);
            ++used;
        }
        out[k] = used > 0 ? Eigen::Vector3d(albedo.cwiseProduct(sum) / (used * std::numbers::pi)) : Eigen::Vector3d::Zero();
    });
    return out;
}

std::vector<Rigid3d> orbitPoses(const Eigen::Vector3d& target, double radius, double height, double from_deg,
                                double to_deg, int count) {
    std::vector<Rigid3d> poses;
    for (int i = 0; i < count; ++i) {
        const double t = count > 1 ? static_cast<double>(i) / (count - 1) : 0.5;
        const double a = (from_deg + t * (to_deg - from_deg)) * std::numbers::pi / 180.0;
        const Eigen::Vector3d eye = target + Eigen::Vector3d(radius * std::sin(a), -radius * std::cos(a), height);
        poses.push_back(*worldFromCamLookingAt(eye, target));
    }
    return poses;
}

Scene asEstimated(const Scene& truth, bool lights, bool albedos) {
    Scene s = truth;
    if (lights) {
        for (Light& l : s.lights) l.emission = RgbOrEstimate::estimate();
    }
    if (albedos) {
        for (RealObject& o : s.real_objects) o.albedo = RgbOrEstimate::estimate();
    }
    return s;
}

}  // namespace commonlight::bench

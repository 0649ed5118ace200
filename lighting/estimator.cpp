#include "lighting/estimator.h"
#include "lighting/estimator_impl.h"

#include <tbb/parallel_for.h>
#if defined(__SANITIZE_THREAD__)
#include <tbb/global_control.h>
#endif

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <map>
#include <numbers>
#include <variant>
#include <cstdio>
#include <cstdlib>

#include "core/log.h"
#include "lighting/distant.h"
#include "lighting/form_factor.h"
#include "lighting/influence.h"
#include "lighting/sampling.h"
#include "lighting/snapshot_builder.h"
#include "lighting/texel_direct.h"

namespace commonlight::lighting {

using namespace estimator_detail;

#if defined(__SANITIZE_THREAD__)
namespace {
// ThreadSanitizer cannot see oneTBB's hand-over of tasks between its workers (libtbb is not built
// with TSan), so every parallel_for would be reported as a race between a worker's writes and the
// caller's reads. Under TSan the lighting module's TBB work therefore runs on the calling thread
// alone: the checks then cover the threads that are ours (the lighting engine's thread, its
// producers and readers), which is what the TSan suite is for.
const tbb::global_control kTsanParallelism(tbb::global_control::max_allowed_parallelism, 1);
}  // namespace
#endif

namespace {

// The influence's options. When the area lights' direct light is drawn per texel (every light an
// area or disc light: lighting/texel_direct.h), the elements follow only what they draw themselves
// (the indirect light, the objects' own light, the direct light's share of D) and need not follow
// the penumbrae to the pixel: EstimatorOptions::texel_refine_epsilon and texel_footprint_pixels.
InfluenceOptions influenceOptions(const EstimatorOptions& o, const Scene& scene) {
    InfluenceOptions io = o.influence;
    io.max_leaves = o.radiosity.max_elements;
    const bool per_texel = o.texel_direct_pairs > 0 && !scene.lights.empty() && std::all_of(scene.lights.begin(), scene.lights.end(), [](const Light& l) {
                               return std::holds_alternative<AreaLightShape>(l.shape) || std::holds_alternative<DiscLightShape>(l.shape);
                           });
    if (per_texel) {
        io.refine_epsilon = o.texel_refine_epsilon;
        io.footprint_pixels = o.texel_footprint_pixels;
        io.direct_per_texel = true;
    }
    return io;
}

}  // namespace

Estimator::Estimator(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Estimator::~Estimator() = default;

Result<std::unique_ptr<Estimator>> Estimator::create(const Scene& scene, const CameraModel& camera,
                                                     const SceneLightingOptions& options,
                                                     const EstimatorOptions& estimator_options) {
    CL_TRY_VOID(camera.validate());
    auto impl = std::make_unique<Impl>();
    impl->scene = scene;
    impl->camera = camera;
    impl->options = options;
    // Step 1: faces and their validation (errors name the object).
    CL_TRY(impl->real_faces, realFaces(scene));
    std::vector<VirtualShape> shapes;
    for (std::size_t v = 0; v < scene.virtual_objects.size(); ++v) {
        CL_TRY(std::vector<Face> faces, virtualFaces(scene, static_cast<int>(v)));
        VirtualShape shape;
        const auto* sphere = std::get_if<SphereShape>(&scene.virtual_objects[v].shape);
        if (sphere) {
            shape.sphere_radius = sphere->radius;
        } else {
            shape.faces = faces;
        }
        impl->sphere_radius.push_back(sphere ? sphere->radius : 0.0);
        impl->virtual_faces.insert(impl->virtual_faces.end(), faces.begin(), faces.end());
        shapes.push_back(std::move(shape));
    }
    CL_TRY(impl->light_geometry, lightGeometry(scene));

    auto out = std::unique_ptr<Estimator>(new Estimator(std::move(impl)));
    Impl& d = *out->impl_;
    out->options_ = estimator_options;
    out->options_.radiosity.max_elements = std::max(64, scene.lighting.max_elements);
    if (scene.lighting.texel_pairs) out->options_.texel_direct_pairs = *scene.lighting.texel_pairs;
    if (scene.lighting.texel_oversample) out->options_.texel_direct_oversample = *scene.lighting.texel_oversample;
    out->radiance_scale_ = options.radiance_scale.value_or(1.0);
    if (!options.radiance_scale) {
        d.setup_warnings.push_back(
            "the camera is not radiometrically calibrated (no radiance_scale): emissions are in relative units");
    }

    // Step 2: Embree scenes, the radiosity system and the observation grids.
    CL_TRY(out->rays_, RayScene::build(d.real_faces, d.light_geometry, shapes));
    out->radiosity_ = std::make_unique<Radiosity>(d.real_faces, d.virtual_faces, d.sphere_radius, *out->rays_,
                                                  out->options_.radiosity);
    d.influence = std::make_unique<VirtualInfluence>(*out->radiosity_, *out->rays_, influenceOptions(out->options_, scene));
    d.present.assign(scene.virtual_objects.size(), true);
    d.emission.assign(scene.virtual_objects.size(), std::nullopt);
    out->observations_ = std::make_unique<Observations>(d.real_faces, scene, camera, options.response,
                                                        options.observation_stride, out->options_.observation_cell,
                                                        options.observation_interleave);
    d.poses = scenePoses(scene, 0.0);

    // Step 3: the light model's columns.
    for (std::size_t i = 0; i < scene.lights.size(); ++i) {
        const Light& light = scene.lights[i];
        const bool estimate = light.emission.isEstimate();
        const Eigen::Vector3d known = estimate ? Eigen::Vector3d::Zero() : Eigen::Vector3d(*light.emission.value * out->radiance_scale_);
        Source s;
        s.light = static_cast<int>(i);
        s.estimate = estimate;
        s.known = known;
        if (std::holds_alternative<AreaLightShape>(light.shape) || std::holds_alternative<DiscLightShape>(light.shape)) {
            s.direct.kind = DirectSource::Kind::kPolygon;
            for (const LightGeometry& g : d.light_geometry) {
                if (g.light_index == static_cast<int>(i)) s.direct.polygon = &g;
            }
            if (!s.direct.polygon) continue;
        } else if (std::holds_alternative<PointLightShape>(light.shape)) {
            s.direct.kind = DirectSource::Kind::kPoint;
            s.direct.position = light.world_from_object.translation;
        } else if (const auto* dir = std::get_if<DirectionalLightShape>(&light.shape)) {
            s.direct.kind = DirectSource::Kind::kDirection;
            if (!(dir->direction.allFinite() && dir->direction.norm() > 0.0)) {
                return fail(ErrorCode::kBadInput, "light '" + light.name + "': direction must be a non-zero vector");
            }
            s.direct.direction = dir->direction.normalized();
        } else if (const auto* distant = std::get_if<DistantLightShape>(&light.shape)) {
            const int n = distant->directions > 0 ? distant->directions : 128;
            for (DirectSource cell : distantCells(static_cast<int>(i), n)) {
                Source c = s;
                c.direct = cell;
                d.sources.push_back(std::move(c));
            }
            continue;
        }
        s.direct.light = static_cast<int>(i);
        d.sources.push_back(std::move(s));
    }
    // Reflectance groups: one per real object whose albedo is to be estimated.
    d.group_of_object.assign(scene.real_objects.size(), -1);
    for (std::size_t o = 0; o < scene.real_objects.size(); ++o) {
        if (scene.real_objects[o].albedo.isEstimate()) d.group_of_object[o] = d.groups++;
    }
    d.group_albedo.assign(static_cast<std::size_t>(d.groups), Eigen::Vector3d::Constant(0.5));
    return out;
}

void Estimator::setVirtualPoses(const std::vector<Rigid3d>& world_from_object) {
    Impl& d = *impl_;
    if (world_from_object.size() != d.scene.virtual_objects.size()) return;
    bool changed = false;
    for (std::size_t i = 0; i < world_from_object.size(); ++i) {
        const Rigid3d& a = world_from_object[i];
        const Rigid3d& b = d.poses[i];
        if (!a.isValid()) continue;  // hard case: a NaN pose keeps the last good one
        if ((a.translation - b.translation).norm() > 1e-9 || a.rotation.angularDistance(b.rotation) > 1e-9) {
            d.poses[i] = a;
            changed = true;
        }
    }
    if (changed || !d.mesh_built) d.poses_changed = true;
}

void Estimator::setVirtualPresent(int index, bool present) {
    Impl& d = *impl_;
    if (index >= 0 && static_cast<std::size_t>(index) < d.present.size()) d.present[static_cast<std::size_t>(index)] = present;
}

void Estimator::setVirtualEmission(int index, const std::optional<Eigen::Vector3d>& emission) {
    Impl& d = *impl_;
    if (index < 0 || static_cast<std::size_t>(index) >= d.emission.size()) return;
    if (emission && !(emission->allFinite() && emission->minCoeff() >= 0.0)) return;  // hard case: keep the last good one
    d.emission[static_cast<std::size_t>(index)] = emission;
}

void Estimator::setViewer(const std::optional<Rigid3d>& cam_from_world) {
    if (cam_from_world && !cam_from_world->isValid()) return;
    impl_->viewer = cam_from_world;
}

void Estimator::requestFullUpdate() { impl_->force_full = true; }

VirtualInfluence& Estimator::influence() noexcept { return *impl_->influence; }
const VirtualInfluence& Estimator::influence() const noexcept { return *impl_->influence; }

Result<void> Estimator::observe(const ImageView& rgb8, const Rigid3d& cam_from_world, double exposure_s,
                                double analog_gain, std::int64_t) {
    Impl& d = *impl_;
    if (cam_from_world.isValid()) d.viewer = cam_from_world;
    if (d.poses_changed) {
        for (std::size_t v = 0; v < d.poses.size(); ++v) rays_->setVirtualPose(static_cast<int>(v), d.poses[v]);
        CL_TRY_VOID(rays_->commitVirtual());
    }
    const auto t0 = std::chrono::steady_clock::now();
    CL_TRY(FrameObservation frame, observations_->add(rgb8, cam_from_world, exposure_s, analog_gain, *rays_, d.illuminant));
    (void)frame;
    last_observe_ms_ = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    return {};
}

const DirectColumn* Estimator::column(int light) const {
    for (const Source& s : impl_->sources) {
        if (s.light == light && s.direct.kind != DirectSource::Kind::kCell) return &s.column;
    }
    return nullptr;
}

Result<void> Estimator::solveWith(const std::vector<Eigen::Vector3d>& emission, const std::vector<Eigen::Vector3d>& albedo,
                                  const std::vector<Rigid3d>& virtual_world_from_object) {
    Impl& d = *impl_;
    if (emission.size() != d.scene.lights.size() || albedo.size() != d.scene.real_objects.size()) {
        return fail(ErrorCode::kUsage, "solveWith: one emission per light and one albedo per real object");
    }
    for (Source& s : d.sources) {
        s.estimate = false;
        s.known = emission[static_cast<std::size_t>(s.light)];
    }
    for (std::size_t f = 0; f < d.real_faces.size(); ++f) {
        d.real_faces[f].albedo = albedo[static_cast<std::size_t>(d.real_faces[f].object_index)];
        d.real_faces[f].albedo_known = true;
    }
    // The radiosity system reads albedos from its own faces: rebuild it with the new ones.
    radiosity_ = std::make_unique<Radiosity>(d.real_faces, d.virtual_faces, d.sphere_radius, *rays_, options_.radiosity);
    d.influence = std::make_unique<VirtualInfluence>(*radiosity_, *rays_, influenceOptions(options_, d.scene));
    d.face_builds.clear();
    d.mesh_built = false;
    d.links_from_fit = false;
    d.poses_changed = true;
    d.column_valid.clear();
    for (Source& s : d.sources) s.column = {};
    for (auto& g : d.group_of_object) g = -1;
    d.groups = 0;
    d.group_albedo.clear();
    // Nothing needs observing: a pseudo-observation is not used by the known-everything path.
    CL_TRY(LightingSnapshot ignored, update(virtual_world_from_object));
    (void)ignored;
    return {};
}

}  // namespace commonlight::lighting

// The estimator behind SceneLighting (lighting/scene_lighting.h): observations -> lights and
// reflectances -> radiosity with and without the virtual objects -> snapshot. Public so that
// tests and the benchmark can reach its intermediate results (the fit, the solutions).
//
// The three light cases, chosen per light by the scene file (issue 10, seeds 001 and 003):
//   1. Known geometry, unknown emission (`radiance: estimate`): one unit-emission direct column per
//      light; emissions fitted jointly with per-object reflectances (lighting/light_fit.h).
//   2. Unknown distant light (`distant: {directions: N}`): N equal-solid-angle cells of the upper
//      hemisphere as columns, interreflection removed first (inverse radiosity), NNLS with a small
//      Tikhonov term; then the dominant direction refined continuously (a pattern search on the
//      direction of a directional light added to the fit).
//   3. No light at all in the scene: every observed surface emits what is not explained by
//      interreflection (seed 001 sec. 4.4.2), so virtual objects still shadow and bounce light.
// Lights whose emission the scene gives are used as given (in scene units, times radiance_scale).
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "lighting/direct.h"
#include "lighting/influence.h"
#include "lighting/light_fit.h"
#include "lighting/observations.h"
#include "lighting/radiosity.h"
#include "lighting/ray_scene.h"
#include "lighting/scene_lighting.h"

namespace commonlight::lighting {

struct EstimatorOptions {
    RadiosityOptions radiosity;
    InfluenceOptions influence;         // the virtual objects' influence (max_leaves: the scene's element budget)
    double initial_element_size = 0.0;  // metres; 0: from the scene's area and the element budget (1/16 of it)
    double light_refinement_size = 0.04;  // metres: refinement by light and observations stops here
    double observation_cell = 0.01;     // metres
    double tikhonov = 1e-4;             // relative (lighting/light_fit.h), known-geometry lights
    double distant_tikhonov = 1e-3;     // relative, distant cells
    int fit_iterations = 2;             // outer passes of (fit, reflectances, solve)
    bool refine_distant = true;         // continuous refinement of the dominant distant direction
    int min_pixels = 3;                 // an element counts as observed from this many pixels
    int min_ring_pixels = 4;            // a tag's white ring anchors the scale from this many pure pixels
    bool refine_by_light = true;        // split leaves where direct light varies (shadow boundaries)
    bool refine_unobserved = false;     // ... also where no frame has looked (benchmarks of the solver)
    bool refine_by_observation = true;  // split observed leaves whose radiance varies
    double mean_albedo_prior = 0.5;     // scale of reflectances when nothing of known albedo is seen
    // The area lights' direct light per texel where the virtual objects change it, from this many
    // visibility pairs per texel and light (lighting/texel_direct.h); 0: the elements' (box-filtered).
    int texel_direct_pairs = 16;  // at most 64 (a bit mask per texel and light)
    int texel_direct_oversample = 1;  // texels per 2 camera pixels along a side on those faces (without a camera:
                                      // per finest leaf)
    // With the direct light drawn per texel, the influence's elements follow only what they draw
    // themselves (InfluenceOptions::refine_epsilon and footprint_pixels for them; measured by
    // `commonlight bench lighting --incremental`: the same ratio with a third fewer answers per move).
    double texel_refine_epsilon = 0.05;
    double texel_footprint_pixels = 4.0;
};

// One light's estimate, in relative units (multiply by 1 / radiance_scale for scene units).
struct LightEstimate {
    int light = -1;                 // Scene::lights index
    Eigen::Vector3d emission = Eigen::Vector3d::Zero();  // per-unit of the light's quantity (radiance, intensity, irradiance)
    bool estimated = false;
    Eigen::Vector3d relative_error = Eigen::Vector3d::Zero();
    std::string warning;
    // Distant lights: the cells' radiance and the refined dominant direction (towards the light).
    std::vector<Eigen::Vector3d> cells;
    std::optional<Eigen::Vector3d> dominant_direction;
    Eigen::Vector3d dominant_irradiance = Eigen::Vector3d::Zero();  // on a surface facing it, relative
    double condition_number = 0.0;
    int negative_in_plain_least_squares = 0;
};

// Where an update's time and elements went (the benchmark reports them).
struct EstimatorStats {
    int leaves_initial = 0;       // after the initial mesh
    int leaves_light = 0;         // after refinement where direct light varies
    int leaves_links = 0;         // after link refinement
    int leaves_observation = 0;   // after refinement where the observations vary
    int observed_leaves = 0;
    double ms_columns = 0.0;      // direct-light columns (visibility rays)
    double ms_links = 0.0;        // link refinement, form factors and visibility
    double ms_fit = 0.0;          // light and reflectance fit (all passes)
    double ms_solve = 0.0;        // the radiosity solves
    double ms_snapshot = 0.0;     // textures and probes
    long texels_built = 0;        // texels the update's textures computed (lighting/snapshot_builder.h FaceBuild) ...
    long texels = 0;              // ... of the texels of the faces it rebuilt
    long texels_traced = 0;       // ... and of those, the texels whose direct light was traced again (a move reached it)
    double ms_observe = 0.0;      // the last frame's observation (ray cast and accumulation)
    double ms_influence = 0.0;    // the virtual objects' influence (lighting/influence.h)
    double ms_base = 0.0;         // ... its new base at a full update (setBase(): the shaft index)
    bool full = false;            // a full update (fit, B~); else only the influence, incrementally
    int leaves = 0;               // leaves in use, real and virtual
    InfluenceStats influence;
};

class Estimator final : public SceneLighting {
public:
    static Result<std::unique_ptr<Estimator>> create(const Scene& scene, const CameraModel& camera,
                                                     const SceneLightingOptions& options,
                                                     const EstimatorOptions& estimator = {});
    ~Estimator() override;

    void setVirtualPoses(const std::vector<Rigid3d>& world_from_object) override;
    // A virtual object taken out of the scene (false) or put back; its emission changed (scene
    // units, W/(m^2 sr); nullopt: the scene's). Both take effect at the next update(), which
    // updates incrementally like a move (a virtual light turned on is an update like any other).
    void setVirtualPresent(int index, bool present);
    void setVirtualEmission(int index, const std::optional<Eigen::Vector3d>& emission);
    // The camera whose resolution the refinement follows (observe() sets it to the newest frame's);
    // nullopt: none, elements down to InfluenceOptions::min_size.
    void setViewer(const std::optional<Rigid3d>& cam_from_world);
    // The next update() is a full one (fit, B~, the influence from scratch) even if no new frame
    // asks for it. Full updates otherwise happen when the observations have doubled since the last.
    void requestFullUpdate();
    VirtualInfluence& influence() noexcept;
    const VirtualInfluence& influence() const noexcept;
    Result<void> observe(const ImageView& rgb8, const Rigid3d& cam_from_world, double exposure_s, double analog_gain,
                         std::int64_t timestamp_ns) override;
    Result<LightingSnapshot> update(const std::vector<Rigid3d>& virtual_world_from_object) override;

    bool lastUpdateFull() const override { return stats_.full; }
    bool nextUpdateFull() const override;

    // After update(): the estimates and solutions it used.
    const std::vector<LightEstimate>& lights() const noexcept { return estimates_; }
    const Radiosity& radiosity() const noexcept { return *radiosity_; }
    const Observations& observations() const noexcept { return *observations_; }
    const Solution& without() const noexcept { return without_; }   // B~ (the base's leaves; influence().original() adds the refined)
    const Solution& with() const noexcept { return with_; }         // B: radiance by element (every leaf, refined ones too)
    const std::vector<Eigen::Vector3d>& reflectance() const noexcept { return rho_; }  // per element
    const std::vector<std::string>& warnings() const noexcept { return warnings_; }
    const EstimatorStats& stats() const noexcept { return stats_; }
    // The last fit's relative residual (weighted RMS of observed - model over RMS of observed,
    // largest over the channels); 0 when nothing was fitted.
    double fitResidual() const noexcept { return fit_residual_; }
    double radianceScale() const noexcept { return radiance_scale_; }
    EstimatorOptions& options() noexcept { return options_; }
    // Solve with given emissions and reflectances (no fit): for benchmarks that isolate the solver.
    // `emission`: per scene light, relative units; `albedo_override`: per real object.
    Result<void> solveWith(const std::vector<Eigen::Vector3d>& emission, const std::vector<Eigen::Vector3d>& albedo,
                           const std::vector<Rigid3d>& virtual_world_from_object);
    // What a snapshot predicts for a camera view: per pixel the ratio B/B~ (RGB) of the real surface
    // it sees, sampled bilinearly from the snapshot's face textures (kRgbF32; NaN where the pixel
    // sees no real proxy or sees a virtual object; with `through_virtual` the real proxy behind
    // the object: SceneLighting::ratioImage()). Every `stride`-th pixel (the others NaN).
    Result<Image> ratioImage(const LightingSnapshot& snapshot, const Rigid3d& cam_from_world, int stride = 1,
                             bool through_virtual = false) const override;

    // Analysis for the benchmark (issue 12: per-texel shadow rays against element links for the
    // direct term). For the pixels of a camera view with `mask` set (width x height, row-major;
    // empty: all) that see a real surface: the ratio B/B~ (luminance) with the direct light of area
    // lights computed at the pixel's own surface point (`pairs` visibility pairs per light, kernel-
    // weighted as the elements' are: real and virtual occluders) and the indirect light and the
    // other lights' direct light from the pixel's leaf (B~'s gathered irradiance, the influence's
    // change of it); beside it the same formula with the leaf's own direct light (what the
    // elements predict before the textures' filtering), the real face index (-1: none), and the
    // time and the visibility rays the per-texel direct light took.
    struct TexelRatio {
        std::vector<float> texel, leaf;  // NaN where not computed
        std::vector<int> face;
        double ms = 0.0;
        long rays = 0;
    };
    Result<TexelRatio> texelDirectRatio(const Rigid3d& cam_from_world, int pairs, const std::vector<std::uint8_t>& mask) const;

    // The unit-emission direct column of a scene light (area, disc, point, directional), for tests.
    const DirectColumn* column(int light) const;

    struct Impl;

private:
    explicit Estimator(std::unique_ptr<Impl> impl);
    Result<LightingSnapshot> incrementalUpdate();
    Result<LightingSnapshot> finishUpdate();

    std::unique_ptr<Impl> impl_;
    EstimatorOptions options_;
    std::unique_ptr<RayScene> rays_;
    std::unique_ptr<Radiosity> radiosity_;
    std::unique_ptr<Observations> observations_;
    std::vector<LightEstimate> estimates_;
    Solution without_;
    Solution with_;
    std::vector<Eigen::Vector3d> rho_;
    std::vector<std::string> warnings_;
    EstimatorStats stats_;
    double fit_residual_ = 0.0;
    double last_observe_ms_ = 0.0;
    double radiance_scale_ = 1.0;
};

}  // namespace commonlight::lighting

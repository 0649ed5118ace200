// The estimator end to end against the simulated camera (mocks/sim: path tracing, sensor noise),
// at test size (small images, few samples): the three light cases, reflectances, the ratio,
// and the response assumption. Full-precision figures come from `commonlight bench lighting`.
#include "lighting/estimator.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "bench/lighting_eval.h"
#include "core/scene_io.h"

namespace commonlight::lighting {
namespace {

Scene parse(const std::string& yaml) {
    auto scene = parseScene(yaml, "test.yaml");
    EXPECT_TRUE(scene) << scene.error().message;
    return *scene;
}

CameraModel camera(int w, int h) {
    CameraModel c;
    c.width = w;
    c.height = h;
    c.fx = c.fy = 0.82 * w;
    c.cx = (w - 1) / 2.0;
    c.cy = (h - 1) / 2.0;
    return c;
}

// A room corner: the back wall's albedo is known (the radiometric anchor), the floor's and the
// box's are not; a ceiling panel and a small lamp of unknown emission.
const char* kCorner = R"(
real:
  - {name: floor, plane: {size: [2.4, 2.4]}, world_from_object: {t: [0, 0.3, 0]}, albedo: [0.45, 0.4, 0.33]}
  - {name: wall, plane: {size: [2.4, 1.8]}, world_from_object: {t: [0, 1.5, 0.9], rpy_deg: [90, 0, 0]}, albedo: [0.7, 0.7, 0.7]}
  - {name: box, box: {size: [0.3, 0.3, 0.3]}, world_from_object: {t: [0.2, 0.6, 0.15], rpy_deg: [0, 0, 20]}, albedo: [0.6, 0.3, 0.2]}
lights:
  - {name: panel, area: {size: [0.6, 0.6]}, world_from_object: {t: [0, 0.5, 1.8], rpy_deg: [180, 0, 0]}, radiance: [12, 11, 10]}
  - {name: lamp, area: {size: [0.12, 0.12]}, world_from_object: {t: [-0.5, 0.4, 0.8], rpy_deg: [180, 20, 0]}, radiance: [60, 50, 40]}
virtual:
  - {name: ball, sphere: {radius: 0.08}, material: {albedo: [0.8, 0.8, 0.8]}, world_from_object: {t: [-0.2, 0.2, 0.08]}}
)";

Scene estimatedCorner(const Scene& truth) {
    Scene s = bench::asEstimated(truth, true, false);
    s.real_objects[0].albedo = RgbOrEstimate::estimate();
    s.real_objects[2].albedo = RgbOrEstimate::estimate();
    return s;
}

struct EstimateRun {
    std::unique_ptr<Estimator> estimator;
    LightingSnapshot snapshot;
};

EstimateRun estimate(const Scene& truth, const Scene& estimated, const CameraModel& cam, const std::vector<Rigid3d>& poses,
             const bench::RenderSettings& settings, const ResponseCurve& response, int updates = 1) {
    auto frames = bench::renderFrames(truth, cam, poses, settings);
    EXPECT_TRUE(frames) << frames.error().message;
    SceneLightingOptions options;
    options.response = response;
    options.radiance_scale = bench::radianceScale(settings.sensor);
    auto est = Estimator::create(estimated, cam, options);
    EXPECT_TRUE(est) << est.error().message;
    EstimateRun run{std::move(*est), {}};
    const auto virtual_poses = SceneLighting::scenePoses(estimated, 0.0);
    run.estimator->setVirtualPoses(virtual_poses);
    for (const bench::SimFrame& f : *frames) {
        auto ok = run.estimator->observe(f.rgb8.view(), f.cam_from_world, f.exposure_s, f.gain, 0);
        EXPECT_TRUE(ok) << ok.error().message;
    }
    for (int u = 0; u < updates; ++u) {
        auto snap = run.estimator->update(virtual_poses);
        EXPECT_TRUE(snap) << snap.error().message;
        if (snap) run.snapshot = std::move(*snap);
    }
    return run;
}

std::vector<Rigid3d> cornerPoses() { return bench::orbitPoses({0, 0.6, 0.3}, 1.6, 0.9, -25, 25, 3); }

bench::RenderSettings cornerSettings() {
    bench::RenderSettings s;
    s.spp = 16;
    s.max_depth = 6;
    s.sensor.exposure_us = 20000;
    return s;
}

// Case 1 (known geometry, unknown emission): each emission within 5% of the truth at this test
// size (200 x 150, 16 spp, three frames; the small lamp comes out 3% low here, at 640 x 480 within
// 1.5%: `commonlight bench lighting` measures the issue's 3% bound at full precision), the objects'
// reflectances within 5% (median over elements), the albedo-anchored scale.
TEST(Estimator, KnownGeometryLightsAndReflectancesFromSimulatedFrames) {
    const Scene truth = parse(kCorner);
    EstimateRun run = estimate(truth, estimatedCorner(truth), camera(200, 150), cornerPoses(), cornerSettings(), ResponseCurve::srgb());
    ASSERT_EQ(run.estimator->lights().size(), 2u);
    for (const LightEstimate& e : run.estimator->lights()) {
        const Eigen::Vector3d t = *truth.lights[static_cast<std::size_t>(e.light)].emission.value;
        const Eigen::Vector3d got = e.emission / run.estimator->radianceScale();
        for (int c = 0; c < 3; ++c) {
            RecordProperty(truth.lights[static_cast<std::size_t>(e.light)].name + "_" + std::to_string(c), std::to_string(got[c] / t[c] - 1.0));
            EXPECT_NEAR(got[c], t[c], 0.05 * t[c]) << truth.lights[static_cast<std::size_t>(e.light)].name << " channel " << c;
        }
    }
    // Reflectance per observed element against the truth of its object.
    const Radiosity& rad = run.estimator->radiosity();
    std::vector<double> errors;
    for (int e : rad.leaves(Mode::kReal)) {
        const Face& f = rad.face(rad.hierarchy()[e].face);
        if (f.albedo_known) continue;
        if (run.estimator->observations().aggregate(rad.hierarchy()[e]).pixels < 20) continue;
        const Eigen::Vector3d t = *truth.real_objects[static_cast<std::size_t>(f.object_index)].albedo.value;
        errors.push_back(((run.estimator->reflectance()[static_cast<std::size_t>(e)] - t).cwiseQuotient(t)).cwiseAbs().maxCoeff());
    }
    ASSERT_GT(errors.size(), 20u);
    std::nth_element(errors.begin(), errors.begin() + static_cast<std::ptrdiff_t>(errors.size() / 2), errors.end());
    EXPECT_LT(errors[errors.size() / 2], 0.05);
    EXPECT_TRUE(run.snapshot.radiance_scale_known);
    EXPECT_FALSE(run.snapshot.faces.empty());
}

// The virtual ball on the floor darkens the floor under it (B < B~) and changes nothing far away;
// every ratio is finite and within [0, kMaxRatio].
TEST(Estimator, VirtualObjectCastsAShadowInTheRatio) {
    const Scene truth = parse(kCorner);
    EstimateRun run = estimate(truth, estimatedCorner(truth), camera(160, 120), cornerPoses(), cornerSettings(), ResponseCurve::srgb());
    const FaceModulation* floor = run.snapshot.findFace(0, 0);
    ASSERT_NE(floor, nullptr);
    float darkest = 1.0f, far_from_ball = 0.0f;
    for (int j = 0; j < floor->height; ++j) {
        for (int i = 0; i < floor->width; ++i) {
            const Rgb r = floor->ratio[floor->texel(i, j)];
            ASSERT_TRUE(r.allFinite());
            EXPECT_GE(r.minCoeff(), 0.0f);
            EXPECT_LE(r.maxCoeff(), kMaxRatio);
            const double s = (i + 0.5) / floor->width, t = (j + 0.5) / floor->height;
            const Eigen::Vector3d p = floor->corners[0] + s * (floor->corners[1] - floor->corners[0]) + t * (floor->corners[3] - floor->corners[0]);
            const double d = (p - Eigen::Vector3d(-0.2, 0.2, 0.0)).norm();
            if (d < 0.25) darkest = std::min(darkest, r.y());
            if (d > 0.9) far_from_ball = std::max(far_from_ball, std::abs(r.y() - 1.0f));
        }
    }
    EXPECT_LT(darkest, 0.9f);          // a shadow
    EXPECT_LT(far_from_ball, 0.02f);   // nothing changes far away
}

// A camera that delivers linear values read as sRGB: the model cannot fit what it sees as well as
// with the right response; the fit's relative residual shows it.
TEST(Estimator, LinearResponseReadAsSrgbIsDetectableInTheResidual) {
    const Scene truth = parse(kCorner);
    bench::RenderSettings settings = cornerSettings();
    settings.sensor.response = mocks::sim::SensorResponse::kLinear;
    settings.sensor.exposure_us = 60000;
    const auto cam = camera(160, 120);
    EstimateRun right = estimate(truth, estimatedCorner(truth), cam, cornerPoses(), settings, ResponseCurve::linear());
    EstimateRun wrong = estimate(truth, estimatedCorner(truth), cam, cornerPoses(), settings, ResponseCurve::srgb());
    const double r_right = right.estimator->fitResidual();
    const double r_wrong = wrong.estimator->fitResidual();
    RecordProperty("relative_residual_right", std::to_string(r_right));
    RecordProperty("relative_residual_wrong", std::to_string(r_wrong));
    EXPECT_GT(r_wrong, 2.0 * r_right) << "right " << r_right << " wrong " << r_wrong;
}

// Case 3: no light in the scene. Every observed surface emits what interreflection does not
// explain: the real scene alone reproduces what was observed, and the virtual ball still shadows.
TEST(Estimator, NothingKnownEverySurfaceEmitsAndVirtualObjectsStillShadow) {
    const Scene truth = parse(kCorner);
    Scene estimated = bench::asEstimated(truth, true, true);
    estimated.lights.clear();
    EstimateRun run = estimate(truth, estimated, camera(160, 120), cornerPoses(), cornerSettings(), ResponseCurve::srgb());
    const Radiosity& rad = run.estimator->radiosity();
    double worst = 0.0;
    int checked = 0;
    for (int e : rad.leaves(Mode::kReal)) {
        const RadianceStats s = run.estimator->observations().aggregate(rad.hierarchy()[e]);
        if (s.pixels < 20) continue;
        const double observed = s.mean().y();
        worst = std::max(worst, std::abs(run.estimator->without().radiance[static_cast<std::size_t>(e)].y() - observed) / observed);
        ++checked;
    }
    ASSERT_GT(checked, 20);
    EXPECT_LT(worst, 0.02);
    const FaceModulation* floor = run.snapshot.findFace(0, 0);
    ASSERT_NE(floor, nullptr);
    // The ball blocks only what the other surfaces send (their emission and interreflection):
    // the floor's own emission (its direct light from the real lamps, baked in) is not blocked,
    // so the shadow is shallow (1.0% at its darkest here, visibility weighted by the kernel; the
    // ball's own light, by its exact form factor, fills part of it), but it is there: without the
    // ball the ratio is 1 everywhere (within 1e-4).
    float darkest = 1.0f;
    for (const Rgb& r : floor->ratio) darkest = std::min(darkest, r.y());
    EXPECT_LT(darkest, 0.995f);
    EXPECT_TRUE(std::any_of(run.snapshot.warnings.begin(), run.snapshot.warnings.end(),
                            [](const std::string& w) { return w.find("names no light") != std::string::npos; }));
}

// Case 2: an unknown distant light (a sun and a sky in the truth): the dominant direction within
// 3 degrees at this test size (32 directions, 240 x 180, two frames; the issue's 2 degrees with
// 128 directions at full size is measured by the benchmark), and NNLS keeps every cell >= 0.
TEST(Estimator, DistantLightDominantDirectionFound) {
    auto truth = readScene(std::filesystem::path(COMMONLIGHT_SOURCE_DIR) / "data/scenes/sunlit/scene.yaml");
    auto estimated = readScene(std::filesystem::path(COMMONLIGHT_SOURCE_DIR) / "data/scenes/sunlit/scene_estimated.yaml");
    ASSERT_TRUE(truth && estimated);
    std::get<DistantLightShape>(estimated->lights[0].shape).directions = 32;  // test size
    bench::RenderSettings settings;
    settings.spp = 16;
    settings.max_depth = 4;
    EstimateRun run = estimate(*truth, *estimated, camera(240, 180), bench::orbitPoses({0, 0, 0.05}, 1.0, 0.8, -30, 30, 2),
                       settings, ResponseCurve::srgb(), 2);
    ASSERT_EQ(run.estimator->lights().size(), 1u);
    const LightEstimate& sky = run.estimator->lights()[0];
    ASSERT_TRUE(sky.dominant_direction.has_value());
    const Eigen::Vector3d sun = -Eigen::Vector3d(-0.35, 0.45, -0.82).normalized();
    const double error_deg = std::acos(std::clamp(sky.dominant_direction->dot(sun), -1.0, 1.0)) * 180.0 / M_PI;
    RecordProperty("direction_error_deg", std::to_string(error_deg));
    EXPECT_LT(error_deg, 3.0);
    for (const Eigen::Vector3d& cell : sky.cells) EXPECT_GE(cell.minCoeff(), 0.0);
    EXPECT_GT(sky.condition_number, 1.0);
    // The renderer gets the direction as a directional light.
    const auto it = std::find_if(run.snapshot.lights.begin(), run.snapshot.lights.end(),
                                 [](const EstimatedLight& l) { return l.name == "sky#1"; });
    ASSERT_NE(it, run.snapshot.lights.end());
    EXPECT_EQ(it->kind, LightKind::kDirectional);
}

}  // namespace
}  // namespace commonlight::lighting

namespace commonlight::lighting {
namespace {

// Bad input for the light fit: a light that lights nothing the camera sees (behind a wall) and two
// lights that light everything the same way (an ill-conditioned pair) get regularised,
// non-negative, finite answers and warnings naming them; never NaN.
TEST(Estimator, UnobservableLightsGetRegularisedAnswersAndWarnings) {
    const Scene truth = parse(R"(
real:
  - {name: floor, plane: {size: [2.4, 2.4]}, world_from_object: {t: [0, 0.3, 0]}, albedo: [0.45, 0.4, 0.33]}
  - {name: wall, plane: {size: [2.4, 1.8]}, world_from_object: {t: [0, 1.5, 0.9], rpy_deg: [90, 0, 0]}, albedo: [0.7, 0.7, 0.7]}
lights:
  - {name: panel, area: {size: [0.6, 0.6]}, world_from_object: {t: [0, 0.5, 1.8], rpy_deg: [180, 0, 0]}, radiance: [12, 11, 10]}
  - {name: twin, area: {size: [0.6, 0.6]}, world_from_object: {t: [0.001, 0.5, 1.8], rpy_deg: [180, 0, 0]}, radiance: [12, 11, 10]}
  - {name: hidden, area: {size: [0.3, 0.3]}, world_from_object: {t: [0, 2.5, 0.9], rpy_deg: [-90, 0, 0]}, radiance: [50, 50, 50]}
)");
    Scene estimated = bench::asEstimated(truth, true, false);
    estimated.real_objects[0].albedo = RgbOrEstimate::estimate();
    EstimateRun run = estimate(truth, estimated, camera(160, 120), cornerPoses(), cornerSettings(), ResponseCurve::srgb());
    ASSERT_EQ(run.estimator->lights().size(), 3u);
    for (const LightEstimate& e : run.estimator->lights()) {
        EXPECT_TRUE(e.emission.allFinite());
        EXPECT_GE(e.emission.minCoeff(), 0.0);
    }
    const auto warned = [&](const std::string& name) {
        return std::any_of(run.snapshot.warnings.begin(), run.snapshot.warnings.end(),
                           [&](const std::string& w) { return w.find("'" + name + "'") != std::string::npos; });
    };
    EXPECT_TRUE(warned("hidden"));
    EXPECT_TRUE(warned("panel") || warned("twin"));
    // The pair together still carries the right total light (what is seen is explained).
    const Eigen::Vector3d pair = (run.estimator->lights()[0].emission + run.estimator->lights()[1].emission) / run.estimator->radianceScale();
    EXPECT_NEAR(pair.y(), 22.0, 0.1 * 22.0);
}

// A narrow gap against the path tracer (mocks/sim): a cabinet 5 cm from a wall under a ceiling
// panel. Coarse links pushed the open wall's visibility into the gap and the two gap faces
// gathered each other's mean radiance (measured here with the shelter, near-field, gap and
// consistency refinements off: 3.2x the truth, the room 4.2% RMS). The element radiance, solved
// with the true lights and albedos, against the path-traced element averages: the gap's wall
// within a factor of 2 (measured 1.6x: still too bright, see docs/lighting.md; it is nearly black
// and the truth's own noise there is ~10%), and the room as a whole within 4% RMS (measured 2.3%;
// the benchmark measures 1.5% on the full room).
TEST(Estimator, NarrowGapAgainstThePathTracer) {
    const Scene truth = parse(R"(
real:
  - {name: floor, plane: {size: [3.0, 2.4]}, albedo: [0.4, 0.4, 0.4]}
  - {name: ceiling, plane: {size: [3.0, 2.4]}, world_from_object: {t: [0, 0, 2.2], rpy_deg: [180, 0, 0]}, albedo: [0.8, 0.8, 0.8]}
  - {name: north, plane: {size: [3.0, 2.2]}, world_from_object: {t: [0, 1.2, 1.1], rpy_deg: [90, 0, 0]}, albedo: [0.7, 0.7, 0.7]}
  - {name: south, plane: {size: [3.0, 2.2]}, world_from_object: {t: [0, -1.2, 1.1], rpy_deg: [-90, 0, 0]}, albedo: [0.7, 0.7, 0.7]}
  - {name: west, plane: {size: [2.2, 2.4]}, world_from_object: {t: [-1.5, 0, 1.1], rpy_deg: [0, 90, 0]}, albedo: [0.7, 0.7, 0.7]}
  - {name: east, plane: {size: [2.2, 2.4]}, world_from_object: {t: [1.5, 0, 1.1], rpy_deg: [0, -90, 0]}, albedo: [0.7, 0.7, 0.7]}
  - {name: cabinet, box: {size: [0.4, 0.8, 1.2]}, world_from_object: {t: [1.25, 0.0, 0.6]}, albedo: [0.75, 0.75, 0.75]}
lights:
  - {name: panel, area: {size: [0.8, 0.8]}, world_from_object: {t: [0, 0, 2.19], rpy_deg: [180, 0, 0]}, radiance: [20, 20, 20]}
)");
    EstimatorOptions eo;
    eo.refine_unobserved = true;
    eo.refine_by_light = false;
    eo.initial_element_size = 0.6;
    eo.radiosity.link_epsilon = 0.01;
    eo.radiosity.min_link_size = 0.3;
    eo.radiosity.source_epsilon = 0.0005;
    auto est = Estimator::create(truth, camera(64, 48), {}, eo);
    ASSERT_TRUE(est) << est.error().message;
    std::vector<Eigen::Vector3d> emission{Eigen::Vector3d::Constant(20.0)}, albedo;
    for (const RealObject& o : truth.real_objects) albedo.push_back(*o.albedo.value);
    ASSERT_TRUE((*est)->solveWith(emission, albedo, {}));
    const Radiosity& rad = (*est)->radiosity();
    std::vector<int> gap, all;
    const std::vector<int> leaves = rad.leaves(Mode::kReal);
    for (std::size_t k = 0; k < leaves.size(); ++k) {
        const int e = leaves[k];
        const ElementGeometry g = rad.geometry(e);
        const Face& f = rad.face(rad.hierarchy()[e].face);
        // The east wall behind the cabinet (y within its 0.8 m, below its top).
        if (f.object_index == 5 && std::abs(g.centroid.y()) < 0.3 && g.centroid.z() < 1.0) gap.push_back(e);
        if (k % 6 == 0) all.push_back(e);
    }
    ASSERT_GE(gap.size(), 4u);
    auto truth_gap = bench::truthOfLeaves(truth, **est, gap, false, 16, 64, 3);
    auto truth_all = bench::truthOfLeaves(truth, **est, all, false, 16, 64, 4);
    ASSERT_TRUE(truth_gap && truth_all);
    double model = 0.0, reference = 0.0;
    for (std::size_t k = 0; k < gap.size(); ++k) {
        const double a = rad.hierarchy()[gap[k]].area;
        model += a * (*est)->without().radiance[static_cast<std::size_t>(gap[k])].y();
        reference += a * (*truth_gap)[k].y();
    }
    RecordProperty("gap_model_over_truth", std::to_string(model / reference));
    EXPECT_LT(model / reference, 2.0) << "gap: model " << model << " truth " << reference;
    EXPECT_GT(model / reference, 0.5) << "gap: model " << model << " truth " << reference;
    double se = 0.0, st = 0.0;
    for (std::size_t k = 0; k < all.size(); ++k) {
        const double a = rad.hierarchy()[all[k]].area * rad.exposure(all[k]);
        const double t = (*truth_all)[k].y(), d = (*est)->without().radiance[static_cast<std::size_t>(all[k])].y() - t;
        se += a * d * d;
        st += a * t * t;
    }
    RecordProperty("rms", std::to_string(std::sqrt(se / st)));
    EXPECT_LT(std::sqrt(se / st), 0.04) << all.size() << " leaves compared";
}

}  // namespace
}  // namespace commonlight::lighting

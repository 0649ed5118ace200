// Model-edge refinement against ground truth from the simulated camera: the desk scene
// (data/scenes/desk) rendered by the path tracer at known poses, refined from perturbed poses.
// Also the edge model on synthetic scenes, and the hard cases: no edges, distortion, a prior,
// occlusion, bad input.
#include "tracking/edge_refine.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <variant>
#include <map>
#include <numbers>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "core/scene_io.h"
#include "mocks/sim/render.h"
#include "mocks/sim/trajectory.h"
#include "tests/test_support.h"

namespace commonlight::tracking {
namespace {

using Eigen::Vector2d;
using Eigen::Vector3d;
namespace sim = mocks::sim;

constexpr double kDegToRad = std::numbers::pi / 180.0;

// ---------------------------------------------------------------------------------------------
// Rendering helpers

// Linear radiance to 8-bit grey: the mean of the channels, scaled so that the 99th percentile
// lands on 220 (a simple auto-exposure), clipped.
Image toGray8(const Image& radiance) {
    const int w = radiance.width();
    const int h = radiance.height();
    std::vector<float> grey(static_cast<std::size_t>(w) * h);
    for (int v = 0; v < h; ++v) {
        const auto* row = reinterpret_cast<const float*>(radiance.data() + v * radiance.stride());
        for (int u = 0; u < w; ++u) grey[v * w + u] = (row[3 * u] + row[3 * u + 1] + row[3 * u + 2]) / 3.0f;
    }
    std::vector<float> sorted = grey;
    const auto p99 = sorted.begin() + static_cast<std::ptrdiff_t>(0.99 * sorted.size());
    std::nth_element(sorted.begin(), p99, sorted.end());
    const double scale = *p99 > 0 ? 220.0 / *p99 : 1.0;
    Image out(PixelFormat::kGray8, w, h);
    for (int v = 0; v < h; ++v) {
        for (int u = 0; u < w; ++u) {
            out.data()[v * out.stride() + u] =
                static_cast<std::uint8_t>(std::clamp(std::lround(scale * grey[v * w + u]), 0L, 255L));
        }
    }
    return out;
}

Image renderGray(const Scene& scene, const CameraModel& camera, const Rigid3d& world_from_cam, int spp = 8) {
    auto built = sim::SimScene::build(scene);
    EXPECT_TRUE(built) << built.error().message;
    sim::RenderRequest request;
    request.scene = &*built;
    request.camera = camera;
    request.world_from_cam = world_from_cam;
    request.spp = spp;
    request.max_depth = 3;
    request.seed = 1;
    auto out = sim::render(request);
    EXPECT_TRUE(out) << out.error().message;
    std::printf("  rendered %dx%d at %d spp in %.2f s\n", camera.width, camera.height, spp, out->seconds);
    return toGray8(out->radiance);
}

const Scene& deskScene() {
    static const Scene scene = [] {
        auto s = readScene(testing::sourceDir() / "data/scenes/desk/scene.yaml");
        EXPECT_TRUE(s) << s.error().message;
        return *s;
    }();
    return scene;
}

const sim::Trajectory& deskTrajectory() {
    static const sim::Trajectory trajectory = [] {
        auto t = sim::Trajectory::read(testing::sourceDir() / "data/scenes/desk/trajectory.yaml");
        EXPECT_TRUE(t) << t.error().message;
        return *t;
    }();
    return trajectory;
}

// The rendered desk at trajectory time t with `camera`, rendered once per process.
const Image& deskImage(double t, const CameraModel& camera) {
    static std::map<std::pair<double, double>, Image> cache;
    const auto key = std::make_pair(t, camera.distortion.k1);
    auto it = cache.find(key);
    if (it == cache.end()) {
        it = cache.emplace(key, renderGray(deskScene(), camera, deskTrajectory().worldFromCam(t))).first;
    }
    return it->second;
}

const CameraModel& deskCamera() { return *deskScene().camera; }

// The true pose moved by `rot_deg` about a random axis and `trans_m` along another (seeded).
Rigid3d perturb(const Rigid3d& truth, double rot_deg, double trans_m, unsigned seed) {
    std::mt19937 rng(seed);
    std::normal_distribution<double> normal;
    const Vector3d axis_r = Vector3d(normal(rng), normal(rng), normal(rng)).normalized();
    const Vector3d axis_t = Vector3d(normal(rng), normal(rng), normal(rng)).normalized();
    // Rotate about the camera centre (so rotation and translation errors are independent).
    Vector6d xi;
    xi << rot_deg * kDegToRad * axis_r, Vector3d::Zero();
    const Rigid3d rotated = expSe3(xi) * truth;
    return Rigid3d(rotated.rotation, rotated.translation + trans_m * axis_t);
}

// Camera-centre distance, metres: the translation error a user sees.
double centreError(const Rigid3d& a, const Rigid3d& b) {
    return (a.inverse().translation - b.inverse().translation).norm();
}

// ---------------------------------------------------------------------------------------------
// The edge model

Scene oneObject(Shape shape, const Rigid3d& pose = Rigid3d::fromRpyDeg({0.1, 0.2, 0.3}, {10, 20, 30})) {
    Scene scene;
    scene.real_objects.push_back({"thing", std::move(shape), pose, RgbOrEstimate::constant(Vector3d::Constant(0.5))});
    return scene;
}

// A unit cube as a glTF exporter writes it: 24 vertices (4 per face, for flat normals), 12 triangles.
std::shared_ptr<Mesh> splitVertexCube() {
    auto mesh = std::make_shared<Mesh>();
    for (int axis = 0; axis < 3; ++axis) {
        for (const float sign : {-1.0f, 1.0f}) {
            const int u = (axis + 1) % 3;
            const int v = (axis + 2) % 3;
            const auto base = static_cast<std::uint32_t>(mesh->positions.size());
            for (const auto& [a, b] : {std::pair{-1.f, -1.f}, {1.f, -1.f}, {1.f, 1.f}, {-1.f, 1.f}}) {
                Eigen::Vector3f p;
                p[axis] = 0.5f * sign;
                p[u] = 0.5f * a;
                p[v] = 0.5f * b;
                mesh->positions.push_back(p);
            }
            // Counter-clockwise seen from outside.
            if (sign > 0) {
                mesh->indices.insert(mesh->indices.end(), {base, base + 1, base + 2, base, base + 2, base + 3});
            } else {
                mesh->indices.insert(mesh->indices.end(), {base, base + 2, base + 1, base, base + 3, base + 2});
            }
        }
    }
    return mesh;
}

TEST(EdgeModel, BoxHasTwelveEdgesWithTwoOutwardNormals) {
    const Rigid3d pose = Rigid3d::fromRpyDeg({0.1, 0.2, 0.3}, {10, 20, 30});
    auto model = EdgeModel::fromScene(oneObject(BoxShape{{0.4, 0.3, 0.2}}, pose));
    ASSERT_TRUE(model) << model.error().message;
    ASSERT_EQ(model->edges().size(), 12u);
    double total_length = 0;
    for (const ModelEdge& e : model->edges()) {
        EXPECT_TRUE(e.hasTwoFaces());
        EXPECT_NEAR(e.normal0.norm(), 1.0, 1e-12);
        EXPECT_NEAR(e.normal1.norm(), 1.0, 1e-12);
        EXPECT_NEAR(e.normal0.dot(e.normal1), 0.0, 1e-12);
        // Both normals are perpendicular to the edge and point away from the centre.
        const Vector3d mid = 0.5 * (e.a_in_world + e.b_in_world);
        EXPECT_NEAR(e.normal0.dot(e.b_in_world - e.a_in_world), 0.0, 1e-12);
        EXPECT_GT(e.normal0.dot(mid - pose.translation), 0.0);
        EXPECT_GT(e.normal1.dot(mid - pose.translation), 0.0);
        EXPECT_EQ(e.object, 0);
        total_length += (e.b_in_world - e.a_in_world).norm();
    }
    EXPECT_NEAR(total_length, 4 * (0.4 + 0.3 + 0.2), 1e-12);
}

TEST(EdgeModel, PlaneHasFourBoundaryEdgesWithOneFace) {
    auto model = EdgeModel::fromScene(oneObject(PlaneShape{{2.0, 1.0}}, Rigid3d::fromRpyDeg({0, 1, 1}, {90, 0, 0})));
    ASSERT_TRUE(model);
    ASSERT_EQ(model->edges().size(), 4u);
    for (const ModelEdge& e : model->edges()) {
        EXPECT_FALSE(e.hasTwoFaces());
        // rpy (90, 0, 0) turns the plane's +z to -y.
        EXPECT_LT((e.normal0 - Vector3d(0, -1, 0)).norm(), 1e-12);
    }
}

TEST(EdgeModel, MeshCubeGivesItsTwelveEdgesAndNoDiagonals) {
    MeshShape shape;
    shape.path = "cube.gltf";
    shape.mesh = splitVertexCube();
    auto model = EdgeModel::fromScene(oneObject(shape, Rigid3d::identity()));
    ASSERT_TRUE(model) << model.error().message;
    EXPECT_EQ(model->edges().size(), 12u);
    for (const ModelEdge& e : model->edges()) {
        EXPECT_TRUE(e.hasTwoFaces());
        EXPECT_NEAR((e.b_in_world - e.a_in_world).norm(), 1.0, 1e-6) << "a diagonal would be sqrt(2) long";
        EXPECT_NEAR(e.normal0.dot(e.normal1), 0.0, 1e-6);
    }
}

TEST(EdgeModel, MeshCreasesBelowTheAngleAreNotEdgesAndOpenBordersAre) {
    // Two triangles folded by 20 degrees along the y axis: an open mesh with 4 boundary edges and
    // a fold that is an edge only when the crease angle is below 20 degrees.
    auto mesh = std::make_shared<Mesh>();
    const double fold = 20 * kDegToRad;
    mesh->positions = {Eigen::Vector3f(0, 0, 0), Eigen::Vector3f(0, 1, 0), Eigen::Vector3f(1, 0, 0),
                       Eigen::Vector3f(static_cast<float>(-std::cos(fold)), 0, static_cast<float>(std::sin(fold)))};
    mesh->indices = {0, 2, 1, 0, 1, 3};
    MeshShape shape;
    shape.mesh = mesh;
    auto model = EdgeModel::fromScene(oneObject(shape, Rigid3d::identity()));
    ASSERT_TRUE(model);
    EXPECT_EQ(model->edges().size(), 4u);
    for (const ModelEdge& e : model->edges()) EXPECT_FALSE(e.hasTwoFaces());
    EdgeModelOptions sharp;
    sharp.crease_angle_deg = 10;
    model = EdgeModel::fromScene(oneObject(shape, Rigid3d::identity()), sharp);
    ASSERT_TRUE(model);
    EXPECT_EQ(model->edges().size(), 5u);
}

TEST(EdgeModel, SpheresOccludeButHaveNoEdgesAndUnloadedMeshesFail) {
    auto model = EdgeModel::fromScene(oneObject(SphereShape{0.5}, Rigid3d::identity()));
    ASSERT_TRUE(model);
    EXPECT_TRUE(model->edges().empty());
    EXPECT_TRUE(model->occluded({0, 0, -2}, {0, 0, 2}, 1e-3));
    EXPECT_FALSE(model->occluded({0, 0, -2}, {0, 0, -0.6}, 1e-3));
    EXPECT_NEAR(*model->firstHit({0, 0, -2}, {0, 0, 1}, 0, 10), 1.5, 1e-12);
    MeshShape unloaded;
    unloaded.path = "missing.gltf";
    auto bad = EdgeModel::fromScene(oneObject(unloaded));
    ASSERT_FALSE(bad);
    EXPECT_NE(bad.error().message.find("thing"), std::string::npos) << bad.error().message;
    EXPECT_FALSE(EdgeModel::fromScene(oneObject(BoxShape{{0.1, -0.1, 0.1}})));
}

TEST(EdgeModel, OcclusionOfBoxesPlanesAndMeshesIgnoresTheSurfaceItself) {
    Scene scene;
    const auto grey = RgbOrEstimate::constant(Vector3d::Constant(0.5));
    scene.real_objects.push_back({"box", BoxShape{{1, 1, 1}}, Rigid3d::identity(), grey});
    scene.real_objects.push_back({"plane", PlaneShape{{1, 1}}, Rigid3d({1, 0, 0, 0}, {0, 0, 3}), grey});
    MeshShape cube;
    cube.mesh = splitVertexCube();
    scene.real_objects.push_back({"cube", cube, Rigid3d({1, 0, 0, 0}, {0, 0, 6}), grey});
    auto model = EdgeModel::fromScene(scene);
    ASSERT_TRUE(model);
    EXPECT_EQ(model->edges().size(), 12u + 4u + 12u);
    const Vector3d eye(0, 0, -5);
    // Box: the near corner edge is visible, the far face's centre is not.
    EXPECT_FALSE(model->occluded(eye, {0.5, 0.5, -0.5}, 1e-3));
    EXPECT_TRUE(model->occluded(eye, {0, 0, 0.5}, 1e-3));
    // Behind the box: the plane, and behind that the mesh cube.
    EXPECT_TRUE(model->occluded(eye, {0, 0, 3}, 1e-3));
    EXPECT_FALSE(model->occluded({0, 0, 2}, {0.4, 0.4, 3}, 1e-3));
    EXPECT_TRUE(model->occluded({0, 0, 2}, {0, 0, 6.5}, 1e-3));
    EXPECT_FALSE(model->occluded({0, 0, 4}, {0.5, 0.5, 5.5}, 1e-3));
    // From inside the box, its walls are the first surface.
    EXPECT_NEAR(*model->firstHit(Vector3d::Zero(), Vector3d::UnitX(), 0, 10), 0.5, 1e-12);
}

// ---------------------------------------------------------------------------------------------
// Refinement on the rendered desk

struct DeskCase {
    double t_s;     // trajectory time
    unsigned seed;  // of the perturbation's axes
};

class EdgeRefineDesk : public ::testing::TestWithParam<DeskCase> {};

TEST_P(EdgeRefineDesk, ConvergesFromAPerturbedPose) {
    const DeskCase c = GetParam();
    const CameraModel& camera = deskCamera();
    const Image& image = deskImage(c.t_s, camera);
    const Rigid3d truth = deskTrajectory().worldFromCam(c.t_s).inverse();
    auto model = EdgeModel::fromScene(deskScene());
    ASSERT_TRUE(model) << model.error().message;
    const Rigid3d start = perturb(truth, 1.5, 0.025, c.seed);
    const EdgeRefineOptions options;
    auto result = refinePoseWithEdges(image, camera, *model, start, options);
    ASSERT_TRUE(result) << result.error().message;
    const double rot0 = rotationErrorDeg(start, truth);
    const double trans0 = centreError(start, truth) * 1000;
    const double rot = rotationErrorDeg(result->cam_from_world, truth);
    const double trans = centreError(result->cam_from_world, truth) * 1000;
    std::printf(
        "desk t=%.1f s: start %.3f deg %.1f mm -> refined %.4f deg %.2f mm; %s %s; %d edges, %d/%d points, "
        "rms %.3f px, %d steps, %.1f ms\n",
        c.t_s, rot0, trans0, rot, trans, result->ok ? "ok" : "NOT OK", result->reason.c_str(), result->edges_used,
        result->points_used, result->points_visible, result->rms_px, result->iterations, 1000 * result->seconds);
    ASSERT_TRUE(result->ok) << result->reason;
    // Measured 0.02-0.03 degrees and 0.4-0.5 mm at 1.2 m (a fifth of a pixel): the limits leave a
    // factor of 3 to 4 (the images are deterministic; the margin is for platform differences).
    EXPECT_LT(rot, 0.1);
    EXPECT_LT(trans, 2.0);
    EXPECT_LT(rot, rot0);
    EXPECT_LT(trans, trans0);
    std::printf("  steps: pyramid %.1f ms, sampling %.1f ms, search %.1f ms, solve %.1f ms\n",
                1000 * result->step_seconds.pyramid, 1000 * result->step_seconds.sampling,
                1000 * result->step_seconds.search, 1000 * result->step_seconds.solve);
    // The reported covariance is about right: the error is within a few of its sigmas.
    const Vector6d e = logSe3(truth * result->cam_from_world.inverse());
    const double m2 = e.dot(result->covariance.ldlt().solve(e));
    std::printf("  covariance: sigma %.4f deg, %.2f mm (camera frame); Mahalanobis^2 of the error %.1f\n",
                std::sqrt(result->covariance.topLeftCorner<3, 3>().trace()) / kDegToRad,
                1000 * std::sqrt(result->covariance.bottomRightCorner<3, 3>().trace()), m2);
    EXPECT_GT(result->covariance.determinant(), 0.0);
    // Chi-square with 6 degrees of freedom: below 22.46 with 99.9 % probability (measured 3 to 7).
    EXPECT_LT(m2, 22.46);
}

INSTANTIATE_TEST_SUITE_P(Desk, EdgeRefineDesk, ::testing::Values(DeskCase{0.0, 1}, DeskCase{1.0, 2}, DeskCase{2.0, 3}),
                         [](const auto& param_info) {
                             // (snprintf: GCC 12 warns falsely about "t" + std::to_string.)
                             char name[16];
                             std::snprintf(name, sizeof name, "t%02d", static_cast<int>(param_info.param.t_s * 10));
                             return std::string(name);
                         });
TEST(EdgeRefineDesk, ConvergesFromManyStartsAndFailsLoudlyFromFarOnes) {
    // From 2 degrees / 30 mm every start converges; from 6 degrees / 100 mm (beyond the search
    // range of the coarsest level) some do not, and those must say so (ok = false) rather than
    // return a wrong pose.
    const CameraModel& camera = deskCamera();
    auto model = EdgeModel::fromScene(deskScene());
    ASSERT_TRUE(model);
    int near_ok = 0, far_ok = 0, far_reported = 0;
    double worst_rot = 0, worst_trans = 0;
    for (const double t : {0.0, 2.0}) {
        const Image& image = deskImage(t, camera);
        const Rigid3d truth = deskTrajectory().worldFromCam(t).inverse();
        for (unsigned seed = 100; seed < 110; ++seed) {
            auto near =
                refinePoseWithEdges(image, camera, *model, perturb(truth, 2.0, 0.03, seed), EdgeRefineOptions{});
            ASSERT_TRUE(near);
            if (near->ok) {
                ++near_ok;
                worst_rot = std::max(worst_rot, rotationErrorDeg(near->cam_from_world, truth));
                worst_trans = std::max(worst_trans, 1000 * centreError(near->cam_from_world, truth));
            }
            auto far = refinePoseWithEdges(image, camera, *model, perturb(truth, 6.0, 0.1, seed), EdgeRefineOptions{});
            ASSERT_TRUE(far);
            if (!far->ok) {
                ++far_reported;
                continue;
            }
            ++far_ok;
            EXPECT_LT(rotationErrorDeg(far->cam_from_world, truth), 0.1) << "t " << t << " seed " << seed;
            EXPECT_LT(centreError(far->cam_from_world, truth), 0.002) << "t " << t << " seed " << seed;
        }
    }
    std::printf(
        "2 deg / 30 mm starts: %d of 20 ok, worst %.4f deg %.2f mm; 6 deg / 100 mm starts: %d ok, %d reported "
        "as failed\n",
        near_ok, worst_rot, worst_trans, far_ok, far_reported);
    EXPECT_EQ(near_ok, 20);
    EXPECT_LT(worst_rot, 0.1);
    EXPECT_LT(worst_trans, 2.0);
}

// An ideal image of the proxies, without path tracing: every pixel is the mean of 4 x 4 sub-pixel
// rays, each shaded flat by the normal of the face it hits. Nothing but geometry makes edges here,
// so what remains of the error is the method's own (sampling, search, sub-pixel peak, solver).
Vector3d faceNormal(const Scene& scene, const Vector3d& p) {
    Vector3d normal = Vector3d::UnitZ();
    double best = std::numeric_limits<double>::infinity();
    for (const RealObject& object : scene.real_objects) {
        const Vector3d q = object.world_from_object.inverse() * p;
        if (const auto* box = std::get_if<BoxShape>(&object.shape)) {
            const Vector3d h = 0.5 * box->size;
            if ((q.cwiseAbs() - h).maxCoeff() > 1e-6) continue;
            for (int k = 0; k < 3; ++k) {
                for (const double sign : {-1.0, 1.0}) {
                    const double distance = std::abs(q[k] - sign * h[k]);
                    if (distance < best) {
                        best = distance;
                        normal = object.world_from_object.rotation * (sign * Vector3d::Unit(k));
                    }
                }
            }
        } else if (const auto* plane = std::get_if<PlaneShape>(&object.shape)) {
            if (std::abs(q.x()) > 0.5 * plane->size.x() || std::abs(q.y()) > 0.5 * plane->size.y()) continue;
            if (std::abs(q.z()) < best) {
                best = std::abs(q.z());
                normal = object.world_from_object.rotation * Vector3d::UnitZ();
            }
        }
    }
    return normal;
}

Image flatShaded(const Scene& scene, const EdgeModel& model, const CameraModel& camera, const Rigid3d& world_from_cam) {
    const Vector3d light = Vector3d(0.3, -0.5, 1).normalized();
    Image image(PixelFormat::kGray8, camera.width, camera.height);
    for (int v = 0; v < camera.height; ++v) {
        for (int u = 0; u < camera.width; ++u) {
            double sum = 0;
            for (int sy = 0; sy < 4; ++sy) {
                for (int sx = 0; sx < 4; ++sx) {
                    const auto ray = camera.unproject({u - 0.5 + (sx + 0.5) / 4, v - 0.5 + (sy + 0.5) / 4});
                    if (!ray) continue;
                    const Vector3d d = world_from_cam.rotation * ray->normalized();
                    const auto t = model.firstHit(world_from_cam.translation, d, 0, 100);
                    if (!t) continue;
                    sum += 40 + 180 * std::abs(faceNormal(scene, world_from_cam.translation + *t * d).dot(light));
                }
            }
            image.data()[v * image.stride() + u] = static_cast<std::uint8_t>(std::lround(sum / 16));
        }
    }
    return image;
}

TEST(EdgeRefineDesk, IdealImageIsFitWithoutBias) {
    const CameraModel& camera = deskCamera();
    auto model = EdgeModel::fromScene(deskScene());
    ASSERT_TRUE(model);
    const Rigid3d world_from_cam = deskTrajectory().worldFromCam(1.0);
    const Rigid3d truth = world_from_cam.inverse();
    const Image image = flatShaded(deskScene(), *model, camera, world_from_cam);
    auto result = refinePoseWithEdges(image, camera, *model, perturb(truth, 1.5, 0.025, 4), EdgeRefineOptions{});
    ASSERT_TRUE(result);
    ASSERT_TRUE(result->ok) << result->reason;
    const double rot = rotationErrorDeg(result->cam_from_world, truth);
    const double trans = 1000 * centreError(result->cam_from_world, truth);
    std::printf("ideal image: %.4f deg, %.3f mm, rms %.3f px, %d points\n", rot, trans, result->rms_px,
                result->points_used);
    // Measured: 0.007 degrees, 0.19 mm (a tenth of a pixel or less), against 0.02-0.03 degrees
    // and 0.4-0.6 mm on the path-traced images (noise, soft shadows and shading at the edges).
    EXPECT_LT(rot, 0.015);
    EXPECT_LT(trans, 0.4);
}

TEST(EdgeRefineDesk, PriorIsFusedBetweenEdgesAndPrior) {
    const CameraModel& camera = deskCamera();
    const Image& image = deskImage(1.0, camera);
    const Rigid3d truth = deskTrajectory().worldFromCam(1.0).inverse();
    auto model = EdgeModel::fromScene(deskScene());
    ASSERT_TRUE(model);
    const Rigid3d start = perturb(truth, 1.0, 0.015, 5);
    auto edges = refinePoseWithEdges(image, camera, *model, start, EdgeRefineOptions{});
    ASSERT_TRUE(edges && edges->ok);
    const Matrix6d c = edges->covariance;
    // Exactly symmetric (the pose filter refuses a covariance that is not: symmetrising it in place
    // without a temporary let the transpose read entries already overwritten, 6e-11 off).
    EXPECT_EQ((c - c.transpose()).cwiseAbs().maxCoeff(), 0.0);
    // The prior: 3 sigma away from the edges' answer (in the edges' own metric), along a mixed direction.
    const Matrix6d l = c.llt().matrixL();
    const Vector6d u = (Vector6d() << 0.3, -0.5, 0.2, 0.6, 0.4, -0.3).finished().normalized();
    const Vector6d offset = 3.0 * l * u;
    const Rigid3d prior_pose = expSe3(offset) * edges->cam_from_world;
    const Matrix6d c_inv = c.inverse();
    // Where the fused pose lies on the way from the edges' pose to the prior (0: edges, 1: prior).
    const auto fraction = [&](const Rigid3d& fused, double* off_line) {
        const Vector6d x = logSe3(fused * edges->cam_from_world.inverse());
        const double f = x.dot(c_inv * offset) / offset.dot(c_inv * offset);
        const Vector6d rest = x - f * offset;
        *off_line = std::sqrt(rest.dot(c_inv * rest));
        return f;
    };
    for (const double scale : {1.0, 0.01, 100.0}) {
        PoseMeasurement prior{0, prior_pose, c * scale};
        auto fused = refinePoseWithEdges(image, camera, *model, start, EdgeRefineOptions{}, prior);
        ASSERT_TRUE(fused);
        ASSERT_TRUE(fused->ok) << fused->reason;
        double off_line = 0;
        const double f = fraction(fused->cam_from_world, &off_line);
        const double trace_ratio = fused->covariance.trace() / c.trace();
        std::printf(
            "prior with %g x the edges' covariance: fused at %.2f of the way to the prior (%.2f sigma off the "
            "line), covariance trace %.2f x the edges'\n",
            scale, f, off_line, trace_ratio);
        if (scale == 1.0) {
            // Equal information: half-way, with half the covariance.
            EXPECT_GT(f, 0.3);
            EXPECT_LT(f, 0.7);
            EXPECT_GT(trace_ratio, 0.35);
            EXPECT_LT(trace_ratio, 0.65);
        } else if (scale < 1.0) {
            EXPECT_GT(f, 0.9);
            EXPECT_LT(trace_ratio, 0.05);
        } else {
            EXPECT_LT(f, 0.1);
            EXPECT_GT(trace_ratio, 0.9);
        }
        EXPECT_LT(off_line, 1.0);
    }
}

TEST(EdgeRefineDesk, ATightPriorStartsAtFullResolutionAndALooseOneAtTheCoarsestLevel) {
    // EdgeRefineOptions::prior_sigmas: a prior that puts the pose within a few pixels (a tag
    // bundle's) skips the coarse levels; one that allows more, or an initial pose far from the
    // prior's, keeps them. The result is as good either way.
    const CameraModel& camera = deskCamera();
    const Image& image = deskImage(1.0, camera);
    const Rigid3d truth = deskTrajectory().worldFromCam(1.0).inverse();
    auto model = EdgeModel::fromScene(deskScene());
    ASSERT_TRUE(model);
    const Rigid3d start = perturb(truth, 0.1, 0.002, 8);
    const auto covariance = [](double rot_deg, double trans_m) {
        Vector6d sigma;
        const double r = rot_deg * M_PI / 180.0;
        sigma << r, r, r, trans_m, trans_m, trans_m;
        return Matrix6d(sigma.cwiseAbs2().asDiagonal());
    };
    struct Case {
        const char* what;
        Rigid3d initial;
        Matrix6d cov;
        int min_level, max_level;
    };
    const Case cases[] = {
        {"tight prior (0.02 deg, 0.3 mm)", start, covariance(0.02, 0.0003), 0, 0},
        {"loose prior (2 deg, 30 mm)", start, covariance(2.0, 0.03), 2, 2},
        {"tight prior, initial pose 1.5 deg from it", perturb(truth, 1.5, 0.025, 9), covariance(0.02, 0.0003), 1, 2},
    };
    for (const Case& c : cases) {
        const PoseMeasurement prior{0, start, c.cov};
        auto r = refinePoseWithEdges(image, camera, *model, c.initial, EdgeRefineOptions{}, prior);
        ASSERT_TRUE(r);
        std::printf("%s: first level %d, %d iterations, ok %d\n", c.what, r->first_level, r->iterations, r->ok ? 1 : 0);
        EXPECT_GE(r->first_level, c.min_level) << c.what;
        EXPECT_LE(r->first_level, c.max_level) << c.what;
    }
    // With the tight prior, from the start it describes: as accurate as from the coarsest level.
    const PoseMeasurement prior{0, start, covariance(0.1, 0.002)};
    EdgeRefineOptions all_levels;
    all_levels.prior_sigmas = 0.0;
    auto fine = refinePoseWithEdges(image, camera, *model, start, EdgeRefineOptions{}, prior);
    auto coarse = refinePoseWithEdges(image, camera, *model, start, all_levels, prior);
    ASSERT_TRUE(fine && coarse);
    ASSERT_TRUE(fine->ok && coarse->ok) << fine->reason << " / " << coarse->reason;
    EXPECT_EQ(coarse->first_level, 2);
    EXPECT_LT(fine->first_level, 2);
    const double fine_deg = rotationErrorDeg(fine->cam_from_world, truth);
    const double coarse_deg = rotationErrorDeg(coarse->cam_from_world, truth);
    std::printf("prior 0.1 deg, 2 mm: from level %d %.4f deg %.3f mm (%d iterations), from level 2 %.4f deg %.3f mm "
                "(%d iterations)\n",
                fine->first_level, fine_deg, 1000 * centreError(fine->cam_from_world, truth), fine->iterations,
                coarse_deg, 1000 * centreError(coarse->cam_from_world, truth), coarse->iterations);
    EXPECT_LT(fine_deg, 0.05);
    EXPECT_LT(std::abs(fine_deg - coarse_deg), 0.01);
    EXPECT_LT(fine->iterations, coarse->iterations);
    EdgeRefineOptions bad;
    bad.prior_sigmas = -1.0;
    EXPECT_FALSE(refinePoseWithEdges(image, camera, *model, start, bad, prior));
    bad = EdgeRefineOptions{};
    bad.coarse_converged_px = NAN;
    EXPECT_FALSE(refinePoseWithEdges(image, camera, *model, start, bad, prior));
}

TEST(EdgeRefineFailures, BlankWallAndFeaturelessImageAreNotOkWithAReason) {
    const CameraModel& camera = deskCamera();
    auto model = EdgeModel::fromScene(deskScene());
    ASSERT_TRUE(model);
    // Half a metre in front of the back wall, looking at it: no model edge in view.
    auto wall_pose = worldFromCamLookingAt({0.2, 0.7, 1.4}, {0.2, 1.2, 1.4});
    ASSERT_TRUE(wall_pose);
    const Image wall = renderGray(deskScene(), camera, *wall_pose, 2);
    auto r = refinePoseWithEdges(wall, camera, *model, wall_pose->inverse(), EdgeRefineOptions{});
    ASSERT_TRUE(r) << r.error().message;
    EXPECT_FALSE(r->ok);
    std::printf("blank wall: %s\n", r->reason.c_str());
    EXPECT_NE(r->reason.find("edges visible, need"), std::string::npos) << r->reason;
    EXPECT_EQ(r->covariance, Matrix6d::Zero());

    // The desk's edges are in view, but the image is a uniform grey: nothing to match.
    Image grey(PixelFormat::kGray8, camera.width, camera.height);
    std::fill(grey.data(), grey.data() + grey.sizeBytes(), std::uint8_t{128});
    const Rigid3d desk = deskTrajectory().worldFromCam(0.0).inverse();
    r = refinePoseWithEdges(grey, camera, *model, desk, EdgeRefineOptions{});
    ASSERT_TRUE(r);
    EXPECT_FALSE(r->ok);
    std::printf("uniform image: %s\n", r->reason.c_str());
    EXPECT_NE(r->reason.find("gradient"), std::string::npos) << r->reason;
    EXPECT_GT(r->points_visible, 100);
    // Not ok leaves the pose where it was.
    EXPECT_EQ(r->cam_from_world.translation, desk.translation);
}

TEST(EdgeRefineDesk, StronglyDistortedCameraConverges) {
    CameraModel camera = deskCamera();
    camera.distortion.k1 = -0.3;
    camera.distortion.k2 = 0.05;
    const Image& image = deskImage(1.0, camera);
    const Rigid3d truth = deskTrajectory().worldFromCam(1.0).inverse();
    auto model = EdgeModel::fromScene(deskScene());
    ASSERT_TRUE(model);
    const Rigid3d start = perturb(truth, 1.5, 0.025, 6);
    auto result = refinePoseWithEdges(image, camera, *model, start, EdgeRefineOptions{});
    ASSERT_TRUE(result);
    ASSERT_TRUE(result->ok) << result->reason;
    const double rot = rotationErrorDeg(result->cam_from_world, truth);
    const double trans = 1000 * centreError(result->cam_from_world, truth);
    std::printf("k1 = -0.3: start %.3f deg %.1f mm -> %.4f deg %.2f mm, %d points, rms %.3f px, %.1f ms\n",
                rotationErrorDeg(start, truth), 1000 * centreError(start, truth), rot, trans, result->points_used,
                result->rms_px, 1000 * result->seconds);
    EXPECT_LT(rot, 0.1);
    EXPECT_LT(trans, 2.0);
    // Ignoring the distortion does not fit: the lens model is what makes it work.
    CameraModel pinhole = camera;
    pinhole.distortion = {};
    auto wrong = refinePoseWithEdges(image, pinhole, *model, start, EdgeRefineOptions{});
    ASSERT_TRUE(wrong);
    std::printf("  same image, distortion ignored: %s, %.3f deg %.1f mm, rms %.2f px\n",
                wrong->ok ? "ok" : wrong->reason.c_str(), rotationErrorDeg(wrong->cam_from_world, truth),
                1000 * centreError(wrong->cam_from_world, truth), wrong->rms_px);
    EXPECT_TRUE(!wrong->ok || wrong->rms_px > 2 * result->rms_px);
}

TEST(EdgeRefineFailures, BadInputIsAnError) {
    const CameraModel& camera = deskCamera();
    auto model = EdgeModel::fromScene(deskScene());
    ASSERT_TRUE(model);
    const Rigid3d pose = deskTrajectory().worldFromCam(0.0).inverse();
    Image grey(PixelFormat::kGray8, camera.width, camera.height);
    std::fill(grey.data(), grey.data() + grey.sizeBytes(), std::uint8_t{128});

    Rigid3d nan_pose = pose;
    nan_pose.translation.y() = std::numeric_limits<double>::quiet_NaN();
    auto r = refinePoseWithEdges(grey, camera, *model, nan_pose, EdgeRefineOptions{});
    ASSERT_FALSE(r);
    EXPECT_EQ(r.error().code, ErrorCode::kBadInput);

    Image rgb(PixelFormat::kRgb8, camera.width, camera.height);
    r = refinePoseWithEdges(rgb, camera, *model, pose, EdgeRefineOptions{});
    ASSERT_FALSE(r);
    EXPECT_NE(r.error().message.find("gray8"), std::string::npos) << r.error().message;

    Image small(PixelFormat::kGray8, 320, 240);
    r = refinePoseWithEdges(small, camera, *model, pose, EdgeRefineOptions{});
    ASSERT_FALSE(r);
    EXPECT_EQ(r.error().code, ErrorCode::kBadInput);

    EdgeRefineOptions bad;
    bad.sample_spacing_px = 0;
    r = refinePoseWithEdges(grey, camera, *model, pose, bad);
    ASSERT_FALSE(r);
    EXPECT_NE(r.error().message.find("sample_spacing_px"), std::string::npos) << r.error().message;

    PoseMeasurement prior{0, pose, Matrix6d::Identity()};
    prior.covariance(2, 2) = -1;
    r = refinePoseWithEdges(grey, camera, *model, pose, EdgeRefineOptions{}, prior);
    ASSERT_FALSE(r);
    EXPECT_NE(r.error().message.find("prior"), std::string::npos) << r.error().message;
    prior.covariance = Matrix6d::Identity();
    prior.cam_from_world.rotation.coeffs()[1] = std::numeric_limits<double>::infinity();
    EXPECT_FALSE(refinePoseWithEdges(grey, camera, *model, pose, EdgeRefineOptions{}, prior));
}

TEST(EdgeRefineOcclusion, HiddenBoxContributesNoPoints) {
    // A small box right behind a tall one, seen from below the tall one's top: hidden. A wall
    // behind them closes the view.
    Scene scene;
    const auto grey = [](double a) { return RgbOrEstimate::constant(Vector3d::Constant(a)); };
    scene.real_objects.push_back({"floor", PlaneShape{{4, 4}}, Rigid3d::identity(), grey(0.3)});
    scene.real_objects.push_back(
        {"wall", PlaneShape{{4, 3}}, Rigid3d::fromRpyDeg({0, 1.0, 1.5}, {90, 0, 0}), grey(0.7)});
    scene.real_objects.push_back({"front", BoxShape{{0.3, 0.3, 0.6}}, Rigid3d({1, 0, 0, 0}, {0, 0, 0.3}), grey(0.55)});
    scene.real_objects.push_back(
        {"hidden", BoxShape{{0.12, 0.12, 0.12}}, Rigid3d::fromRpyDeg({0, 0.35, 0.06}, {0, 0, 20}), grey(0.85)});
    scene.lights.push_back({"sun", DirectionalLightShape{Vector3d(0.4, 0.3, -1).normalized()}, Rigid3d::identity(),
                            RgbOrEstimate::constant(Vector3d::Constant(2.0))});
    scene.lights.push_back(
        {"sky", DistantLightShape{16}, Rigid3d::identity(), RgbOrEstimate::constant(Vector3d::Constant(0.3))});
    constexpr int kFront = 2;
    constexpr int kHidden = 3;
    const CameraModel& camera = deskCamera();
    auto world_from_cam = worldFromCamLookingAt({0.05, -0.9, 0.4}, {0, 0.6, 0.15});
    ASSERT_TRUE(world_from_cam);
    const Rigid3d truth = world_from_cam->inverse();
    const Image image = renderGray(scene, camera, *world_from_cam, 8);
    auto model = EdgeModel::fromScene(scene);
    ASSERT_TRUE(model);
    auto result = refinePoseWithEdges(image, camera, *model, perturb(truth, 1.0, 0.01, 7), EdgeRefineOptions{});
    ASSERT_TRUE(result);
    ASSERT_TRUE(result->ok) << result->reason;
    std::printf("occlusion: points per object: floor %d, wall %d, front %d, hidden %d; %.4f deg %.2f mm\n",
                result->points_per_object[0], result->points_per_object[1], result->points_per_object[kFront],
                result->points_per_object[kHidden], rotationErrorDeg(result->cam_from_world, truth),
                1000 * centreError(result->cam_from_world, truth));
    EXPECT_EQ(result->points_per_object[kHidden], 0);
    EXPECT_GT(result->points_per_object[kFront], 40);
    int total = 0;
    for (const int n : result->points_per_object) total += n;
    EXPECT_EQ(total, result->points_used);
    EXPECT_LT(rotationErrorDeg(result->cam_from_world, truth), 0.15);
    EXPECT_LT(centreError(result->cam_from_world, truth), 0.003);

    // Without the front box in the model, the hidden box's edges would be taken as visible: the
    // occlusion test is what keeps them out.
    Scene without_front = scene;
    without_front.real_objects.erase(without_front.real_objects.begin() + kFront);
    auto only_hidden = EdgeModel::fromScene(without_front);
    ASSERT_TRUE(only_hidden);
    auto unguarded = refinePoseWithEdges(image, camera, *only_hidden, truth, EdgeRefineOptions{});
    ASSERT_TRUE(unguarded);
    int hidden_edges_in_view = 0;
    for (const ModelEdge& e : only_hidden->edges()) {
        if (e.object != kHidden - 1) continue;
        const auto pa = camera.project(truth * e.a_in_world);
        if (pa && camera.inImage(*pa)) ++hidden_edges_in_view;
    }
    EXPECT_GE(hidden_edges_in_view, 4);
    EXPECT_GT(unguarded->points_visible, 0);
}

}  // namespace
}  // namespace commonlight::tracking

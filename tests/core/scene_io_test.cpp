#include "core/scene_io.h"

#include <algorithm>
#include <cmath>
#include <string>

#include <gtest/gtest.h>

#include "tests/test_support.h"

namespace commonlight {
namespace {

using testing::readText;
using testing::sourceDir;
using testing::TempDir;
using testing::writeText;

std::filesystem::path dataDir() { return sourceDir() / "tests/core/data"; }

void expectPoseNear(const Rigid3d& actual, const Rigid3d& expected, double tolerance = 1e-12) {
    EXPECT_LE(rotationErrorDeg(actual, expected), tolerance * 180.0) << actual.rotation.coeffs().transpose();
    EXPECT_LE(translationError(actual, expected), tolerance) << actual.translation.transpose();
}

TEST(SceneIo, ReadsExampleScene) {
    const auto scene = readScene(dataDir() / "scene_example.yaml");
    ASSERT_TRUE(scene) << scene.error().message;
    // Camera, resolved against the scene's folder and loaded.
    ASSERT_TRUE(scene->camera_path);
    EXPECT_EQ(scene->camera_path->filename(), "calib_opencv_sample.yaml");
    EXPECT_TRUE(scene->camera_path->is_absolute());
    ASSERT_TRUE(scene->camera);
    EXPECT_EQ(scene->camera->width, 640);

    // Tags.
    EXPECT_EQ(scene->tags.family, "tag36h11");
    ASSERT_EQ(scene->tags.items.size(), 2u);
    const TagItem* tag3 = scene->tags.find(3);
    ASSERT_NE(tag3, nullptr);
    EXPECT_EQ(tag3->size, 0.08);
    EXPECT_EQ(tag3->albedo_black, 0.05);
    EXPECT_EQ(tag3->albedo_white, 0.85);
    expectPoseNear(tag3->world_from_tag, Rigid3d::fromRpyDeg({0.3, 0.1, 0.75}, {0, 0, 90}));
    EXPECT_EQ(scene->tags.items[0].albedo_black, 0.04);  // defaults
    EXPECT_EQ(scene->tags.items[0].albedo_white, 0.8);

    // Real objects.
    ASSERT_EQ(scene->real_objects.size(), 3u);
    EXPECT_EQ(std::get<PlaneShape>(scene->real_objects[0].shape).size, Eigen::Vector2d(4, 4));
    EXPECT_TRUE(scene->real_objects[0].albedo.isEstimate());  // default
    EXPECT_EQ(std::get<BoxShape>(scene->real_objects[1].shape).size, Eigen::Vector3d(1.2, 0.8, 0.75));
    const RealObject& shelf = scene->real_objects[2];
    const auto& shelf_mesh = std::get<MeshShape>(shelf.shape);
    EXPECT_EQ(shelf_mesh.path, (dataDir() / "cube.obj").lexically_normal());
    ASSERT_NE(shelf_mesh.mesh, nullptr);
    EXPECT_EQ(shelf_mesh.mesh->triangleCount(), 12u);
    expectPoseNear(shelf.world_from_object, Rigid3d::fromRpyDeg({1.5, 0, 0.5}, {0, 0, 90}));
    EXPECT_EQ(*shelf.albedo.value, Eigen::Vector3d(0.6, 0.5, 0.4));

    // Lights.
    ASSERT_EQ(scene->lights.size(), 5u);
    EXPECT_EQ(std::get<AreaLightShape>(scene->lights[0].shape).size, Eigen::Vector2d(0.6, 0.6));
    EXPECT_TRUE(scene->lights[0].emission.isEstimate());
    EXPECT_NEAR((scene->lights[0].world_from_object.rotation * Eigen::Vector3d::UnitZ()).z(), -1.0, 1e-12);
    EXPECT_EQ(std::get<DiscLightShape>(scene->lights[1].shape).radius, 0.2);
    EXPECT_EQ(*scene->lights[1].emission.value, Eigen::Vector3d::Constant(30));
    EXPECT_TRUE(std::holds_alternative<PointLightShape>(scene->lights[2].shape));
    EXPECT_EQ(*scene->lights[2].emission.value, Eigen::Vector3d(20, 18, 15));
    EXPECT_EQ(scene->lights[2].world_from_object.translation, Eigen::Vector3d(1, 1, 2));
    const auto& sun = std::get<DirectionalLightShape>(scene->lights[3].shape);
    EXPECT_LT((sun.direction - Eigen::Vector3d(0, 1, -1).normalized()).norm(), 1e-15);
    EXPECT_EQ(*scene->lights[3].emission.value, Eigen::Vector3d::Constant(500));
    EXPECT_EQ(std::get<DistantLightShape>(scene->lights[4].shape).directions, 128);

    // Virtual objects.
    ASSERT_EQ(scene->virtual_objects.size(), 4u);
    const VirtualObject& ball = scene->virtual_objects[0];
    EXPECT_EQ(std::get<SphereShape>(ball.shape).radius, 0.08);
    EXPECT_EQ(ball.material.type, MaterialType::kLambertian);
    EXPECT_EQ(ball.material.albedo, Eigen::Vector3d(0.8, 0.2, 0.2));
    EXPECT_FALSE(ball.emission);
    const VirtualObject& card = scene->virtual_objects[1];
    EXPECT_EQ(card.material.type, MaterialType::kGgx);
    EXPECT_EQ(card.material.roughness, 0.3);
    EXPECT_EQ(card.material.albedo, Eigen::Vector3d::Constant(0.9));
    ASSERT_TRUE(std::holds_alternative<TagPlacement>(card.placement));
    EXPECT_EQ(std::get<TagPlacement>(card.placement).tag, 3);
    const auto card_pose = worldFromObject(card, scene->tags, 0.0);
    ASSERT_TRUE(card_pose);
    expectPoseNear(*card_pose, tag3->world_from_tag * Rigid3d(Eigen::Quaterniond::Identity(), {0, 0, 0.02}));
    const VirtualObject& drone = scene->virtual_objects[2];
    const auto& keyframes = std::get<KeyframePlacement>(drone.placement).keyframes;
    ASSERT_EQ(keyframes.size(), 2u);
    EXPECT_EQ(keyframes[1].t, 2.5);
    expectPoseNear(*worldFromObject(drone, scene->tags, 1.25), Rigid3d::fromRpyDeg({0.5, 0, 1}, {0, 0, 45}));
    expectPoseNear(*worldFromObject(drone, scene->tags, -1.0), keyframes[0].world_from_object);
    expectPoseNear(*worldFromObject(drone, scene->tags, 9.0), keyframes[1].world_from_object);
    const VirtualObject& lamp = scene->virtual_objects[3];
    EXPECT_EQ(*lamp.emission, Eigen::Vector3d(5, 5, 4));
    expectPoseNear(std::get<FixedPlacement>(lamp.placement).world_from_object,
                   Rigid3d(Eigen::Quaterniond::Identity(), {0.5, 0.5, 1.2}));

    EXPECT_EQ(scene->lighting.max_elements, 4000);
    EXPECT_EQ(scene->lighting.error, 0.02);
}

TEST(SceneIo, MinimalSceneGetsDefaults) {
    const auto scene = parseScene("real:\n  - {name: floor, plane: {size: [2, 3]}}\n", "/tmp/minimal.yaml");
    ASSERT_TRUE(scene) << scene.error().message;
    EXPECT_FALSE(scene->camera_path);
    EXPECT_EQ(scene->tags.family, "tag36h11");
    EXPECT_TRUE(scene->tags.items.empty());
    EXPECT_TRUE(scene->real_objects[0].albedo.isEstimate());
    expectPoseNear(scene->real_objects[0].world_from_object, Rigid3d::identity(), 0.0);
    EXPECT_EQ(scene->lighting, LightingOptions{});
    EXPECT_EQ(scene->lighting.max_elements, 8000);
    EXPECT_EQ(scene->lighting.error, 0.01);
    EXPECT_FALSE(scene->lighting.texel_pairs);
    EXPECT_FALSE(scene->lighting.texel_oversample);
}

TEST(SceneIo, TexelSettings) {
    const auto scene = parseScene("real:\n  - {name: floor, plane: {size: [2, 3]}}\nlighting: {texel_pairs: 32, texel_oversample: 2}\n",
                                  "/tmp/texels.yaml");
    ASSERT_TRUE(scene) << scene.error().message;
    EXPECT_EQ(scene->lighting.texel_pairs, 32);
    EXPECT_EQ(scene->lighting.texel_oversample, 2);
}

TEST(SceneIo, TransformSpellingsAgree) {
    // The same pose four ways: rpy, quaternion, matrix, and R = Rz(yaw) Ry(pitch) Rx(roll) by hand.
    const Rigid3d expected = Rigid3d::fromRpyDeg({1, 2, 3}, {30, -20, 110});
    const Eigen::Quaterniond q = expected.rotation;
    const Eigen::Matrix4d m = expected.matrix();
    std::string matrix;
    for (int r = 0; r < 4; ++r) {
        for (int c = 0; c < 4; ++c) matrix += (matrix.empty() ? "" : ", ") + std::to_string(m(r, c));
    }
    char quaternion[256];
    std::snprintf(quaternion, sizeof quaternion, "[%.17g, %.17g, %.17g, %.17g]", q.w(), q.x(), q.y(), q.z());
    const std::string text =
        "real:\n"
        "  - {name: a, sphere: {radius: 1}, world_from_object: {t: [1, 2, 3], rpy_deg: [30, -20, 110]}}\n"
        "  - {name: b, sphere: {radius: 1}, world_from_object: {t: [1, 2, 3], q_wxyz: " +
        std::string(quaternion) + "}}\n  - {name: c, sphere: {radius: 1}, world_from_object: {matrix: [" + matrix +
        "]}}\n";
    // std::to_string keeps 6 decimals: the matrix is rigid to about 1e-6, inside fromMatrix's tolerance.
    const auto scene = parseScene(text, "/tmp/spellings.yaml");
    ASSERT_TRUE(scene) << scene.error().message;
    expectPoseNear(scene->real_objects[0].world_from_object, expected);
    expectPoseNear(scene->real_objects[1].world_from_object, expected);
    expectPoseNear(scene->real_objects[2].world_from_object, expected, 1e-5);
    const Eigen::Matrix3d by_hand = (Eigen::AngleAxisd(110 * M_PI / 180, Eigen::Vector3d::UnitZ()) *
                                     Eigen::AngleAxisd(-20 * M_PI / 180, Eigen::Vector3d::UnitY()) *
                                     Eigen::AngleAxisd(30 * M_PI / 180, Eigen::Vector3d::UnitX()))
                                        .toRotationMatrix();
    EXPECT_LT((scene->real_objects[0].world_from_object.rotationMatrix() - by_hand).norm(), 1e-12);
}

TEST(SceneIo, OptionsSkipCameraAndMeshes) {
    SceneReadOptions options;
    options.load_camera = false;
    options.load_meshes = false;
    const auto scene = readScene(dataDir() / "scene_example.yaml", options);
    ASSERT_TRUE(scene) << scene.error().message;
    EXPECT_TRUE(scene->camera_path);
    EXPECT_FALSE(scene->camera);
    EXPECT_EQ(std::get<MeshShape>(scene->real_objects[2].shape).mesh, nullptr);
}

TEST(SceneIo, SameMeshFileIsLoadedOnce) {
    TempDir dir;
    std::filesystem::copy_file(dataDir() / "cube.obj", dir / "cube.obj");
    writeText(dir / "scene.yaml",
              "real:\n  - {name: a, mesh: cube.obj}\n  - {name: b, mesh: ./cube.obj}\n"
              "virtual:\n  - {name: c, mesh: cube.obj}\n");
    const auto scene = readScene(dir / "scene.yaml");
    ASSERT_TRUE(scene) << scene.error().message;
    const auto& a = std::get<MeshShape>(scene->real_objects[0].shape);
    const auto& b = std::get<MeshShape>(scene->real_objects[1].shape);
    const auto& c = std::get<MeshShape>(scene->virtual_objects[0].shape);
    EXPECT_EQ(a.mesh, b.mesh);
    EXPECT_EQ(a.mesh, c.mesh);
}

void expectSameTransform(const Rigid3d& a, const Rigid3d& b) {
    EXPECT_EQ(a.translation, b.translation);
    // Re-normalising a unit quaternion read back may move it by an ulp.
    EXPECT_LT((a.rotation.coeffs() - b.rotation.coeffs()).cwiseAbs().maxCoeff(), 1e-15);
}

void expectSameScene(const Scene& a, const Scene& b) {
    EXPECT_EQ(a.camera_path, b.camera_path);
    EXPECT_EQ(a.tags.family, b.tags.family);
    ASSERT_EQ(a.tags.items.size(), b.tags.items.size());
    for (std::size_t i = 0; i < a.tags.items.size(); ++i) {
        EXPECT_EQ(a.tags.items[i].id, b.tags.items[i].id);
        EXPECT_EQ(a.tags.items[i].size, b.tags.items[i].size);
        EXPECT_EQ(a.tags.items[i].albedo_black, b.tags.items[i].albedo_black);
        EXPECT_EQ(a.tags.items[i].albedo_white, b.tags.items[i].albedo_white);
        expectSameTransform(a.tags.items[i].world_from_tag, b.tags.items[i].world_from_tag);
    }
    ASSERT_EQ(a.real_objects.size(), b.real_objects.size());
    for (std::size_t i = 0; i < a.real_objects.size(); ++i) {
        EXPECT_EQ(a.real_objects[i].name, b.real_objects[i].name);
        EXPECT_EQ(a.real_objects[i].shape, b.real_objects[i].shape);
        EXPECT_EQ(a.real_objects[i].albedo, b.real_objects[i].albedo);
        expectSameTransform(a.real_objects[i].world_from_object, b.real_objects[i].world_from_object);
    }
    ASSERT_EQ(a.lights.size(), b.lights.size());
    for (std::size_t i = 0; i < a.lights.size(); ++i) {
        EXPECT_EQ(a.lights[i].name, b.lights[i].name);
        EXPECT_EQ(a.lights[i].shape, b.lights[i].shape);
        EXPECT_EQ(a.lights[i].emission, b.lights[i].emission);
        expectSameTransform(a.lights[i].world_from_object, b.lights[i].world_from_object);
    }
    ASSERT_EQ(a.virtual_objects.size(), b.virtual_objects.size());
    for (std::size_t i = 0; i < a.virtual_objects.size(); ++i) {
        const VirtualObject& va = a.virtual_objects[i];
        const VirtualObject& vb = b.virtual_objects[i];
        EXPECT_EQ(va.name, vb.name);
        EXPECT_EQ(va.shape, vb.shape);
        EXPECT_EQ(va.material, vb.material);
        EXPECT_EQ(va.emission, vb.emission);
        ASSERT_EQ(va.placement.index(), vb.placement.index());
        if (const auto* fixed = std::get_if<FixedPlacement>(&va.placement)) {
            expectSameTransform(fixed->world_from_object, std::get<FixedPlacement>(vb.placement).world_from_object);
        } else if (const auto* attached = std::get_if<TagPlacement>(&va.placement)) {
            EXPECT_EQ(attached->tag, std::get<TagPlacement>(vb.placement).tag);
            expectSameTransform(attached->tag_from_object, std::get<TagPlacement>(vb.placement).tag_from_object);
        } else {
            const auto& ka = std::get<KeyframePlacement>(va.placement).keyframes;
            const auto& kb = std::get<KeyframePlacement>(vb.placement).keyframes;
            ASSERT_EQ(ka.size(), kb.size());
            for (std::size_t k = 0; k < ka.size(); ++k) {
                EXPECT_EQ(ka[k].t, kb[k].t);
                expectSameTransform(ka[k].world_from_object, kb[k].world_from_object);
            }
        }
    }
    EXPECT_EQ(a.lighting, b.lighting);
}

TEST(SceneIo, ExampleRoundTrips) {
    const auto scene = readScene(dataDir() / "scene_example.yaml");
    ASSERT_TRUE(scene) << scene.error().message;
    TempDir dir;
    std::filesystem::create_directories(dir / "written");
    const auto written = writeScene(dir / "written" / "scene.yaml", *scene);
    ASSERT_TRUE(written) << written.error().message;
    const auto back = readScene(dir / "written" / "scene.yaml");
    ASSERT_TRUE(back) << back.error().message << "\n" << readText(dir / "written" / "scene.yaml");
    expectSameScene(*scene, *back);
    EXPECT_EQ(back->camera, scene->camera);
}

TEST(SceneIo, AwkwardValuesRoundTripExactly) {
    TempDir dir;
    Scene scene;
    scene.camera_path = dir / "calib" / "cam 0.yaml";
    scene.tags.family = "tagStandard41h12";
    scene.tags.items.push_back({2000, 1.0 / 3.0, Rigid3d::fromRpyDeg({0.1, 0.2, 0.3}, {1e-20, -45, 179.9}), 0.0, 1.0});
    scene.real_objects.push_back({"my table", BoxShape{{0.1, 0.7, 1e-3}},
                                  Rigid3d::fromRpyDeg({-1.0 / 7.0, 2e10, 0}, {1, 2, 3}),
                                  RgbOrEstimate::constant({0.1, 0.2, 0.30000000000000004})});
    scene.real_objects.push_back({"null", MeshShape{dir / "meshes" / "thing.obj", nullptr}, Rigid3d::identity(),
                                  RgbOrEstimate::constant(Eigen::Vector3d::Constant(0.25))});
    scene.lights.push_back({"sun \"bright\"", DirectionalLightShape{Eigen::Vector3d(1, 2, -3).normalized()},
                            Rigid3d::identity(), RgbOrEstimate::constant({1000.5, 999, 998})});
    scene.lights.push_back(
        {"spot", PointLightShape{}, Rigid3d::fromRpyDeg({0, 0, 3}, {0, 0, 0}), RgbOrEstimate::estimate()});
    scene.lights.push_back({"env", DistantLightShape{64}, Rigid3d::identity(), RgbOrEstimate::constant({1, 1, 1})});
    VirtualObject moving;
    moving.name = "moving";
    moving.shape = SphereShape{0.123456789012345678};
    moving.material = {MaterialType::kGgx, {0.9, 0.8, 0.7}, 0.05};
    moving.emission = Eigen::Vector3d(0, 0.5, 1e-9);
    moving.placement = KeyframePlacement{{{0.0, Rigid3d::identity()},
                                          {0.1, Rigid3d::fromRpyDeg({1, 1, 1}, {10, 20, 30})},
                                          {0.30000000000000004, Rigid3d::fromRpyDeg({2, 2, 2}, {-10, -20, -30})}}};
    scene.virtual_objects.push_back(moving);
    VirtualObject attached;
    attached.name = "on tag";
    attached.shape = PlaneShape{{0.2, 0.1}};
    attached.placement = TagPlacement{2000, Rigid3d::fromRpyDeg({0, 0, 0.01}, {90, 0, 0})};
    scene.virtual_objects.push_back(attached);
    scene.lighting = {123, 1e-4, 32, 2};

    const auto file = dir / "scene.yaml";
    ASSERT_TRUE(writeScene(file, scene));
    const std::string text = readText(file);
    EXPECT_NE(text.find("camera: \"calib/cam 0.yaml\""), std::string::npos) << text;
    EXPECT_NE(text.find("mesh: meshes/thing.obj"), std::string::npos) << text;
    SceneReadOptions options;
    options.load_camera = false;
    options.load_meshes = false;
    const auto back = readScene(file, options);
    ASSERT_TRUE(back) << back.error().message << "\n" << text;
    expectSameScene(scene, *back);
}

}  // namespace
}  // namespace commonlight

// Malformed scene files: every error names the file, the line and the key path.
#include <algorithm>
#include <string>

#include <gtest/gtest.h>

#include "core/scene_io.h"
#include "tests/test_support.h"

namespace commonlight {
namespace {

using testing::sourceDir;
using testing::TempDir;
using testing::writeText;

int lineOf(const std::string& text, const std::string& needle) {
    const auto pos = text.find(needle);
    if (pos == std::string::npos) return 0;
    return 1 + static_cast<int>(std::count(text.begin(), text.begin() + static_cast<std::ptrdiff_t>(pos), '\n'));
}

// Reads `text` as <dir>/scene.yaml and checks the error: its code, that the message starts with
// "<file>:<line of line_needle>: key '<key>': ", and that it contains `problem`.
void expectSceneError(const TempDir& dir, const std::string& text, const std::string& key, const std::string& problem,
                      const std::string& line_needle, ErrorCode code = ErrorCode::kBadInput) {
    const auto file = dir / "scene.yaml";
    writeText(file, text);
    const auto scene = readScene(file);
    ASSERT_FALSE(scene) << "accepted:\n" << text;
    const std::string& msg = scene.error().message;
    EXPECT_EQ(scene.error().code, code) << msg;
    const int line = lineOf(text, line_needle);
    ASSERT_GT(line, 0) << line_needle;
    const std::string prefix = file.string() + ":" + std::to_string(line) + ": key '" + key + "': ";
    EXPECT_EQ(msg.rfind(prefix, 0), 0u) << msg << "\n(expected it to start with " << prefix << ")";
    EXPECT_NE(msg.find(problem), std::string::npos) << msg;
}

void expectSceneError(const std::string& text, const std::string& key, const std::string& problem,
                      const std::string& line_needle, ErrorCode code = ErrorCode::kBadInput) {
    TempDir dir;
    expectSceneError(dir, text, key, problem, line_needle, code);
}

const std::string kTags =
    "tags:\n"
    "  items:\n"
    "    - {id: 3, size: 0.16, world_from_tag: {t: [0, 0, 0.75]}}\n";

TEST(SceneIoBadInput, SyntaxErrorGivesLineAndColumn) {
    TempDir dir;
    const std::string text = "real:\n  - {name: floor, plane: {size: [4, 4]}\n  - {name: x}\n";
    writeText(dir / "scene.yaml", text);
    const auto scene = readScene(dir / "scene.yaml");
    ASSERT_FALSE(scene);
    EXPECT_EQ(scene.error().code, ErrorCode::kBadInput);
    const std::string& msg = scene.error().message;
    const std::string prefix = (dir / "scene.yaml").string() + ":";
    ASSERT_EQ(msg.rfind(prefix, 0), 0u) << msg;
    // <line>:<column>: YAML syntax error
    int line = 0;
    int column = 0;
    ASSERT_EQ(std::sscanf(msg.c_str() + prefix.size(), "%d:%d:", &line, &column), 2) << msg;
    EXPECT_GE(line, 2) << msg;
    EXPECT_GT(column, 0) << msg;
    EXPECT_NE(msg.find("YAML syntax error"), std::string::npos) << msg;
}

TEST(SceneIoBadInput, EmptyFile) {
    TempDir dir;
    writeText(dir / "scene.yaml", "# nothing here\n");
    const auto scene = readScene(dir / "scene.yaml");
    ASSERT_FALSE(scene);
    EXPECT_NE(scene.error().message.find("scene.yaml: the scene file is empty"), std::string::npos);
}

TEST(SceneIoBadInput, MissingSceneFileIsNotFound) {
    TempDir dir;
    const auto scene = readScene(dir / "nope.yaml");
    ASSERT_FALSE(scene);
    EXPECT_EQ(scene.error().code, ErrorCode::kNotFound);
    EXPECT_NE(scene.error().message.find("nope.yaml"), std::string::npos);
}

TEST(SceneIoBadInput, MissingRequiredKey) {
    expectSceneError("tags:\n  items:\n    - {id: 3, world_from_tag: {t: [0, 0, 0]}}\n", "tags.items[0].size",
                     "missing", "- {id: 3");
}

TEST(SceneIoBadInput, MissingShape) {
    expectSceneError("real:\n  - {name: floor, world_from_object: {t: [0, 0, 0]}}\n", "real[0]",
                     "missing its shape (plane, box, sphere, mesh)", "- {name: floor");
}

TEST(SceneIoBadInput, WrongTypeNumber) {
    expectSceneError("real:\n  - {name: floor, plane: {size: [4, big]}}\n", "real[0].plane.size[1]",
                     "expected a number, found 'big'", "- {name: floor");
}

TEST(SceneIoBadInput, WrongTypeListExpected) {
    expectSceneError("real:\n  name: floor\n  plane: {size: [4, 4]}\n", "real", "expected a list", "name: floor");
}

TEST(SceneIoBadInput, WrongTypeMapExpected) {
    expectSceneError("lighting: 8000\n", "lighting", "expected a map", "lighting");
}

TEST(SceneIoBadInput, UnknownKeyInTransform) {
    const std::string text =
        "real:\n"
        "  - {name: floor, plane: {size: [4, 4]}}\n"
        "  - {name: wall, plane: {size: [4, 3]}}\n"
        "  - name: table\n"
        "    box: {size: [1.2, 0.8, 0.75]}\n"
        "    world_from_object:\n"
        "      t: [0, 0, 0.375]\n"
        "      rpy: [0, 0, 90]\n";
    expectSceneError(text, "real[2].world_from_object.rpy", "unknown key (expected t, rpy_deg, q_wxyz or matrix)",
                     "rpy:");
}

TEST(SceneIoBadInput, UnknownTopLevelKey) {
    expectSceneError("virtuals:\n  - {name: ball, sphere: {radius: 0.1}}\n", "virtuals",
                     "unknown key (expected camera, tags, real, lights, virtual, lighting or sensor)", "virtuals:");
}

TEST(SceneIoBadInput, DuplicateKey) {
    expectSceneError("lighting:\n  error: 0.1\n  error: 0.2\n", "lighting.error", "appears twice", "error: 0.2");
}

TEST(SceneIoBadInput, TwoRotations) {
    expectSceneError(
        "real:\n  - name: floor\n    plane: {size: [4, 4]}\n"
        "    world_from_object: {t: [0, 0, 0], rpy_deg: [0, 0, 0],\n"
        "                        q_wxyz: [1, 0, 0, 0]}\n",
        "real[0].world_from_object.q_wxyz", "give one rotation: rpy_deg or q_wxyz, not both", "q_wxyz");
}

TEST(SceneIoBadInput, MatrixWithTranslation) {
    expectSceneError(
        "real:\n  - name: floor\n    plane: {size: [4, 4]}\n"
        "    world_from_object: {matrix: [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1],\n"
        "                        t: [0, 0, 1]}\n",
        "real[0].world_from_object.t", "a transform with a matrix takes nothing else", "t: [0, 0, 1]");
}

TEST(SceneIoBadInput, TransformWithoutTranslation) {
    expectSceneError(
        "real:\n  - name: floor\n    plane: {size: [4, 4]}\n    world_from_object: {rpy_deg: [0, 0, 90]}\n",
        "real[0].world_from_object.t", "missing", "world_from_object");
}

TEST(SceneIoBadInput, NonUnitQuaternion) {
    expectSceneError(
        "real:\n  - name: floor\n    plane: {size: [4, 4]}\n"
        "    world_from_object: {t: [0, 0, 0], q_wxyz: [1, 0, 0, 0.01]}\n",
        "real[0].world_from_object.q_wxyz", "quaternion has length 1.00005", "world_from_object");
}

TEST(SceneIoBadInput, NonRigidMatrix) {
    expectSceneError(
        "real:\n  - name: floor\n    plane: {size: [4, 4]}\n"
        "    world_from_object: {matrix: [2,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]}\n",
        "real[0].world_from_object.matrix", "not a rigid transform: rotation block is not a rotation",
        "world_from_object");
}

TEST(SceneIoBadInput, UnknownTagInAttach) {
    expectSceneError(kTags + "virtual:\n  - name: ball\n    sphere: {radius: 0.1}\n    attach: {tag: 4}\n",
                     "virtual[0].attach.tag", "tag 4 is not in tags.items", "attach:");
}

TEST(SceneIoBadInput, TwoPlacements) {
    expectSceneError(kTags +
                         "virtual:\n  - name: ball\n    sphere: {radius: 0.1}\n    attach: {tag: 3}\n"
                         "    world_from_object: {t: [0, 0, 1]}\n",
                     "virtual[0]", "give one placement", "- name: ball");
}

TEST(SceneIoBadInput, KeyframeTimesMustIncrease) {
    expectSceneError(
        "virtual:\n  - name: ball\n    sphere: {radius: 0.1}\n    keyframes:\n"
        "      - {t: 0, world_from_object: {t: [0, 0, 1]}}\n"
        "      - {t: 1.5, world_from_object: {t: [1, 0, 1]}}\n"
        "      - {t: 1.5, world_from_object: {t: [2, 0, 1]}}\n",
        "virtual[0].keyframes[2].t", "times must increase strictly: 1.5 after 1.5", "t: [2, 0, 1]");
}

TEST(SceneIoBadInput, MissingMeshFile) {
    TempDir dir;
    expectSceneError(dir, "real:\n  - {name: shelf, mesh: meshes/shelf.gltf}\n", "real[0].mesh",
                     (dir / "meshes/shelf.gltf").string() + ": no such file", "shelf.gltf", ErrorCode::kNotFound);
}

TEST(SceneIoBadInput, TruncatedGltf) {
    TempDir dir;
    const std::string gltf = testing::readText(sourceDir() / "tests/core/data/quad.gltf");
    writeText(dir / "quad.gltf", gltf.substr(0, gltf.size() / 3));
    expectSceneError(dir, "virtual:\n  - {name: card, mesh: quad.gltf}\n", "virtual[0].mesh",
                     "quad.gltf: not a valid glTF 2.0 file", "quad.gltf");
}

TEST(SceneIoBadInput, MissingCameraFile) {
    TempDir dir;
    expectSceneError(dir, "camera: calib.yaml\n", "camera", "calib.yaml", "camera:", ErrorCode::kNotFound);
}

TEST(SceneIoBadInput, BadCalibrationNamesBothFiles) {
    TempDir dir;
    writeText(dir / "calib.yaml", "image_width: 640\nimage_height: 480\n");
    expectSceneError(dir, "camera: calib.yaml\n", "camera", "calib.yaml:1: key 'camera_matrix': missing", "camera:");
}

TEST(SceneIoBadInput, DuplicateNames) {
    expectSceneError(
        "real:\n  - {name: table, box: {size: [1, 1, 1]}}\n"
        "virtual:\n  - {name: table, sphere: {radius: 0.1}}\n",
        "virtual[0].name", "name 'table' is already used (line 2)", "table, sphere");
}

TEST(SceneIoBadInput, DuplicateTagIds) {
    expectSceneError(
        "tags:\n  items:\n    - {id: 3, size: 0.16, world_from_tag: {t: [0, 0, 0]}}\n"
        "    - {id: 3, size: 0.08, world_from_tag: {t: [1, 0, 0]}}\n",
        "tags.items[1].id", "tag 3 appears twice (first at line 3)", "size: 0.08");
}

TEST(SceneIoBadInput, TagIdOutsideFamily) {
    expectSceneError("tags:\n  family: tag16h5\n  items:\n    - {id: 30, size: 0.16, world_from_tag: {t: [0, 0, 0]}}\n",
                     "tags.items[0].id", "tag 30 is not in tag16h5 (ids 0 to 29)", "id: 30");
}

TEST(SceneIoBadInput, UnknownTagFamily) {
    expectSceneError("tags:\n  family: tag36h10\n  items: []\n", "tags.family", "unknown tag family 'tag36h10'",
                     "family:");
}

TEST(SceneIoBadInput, NegativeSize) {
    expectSceneError("real:\n  - {name: table, box: {size: [1.2, -0.8, 0.75]}}\n", "real[0].box.size[1]",
                     "must be positive, found -0.8", "table");
}

TEST(SceneIoBadInput, NonFiniteNumber) {
    expectSceneError("virtual:\n  - name: ball\n    sphere: {radius: .inf}\n", "virtual[0].sphere.radius",
                     "must be finite", "radius");
}

TEST(SceneIoBadInput, NaNInTranslation) {
    expectSceneError("real:\n  - name: floor\n    plane: {size: [4, 4]}\n    world_from_object: {t: [0, nan, 0]}\n",
                     "real[0].world_from_object.t[1]", "must be finite", "nan");
}

TEST(SceneIoBadInput, AlbedoOutOfRange) {
    expectSceneError("real:\n  - {name: floor, plane: {size: [4, 4]}, albedo: [0.5, 1.2, 0.5]}\n", "real[0].albedo",
                     "must be in [0, 1], found 1.2", "floor");
}

TEST(SceneIoBadInput, MisspelledEstimate) {
    expectSceneError("lights:\n  - {name: sky, distant: {directions: 64}, radiance: estimated}\n", "lights[0].radiance",
                     "expected a number, [r, g, b] or estimate, found 'estimated'", "sky");
}

TEST(SceneIoBadInput, WrongEmissionKeyForLight) {
    expectSceneError("lights:\n  - name: panel\n    area: {size: [0.6, 0.6]}\n    intensity: 20\n",
                     "lights[0].intensity", "a area light takes radiance, not intensity", "intensity");
}

TEST(SceneIoBadInput, DirectionalLightHasNoPose) {
    expectSceneError(
        "lights:\n  - name: sun\n    directional: {direction: [0, 0, -1]}\n"
        "    world_from_object: {t: [0, 0, 10]}\n",
        "lights[0].world_from_object", "a directional light has no position", "world_from_object");
}

TEST(SceneIoBadInput, TwoLightTypes) {
    expectSceneError("lights:\n  - name: lamp\n    point: {}\n    disc: {radius: 0.1}\n", "lights[0].point",
                     "give one type, found both disc and point", "point:");
}

TEST(SceneIoBadInput, ZeroLightDirection) {
    expectSceneError("lights:\n  - {name: sun, directional: {direction: [0, 0, 0]}}\n",
                     "lights[0].directional.direction", "must not be zero", "sun");
}

TEST(SceneIoBadInput, RoughnessNeedsGgx) {
    expectSceneError(
        "virtual:\n  - name: ball\n    sphere: {radius: 0.1}\n    material:\n      albedo: 0.5\n"
        "      roughness: 0.2\n",
        "virtual[0].material.roughness", "only a ggx material has a roughness", "roughness");
}

TEST(SceneIoBadInput, UnknownMaterialType) {
    expectSceneError("virtual:\n  - name: ball\n    sphere: {radius: 0.1}\n    material: {type: phong}\n",
                     "virtual[0].material.type", "unknown material type 'phong' (expected lambertian or ggx)", "phong");
}

TEST(SceneIoBadInput, EstimateIsNotAVirtualAlbedo) {
    expectSceneError("virtual:\n  - name: ball\n    sphere: {radius: 0.1}\n    material: {albedo: estimate}\n",
                     "virtual[0].material.albedo", "expected a number, found 'estimate'", "estimate");
}

TEST(SceneIoBadInput, TexelSettingsOutOfRange) {
    expectSceneError("lighting: {texel_pairs: 65}\n", "lighting.texel_pairs", "must be between 0 and 64", "lighting");
    expectSceneError("lighting: {texel_oversample: 0}\n", "lighting.texel_oversample", "must be between 1 and 4", "lighting");
    expectSceneError("lighting: {texel_pairs: many}\n", "lighting.texel_pairs", "", "many");
}

TEST(SceneIoBadInput, NonPositiveMaxElements) {
    expectSceneError("lighting: {max_elements: 0, error: 0.01}\n", "lighting.max_elements", "must be positive",
                     "lighting");
}

}  // namespace
}  // namespace commonlight

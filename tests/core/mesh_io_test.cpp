#include "core/mesh_io.h"

#include <cstring>
#include <fstream>
#include <string>
#include <vector>

#include <Eigen/Geometry>
#include <gtest/gtest.h>

#include "tests/test_support.h"

namespace commonlight {
namespace {

using testing::sourceDir;
using testing::TempDir;
using testing::writeText;

std::filesystem::path dataDir() { return sourceDir() / "tests/core/data"; }

std::string base64(const std::vector<std::uint8_t>& bytes) {
    static const char* kAlphabet = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    std::string out;
    for (std::size_t i = 0; i < bytes.size(); i += 3) {
        const std::uint32_t b0 = bytes[i];
        const std::uint32_t b1 = i + 1 < bytes.size() ? bytes[i + 1] : 0;
        const std::uint32_t b2 = i + 2 < bytes.size() ? bytes[i + 2] : 0;
        const std::uint32_t v = (b0 << 16) | (b1 << 8) | b2;
        out += kAlphabet[(v >> 18) & 63];
        out += kAlphabet[(v >> 12) & 63];
        out += i + 1 < bytes.size() ? kAlphabet[(v >> 6) & 63] : '=';
        out += i + 2 < bytes.size() ? kAlphabet[v & 63] : '=';
    }
    return out;
}

template <typename T>
void append(std::vector<std::uint8_t>& bytes, const std::vector<T>& values) {
    const std::size_t at = bytes.size();
    bytes.resize(at + values.size() * sizeof(T));
    if (!values.empty()) std::memcpy(bytes.data() + at, values.data(), values.size() * sizeof(T));
}

// A one-mesh glTF: buffer = positions | normals | indices (uint16), views 0, 1, 2, accessors 0, 1, 2.
struct GltfSpec {
    std::vector<float> positions = {0, 0, 0, 1, 0, 0, 0, 1, 0, 1, 1, 0};
    std::vector<float> normals = {0, 0, 1, 0, 0, 1, 0, 0, 1, 0, 0, 1};
    std::vector<std::uint16_t> indices = {0, 1, 2, 2, 1, 3};
    std::string nodes = R"([{"mesh": 0}])";
    std::string scene_nodes = "[0]";
    int mode = 4;
    std::string buffer_uri;   // empty: embedded as a data URI
    int position_count = -1;  // accessor count override
};

std::vector<std::uint8_t> bufferOf(const GltfSpec& spec) {
    std::vector<std::uint8_t> bytes;
    append(bytes, spec.positions);
    append(bytes, spec.normals);
    append(bytes, spec.indices);
    while (bytes.size() % 4 != 0) bytes.push_back(0);
    return bytes;
}

// The JSON; `glb` leaves the buffer's uri out (it is the binary chunk).
std::string gltfJson(const GltfSpec& spec, bool glb = false) {
    const std::vector<std::uint8_t> bytes = bufferOf(spec);
    const std::size_t pos_bytes = spec.positions.size() * 4;
    const std::size_t nrm_bytes = spec.normals.size() * 4;
    const std::size_t idx_bytes = spec.indices.size() * 2;
    const int count = spec.position_count >= 0 ? spec.position_count : static_cast<int>(spec.positions.size() / 3);
    std::string uri;
    if (!glb) {
        uri = spec.buffer_uri.empty() ? "data:application/octet-stream;base64," + base64(bytes) : spec.buffer_uri;
        uri = R"(, "uri": ")" + uri + "\"";
    }
    std::string attributes = R"("POSITION": 0)";
    if (!spec.normals.empty()) attributes += R"(, "NORMAL": 1)";
    return std::string(R"({"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": )") + spec.scene_nodes +
           "}],\n\"nodes\": " + spec.nodes + ",\n" + R"("meshes": [{"primitives": [{"attributes": {)" + attributes +
           R"(}, "indices": 2, "mode": )" + std::to_string(spec.mode) + "}]}],\n" + R"("buffers": [{"byteLength": )" +
           std::to_string(bytes.size()) + uri + "}],\n" +
           R"("bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": )" + std::to_string(pos_bytes) + "},\n" +
           R"({"buffer": 0, "byteOffset": )" + std::to_string(pos_bytes) + R"(, "byteLength": )" +
           std::to_string(std::max<std::size_t>(nrm_bytes, 4)) + "},\n" + R"({"buffer": 0, "byteOffset": )" +
           std::to_string(pos_bytes + nrm_bytes) + R"(, "byteLength": )" + std::to_string(idx_bytes) + "}],\n" +
           R"("accessors": [{"bufferView": 0, "componentType": 5126, "count": )" + std::to_string(count) +
           R"(, "type": "VEC3"},)" + "\n" + R"({"bufferView": 1, "componentType": 5126, "count": )" +
           std::to_string(spec.normals.size() / 3) + R"(, "type": "VEC3"},)" + "\n" +
           R"({"bufferView": 2, "componentType": 5123, "count": )" + std::to_string(spec.indices.size()) +
           R"(, "type": "SCALAR"}]})" + "\n";
}

void writeBytes(const std::filesystem::path& file, const std::vector<std::uint8_t>& bytes) {
    std::ofstream out(file, std::ios::binary);
    out.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
}

std::vector<std::uint8_t> glbBytes(const GltfSpec& spec) {
    std::string json = gltfJson(spec, true);
    while (json.size() % 4 != 0) json += ' ';
    const std::vector<std::uint8_t> bin = bufferOf(spec);
    std::vector<std::uint8_t> out;
    const auto u32 = [&out](std::uint32_t v) { append(out, std::vector<std::uint32_t>{v}); };
    u32(0x46546C67);  // "glTF"
    u32(2);
    u32(static_cast<std::uint32_t>(12 + 8 + json.size() + 8 + bin.size()));
    u32(static_cast<std::uint32_t>(json.size()));
    u32(0x4E4F534A);  // "JSON"
    out.insert(out.end(), json.begin(), json.end());
    u32(static_cast<std::uint32_t>(bin.size()));
    u32(0x004E4942);  // "BIN\0"
    out.insert(out.end(), bin.begin(), bin.end());
    return out;
}

// Every triangle's geometric normal points the way its vertex normals do.
void expectWindingMatchesNormals(const Mesh& mesh) {
    ASSERT_EQ(mesh.normals.size(), mesh.positions.size());
    for (std::size_t t = 0; t < mesh.triangleCount(); ++t) {
        const Eigen::Vector3f& a = mesh.positions[mesh.indices[3 * t]];
        const Eigen::Vector3f& b = mesh.positions[mesh.indices[3 * t + 1]];
        const Eigen::Vector3f& c = mesh.positions[mesh.indices[3 * t + 2]];
        const Eigen::Vector3f face = (b - a).cross(c - a);
        EXPECT_GT(face.dot(mesh.normals[mesh.indices[3 * t]]), 0.0f) << "triangle " << t;
    }
}

void expectError(const Result<Mesh>& mesh, const std::filesystem::path& file, const std::string& problem,
                 ErrorCode code = ErrorCode::kBadInput) {
    ASSERT_FALSE(mesh) << "accepted " << file;
    EXPECT_EQ(mesh.error().code, code) << mesh.error().message;
    EXPECT_NE(mesh.error().message.find(file.string()), std::string::npos) << mesh.error().message;
    EXPECT_NE(mesh.error().message.find(problem), std::string::npos) << mesh.error().message;
}

TEST(MeshIo, ReadsObjCubeWithNormals) {
    const auto mesh = readMesh(dataDir() / "cube.obj");
    ASSERT_TRUE(mesh) << mesh.error().message;
    EXPECT_EQ(mesh->triangleCount(), 12u);
    EXPECT_EQ(mesh->positions.size(), 24u);  // 6 faces x 4 corners, each with its own normal
    for (const Eigen::Vector3f& p : mesh->positions) EXPECT_FLOAT_EQ(p.cwiseAbs().maxCoeff(), 0.5f);
    for (const Eigen::Vector3f& n : mesh->normals) EXPECT_FLOAT_EQ(n.norm(), 1.0f);
    expectWindingMatchesNormals(*mesh);
}

TEST(MeshIo, ReadsObjWithoutNormals) {
    TempDir dir;
    writeText(dir / "quad.OBJ", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n");
    const auto mesh = readMesh(dir / "quad.OBJ");
    ASSERT_TRUE(mesh) << mesh.error().message;
    EXPECT_EQ(mesh->positions.size(), 4u);
    EXPECT_TRUE(mesh->normals.empty());
    ASSERT_EQ(mesh->triangleCount(), 2u);
    // Whichever diagonal the triangulation takes, both halves face +z and cover the unit square.
    float area = 0.0f;
    for (std::size_t t = 0; t < 2; ++t) {
        const Eigen::Vector3f& a = mesh->positions[mesh->indices[3 * t]];
        const Eigen::Vector3f& b = mesh->positions[mesh->indices[3 * t + 1]];
        const Eigen::Vector3f& c = mesh->positions[mesh->indices[3 * t + 2]];
        const Eigen::Vector3f face = (b - a).cross(c - a);
        EXPECT_GT(face.z(), 0.0f);
        area += 0.5f * face.norm();
    }
    EXPECT_FLOAT_EQ(area, 1.0f);
}

TEST(MeshIo, ReadsGltfFixture) {
    const auto mesh = readMesh(dataDir() / "quad.gltf");
    ASSERT_TRUE(mesh) << mesh.error().message;
    EXPECT_EQ(mesh->triangleCount(), 2u);
    ASSERT_EQ(mesh->positions.size(), 4u);
    // The node lifts the quad to z = 1.
    EXPECT_EQ(mesh->positions[2], Eigen::Vector3f(1, 1, 1));
    expectWindingMatchesNormals(*mesh);
}

TEST(MeshIo, AppliesNodeHierarchyTransforms) {
    TempDir dir;
    GltfSpec spec;
    // Parent: translation (1, 2, 3). Child: 90 degrees about z (quaternion x y z w), scale 2.
    spec.nodes = R"([{"translation": [1, 2, 3], "children": [1]},
                     {"rotation": [0, 0, 0.7071067811865476, 0.7071067811865476], "scale": [2, 2, 2], "mesh": 0}])";
    writeText(dir / "tree.gltf", gltfJson(spec));
    const auto mesh = readMesh(dir / "tree.gltf");
    ASSERT_TRUE(mesh) << mesh.error().message;
    ASSERT_EQ(mesh->positions.size(), 4u);
    // (1, 0, 0) -> scaled (2, 0, 0) -> rotated (0, 2, 0) -> translated (1, 4, 3).
    EXPECT_LT((mesh->positions[1] - Eigen::Vector3f(1, 4, 3)).norm(), 1e-6f);
    EXPECT_LT((mesh->normals[1] - Eigen::Vector3f(0, 0, 1)).norm(), 1e-6f);

    // The same through a column-major matrix: translation in elements 12..14.
    spec.nodes = R"([{"matrix": [1,0,0,0, 0,1,0,0, 0,0,1,0, 5,6,7,1], "mesh": 0}])";
    writeText(dir / "matrix.gltf", gltfJson(spec));
    const auto moved = readMesh(dir / "matrix.gltf");
    ASSERT_TRUE(moved) << moved.error().message;
    EXPECT_EQ(moved->positions[3], Eigen::Vector3f(6, 7, 7));
}

TEST(MeshIo, MirroringNodeKeepsFrontFaces) {
    TempDir dir;
    GltfSpec spec;
    spec.nodes = R"([{"scale": [1, 1, -1], "mesh": 0}])";
    writeText(dir / "mirror.gltf", gltfJson(spec));
    const auto mesh = readMesh(dir / "mirror.gltf");
    ASSERT_TRUE(mesh) << mesh.error().message;
    EXPECT_LT((mesh->normals[0] - Eigen::Vector3f(0, 0, -1)).norm(), 1e-6f);
    expectWindingMatchesNormals(*mesh);
}

TEST(MeshIo, ReadsGlb) {
    TempDir dir;
    writeBytes(dir / "quad.glb", glbBytes(GltfSpec{}));
    const auto mesh = readMesh(dir / "quad.glb");
    ASSERT_TRUE(mesh) << mesh.error().message;
    EXPECT_EQ(mesh->triangleCount(), 2u);
    EXPECT_EQ(mesh->indices, (std::vector<std::uint32_t>{0, 1, 2, 2, 1, 3}));
}

TEST(MeshIo, MeshWithoutNormalsHasEmptyNormals) {
    TempDir dir;
    GltfSpec spec;
    spec.normals.clear();
    writeText(dir / "bare.gltf", gltfJson(spec));
    const auto mesh = readMesh(dir / "bare.gltf");
    ASSERT_TRUE(mesh) << mesh.error().message;
    EXPECT_TRUE(mesh->normals.empty());
    EXPECT_EQ(mesh->positions.size(), 4u);
}

TEST(MeshIoBadInput, MissingFileIsNotFound) {
    TempDir dir;
    expectError(readMesh(dir / "nothing.gltf"), dir / "nothing.gltf", "no such file", ErrorCode::kNotFound);
    expectError(readMesh(dir / "nothing.obj"), dir / "nothing.obj", "no such file", ErrorCode::kNotFound);
}

TEST(MeshIoBadInput, UnknownExtension) {
    TempDir dir;
    writeText(dir / "mesh.stl", "solid x\nendsolid x\n");
    expectError(readMesh(dir / "mesh.stl"), dir / "mesh.stl", "unknown mesh format '.stl'");
}

TEST(MeshIoBadInput, TruncatedGltf) {
    TempDir dir;
    const std::string json = gltfJson(GltfSpec{});
    writeText(dir / "cut.gltf", json.substr(0, json.size() / 2));
    expectError(readMesh(dir / "cut.gltf"), dir / "cut.gltf", "not a valid glTF 2.0 file");
}

TEST(MeshIoBadInput, TruncatedGlb) {
    TempDir dir;
    std::vector<std::uint8_t> bytes = glbBytes(GltfSpec{});
    bytes.resize(bytes.size() - 20);
    writeBytes(dir / "cut.glb", bytes);
    expectError(readMesh(dir / "cut.glb"), dir / "cut.glb", "not a valid glTF 2.0 file");
}

TEST(MeshIoBadInput, MissingBufferFile) {
    TempDir dir;
    GltfSpec spec;
    spec.buffer_uri = "geometry.bin";
    writeText(dir / "external.gltf", gltfJson(spec));
    expectError(readMesh(dir / "external.gltf"), dir / "external.gltf", "geometry.bin");
}

TEST(MeshIoBadInput, IndexOutOfRange) {
    TempDir dir;
    GltfSpec spec;
    spec.indices = {0, 1, 2, 2, 1, 7};
    writeText(dir / "bad_index.gltf", gltfJson(spec));
    expectError(readMesh(dir / "bad_index.gltf"), dir / "bad_index.gltf",
                "index 7 (entry 5) is out of range: the primitive has 4 vertices");
}

TEST(MeshIoBadInput, AccessorPastEndOfBuffer) {
    TempDir dir;
    GltfSpec spec;
    spec.position_count = 40;
    writeText(dir / "overrun.gltf", gltfJson(spec));
    expectError(readMesh(dir / "overrun.gltf"), dir / "overrun.gltf", "reads past the end of its buffer");
}

TEST(MeshIoBadInput, TriangleStripIsRefused) {
    TempDir dir;
    GltfSpec spec;
    spec.mode = 5;
    writeText(dir / "strip.gltf", gltfJson(spec));
    expectError(readMesh(dir / "strip.gltf"), dir / "strip.gltf", "mode TRIANGLE_STRIP (5) is not supported");
}

TEST(MeshIoBadInput, SceneWithoutMeshesIsEmpty) {
    TempDir dir;
    GltfSpec spec;
    spec.nodes = R"([{"name": "empty"}])";
    writeText(dir / "empty.gltf", gltfJson(spec));
    expectError(readMesh(dir / "empty.gltf"), dir / "empty.gltf", "contains no triangles");
}

TEST(MeshIoBadInput, NodeCycle) {
    TempDir dir;
    GltfSpec spec;
    spec.nodes = R"([{"children": [1]}, {"children": [0], "mesh": 0}])";
    writeText(dir / "cycle.gltf", gltfJson(spec));
    expectError(readMesh(dir / "cycle.gltf"), dir / "cycle.gltf", "cycle");
}

TEST(MeshIoBadInput, ObjVertexOutOfRange) {
    TempDir dir;
    writeText(dir / "bad.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 9\n");
    expectError(readMesh(dir / "bad.obj"), dir / "bad.obj", "9");
}

TEST(MeshIoBadInput, ObjWithoutFaces) {
    TempDir dir;
    writeText(dir / "points.obj", "v 0 0 0\nv 1 0 0\n");
    expectError(readMesh(dir / "points.obj"), dir / "points.obj", "contains no triangles");
}

}  // namespace
}  // namespace commonlight

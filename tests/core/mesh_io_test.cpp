#include "core/mesh_io.h"

#include <cstring>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include <Eigen/Geometry>
#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

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

// A textured unit quad: positions, normals, TEXCOORD_0 (u along x, v down from the top edge, as
// glTF has it) and indices in an embedded buffer; one material (baseColorFactor and a base colour
// texture whose image is `image_uri`), a sampler that clamps.
std::string texturedQuad(const std::string& image_uri, const std::string& factor = "[0.5, 1.0, 0.25, 1.0]",
                         const std::string& extra_images = "") {
    std::vector<std::uint8_t> bytes;
    append(bytes, std::vector<float>{0, 0, 0, 1, 0, 0, 0, 1, 0, 1, 1, 0});
    append(bytes, std::vector<float>{0, 0, 1, 0, 0, 1, 0, 0, 1, 0, 0, 1});
    append(bytes, std::vector<float>{0, 1, 1, 1, 0, 0, 1, 0});
    append(bytes, std::vector<std::uint16_t>{0, 1, 2, 2, 1, 3});
    return std::string(R"({"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
"meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2}, "indices": 3, "material": 0}]}],
"materials": [{"name": "painted", "pbrMetallicRoughness": {"baseColorFactor": )") + factor + R"(, "baseColorTexture": {"index": 0}}}],
"textures": [{"source": 0, "sampler": 0}], "samplers": [{"wrapS": 33071, "wrapT": 33071}],
"images": [{"uri": ")" + image_uri + "\"}" + extra_images + R"(],
"buffers": [{"byteLength": )" + std::to_string(bytes.size()) + R"(, "uri": "data:application/octet-stream;base64,)" + base64(bytes) + R"("}],
"bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 48}, {"buffer": 0, "byteOffset": 48, "byteLength": 48},
                {"buffer": 0, "byteOffset": 96, "byteLength": 32}, {"buffer": 0, "byteOffset": 128, "byteLength": 12}],
"accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3"},
              {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"},
              {"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC2"},
              {"bufferView": 3, "componentType": 5123, "count": 6, "type": "SCALAR"}]})";
}

// A 2 x 2 PNG: top row red, green; bottom row blue, white (RGB).
void writeCheckerPng(const std::filesystem::path& file) {
    cv::Mat bgr(2, 2, CV_8UC3);
    bgr.at<cv::Vec3b>(0, 0) = {0, 0, 255};
    bgr.at<cv::Vec3b>(0, 1) = {0, 255, 0};
    bgr.at<cv::Vec3b>(1, 0) = {255, 0, 0};
    bgr.at<cv::Vec3b>(1, 1) = {255, 255, 255};
    ASSERT_TRUE(cv::imwrite(file.string(), bgr));
}

void expectChecker(const MeshMaterial& m) {
    ASSERT_TRUE(m.texture);
    ASSERT_EQ(m.texture->format(), PixelFormat::kRgba8);
    ASSERT_EQ(m.texture->width(), 2);
    ASSERT_EQ(m.texture->height(), 2);
    const auto px = [&](int x, int y) {
        const std::uint8_t* p = m.texture->view().row(y) + 4 * x;
        return Eigen::Vector4i(p[0], p[1], p[2], p[3]);
    };
    EXPECT_EQ(px(0, 0), Eigen::Vector4i(255, 0, 0, 255));  // top row first
    EXPECT_EQ(px(1, 0), Eigen::Vector4i(0, 255, 0, 255));
    EXPECT_EQ(px(0, 1), Eigen::Vector4i(0, 0, 255, 255));
    EXPECT_EQ(px(1, 1), Eigen::Vector4i(255, 255, 255, 255));
}

TEST(MeshIo, ReadsGltfBaseColourTextureAndFactor) {
    TempDir dir;
    writeCheckerPng(dir / "checker.png");
    // An image no material uses is not decoded: garbage there is no error.
    writeText(dir / "quad.gltf", texturedQuad("checker.png", "[0.5, 1.0, 0.25, 1.0]", R"(, {"uri": "unused.png"})"));
    writeText(dir / "unused.png", "not an image");
    const auto mesh = readMesh(dir / "quad.gltf");
    ASSERT_TRUE(mesh) << mesh.error().message;
    ASSERT_EQ(mesh->materials.size(), 1u);
    const MeshMaterial& m = mesh->materials[0];
    EXPECT_EQ(m.name, "painted");
    EXPECT_EQ(m.base_colour, Eigen::Vector4f(0.5f, 1.0f, 0.25f, 1.0f));
    EXPECT_FALSE(m.repeat_s);
    EXPECT_FALSE(m.repeat_t);
    EXPECT_NE(m.texture_file.find("checker.png"), std::string::npos);
    expectChecker(m);
    ASSERT_EQ(mesh->texcoords.size(), 4u);
    EXPECT_EQ(mesh->texcoords[0], Eigen::Vector2f(0, 1));  // the quad's (0, 0, 0) corner samples the image's bottom-left
    EXPECT_EQ(mesh->texcoords[3], Eigen::Vector2f(1, 0));
    ASSERT_EQ(mesh->ranges.size(), 1u);
    EXPECT_EQ(mesh->ranges[0].first, 0u);
    EXPECT_EQ(mesh->ranges[0].count, 6u);
    EXPECT_EQ(mesh->ranges[0].material, 0);

    // The same image embedded as a data URI.
    std::ifstream in(dir / "checker.png", std::ios::binary);
    const std::vector<std::uint8_t> png((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    writeText(dir / "embedded.gltf", texturedQuad("data:image/png;base64," + base64(png)));
    const auto embedded = readMesh(dir / "embedded.gltf");
    ASSERT_TRUE(embedded) << embedded.error().message;
    ASSERT_EQ(embedded->materials.size(), 1u);
    expectChecker(embedded->materials[0]);
    EXPECT_NE(embedded->materials[0].texture_file.find("image 0 of"), std::string::npos);

    // Geometry-only files have no materials, ranges or texture coordinates.
    const auto plain = readMesh(dataDir() / "quad.gltf");
    ASSERT_TRUE(plain) << plain.error().message;
    EXPECT_TRUE(plain->materials.empty());
    EXPECT_TRUE(plain->ranges.empty());
    EXPECT_TRUE(plain->texcoords.empty());
}

TEST(MeshIo, ReadsObjMaterialsKdAndMapKd) {
    TempDir dir;
    writeCheckerPng(dir / "checker.png");
    writeText(dir / "two.mtl", "newmtl plain\nKd 0.2 0.4 0.6\n\nnewmtl painted\nKd 1 1 1\nmap_Kd checker.png\n");
    // Two quads, the painted one second in the file and first... in material order.
    writeText(dir / "two.obj",
              "mtllib two.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
              "usemtl plain\nf 1/1 2/2 3/3 4/4\nusemtl painted\nf 1/1 2/2 3/3 4/4\n");
    const auto mesh = readMesh(dir / "two.obj");
    ASSERT_TRUE(mesh) << mesh.error().message;
    ASSERT_EQ(mesh->materials.size(), 2u);
    EXPECT_EQ(mesh->materials[0].name, "plain");
    EXPECT_LT((mesh->materials[0].base_colour - Eigen::Vector4f(0.2f, 0.4f, 0.6f, 1.0f)).norm(), 1e-6f);
    EXPECT_FALSE(mesh->materials[0].texture);
    expectChecker(mesh->materials[1]);
    ASSERT_EQ(mesh->ranges.size(), 2u);
    EXPECT_EQ(mesh->ranges[0].material, 0);
    EXPECT_EQ(mesh->ranges[0].count, 6u);
    EXPECT_EQ(mesh->ranges[1].material, 1);
    EXPECT_EQ(mesh->ranges[1].first, 6u);
    ASSERT_EQ(mesh->texcoords.size(), mesh->positions.size());
    // OBJ's vt (0, 0) is the image's bottom-left corner: v flipped into glTF's convention.
    for (std::size_t i = 0; i < mesh->positions.size(); ++i) {
        EXPECT_FLOAT_EQ(mesh->texcoords[i].x(), mesh->positions[i].x());
        EXPECT_FLOAT_EQ(mesh->texcoords[i].y(), 1.0f - mesh->positions[i].y());
    }
}

TEST(MeshIoBadInput, BadTextureNamesItsFile) {
    TempDir dir;
    writeText(dir / "missing.gltf", texturedQuad("nowhere.png"));
    const auto missing = readMesh(dir / "missing.gltf");
    expectError(missing, dir / "missing.gltf", "nowhere.png' cannot be read");
    writeText(dir / "garbage.png", "these bytes are not an image");
    writeText(dir / "garbage.gltf", texturedQuad("garbage.png"));
    expectError(readMesh(dir / "garbage.gltf"), dir / "garbage.gltf", "garbage.png' cannot be decoded");
    writeText(dir / "bad.mtl", "newmtl painted\nmap_Kd garbage.png\n");
    writeText(dir / "bad.obj", "mtllib bad.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nusemtl painted\nf 1/1 2/2 3/3\n");
    expectError(readMesh(dir / "bad.obj"), dir / "bad.obj", "garbage.png' (map_Kd of material 'painted') cannot be decoded");
    writeText(dir / "gone.mtl", "newmtl painted\nmap_Kd gone.png\n");
    writeText(dir / "gone.obj", "mtllib gone.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nusemtl painted\nf 1/1 2/2 3/3\n");
    expectError(readMesh(dir / "gone.obj"), dir / "gone.obj", "gone.png' (map_Kd of material 'painted') cannot be read");
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

// Issue 14, a crafted input run through fuzz_gltf: tinygltf's own file reader took a folder for a file of 2^63
// bytes and asked for that much memory. Only regular files are read for a mesh.
TEST(MeshIoBadInput, BufferThatIsAFolder) {
    TempDir dir;
    GltfSpec spec;
    for (const char* uri : {".", "..", "/"}) {
        spec.buffer_uri = uri;
        writeText(dir / "folder.gltf", gltfJson(spec));
        expectError(readMesh(dir / "folder.gltf"), dir / "folder.gltf", std::string("File not found : ") + uri);
    }
}

// Issue 14, found by fuzz_glb: an empty .glb made tinygltf throw std::out_of_range.
TEST(MeshIoBadInput, EmptyFiles) {
    TempDir dir;
    writeText(dir / "empty.glb", "");
    expectError(readMesh(dir / "empty.glb"), dir / "empty.glb", "(missing, empty, or not a regular file)");
    writeText(dir / "empty.gltf", "");
    expectError(readMesh(dir / "empty.gltf"), dir / "empty.gltf", "(missing, empty, or not a regular file)");
    writeText(dir / "empty.obj", "");
    expectError(readMesh(dir / "empty.obj"), dir / "empty.obj", "contains no triangles");
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

// Issue 14, a crafted input run through fuzz_gltf: byteOffset + stride x (count - 1) + element wrapped around 2^64
// (count 2^57 + 1 at stride 128 gives 12 bytes), passed the check and asked for a 1.7e18-byte vector.
TEST(MeshIoBadInput, AccessorSizeThatWrapsAround) {
    TempDir dir;
    std::string json = gltfJson(GltfSpec{});
    const auto replace = [&json](const std::string& from, const std::string& to) {
        const auto at = json.find(from);
        ASSERT_NE(at, std::string::npos) << from;
        json.replace(at, from.size(), to);
    };
    replace(R"("byteOffset": 0, "byteLength": 48})", R"("byteOffset": 0, "byteLength": 48, "byteStride": 128})");
    replace(R"("componentType": 5126, "count": 4,)", R"("componentType": 5126, "count": 144115188075855873,)");
    writeText(dir / "wrap.gltf", json);
    expectError(readMesh(dir / "wrap.gltf"), dir / "wrap.gltf",
                "POSITION (accessor 0): reads past the end of its buffer (144115188075855873 elements of 12 bytes every 128");
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

// Issue 14, a crafted input run through fuzz_gltf: the node trees were walked by recursion, and 2000 nested nodes
// overflowed the stack under ASan (30000 without). Now a chain of any depth reads, in the same
// order, with the transforms of all its ancestors.
TEST(MeshIo, DeepNodeChainReads) {
    TempDir dir;
    GltfSpec spec;
    constexpr int kDepth = 50000;
    std::string nodes = "[";
    for (int i = 0; i + 1 < kDepth; ++i) nodes += R"({"translation": [0, 0, 0.0001], "children": [)" + std::to_string(i + 1) + "]},";
    nodes += R"({"mesh": 0}])";
    spec.nodes = nodes;
    writeText(dir / "deep.gltf", gltfJson(spec));
    const auto mesh = readMesh(dir / "deep.gltf");
    ASSERT_TRUE(mesh) << mesh.error().message;
    ASSERT_FALSE(mesh->positions.empty());
    // 49999 ancestors, each 0.1 mm up: the quad lies 5 m up (float sums: 1e-3 relative).
    for (const auto& p : mesh->positions) EXPECT_NEAR(p.z(), 4.9999, 5e-3);
}

// glTF nodes form trees: a node with two parents would be read twice per path (a file listing
// each child twice at every level doubles the work per level).
TEST(MeshIoBadInput, NodeWithTwoParents) {
    TempDir dir;
    GltfSpec spec;
    spec.nodes = R"([{"children": [1, 1]}, {"mesh": 0}])";
    writeText(dir / "dag.gltf", gltfJson(spec));
    expectError(readMesh(dir / "dag.gltf"), dir / "dag.gltf", "node 1 has more than one parent");
    spec.nodes = R"([{"children": [2]}, {"children": [2]}, {"mesh": 0}])";
    spec.scene_nodes = "[0, 1]";
    writeText(dir / "shared.gltf", gltfJson(spec));
    expectError(readMesh(dir / "shared.gltf"), dir / "shared.gltf", "node 2 has more than one parent");
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

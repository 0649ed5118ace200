// Triangle meshes from glTF 2.0 (.gltf, .glb) and Wavefront OBJ files, for proxy geometry of real
// objects and the shapes of virtual ones: the geometry, and the base colour of their materials
// (glTF baseColorFactor and baseColorTexture; OBJ Kd and map_Kd) with the texture coordinates it
// needs. Other material properties are not read.
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/image.h"
#include "core/result.h"

namespace commonlight {

// The base colour of a material: albedo = base_colour x the texture's colour at the surface's
// texture coordinates (both linear; the texture is stored sRGB-encoded, as files hold it).
struct MeshMaterial {
    std::string name;                                      // the file's name for the material (may be empty)
    Eigen::Vector4f base_colour = Eigen::Vector4f::Ones();  // linear RGBA: glTF baseColorFactor, OBJ Kd (alpha 1)
    std::shared_ptr<const Image> texture;                   // kRgba8, sRGB, top row first; null: none
    std::string texture_file;                               // where the texture came from (a path, or "image N of <file>")
    // Wrapping outside [0, 1] (glTF sampler): true repeats, false clamps to the edge.
    bool repeat_s = true, repeat_t = true;
};

// Triangles [first, first + count) of `indices` (counted in indices, a multiple of 3) drawn with
// materials[material]; -1: no material (the scene's albedo).
struct MeshRange {
    std::size_t first = 0;
    std::size_t count = 0;
    int material = -1;
};

// An indexed triangle list in the file's own frame (metres, as the file states them).
struct Mesh {
    std::vector<Eigen::Vector3f> positions;
    std::vector<Eigen::Vector3f> normals;  // unit, one per position, or empty when the file has none
    std::vector<std::uint32_t> indices;    // three per triangle, counter-clockwise seen from the front
    // Texture coordinates, one per position, glTF's convention ((0, 0) is the texture image's
    // top-left corner, v grows downwards; OBJ's are converted), or empty when no material has a
    // texture.
    std::vector<Eigen::Vector2f> texcoords;
    std::vector<MeshMaterial> materials;
    std::vector<MeshRange> ranges;  // in order, covering every index, when the file has materials; empty otherwise

    std::size_t triangleCount() const { return indices.size() / 3; }
};

// Reads a mesh, choosing the format by extension (case-insensitive): .gltf and .glb (glTF 2.0:
// every mesh reachable from the default scene's nodes, with node transforms applied; primitives
// must be TRIANGLES) or .obj (polygons are triangulated; materials from the .mtl files it names,
// triangles grouped by material). Base colour textures are decoded with OpenCV (PNG, JPEG and
// whatever else it reads); an image no material uses is not decoded. Errors name the file and
// what is wrong (code kBadInput; kNotFound when the mesh file does not exist); a texture that
// is missing or cannot be decoded is kBadInput naming the texture's file.
Result<Mesh> readMesh(const std::filesystem::path& file);

// The format readers behind readMesh, for files whose extension says nothing.
Result<Mesh> readGltfMesh(const std::filesystem::path& file, bool binary);
Result<Mesh> readObjMesh(const std::filesystem::path& file);

}  // namespace commonlight

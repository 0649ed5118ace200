// Triangle meshes from glTF 2.0 (.gltf, .glb) and Wavefront OBJ files, for proxy geometry of real
// objects and the shapes of virtual ones. Only geometry is read: materials and textures are not.
#pragma once

#include <cstdint>
#include <filesystem>
#include <vector>

#include <Eigen/Core>

#include "core/result.h"

namespace commonlight {

// An indexed triangle list in the file's own frame (metres, as the file states them).
struct Mesh {
    std::vector<Eigen::Vector3f> positions;
    std::vector<Eigen::Vector3f> normals;  // unit, one per position, or empty when the file has none
    std::vector<std::uint32_t> indices;    // three per triangle, counter-clockwise seen from the front
    std::vector<Eigen::Vector2f> texcoords;  // one per position (glTF convention: (0, 0) the image's top-left corner), or empty

    std::size_t triangleCount() const { return indices.size() / 3; }
};

// Reads a mesh, choosing the format by extension (case-insensitive): .gltf and .glb (glTF 2.0:
// every mesh reachable from the default scene's nodes, with node transforms applied; primitives
// must be TRIANGLES) or .obj (polygons are triangulated). Errors name the file and what is wrong
// (code kBadInput; kNotFound when the file does not exist).
Result<Mesh> readMesh(const std::filesystem::path& file);

// The format readers behind readMesh, for files whose extension says nothing.
Result<Mesh> readGltfMesh(const std::filesystem::path& file, bool binary);
Result<Mesh> readObjMesh(const std::filesystem::path& file);

}  // namespace commonlight

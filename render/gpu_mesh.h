// The compositor's meshes on the GPU: a shape of the scene (plane, box, sphere, loaded mesh) as one
// vertex array, in parts that carry the snapshot's face number (real proxies' modulation). Internal
// to render/.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "core/scene.h"
#include "render/gl_objects.h"

namespace commonlight::render {

struct Vertex {
    float p[3];   // object frame, metres
    float n[3];   // unit
    float uv[2];  // texture coordinates (glTF convention: v down the image)
};

struct MeshPart {
    int face = -1;      // the snapshot's face number, -1: not modulated
    int first = 0;      // first index
    int count = 0;
    int material = -1;  // GpuMesh::materials index, -1: the scene's albedo
};

// A mesh file's base colour on the GPU: albedo = colour x the texture (sRGB, decoded to linear by
// the GL when it is sampled).
struct GpuMaterial {
    Eigen::Vector3f colour = Eigen::Vector3f::Ones();  // linear
    GLuint texture = 0;                                // SRGB8_ALPHA8 with mipmaps, 0: none
};

struct GpuMesh {
    GLuint vao = 0, vbo = 0, ebo = 0;
    std::vector<MeshPart> parts;
    std::vector<MeshPart> shadow_parts;  // what shadow maps draw instead of `parts` (empty: `parts`)
    bool closed = false;  // a closed surface, counter-clockwise from outside (box, sphere): back faces can be culled
    std::vector<GpuMaterial> materials;
    Eigen::Vector3d bmin = Eigen::Vector3d::Constant(1e30), bmax = Eigen::Vector3d::Constant(-1e30);  // object frame
    int index_count = 0;
};

// The triangles of a shape: planes and boxes one part per face (the snapshot's face numbers: plane 0
// the front, box 0..5 = +x, -x, +y, -y, +z, -z), spheres and meshes one unmodulated part. A mesh
// shape that is not loaded gives nothing.
void buildShape(const Shape& shape, std::vector<Vertex>& vertices, std::vector<std::uint32_t>& indices, std::vector<MeshPart>& parts);

// Uploads a shape (vertex attributes 0 position, 1 normal, 2 texture coordinates) and, for a mesh
// file, its materials' base colours and textures.
GpuMesh uploadMesh(const Shape& shape);
void releaseMesh(GpuMesh& mesh);

// Draws one part (the mesh's vertex array must be bound).
void drawPart(const MeshPart& part);

}  // namespace commonlight::render

#include "render/gpu_mesh.h"

#include <cmath>
#include <cstddef>
#include <numbers>

#include <Eigen/Geometry>

namespace commonlight::render {

namespace {

void addQuad(std::vector<Vertex>& v, std::vector<std::uint32_t>& idx, const Eigen::Vector3f& c, const Eigen::Vector3f& a,
             const Eigen::Vector3f& b, const Eigen::Vector3f& n) {
    // c: centre, a and b: half extents along the two edges, counter-clockwise seen from n.
    const auto base = static_cast<std::uint32_t>(v.size());
    const Eigen::Vector3f corners[4] = {c - a - b, c + a - b, c + a + b, c - a + b};
    const float uvs[4][2] = {{0, 1}, {1, 1}, {1, 0}, {0, 0}};
    for (int k = 0; k < 4; ++k) {
        const Eigen::Vector3f& p = corners[k];
        v.push_back({{p.x(), p.y(), p.z()}, {n.x(), n.y(), n.z()}, {uvs[k][0], uvs[k][1]}});
    }
    for (std::uint32_t k : {0u, 1u, 2u, 0u, 2u, 3u}) idx.push_back(base + k);
}

// A UV sphere as one part: `rings` x `segments` quads, vertices on the sphere.
MeshPart addSphere(std::vector<Vertex>& v, std::vector<std::uint32_t>& idx, double radius, int rings, int segments) {
    const auto base = static_cast<std::uint32_t>(v.size());
    for (int i = 0; i <= rings; ++i) {
        const double theta = std::numbers::pi * i / rings;
        for (int j = 0; j <= segments; ++j) {
            const double phi = 2.0 * std::numbers::pi * j / segments;
            const Eigen::Vector3f n(static_cast<float>(std::sin(theta) * std::cos(phi)), static_cast<float>(std::sin(theta) * std::sin(phi)),
                                    static_cast<float>(std::cos(theta)));
            const Eigen::Vector3f p = n * static_cast<float>(radius);
            v.push_back({{p.x(), p.y(), p.z()}, {n.x(), n.y(), n.z()}, {static_cast<float>(j) / segments, static_cast<float>(i) / rings}});
        }
    }
    const int first = static_cast<int>(idx.size());
    for (int i = 0; i < rings; ++i) {
        for (int j = 0; j < segments; ++j) {
            const auto a = base + static_cast<std::uint32_t>(i * (segments + 1) + j);
            const auto b = a + static_cast<std::uint32_t>(segments + 1);
            for (std::uint32_t k : {a, b, a + 1, a + 1, b, b + 1}) idx.push_back(k);
        }
    }
    return MeshPart{-1, first, static_cast<int>(idx.size()) - first};
}

}  // namespace

void buildShape(const Shape& shape, std::vector<Vertex>& v, std::vector<std::uint32_t>& idx, std::vector<MeshPart>& parts) {
    if (const auto* plane = std::get_if<PlaneShape>(&shape)) {
        const int first = static_cast<int>(idx.size());
        addQuad(v, idx, Eigen::Vector3f::Zero(), Eigen::Vector3f(0.5f * static_cast<float>(plane->size.x()), 0, 0),
                Eigen::Vector3f(0, 0.5f * static_cast<float>(plane->size.y()), 0), Eigen::Vector3f::UnitZ());
        parts.push_back({0, first, 6});
    } else if (const auto* box = std::get_if<BoxShape>(&shape)) {
        const Eigen::Vector3f h = (0.5 * box->size).cast<float>();
        // Faces 0..5 = +x, -x, +y, -y, +z, -z (the snapshot's numbering).
        for (int f = 0; f < 6; ++f) {
            const int axis = f / 2;
            const float sign = f % 2 == 0 ? 1.0f : -1.0f;
            Eigen::Vector3f n = Eigen::Vector3f::Zero();
            n[axis] = sign;
            const int ua = (axis + 1) % 3, va = (axis + 2) % 3;
            Eigen::Vector3f a = Eigen::Vector3f::Zero(), b = Eigen::Vector3f::Zero();
            a[ua] = h[ua];
            b[va] = h[va] * sign;  // keeps the quad counter-clockwise seen from n
            const int first = static_cast<int>(idx.size());
            addQuad(v, idx, n.cwiseProduct(h), a, b, n);
            parts.push_back({f, first, 6});
        }
    } else if (const auto* sphere = std::get_if<SphereShape>(&shape)) {
        parts.push_back(addSphere(v, idx, sphere->radius, 24, 48));
    } else if (const auto* mesh = std::get_if<MeshShape>(&shape)) {
        if (!mesh->mesh) return;
        const Mesh& m = *mesh->mesh;
        const auto base = static_cast<std::uint32_t>(v.size());
        std::vector<Eigen::Vector3f> normals = m.normals;
        if (normals.size() != m.positions.size()) {
            // Area-weighted vertex normals from the triangles.
            normals.assign(m.positions.size(), Eigen::Vector3f::Zero());
            for (std::size_t t = 0; t + 2 < m.indices.size(); t += 3) {
                const Eigen::Vector3f& p0 = m.positions[m.indices[t]];
                const Eigen::Vector3f n = (m.positions[m.indices[t + 1]] - p0).cross(m.positions[m.indices[t + 2]] - p0);
                for (int k = 0; k < 3; ++k) normals[m.indices[t + static_cast<std::size_t>(k)]] += n;
            }
            for (Eigen::Vector3f& n : normals) n = n.norm() > 0.0f ? n.normalized() : Eigen::Vector3f::UnitZ();
        }
        const bool has_uv = m.texcoords.size() == m.positions.size();
        for (std::size_t i = 0; i < m.positions.size(); ++i) {
            const Eigen::Vector2f uv = has_uv ? m.texcoords[i] : Eigen::Vector2f::Zero();
            v.push_back({{m.positions[i].x(), m.positions[i].y(), m.positions[i].z()},
                         {normals[i].x(), normals[i].y(), normals[i].z()},
                         {uv.x(), uv.y()}});
        }
        const int first = static_cast<int>(idx.size());
        for (std::uint32_t k : m.indices) idx.push_back(base + k);
        if (m.ranges.empty()) {
            parts.push_back({-1, first, static_cast<int>(idx.size()) - first, -1});
        } else {
            for (const MeshRange& r : m.ranges) {
                parts.push_back({-1, first + static_cast<int>(r.first), static_cast<int>(r.count), r.material});
            }
        }
    }
}

GpuMesh uploadMesh(const Shape& shape) {
    std::vector<Vertex> v;
    std::vector<std::uint32_t> idx;
    GpuMesh mesh;
    buildShape(shape, v, idx, mesh.parts);
    for (const Vertex& x : v) {
        const Eigen::Vector3d p(x.p[0], x.p[1], x.p[2]);
        mesh.bmin = mesh.bmin.cwiseMin(p);
        mesh.bmax = mesh.bmax.cwiseMax(p);
    }
    mesh.index_count = static_cast<int>(idx.size());
    mesh.closed = std::holds_alternative<SphereShape>(shape) || std::holds_alternative<BoxShape>(shape);
    if (const auto* sphere = std::get_if<SphereShape>(&shape)) {
        // Shadow maps: a coarser sphere (inscribed, so the fine surface never shadows itself
        // through it); a shadow map's texel is coarser than the camera's pixel, and llvmpipe's
        // cost goes with the triangles (the sample's ball: 2304 triangles in 8 maps cost 4.5 ms).
        mesh.shadow_parts.push_back(addSphere(v, idx, sphere->radius, 12, 24));
    }
    if (const auto* file = std::get_if<MeshShape>(&shape); file && file->mesh) {
        for (const MeshMaterial& m : file->mesh->materials) {
            GpuMaterial g;
            g.colour = m.base_colour.head<3>();
            if (m.texture && m.texture->format() == PixelFormat::kRgba8) {
                g.texture = gl::newTexture();
                glBindTexture(GL_TEXTURE_2D, g.texture);
                glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
                glPixelStorei(GL_UNPACK_ROW_LENGTH, static_cast<GLint>(m.texture->stride() / 4));
                // Row 0 is the image's top row: texture coordinate v = 0, as glTF has it.
                glTexImage2D(GL_TEXTURE_2D, 0, GL_SRGB8_ALPHA8, m.texture->width(), m.texture->height(), 0, GL_RGBA, GL_UNSIGNED_BYTE,
                             m.texture->data());
                glPixelStorei(GL_UNPACK_ROW_LENGTH, 0);
                glGenerateMipmap(GL_TEXTURE_2D);
                glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR_MIPMAP_LINEAR);
                glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
                glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, m.repeat_s ? GL_REPEAT : GL_CLAMP_TO_EDGE);
                glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, m.repeat_t ? GL_REPEAT : GL_CLAMP_TO_EDGE);
            }
            mesh.materials.push_back(g);
        }
    }
    mesh.vao = gl::newVertexArray();
    mesh.vbo = gl::newBuffer();
    mesh.ebo = gl::newBuffer();
    glBindVertexArray(mesh.vao);
    glBindBuffer(GL_ARRAY_BUFFER, mesh.vbo);
    glBufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(v.size() * sizeof(Vertex)), v.data(), GL_STATIC_DRAW);
    glBindBuffer(GL_ELEMENT_ARRAY_BUFFER, mesh.ebo);
    glBufferData(GL_ELEMENT_ARRAY_BUFFER, static_cast<GLsizeiptr>(idx.size() * sizeof(std::uint32_t)), idx.data(), GL_STATIC_DRAW);
    glEnableVertexAttribArray(0);
    glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, sizeof(Vertex), reinterpret_cast<void*>(offsetof(Vertex, p)));
    glEnableVertexAttribArray(1);
    glVertexAttribPointer(1, 3, GL_FLOAT, GL_FALSE, sizeof(Vertex), reinterpret_cast<void*>(offsetof(Vertex, n)));
    glEnableVertexAttribArray(2);
    glVertexAttribPointer(2, 2, GL_FLOAT, GL_FALSE, sizeof(Vertex), reinterpret_cast<void*>(offsetof(Vertex, uv)));
    glBindVertexArray(0);
    return mesh;
}

void releaseMesh(GpuMesh& mesh) {
    for (GpuMaterial& m : mesh.materials) gl::deleteTexture(m.texture);
    gl::deleteVertexArray(mesh.vao);
    gl::deleteBuffer(mesh.vbo);
    gl::deleteBuffer(mesh.ebo);
}

void drawPart(const MeshPart& part) {
    glDrawElements(GL_TRIANGLES, part.count, GL_UNSIGNED_INT,
                   reinterpret_cast<void*>(static_cast<std::uintptr_t>(part.first) * sizeof(std::uint32_t)));
}

}  // namespace commonlight::render

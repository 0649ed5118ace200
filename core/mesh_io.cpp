#include "core/mesh_io.h"

#include <algorithm>
#include <cctype>
#include <cstring>
#include <limits>
#include <sstream>
#include <string>
#include <unordered_map>

#include <Eigen/Geometry>
#include <Eigen/LU>
// The library (libtinygltf) holds the implementation and stb_image; only declarations here.
#include <tiny_gltf.h>
#include <tiny_obj_loader.h>

namespace commonlight {

namespace {

Error meshError(const std::filesystem::path& file, const std::string& problem) {
    return Error{ErrorCode::kBadInput, file.string() + ": " + problem};
}

Result<void> checkExists(const std::filesystem::path& file) {
    std::error_code ec;
    if (!std::filesystem::exists(file, ec)) return fail(ErrorCode::kNotFound, file.string() + ": no such file");
    if (!std::filesystem::is_regular_file(file, ec)) return fail(ErrorCode::kIo, file.string() + ": not a file");
    return {};
}

// tinygltf reports several lines; one line reads better inside our messages.
std::string oneLine(std::string text) {
    while (!text.empty() && std::isspace(static_cast<unsigned char>(text.back()))) text.pop_back();
    std::replace(text.begin(), text.end(), '\n', ';');
    // JSON errors quote what they last read, which can be a whole base64 buffer.
    constexpr std::size_t kMaxLength = 240;
    if (text.size() > kMaxLength) text = text.substr(0, kMaxLength) + "...";
    return text.empty() ? std::string("unknown error") : text;
}

// Meshes need no textures: skip decoding them (and do not fail on formats stb cannot read).
bool skipImage(tinygltf::Image*, const int, std::string*, std::string*, int, int, const unsigned char*, int, void*) {
    return true;
}

const char* modeName(int mode) {
    switch (mode) {
        case TINYGLTF_MODE_POINTS:
            return "POINTS";
        case TINYGLTF_MODE_LINE:
            return "LINES";
        case TINYGLTF_MODE_LINE_LOOP:
            return "LINE_LOOP";
        case TINYGLTF_MODE_LINE_STRIP:
            return "LINE_STRIP";
        case TINYGLTF_MODE_TRIANGLE_STRIP:
            return "TRIANGLE_STRIP";
        case TINYGLTF_MODE_TRIANGLE_FAN:
            return "TRIANGLE_FAN";
        default:
            return "unknown";
    }
}

// The bytes of one accessor, checked against its buffer view and buffer.
struct AccessorView {
    const unsigned char* data = nullptr;
    std::size_t stride = 0;  // bytes from one element to the next
    std::size_t count = 0;
    int component_type = 0;
};

class GltfReader {
public:
    GltfReader(const std::filesystem::path& file, const tinygltf::Model& model)
        : file_(file), model_(model), on_path_(model.nodes.size(), 0) {}

    Result<Mesh> read() {
        // Step 1: the scene to flatten.
        int scene = model_.defaultScene;
        if (scene < 0 && !model_.scenes.empty()) scene = 0;
        if (scene < 0) return fail(meshError(file_, "glTF file has no scene (its 'scenes' list is empty)"));
        if (scene >= static_cast<int>(model_.scenes.size())) {
            return fail(meshError(file_, "default scene " + std::to_string(scene) + " does not exist"));
        }
        // Step 2: walk every node tree, accumulating world transforms.
        for (const int node : model_.scenes[static_cast<std::size_t>(scene)].nodes) {
            CL_TRY_VOID(visit(node, Eigen::Matrix4d::Identity()));
        }
        // Step 3: normals only when every primitive had them.
        if (!all_have_normals_) mesh_.normals.clear();
        if (mesh_.indices.empty()) return fail(meshError(file_, "contains no triangles"));
        return std::move(mesh_);
    }

private:
    std::string nodeName(int node) const {
        const std::string& name = model_.nodes[static_cast<std::size_t>(node)].name;
        return "node " + std::to_string(node) + (name.empty() ? "" : " '" + name + "'");
    }

    Result<void> visit(int node, const Eigen::Matrix4d& parent) {
        if (node < 0 || node >= static_cast<int>(model_.nodes.size())) {
            return fail(meshError(file_, "node index " + std::to_string(node) + " is out of range (" +
                                             std::to_string(model_.nodes.size()) + " nodes)"));
        }
        const auto index = static_cast<std::size_t>(node);
        if (on_path_[index]) return fail(meshError(file_, nodeName(node) + " is its own ancestor (a cycle)"));
        const tinygltf::Node& n = model_.nodes[index];
        const Eigen::Matrix4d world = parent * localTransform(n);
        if (!world.allFinite()) return fail(meshError(file_, nodeName(node) + " has a non-finite transform"));
        if (n.mesh >= 0) {
            if (n.mesh >= static_cast<int>(model_.meshes.size())) {
                return fail(meshError(
                    file_, nodeName(node) + " refers to mesh " + std::to_string(n.mesh) + ", which does not exist"));
            }
            const tinygltf::Mesh& mesh = model_.meshes[static_cast<std::size_t>(n.mesh)];
            for (std::size_t p = 0; p < mesh.primitives.size(); ++p) {
                const std::string where = "mesh " + std::to_string(n.mesh) +
                                          (mesh.name.empty() ? "" : " '" + mesh.name + "'") + " primitive " +
                                          std::to_string(p);
                CL_TRY_VOID(addPrimitive(mesh.primitives[p], world, where));
            }
        }
        on_path_[index] = 1;
        for (const int child : n.children) CL_TRY_VOID(visit(child, world));
        on_path_[index] = 0;
        return {};
    }

    static Eigen::Matrix4d localTransform(const tinygltf::Node& n) {
        Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
        if (n.matrix.size() == 16) {
            for (int i = 0; i < 16; ++i) m(i % 4, i / 4) = n.matrix[static_cast<std::size_t>(i)];  // column-major
            return m;
        }
        // T * R * S
        if (n.scale.size() == 3)
            m.topLeftCorner<3, 3>() = Eigen::Vector3d(n.scale[0], n.scale[1], n.scale[2]).asDiagonal();
        if (n.rotation.size() == 4) {  // x, y, z, w
            const Eigen::Quaterniond q(n.rotation[3], n.rotation[0], n.rotation[1], n.rotation[2]);
            m.topLeftCorner<3, 3>() = q.normalized().toRotationMatrix() * m.topLeftCorner<3, 3>();
        }
        if (n.translation.size() == 3)
            m.topRightCorner<3, 1>() = Eigen::Vector3d(n.translation[0], n.translation[1], n.translation[2]);
        return m;
    }

    Result<AccessorView> view(int accessor_index, int type, const std::string& what) const {
        if (accessor_index < 0 || accessor_index >= static_cast<int>(model_.accessors.size())) {
            return fail(meshError(file_, what + ": accessor " + std::to_string(accessor_index) + " does not exist"));
        }
        const tinygltf::Accessor& a = model_.accessors[static_cast<std::size_t>(accessor_index)];
        const std::string name = what + " (accessor " + std::to_string(accessor_index) + ")";
        if (a.sparse.isSparse) return fail(meshError(file_, name + ": sparse accessors are not supported"));
        if (a.type != type) return fail(meshError(file_, name + ": has the wrong element type"));
        if (a.bufferView < 0 || a.bufferView >= static_cast<int>(model_.bufferViews.size())) {
            return fail(meshError(file_, name + ": missing buffer view " + std::to_string(a.bufferView)));
        }
        const tinygltf::BufferView& bv = model_.bufferViews[static_cast<std::size_t>(a.bufferView)];
        if (bv.buffer < 0 || bv.buffer >= static_cast<int>(model_.buffers.size())) {
            return fail(meshError(file_, name + ": missing buffer " + std::to_string(bv.buffer)));
        }
        const std::vector<unsigned char>& bytes = model_.buffers[static_cast<std::size_t>(bv.buffer)].data;
        const int component_size = tinygltf::GetComponentSizeInBytes(static_cast<std::uint32_t>(a.componentType));
        const int components = tinygltf::GetNumComponentsInType(static_cast<std::uint32_t>(a.type));
        if (component_size <= 0 || components <= 0) return fail(meshError(file_, name + ": unknown component type"));
        const std::size_t element = static_cast<std::size_t>(component_size) * static_cast<std::size_t>(components);
        const std::size_t stride = bv.byteStride == 0 ? element : bv.byteStride;
        if (stride < element) return fail(meshError(file_, name + ": byteStride is smaller than an element"));
        // Hard case: every size here comes from the file; check before any byte is read.
        const std::size_t needed = a.count == 0 ? 0 : a.byteOffset + stride * (a.count - 1) + element;
        if (needed > bv.byteLength || bv.byteOffset > bytes.size() || bv.byteLength > bytes.size() - bv.byteOffset) {
            return fail(meshError(file_, name + ": reads past the end of its buffer (needs " + std::to_string(needed) +
                                             " bytes of buffer view " + std::to_string(a.bufferView) + ", which has " +
                                             std::to_string(bv.byteLength) + " of a " + std::to_string(bytes.size()) +
                                             "-byte buffer)"));
        }
        return AccessorView{bytes.data() + bv.byteOffset + a.byteOffset, stride, a.count, a.componentType};
    }

    Result<std::vector<Eigen::Vector3f>> readVec3(int accessor_index, const std::string& what) const {
        CL_TRY(const AccessorView v, view(accessor_index, TINYGLTF_TYPE_VEC3, what));
        if (v.component_type != TINYGLTF_COMPONENT_TYPE_FLOAT) {
            return fail(meshError(file_, what + ": components must be FLOAT (quantized meshes are not supported)"));
        }
        std::vector<Eigen::Vector3f> out(v.count);
        for (std::size_t i = 0; i < v.count; ++i) std::memcpy(out[i].data(), v.data + i * v.stride, 3 * sizeof(float));
        return out;
    }

    Result<std::vector<std::uint32_t>> readIndices(int accessor_index, const std::string& what) const {
        CL_TRY(const AccessorView v, view(accessor_index, TINYGLTF_TYPE_SCALAR, what));
        std::vector<std::uint32_t> out(v.count);
        for (std::size_t i = 0; i < v.count; ++i) {
            const unsigned char* p = v.data + i * v.stride;
            switch (v.component_type) {
                case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE:
                    out[i] = *p;
                    break;
                case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: {
                    std::uint16_t s = 0;
                    std::memcpy(&s, p, sizeof s);
                    out[i] = s;
                    break;
                }
                case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT:
                    std::memcpy(&out[i], p, sizeof(std::uint32_t));
                    break;
                default:
                    return fail(meshError(file_, what + ": index components must be unsigned byte, short or int"));
            }
        }
        return out;
    }

    Result<void> addPrimitive(const tinygltf::Primitive& primitive, const Eigen::Matrix4d& world,
                              const std::string& where) {
        // tinygltf leaves mode at -1 or TRIANGLES when the file does not give one (the default).
        if (primitive.mode != -1 && primitive.mode != TINYGLTF_MODE_TRIANGLES) {
            return fail(meshError(file_, where + ": mode " + modeName(primitive.mode) + " (" +
                                             std::to_string(primitive.mode) +
                                             ") is not supported, only TRIANGLES (4)"));
        }
        const auto position_it = primitive.attributes.find("POSITION");
        if (position_it == primitive.attributes.end()) {
            return fail(meshError(file_, where + ": has no POSITION attribute"));
        }
        CL_TRY(const std::vector<Eigen::Vector3f> positions, readVec3(position_it->second, where + " POSITION"));
        std::vector<Eigen::Vector3f> normals;
        if (const auto it = primitive.attributes.find("NORMAL"); it != primitive.attributes.end()) {
            CL_TRY(normals, readVec3(it->second, where + " NORMAL"));
            if (normals.size() != positions.size()) {
                return fail(meshError(file_, where + ": has " + std::to_string(normals.size()) + " normals for " +
                                                 std::to_string(positions.size()) + " positions"));
            }
        }
        std::vector<std::uint32_t> indices;
        if (primitive.indices >= 0) {
            CL_TRY(indices, readIndices(primitive.indices, where + " indices"));
        } else {
            indices.reserve(positions.size());
            for (std::size_t i = 0; i < positions.size(); ++i) indices.push_back(static_cast<std::uint32_t>(i));
        }
        if (indices.size() % 3 != 0) {
            return fail(meshError(
                file_, where + ": " + std::to_string(indices.size()) + " indices is not a whole number of triangles"));
        }
        for (std::size_t i = 0; i < indices.size(); ++i) {
            if (indices[i] >= positions.size()) {
                return fail(meshError(file_, where + ": index " + std::to_string(indices[i]) + " (entry " +
                                                 std::to_string(i) + ") is out of range: the primitive has " +
                                                 std::to_string(positions.size()) + " vertices"));
            }
        }
        if (mesh_.positions.size() + positions.size() > std::numeric_limits<std::uint32_t>::max()) {
            return fail(meshError(file_, "has more vertices than 32-bit indices can address"));
        }

        const auto base = static_cast<std::uint32_t>(mesh_.positions.size());
        const Eigen::Matrix3d linear = world.topLeftCorner<3, 3>();
        const Eigen::Vector3d offset = world.topRightCorner<3, 1>();
        for (const Eigen::Vector3f& p : positions)
            mesh_.positions.push_back((linear * p.cast<double>() + offset).cast<float>());
        if (normals.empty()) {
            all_have_normals_ = false;
        } else if (all_have_normals_) {
            // Normals transform with the inverse transpose; a degenerate (zero) normal stays zero.
            const Eigen::Matrix3d normal_matrix = linear.inverse().transpose();
            for (const Eigen::Vector3f& n : normals) {
                mesh_.normals.push_back((normal_matrix * n.cast<double>()).normalized().cast<float>());
            }
        }
        // A mirroring transform (negative determinant) turns the faces over: glTF says to flip the
        // winding so that front faces stay front faces.
        const bool mirrored = linear.determinant() < 0.0;
        for (std::size_t i = 0; i < indices.size(); i += 3) {
            mesh_.indices.push_back(base + indices[i]);
            mesh_.indices.push_back(base + indices[mirrored ? i + 2 : i + 1]);
            mesh_.indices.push_back(base + indices[mirrored ? i + 1 : i + 2]);
        }
        return {};
    }

    const std::filesystem::path& file_;
    const tinygltf::Model& model_;
    Mesh mesh_;
    bool all_have_normals_ = true;
    std::vector<std::uint8_t> on_path_;  // 1 for nodes on the current root-to-node path, to catch cycles
};

std::string lowerExtension(const std::filesystem::path& file) {
    std::string ext = file.extension().string();
    for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    return ext;
}

}  // namespace

Result<Mesh> readGltfMesh(const std::filesystem::path& file, bool binary) {
    CL_TRY_VOID(checkExists(file));
    tinygltf::TinyGLTF loader;
    loader.SetImageLoader(&skipImage, nullptr);
    tinygltf::Model model;
    std::string err;
    std::string warn;
    const bool ok = binary ? loader.LoadBinaryFromFile(&model, &err, &warn, file.string())
                           : loader.LoadASCIIFromFile(&model, &err, &warn, file.string());
    if (!ok) return fail(meshError(file, "not a valid glTF 2.0 file: " + oneLine(err)));
    return GltfReader(file, model).read();
}

Result<Mesh> readObjMesh(const std::filesystem::path& file) {
    CL_TRY_VOID(checkExists(file));
    tinyobj::ObjReaderConfig config;
    config.triangulate = true;
    config.vertex_color = false;
    tinyobj::ObjReader reader;
    if (!reader.ParseFromFile(file.string(), config)) {
        return fail(meshError(file, "not a valid OBJ file: " + oneLine(reader.Error())));
    }
    const tinyobj::attrib_t& attrib = reader.GetAttrib();
    const std::size_t vertex_count = attrib.vertices.size() / 3;
    const std::size_t normal_count = attrib.normals.size() / 3;
    const auto position = [&](std::size_t i) {
        return Eigen::Vector3f(attrib.vertices[3 * i], attrib.vertices[3 * i + 1], attrib.vertices[3 * i + 2]);
    };

    // Step 1: every corner, checked against the vertex and normal lists.
    std::vector<tinyobj::index_t> corners;
    bool all_have_normals = true;
    for (const tinyobj::shape_t& shape : reader.GetShapes()) {
        const std::string shape_name = shape.name.empty() ? std::string("shape") : "shape '" + shape.name + "'";
        const auto& faces = shape.mesh.num_face_vertices;
        std::size_t offset = 0;
        for (std::size_t f = 0; f < faces.size(); ++f) {
            if (faces[f] != 3) {
                return fail(meshError(file, shape_name + " face " + std::to_string(f) + " has " +
                                                std::to_string(faces[f]) + " vertices after triangulation"));
            }
            for (std::size_t k = 0; k < 3; ++k) {
                if (offset + k >= shape.mesh.indices.size()) {
                    return fail(meshError(file, shape_name + " has fewer indices than its faces need"));
                }
                const tinyobj::index_t corner = shape.mesh.indices[offset + k];
                if (corner.vertex_index < 0 || static_cast<std::size_t>(corner.vertex_index) >= vertex_count) {
                    return fail(meshError(file, shape_name + " face " + std::to_string(f) + " refers to vertex " +
                                                    std::to_string(corner.vertex_index + 1) + ", but the file has " +
                                                    std::to_string(vertex_count)));
                }
                if (corner.normal_index < 0) {
                    all_have_normals = false;
                } else if (static_cast<std::size_t>(corner.normal_index) >= normal_count) {
                    return fail(meshError(file, shape_name + " face " + std::to_string(f) + " refers to normal " +
                                                    std::to_string(corner.normal_index + 1) + ", but the file has " +
                                                    std::to_string(normal_count)));
                }
                corners.push_back(corner);
            }
            offset += 3;
        }
    }
    if (corners.empty()) return fail(meshError(file, "contains no triangles"));
    if (vertex_count > std::numeric_limits<std::uint32_t>::max() / 2) {
        return fail(meshError(file, "has more vertices than 32-bit indices can address"));
    }

    // Step 2: one mesh vertex per OBJ vertex, or per (vertex, normal) pair when there are normals.
    Mesh mesh;
    mesh.indices.reserve(corners.size());
    if (!all_have_normals) {
        mesh.positions.reserve(vertex_count);
        for (std::size_t i = 0; i < vertex_count; ++i) mesh.positions.push_back(position(i));
        for (const tinyobj::index_t& c : corners) mesh.indices.push_back(static_cast<std::uint32_t>(c.vertex_index));
        return mesh;
    }
    std::unordered_map<std::uint64_t, std::uint32_t> vertex_of_pair;
    for (const tinyobj::index_t& c : corners) {
        const std::uint64_t key =
            (static_cast<std::uint64_t>(c.vertex_index) << 32) | static_cast<std::uint32_t>(c.normal_index);
        auto [it, inserted] = vertex_of_pair.try_emplace(key, static_cast<std::uint32_t>(mesh.positions.size()));
        if (inserted) {
            const auto n = static_cast<std::size_t>(c.normal_index);
            const Eigen::Vector3f normal(attrib.normals[3 * n], attrib.normals[3 * n + 1], attrib.normals[3 * n + 2]);
            mesh.positions.push_back(position(static_cast<std::size_t>(c.vertex_index)));
            mesh.normals.push_back(normal.squaredNorm() > 0.0f ? normal.normalized() : normal);
        }
        mesh.indices.push_back(it->second);
    }
    return mesh;
}

Result<Mesh> readMesh(const std::filesystem::path& file) {
    const std::string ext = lowerExtension(file);
    if (ext == ".gltf") return readGltfMesh(file, false);
    if (ext == ".glb") return readGltfMesh(file, true);
    if (ext == ".obj") return readObjMesh(file);
    return fail(meshError(file, "unknown mesh format '" + ext + "' (expected .gltf, .glb or .obj)"));
}

}  // namespace commonlight

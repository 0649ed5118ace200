#include "core/mesh_io.h"

#include <algorithm>
#include <cctype>
#include <cstring>
#include <iterator>
#include <limits>
#include <map>
#include <sstream>
#include <tuple>
#include <string>
#include <unordered_map>

#include <Eigen/Geometry>
#include <Eigen/LU>
// The library (libtinygltf) holds the implementation and stb_image; only declarations here.
#include <nlohmann/json.hpp>
#include <tiny_gltf.h>
#include <tiny_obj_loader.h>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/file_util.h"
#include "core/reader_guard.h"

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

// The files a mesh names (glTF buffers and images, OBJ textures) are read only when they are
// regular files: tinygltf's own reader took a folder ("uri": ".") for a file of 2^63 bytes and
// asked for that much memory (a crafted input run through fuzz_gltf), and a device (/dev/zero)
// never ends.
bool readRegularFile(const std::filesystem::path& file, std::vector<unsigned char>& out) {
    out.clear();
    std::error_code ec;
    if (!std::filesystem::is_regular_file(file, ec)) return false;
    return static_cast<bool>(readFileInto(file, out));
}

bool regularFileExists(const std::string& path, void*) {
    std::error_code ec;
    return std::filesystem::is_regular_file(path, ec);
}

std::string samePath(const std::string& path, void*) { return path; }  // no ~ or $VAR expansion

// tinygltf reads the first bytes of what this gives without checking for them: an empty file is
// an error here (found by fuzz_glb: an empty .glb threw std::out_of_range from inside tinygltf).
bool readWholeRegularFile(std::vector<unsigned char>* out, std::string* err, const std::string& path, void*) {
    if (readRegularFile(path, *out) && !out->empty()) return true;
    if (err != nullptr) *err += "cannot read '" + path + "' (missing, empty, or not a regular file)\n";
    return false;
}

bool refuseToWrite(std::string*, const std::string&, const std::vector<unsigned char>&, void*) { return false; }

// Images are decoded only when a material's base colour uses them (decodeTexture): keep the
// encoded bytes (and do not fail on an image nothing uses).
bool keepImageBytes(tinygltf::Image* image, const int, std::string*, std::string*, int, int, const unsigned char* bytes, int size,
                    void*) {
    image->image.assign(bytes, bytes + size);
    image->width = -1;
    image->height = -1;
    image->component = 0;
    return true;
}

// An encoded image (PNG, JPEG, ...) as an RGBA8 texture, top row first, by OpenCV. `name` says
// which texture in the errors.
Result<std::shared_ptr<const Image>> decodeTexture(const std::vector<unsigned char>& bytes, const std::filesystem::path& file,
                                                   const std::string& name) {
    if (bytes.empty()) return fail(meshError(file, "base colour texture " + name + " cannot be read (missing or empty)"));
    cv::Mat decoded;
    try {
        decoded = cv::imdecode(cv::Mat(1, static_cast<int>(bytes.size()), CV_8UC1, const_cast<unsigned char*>(bytes.data())),
                               cv::IMREAD_UNCHANGED);
    } catch (const cv::Exception&) {
        decoded = cv::Mat();  // hard case: a corrupt file OpenCV throws on rather than reports
    }
    if (decoded.empty() || decoded.cols <= 0 || decoded.rows <= 0) {
        return fail(meshError(file, "base colour texture " + name + " cannot be decoded (not an image OpenCV reads)"));
    }
    if (decoded.depth() == CV_16U) decoded.convertTo(decoded, CV_8U, 1.0 / 257.0);
    if (decoded.depth() != CV_8U) return fail(meshError(file, "base colour texture " + name + " is neither 8 nor 16 bits per channel"));
    cv::Mat rgba;
    switch (decoded.channels()) {
        case 1: cv::cvtColor(decoded, rgba, cv::COLOR_GRAY2RGBA); break;
        case 3: cv::cvtColor(decoded, rgba, cv::COLOR_BGR2RGBA); break;
        case 4: cv::cvtColor(decoded, rgba, cv::COLOR_BGRA2RGBA); break;
        default: return fail(meshError(file, "base colour texture " + name + " has " + std::to_string(decoded.channels()) + " channels"));
    }
    auto image = std::make_shared<Image>(PixelFormat::kRgba8, rgba.cols, rgba.rows);
    for (int y = 0; y < rgba.rows; ++y) std::memcpy(image->mutableView().row(y), rgba.ptr(y), 4 * static_cast<std::size_t>(rgba.cols));
    return std::shared_ptr<const Image>(std::move(image));
}

// Ranges in index order with neighbours of the same material merged.
std::vector<MeshRange> mergedRanges(const std::vector<MeshRange>& ranges) {
    std::vector<MeshRange> out;
    for (const MeshRange& r : ranges) {
        if (r.count == 0) continue;
        if (!out.empty() && out.back().material == r.material && out.back().first + out.back().count == r.first) {
            out.back().count += r.count;
        } else {
            out.push_back(r);
        }
    }
    return out;
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
        : file_(file), model_(model), on_path_(model.nodes.size(), 0), visited_(model.nodes.size(), 0) {}

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
            CL_TRY_VOID(visit(node));
        }
        // Step 3: normals only when every primitive had them; texture coordinates and materials
        // only when some primitive had them.
        if (!all_have_normals_) mesh_.normals.clear();
        if (!any_texcoords_) mesh_.texcoords.clear();
        if (mesh_.materials.empty()) {
            mesh_.ranges.clear();
        } else {
            mesh_.ranges = mergedRanges(mesh_.ranges);
        }
        if (mesh_.indices.empty()) return fail(meshError(file_, "contains no triangles"));
        return std::move(mesh_);
    }

private:
    std::string nodeName(int node) const {
        const std::string& name = model_.nodes[static_cast<std::size_t>(node)].name;
        return "node " + std::to_string(node) + (name.empty() ? "" : " '" + name + "'");
    }

    // Depth first over one node tree, in the order a recursion would take, with a stack of its
    // own: a chain of nodes as deep as the file likes must not exhaust the call stack (found
    // while fuzzing: 2000 nested nodes overflowed it under ASan, 30000 without). glTF nodes form
    // strict trees (at most one parent each): a node met twice is an error, which also bounds the
    // work by the node count (a node listed twice as a child, at every level, would double it
    // per level).
    Result<void> visit(int root) {
        struct Step {
            int node;
            Eigen::Matrix4d parent;  // world transform of the parent
            bool leave;              // the node's children are done: it leaves the path
        };
        std::vector<Step> stack{{root, Eigen::Matrix4d::Identity(), false}};
        while (!stack.empty()) {
            const Step step = stack.back();
            stack.pop_back();
            const int node = step.node;
            if (step.leave) {
                on_path_[static_cast<std::size_t>(node)] = 0;
                continue;
            }
            if (node < 0 || node >= static_cast<int>(model_.nodes.size())) {
                return fail(meshError(file_, "node index " + std::to_string(node) + " is out of range (" +
                                                 std::to_string(model_.nodes.size()) + " nodes)"));
            }
            const auto index = static_cast<std::size_t>(node);
            if (on_path_[index]) return fail(meshError(file_, nodeName(node) + " is its own ancestor (a cycle)"));
            if (visited_[index]) {
                return fail(meshError(file_, nodeName(node) + " has more than one parent (glTF nodes form trees)"));
            }
            visited_[index] = 1;
            const tinygltf::Node& n = model_.nodes[index];
            const Eigen::Matrix4d world = step.parent * localTransform(n);
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
            stack.push_back({node, Eigen::Matrix4d::Identity(), true});
            for (auto child = n.children.rbegin(); child != n.children.rend(); ++child) {
                stack.push_back({*child, world, false});
            }
        }
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
        // Hard case: every size here comes from the file; check before any byte is read, and
        // without forming byteOffset + stride x (count - 1) + element, which a file can make wrap
        // around (a crafted input through fuzz_gltf: count 2^57 + 1 at stride 128 wrapped to 12
        // bytes and asked for a 1.7e18-byte vector).
        const bool view_fits = bv.byteOffset <= bytes.size() && bv.byteLength <= bytes.size() - bv.byteOffset;
        const bool elements_fit = a.count == 0 || (a.byteOffset <= bv.byteLength && element <= bv.byteLength - a.byteOffset &&
                                                   a.count - 1 <= (bv.byteLength - a.byteOffset - element) / stride);
        if (!view_fits || !elements_fit) {
            return fail(meshError(file_, name + ": reads past the end of its buffer (" + std::to_string(a.count) +
                                             " elements of " + std::to_string(element) + " bytes every " +
                                             std::to_string(stride) + " from byte " + std::to_string(a.byteOffset) +
                                             " of buffer view " + std::to_string(a.bufferView) + ", which has " +
                                             std::to_string(bv.byteLength) + " bytes of a " +
                                             std::to_string(bytes.size()) + "-byte buffer)"));
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

    // TEXCOORD_n: FLOAT, or normalized UNSIGNED_BYTE / UNSIGNED_SHORT (glTF 2.0 sec. 3.7.2.1).
    Result<std::vector<Eigen::Vector2f>> readTexcoords(int accessor_index, const std::string& what) const {
        CL_TRY(const AccessorView v, view(accessor_index, TINYGLTF_TYPE_VEC2, what));
        std::vector<Eigen::Vector2f> out(v.count);
        for (std::size_t i = 0; i < v.count; ++i) {
            const unsigned char* p = v.data + i * v.stride;
            switch (v.component_type) {
                case TINYGLTF_COMPONENT_TYPE_FLOAT: std::memcpy(out[i].data(), p, 2 * sizeof(float)); break;
                case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE: out[i] = Eigen::Vector2f(p[0], p[1]) / 255.0f; break;
                case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: {
                    std::uint16_t uv[2];
                    std::memcpy(uv, p, sizeof uv);
                    out[i] = Eigen::Vector2f(uv[0], uv[1]) / 65535.0f;
                    break;
                }
                default: return fail(meshError(file_, what + ": components must be FLOAT or normalized unsigned byte or short"));
            }
        }
        return out;
    }

    // The mesh's material for a glTF material (made at its first use, its texture decoded then).
    Result<int> material(int index, const std::string& where) {
        if (index < 0) return -1;
        if (index >= static_cast<int>(model_.materials.size())) {
            return fail(meshError(file_, where + ": material " + std::to_string(index) + " does not exist"));
        }
        if (const auto it = material_of_.find(index); it != material_of_.end()) return it->second;
        const tinygltf::Material& m = model_.materials[static_cast<std::size_t>(index)];
        const tinygltf::PbrMetallicRoughness& pbr = m.pbrMetallicRoughness;
        MeshMaterial out;
        out.name = m.name;
        if (pbr.baseColorFactor.size() == 4) {
            for (int c = 0; c < 4; ++c) out.base_colour[c] = static_cast<float>(pbr.baseColorFactor[static_cast<std::size_t>(c)]);
        }
        if (!out.base_colour.allFinite() || (out.base_colour.array() < 0.0f).any()) {
            return fail(meshError(file_, "material " + std::to_string(index) + ": baseColorFactor must be finite and not negative"));
        }
        if (pbr.baseColorTexture.index >= 0) {
            const int t = pbr.baseColorTexture.index;
            if (t >= static_cast<int>(model_.textures.size())) {
                return fail(meshError(file_, "material " + std::to_string(index) + ": texture " + std::to_string(t) + " does not exist"));
            }
            const tinygltf::Texture& texture = model_.textures[static_cast<std::size_t>(t)];
            if (texture.source < 0 || texture.source >= static_cast<int>(model_.images.size())) {
                return fail(meshError(file_, "texture " + std::to_string(t) + ": image " + std::to_string(texture.source) + " does not exist"));
            }
            const tinygltf::Image& image = model_.images[static_cast<std::size_t>(texture.source)];
            out.texture_file = !image.uri.empty() && image.uri.rfind("data:", 0) != 0
                                   ? (file_.parent_path() / image.uri).string()
                                   : "image " + std::to_string(texture.source) + " of " + file_.string();
            CL_TRY(out.texture, decodeTexture(image.image, file_, "'" + out.texture_file + "'"));
            if (texture.sampler >= 0 && texture.sampler < static_cast<int>(model_.samplers.size())) {
                const tinygltf::Sampler& sampler = model_.samplers[static_cast<std::size_t>(texture.sampler)];
                out.repeat_s = sampler.wrapS != TINYGLTF_TEXTURE_WRAP_CLAMP_TO_EDGE;
                out.repeat_t = sampler.wrapT != TINYGLTF_TEXTURE_WRAP_CLAMP_TO_EDGE;
            }
        }
        mesh_.materials.push_back(std::move(out));
        const int mesh_index = static_cast<int>(mesh_.materials.size()) - 1;
        material_of_[index] = mesh_index;
        return mesh_index;
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

        // The base colour: its material, and the texture coordinates its texture asks for.
        CL_TRY(const int material_index, material(primitive.material, where));
        std::vector<Eigen::Vector2f> texcoords(positions.size(), Eigen::Vector2f::Zero());
        if (material_index >= 0 && mesh_.materials[static_cast<std::size_t>(material_index)].texture) {
            const int set = model_.materials[static_cast<std::size_t>(primitive.material)].pbrMetallicRoughness.baseColorTexture.texCoord;
            const std::string name = "TEXCOORD_" + std::to_string(std::max(set, 0));
            const auto it = primitive.attributes.find(name);
            if (it == primitive.attributes.end()) {
                return fail(meshError(file_, where + ": its material has a base colour texture but the primitive has no " + name));
            }
            CL_TRY(texcoords, readTexcoords(it->second, where + " " + name));
            if (texcoords.size() != positions.size()) {
                return fail(meshError(file_, where + ": has " + std::to_string(texcoords.size()) + " texture coordinates for " +
                                                 std::to_string(positions.size()) + " positions"));
            }
            any_texcoords_ = true;
        }
        mesh_.texcoords.insert(mesh_.texcoords.end(), texcoords.begin(), texcoords.end());
        mesh_.ranges.push_back({mesh_.indices.size(), indices.size(), material_index});

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
    bool any_texcoords_ = false;
    std::unordered_map<int, int> material_of_;  // glTF material -> mesh_.materials index
    std::vector<std::uint8_t> on_path_;  // 1 for nodes on the current root-to-node path, to catch cycles
    std::vector<std::uint8_t> visited_;  // 1 for nodes already read: each has one parent at most
};

// tinygltf copies a GLB's first buffer (the BIN chunk) with data.at(0) after resizing it to the
// buffer's byteLength, so a byteLength of 0 (which glTF forbids: its minimum is 1) threw
// std::out_of_range from inside it (found by fuzz_glb). Every buffer's byteLength is checked in
// the JSON chunk first; what cannot be parsed here is left to tinygltf's own errors.
Result<void> checkGlbBufferLengths(const std::filesystem::path& file) {
    std::vector<unsigned char> bytes;
    if (!readRegularFile(file, bytes) || bytes.size() < 20) return {};
    std::uint32_t json_length = 0;
    std::memcpy(&json_length, bytes.data() + 12, 4);
    if (std::memcmp(bytes.data() + 16, "JSON", 4) != 0 || json_length > bytes.size() - 20) return {};
    const nlohmann::json j = nlohmann::json::parse(bytes.begin() + 20, bytes.begin() + 20 + json_length, nullptr, false);
    if (j.is_discarded() || !j.is_object()) return {};
    const auto buffers = j.find("buffers");
    if (buffers == j.end() || !buffers->is_array()) return {};
    for (std::size_t i = 0; i < buffers->size(); ++i) {
        const nlohmann::json& b = (*buffers)[i];
        if (!b.is_object()) continue;
        const auto length = b.find("byteLength");
        if (length != b.end() && length->is_number() && !(length->get<double>() >= 1.0)) {
            return fail(meshError(file, "buffers[" + std::to_string(i) + "].byteLength must be at least 1"));
        }
    }
    return {};
}

std::string lowerExtension(const std::filesystem::path& file) {
    std::string ext = file.extension().string();
    for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    return ext;
}

}  // namespace

Result<Mesh> readGltfMesh(const std::filesystem::path& file, bool binary) {
    return guardReader(file, [&]() -> Result<Mesh> {
        CL_TRY_VOID(checkExists(file));
        if (binary) CL_TRY_VOID(checkGlbBufferLengths(file));
        tinygltf::TinyGLTF loader;
        loader.SetImageLoader(&keepImageBytes, nullptr);
        loader.SetFsCallbacks(tinygltf::FsCallbacks{&regularFileExists, &samePath, &readWholeRegularFile,
                                                    &refuseToWrite, nullptr});
        tinygltf::Model model;
        std::string err;
        std::string warn;
        const bool ok = binary ? loader.LoadBinaryFromFile(&model, &err, &warn, file.string())
                               : loader.LoadASCIIFromFile(&model, &err, &warn, file.string());
        if (!ok) return fail(meshError(file, "not a valid glTF 2.0 file: " + oneLine(err)));
        return GltfReader(file, model).read();
    });
}

Result<Mesh> readObjMesh(const std::filesystem::path& file) {
    return guardReader(file, [&]() -> Result<Mesh> {
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

        // Step 1: every corner, checked against the vertex, normal and texture coordinate lists; the
        // material of every triangle.
        const std::vector<tinyobj::material_t>& obj_materials = reader.GetMaterials();
        const std::size_t texcoord_count = attrib.texcoords.size() / 2;
        std::vector<tinyobj::index_t> corners;
        std::vector<int> triangle_material;
        bool all_have_normals = true;
        bool all_have_texcoords = true;
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
                    if (corner.texcoord_index < 0) {
                        all_have_texcoords = false;
                    } else if (static_cast<std::size_t>(corner.texcoord_index) >= texcoord_count) {
                        return fail(meshError(file, shape_name + " face " + std::to_string(f) + " refers to texture coordinate " +
                                                        std::to_string(corner.texcoord_index + 1) + ", but the file has " +
                                                        std::to_string(texcoord_count)));
                    }
                    corners.push_back(corner);
                }
                const int id = f < shape.mesh.material_ids.size() ? shape.mesh.material_ids[f] : -1;
                triangle_material.push_back(id >= 0 && static_cast<std::size_t>(id) < obj_materials.size() ? id : -1);
                offset += 3;
            }
        }
        if (corners.empty()) return fail(meshError(file, "contains no triangles"));
        if (vertex_count > std::numeric_limits<std::uint32_t>::max() / 2) {
            return fail(meshError(file, "has more vertices than 32-bit indices can address"));
        }

        // Step 2: the materials the triangles use (Kd, map_Kd relative to the .mtl's folder, which is the
        // OBJ's).
        Mesh mesh;
        std::vector<int> material_of(obj_materials.size(), -1);
        bool textured = false;
        for (const int id : triangle_material) {
            if (id < 0 || material_of[static_cast<std::size_t>(id)] >= 0) continue;
            const tinyobj::material_t& m = obj_materials[static_cast<std::size_t>(id)];
            MeshMaterial out;
            out.name = m.name;
            out.base_colour = Eigen::Vector4f(static_cast<float>(m.diffuse[0]), static_cast<float>(m.diffuse[1]),
                                              static_cast<float>(m.diffuse[2]), 1.0f);
            if (!out.base_colour.allFinite() || (out.base_colour.array() < 0.0f).any()) {
                return fail(meshError(file, "material '" + m.name + "': Kd must be finite and not negative"));
            }
            if (!m.diffuse_texname.empty()) {
                const std::filesystem::path texture = file.parent_path() / m.diffuse_texname;
                out.texture_file = texture.string();
                std::vector<unsigned char> bytes;
                readRegularFile(texture, bytes);  // missing, a folder or a device: no bytes
                CL_TRY(out.texture, decodeTexture(bytes, file, "'" + texture.string() + "' (map_Kd of material '" + m.name + "')"));
                textured = true;
            }
            mesh.materials.push_back(std::move(out));
            material_of[static_cast<std::size_t>(id)] = static_cast<int>(mesh.materials.size()) - 1;
        }
        const bool with_texcoords = textured && all_have_texcoords;
        if (textured && !all_have_texcoords) {
            return fail(meshError(file, "has a material with a texture (map_Kd) but faces without texture coordinates (vt)"));
        }

        // Step 3: triangles grouped by material, in file order within each (unchanged with one).
        std::vector<std::size_t> order(triangle_material.size());
        for (std::size_t t = 0; t < order.size(); ++t) order[t] = t;
        const auto materialOf = [&](std::size_t t) { return triangle_material[t] < 0 ? -1 : material_of[static_cast<std::size_t>(triangle_material[t])]; };
        std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return materialOf(a) < materialOf(b); });

        // Step 4: one mesh vertex per OBJ vertex, or per (vertex, normal, texture coordinate)
        // combination when there are normals or texture coordinates.
        mesh.indices.reserve(corners.size());
        if (!mesh.materials.empty()) {
            for (std::size_t i = 0; i < order.size(); ++i) mesh.ranges.push_back({3 * i, 3, materialOf(order[i])});
            mesh.ranges = mergedRanges(mesh.ranges);
        }
        if (!all_have_normals && !with_texcoords) {
            mesh.positions.reserve(vertex_count);
            for (std::size_t i = 0; i < vertex_count; ++i) mesh.positions.push_back(position(i));
            for (const std::size_t t : order) {
                for (std::size_t k = 0; k < 3; ++k) mesh.indices.push_back(static_cast<std::uint32_t>(corners[3 * t + k].vertex_index));
            }
            return mesh;
        }
        std::map<std::tuple<int, int, int>, std::uint32_t> vertex_of;
        for (const std::size_t t : order) {
            for (std::size_t k = 0; k < 3; ++k) {
                const tinyobj::index_t& c = corners[3 * t + k];
                const std::tuple<int, int, int> key(c.vertex_index, all_have_normals ? c.normal_index : -1, with_texcoords ? c.texcoord_index : -1);
                auto [it, inserted] = vertex_of.try_emplace(key, static_cast<std::uint32_t>(mesh.positions.size()));
                if (inserted) {
                    mesh.positions.push_back(position(static_cast<std::size_t>(c.vertex_index)));
                    if (all_have_normals) {
                        const auto n = static_cast<std::size_t>(c.normal_index);
                        const Eigen::Vector3f normal(attrib.normals[3 * n], attrib.normals[3 * n + 1], attrib.normals[3 * n + 2]);
                        mesh.normals.push_back(normal.squaredNorm() > 0.0f ? normal.normalized() : normal);
                    }
                    if (with_texcoords) {
                        // OBJ's v grows upwards from the image's bottom row; glTF's convention has it downwards from the top.
                        const auto i = static_cast<std::size_t>(c.texcoord_index);
                        mesh.texcoords.emplace_back(attrib.texcoords[2 * i], 1.0f - attrib.texcoords[2 * i + 1]);
                    }
                }
                mesh.indices.push_back(it->second);
            }
        }
        return mesh;
    });
}

Result<Mesh> readMesh(const std::filesystem::path& file) {
    const std::string ext = lowerExtension(file);
    if (ext == ".gltf") return readGltfMesh(file, false);
    if (ext == ".glb") return readGltfMesh(file, true);
    if (ext == ".obj") return readObjMesh(file);
    return fail(meshError(file, "unknown mesh format '" + ext + "' (expected .gltf, .glb or .obj)"));
}

}  // namespace commonlight

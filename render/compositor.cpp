#include "render/compositor.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <map>
#include <numbers>
#include <string>
#include <utility>

#include <Eigen/Geometry>

#include "render/gl_objects.h"

namespace commonlight::render {

const char* debugViewName(DebugView view) {
    switch (view) {
        case DebugView::kNone: return "composite";
        case DebugView::kProxyWireframe: return "proxies (wireframe)";
        case DebugView::kElements: return "elements (radiosity of the real scene)";
        case DebugView::kRatio: return "ratio B/B~";
        case DebugView::kTags: return "tag detections";
    }
    return "?";
}

DebugView nextDebugView(DebugView view) {
    switch (view) {
        case DebugView::kNone: return DebugView::kProxyWireframe;
        case DebugView::kProxyWireframe: return DebugView::kElements;
        case DebugView::kElements: return DebugView::kRatio;
        case DebugView::kRatio: return DebugView::kTags;
        case DebugView::kTags: return DebugView::kNone;
    }
    return DebugView::kNone;
}

namespace {

constexpr int kMaxLightSamples = 16;
constexpr int kForwardLutSize = 4096;

// ---------------------------------------------------------------------------------------------
// Shaders (GLSL 3.30 core).

const char* kShadowVs = R"(#version 330 core
layout(location = 0) in vec3 a_position;
uniform mat4 u_model;
uniform mat4 u_view_proj;
void main() { gl_Position = u_view_proj * u_model * vec4(a_position, 1.0); }
)";
const char* kShadowFs = R"(#version 330 core
void main() {}
)";

const char* kSceneVs = R"(#version 330 core
layout(location = 0) in vec3 a_position;
layout(location = 1) in vec3 a_normal;
uniform mat4 u_model;
uniform mat4 u_view_proj;
out vec3 v_world;
out vec3 v_normal;
void main() {
    vec4 world = u_model * vec4(a_position, 1.0);
    v_world = world.xyz;
    v_normal = mat3(u_model) * a_normal;
    gl_Position = u_view_proj * world;
}
)";

// Real proxies: the background's modulation at this face (M, D), or nothing (M = 1, D = 0).
const char* kProxyFs = R"(#version 330 core
in vec3 v_world;
in vec3 v_normal;
layout(location = 0) out vec4 o_virtual;
layout(location = 1) out vec4 o_m;
layout(location = 2) out vec4 o_d;
uniform int u_has_mod;
uniform vec3 u_c0;
uniform vec3 u_du;
uniform vec3 u_dv;
uniform sampler2D u_mod_m;
uniform sampler2D u_mod_d;
uniform sampler2D u_mod_o;
uniform int u_show_original;   // debug: the model's B~ in the virtual layer
uniform float u_inv_exposure;  // 1 / (exposure x gain)
void main() {
    o_virtual = vec4(0.0);
    o_m = vec4(1.0);
    o_d = vec4(0.0);
    if (u_has_mod == 0) return;
    vec3 p = v_world - u_c0;
    vec2 st = vec2(dot(p, u_du), dot(p, u_dv));
    o_m = vec4(texture(u_mod_m, st).rgb, 1.0);
    o_d = vec4(texture(u_mod_d, st).rgb, 0.0);
    if (u_show_original != 0) o_virtual = vec4(texture(u_mod_o, st).rgb, 1.0);
}
)";

// Virtual objects: Lambertian, direct light with shadow maps, the snapshot's indirect SH
// irradiance, emission. Linear relative radiance.
const char* kVirtualFs = R"(#version 330 core
in vec3 v_world;
in vec3 v_normal;
layout(location = 0) out vec4 o_virtual;
layout(location = 1) out vec4 o_m;
layout(location = 2) out vec4 o_d;
const int kMaxSamples = 16;
uniform vec3 u_albedo;
uniform vec3 u_emission;        // relative radiance
uniform vec3 u_ambient;         // relative irradiance (fallback when nothing was estimated)
uniform vec3 u_camera_centre;   // world
uniform int u_samples;
uniform int u_kind[kMaxSamples];       // 0: a point of an area light (cosine at the light), 1: point light, 2: directional
uniform vec3 u_position[kMaxSamples];
uniform vec3 u_axis[kMaxSamples];      // area: the emitting normal; directional: the direction light travels
uniform vec3 u_power[kMaxSamples];     // relative: L A / n, I, or E
uniform int u_shadow_layer[kMaxSamples];  // -1: no shadow map
uniform mat4 u_shadow_vp[kMaxSamples];
uniform sampler2DArrayShadow u_shadow_maps;
uniform int u_has_sh;
uniform ivec3 u_dims;
uniform vec3 u_bmin;
uniform vec3 u_bmax;
uniform sampler2D u_sh;  // width 9 (coefficients), one row per probe; RGB

float visibility(int i, vec3 world, vec3 n) {
    if (u_shadow_layer[i] < 0) return 1.0;
    vec4 clip = u_shadow_vp[i] * vec4(world + n * 0.002, 1.0);
    if (clip.w <= 0.0) return 1.0;
    vec3 ndc = clip.xyz / clip.w;
    vec3 uvz = ndc * 0.5 + 0.5;
    if (any(lessThan(uvz.xy, vec2(0.0))) || any(greaterThan(uvz.xy, vec2(1.0))) || uvz.z > 1.0) return 1.0;
    return texture(u_shadow_maps, vec4(uvz.xy, float(u_shadow_layer[i]), uvz.z - 0.0005));
}

vec3 probe(int index, vec3 n) {
    float basis[9] = float[9](0.282095, 0.488603 * n.y, 0.488603 * n.z, 0.488603 * n.x, 1.092548 * n.x * n.y,
                              1.092548 * n.y * n.z, 0.315392 * (3.0 * n.z * n.z - 1.0), 1.092548 * n.x * n.z,
                              0.546274 * (n.x * n.x - n.y * n.y));
    vec3 e = vec3(0.0);
    for (int k = 0; k < 9; ++k) e += texelFetch(u_sh, ivec2(k, index), 0).rgb * basis[k];
    return e;
}

vec3 indirect(vec3 world, vec3 n) {
    if (u_has_sh == 0) return vec3(0.0);
    vec3 extent = max(u_bmax - u_bmin, vec3(1e-6));
    vec3 g = clamp((world - u_bmin) / extent, 0.0, 1.0) * vec3(max(u_dims - 1, ivec3(0)));
    ivec3 i0 = ivec3(floor(g));
    ivec3 i1 = min(i0 + 1, u_dims - 1);
    vec3 f = g - vec3(i0);
    vec3 e = vec3(0.0);
    for (int c = 0; c < 8; ++c) {
        ivec3 pick = ivec3(c & 1, (c >> 1) & 1, (c >> 2) & 1);
        ivec3 idx = ivec3(mix(vec3(i0), vec3(i1), vec3(pick)) + 0.5);
        vec3 w3 = mix(1.0 - f, f, vec3(pick));
        float w = w3.x * w3.y * w3.z;
        if (w > 0.0) e += w * probe(idx.x + u_dims.x * (idx.y + u_dims.y * idx.z), n);
    }
    return max(e, vec3(0.0));
}

void main() {
    vec3 n = normalize(v_normal);
    // Two-sided: a face seen from behind is lit on the side the camera sees.
    if (dot(n, u_camera_centre - v_world) < 0.0) n = -n;
    vec3 e = u_ambient + indirect(v_world, n);
    for (int i = 0; i < u_samples; ++i) {
        vec3 irradiance;
        if (u_kind[i] == 2) {
            irradiance = u_power[i] * max(dot(n, -u_axis[i]), 0.0);
        } else {
            vec3 to_light = u_position[i] - v_world;
            float d2 = max(dot(to_light, to_light), 1e-4);
            vec3 l = to_light * inversesqrt(d2);
            float cos_r = max(dot(n, l), 0.0);
            float cos_l = u_kind[i] == 0 ? max(dot(u_axis[i], -l), 0.0) : 1.0;
            irradiance = u_power[i] * cos_r * cos_l / d2;
        }
        if (any(greaterThan(irradiance, vec3(0.0)))) irradiance *= visibility(i, v_world, n);
        e += irradiance;
    }
    o_virtual = vec4(u_albedo / 3.14159265 * e + u_emission, 1.0);
    o_m = vec4(1.0);
    o_d = vec4(0.0);
}
)";

// Debug lines (wireframe of the proxies): a constant colour in the virtual layer.
const char* kLineFs = R"(#version 330 core
in vec3 v_world;
in vec3 v_normal;
layout(location = 0) out vec4 o_virtual;
layout(location = 1) out vec4 o_m;
layout(location = 2) out vec4 o_d;
uniform vec3 u_colour;
void main() { o_virtual = vec4(u_colour, 1.0); o_m = vec4(1.0); o_d = vec4(0.0); }
)";

const char* kFinalVs = R"(#version 330 core
void main() {
    vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
    gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}
)";

// At each camera pixel: the frame's code, the layer at the undistorted position, the
// differential combination, the camera's response.
const char* kFinalFs = R"(#version 330 core
out vec4 o_colour;
uniform sampler2D u_frame;       // RGB8, row 0 = the image's top row
uniform sampler2D u_undistort;   // RG32F: the ideal pixel of each camera pixel, same rows
uniform sampler2D u_layer_v;     // the 3D layer, GL orientation (row 0 = bottom)
uniform sampler2D u_layer_m;
uniform sampler2D u_layer_d;
uniform sampler2D u_to_linear;   // 256 x 1 RGB32F
uniform sampler2D u_to_code;     // 4096 x 1 RGB32F, index sqrt(linear) x 4095 -> encoded [0, 1]
uniform float u_exposure_gain;
uniform vec2 u_size;
uniform int u_view;              // 0 composite, 3 ratio
float encode(float linear, int c) {
    float x = sqrt(clamp(linear, 0.0, 1.0)) * 4095.0;
    float i0 = floor(x);
    float a = texelFetch(u_to_code, ivec2(int(i0), 0), 0)[c];
    float b = texelFetch(u_to_code, ivec2(min(int(i0) + 1, 4095), 0), 0)[c];
    return mix(a, b, x - i0);
}
void main() {
    ivec2 fc = ivec2(gl_FragCoord.xy);
    ivec2 pixel = ivec2(fc.x, int(u_size.y) - 1 - fc.y);
    vec3 frame = texelFetch(u_frame, pixel, 0).rgb;
    vec2 ideal = texelFetch(u_undistort, pixel, 0).xy;
    vec2 uv = vec2((ideal.x + 0.5) / u_size.x, 1.0 - (ideal.y + 0.5) / u_size.y);
    vec4 v = texture(u_layer_v, uv);
    vec3 m = texture(u_layer_m, uv).rgb;
    vec3 d = texture(u_layer_d, uv).rgb;
    if (u_view == 3) { o_colour = vec4(clamp(m * 0.5, 0.0, 1.0), 1.0); return; }
    // Nothing changes this pixel: its code, exactly.
    if (v.a < 1.0 / 1024.0 && all(lessThan(abs(m - 1.0), vec3(1e-4))) && all(lessThan(abs(d * u_exposure_gain), vec3(1e-6)))) {
        o_colour = vec4(frame, 1.0);
        return;
    }
    vec3 result;
    for (int c = 0; c < 3; ++c) {
        int code = int(frame[c] * 255.0 + 0.5);
        float linear = texelFetch(u_to_linear, ivec2(code, 0), 0)[c];
        float out_linear = (linear * m[c] + d[c] * u_exposure_gain) * (1.0 - v.a) + v[c] * u_exposure_gain;
        result[c] = floor(encode(out_linear, c) * 255.0 + 0.5) / 255.0;
    }
    o_colour = vec4(result, 1.0);
}
)";

// ---------------------------------------------------------------------------------------------
// Geometry.

struct Vertex {
    float p[3];
    float n[3];
};

struct Part {
    int face = -1;  // the snapshot's face number, -1: not modulated
    int first = 0;  // first index
    int count = 0;
};

struct GpuMesh {
    GLuint vao = 0, vbo = 0, ebo = 0;
    std::vector<Part> parts;
    Eigen::Vector3d bmin = Eigen::Vector3d::Constant(1e30), bmax = Eigen::Vector3d::Constant(-1e30);  // object frame
    int index_count = 0;
};

void addQuad(std::vector<Vertex>& v, std::vector<std::uint32_t>& idx, const Eigen::Vector3f& c, const Eigen::Vector3f& a,
             const Eigen::Vector3f& b, const Eigen::Vector3f& n) {
    // c: centre, a and b: half extents along the two edges, counter-clockwise seen from n.
    const auto base = static_cast<std::uint32_t>(v.size());
    const Eigen::Vector3f corners[4] = {c - a - b, c + a - b, c + a + b, c - a + b};
    for (const Eigen::Vector3f& p : corners) v.push_back({{p.x(), p.y(), p.z()}, {n.x(), n.y(), n.z()}});
    for (std::uint32_t k : {0u, 1u, 2u, 0u, 2u, 3u}) idx.push_back(base + k);
}

void buildShape(const Shape& shape, std::vector<Vertex>& v, std::vector<std::uint32_t>& idx, std::vector<Part>& parts) {
    if (const auto* plane = std::get_if<PlaneShape>(&shape)) {
        addQuad(v, idx, Eigen::Vector3f::Zero(), Eigen::Vector3f(0.5f * static_cast<float>(plane->size.x()), 0, 0),
                Eigen::Vector3f(0, 0.5f * static_cast<float>(plane->size.y()), 0), Eigen::Vector3f::UnitZ());
        parts.push_back({0, 0, 6});
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
        const int rings = 24, segments = 48;
        const auto base = static_cast<std::uint32_t>(v.size());
        for (int i = 0; i <= rings; ++i) {
            const double theta = std::numbers::pi * i / rings;
            for (int j = 0; j <= segments; ++j) {
                const double phi = 2.0 * std::numbers::pi * j / segments;
                const Eigen::Vector3f n(static_cast<float>(std::sin(theta) * std::cos(phi)),
                                        static_cast<float>(std::sin(theta) * std::sin(phi)), static_cast<float>(std::cos(theta)));
                const Eigen::Vector3f p = n * static_cast<float>(sphere->radius);
                v.push_back({{p.x(), p.y(), p.z()}, {n.x(), n.y(), n.z()}});
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
        parts.push_back({-1, first, static_cast<int>(idx.size()) - first});
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
        for (std::size_t i = 0; i < m.positions.size(); ++i) {
            v.push_back({{m.positions[i].x(), m.positions[i].y(), m.positions[i].z()}, {normals[i].x(), normals[i].y(), normals[i].z()}});
        }
        const int first = static_cast<int>(idx.size());
        for (std::uint32_t k : m.indices) idx.push_back(base + k);
        parts.push_back({-1, first, static_cast<int>(idx.size()) - first});
    }
}

GpuMesh upload(const Shape& shape) {
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
    mesh.vao = gl::newVertexArray();
    mesh.vbo = gl::newBuffer();
    mesh.ebo = gl::newBuffer();
    glBindVertexArray(mesh.vao);
    glBindBuffer(GL_ARRAY_BUFFER, mesh.vbo);
    glBufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(v.size() * sizeof(Vertex)), v.data(), GL_STATIC_DRAW);
    glBindBuffer(GL_ELEMENT_ARRAY_BUFFER, mesh.ebo);
    glBufferData(GL_ELEMENT_ARRAY_BUFFER, static_cast<GLsizeiptr>(idx.size() * sizeof(std::uint32_t)), idx.data(), GL_STATIC_DRAW);
    glEnableVertexAttribArray(0);
    glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, sizeof(Vertex), reinterpret_cast<void*>(0));
    glEnableVertexAttribArray(1);
    glVertexAttribPointer(1, 3, GL_FLOAT, GL_FALSE, sizeof(Vertex), reinterpret_cast<void*>(offsetof(Vertex, n)));
    glBindVertexArray(0);
    return mesh;
}

void release(GpuMesh& mesh) {
    gl::deleteVertexArray(mesh.vao);
    gl::deleteBuffer(mesh.vbo);
    gl::deleteBuffer(mesh.ebo);
}

Eigen::Matrix4f toGl(const Rigid3d& pose) {
    Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
    m.topLeftCorner<3, 3>() = pose.rotation.toRotationMatrix();
    m.topRightCorner<3, 1>() = pose.translation;
    return m.cast<float>();
}

// A look-at view matrix (GL camera: looks along -z).
Eigen::Matrix4d lookAt(const Eigen::Vector3d& eye, const Eigen::Vector3d& target) {
    const Eigen::Vector3d f = (target - eye).normalized();
    Eigen::Vector3d up = std::abs(f.z()) < 0.9 ? Eigen::Vector3d::UnitZ() : Eigen::Vector3d::UnitX();
    const Eigen::Vector3d s = f.cross(up).normalized();
    const Eigen::Vector3d u = s.cross(f);
    Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
    m.row(0).head<3>() = s;
    m.row(1).head<3>() = u;
    m.row(2).head<3>() = -f;
    m(0, 3) = -s.dot(eye);
    m(1, 3) = -u.dot(eye);
    m(2, 3) = f.dot(eye);
    return m;
}

Eigen::Matrix4d perspective(double half_angle, double near_m, double far_m) {
    const double f = 1.0 / std::tan(half_angle);
    Eigen::Matrix4d p = Eigen::Matrix4d::Zero();
    p(0, 0) = f;
    p(1, 1) = f;
    p(2, 2) = -(far_m + near_m) / (far_m - near_m);
    p(2, 3) = -2.0 * far_m * near_m / (far_m - near_m);
    p(3, 2) = -1.0;
    return p;
}

Eigen::Matrix4d orthographic(double half, double near_m, double far_m) {
    Eigen::Matrix4d p = Eigen::Matrix4d::Identity();
    p(0, 0) = 1.0 / half;
    p(1, 1) = 1.0 / half;
    p(2, 2) = -2.0 / (far_m - near_m);
    p(2, 3) = -(far_m + near_m) / (far_m - near_m);
    return p;
}

struct FaceTextures {
    GLuint m = 0, d = 0, o = 0;
    Eigen::Vector3f c0, du, dv;
};

struct LightSample {
    int kind = 0;  // 0 area point, 1 point, 2 directional
    Eigen::Vector3d position = Eigen::Vector3d::Zero();
    Eigen::Vector3d axis = Eigen::Vector3d::UnitZ();
    Eigen::Vector3d power = Eigen::Vector3d::Zero();
    int layer = -1;
    Eigen::Matrix4f view_proj = Eigen::Matrix4f::Identity();
};

GLint uniform(GLuint program, const char* name) { return glGetUniformLocation(program, name); }

void setMat4(GLuint program, const char* name, const Eigen::Matrix4f& m) {
    glUniformMatrix4fv(uniform(program, name), 1, GL_FALSE, m.data());
}
void setVec3(GLuint program, const char* name, const Eigen::Vector3f& v) { glUniform3f(uniform(program, name), v.x(), v.y(), v.z()); }

}  // namespace

// -------------------------------------------------------------------------------------------------

struct Compositor::Impl {
    GlContext* context = nullptr;
    Scene scene;
    CameraModel camera;
    ResponseCurve response;
    CompositorOptions options;
    int width = 0, height = 0;

    GLuint shadow_program = 0, proxy_program = 0, virtual_program = 0, line_program = 0, final_program = 0;
    GLuint empty_vao = 0;
    std::vector<GpuMesh> real_meshes;     // by Scene::real_objects index
    std::vector<GpuMesh> virtual_meshes;  // by Scene::virtual_objects index

    GLuint frame_texture = 0, frame_pbo = 0, undistort_texture = 0, to_linear = 0, to_code = 0;
    GLuint layer_fbo = 0, layer_rb[3] = {0, 0, 0}, layer_depth = 0;
    GLuint resolve_fbo = 0, resolve_tex[3] = {0, 0, 0};
    GLuint output_fbo = 0, output_tex = 0;
    GLuint shadow_fbo = 0, shadow_maps = 0;
    int shadow_layers = 0, shadow_size = 0, layer_samples = -1;
    std::vector<float> shadow_key;  // what the shadow maps were rendered for (light views, object poses)

    // Snapshot textures, rebuilt when the snapshot (version, lighting on/off) changes.
    std::uint64_t snapshot_version = ~0ull;
    const void* snapshot_address = nullptr;
    bool snapshot_lighting = true;
    std::map<std::pair<int, int>, FaceTextures> faces;
    std::vector<GLuint> sh_textures;  // by virtual object index (0: none)

    Result<void> makeTargets();
    void releaseTargets();
    void releaseSnapshot();
    void uploadSnapshot(const lighting::LightingSnapshot& snapshot);
    void drawParts(GLuint program, const GpuMesh& mesh, const Eigen::Matrix4f& model, bool modulated, int object_index);
};

Compositor::Compositor() : impl_(std::make_unique<Impl>()) {}

Result<void> Compositor::Impl::makeTargets() {
    GLint max_samples = 0;
    glGetIntegerv(GL_MAX_SAMPLES, &max_samples);
    GLint max_float_samples = 0;
    glGetInternalformativ(GL_RENDERBUFFER, GL_RGBA16F, GL_SAMPLES, 1, &max_float_samples);
    if (max_float_samples > 0) max_samples = std::min(max_samples, max_float_samples);
    // More samples than the GL has: the most it has (llvmpipe: 4).
    const int samples = options.msaa_samples > 1 ? std::min(options.msaa_samples, static_cast<int>(max_samples)) : 0;
    if (samples == layer_samples && layer_fbo != 0) return {};
    for (GLuint& rb : layer_rb) gl::deleteRenderbuffer(rb);
    gl::deleteRenderbuffer(layer_depth);
    gl::deleteFramebuffer(layer_fbo);
    layer_fbo = gl::newFramebuffer();
    glBindFramebuffer(GL_FRAMEBUFFER, layer_fbo);
    for (int i = 0; i < 3; ++i) {
        layer_rb[i] = gl::newRenderbuffer();
        glBindRenderbuffer(GL_RENDERBUFFER, layer_rb[i]);
        glRenderbufferStorageMultisample(GL_RENDERBUFFER, samples, GL_RGBA16F, width, height);
        glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0 + static_cast<GLenum>(i), GL_RENDERBUFFER, layer_rb[i]);
    }
    layer_depth = gl::newRenderbuffer();
    glBindRenderbuffer(GL_RENDERBUFFER, layer_depth);
    glRenderbufferStorageMultisample(GL_RENDERBUFFER, samples, GL_DEPTH_COMPONENT24, width, height);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, layer_depth);
    if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
        return fail(ErrorCode::kDevice, "render: the GL cannot make a " + std::to_string(samples) + "x multisampled float framebuffer");
    }
    layer_samples = samples;
    return {};
}

void Compositor::Impl::releaseSnapshot() {
    for (auto& [key, f] : faces) {
        gl::deleteTexture(f.m);
        gl::deleteTexture(f.d);
        gl::deleteTexture(f.o);
    }
    faces.clear();
    for (GLuint& t : sh_textures) gl::deleteTexture(t);
    sh_textures.clear();
}

void Compositor::Impl::releaseTargets() {
    for (GLuint& rb : layer_rb) gl::deleteRenderbuffer(rb);
    gl::deleteRenderbuffer(layer_depth);
    gl::deleteFramebuffer(layer_fbo);
    for (GLuint& t : resolve_tex) gl::deleteTexture(t);
    gl::deleteFramebuffer(resolve_fbo);
    gl::deleteTexture(output_tex);
    gl::deleteFramebuffer(output_fbo);
    gl::deleteTexture(shadow_maps);
    gl::deleteFramebuffer(shadow_fbo);
}

namespace {

GLuint floatTexture(int width, int height, GLenum internal, GLenum format, const float* data, GLenum filter) {
    const GLuint t = gl::newTexture();
    glBindTexture(GL_TEXTURE_2D, t);
    glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
    glTexImage2D(GL_TEXTURE_2D, 0, static_cast<GLint>(internal), width, height, 0, format, GL_FLOAT, data);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, static_cast<GLint>(filter));
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, static_cast<GLint>(filter));
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
    return t;
}

}  // namespace

void Compositor::Impl::uploadSnapshot(const lighting::LightingSnapshot& snapshot) {
    releaseSnapshot();
    snapshot_version = snapshot.version;
    snapshot_address = &snapshot;
    snapshot_lighting = options.lighting;
    if (!options.lighting) return;
    for (const lighting::FaceModulation& f : snapshot.faces) {
        if (f.width <= 0 || f.height <= 0 || f.corners.size() < 3) continue;
        const std::size_t n = static_cast<std::size_t>(f.width) * static_cast<std::size_t>(f.height);
        if (f.ratio.size() != n || f.difference.size() != n || f.original.size() != n) continue;
        std::vector<float> m(4 * n), d(4 * n), o(4 * n);
        for (std::size_t k = 0; k < n; ++k) {
            const float w = lighting::ratioWeight(lighting::luminance(f.original[k]), f.mean_original);
            for (int c = 0; c < 3; ++c) {
                const float ratio = std::isfinite(f.ratio[k][c]) ? f.ratio[k][c] : 1.0f;
                const float diff = std::isfinite(f.difference[k][c]) ? f.difference[k][c] : 0.0f;
                m[4 * k + static_cast<std::size_t>(c)] = w * ratio + (1.0f - w);
                d[4 * k + static_cast<std::size_t>(c)] = (1.0f - w) * diff;
                o[4 * k + static_cast<std::size_t>(c)] = std::isfinite(f.original[k][c]) ? f.original[k][c] : 0.0f;
            }
            m[4 * k + 3] = 1.0f;
            d[4 * k + 3] = 0.0f;
            o[4 * k + 3] = 1.0f;
        }
        // Element outlines in the debug view of B~: a darker rim on the texels at element borders.
        for (const Eigen::Vector4f& e : f.elements) {
            const int i0 = std::clamp(static_cast<int>(e[0] * static_cast<float>(f.width)), 0, f.width - 1);
            const int j0 = std::clamp(static_cast<int>(e[1] * static_cast<float>(f.height)), 0, f.height - 1);
            const int i1 = std::clamp(static_cast<int>(std::ceil(e[2] * static_cast<float>(f.width))) - 1, 0, f.width - 1);
            const int j1 = std::clamp(static_cast<int>(std::ceil(e[3] * static_cast<float>(f.height))) - 1, 0, f.height - 1);
            for (int i = i0; i <= i1; ++i) {
                for (int j : {j0, j1}) for (int c = 0; c < 3; ++c) o[4 * f.texel(i, j) + static_cast<std::size_t>(c)] *= 0.6f;
            }
            for (int j = j0; j <= j1; ++j) {
                for (int i : {i0, i1}) for (int c = 0; c < 3; ++c) o[4 * f.texel(i, j) + static_cast<std::size_t>(c)] *= 0.6f;
            }
        }
        FaceTextures t;
        t.m = floatTexture(f.width, f.height, GL_RGBA32F, GL_RGBA, m.data(), GL_LINEAR);
        t.d = floatTexture(f.width, f.height, GL_RGBA32F, GL_RGBA, d.data(), GL_LINEAR);
        t.o = floatTexture(f.width, f.height, GL_RGBA32F, GL_RGBA, o.data(), GL_NEAREST);
        // The face's parametrisation p = c0 + s e1 + t e2 inverted by its dual basis.
        const Eigen::Vector3d c0 = f.corners[0], e1 = f.corners[1] - c0, e2 = f.corners.back() - c0;
        Eigen::Matrix2d g;
        g << e1.dot(e1), e1.dot(e2), e1.dot(e2), e2.dot(e2);
        if (!(std::abs(g.determinant()) > 1e-18)) {
            gl::deleteTexture(t.m);
            gl::deleteTexture(t.d);
            gl::deleteTexture(t.o);
            continue;  // hard case: a degenerate face
        }
        const Eigen::Matrix2d gi = g.inverse();
        t.c0 = c0.cast<float>();
        t.du = (gi(0, 0) * e1 + gi(0, 1) * e2).cast<float>();
        t.dv = (gi(1, 0) * e1 + gi(1, 1) * e2).cast<float>();
        faces[{f.object_index, f.face}] = t;
    }
    sh_textures.assign(scene.virtual_objects.size(), 0);
    for (const lighting::VirtualIrradiance& v : snapshot.virtual_objects) {
        if (v.object_index < 0 || static_cast<std::size_t>(v.object_index) >= sh_textures.size()) continue;
        const std::size_t probes = static_cast<std::size_t>(v.dims.prod());
        if (probes == 0 || v.indirect.size() != probes) continue;
        std::vector<float> data(probes * 9 * 3);
        for (std::size_t p = 0; p < probes; ++p) {
            for (std::size_t k = 0; k < 9; ++k) {
                for (int c = 0; c < 3; ++c) {
                    const float x = v.indirect[p][k][c];
                    data[(p * 9 + k) * 3 + static_cast<std::size_t>(c)] = std::isfinite(x) ? x : 0.0f;
                }
            }
        }
        sh_textures[static_cast<std::size_t>(v.object_index)] =
            floatTexture(9, static_cast<int>(probes), GL_RGB32F, GL_RGB, data.data(), GL_NEAREST);
    }
}

void Compositor::Impl::drawParts(GLuint program, const GpuMesh& mesh, const Eigen::Matrix4f& model, bool modulated,
                                 int object_index) {
    setMat4(program, "u_model", model);
    glBindVertexArray(mesh.vao);
    for (const Part& part : mesh.parts) {
        if (modulated) {
            const auto it = part.face >= 0 ? faces.find({object_index, part.face}) : faces.end();
            if (it != faces.end()) {
                glUniform1i(uniform(program, "u_has_mod"), 1);
                setVec3(program, "u_c0", it->second.c0);
                setVec3(program, "u_du", it->second.du);
                setVec3(program, "u_dv", it->second.dv);
                glActiveTexture(GL_TEXTURE0);
                glBindTexture(GL_TEXTURE_2D, it->second.m);
                glActiveTexture(GL_TEXTURE1);
                glBindTexture(GL_TEXTURE_2D, it->second.d);
                glActiveTexture(GL_TEXTURE2);
                glBindTexture(GL_TEXTURE_2D, it->second.o);
            } else {
                glUniform1i(uniform(program, "u_has_mod"), 0);
            }
        }
        glDrawElements(GL_TRIANGLES, part.count, GL_UNSIGNED_INT,
                       reinterpret_cast<void*>(static_cast<std::uintptr_t>(part.first) * sizeof(std::uint32_t)));
    }
    glBindVertexArray(0);
}

Result<std::unique_ptr<Compositor>> Compositor::create(GlContext& context, const Scene& scene, const CameraModel& camera,
                                                       const ResponseCurve& response, const CompositorOptions& options) {
    if (camera.width <= 0 || camera.height <= 0) return fail(ErrorCode::kBadInput, "render: the camera has no size");
    auto compositor = std::unique_ptr<Compositor>(new Compositor());
    Impl& d = *compositor->impl_;
    d.context = &context;
    d.scene = scene;
    d.camera = camera;
    d.response = response;
    d.options = options;
    d.width = camera.width;
    d.height = camera.height;
    context.makeCurrent();
    const std::string vs = kSceneVs;
    CL_TRY(d.shadow_program, gl::newProgram("shadow", kShadowVs, kShadowFs));
    CL_TRY(d.proxy_program, gl::newProgram("proxy", vs, kProxyFs));
    CL_TRY(d.virtual_program, gl::newProgram("virtual", vs, kVirtualFs));
    CL_TRY(d.line_program, gl::newProgram("lines", vs, kLineFs));
    CL_TRY(d.final_program, gl::newProgram("final", kFinalVs, kFinalFs));
    d.empty_vao = gl::newVertexArray();
    for (const RealObject& o : scene.real_objects) d.real_meshes.push_back(upload(o.shape));
    for (const VirtualObject& o : scene.virtual_objects) d.virtual_meshes.push_back(upload(o.shape));

    // The frame, streamed through a pixel buffer.
    d.frame_texture = gl::newTexture();
    glBindTexture(GL_TEXTURE_2D, d.frame_texture);
    glTexImage2D(GL_TEXTURE_2D, 0, GL_RGB8, d.width, d.height, 0, GL_RGB, GL_UNSIGNED_BYTE, nullptr);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    d.frame_pbo = gl::newBuffer();

    // The ideal (undistorted) pixel of every camera pixel.
    std::vector<float> map(static_cast<std::size_t>(d.width) * static_cast<std::size_t>(d.height) * 2);
    for (int y = 0; y < d.height; ++y) {
        for (int x = 0; x < d.width; ++x) {
            const Eigen::Vector2d p(x, y);
            const Eigen::Vector2d ideal = camera.undistortPixel(p).value_or(p);
            const std::size_t k = (static_cast<std::size_t>(y) * static_cast<std::size_t>(d.width) + static_cast<std::size_t>(x)) * 2;
            map[k] = static_cast<float>(ideal.x());
            map[k + 1] = static_cast<float>(ideal.y());
        }
    }
    d.undistort_texture = floatTexture(d.width, d.height, GL_RG32F, GL_RG, map.data(), GL_NEAREST);

    // The camera's response both ways.
    std::vector<float> lin(256 * 3), code(kForwardLutSize * 3);
    for (int k = 0; k < 256; ++k) {
        for (int c = 0; c < 3; ++c) lin[static_cast<std::size_t>(3 * k + c)] = response.toLinear(c, static_cast<std::uint8_t>(k));
    }
    for (int k = 0; k < kForwardLutSize; ++k) {
        const double s = static_cast<double>(k) / (kForwardLutSize - 1);
        for (int c = 0; c < 3; ++c) code[static_cast<std::size_t>(3 * k + c)] = response.toEncoded(c, static_cast<float>(s * s));
    }
    d.to_linear = floatTexture(256, 1, GL_RGB32F, GL_RGB, lin.data(), GL_NEAREST);
    d.to_code = floatTexture(kForwardLutSize, 1, GL_RGB32F, GL_RGB, code.data(), GL_NEAREST);

    // Targets: the 3D layer (multisampled), its resolve, the output.
    CL_TRY_VOID(d.makeTargets());
    d.resolve_fbo = gl::newFramebuffer();
    glBindFramebuffer(GL_FRAMEBUFFER, d.resolve_fbo);
    for (int i = 0; i < 3; ++i) {
        d.resolve_tex[i] = floatTexture(d.width, d.height, GL_RGBA16F, GL_RGBA, nullptr, GL_LINEAR);
        glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0 + static_cast<GLenum>(i), GL_TEXTURE_2D, d.resolve_tex[i], 0);
    }
    if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
        return fail(ErrorCode::kDevice, "render: the GL cannot make the float resolve framebuffer");
    }
    d.output_fbo = gl::newFramebuffer();
    d.output_tex = gl::newTexture();
    glBindTexture(GL_TEXTURE_2D, d.output_tex);
    glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA8, d.width, d.height, 0, GL_RGBA, GL_UNSIGNED_BYTE, nullptr);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
    glBindFramebuffer(GL_FRAMEBUFFER, d.output_fbo);
    glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, d.output_tex, 0);
    if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
        return fail(ErrorCode::kDevice, "render: the GL cannot make the output framebuffer");
    }
    d.shadow_fbo = gl::newFramebuffer();
    glBindFramebuffer(GL_FRAMEBUFFER, 0);
    return compositor;
}

Compositor::~Compositor() {
    if (!impl_ || impl_->context == nullptr) return;
    Impl& d = *impl_;
    d.context->makeCurrent();
    d.releaseSnapshot();
    d.releaseTargets();
    for (GpuMesh& m : d.real_meshes) release(m);
    for (GpuMesh& m : d.virtual_meshes) release(m);
    gl::deleteVertexArray(d.empty_vao);
    gl::deleteTexture(d.frame_texture);
    gl::deleteBuffer(d.frame_pbo);
    gl::deleteTexture(d.undistort_texture);
    gl::deleteTexture(d.to_linear);
    gl::deleteTexture(d.to_code);
    for (GLuint* p : {&d.shadow_program, &d.proxy_program, &d.virtual_program, &d.line_program, &d.final_program}) gl::deleteProgram(*p);
}

void Compositor::setOptions(const CompositorOptions& options) { impl_->options = options; }
const CompositorOptions& Compositor::options() const noexcept { return impl_->options; }

Result<void> Compositor::draw(const FrameInput& frame, const lighting::LightingSnapshot& snapshot) {
    Impl& d = *impl_;
    if (frame.image.format != PixelFormat::kRgb8 || frame.image.width != d.width || frame.image.height != d.height ||
        frame.image.data == nullptr) {
        return fail(ErrorCode::kBadInput, "render: the frame must be RGB8 of " + std::to_string(d.width) + "x" +
                                              std::to_string(d.height) + " (got " + std::string(pixelFormatName(frame.image.format)) +
                                              " " + std::to_string(frame.image.width) + "x" + std::to_string(frame.image.height) + ")");
    }
    if (!frame.virtual_poses.empty() && frame.virtual_poses.size() != d.scene.virtual_objects.size()) {
        return fail(ErrorCode::kBadInput, "render: " + std::to_string(frame.virtual_poses.size()) + " virtual poses for " +
                                              std::to_string(d.scene.virtual_objects.size()) + " virtual objects");
    }
    d.context->makeCurrent();
    while (glGetError() != GL_NO_ERROR) {
    }  // errors left by others (the check below is for this frame's)
    CL_TRY_VOID(d.makeTargets());
    const double eg = frame.exposure_gain > 0.0 && std::isfinite(frame.exposure_gain) ? frame.exposure_gain : 1.0;
    const bool posed = frame.cam_from_world && frame.cam_from_world->isValid();

    // Step 1: the frame, through the pixel buffer (rows packed).
    const std::size_t row = static_cast<std::size_t>(d.width) * 3;
    glBindBuffer(GL_PIXEL_UNPACK_BUFFER, d.frame_pbo);
    glBufferData(GL_PIXEL_UNPACK_BUFFER, static_cast<GLsizeiptr>(row * static_cast<std::size_t>(d.height)), nullptr, GL_STREAM_DRAW);
    if (auto* dst = static_cast<std::uint8_t*>(glMapBuffer(GL_PIXEL_UNPACK_BUFFER, GL_WRITE_ONLY))) {
        for (int y = 0; y < d.height; ++y) std::memcpy(dst + row * static_cast<std::size_t>(y), frame.image.row(y), row);
        glUnmapBuffer(GL_PIXEL_UNPACK_BUFFER);
    }
    glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
    glBindTexture(GL_TEXTURE_2D, d.frame_texture);
    glTexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, d.width, d.height, GL_RGB, GL_UNSIGNED_BYTE, nullptr);
    glBindBuffer(GL_PIXEL_UNPACK_BUFFER, 0);

    if (snapshot.version != d.snapshot_version || &snapshot != d.snapshot_address || d.options.lighting != d.snapshot_lighting) {
        d.uploadSnapshot(snapshot);
    }

    // The poses of what is drawn.
    std::vector<std::optional<Eigen::Matrix4f>> virtual_model(d.scene.virtual_objects.size());
    Eigen::Vector3d vmin = Eigen::Vector3d::Constant(1e30), vmax = Eigen::Vector3d::Constant(-1e30);
    for (std::size_t i = 0; i < virtual_model.size(); ++i) {
        std::optional<Rigid3d> pose = i < frame.virtual_poses.size() ? frame.virtual_poses[i]
                                                                      : worldFromObject(d.scene.virtual_objects[i], d.scene.tags, 0.0);
        if (!pose || !pose->isValid() || d.virtual_meshes[i].index_count == 0) continue;
        virtual_model[i] = toGl(*pose);
        const GpuMesh& m = d.virtual_meshes[i];
        for (int c = 0; c < 8; ++c) {
            const Eigen::Vector3d corner((c & 1) ? m.bmax.x() : m.bmin.x(), (c & 2) ? m.bmax.y() : m.bmin.y(), (c & 4) ? m.bmax.z() : m.bmin.z());
            const Eigen::Vector3d w = pose->rotation * corner + pose->translation;
            vmin = vmin.cwiseMin(w);
            vmax = vmax.cwiseMax(w);
        }
    }
    const bool any_virtual = vmin.x() <= vmax.x();

    // Step 2: light samples and their shadow maps.
    std::vector<LightSample> samples;
    const double scale = snapshot.radiance_scale > 0.0 && std::isfinite(snapshot.radiance_scale) ? snapshot.radiance_scale : 1.0;
    const int per_area = std::clamp(d.options.area_light_samples, 1, 8);
    for (const lighting::EstimatedLight& light : snapshot.lights) {
        if (!light.emission.allFinite() || light.emission.maxCoeff() <= 0.0) continue;
        const Eigen::Vector3d power = light.emission * scale;
        const Eigen::Matrix3d r = light.world_from_object.rotation.toRotationMatrix();
        if (light.kind == lighting::LightKind::kDirectional) {
            LightSample s;
            s.kind = 2;
            s.axis = light.direction.normalized();
            s.power = power;
            samples.push_back(s);
        } else if (light.kind == lighting::LightKind::kPoint) {
            LightSample s;
            s.kind = 1;
            s.position = light.world_from_object.translation;
            s.power = power;
            samples.push_back(s);
        } else {
            const bool disc = light.kind == lighting::LightKind::kDisc;
            const double area = disc ? std::numbers::pi * light.radius * light.radius : light.size.x() * light.size.y();
            const int grid = static_cast<int>(std::ceil(std::sqrt(static_cast<double>(per_area))));
            for (int k = 0; k < per_area; ++k) {
                Eigen::Vector3d local = Eigen::Vector3d::Zero();
                if (disc) {
                    const double rr = light.radius * std::sqrt((k + 0.5) / per_area);
                    const double phi = k * 2.399963229728653;  // golden angle
                    local = Eigen::Vector3d(rr * std::cos(phi), rr * std::sin(phi), 0.0);
                } else {
                    const int gx = k % grid, gy = k / grid;
                    const int rows = (per_area + grid - 1) / grid;
                    local = Eigen::Vector3d(((gx + 0.5) / grid - 0.5) * light.size.x(), ((gy + 0.5) / rows - 0.5) * light.size.y(), 0.0);
                }
                LightSample s;
                s.kind = 0;
                s.position = light.world_from_object.rotation * local + light.world_from_object.translation;
                s.axis = r.col(2);
                s.power = power * (area / per_area);
                samples.push_back(s);
            }
        }
        if (static_cast<int>(samples.size()) >= kMaxLightSamples) break;
    }
    if (static_cast<int>(samples.size()) > kMaxLightSamples) samples.resize(kMaxLightSamples);
    const bool shade = posed && any_virtual;
    int layers = 0;
    if (shade && !samples.empty()) {
        const Eigen::Vector3d centre = 0.5 * (vmin + vmax);
        const double radius = std::max(0.5 * (vmax - vmin).norm(), 1e-3);
        for (LightSample& s : samples) {
            Eigen::Matrix4d vp;
            if (s.kind == 2) {
                const double back = radius + 10.0;
                vp = orthographic(radius * 1.05, 0.0, back + radius) * lookAt(centre - s.axis * back, centre);
            } else {
                const double dist = (centre - s.position).norm();
                if (dist > radius * 1.05) {
                    // The objects' bounding sphere, seen from the light.
                    const double half = std::asin(std::min(0.99, radius * 1.05 / dist));
                    vp = perspective(half, std::max(0.01, 0.02 * dist), dist + 2.0 * radius) * lookAt(s.position, centre);
                } else {
                    // The light is among the objects: a wide frustum along its axis (area, disc) or
                    // towards the objects (point).
                    Eigen::Vector3d axis = s.kind == 0 ? s.axis : (dist > 1e-6 ? Eigen::Vector3d(centre - s.position) : Eigen::Vector3d(-Eigen::Vector3d::UnitZ()));
                    axis.normalize();
                    vp = perspective(75.0 * std::numbers::pi / 180.0, 0.01, dist + 2.0 * radius) * lookAt(s.position, s.position + axis);
                }
            }
            s.view_proj = vp.cast<float>();
            s.layer = layers++;
        }
        const int size = std::clamp(d.options.shadow_map_size, 64, 4096);
        if (layers > d.shadow_layers || size != d.shadow_size) {
            gl::deleteTexture(d.shadow_maps);
            d.shadow_maps = gl::newTexture();
            glBindTexture(GL_TEXTURE_2D_ARRAY, d.shadow_maps);
            glTexImage3D(GL_TEXTURE_2D_ARRAY, 0, GL_DEPTH_COMPONENT24, size, size, std::max(layers, 1), 0, GL_DEPTH_COMPONENT,
                         GL_FLOAT, nullptr);
            glTexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
            glTexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
            glTexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
            glTexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
            glTexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_COMPARE_MODE, GL_COMPARE_REF_TO_TEXTURE);
            glTexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_COMPARE_FUNC, GL_LEQUAL);
            d.shadow_layers = std::max(layers, 1);
            d.shadow_size = size;
            d.shadow_key.clear();
        }
        // The maps depend only on the light samples' views and the virtual objects' poses (the real
        // proxies do not move): unchanged since the last frame, they are reused.
        std::vector<float> key;
        for (const LightSample& s : samples) key.insert(key.end(), s.view_proj.data(), s.view_proj.data() + 16);
        for (const auto& m : virtual_model) {
            if (m) key.insert(key.end(), m->data(), m->data() + 16);
            key.push_back(m ? 1.0f : 0.0f);
        }
        key.push_back(static_cast<float>(d.shadow_size));
        const bool reuse = key == d.shadow_key;
        d.shadow_key = std::move(key);
        if (!reuse) {
        glUseProgram(d.shadow_program);
        glBindFramebuffer(GL_FRAMEBUFFER, d.shadow_fbo);
        glDrawBuffer(GL_NONE);
        glReadBuffer(GL_NONE);
        glViewport(0, 0, d.shadow_size, d.shadow_size);
        glEnable(GL_DEPTH_TEST);
        glDepthFunc(GL_LESS);
        glDisable(GL_CULL_FACE);
        glEnable(GL_POLYGON_OFFSET_FILL);
        glPolygonOffset(2.0f, 4.0f);
        for (const LightSample& s : samples) {
            if (s.layer < 0) continue;
            glFramebufferTextureLayer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, d.shadow_maps, 0, s.layer);
            glClear(GL_DEPTH_BUFFER_BIT);
            setMat4(d.shadow_program, "u_view_proj", s.view_proj);
            for (std::size_t i = 0; i < d.real_meshes.size(); ++i) {
                d.drawParts(d.shadow_program, d.real_meshes[i], toGl(d.scene.real_objects[i].world_from_object), false, -1);
            }
            for (std::size_t i = 0; i < d.virtual_meshes.size(); ++i) {
                if (virtual_model[i]) d.drawParts(d.shadow_program, d.virtual_meshes[i], *virtual_model[i], false, -1);
            }
        }
        glDisable(GL_POLYGON_OFFSET_FILL);
        }
    }

    // Step 3: the 3D layer in the undistorted image.
    glBindFramebuffer(GL_FRAMEBUFFER, d.layer_fbo);
    const GLenum buffers[3] = {GL_COLOR_ATTACHMENT0, GL_COLOR_ATTACHMENT1, GL_COLOR_ATTACHMENT2};
    glDrawBuffers(3, buffers);
    glViewport(0, 0, d.width, d.height);
    for (int i = 0; i < 3; ++i) glColorMaski(static_cast<GLuint>(i), GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
    glDepthMask(GL_TRUE);
    const float clear_v[4] = {0, 0, 0, 0}, clear_m[4] = {1, 1, 1, 1}, clear_d[4] = {0, 0, 0, 0};
    glClearBufferfv(GL_COLOR, 0, clear_v);
    glClearBufferfv(GL_COLOR, 1, clear_m);
    glClearBufferfv(GL_COLOR, 2, clear_d);
    glClear(GL_DEPTH_BUFFER_BIT);
    if (posed) {
        // GL camera: x right, y up, looking along -z.
        Eigen::Matrix4d view = Eigen::Matrix4d::Identity();
        view.topLeftCorner<3, 3>() = frame.cam_from_world->rotation.toRotationMatrix();
        view.topRightCorner<3, 1>() = frame.cam_from_world->translation;
        view.row(1) *= -1.0;
        view.row(2) *= -1.0;
        const Eigen::Matrix4f view_proj = (d.camera.glProjection(0.01, 100.0) * view).cast<float>();
        const Eigen::Vector3f camera_centre = frame.cam_from_world->inverse().translation.cast<float>();
        glEnable(GL_DEPTH_TEST);
        glDepthFunc(GL_LESS);
        glDisable(GL_CULL_FACE);
        if (d.options.msaa_samples > 1) glEnable(GL_MULTISAMPLE);
        // Real proxies: depth and the background's modulation.
        glUseProgram(d.proxy_program);
        setMat4(d.proxy_program, "u_view_proj", view_proj);
        glUniform1i(uniform(d.proxy_program, "u_mod_m"), 0);
        glUniform1i(uniform(d.proxy_program, "u_mod_d"), 1);
        glUniform1i(uniform(d.proxy_program, "u_mod_o"), 2);
        glUniform1i(uniform(d.proxy_program, "u_show_original"), d.options.debug == DebugView::kElements ? 1 : 0);
        for (std::size_t i = 0; i < d.real_meshes.size(); ++i) {
            d.drawParts(d.proxy_program, d.real_meshes[i], toGl(d.scene.real_objects[i].world_from_object), true, static_cast<int>(i));
        }
        // Virtual objects: only the virtual layer is written (M and D keep the proxies' values
        // under every sample, so an antialiased edge over a proxy has no halo).
        glColorMaski(1, GL_FALSE, GL_FALSE, GL_FALSE, GL_FALSE);
        glColorMaski(2, GL_FALSE, GL_FALSE, GL_FALSE, GL_FALSE);
        if (any_virtual) {
            glUseProgram(d.virtual_program);
            const GLuint vp = d.virtual_program;
            setMat4(vp, "u_view_proj", view_proj);
            setVec3(vp, "u_camera_centre", camera_centre);
            const int n = static_cast<int>(samples.size());
            glUniform1i(uniform(vp, "u_samples"), n);
            for (int k = 0; k < n; ++k) {
                const LightSample& s = samples[static_cast<std::size_t>(k)];
                const std::string index = "[" + std::to_string(k) + "]";
                glUniform1i(uniform(vp, ("u_kind" + index).c_str()), s.kind);
                setVec3(vp, ("u_position" + index).c_str(), s.position.cast<float>());
                setVec3(vp, ("u_axis" + index).c_str(), s.axis.cast<float>());
                setVec3(vp, ("u_power" + index).c_str(), s.power.cast<float>());
                glUniform1i(uniform(vp, ("u_shadow_layer" + index).c_str()), s.layer);
                setMat4(vp, ("u_shadow_vp" + index).c_str(), s.view_proj);
            }
            glActiveTexture(GL_TEXTURE3);
            glBindTexture(GL_TEXTURE_2D_ARRAY, d.shadow_maps);
            glUniform1i(uniform(vp, "u_shadow_maps"), 3);
            glUniform1i(uniform(vp, "u_sh"), 4);
            for (std::size_t i = 0; i < d.virtual_meshes.size(); ++i) {
                if (!virtual_model[i]) continue;
                const VirtualObject& object = d.scene.virtual_objects[i];
                setVec3(vp, "u_albedo", object.material.albedo.cast<float>());
                setVec3(vp, "u_emission", (object.emission.value_or(Eigen::Vector3d::Zero()) * scale).cast<float>());
                const lighting::VirtualIrradiance* irradiance = snapshot.findVirtual(static_cast<int>(i));
                const GLuint sh = i < d.sh_textures.size() ? d.sh_textures[i] : 0;
                // With nothing estimated yet (and no light to shade with), a neutral light that
                // shows the object at mid grey.
                const bool unlit = sh == 0 && samples.empty();
                const float ambient = unlit ? static_cast<float>(std::numbers::pi * 0.18 / eg) : 0.0f;
                setVec3(vp, "u_ambient", Eigen::Vector3f::Constant(ambient));
                glUniform1i(uniform(vp, "u_has_sh"), sh != 0 ? 1 : 0);
                if (sh != 0 && irradiance) {
                    glActiveTexture(GL_TEXTURE4);
                    glBindTexture(GL_TEXTURE_2D, sh);
                    glUniform3i(uniform(vp, "u_dims"), irradiance->dims.x(), irradiance->dims.y(), irradiance->dims.z());
                    setVec3(vp, "u_bmin", irradiance->bounds_min.cast<float>());
                    setVec3(vp, "u_bmax", irradiance->bounds_max.cast<float>());
                }
                d.drawParts(vp, d.virtual_meshes[i], *virtual_model[i], false, -1);
            }
        }
        if (d.options.debug == DebugView::kProxyWireframe) {
            glUseProgram(d.line_program);
            setMat4(d.line_program, "u_view_proj", view_proj);
            setVec3(d.line_program, "u_colour", Eigen::Vector3f(0.1f, 0.9f, 0.2f) / static_cast<float>(eg));
            glDisable(GL_DEPTH_TEST);
            glPolygonMode(GL_FRONT_AND_BACK, GL_LINE);
            for (std::size_t i = 0; i < d.real_meshes.size(); ++i) {
                d.drawParts(d.line_program, d.real_meshes[i], toGl(d.scene.real_objects[i].world_from_object), false, -1);
            }
            glPolygonMode(GL_FRONT_AND_BACK, GL_FILL);
        }
        glColorMaski(1, GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
        glColorMaski(2, GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
        glDisable(GL_DEPTH_TEST);
    }
    // Resolve each attachment.
    for (int i = 0; i < 3; ++i) {
        glBindFramebuffer(GL_READ_FRAMEBUFFER, d.layer_fbo);
        glReadBuffer(buffers[i]);
        glBindFramebuffer(GL_DRAW_FRAMEBUFFER, d.resolve_fbo);
        glDrawBuffers(1, &buffers[i]);
        glBlitFramebuffer(0, 0, d.width, d.height, 0, 0, d.width, d.height, GL_COLOR_BUFFER_BIT, GL_NEAREST);
    }

    // Step 4: the final pass at each camera pixel.
    glBindFramebuffer(GL_FRAMEBUFFER, d.output_fbo);
    const GLenum out0 = GL_COLOR_ATTACHMENT0;
    glDrawBuffers(1, &out0);
    glViewport(0, 0, d.width, d.height);
    glUseProgram(d.final_program);
    const GLuint fp = d.final_program;
    const std::pair<const char*, GLuint> textures[] = {{"u_frame", d.frame_texture}, {"u_undistort", d.undistort_texture},
                                                       {"u_layer_v", d.resolve_tex[0]}, {"u_layer_m", d.resolve_tex[1]},
                                                       {"u_layer_d", d.resolve_tex[2]}, {"u_to_linear", d.to_linear},
                                                       {"u_to_code", d.to_code}};
    for (int k = 0; k < 7; ++k) {
        glActiveTexture(GL_TEXTURE0 + static_cast<GLenum>(k));
        glBindTexture(GL_TEXTURE_2D, textures[k].second);
        glUniform1i(uniform(fp, textures[k].first), k);
    }
    glUniform1f(uniform(fp, "u_exposure_gain"), static_cast<float>(eg));
    glUniform2f(uniform(fp, "u_size"), static_cast<float>(d.width), static_cast<float>(d.height));
    glUniform1i(uniform(fp, "u_view"), d.options.debug == DebugView::kRatio ? 3 : 0);
    glBindVertexArray(d.empty_vao);
    glDrawArrays(GL_TRIANGLES, 0, 3);
    glBindVertexArray(0);
    glActiveTexture(GL_TEXTURE0);

    // In a window: the composite, scaled to the window.
    if (d.context->kind() == ContextKind::kWindow) {
        int w = 0, h = 0;
        d.context->windowSize(w, h);
        glBindFramebuffer(GL_READ_FRAMEBUFFER, d.output_fbo);
        glReadBuffer(GL_COLOR_ATTACHMENT0);
        glBindFramebuffer(GL_DRAW_FRAMEBUFFER, 0);
        glDrawBuffer(GL_BACK);
        glBlitFramebuffer(0, 0, d.width, d.height, 0, 0, w, h, GL_COLOR_BUFFER_BIT, GL_LINEAR);
    }
    glBindFramebuffer(GL_FRAMEBUFFER, 0);
    const GLenum error = glGetError();
    if (error != GL_NO_ERROR) return fail(ErrorCode::kInternal, "render: GL error " + std::to_string(error) + " while compositing");
    return {};
}

Result<Image> Compositor::read() const {
    const Impl& d = *impl_;
    d.context->makeCurrent();
    std::vector<std::uint8_t> rgba(static_cast<std::size_t>(d.width) * static_cast<std::size_t>(d.height) * 4);
    glBindFramebuffer(GL_READ_FRAMEBUFFER, d.output_fbo);
    glReadBuffer(GL_COLOR_ATTACHMENT0);
    glPixelStorei(GL_PACK_ALIGNMENT, 1);
    glReadPixels(0, 0, d.width, d.height, GL_RGBA, GL_UNSIGNED_BYTE, rgba.data());
    glBindFramebuffer(GL_READ_FRAMEBUFFER, 0);
    Image out(PixelFormat::kRgb8, d.width, d.height);
    MutableImageView view = out.mutableView();
    for (int y = 0; y < d.height; ++y) {
        const std::uint8_t* src = rgba.data() + static_cast<std::size_t>(d.height - 1 - y) * static_cast<std::size_t>(d.width) * 4;
        std::uint8_t* dst = view.row(y);
        for (int x = 0; x < d.width; ++x) {
            dst[3 * x] = src[4 * x];
            dst[3 * x + 1] = src[4 * x + 1];
            dst[3 * x + 2] = src[4 * x + 2];
        }
    }
    return out;
}

}  // namespace commonlight::render

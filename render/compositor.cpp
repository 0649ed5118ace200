#include "render/compositor.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <numbers>
#include <string>
#include <utility>

#include <Eigen/Geometry>
#include <opencv2/imgproc.hpp>

#include <sys/resource.h>

#include "core/clock.h"
#include "render/ggx_albedo.h"
#include "render/gl_objects.h"
#include "render/gpu_mesh.h"
#include "render/light_samples.h"
#include "render/shaders.h"
#include "render/snapshot_textures.h"

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

constexpr int kToCodeSize = 1024;   // entries of the encoding table (index sqrt(linear)): within 0.02 codes of the response
constexpr int kBlock = 16;          // camera pixels per side of the blocks that bound the layer's footprint
constexpr float kNoIdeal = -1e6f;   // a camera pixel with no ideal position inside the layer

// Texture units of the final pass and of the virtual objects' program.
enum FinalUnit : int { kUnitFrame = 0, kUnitFrameUv, kUnitUndistort, kUnitProxyAtlas, kUnitAtlasM, kUnitAtlasD, kUnitAtlasO, kUnitLayerV };
enum VirtualUnit : int { kUnitShadowMaps = 3, kUnitSh = 4, kUnitBaseColour = 5, kUnitStaticShadowMaps = 6, kUnitGgxAlbedo = 7 };
constexpr int kGgxTableSize = 32;      // the GGX directional albedo table, per side (render/ggx_albedo.h)
constexpr int kGgxTableSamples = 256;  // visible normals per entry: within 0.5% of a 262 144-sample integral

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

GLuint byteTexture(int width, int height, GLenum internal, GLenum format) {
    const GLuint t = gl::newTexture();
    glBindTexture(GL_TEXTURE_2D, t);
    glTexImage2D(GL_TEXTURE_2D, 0, static_cast<GLint>(internal), width, height, 0, format, GL_UNSIGNED_BYTE, nullptr);
    // Nearest: integer textures are incomplete with any other filter.
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
    return t;
}

GLint loc(GLuint program, const char* name) { return glGetUniformLocation(program, name); }
void setMat4(GLint location, const Eigen::Matrix4f& m) { glUniformMatrix4fv(location, 1, GL_FALSE, m.data()); }
void setVec3(GLint location, const Eigen::Vector3f& v) { glUniform3f(location, v.x(), v.y(), v.z()); }

// Pixels [x0, x1] x [y0, y1], inclusive, in some framebuffer's GL rows.
struct Rect {
    int x0 = 0, y0 = 0, x1 = -1, y1 = -1;
    bool empty() const { return x1 < x0 || y1 < y0; }
    void scissor() const { glScissor(x0, y0, x1 - x0 + 1, y1 - y0 + 1); }
};

// The smallest rectangle around both.
Rect unite(const Rect& a, const Rect& b) {
    if (a.empty()) return b;
    if (b.empty()) return a;
    return Rect{std::min(a.x0, b.x0), std::min(a.y0, b.y0), std::max(a.x1, b.x1), std::max(a.y1, b.y1)};
}

// A closed mesh's faces turned away from the camera are hidden by its own front: not drawn (their
// fragments would be shaded and then overwritten). Open surfaces are drawn from both sides.
void cullBackFaces(const GpuMesh& mesh) {
    if (mesh.closed) {
        glEnable(GL_CULL_FACE);
        glCullFace(GL_BACK);
        glFrontFace(GL_CCW);
    } else {
        glDisable(GL_CULL_FACE);
    }
}

// A real proxy's faces turned away from the camera, when it is closed and the camera outside it
// (its bounds, 1 mm wider): hidden by its own front, not drawn. A closed proxy the camera is in (a
// room modelled as a box) is drawn from both sides, as are open ones.
void cullProxyBackFaces(const GpuMesh& mesh, const Eigen::Matrix4f& model, const Eigen::Vector3f& camera_centre) {
    bool outside = false;
    if (mesh.closed) {
        // The model is a rigid motion: its inverse is the transposed rotation.
        const Eigen::Matrix3f r = model.topLeftCorner<3, 3>();
        const Eigen::Vector3f c = r.transpose() * (camera_centre - model.topRightCorner<3, 1>());
        const Eigen::Vector3f lo = mesh.bmin.cast<float>().array() - 1e-3f, hi = mesh.bmax.cast<float>().array() + 1e-3f;
        outside = (c.array() < lo.array()).any() || (c.array() > hi.array()).any();
    }
    if (outside) {
        glEnable(GL_CULL_FACE);
        glCullFace(GL_BACK);
        glFrontFace(GL_CCW);
    } else {
        glDisable(GL_CULL_FACE);
    }
}

// Shadow maps as tiles of one depth texture, drawn in one pass (llvmpipe flushes its work at every
// change of render target).
struct ShadowAtlas {
    GLuint fbo = 0, texture = 0;
    int tiles = 0, cols = 0, rows = 0, size = 0;
    std::vector<float> key;  // what the maps were drawn for (views, poses); empty: nothing

    // Room for `n` maps of `size` texels per side (reallocated, and so to be drawn, when it grows).
    void ensure(int n, int map_size) {
        if (n <= tiles && map_size == size) return;
        rows = std::max(1, static_cast<int>(std::floor(std::sqrt(static_cast<double>(n)))));
        cols = (n + rows - 1) / rows;  // 8 maps: 4 x 2
        tiles = rows * cols;
        size = map_size;
        gl::deleteTexture(texture);
        texture = gl::newTexture();
        glBindTexture(GL_TEXTURE_2D, texture);
        glTexImage2D(GL_TEXTURE_2D, 0, GL_DEPTH_COMPONENT24, cols * size, rows * size, 0, GL_DEPTH_COMPONENT, GL_FLOAT, nullptr);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_COMPARE_MODE, GL_COMPARE_REF_TO_TEXTURE);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_COMPARE_FUNC, GL_LEQUAL);
        glBindTexture(GL_TEXTURE_2D, 0);
        if (fbo == 0) fbo = gl::newFramebuffer();
        glBindFramebuffer(GL_FRAMEBUFFER, fbo);
        glFramebufferTexture2D(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_TEXTURE_2D, texture, 0);
        glDrawBuffer(GL_NONE);
        glReadBuffer(GL_NONE);
        key.clear();
    }
    // Map `layer`'s tile in texture coordinates: offset, scale.
    Eigen::Vector4f tile(int layer) const {
        if (cols == 0) return Eigen::Vector4f::Zero();
        return Eigen::Vector4f(static_cast<float>(layer % cols) / static_cast<float>(cols), static_cast<float>(layer / cols) / static_cast<float>(rows),
                               1.0f / static_cast<float>(cols), 1.0f / static_cast<float>(rows));
    }
    void release() {
        gl::deleteTexture(texture);
        gl::deleteFramebuffer(fbo);
        *this = ShadowAtlas{};
    }
};

struct SceneProgram {  // shadow (depth only) and line programs
    GLuint id = 0;
    GLint model = -1, view_proj = -1, colour = -1, line = -1;
};

struct ProxyProgram {
    GLuint id = 0;
    GLint model = -1, view_proj = -1, has_mod = -1, c0 = -1, du = -1, dv = -1, atlas_rect = -1, clamp = -1;
};

struct VirtualProgram {
    GLuint id = 0;
    GLint model = -1, view_proj = -1, albedo = -1, emission = -1, ambient = -1, camera_centre = -1, samples = -1;
    GLint kind = -1, position = -1, axis = -1, power = -1, shadow_layer = -1, shadow_vp = -1, static_vp = -1, shadow_tile = -1, shadow_inset = -1,
          static_tile = -1, static_inset = -1;
    GLint has_sh = -1, bmin = -1, bmax = -1, sh_scale = -1, sh_offset = -1, sh_depth = -1, has_texture = -1;
    GLint roughness = -1, radius = -1;  // GGX only
};

struct FinalProgram {
    GLuint id = 0;
    GLint atlas_size = -1, layer_rect = -1, exposure_gain = -1, size = -1, noise = -1, seed = -1;
};

// The final pass's variants.
enum FinalBits : int {
    kFinalYuyv = 1,
    kFinalNv12 = 2,
    kFinalModulation = 4,
    kFinalVirtual = 8,
    kFinalElements = 16,
    kFinalRatio = 32,
    kFinalNoise = 64,
};

}  // namespace

// -------------------------------------------------------------------------------------------------

struct Compositor::Impl {
    GlContext* context = nullptr;
    Scene scene;
    CameraModel camera;
    CameraModel layer_camera;  // the undistorted pinhole of the 3D layer: camera's fx fy, a margin so every camera pixel's ideal position is inside
    Eigen::Vector2i layer_origin = Eigen::Vector2i::Zero();  // the layer's pixel (0, 0) in the camera's ideal pixels
    ResponseCurve response;
    CompositorOptions options;
    int width = 0, height = 0;              // the camera's
    int layer_width = 0, layer_height = 0;  // the layer's

    SceneProgram shadow_program, line_program, geometry_program;
    GLuint compose_program = 0;
    GLint compose_sample_count = -1;
    ProxyProgram proxy_program;
    VirtualProgram virtual_program;      // Lambertian
    VirtualProgram virtual_ggx_program;  // `material: {type: ggx}`
    GLuint ggx_albedo_texture = 0;       // RG32F (A, B) of render/ggx_albedo.h
    std::map<int, FinalProgram> final_programs;  // by FinalBits
    GLuint empty_vao = 0;
    std::vector<GpuMesh> real_meshes;     // by Scene::real_objects index
    std::vector<GpuMesh> virtual_meshes;  // by Scene::virtual_objects index
    std::vector<Eigen::Matrix4f> real_models;

    // The frame: a pixel buffer and the texture(s) of its format.
    GLuint frame_pbo = 0, frame_texture = 0, frame_uv_texture = 0;
    PixelFormat frame_format = PixelFormat::kInvalid;
    // Camera pixel -> layer texel coordinates (GL rows), and its footprint per block of pixels.
    GLuint undistort_texture = 0;
    std::vector<Eigen::Vector4f> block_bounds;  // min x, min y, max x, max y of the layer coordinates per block
    int blocks_x = 0, blocks_y = 0;
    GLuint to_linear_ubo = 0, to_code_ubo = 0;

    // Real proxies, single-sampled: the atlas coordinates of the surface at each layer pixel.
    GLuint proxy_fbo = 0, proxy_atlas = 0, proxy_depth = 0;
    // The virtual layer, drawn only in a rectangle around the virtual objects: shaded once per
    // pixel (with the proxies' depth), the geometry multisampled, composed.
    GLuint shade_fbo = 0, shade_texture = 0, shade_geometry = 0;
    GLuint layer_fbo = 0, layer_samples_texture = 0, layer_depth = 0;
    int layer_samples = -1;
    GLuint resolve_fbo = 0, resolve_texture = 0;
    GLuint layer_v = 0;  // what the final pass reads as the virtual layer this frame
    GLuint output_fbo = 0, output_texture = 0;
    // The shadow maps as tiles of one depth texture (drawn in one pass: llvmpipe flushes at every
    // change of render target, which cost more than the drawing when each map was a layer).
    // Two sets: the virtual objects' (fitted to their bounds, drawn again when they move) and the
    // real proxies' (which do not move: fitted to a sphere around the objects' 1.5 times as large,
    // kept while they move inside it).
    ShadowAtlas virtual_shadows, real_shadows;
    Eigen::Vector3d real_shadow_centre = Eigen::Vector3d::Zero();
    double real_shadow_radius = 0.0;
    SnapshotTextures snapshot_textures;

    // Camera matching: the last measurement, the frame as RGB8 when it came as YUV, the blur passes.
    std::optional<CameraMatch> match;
    std::uint64_t frames_drawn = 0;
    Image match_rgb;
    double warp_variance = 0.0;  // mean f (1 - f) of the layer's bilinear read (f: the fractional texel offset), px^2
    GLuint blur_program = 0, blur_fbo[2] = {0, 0}, blur_texture[2] = {0, 0};
    GLint blur_direction = -1, blur_radius = -1, blur_weights = -1, blur_rect = -1;

    // surfacePoints(), made at its first call.
    GLuint world_program = 0, warp_program = 0, world_fbo = 0, world_texture = 0, warp_fbo = 0, warp_texture = 0;
    GLint world_model = -1, world_view_proj = -1, world_surface = -1;

    mutable std::vector<PassTime> pass_times;
    mutable std::int64_t pass_start_ns = 0;
    mutable double pass_start_cpu = 0.0;

    // Profiling: waits for the GL and books the time since the last mark to `name`.
    void mark(const char* name) const {
        if (!options.profile) return;
        glFinish();
        const std::int64_t now = monotonicNowNs();
        rusage usage{};
        getrusage(RUSAGE_SELF, &usage);
        const double cpu = 1e3 * static_cast<double>(usage.ru_utime.tv_sec + usage.ru_stime.tv_sec) +
                           1e-3 * static_cast<double>(usage.ru_utime.tv_usec + usage.ru_stime.tv_usec);
        if (name != nullptr) pass_times.push_back({name, static_cast<double>(now - pass_start_ns) / 1e6, cpu - pass_start_cpu});
        pass_start_ns = now;
        pass_start_cpu = cpu;
    }

    Result<void> makePrograms();
    Result<void> makeVirtualProgram(VirtualProgram& vp, bool ggx);
    Result<const FinalProgram*> finalProgram(int bits);
    Result<void> makeLayerTargets();
    void makeFrameTextures(PixelFormat format);
    void uploadFrame(const ImageView& image);
    void makeUndistortMap();
    Rect layerRect(const std::vector<std::optional<Eigen::Matrix4f>>& models, const Eigen::Matrix4d& cam_from_world, double margin) const;
    Rect cameraRect(const Rect& layer) const;
    Rect layerRectOfCamera(const Rect& camera) const;
    Rect influenceRect(const Eigen::Matrix4d& cam_from_world) const;
    void renderShadowMaps(std::vector<LightSample>& samples, const std::vector<std::optional<Eigen::Matrix4f>>& models,
                          const Eigen::Vector3d& vmin, const Eigen::Vector3d& vmax, double footprint_px);
    void drawProxies(const Eigen::Matrix4f& view_proj, const Eigen::Vector3f& camera_centre, const Rect& rect);
    void drawProxyDepth(const Eigen::Vector3f& camera_centre);
    void drawVirtualLayer(const Rect& rect, bool proxy_depth_drawn, const Eigen::Matrix4f& view_proj, const Eigen::Vector3f& camera_centre,
                          const std::vector<LightSample>& samples, const std::vector<std::optional<Eigen::Matrix4f>>& models,
                          const lighting::LightingSnapshot& snapshot, double eg);
    void releaseAll();
    Result<void> measureCamera(const ImageView& image);
    Result<void> blurLayer(const Rect& rect, double sigma);
};

Compositor::Compositor() : impl_(std::make_unique<Impl>()) {}

Result<void> Compositor::Impl::makePrograms() {
    using shaders::programSource;
    const std::string scene_vs = programSource({}, shaders::kSceneVs);
    CL_TRY(shadow_program.id, gl::newProgram("shadow", programSource({}, shaders::kShadowVs), programSource({}, shaders::kShadowFs)));
    shadow_program.model = loc(shadow_program.id, "u_model");
    shadow_program.view_proj = loc(shadow_program.id, "u_view_proj");
    CL_TRY(line_program.id, gl::newProgram("lines", scene_vs, programSource({}, shaders::kLineFs)));
    line_program.model = loc(line_program.id, "u_model");
    line_program.view_proj = loc(line_program.id, "u_view_proj");
    line_program.colour = loc(line_program.id, "u_colour");

    CL_TRY(geometry_program.id, gl::newProgram("geometry", scene_vs, programSource({}, shaders::kGeometryFs)));
    geometry_program.model = loc(geometry_program.id, "u_model");
    geometry_program.view_proj = loc(geometry_program.id, "u_view_proj");
    geometry_program.line = loc(geometry_program.id, "u_line");
    CL_TRY(compose_program, gl::newProgram("compose", programSource({}, shaders::kFinalVs), programSource({}, shaders::kComposeFs)));
    glUseProgram(compose_program);
    glUniform1i(loc(compose_program, "u_shaded"), 0);
    glUniform1i(loc(compose_program, "u_shaded_geometry"), 1);
    glUniform1i(loc(compose_program, "u_samples"), 2);
    compose_sample_count = loc(compose_program, "u_sample_count");
    glUseProgram(0);

    CL_TRY(proxy_program.id, gl::newProgram("proxy", programSource({}, shaders::kProxyVs), programSource({}, shaders::kProxyFs)));
    ProxyProgram& pp = proxy_program;
    pp.model = loc(pp.id, "u_model");
    pp.view_proj = loc(pp.id, "u_view_proj");
    pp.has_mod = loc(pp.id, "u_has_mod");
    pp.c0 = loc(pp.id, "u_c0");
    pp.du = loc(pp.id, "u_du");
    pp.dv = loc(pp.id, "u_dv");
    pp.atlas_rect = loc(pp.id, "u_atlas_rect");
    pp.clamp = loc(pp.id, "u_clamp");

    CL_TRY_VOID(makeVirtualProgram(virtual_program, false));
    CL_TRY_VOID(makeVirtualProgram(virtual_ggx_program, true));

    // The final pass's everyday variants (RGB8 frames); the others are made when first needed.
    for (int bits : {0, int{kFinalModulation}, int{kFinalVirtual}, kFinalModulation | kFinalVirtual}) CL_TRY_VOID(finalProgram(bits));
    return {};
}

Result<void> Compositor::Impl::makeVirtualProgram(VirtualProgram& vp, bool ggx) {
    using shaders::programSource;
    const std::string vs = std::string(shaders::kShIrradiance) + shaders::kVirtualVs;
    const std::string fs = ggx ? std::string(shaders::kShIrradiance) + shaders::kVirtualFs : std::string(shaders::kVirtualFs);
    const std::vector<std::string> defines =
        ggx ? std::vector<std::string>{"GGX", "GGX_TABLE_SIZE " + std::to_string(kGgxTableSize) + ".0"} : std::vector<std::string>{};
    CL_TRY(vp.id, gl::newProgram(ggx ? "virtual (ggx)" : "virtual", programSource({}, vs.c_str()), programSource(defines, fs.c_str())));
    vp.model = loc(vp.id, "u_model");
    vp.view_proj = loc(vp.id, "u_view_proj");
    vp.albedo = loc(vp.id, "u_albedo");
    vp.emission = loc(vp.id, "u_emission");
    vp.ambient = loc(vp.id, "u_ambient");
    vp.camera_centre = loc(vp.id, "u_camera_centre");
    vp.samples = loc(vp.id, "u_samples");
    vp.kind = loc(vp.id, "u_kind");
    vp.position = loc(vp.id, "u_position");
    vp.axis = loc(vp.id, "u_axis");
    vp.power = loc(vp.id, "u_power");
    vp.shadow_layer = loc(vp.id, "u_shadow_layer");
    vp.shadow_vp = loc(vp.id, "u_shadow_vp");
    vp.static_vp = loc(vp.id, "u_static_vp");
    vp.shadow_tile = loc(vp.id, "u_shadow_tile");
    vp.shadow_inset = loc(vp.id, "u_shadow_inset");
    vp.static_tile = loc(vp.id, "u_static_tile");
    vp.static_inset = loc(vp.id, "u_static_inset");
    vp.has_sh = loc(vp.id, "u_has_sh");
    vp.bmin = loc(vp.id, "u_bmin");
    vp.bmax = loc(vp.id, "u_bmax");
    vp.sh_scale = loc(vp.id, "u_sh_scale");
    vp.sh_offset = loc(vp.id, "u_sh_offset");
    vp.sh_depth = loc(vp.id, "u_sh_depth");
    vp.has_texture = loc(vp.id, "u_has_texture");
    vp.roughness = loc(vp.id, "u_roughness");
    vp.radius = loc(vp.id, "u_radius");
    glUseProgram(vp.id);
    glUniform1i(loc(vp.id, "u_shadow_maps"), kUnitShadowMaps);
    glUniform1i(loc(vp.id, "u_static_maps"), kUnitStaticShadowMaps);
    glUniform1i(loc(vp.id, "u_sh"), kUnitSh);
    glUniform1i(loc(vp.id, "u_base_colour"), kUnitBaseColour);
    if (ggx) glUniform1i(loc(vp.id, "u_ggx_albedo"), kUnitGgxAlbedo);
    glUniform1f(vp.sh_depth, 1.0f / 9.0f);
    glUseProgram(0);
    return {};
}

Result<const FinalProgram*> Compositor::Impl::finalProgram(int bits) {
    if (const auto it = final_programs.find(bits); it != final_programs.end()) return &it->second;
    std::vector<std::string> defines;
    defines.push_back((bits & kFinalYuyv) ? "FRAME_YUYV" : (bits & kFinalNv12) ? "FRAME_NV12" : "FRAME_RGB8");
    if (bits & kFinalModulation) defines.push_back("MODULATION");
    if (bits & kFinalVirtual) defines.push_back("VIRTUAL");
    if (bits & kFinalElements) defines.push_back("VIEW_ELEMENTS");
    if (bits & kFinalRatio) defines.push_back("VIEW_RATIO");
    if (bits & kFinalNoise) defines.push_back("MATCH_NOISE");
    defines.push_back("MODULATION_EPSILON " + std::to_string(kModulationEpsilon));
    FinalProgram p;
    CL_TRY(p.id, gl::newProgram("final", shaders::programSource({}, shaders::kFinalVs), shaders::programSource(defines, shaders::kFinalFs)));
    p.atlas_size = loc(p.id, "u_atlas_size");
    p.layer_rect = loc(p.id, "u_layer_rect");
    p.exposure_gain = loc(p.id, "u_exposure_gain");
    p.size = loc(p.id, "u_size");
    p.noise = loc(p.id, "u_noise");
    p.seed = loc(p.id, "u_seed");
    glUseProgram(p.id);
    const std::pair<const char*, int> units[] = {{"u_frame", kUnitFrame},         {"u_frame_uv", kUnitFrameUv},
                                                 {"u_undistort", kUnitUndistort}, {"u_proxy_atlas", kUnitProxyAtlas},
                                                 {"u_atlas_m", kUnitAtlasM},      {"u_atlas_d", kUnitAtlasD},
                                                 {"u_atlas_o", kUnitAtlasO},      {"u_layer_v", kUnitLayerV}};
    for (const auto& [name, unit] : units) {
        if (const GLint l = loc(p.id, name); l >= 0) glUniform1i(l, unit);
    }
    if (const GLuint block = glGetUniformBlockIndex(p.id, "ToLinear"); block != GL_INVALID_INDEX) glUniformBlockBinding(p.id, block, 0);
    if (const GLuint block = glGetUniformBlockIndex(p.id, "ToCode"); block != GL_INVALID_INDEX) glUniformBlockBinding(p.id, block, 1);
    glUniform2i(p.size, layer_width, layer_height);
    glUseProgram(0);
    return &(final_programs[bits] = p);
}

Result<void> Compositor::Impl::makeLayerTargets() {
    GLint max_samples = 0, max_texture_samples = 0, max_format_samples = 0;
    glGetIntegerv(GL_MAX_SAMPLES, &max_samples);
    glGetIntegerv(GL_MAX_COLOR_TEXTURE_SAMPLES, &max_texture_samples);
    glGetInternalformativ(GL_TEXTURE_2D_MULTISAMPLE, GL_RGBA16F, GL_SAMPLES, 1, &max_format_samples);
    max_samples = std::min(max_samples, max_texture_samples);
    if (max_format_samples > 0) max_samples = std::min(max_samples, max_format_samples);
    // More samples than the GL has: the most it has (llvmpipe: 4). One sample: no multisampled pass.
    const int samples = options.msaa_samples > 1 ? std::min(options.msaa_samples, static_cast<int>(max_samples)) : 1;
    if (samples == layer_samples) return {};
    gl::deleteTexture(layer_samples_texture);
    gl::deleteRenderbuffer(layer_depth);
    gl::deleteFramebuffer(layer_fbo);
    layer_samples = samples;
    if (samples <= 1) return {};
    layer_fbo = gl::newFramebuffer();
    glBindFramebuffer(GL_FRAMEBUFFER, layer_fbo);
    layer_samples_texture = gl::newTexture();
    glBindTexture(GL_TEXTURE_2D_MULTISAMPLE, layer_samples_texture);
    glTexImage2DMultisample(GL_TEXTURE_2D_MULTISAMPLE, samples, GL_RGBA16F, layer_width, layer_height, GL_TRUE);
    glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D_MULTISAMPLE, layer_samples_texture, 0);
    layer_depth = gl::newRenderbuffer();
    glBindRenderbuffer(GL_RENDERBUFFER, layer_depth);
    glRenderbufferStorageMultisample(GL_RENDERBUFFER, samples, GL_DEPTH_COMPONENT24, layer_width, layer_height);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, layer_depth);
    if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
        layer_samples = -1;
        return fail(ErrorCode::kDevice, "render: the GL cannot make a " + std::to_string(samples) + "x multisampled float framebuffer");
    }
    return {};
}

void Compositor::Impl::makeFrameTextures(PixelFormat format) {
    if (format == frame_format) return;
    gl::deleteTexture(frame_texture);
    gl::deleteTexture(frame_uv_texture);
    switch (format) {
        case PixelFormat::kYuyv: frame_texture = byteTexture(width / 2, height, GL_RGBA8UI, GL_RGBA_INTEGER); break;
        case PixelFormat::kNv12:
            frame_texture = byteTexture(width, height, GL_R8UI, GL_RED_INTEGER);
            frame_uv_texture = byteTexture(width / 2, height / 2, GL_RG8UI, GL_RG_INTEGER);
            break;
        default: frame_texture = byteTexture(width, height, GL_RGB8, GL_RGB); break;
    }
    frame_format = format;
}

// The frame's bytes into the pixel buffer (rows packed), then into its texture(s) as they are.
void Compositor::Impl::uploadFrame(const ImageView& image) {
    makeFrameTextures(image.format);
    const bool nv12 = image.format == PixelFormat::kNv12;
    const std::size_t row = image.format == PixelFormat::kRgb8 ? 3 * static_cast<std::size_t>(width)
                            : image.format == PixelFormat::kYuyv ? 2 * static_cast<std::size_t>(width)
                                                                 : static_cast<std::size_t>(width);
    const int rows = nv12 ? height + height / 2 : height;
    glBindBuffer(GL_PIXEL_UNPACK_BUFFER, frame_pbo);
    glBufferData(GL_PIXEL_UNPACK_BUFFER, static_cast<GLsizeiptr>(row * static_cast<std::size_t>(rows)), nullptr, GL_STREAM_DRAW);
    if (auto* dst = static_cast<std::uint8_t*>(glMapBuffer(GL_PIXEL_UNPACK_BUFFER, GL_WRITE_ONLY))) {
        for (int y = 0; y < rows; ++y) std::memcpy(dst + row * static_cast<std::size_t>(y), image.row(y), row);
        glUnmapBuffer(GL_PIXEL_UNPACK_BUFFER);
    }
    glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
    glBindTexture(GL_TEXTURE_2D, frame_texture);
    switch (image.format) {
        case PixelFormat::kYuyv: glTexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, width / 2, height, GL_RGBA_INTEGER, GL_UNSIGNED_BYTE, nullptr); break;
        case PixelFormat::kNv12: {
            glTexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, width, height, GL_RED_INTEGER, GL_UNSIGNED_BYTE, nullptr);
            glBindTexture(GL_TEXTURE_2D, frame_uv_texture);
            const std::size_t offset = row * static_cast<std::size_t>(height);
            glTexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, width / 2, height / 2, GL_RG_INTEGER, GL_UNSIGNED_BYTE,
                            reinterpret_cast<void*>(static_cast<std::uintptr_t>(offset)));
            break;
        }
        default: glTexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, width, height, GL_RGB, GL_UNSIGNED_BYTE, nullptr); break;
    }
    glBindBuffer(GL_PIXEL_UNPACK_BUFFER, 0);
}

// Every camera pixel's ideal (undistorted) position in the layer's texel coordinates (GL rows),
// and the layer that holds them all: the camera's pinhole with a margin (barrel distortion puts
// the corners' ideal positions outside the camera's own rectangle).
void Compositor::Impl::makeUndistortMap() {
    const std::size_t n = static_cast<std::size_t>(width) * static_cast<std::size_t>(height);
    std::vector<Eigen::Vector2f> ideal(n, Eigen::Vector2f::Constant(kNoIdeal));
    Eigen::Vector2d lo(0.0, 0.0), hi(width - 1.0, height - 1.0);
    // Hard case: beyond the fold of a strong barrel distortion ideal positions run far out; the
    // layer covers at most twice the camera's size around it, and pixels beyond show no layer.
    const Eigen::Vector2d limit_lo(-0.5 * width, -0.5 * height), limit_hi(1.5 * width, 1.5 * height);
    for (int y = 0; y < height; ++y) {
        for (int x = 0; x < width; ++x) {
            const std::optional<Eigen::Vector2d> p = camera.undistortPixel(Eigen::Vector2d(x, y));
            if (!p || !p->allFinite() || (p->array() < limit_lo.array()).any() || (p->array() > limit_hi.array()).any()) continue;
            ideal[static_cast<std::size_t>(y) * static_cast<std::size_t>(width) + static_cast<std::size_t>(x)] = p->cast<float>();
            lo = lo.cwiseMin(*p);
            hi = hi.cwiseMax(*p);
        }
    }
    // Two pixels of margin: bilinear reads and the rectangles' rounding.
    layer_origin = Eigen::Vector2i(static_cast<int>(std::floor(lo.x())) - 2, static_cast<int>(std::floor(lo.y())) - 2);
    layer_width = static_cast<int>(std::ceil(hi.x())) + 2 - layer_origin.x() + 1;
    layer_height = static_cast<int>(std::ceil(hi.y())) + 2 - layer_origin.y() + 1;
    layer_camera = camera;
    layer_camera.width = layer_width;
    layer_camera.height = layer_height;
    layer_camera.cx = camera.cx - layer_origin.x();
    layer_camera.cy = camera.cy - layer_origin.y();
    layer_camera.distortion = Distortion{};

    std::vector<float> map(2 * n);
    warp_variance = 0.0;
    std::size_t warp_pixels = 0;
    blocks_x = (width + kBlock - 1) / kBlock;
    blocks_y = (height + kBlock - 1) / kBlock;
    block_bounds.assign(static_cast<std::size_t>(blocks_x) * static_cast<std::size_t>(blocks_y),
                        Eigen::Vector4f(1e9f, 1e9f, -1e9f, -1e9f));
    for (int y = 0; y < height; ++y) {
        for (int x = 0; x < width; ++x) {
            const std::size_t k = static_cast<std::size_t>(y) * static_cast<std::size_t>(width) + static_cast<std::size_t>(x);
            Eigen::Vector2f t = Eigen::Vector2f::Constant(kNoIdeal);
            if (ideal[k].x() != kNoIdeal) {
                // Texel coordinates: x + 0.5 from the layer's left, rows counted from its bottom.
                t = Eigen::Vector2f(ideal[k].x() - static_cast<float>(layer_origin.x()) + 0.5f,
                                    static_cast<float>(layer_height) - (ideal[k].y() - static_cast<float>(layer_origin.y())) - 0.5f);
                const Eigen::Vector2f f = t - t.array().floor().matrix() - Eigen::Vector2f::Constant(0.5f);  // offset from the texel's centre
                const Eigen::Vector2f g = f.array().abs().matrix();
                warp_variance += 0.5 * static_cast<double>(g.x() * (1.0f - g.x()) + g.y() * (1.0f - g.y()));
                ++warp_pixels;
                Eigen::Vector4f& b = block_bounds[static_cast<std::size_t>(y / kBlock * blocks_x + x / kBlock)];
                b = Eigen::Vector4f(std::min(b[0], t.x()), std::min(b[1], t.y()), std::max(b[2], t.x()), std::max(b[3], t.y()));
            }
            map[2 * k] = t.x();
            map[2 * k + 1] = t.y();
        }
    }
    undistort_texture = floatTexture(width, height, GL_RG32F, GL_RG, map.data(), GL_NEAREST);
    warp_variance = warp_pixels > 0 ? warp_variance / static_cast<double>(warp_pixels) : 0.0;
}

// The layer pixels the virtual objects can cover: their bounding boxes' corners through the
// layer's pinhole, plus a margin. Everything when a corner is at or behind the camera's plane.
Rect Compositor::Impl::layerRect(const std::vector<std::optional<Eigen::Matrix4f>>& models, const Eigen::Matrix4d& cam_from_world,
                                double margin) const {
    Rect full{0, 0, layer_width - 1, layer_height - 1};
    double x0 = 1e30, y0 = 1e30, x1 = -1e30, y1 = -1e30;
    bool any = false;
    for (std::size_t i = 0; i < models.size(); ++i) {
        if (!models[i]) continue;
        const GpuMesh& m = virtual_meshes[i];
        const Eigen::Matrix4d model = models[i]->cast<double>();
        for (int c = 0; c < 8; ++c) {
            const Eigen::Vector4d corner((c & 1) ? m.bmax.x() : m.bmin.x(), (c & 2) ? m.bmax.y() : m.bmin.y(),
                                         (c & 4) ? m.bmax.z() : m.bmin.z(), 1.0);
            const Eigen::Vector4d p = cam_from_world * (model * corner);
            if (!(p.z() > 0.01)) return full;
            const double u = layer_camera.fx * p.x() / p.z() + layer_camera.cx;
            const double v = layer_camera.fy * p.y() / p.z() + layer_camera.cy;
            if (!std::isfinite(u) || !std::isfinite(v)) return full;
            x0 = std::min(x0, u);
            x1 = std::max(x1, u);
            y0 = std::min(y0, v);
            y1 = std::max(y1, v);
            any = true;
        }
    }
    if (!any) return Rect{};
    // Image rows (down) to GL rows (up); `margin` pixels for the antialiased edge (and a blur).
    Rect r;
    r.x0 = static_cast<int>(std::max(0.0, std::floor(x0 - margin)));
    r.x1 = static_cast<int>(std::min(layer_width - 1.0, std::ceil(x1 + margin)));
    r.y0 = static_cast<int>(std::max(0.0, std::floor(layer_height - 1.0 - y1 - margin)));
    r.y1 = static_cast<int>(std::min(layer_height - 1.0, std::ceil(layer_height - 1.0 - y0 + margin)));
    return r;
}

// The layer pixels (GL rows) that the final pass can read for the camera pixels of `pixels`
// (whole blocks): their ideal positions, and the neighbours the filtering reads, 2 pixels around.
Rect Compositor::Impl::layerRectOfCamera(const Rect& pixels) const {
    Rect r{1 << 30, 1 << 30, -1, -1};
    if (pixels.empty()) return Rect{};
    for (int by = std::max(0, pixels.y0 / kBlock); by <= std::min(blocks_y - 1, pixels.y1 / kBlock); ++by) {
        for (int bx = std::max(0, pixels.x0 / kBlock); bx <= std::min(blocks_x - 1, pixels.x1 / kBlock); ++bx) {
            const Eigen::Vector4f& b = block_bounds[static_cast<std::size_t>(by * blocks_x + bx)];
            if (b[0] > b[2]) continue;  // no pixel of the block has an ideal position
            r.x0 = std::min(r.x0, static_cast<int>(std::floor(b[0])) - 2);
            r.y0 = std::min(r.y0, static_cast<int>(std::floor(b[1])) - 2);
            r.x1 = std::max(r.x1, static_cast<int>(std::floor(b[2])) + 2);
            r.y1 = std::max(r.y1, static_cast<int>(std::floor(b[3])) + 2);
        }
    }
    if (r.x1 < 0) return Rect{};
    return Rect{std::max(0, r.x0), std::max(0, r.y0), std::min(layer_width - 1, r.x1), std::min(layer_height - 1, r.y1)};
}

// The layer pixels (GL rows) where the snapshot's modulation can change the frame: the influenced
// part of every face (SnapshotTextures), clipped at the camera's near plane and projected, with 2
// pixels for the filtering. Empty when the snapshot changes nothing.
Rect Compositor::Impl::influenceRect(const Eigen::Matrix4d& cam_from_world) const {
    constexpr double kNear = 0.01;
    double x0 = 1e30, y0 = 1e30, x1 = -1e30, y1 = -1e30;
    for (const auto& [key, face] : snapshot_textures.faces()) {
        const Eigen::Vector4f& in = face.influence;
        if (in[0] > in[2] || in[1] > in[3]) continue;
        const Eigen::Vector2f st[4] = {{in[0], in[1]}, {in[2], in[1]}, {in[2], in[3]}, {in[0], in[3]}};
        std::array<Eigen::Vector3d, 4> c;
        for (int k = 0; k < 4; ++k) {
            const Eigen::Vector3f w = face.c0 + st[k].x() * face.e1 + st[k].y() * face.e2;
            c[static_cast<std::size_t>(k)] = (cam_from_world * Eigen::Vector4d(w.x(), w.y(), w.z(), 1.0)).head<3>();
        }
        // The quad's part in front of the near plane (Sutherland-Hodgman against one plane).
        std::vector<Eigen::Vector3d> kept;
        for (std::size_t k = 0; k < 4; ++k) {
            const Eigen::Vector3d& a = c[k];
            const Eigen::Vector3d& b = c[(k + 1) % 4];
            if (a.z() >= kNear) kept.push_back(a);
            if ((a.z() >= kNear) != (b.z() >= kNear)) kept.push_back(a + (b - a) * ((kNear - a.z()) / (b.z() - a.z())));
        }
        for (const Eigen::Vector3d& p : kept) {
            const double u = layer_camera.fx * p.x() / p.z() + layer_camera.cx;
            const double v = layer_camera.fy * p.y() / p.z() + layer_camera.cy;
            if (!std::isfinite(u) || !std::isfinite(v)) return Rect{0, 0, layer_width - 1, layer_height - 1};
            x0 = std::min(x0, u);
            x1 = std::max(x1, u);
            y0 = std::min(y0, v);
            y1 = std::max(y1, v);
        }
    }
    if (x0 > x1) return Rect{};
    // Image rows (down) to GL rows (up).
    Rect r;
    r.x0 = static_cast<int>(std::max(0.0, std::floor(std::max(-1.0, x0) - 2.0)));
    r.x1 = static_cast<int>(std::min(layer_width - 1.0, std::ceil(std::min(1e6, x1) + 2.0)));
    r.y0 = static_cast<int>(std::max(0.0, std::floor(layer_height - 1.0 - std::min(1e6, y1) - 2.0)));
    r.y1 = static_cast<int>(std::min(layer_height - 1.0, std::ceil(layer_height - 1.0 - std::max(-1.0, y0) + 2.0)));
    return r;
}

// The camera pixels whose ideal positions can fall in a layer rectangle (whole blocks; output
// rows are image rows).
Rect Compositor::Impl::cameraRect(const Rect& layer) const {
    Rect r{1 << 30, 1 << 30, -1, -1};
    if (layer.empty()) return Rect{};
    const float lx0 = static_cast<float>(layer.x0), ly0 = static_cast<float>(layer.y0);
    const float lx1 = static_cast<float>(layer.x1 + 1), ly1 = static_cast<float>(layer.y1 + 1);
    for (int by = 0; by < blocks_y; ++by) {
        for (int bx = 0; bx < blocks_x; ++bx) {
            const Eigen::Vector4f& b = block_bounds[static_cast<std::size_t>(by * blocks_x + bx)];
            if (b[2] < lx0 || b[0] > lx1 || b[3] < ly0 || b[1] > ly1) continue;
            r.x0 = std::min(r.x0, bx * kBlock);
            r.y0 = std::min(r.y0, by * kBlock);
            r.x1 = std::max(r.x1, std::min(width, (bx + 1) * kBlock) - 1);
            r.y1 = std::max(r.y1, std::min(height, (by + 1) * kBlock) - 1);
        }
    }
    return r.x1 < 0 ? Rect{} : r;
}

void Compositor::Impl::renderShadowMaps(std::vector<LightSample>& samples, const std::vector<std::optional<Eigen::Matrix4f>>& models,
                                        const Eigen::Vector3d& vmin, const Eigen::Vector3d& vmax, double footprint_px) {
    fitShadowViews(samples, vmin, vmax);
    const Eigen::Vector3d centre = 0.5 * (vmin + vmax);
    const double radius = std::max(0.5 * (vmax - vmin).norm(), 1e-3);
    // The real proxies' maps: refitted when the objects leave their sphere, or have become so much
    // smaller that its texels are too coarse for them.
    if (!(real_shadow_radius > 0.0) || (centre - real_shadow_centre).norm() + radius > real_shadow_radius || radius < real_shadow_radius / 3.0) {
        real_shadow_centre = centre;
        real_shadow_radius = 1.5 * radius;
    }
    for (LightSample& s : samples) s.static_view_proj = shadowView(s, real_shadow_centre, real_shadow_radius);
    const int n = std::max(static_cast<int>(samples.size()), 1);
    const int size = std::clamp(options.shadow_map_size, 64, 4096);
    real_shadows.ensure(n, size);
    virtual_shadows.ensure(n, virtualShadowMapSize(footprint_px, virtual_shadows.size, size));
    std::vector<float> real_key, virtual_key;
    for (const LightSample& s : samples) {
        real_key.insert(real_key.end(), s.static_view_proj.data(), s.static_view_proj.data() + 16);
        virtual_key.insert(virtual_key.end(), s.view_proj.data(), s.view_proj.data() + 16);
    }
    for (const auto& m : models) {
        if (m) virtual_key.insert(virtual_key.end(), m->data(), m->data() + 16);
        virtual_key.push_back(m ? 1.0f : 0.0f);
    }
    real_key.push_back(static_cast<float>(real_shadows.size));
    virtual_key.push_back(static_cast<float>(virtual_shadows.size));
    const auto draw = [&](ShadowAtlas& atlas, bool real) {
        glUseProgram(shadow_program.id);
        glBindFramebuffer(GL_FRAMEBUFFER, atlas.fbo);
        glViewport(0, 0, atlas.cols * atlas.size, atlas.rows * atlas.size);
        glDisable(GL_SCISSOR_TEST);
        glDepthMask(GL_TRUE);
        glClear(GL_DEPTH_BUFFER_BIT);
        glEnable(GL_SCISSOR_TEST);
        glEnable(GL_DEPTH_TEST);
        glDepthFunc(GL_LESS);
        glDisable(GL_CULL_FACE);
        glEnable(GL_POLYGON_OFFSET_FILL);
        glPolygonOffset(2.0f, 4.0f);
        for (const LightSample& s : samples) {
            const int x = (s.layer % atlas.cols) * atlas.size, y = (s.layer / atlas.cols) * atlas.size;
            glViewport(x, y, atlas.size, atlas.size);
            glScissor(x, y, atlas.size, atlas.size);
            setMat4(shadow_program.view_proj, real ? s.static_view_proj : s.view_proj);
            const auto drawMesh = [&](const GpuMesh& mesh, const Eigen::Matrix4f& model) {
                setMat4(shadow_program.model, model);
                glBindVertexArray(mesh.vao);
                for (const MeshPart& part : mesh.shadow_parts.empty() ? mesh.parts : mesh.shadow_parts) drawPart(part);
            };
            if (real) {
                for (std::size_t i = 0; i < real_meshes.size(); ++i) drawMesh(real_meshes[i], real_models[i]);
            } else {
                for (std::size_t i = 0; i < virtual_meshes.size(); ++i) {
                    if (models[i]) drawMesh(virtual_meshes[i], *models[i]);
                }
            }
        }
        glBindVertexArray(0);
        glDisable(GL_POLYGON_OFFSET_FILL);
        glDisable(GL_SCISSOR_TEST);
    };
    if (real_key != real_shadows.key) {
        real_shadows.key = std::move(real_key);
        draw(real_shadows, true);
    }
    if (virtual_key != virtual_shadows.key) {
        virtual_shadows.key = std::move(virtual_key);
        draw(virtual_shadows, false);
    }
}

// The real proxies, single-sampled over the whole layer: each pixel gets the atlas coordinates of
// the modulation of the surface it sees (depth-tested among the proxies).
void Compositor::Impl::drawProxies(const Eigen::Matrix4f& view_proj, const Eigen::Vector3f& camera_centre, const Rect& rect) {
    glBindFramebuffer(GL_FRAMEBUFFER, proxy_fbo);
    glViewport(0, 0, layer_width, layer_height);
    glEnable(GL_SCISSOR_TEST);
    rect.scissor();
    const float none[4] = {1.0f, 1.0f, 1.0f, 1.0f};
    glClearBufferfv(GL_COLOR, 0, none);
    glDepthMask(GL_TRUE);
    glClear(GL_DEPTH_BUFFER_BIT);
    glEnable(GL_DEPTH_TEST);
    glDepthFunc(GL_LESS);
    glDisable(GL_CULL_FACE);
    const ProxyProgram& pp = proxy_program;
    glUseProgram(pp.id);
    setMat4(pp.view_proj, view_proj);
    for (std::size_t i = 0; i < real_meshes.size(); ++i) {
        const GpuMesh& mesh = real_meshes[i];
        setMat4(pp.model, real_models[i]);
        cullProxyBackFaces(mesh, real_models[i], camera_centre);
        glBindVertexArray(mesh.vao);
        for (const MeshPart& part : mesh.parts) {
            const FaceInAtlas* face = part.face >= 0 ? snapshot_textures.face(static_cast<int>(i), part.face) : nullptr;
            glUniform1i(pp.has_mod, face ? 1 : 0);
            if (face) {
                setVec3(pp.c0, face->c0);
                setVec3(pp.du, face->du);
                setVec3(pp.dv, face->dv);
                glUniform4fv(pp.atlas_rect, 1, face->rect.data());
                const Eigen::Vector4f& r = face->rect;
                glUniform4f(pp.clamp, 16.0f * r.x(), 16.0f * r.y(), 16.0f * (r.x() + r.z()), 16.0f * (r.y() + r.w()));
            } else {
                glUniform4f(pp.clamp, 65535.0f, 65535.0f, 65535.0f, 65535.0f);
            }
            drawPart(part);
        }
    }
    glBindVertexArray(0);
    glDisable(GL_CULL_FACE);
    glDisable(GL_DEPTH_TEST);
    glDisable(GL_SCISSOR_TEST);
}

// The proxies' depth (only) in the bound framebuffer, for real objects to hide virtual ones.
void Compositor::Impl::drawProxyDepth(const Eigen::Vector3f& camera_centre) {
    glColorMask(GL_FALSE, GL_FALSE, GL_FALSE, GL_FALSE);
    glUseProgram(shadow_program.id);
    for (std::size_t i = 0; i < real_meshes.size(); ++i) {
        setMat4(shadow_program.model, real_models[i]);
        cullProxyBackFaces(real_meshes[i], real_models[i], camera_centre);
        glBindVertexArray(real_meshes[i].vao);
        for (const MeshPart& part : real_meshes[i].parts) drawPart(part);
    }
    glDisable(GL_CULL_FACE);
    glColorMask(GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
}

// The virtual layer in `rect`. llvmpipe runs a fragment shader once per sample of a multisampled
// target (measured: the full shading cost 3.5x as much at 4 samples as at 1), so the objects are
// shaded once per pixel, at its centre, in a single-sampled target depth-tested against the
// proxies; only their geometry (normal, depth: a cheap shader) is multisampled; the composition
// gives each covered sample the colour of the best matching shaded pixel nearby (kComposeFs:
// silhouettes, creases and overlaps antialiased as with multisampled shading).
void Compositor::Impl::drawVirtualLayer(const Rect& rect, bool proxy_depth_drawn, const Eigen::Matrix4f& view_proj,
                                        const Eigen::Vector3f& camera_centre, const std::vector<LightSample>& samples,
                                        const std::vector<std::optional<Eigen::Matrix4f>>& models,
                                        const lighting::LightingSnapshot& snapshot, double eg) {
    const auto drawObjects = [&](GLint model_location) {
        for (std::size_t i = 0; i < virtual_meshes.size(); ++i) {
            if (!models[i]) continue;
            setMat4(model_location, *models[i]);
            cullBackFaces(virtual_meshes[i]);
            glBindVertexArray(virtual_meshes[i].vao);
            for (const MeshPart& part : virtual_meshes[i].parts) drawPart(part);
        }
        glDisable(GL_CULL_FACE);
    };
    const auto drawLines = [&](const SceneProgram& program, bool colour) {
        glUseProgram(program.id);
        setMat4(program.view_proj, view_proj);
        if (colour) setVec3(program.colour, Eigen::Vector3f(0.1f, 0.9f, 0.2f) / static_cast<float>(eg));
        glDisable(GL_DEPTH_TEST);
        glPolygonMode(GL_FRONT_AND_BACK, GL_LINE);
        for (std::size_t i = 0; i < real_meshes.size(); ++i) {
            setMat4(program.model, real_models[i]);
            glBindVertexArray(real_meshes[i].vao);
            for (const MeshPart& part : real_meshes[i].parts) drawPart(part);
        }
        glPolygonMode(GL_FRONT_AND_BACK, GL_FILL);
        glEnable(GL_DEPTH_TEST);
    };
    glViewport(0, 0, layer_width, layer_height);
    glEnable(GL_SCISSOR_TEST);
    rect.scissor();
    glEnable(GL_DEPTH_TEST);
    glDepthFunc(GL_LESS);
    glDepthMask(GL_TRUE);
    glDisable(GL_CULL_FACE);
    const float clear[4] = {0, 0, 0, 0};

    // Step a: shaded once per pixel, against the proxies' depth (already there when the proxies
    // were drawn for the modulation).
    glBindFramebuffer(GL_FRAMEBUFFER, shade_fbo);
    glClearBufferfv(GL_COLOR, 0, clear);
    glClearBufferfv(GL_COLOR, 1, clear);
    glUseProgram(shadow_program.id);
    setMat4(shadow_program.view_proj, view_proj);
    if (!proxy_depth_drawn) {
        glClear(GL_DEPTH_BUFFER_BIT);
        drawProxyDepth(camera_centre);
    }
    // The frame's uniforms (camera, light samples, shadow maps) in each program that draws.
    const auto setFrameUniforms = [&](const VirtualProgram& vp) {
        glUseProgram(vp.id);
        setMat4(vp.view_proj, view_proj);
        setVec3(vp.camera_centre, camera_centre);
        const int n = static_cast<int>(samples.size());
        glUniform1i(vp.samples, n);
        if (n > 0) {
            std::array<GLint, kMaxLightSamples> kinds{}, layers{};
            std::array<float, 3 * kMaxLightSamples> positions{}, axes{}, powers{};
            std::array<float, 16 * kMaxLightSamples> matrices{};
            for (int k = 0; k < n; ++k) {
                const LightSample& s = samples[static_cast<std::size_t>(k)];
                const std::size_t i = static_cast<std::size_t>(k);
                kinds[i] = s.kind;
                layers[i] = s.layer;
                for (int c = 0; c < 3; ++c) {
                    positions[3 * i + static_cast<std::size_t>(c)] = static_cast<float>(s.position[c]);
                    axes[3 * i + static_cast<std::size_t>(c)] = static_cast<float>(s.axis[c]);
                    powers[3 * i + static_cast<std::size_t>(c)] = static_cast<float>(s.power[c]);
                }
                std::copy(s.view_proj.data(), s.view_proj.data() + 16, matrices.begin() + static_cast<std::ptrdiff_t>(16 * i));
            }
            glUniform1iv(vp.kind, n, kinds.data());
            glUniform1iv(vp.shadow_layer, n, layers.data());
            glUniform3fv(vp.position, n, positions.data());
            glUniform3fv(vp.axis, n, axes.data());
            glUniform3fv(vp.power, n, powers.data());
            glUniformMatrix4fv(vp.shadow_vp, n, GL_FALSE, matrices.data());
            // The real proxies' views, and each sample's tile in each atlas (their map sizes differ).
            std::array<float, 4 * kMaxLightSamples> tiles{}, static_tiles{};
            for (int k = 0; k < n; ++k) {
                const LightSample& s = samples[static_cast<std::size_t>(k)];
                const std::size_t i = static_cast<std::size_t>(k);
                std::copy(s.static_view_proj.data(), s.static_view_proj.data() + 16, matrices.begin() + static_cast<std::ptrdiff_t>(16 * i));
                const Eigen::Vector4f t = s.layer >= 0 ? virtual_shadows.tile(s.layer) : Eigen::Vector4f::Zero();
                std::copy(t.data(), t.data() + 4, tiles.begin() + static_cast<std::ptrdiff_t>(4 * i));
                const Eigen::Vector4f st = s.layer >= 0 ? real_shadows.tile(s.layer) : Eigen::Vector4f::Zero();
                std::copy(st.data(), st.data() + 4, static_tiles.begin() + static_cast<std::ptrdiff_t>(4 * i));
            }
            glUniformMatrix4fv(vp.static_vp, n, GL_FALSE, matrices.data());
            glUniform4fv(vp.shadow_tile, n, tiles.data());
            glUniform4fv(vp.static_tile, n, static_tiles.data());
            glUniform1f(vp.shadow_inset, virtual_shadows.size > 0 ? 0.5f / static_cast<float>(virtual_shadows.size) : 0.0f);
            glUniform1f(vp.static_inset, real_shadows.size > 0 ? 0.5f / static_cast<float>(real_shadows.size) : 0.0f);
            if (vp.radius >= 0) {
                std::array<float, kMaxLightSamples> radii{};
                for (int k = 0; k < n; ++k) radii[static_cast<std::size_t>(k)] = static_cast<float>(samples[static_cast<std::size_t>(k)].radius);
                glUniform1fv(vp.radius, n, radii.data());
            }
        }
    };
    bool any_ggx = false, any_lambertian = false;
    for (std::size_t i = 0; i < virtual_meshes.size(); ++i) {
        if (!models[i]) continue;
        (scene.virtual_objects[i].material.type == MaterialType::kGgx ? any_ggx : any_lambertian) = true;
    }
    if (any_ggx) setFrameUniforms(virtual_ggx_program);
    if (any_lambertian) setFrameUniforms(virtual_program);
    glActiveTexture(GL_TEXTURE0 + kUnitGgxAlbedo);
    glBindTexture(GL_TEXTURE_2D, ggx_albedo_texture);
    glActiveTexture(GL_TEXTURE0 + kUnitStaticShadowMaps);
    glBindTexture(GL_TEXTURE_2D, real_shadows.texture);
    glActiveTexture(GL_TEXTURE0 + kUnitShadowMaps);
    glBindTexture(GL_TEXTURE_2D, virtual_shadows.texture);
    const double scale = snapshot.radiance_scale > 0.0 && std::isfinite(snapshot.radiance_scale) ? snapshot.radiance_scale : 1.0;
    for (std::size_t i = 0; i < virtual_meshes.size(); ++i) {
        if (!models[i]) continue;
        const VirtualObject& object = scene.virtual_objects[i];
        const bool ggx = object.material.type == MaterialType::kGgx;
        const VirtualProgram& vp = ggx ? virtual_ggx_program : virtual_program;
        glUseProgram(vp.id);
        if (ggx) glUniform1f(vp.roughness, static_cast<float>(object.material.roughness));
        setVec3(vp.emission, (object.emission.value_or(Eigen::Vector3d::Zero()) * scale).cast<float>());
        const ProbeGrid* grid = snapshot_textures.probes(i);
        // With nothing estimated yet (and no light to shade with), a neutral light that shows the
        // object at mid grey.
        const bool unlit = grid == nullptr && samples.empty();
        const float ambient = unlit ? static_cast<float>(std::numbers::pi * 0.18 / eg) : 0.0f;
        setVec3(vp.ambient, Eigen::Vector3f::Constant(ambient));
        glUniform1i(vp.has_sh, grid ? 1 : 0);
        if (grid) {
            glActiveTexture(GL_TEXTURE0 + kUnitSh);
            glBindTexture(GL_TEXTURE_3D, grid->texture);
            setVec3(vp.bmin, grid->bmin);
            setVec3(vp.bmax, grid->bmax);
            setVec3(vp.sh_scale, grid->scale);
            setVec3(vp.sh_offset, grid->offset);
        }
        setMat4(vp.model, *models[i]);
        cullBackFaces(virtual_meshes[i]);
        glBindVertexArray(virtual_meshes[i].vao);
        for (const MeshPart& part : virtual_meshes[i].parts) {
            // A part with the mesh file's own base colour: that, times its texture, is the albedo.
            const GpuMaterial* material = part.material >= 0 && static_cast<std::size_t>(part.material) < virtual_meshes[i].materials.size()
                                              ? &virtual_meshes[i].materials[static_cast<std::size_t>(part.material)]
                                              : nullptr;
            setVec3(vp.albedo, material ? material->colour : object.material.albedo.cast<float>());
            glUniform1i(vp.has_texture, material && material->texture != 0 ? 1 : 0);
            if (material && material->texture != 0) {
                glActiveTexture(GL_TEXTURE0 + kUnitBaseColour);
                glBindTexture(GL_TEXTURE_2D, material->texture);
                glActiveTexture(GL_TEXTURE0);
            }
            drawPart(part);
        }
    }
    glActiveTexture(GL_TEXTURE0);
    glDisable(GL_CULL_FACE);
    if (options.debug == DebugView::kProxyWireframe) drawLines(line_program, true);
    mark("virtual shading");

    if (layer_samples > 1) {
        // Step b: the geometry of every sample: the proxies' depth, then the objects.
        glBindFramebuffer(GL_FRAMEBUFFER, layer_fbo);
        glClearBufferfv(GL_COLOR, 0, clear);
        glClear(GL_DEPTH_BUFFER_BIT);
        glUseProgram(shadow_program.id);
        setMat4(shadow_program.view_proj, view_proj);
        drawProxyDepth(camera_centre);
        glUseProgram(geometry_program.id);
        setMat4(geometry_program.view_proj, view_proj);
        glUniform1i(geometry_program.line, 0);
        drawObjects(geometry_program.model);
        if (options.debug == DebugView::kProxyWireframe) {
            glUniform1i(geometry_program.line, 1);
            drawLines(geometry_program, false);
        }
        mark("virtual samples");
        // Step c: each sample's colour from the best matching shaded pixel; their mean.
        glDisable(GL_DEPTH_TEST);
        glBindFramebuffer(GL_FRAMEBUFFER, resolve_fbo);
        glUseProgram(compose_program);
        glUniform1i(compose_sample_count, layer_samples);
        glActiveTexture(GL_TEXTURE0);
        glBindTexture(GL_TEXTURE_2D, shade_texture);
        glActiveTexture(GL_TEXTURE1);
        glBindTexture(GL_TEXTURE_2D, shade_geometry);
        glActiveTexture(GL_TEXTURE2);
        glBindTexture(GL_TEXTURE_2D_MULTISAMPLE, layer_samples_texture);
        glBindVertexArray(empty_vao);
        glDrawArrays(GL_TRIANGLES, 0, 3);
        glActiveTexture(GL_TEXTURE0);
        layer_v = resolve_texture;
    } else {
        layer_v = shade_texture;  // one sample: the shaded colour, alpha 1 where an object is, is the layer
    }
    glBindVertexArray(0);
    glDisable(GL_DEPTH_TEST);
    glDisable(GL_SCISSOR_TEST);
}

// The frame's noise and blur (CPU), and the blur the virtual layer lacks.
Result<void> Compositor::Impl::measureCamera(const ImageView& image) {
    ImageView rgb = image;
    if (image.format == PixelFormat::kYuyv || image.format == PixelFormat::kNv12) {
        match_rgb.reshape(PixelFormat::kRgb8, width, height);
        const int rows = image.format == PixelFormat::kNv12 ? height + height / 2 : height;
        const cv::Mat src(rows, width, image.format == PixelFormat::kNv12 ? CV_8UC1 : CV_8UC2, const_cast<std::uint8_t*>(image.data),
                          image.stride);
        cv::Mat dst(height, width, CV_8UC3, match_rgb.data(), match_rgb.stride());
        cv::cvtColor(src, dst, image.format == PixelFormat::kNv12 ? cv::COLOR_YUV2RGB_NV12 : cv::COLOR_YUV2RGB_YUYV);
        rgb = match_rgb.view();
    }
    CameraMatch m;
    CL_TRY(m.noise, estimateNoise(rgb));
    CL_TRY(m.blur, estimateBlur(rgb, response));
    // The layer's own PSF: its square pixels (MSAA coverage, 1/12 px^2) and the bilinear read
    // through the lens warp; the frame's PSF includes its pixels' integration too.
    m.layer_sigma_px = std::sqrt(1.0 / 12.0 + warp_variance);
    const double extra = m.blur.edges > 0 ? m.blur.sigma_px * m.blur.sigma_px - m.layer_sigma_px * m.layer_sigma_px : 0.0;
    m.added_sigma_px = std::min(2.5, std::sqrt(std::max(0.0, extra)));
    m.frame = frames_drawn;
    match = m;
    return {};
}

// A separable Gaussian of `sigma` pixels over the virtual layer in `rect` (two passes), the result
// then the layer the final pass reads.
Result<void> Compositor::Impl::blurLayer(const Rect& rect, double sigma) {
    if (blur_program == 0) {
        using shaders::programSource;
        CL_TRY(blur_program, gl::newProgram("blur", programSource({}, shaders::kFinalVs), programSource({}, shaders::kBlurFs)));
        blur_direction = loc(blur_program, "u_direction");
        blur_radius = loc(blur_program, "u_radius");
        blur_weights = loc(blur_program, "u_weights");
        blur_rect = loc(blur_program, "u_rect");
        glUseProgram(blur_program);
        glUniform1i(loc(blur_program, "u_layer"), 0);
        for (int k = 0; k < 2; ++k) {
            blur_fbo[k] = gl::newFramebuffer();
            glBindFramebuffer(GL_FRAMEBUFFER, blur_fbo[k]);
            blur_texture[k] = floatTexture(layer_width, layer_height, GL_RGBA16F, GL_RGBA, nullptr, GL_LINEAR);
            glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, blur_texture[k], 0);
            if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
                return fail(ErrorCode::kDevice, "render: the GL cannot make the camera matching's blur framebuffers");
            }
        }
    }
    const int radius = std::clamp(static_cast<int>(std::ceil(3.0 * sigma)), 1, 8);
    std::array<float, 9> weights{};
    float total = 0.0f;
    for (int k = 0; k <= radius; ++k) {
        weights[static_cast<std::size_t>(k)] = static_cast<float>(std::exp(-0.5 * k * k / (sigma * sigma)));
        total += (k == 0 ? 1.0f : 2.0f) * weights[static_cast<std::size_t>(k)];
    }
    for (float& w : weights) w /= total;
    glUseProgram(blur_program);
    glUniform1i(blur_radius, radius);
    glUniform1fv(blur_weights, 9, weights.data());
    glViewport(0, 0, layer_width, layer_height);
    glEnable(GL_SCISSOR_TEST);
    rect.scissor();
    glDisable(GL_DEPTH_TEST);
    glBindVertexArray(empty_vao);
    glActiveTexture(GL_TEXTURE0);
    GLuint input = layer_v;
    for (int pass = 0; pass < 2; ++pass) {
        glBindFramebuffer(GL_FRAMEBUFFER, blur_fbo[pass]);
        glBindTexture(GL_TEXTURE_2D, input);
        glUniform2i(blur_direction, pass == 0 ? 1 : 0, pass == 0 ? 0 : 1);
        glUniform4i(blur_rect, rect.x0, rect.y0, rect.x1, rect.y1);
        glDrawArrays(GL_TRIANGLES, 0, 3);
        input = blur_texture[pass];
    }
    glBindVertexArray(0);
    glDisable(GL_SCISSOR_TEST);
    layer_v = blur_texture[1];
    return {};
}

void Compositor::Impl::releaseAll() {
    snapshot_textures.release();
    gl::deleteTexture(layer_samples_texture);
    gl::deleteRenderbuffer(layer_depth);
    gl::deleteFramebuffer(layer_fbo);
    gl::deleteTexture(resolve_texture);
    gl::deleteFramebuffer(resolve_fbo);
    gl::deleteTexture(shade_texture);
    gl::deleteTexture(shade_geometry);
    gl::deleteFramebuffer(shade_fbo);
    gl::deleteTexture(proxy_atlas);
    gl::deleteRenderbuffer(proxy_depth);
    gl::deleteFramebuffer(proxy_fbo);
    gl::deleteTexture(output_texture);
    gl::deleteFramebuffer(output_fbo);
    virtual_shadows.release();
    real_shadows.release();
    for (GpuMesh& m : real_meshes) releaseMesh(m);
    for (GpuMesh& m : virtual_meshes) releaseMesh(m);
    gl::deleteVertexArray(empty_vao);
    gl::deleteTexture(frame_texture);
    gl::deleteTexture(frame_uv_texture);
    gl::deleteBuffer(frame_pbo);
    gl::deleteTexture(undistort_texture);
    gl::deleteBuffer(to_linear_ubo);
    gl::deleteBuffer(to_code_ubo);
    gl::deleteTexture(ggx_albedo_texture);
    for (GLuint* p : {&shadow_program.id, &line_program.id, &geometry_program.id, &compose_program, &proxy_program.id, &virtual_program.id,
                      &virtual_ggx_program.id}) {
        gl::deleteProgram(*p);
    }
    for (auto& [bits, p] : final_programs) gl::deleteProgram(p.id);
    gl::deleteProgram(blur_program);
    for (int k = 0; k < 2; ++k) {
        gl::deleteTexture(blur_texture[k]);
        gl::deleteFramebuffer(blur_fbo[k]);
    }
    gl::deleteProgram(world_program);
    gl::deleteProgram(warp_program);
    gl::deleteTexture(world_texture);
    gl::deleteFramebuffer(world_fbo);
    gl::deleteTexture(warp_texture);
    gl::deleteFramebuffer(warp_fbo);
    final_programs.clear();
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
    d.makeUndistortMap();
    CL_TRY_VOID(d.makePrograms());
    d.empty_vao = gl::newVertexArray();
    for (const RealObject& o : scene.real_objects) {
        d.real_meshes.push_back(uploadMesh(o.shape));
        d.real_models.push_back(toGl(o.world_from_object));
    }
    for (const VirtualObject& o : scene.virtual_objects) d.virtual_meshes.push_back(uploadMesh(o.shape));
    d.frame_pbo = gl::newBuffer();
    d.makeFrameTextures(PixelFormat::kRgb8);

    // The camera's response both ways, as uniform buffers (llvmpipe gathers from them several
    // times faster than it fetches texels).
    std::vector<float> lin(256 * 4, 0.0f), code(kToCodeSize * 4, 0.0f);
    for (int k = 0; k < 256; ++k) {
        for (int c = 0; c < 3; ++c) lin[static_cast<std::size_t>(4 * k + c)] = response.toLinear(c, static_cast<std::uint8_t>(k));
    }
    for (int k = 0; k < kToCodeSize; ++k) {
        const double s = static_cast<double>(k) / (kToCodeSize - 1);
        for (int c = 0; c < 3; ++c) code[static_cast<std::size_t>(4 * k + c)] = response.toEncoded(c, static_cast<float>(s * s));
    }
    d.to_linear_ubo = gl::newBuffer();
    glBindBuffer(GL_UNIFORM_BUFFER, d.to_linear_ubo);
    glBufferData(GL_UNIFORM_BUFFER, static_cast<GLsizeiptr>(lin.size() * sizeof(float)), lin.data(), GL_STATIC_DRAW);
    d.to_code_ubo = gl::newBuffer();
    glBindBuffer(GL_UNIFORM_BUFFER, d.to_code_ubo);
    glBufferData(GL_UNIFORM_BUFFER, static_cast<GLsizeiptr>(code.size() * sizeof(float)), code.data(), GL_STATIC_DRAW);
    glBindBuffer(GL_UNIFORM_BUFFER, 0);
    // The GGX lobe's directional albedo, for the indirect light on `type: ggx` objects.
    const std::vector<float> ggx_table = ggxAlbedoTable(kGgxTableSize, kGgxTableSamples);
    d.ggx_albedo_texture = floatTexture(kGgxTableSize, kGgxTableSize, GL_RG32F, GL_RG, ggx_table.data(), GL_LINEAR);

    // Targets: the proxies' atlas coordinates, the virtual layer (multisampled) and its resolve, the output.
    d.proxy_fbo = gl::newFramebuffer();
    glBindFramebuffer(GL_FRAMEBUFFER, d.proxy_fbo);
    d.proxy_atlas = byteTexture(d.layer_width, d.layer_height, GL_RGBA8, GL_RGBA);
    glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, d.proxy_atlas, 0);
    d.proxy_depth = gl::newRenderbuffer();
    glBindRenderbuffer(GL_RENDERBUFFER, d.proxy_depth);
    glRenderbufferStorage(GL_RENDERBUFFER, GL_DEPTH_COMPONENT24, d.layer_width, d.layer_height);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, d.proxy_depth);
    if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
        return fail(ErrorCode::kDevice, "render: the GL cannot make the proxies' framebuffer");
    }
    d.shade_fbo = gl::newFramebuffer();
    glBindFramebuffer(GL_FRAMEBUFFER, d.shade_fbo);
    d.shade_texture = floatTexture(d.layer_width, d.layer_height, GL_RGBA16F, GL_RGBA, nullptr, GL_LINEAR);
    glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, d.shade_texture, 0);
    d.shade_geometry = floatTexture(d.layer_width, d.layer_height, GL_RGBA16F, GL_RGBA, nullptr, GL_NEAREST);
    glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT1, GL_TEXTURE_2D, d.shade_geometry, 0);
    const GLenum shade_buffers[2] = {GL_COLOR_ATTACHMENT0, GL_COLOR_ATTACHMENT1};
    glDrawBuffers(2, shade_buffers);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, d.proxy_depth);
    if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
        return fail(ErrorCode::kDevice, "render: the GL cannot make the virtual objects' float framebuffer");
    }
    CL_TRY_VOID(d.makeLayerTargets());
    d.resolve_fbo = gl::newFramebuffer();
    glBindFramebuffer(GL_FRAMEBUFFER, d.resolve_fbo);
    d.resolve_texture = floatTexture(d.layer_width, d.layer_height, GL_RGBA16F, GL_RGBA, nullptr, GL_LINEAR);
    glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, d.resolve_texture, 0);
    if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
        return fail(ErrorCode::kDevice, "render: the GL cannot make the float resolve framebuffer");
    }
    d.output_fbo = gl::newFramebuffer();
    d.output_texture = gl::newTexture();
    glBindTexture(GL_TEXTURE_2D, d.output_texture);
    glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA8, d.width, d.height, 0, GL_RGBA, GL_UNSIGNED_BYTE, nullptr);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
    glBindFramebuffer(GL_FRAMEBUFFER, d.output_fbo);
    glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, d.output_texture, 0);
    if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
        return fail(ErrorCode::kDevice, "render: the GL cannot make the output framebuffer");
    }
    glBindFramebuffer(GL_FRAMEBUFFER, 0);
    return compositor;
}

Compositor::~Compositor() {
    if (!impl_ || impl_->context == nullptr) return;
    impl_->context->makeCurrent();
    impl_->releaseAll();
}

void Compositor::setOptions(const CompositorOptions& options) { impl_->options = options; }
const CompositorOptions& Compositor::options() const noexcept { return impl_->options; }
const std::vector<PassTime>& Compositor::passTimes() const noexcept { return impl_->pass_times; }
const std::optional<CameraMatch>& Compositor::cameraMatch() const noexcept { return impl_->match; }

Result<std::vector<Eigen::Vector4f>> Compositor::surfacePoints(const FrameInput& frame) {
    Impl& d = *impl_;
    d.context->makeCurrent();
    std::vector<Eigen::Vector4f> points(static_cast<std::size_t>(d.width) * static_cast<std::size_t>(d.height), Eigen::Vector4f::Zero());
    if (!frame.cam_from_world || !frame.cam_from_world->isValid()) return points;
    if (d.world_program == 0) {
        using shaders::programSource;
        CL_TRY(d.world_program, gl::newProgram("world", programSource({}, shaders::kSceneVs), programSource({}, shaders::kWorldFs)));
        d.world_model = loc(d.world_program, "u_model");
        d.world_view_proj = loc(d.world_program, "u_view_proj");
        d.world_surface = loc(d.world_program, "u_surface");
        CL_TRY(d.warp_program, gl::newProgram("warp", programSource({}, shaders::kFinalVs), programSource({}, shaders::kWarpFs)));
        glUseProgram(d.warp_program);
        glUniform1i(loc(d.warp_program, "u_undistort"), 0);
        glUniform1i(loc(d.warp_program, "u_world"), 1);
        glUniform2i(loc(d.warp_program, "u_size"), d.layer_width, d.layer_height);
        d.world_fbo = gl::newFramebuffer();
        glBindFramebuffer(GL_FRAMEBUFFER, d.world_fbo);
        d.world_texture = floatTexture(d.layer_width, d.layer_height, GL_RGBA32F, GL_RGBA, nullptr, GL_LINEAR);
        glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, d.world_texture, 0);
        glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, d.proxy_depth);
        d.warp_fbo = gl::newFramebuffer();
        glBindFramebuffer(GL_FRAMEBUFFER, d.warp_fbo);
        d.warp_texture = floatTexture(d.width, d.height, GL_RGBA32F, GL_RGBA, nullptr, GL_NEAREST);
        glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, d.warp_texture, 0);
        if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
            return fail(ErrorCode::kDevice, "render: the GL cannot make the RGBA32F framebuffers of surfacePoints");
        }
    }
    // The layer: every proxy and virtual object's world position, depth-tested, with the same
    // view and projection as draw()'s.
    Eigen::Matrix4d view = Eigen::Matrix4d::Identity();
    view.topLeftCorner<3, 3>() = frame.cam_from_world->rotation.toRotationMatrix();
    view.topRightCorner<3, 1>() = frame.cam_from_world->translation;
    view.row(1) *= -1.0;
    view.row(2) *= -1.0;
    const Eigen::Matrix4f view_proj = (d.layer_camera.glProjection(0.01, 100.0) * view).cast<float>();
    glBindFramebuffer(GL_FRAMEBUFFER, d.world_fbo);
    glViewport(0, 0, d.layer_width, d.layer_height);
    const float none[4] = {0, 0, 0, 0};
    glClearBufferfv(GL_COLOR, 0, none);
    glDepthMask(GL_TRUE);
    glClear(GL_DEPTH_BUFFER_BIT);
    glEnable(GL_DEPTH_TEST);
    glDepthFunc(GL_LESS);
    glDisable(GL_CULL_FACE);
    glUseProgram(d.world_program);
    setMat4(d.world_view_proj, view_proj);
    float surface = 0.0f;
    const auto draw = [&](const GpuMesh& mesh, const Eigen::Matrix4f& model) {
        glUniform1f(d.world_surface, surface += 1.0f);
        setMat4(d.world_model, model);
        glBindVertexArray(mesh.vao);
        for (const MeshPart& part : mesh.parts) drawPart(part);
    };
    for (std::size_t i = 0; i < d.real_meshes.size(); ++i) draw(d.real_meshes[i], d.real_models[i]);
    for (std::size_t i = 0; i < d.virtual_meshes.size(); ++i) {
        std::optional<Rigid3d> pose = i < frame.virtual_poses.size() ? frame.virtual_poses[i]
                                                                      : worldFromObject(d.scene.virtual_objects[i], d.scene.tags, 0.0);
        if (pose && pose->isValid()) draw(d.virtual_meshes[i], toGl(*pose));
    }
    glDisable(GL_DEPTH_TEST);
    // The warp at every camera pixel.
    glBindFramebuffer(GL_FRAMEBUFFER, d.warp_fbo);
    glViewport(0, 0, d.width, d.height);
    glUseProgram(d.warp_program);
    glActiveTexture(GL_TEXTURE0);
    glBindTexture(GL_TEXTURE_2D, d.undistort_texture);
    glActiveTexture(GL_TEXTURE1);
    glBindTexture(GL_TEXTURE_2D, d.world_texture);
    glBindVertexArray(d.empty_vao);
    glDrawArrays(GL_TRIANGLES, 0, 3);
    glBindVertexArray(0);
    glActiveTexture(GL_TEXTURE0);
    glPixelStorei(GL_PACK_ALIGNMENT, 4);
    glReadPixels(0, 0, d.width, d.height, GL_RGBA, GL_FLOAT, points.data());
    glBindFramebuffer(GL_FRAMEBUFFER, 0);
    const GLenum error = glGetError();
    if (error != GL_NO_ERROR) return fail(ErrorCode::kInternal, "render: GL error " + std::to_string(error) + " in surfacePoints");
    return points;
}

Result<void> Compositor::draw(const FrameInput& frame, const lighting::LightingSnapshot& snapshot) {
    Impl& d = *impl_;
    const PixelFormat format = frame.image.format;
    const bool yuv = format == PixelFormat::kYuyv || format == PixelFormat::kNv12;
    if ((format != PixelFormat::kRgb8 && !yuv) || frame.image.width != d.width || frame.image.height != d.height ||
        frame.image.data == nullptr || (yuv && (d.width % 2 != 0 || (format == PixelFormat::kNv12 && d.height % 2 != 0)))) {
        return fail(ErrorCode::kBadInput, "render: the frame must be RGB8, YUYV or NV12 (even sizes) of " + std::to_string(d.width) + "x" +
                                              std::to_string(d.height) + " (got " + std::string(pixelFormatName(format)) + " " +
                                              std::to_string(frame.image.width) + "x" + std::to_string(frame.image.height) + ")");
    }
    const std::size_t min_stride = minStride(format, d.width);
    if (frame.image.stride < min_stride || frame.image.size_bytes < imageBytes(format, d.width, d.height, frame.image.stride)) {
        return fail(ErrorCode::kBadInput, "render: the frame's " + std::to_string(frame.image.size_bytes) + " bytes (stride " +
                                              std::to_string(frame.image.stride) + ") are too few for " +
                                              std::string(pixelFormatName(format)) + " " + std::to_string(d.width) + "x" +
                                              std::to_string(d.height));
    }
    if (!frame.virtual_poses.empty() && frame.virtual_poses.size() != d.scene.virtual_objects.size()) {
        return fail(ErrorCode::kBadInput, "render: " + std::to_string(frame.virtual_poses.size()) + " virtual poses for " +
                                              std::to_string(d.scene.virtual_objects.size()) + " virtual objects");
    }
    d.context->makeCurrent();
    while (glGetError() != GL_NO_ERROR) {
    }  // errors left by others (the check below is for this frame's)
    d.pass_times.clear();
    d.mark(nullptr);
    CL_TRY_VOID(d.makeLayerTargets());
    const double eg = frame.exposure_gain > 0.0 && std::isfinite(frame.exposure_gain) ? frame.exposure_gain : 1.0;
    const bool posed = frame.cam_from_world && frame.cam_from_world->isValid();

    // Step 1: the frame, through the pixel buffer, in its own format.
    d.uploadFrame(frame.image);
    d.mark("upload frame");
    if (d.options.camera_matching) {
        const std::uint64_t interval = static_cast<std::uint64_t>(std::max(1, d.options.matching_interval));
        if (!d.match || d.frames_drawn - d.match->frame >= interval) CL_TRY_VOID(d.measureCamera(frame.image));
        d.mark("camera matching");
    } else {
        d.match.reset();
    }
    const bool matching = d.options.camera_matching && d.match.has_value();
    const double added_blur = matching ? d.match->added_sigma_px : 0.0;
    d.snapshot_textures.update(snapshot, d.scene.virtual_objects.size(), d.options.lighting);
    d.mark("upload snapshot");

    // Step 2: the poses of what is drawn.
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

    // Step 3: light samples and their shadow maps (for shading the virtual objects only).
    std::vector<LightSample> samples = lightSamples(snapshot, d.options.area_light_samples);
    if (posed && any_virtual && !samples.empty()) {
        // The objects' bounding sphere across in layer pixels: their maps need no finer texels.
        const Eigen::Vector3d centre = 0.5 * (vmin + vmax);
        const double radius = 0.5 * (vmax - vmin).norm();
        const double depth = (frame.cam_from_world->rotation * centre + frame.cam_from_world->translation).z();
        const double f = std::max(d.layer_camera.fx, d.layer_camera.fy);
        const double footprint = depth > 2.0 * radius ? 2.0 * radius * f / (depth - radius) : std::numeric_limits<double>::infinity();
        d.renderShadowMaps(samples, virtual_model, vmin, vmax, footprint);
    }
    d.mark("shadow maps");

    // Step 4: the real proxies (atlas coordinates of their modulation) and the virtual layer, in
    // the undistorted image.
    const bool modulated = posed && d.snapshot_textures.modulates();
    const bool debug_modulation = d.options.debug == DebugView::kElements || d.options.debug == DebugView::kRatio;
    Rect layer_rect, camera_rect, virtual_camera_rect;
    bool proxies_drawn = false;
    if (posed) {
        // GL camera: x right, y up, looking along -z.
        Eigen::Matrix4d cam_from_world = Eigen::Matrix4d::Identity();
        cam_from_world.topLeftCorner<3, 3>() = frame.cam_from_world->rotation.toRotationMatrix();
        cam_from_world.topRightCorner<3, 1>() = frame.cam_from_world->translation;
        Eigen::Matrix4d view = cam_from_world;
        view.row(1) *= -1.0;
        view.row(2) *= -1.0;
        const Eigen::Matrix4f view_proj = (d.layer_camera.glProjection(0.01, 100.0) * view).cast<float>();
        const Eigen::Vector3f camera_centre = frame.cam_from_world->inverse().translation.cast<float>();
        const Rect full_layer{0, 0, d.layer_width - 1, d.layer_height - 1};
        layer_rect = d.options.debug == DebugView::kProxyWireframe
                         ? full_layer
                         : d.layerRect(virtual_model, cam_from_world, 2.0 + (added_blur > 0.05 ? std::ceil(3.0 * added_blur) : 0.0));
        // The modulation only where the snapshot changes something (the debug views show it all);
        // elsewhere the final pass copies the frame's codes. The proxies are drawn where the final
        // pass reads them and under the virtual objects (their depth hides them).
        Rect modulation_rect;
        if (modulated) modulation_rect = debug_modulation ? full_layer : d.influenceRect(cam_from_world);
        virtual_camera_rect = d.cameraRect(layer_rect);
        camera_rect = unite(virtual_camera_rect, d.cameraRect(modulation_rect));
        const Rect proxy_rect = unite(unite(d.layerRectOfCamera(camera_rect), layer_rect), modulation_rect);
        proxies_drawn = modulated && !camera_rect.empty() && !proxy_rect.empty();
        if (proxies_drawn) d.drawProxies(view_proj, camera_centre, proxy_rect);
        d.mark("proxies");
        if (!layer_rect.empty()) {
            d.drawVirtualLayer(layer_rect, proxies_drawn, view_proj, camera_centre, samples, virtual_model, snapshot, eg);
            if (added_blur > 0.05) CL_TRY_VOID(d.blurLayer(layer_rect, added_blur));
        }
        d.mark("virtual layer");
    }

    // Step 5: the final pass at each camera pixel, the virtual layer read only where it can show.
    // Three nested regions: outside `camera_rect` the frame's codes as they are (converted from
    // YUV); in it, the modulation (where the proxies were drawn); in `virtual_camera_rect`, also
    // the virtual layer. Each program reads only what its region needs.
    const int bits = format == PixelFormat::kYuyv ? kFinalYuyv : format == PixelFormat::kNv12 ? kFinalNv12 : 0;
    int modulation_bits = bits;
    if (proxies_drawn) {
        modulation_bits |= kFinalModulation;
        if (d.options.debug == DebugView::kElements) modulation_bits |= kFinalElements;
        if (d.options.debug == DebugView::kRatio) modulation_bits |= kFinalRatio;
    }
    const int virtual_bits = modulation_bits | kFinalVirtual | (matching ? kFinalNoise : 0);
    if (layer_rect.empty()) virtual_camera_rect = Rect{};
    CL_TRY(const FinalProgram* plain, d.finalProgram(bits));
    CL_TRY(const FinalProgram* modulating, d.finalProgram(modulation_bits));
    const FinalProgram* with_virtual = nullptr;
    if (!virtual_camera_rect.empty()) {
        CL_TRY(with_virtual, d.finalProgram(virtual_bits));
    }
    glBindFramebuffer(GL_FRAMEBUFFER, d.output_fbo);
    const GLenum out0 = GL_COLOR_ATTACHMENT0;
    glDrawBuffers(1, &out0);
    glViewport(0, 0, d.width, d.height);
    const std::pair<int, GLuint> textures[] = {{kUnitFrame, d.frame_texture},       {kUnitFrameUv, d.frame_uv_texture},
                                               {kUnitUndistort, d.undistort_texture}, {kUnitProxyAtlas, d.proxy_atlas},
                                               {kUnitAtlasM, d.snapshot_textures.atlasM()}, {kUnitAtlasD, d.snapshot_textures.atlasD()},
                                               {kUnitAtlasO, d.snapshot_textures.atlasO()}, {kUnitLayerV, d.layer_v}};
    for (const auto& [unit, texture] : textures) {
        glActiveTexture(GL_TEXTURE0 + static_cast<GLenum>(unit));
        glBindTexture(GL_TEXTURE_2D, texture);
    }
    glBindBufferBase(GL_UNIFORM_BUFFER, 0, d.to_linear_ubo);
    glBindBufferBase(GL_UNIFORM_BUFFER, 1, d.to_code_ubo);
    const auto setUniforms = [&](const FinalProgram& p) {
        glUseProgram(p.id);
        glUniform1f(p.exposure_gain, static_cast<float>(eg));
        const Eigen::Vector2f atlas = d.snapshot_textures.atlasSize();
        glUniform2f(p.atlas_size, atlas.x(), atlas.y());
        // Texel coordinates at which a bilinear read stays inside the drawn rectangle.
        glUniform4f(p.layer_rect, static_cast<float>(layer_rect.x0) + 0.5f, static_cast<float>(layer_rect.y0) + 0.5f,
                    static_cast<float>(layer_rect.x1) + 0.5f, static_cast<float>(layer_rect.y1) + 0.5f);
        if (p.noise >= 0 && matching) {
            std::array<float, 3 * NoiseProfile::kBins> noise{};
            for (int b = 0; b < NoiseProfile::kBins; ++b) {
                for (int c = 0; c < 3; ++c) noise[static_cast<std::size_t>(3 * b + c)] = d.match->noise.sigma[static_cast<std::size_t>(b)][c];
            }
            glUniform3fv(p.noise, NoiseProfile::kBins, noise.data());
            glUniform1ui(p.seed, static_cast<GLuint>(d.frames_drawn & 0xffffffffu));
        }
    };
    // `outer` less `inner` (inside it, or empty) as up to four bands.
    const auto drawAround = [](const Rect& outer, const Rect& inner) {
        if (outer.empty()) return;
        if (inner.empty()) {
            outer.scissor();
            glDrawArrays(GL_TRIANGLES, 0, 3);
            return;
        }
        const Rect bands[4] = {{outer.x0, outer.y0, outer.x1, inner.y0 - 1},
                               {outer.x0, inner.y1 + 1, outer.x1, outer.y1},
                               {outer.x0, inner.y0, inner.x0 - 1, inner.y1},
                               {inner.x1 + 1, inner.y0, outer.x1, inner.y1}};
        for (const Rect& band : bands) {
            if (band.empty()) continue;
            band.scissor();
            glDrawArrays(GL_TRIANGLES, 0, 3);
        }
    };
    glBindVertexArray(d.empty_vao);
    glEnable(GL_SCISSOR_TEST);
    const Rect frame_rect{0, 0, d.width - 1, d.height - 1};
    const Rect modulation_camera_rect = modulation_bits != bits ? unite(camera_rect, virtual_camera_rect) : virtual_camera_rect;
    setUniforms(*plain);
    drawAround(frame_rect, modulation_camera_rect);
    if (modulation_bits != bits) {
        setUniforms(*modulating);
        drawAround(modulation_camera_rect, virtual_camera_rect);
    }
    if (with_virtual) {
        setUniforms(*with_virtual);
        drawAround(virtual_camera_rect, Rect{});
    }
    glDisable(GL_SCISSOR_TEST);
    glBindVertexArray(0);
    glActiveTexture(GL_TEXTURE0);
    d.mark("final pass");

    // In a window: the composite, scaled to the window (the output's row 0 is the image's top row).
    if (d.context->kind() == ContextKind::kWindow) {
        int w = 0, h = 0;
        d.context->windowSize(w, h);
        glBindFramebuffer(GL_READ_FRAMEBUFFER, d.output_fbo);
        glReadBuffer(GL_COLOR_ATTACHMENT0);
        glBindFramebuffer(GL_DRAW_FRAMEBUFFER, 0);
        glDrawBuffer(GL_BACK);
        glBlitFramebuffer(0, 0, d.width, d.height, 0, h, w, 0, GL_COLOR_BUFFER_BIT, GL_LINEAR);
        d.mark("window");
    }
    glBindFramebuffer(GL_FRAMEBUFFER, 0);
    ++d.frames_drawn;
    const GLenum error = glGetError();
    if (error != GL_NO_ERROR) return fail(ErrorCode::kInternal, "render: GL error " + std::to_string(error) + " while compositing");
    return {};
}

Result<Image> Compositor::read() const {
    const Impl& d = *impl_;
    d.context->makeCurrent();
    d.mark(nullptr);
    Image out(PixelFormat::kRgb8, d.width, d.height);
    glBindFramebuffer(GL_READ_FRAMEBUFFER, d.output_fbo);
    glReadBuffer(GL_COLOR_ATTACHMENT0);
    glPixelStorei(GL_PACK_ALIGNMENT, 1);
    // Rows come out top row first, packed as the image is.
    glReadPixels(0, 0, d.width, d.height, GL_RGB, GL_UNSIGNED_BYTE, out.data());
    glBindFramebuffer(GL_READ_FRAMEBUFFER, 0);
    d.mark("read back");
    return out;
}

}  // namespace commonlight::render

// Internal state of render/compositor.h, shared by compositor.cpp (programs, targets, frames,
// create, draw) and compositor_layer.cpp (the virtual layer: its footprint, shadow maps, proxies,
// the virtual objects, blur, camera matching). Not part of the module's interface.
#pragma once

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
#include "render/modulation_tiles.h"
#include "render/shaders.h"
#include "render/snapshot_textures.h"

namespace commonlight::render {

namespace compositor_detail {

inline constexpr int kToCodeSize = 1024;   // entries of the encoding table (index sqrt(linear)): within 0.02 codes of the response
inline constexpr int kBlock = 16;          // camera pixels per side of the blocks that bound the layer's footprint
inline constexpr float kNoIdeal = -1e6f;   // a camera pixel with no ideal position inside the layer

// Texture units of the final pass and of the virtual objects' program.
enum FinalUnit : int { kUnitFrame = 0, kUnitFrameUv, kUnitUndistort, kUnitProxyAtlas, kUnitAtlasM, kUnitAtlasD, kUnitAtlasO, kUnitLayerV };
enum VirtualUnit : int { kUnitShadowMaps = 3, kUnitSh = 4, kUnitBaseColour = 5, kUnitStaticShadowMaps = 6, kUnitGgxAlbedo = 7 };
inline constexpr int kGgxTableSize = 32;      // the GGX directional albedo table, per side (render/ggx_albedo.h)
inline constexpr int kGgxTableSamples = 256;  // visible normals per entry: within 0.5% of a 262 144-sample integral

inline GLuint floatTexture(int width, int height, GLenum internal, GLenum format, const float* data, GLenum filter) {
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

inline GLuint byteTexture(int width, int height, GLenum internal, GLenum format) {
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

inline GLint loc(GLuint program, const char* name) { return glGetUniformLocation(program, name); }
inline void setMat4(GLint location, const Eigen::Matrix4f& m) { glUniformMatrix4fv(location, 1, GL_FALSE, m.data()); }
inline void setVec3(GLint location, const Eigen::Vector3f& v) { glUniform3f(location, v.x(), v.y(), v.z()); }

// A closed mesh's faces turned away from the camera are hidden by its own front: not drawn (their
// fragments would be shaded and then overwritten). Open surfaces are drawn from both sides.
inline void cullBackFaces(const GpuMesh& mesh) {
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
inline void cullProxyBackFaces(const GpuMesh& mesh, const Eigen::Matrix4f& model, const Eigen::Vector3f& camera_centre) {
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
    kFinalTiles = 128,  // drawn over quads of camera tiles (kTileVs) instead of one scissored triangle
};

}  // namespace compositor_detail

// (Internal header: its two units use the helpers unqualified.)
using namespace compositor_detail;

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
    // The final pass's regions (render/modulation_tiles.h): the camera tiles it modulates, the
    // layer cells the snapshot's changes project to, the quads of both programs.
    TileMask modulation_tiles;
    CoverageGrid influence_cells;
    std::vector<float> tile_vertices;
    GLuint tile_vao = 0, tile_vbo = 0;
    FinalPassArea final_area;

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
    Rect projectedQuad(const std::array<Eigen::Vector3d, 4>& corners) const;
    Rect influenceRect(const Eigen::Matrix4d& cam_from_world) const;
    void markInfluenceTiles(const Eigen::Matrix4d& cam_from_world, TileMask& tiles);
    void markModulationTiles(const Eigen::Matrix4d& cam_from_world, const Rect& virtual_camera_rect);
    void makeTileBuffers();
    std::pair<GLsizei, GLsizei> uploadTileQuads(const Rect& virtual_camera_rect);
    void drawTileQuads(GLint first, GLsizei count);
    void drawVirtualRect(const Rect& virtual_camera_rect);
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

}  // namespace commonlight::render

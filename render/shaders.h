// GLSL sources of the compositor's programs (GLSL 3.30 core). Internal to render/.
//
// Sources have no #version line: programSource() prepends it with the variant's #defines, so one
// source gives every variant (the final pass has one per frame format, background mode and
// whether the virtual layer is read: llvmpipe runs both sides of a branch, so work a pixel does
// not need is left out at compile time rather than skipped at run time).
#pragma once

#include <string>
#include <vector>

namespace commonlight::render::shaders {

// "#version 330 core" and one "#define NAME" line per name, then `body`.
std::string programSource(const std::vector<std::string>& defines, const char* body);

extern const char* const kShadowVs;   // position only: u_model, u_view_proj
extern const char* const kShadowFs;   // depth only
extern const char* const kSceneVs;    // position, normal, texture coordinates -> world, normal, uv
extern const char* const kProxyVs;    // real proxies: position, the atlas coordinates of the face's modulation
extern const char* const kProxyFs;    // real proxies: those coordinates packed in RGBA8 (location 0)
extern const char* const kShIrradiance;  // shIrradiance(): the snapshot's SH irradiance at a point (prepended to what uses it)
extern const char* const kVirtualVs;  // virtual objects (after kShIrradiance): kSceneVs's outputs and the indirect irradiance of both sides
// Virtual objects: linear relative radiance, alpha 1 (location 0), normal and camera depth
// (location 1). Lambertian; with the defines GGX and GGX_TABLE_SIZE (after kShIrradiance) the GGX lobe.
extern const char* const kVirtualFs;
extern const char* const kLineFs;     // debug lines: a constant colour (location 0), geometry (location 1)
extern const char* const kGeometryFs; // the surface's normal and camera depth (location 0): the multisampled pass
extern const char* const kComposeFs;  // the virtual layer from the shaded pixels and the samples' geometry (full-screen triangle)
extern const char* const kBlurFs;     // one direction of a Gaussian over the virtual layer (camera matching)
extern const char* const kWorldFs;    // the world position, w = 1 (location 0): surfacePoints()
extern const char* const kWarpFs;     // the world positions' layer read at each camera pixel's ideal position (full-screen triangle)
extern const char* const kFinalVs;    // a full-screen triangle
extern const char* const kTileVs;     // quads of camera tiles: clip-space (x, y) at location 0 (render/modulation_tiles.h)
// The final pass. Defines: FRAME_RGB8 | FRAME_YUYV | FRAME_NV12 (the frame's format), MODULATION
// (real surfaces modulated by the snapshot through the face atlas), VIRTUAL (the virtual layer is
// read), MATCH_NOISE (with VIRTUAL: the frame's noise added where the virtual layer shows), VIEW_ELEMENTS |
// VIEW_RATIO (debug views; with MODULATION).
extern const char* const kFinalFs;

}  // namespace commonlight::render::shaders

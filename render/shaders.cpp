#include "render/shaders.h"

namespace commonlight::render::shaders {

std::string programSource(const std::vector<std::string>& defines, const char* body) {
    std::string source = "#version 330 core\n";
    for (const std::string& d : defines) source += "#define " + d + "\n";
    return source + body;
}

const char* const kShadowVs = R"(
layout(location = 0) in vec3 a_position;
uniform mat4 u_model;
uniform mat4 u_view_proj;
void main() { gl_Position = u_view_proj * u_model * vec4(a_position, 1.0); }
)";

const char* const kShadowFs = R"(
void main() {}
)";

const char* const kSceneVs = R"(
layout(location = 0) in vec3 a_position;
layout(location = 1) in vec3 a_normal;
layout(location = 2) in vec2 a_uv;
uniform mat4 u_model;
uniform mat4 u_view_proj;
out vec3 v_world;
out vec3 v_normal;
out vec2 v_uv;
void main() {
    vec4 world = u_model * vec4(a_position, 1.0);
    v_world = world.xyz;
    v_normal = mat3(u_model) * a_normal;
    v_uv = a_uv;
    gl_Position = u_view_proj * world;
}
)";

// Real proxies: where the face's modulation is in the atlas, or nowhere for a face the snapshot
// does not modulate. The final pass reads M and D there, filtered, so they are sampled once,
// straight from the snapshot. The atlas coordinates are an affine function of the position, so
// the vertex shader computes them and the rasteriser interpolates them exactly (perspective
// correct). The target is RGBA8 (llvmpipe's fastest): the coordinates in sixteenths of a texel, x
// then y, high byte first; all ones (65535): no modulation.
const char* const kProxyVs = R"(
layout(location = 0) in vec3 a_position;
uniform mat4 u_model;
uniform mat4 u_view_proj;
uniform int u_has_mod;
uniform vec3 u_c0;          // the face's parametrisation p = c0 + s e1 + t e2, inverted by its dual basis
uniform vec3 u_du;
uniform vec3 u_dv;
uniform vec4 u_atlas_rect;  // texel coordinates of (s, t) = (0, 0), then the face's texels along s and t
out vec2 v_atlas;           // sixteenths of an atlas texel
void main() {
    vec4 world = u_model * vec4(a_position, 1.0);
    gl_Position = u_view_proj * world;
    vec3 p = world.xyz - u_c0;
    vec2 st = vec2(dot(p, u_du), dot(p, u_dv));
    v_atlas = u_has_mod != 0 ? (u_atlas_rect.xy + st * u_atlas_rect.zw) * 16.0 : vec2(65535.0);
}
)";

const char* const kProxyFs = R"(
in vec2 v_atlas;
layout(location = 0) out vec4 o_atlas;
uniform vec4 u_clamp;  // the face's rectangle in sixteenths of a texel (s and t in [0, 1]); 65535: none
void main() {
    vec2 q = floor(clamp(v_atlas, u_clamp.xy, u_clamp.zw) + 0.5);
    vec2 high = floor(q / 256.0);
    vec2 low = q - high * 256.0;
    o_atlas = vec4(high.x, low.x, high.y, low.y) / 255.0;
}
)";

// The snapshot's indirect irradiance around a virtual object: order-2 spherical harmonics on a grid
// of probes over its bounds (trilinear between probes by the GL's filtering).
const char* const kShIrradiance = R"(
uniform int u_has_sh;
uniform vec3 u_bmin;
uniform vec3 u_bmax;
uniform vec3 u_sh_scale;        // texture coordinates of the probe grid: g scale + offset, g in [0, 1]^3
uniform vec3 u_sh_offset;
uniform float u_sh_depth;       // 1 / 9: the coefficients are stacked along the texture's depth
uniform sampler3D u_sh;         // RGB32F, probes x, y and 9 stacks of z (coefficient k at depth k)
// Relative irradiance at world point p on a surface facing the unit direction n (front) and -n (back).
void shIrradiance(vec3 p, vec3 n, out vec3 front, out vec3 back) {
    front = vec3(0.0);
    back = vec3(0.0);
    if (u_has_sh == 0) return;
    vec3 extent = max(u_bmax - u_bmin, vec3(1e-6));
    vec3 t = clamp((p - u_bmin) / extent, 0.0, 1.0) * u_sh_scale + u_sh_offset;
    // Y_k(n) with its sign for -n: the odd band (k = 1..3) flips.
    float basis[9] = float[9](0.282095, 0.488603 * n.y, 0.488603 * n.z, 0.488603 * n.x, 1.092548 * n.x * n.y,
                              1.092548 * n.y * n.z, 0.315392 * (3.0 * n.z * n.z - 1.0), 1.092548 * n.x * n.z,
                              0.546274 * (n.x * n.x - n.y * n.y));
    for (int k = 0; k < 9; ++k) {
        vec3 c = texture(u_sh, vec3(t.xy, (t.z + float(k)) * u_sh_depth)).rgb * basis[k];
        front += c;
        back += (k >= 1 && k <= 3) ? -c : c;
    }
    front = max(front, vec3(0.0));
    back = max(back, vec3(0.0));
}
)";

// Virtual objects: the vertex stage also evaluates the snapshot's indirect SH irradiance for both
// sides of the surface (smooth over the object: trilinear between probes, order-2 SH over the
// normal), so the fragment stage only picks the side it sees. Preceded by kShIrradiance.
const char* const kVirtualVs = R"(
layout(location = 0) in vec3 a_position;
layout(location = 1) in vec3 a_normal;
layout(location = 2) in vec2 a_uv;
uniform mat4 u_model;
uniform mat4 u_view_proj;
out vec3 v_world;
out vec3 v_normal;
out vec2 v_uv;
out vec3 v_indirect_front;      // relative irradiance on the side the normal points to
out vec3 v_indirect_back;
void main() {
    vec4 world = u_model * vec4(a_position, 1.0);
    v_world = world.xyz;
    v_normal = mat3(u_model) * a_normal;
    v_uv = a_uv;
    gl_Position = u_view_proj * world;
    shIrradiance(v_world, normalize(v_normal), v_indirect_front, v_indirect_back);
}
)";

// Virtual objects: direct light with shadow maps, the snapshot's indirect SH irradiance, emission.
// Linear relative radiance. Lambertian (albedo / pi times the irradiance, the indirect part from
// the vertex stage), or with GGX defined (and kShIrradiance before it) the metal-like GGX lobe of
// render/ggx_albedo.h: each light sample through the BRDF, its lobe widened by the patch of the
// light the sample stands for (a = roughness^2 + radius / (2 distance), the peak scaled by
// (a_0 / a)^2 so the energy stays: four points of an area light then give one highlight, not
// four); the indirect light as the irradiance the snapshot gives for a surface facing the mirror
// direction, over pi, times the lobe's directional albedo F0 A + B (ggx_albedo.h) read from
// u_ggx_albedo: exact for uniform surroundings, a blur of them otherwise (SH have no finer detail).
const char* const kVirtualFs = R"(
in vec3 v_world;
in vec3 v_normal;
in vec2 v_uv;
in vec3 v_indirect_front;
in vec3 v_indirect_back;
layout(location = 0) out vec4 o_virtual;
layout(location = 1) out vec4 o_geometry;  // the surface at the pixel's centre: unit normal (as interpolated), camera depth
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
uniform mat4 u_shadow_vp[kMaxSamples];    // world -> the virtual objects' map
uniform mat4 u_static_vp[kMaxSamples];    // world -> the real proxies' map
uniform vec4 u_shadow_tile[kMaxSamples];  // the virtual objects' maps: each one's tile in the atlas (offset, scale)
uniform vec4 u_static_tile[kMaxSamples];  // the same in the real proxies' atlas
uniform float u_shadow_inset;             // half a texel of a virtual objects' tile (no filtering across tiles)
uniform float u_static_inset;             // the same in the real proxies' atlas (its own map size)
uniform sampler2DShadow u_shadow_maps;    // the virtual objects as occluders
uniform sampler2DShadow u_static_maps;    // the real proxies as occluders
uniform int u_has_texture;
uniform sampler2D u_base_colour;  // sRGB texture, decoded to linear by the GL

float mapVisibility(sampler2DShadow maps, mat4 view_proj, vec4 tile, float inset, vec3 p) {
    vec4 clip = view_proj * vec4(p, 1.0);
    if (clip.w <= 0.0) return 1.0;
    vec3 uvz = clip.xyz / clip.w * 0.5 + 0.5;
    if (any(lessThan(uvz.xy, vec2(0.0))) || any(greaterThan(uvz.xy, vec2(1.0))) || uvz.z > 1.0) return 1.0;
    vec2 uv = tile.xy + clamp(uvz.xy, vec2(inset), vec2(1.0 - inset)) * tile.zw;
    return texture(maps, vec3(uv, uvz.z - 0.0005));
}

// The light sample seen from the surface: through the virtual objects and through the proxies.
float visibility(int i, vec3 world, vec3 n) {
    if (u_shadow_layer[i] < 0) return 1.0;
    vec3 p = world + n * 0.002;
    return mapVisibility(u_shadow_maps, u_shadow_vp[i], u_shadow_tile[i], u_shadow_inset, p) *
           mapVisibility(u_static_maps, u_static_vp[i], u_static_tile[i], u_static_inset, p);
}

#ifdef GGX
uniform float u_roughness;                 // perceptual; a = roughness^2, at least 1e-3
uniform float u_radius[kMaxSamples];       // the light patch a sample stands for, m (0: a point)
uniform sampler2D u_ggx_albedo;            // RG32F (A, B) by (cos_o, roughness), texel k at k / (size - 1)

float ggxD(float cos_h, float a) {
    float a2 = a * a;
    float d = cos_h * cos_h * (a2 - 1.0) + 1.0;
    return a2 / (3.14159265 * d * d);
}
// G1(v) / (2 cos_v): finite at grazing angles (the denominator is at least a).
float smithG1OverTwoCos(float c, float a) {
    float a2 = a * a;
    return 1.0 / (c + sqrt(a2 + (1.0 - a2) * c * c));
}
vec3 schlick(vec3 f0, float c) {
    float m = clamp(1.0 - c, 0.0, 1.0);
    float m2 = m * m;
    return f0 + (vec3(1.0) - f0) * (m2 * m2 * m);
}
#endif

void main() {
    vec3 n = normalize(v_normal);
    // Two-sided: a face seen from behind is lit on the side the camera sees.
    vec3 to_eye = u_camera_centre - v_world;
    bool back = dot(n, to_eye) < 0.0;
    if (back) n = -n;
    vec3 albedo = u_albedo;
    if (u_has_texture != 0) albedo *= texture(u_base_colour, v_uv).rgb;
#ifdef GGX
    vec3 wo = normalize(to_eye);
    float cos_o = max(dot(n, wo), 1e-4);
    float a0 = max(u_roughness * u_roughness, 1e-3);
    vec3 radiance = vec3(0.0);
#else
    vec3 e = u_ambient + (back ? v_indirect_back : v_indirect_front);
#endif
    for (int i = 0; i < u_samples; ++i) {
        vec3 irradiance;
        vec3 l;
        float d = 1.0;
        if (u_kind[i] == 2) {
            l = -u_axis[i];
            irradiance = u_power[i] * max(dot(n, l), 0.0);
        } else {
            vec3 to_light = u_position[i] - v_world;
            float d2 = max(dot(to_light, to_light), 1e-4);
            d = sqrt(d2);
            l = to_light / d;
            float cos_r = max(dot(n, l), 0.0);
            float cos_l = u_kind[i] == 0 ? max(dot(u_axis[i], -l), 0.0) : 1.0;
            irradiance = u_power[i] * cos_r * cos_l / d2;
        }
        if (any(greaterThan(irradiance, vec3(0.0)))) irradiance *= visibility(i, v_world, n);
#ifdef GGX
        float cos_i = dot(n, l);
        if (cos_i > 0.0) {
            vec3 h = normalize(wo + l);
            float a = min(a0 + u_radius[i] / (2.0 * d), 1.0);
            float peak = (a0 / a) * (a0 / a);
            vec3 f = schlick(albedo, dot(l, h)) * (ggxD(dot(n, h), a) * peak * smithG1OverTwoCos(cos_o, a0) * smithG1OverTwoCos(cos_i, a0));
            radiance += f * irradiance;
        }
#else
        e += irradiance;
#endif
    }
#ifdef GGX
    vec3 mirror = reflect(-wo, n);
    vec3 front, unused;
    shIrradiance(v_world, mirror, front, unused);
    float r_cos = (cos_o * (GGX_TABLE_SIZE - 1.0) + 0.5) / GGX_TABLE_SIZE;
    float r_rough = (clamp(u_roughness, 0.0, 1.0) * (GGX_TABLE_SIZE - 1.0) + 0.5) / GGX_TABLE_SIZE;
    vec2 ab = texture(u_ggx_albedo, vec2(r_cos, r_rough)).rg;
    radiance += (albedo * ab.x + vec3(ab.y)) * (front + u_ambient) / 3.14159265;
    o_virtual = vec4(radiance + u_emission, 1.0);
#else
    o_virtual = vec4(albedo / 3.14159265 * e + u_emission, 1.0);
#endif
    o_geometry = vec4(normalize(v_normal), 1.0 / gl_FragCoord.w);
}
)";

const char* const kLineFs = R"(
in vec3 v_world;
in vec3 v_normal;
in vec2 v_uv;
layout(location = 0) out vec4 o_virtual;
layout(location = 1) out vec4 o_geometry;
uniform vec3 u_colour;
void main() {
    o_virtual = vec4(u_colour, 1.0);
    o_geometry = vec4(0.0, 0.0, 0.0, 1.0 / gl_FragCoord.w);
}
)";

const char* const kGeometryFs = R"(
in vec3 v_world;
in vec3 v_normal;
in vec2 v_uv;
layout(location = 0) out vec4 o_geometry;
uniform int u_line;
void main() { o_geometry = u_line != 0 ? vec4(0.0, 0.0, 0.0, 1.0 / gl_FragCoord.w) : vec4(normalize(v_normal), 1.0 / gl_FragCoord.w); }
)";

// The virtual layer from the objects shaded once per pixel, at its centre, and their geometry per
// sample (subpixel reconstruction antialiasing, Chajdas, McGuire and Luebke 2011): each covered
// sample takes the colour of the pixel among this one and its 8 neighbours whose surface at the
// centre is most like the sample's (normal, depth), so a silhouette, a crease between faces and an
// edge where one virtual object passes another are antialiased like multisampled shading, for the
// cost of one shading per pixel. The result is premultiplied by the coverage.
const char* const kComposeFs = R"(
layout(location = 0) out vec4 o_layer;
uniform sampler2D u_shaded;           // RGBA16F: radiance, alpha 1 where a virtual object is seen at the pixel's centre
uniform sampler2D u_shaded_geometry;  // RGBA16F: normal and depth there
uniform sampler2DMS u_samples;        // RGBA16F per sample: normal and depth of the surface covering it (depth 0: none)
uniform int u_sample_count;
void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    ivec2 last = textureSize(u_shaded, 0) - 1;
    vec4 colour[9];
    vec4 geometry[9];
    for (int k = 0; k < 9; ++k) {
        int j = (k + 4) % 9;  // the pixel itself first, so it wins ties
        ivec2 q = clamp(p + ivec2(j % 3 - 1, j / 3 - 1), ivec2(0), last);
        colour[k] = texelFetch(u_shaded, q, 0);
        geometry[k] = texelFetch(u_shaded_geometry, q, 0);
    }
    vec3 sum = vec3(0.0);
    float covered = 0.0;
    for (int s = 0; s < u_sample_count; ++s) {
        vec4 g = texelFetch(u_samples, p, s);
        if (g.w <= 0.0) continue;
        covered += 1.0;
        float best = 1e30;
        vec3 c = vec3(0.0);
        for (int k = 0; k < 9; ++k) {
            float score = (1.0 - dot(g.xyz, geometry[k].xyz)) + 10.0 * abs(g.w - geometry[k].w) / g.w;
            if (colour[k].a > 0.0 && score < best) {
                best = score;
                c = colour[k].rgb;
            }
        }
        sum += c;
    }
    float n = float(u_sample_count);
    o_layer = vec4(sum / n, covered / n);
}
)";

// One direction of a separable Gaussian over the virtual layer (premultiplied: the coverage blurs
// with the colour); texels outside the rectangle drawn this frame count as empty.
const char* const kBlurFs = R"(
layout(location = 0) out vec4 o_layer;
uniform sampler2D u_layer;
uniform ivec2 u_direction;   // (1, 0) or (0, 1)
uniform int u_radius;        // texels each side, <= 8
uniform float u_weights[9];  // the kernel's weights at 0 .. u_radius texels (sum over both sides 1)
uniform ivec4 u_rect;        // the rectangle drawn this frame, inclusive (x0, y0, x1, y1)
void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    ivec2 last = textureSize(u_layer, 0) - 1;
    vec4 sum = vec4(0.0);
    for (int k = -u_radius; k <= u_radius; ++k) {
        ivec2 q = p + k * u_direction;
        bool inside = all(greaterThanEqual(q, u_rect.xy)) && all(lessThanEqual(q, u_rect.zw));
        sum += inside ? texelFetch(u_layer, clamp(q, ivec2(0), last), 0) * u_weights[abs(k)] : vec4(0.0);
    }
    o_layer = sum;
}
)";

const char* const kWorldFs = R"(
in vec3 v_world;
in vec3 v_normal;
in vec2 v_uv;
layout(location = 0) out vec4 o_world;
uniform float u_surface;  // which surface (> 0)
void main() { o_world = vec4(v_world, u_surface); }
)";

// The same read of the layer as the final pass's (texel coordinates from the undistortion map,
// bilinear), so it measures the composite's registration.
const char* const kWarpFs = R"(
layout(location = 0) out vec4 o_world;
uniform sampler2D u_undistort;
uniform sampler2D u_world;
uniform ivec2 u_size;  // the layer's
void main() {
    vec2 texel = texelFetch(u_undistort, ivec2(gl_FragCoord.xy), 0).xy;
    bool in_layer = all(greaterThanEqual(texel, vec2(0.0))) && all(lessThan(texel, vec2(u_size)));
    // The four layer pixels the filter reads: one surface, some, or none.
    ivec2 p0 = clamp(ivec2(floor(texel - 0.5)), ivec2(0), u_size - 1);
    ivec2 p1 = clamp(p0 + 1, ivec2(0), u_size - 1);
    vec4 ids = vec4(texelFetch(u_world, p0, 0).w, texelFetch(u_world, ivec2(p1.x, p0.y), 0).w,
                    texelFetch(u_world, ivec2(p0.x, p1.y), 0).w, texelFetch(u_world, p1, 0).w);
    float w = all(equal(ids, vec4(ids.x))) && ids.x > 0.0 ? 1.0 : (any(greaterThan(ids, vec4(0.0))) ? 0.5 : 0.0);
    o_world = in_layer ? vec4(texture(u_world, texel / vec2(u_size)).xyz, w) : vec4(0.0);
}
)";

const char* const kFinalVs = R"(
void main() {
    vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
    gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}
)";

const char* const kTileVs = R"(
layout(location = 0) in vec2 a_position;
void main() { gl_Position = vec4(a_position, 0.0, 1.0); }
)";

// At each camera pixel: the frame's code, the layer at the undistorted position, the
// differential combination, the camera's response. The output's row 0 is the image's top row
// (read back as is).
const char* const kFinalFs = R"(
out vec4 o_colour;
#if defined(FRAME_YUYV)
uniform usampler2D u_frame;      // RGBA8UI, width / 2: Y0 U Y1 V
#elif defined(FRAME_NV12)
uniform usampler2D u_frame;      // R8UI: the Y plane
uniform usampler2D u_frame_uv;   // RG8UI, width / 2 x height / 2: U V
#else
uniform sampler2D u_frame;       // RGB8, row 0 = the image's top row
#endif
uniform sampler2D u_undistort;   // RG32F: each camera pixel's ideal position in layer texel coordinates (GL rows); far out: none
uniform sampler2D u_proxy_atlas; // RGBA8, GL rows: the atlas coordinates of the real surface seen there (kProxyFs)
uniform sampler2D u_atlas_m;     // RGBA32F: M = w ratio + (1 - w) of every modulated face
uniform sampler2D u_atlas_d;     // RGBA32F: D = (1 - w)(B - B~)
uniform sampler2D u_atlas_o;     // RGBA32F: B~ with element outlines (debug view)
uniform vec2 u_atlas_size;
uniform sampler2D u_layer_v;     // the virtual layer, premultiplied by coverage, GL rows
uniform vec4 u_layer_rect;       // where the virtual layer was drawn (texel coordinates, x0 y0 x1 y1)
uniform float u_exposure_gain;
uniform ivec2 u_size;            // the layer's
layout(std140) uniform ToLinear { vec4 u_to_linear[256]; };   // code -> linear, per channel
layout(std140) uniform ToCode { vec4 u_to_code[1024]; };      // index sqrt(linear) x 1023 -> encoded [0, 1]

#if defined(FRAME_YUYV) || defined(FRAME_NV12)
// BT.601 limited range in OpenCV's fixed point (cv::COLOR_YUV2RGB_YUYV / _NV12, what
// capture::PixelConverter does on the CPU): the same integers, so the same codes.
ivec3 yuvToRgb(int y, int u, int v) {
    int uu = u - 128;
    int vv = v - 128;
    int yy = max(0, y - 16) * 1220542;
    int r = (yy + 524288 + 1673527 * vv) >> 20;
    int g = (yy + 524288 - 852492 * vv - 409993 * uu) >> 20;
    int b = (yy + 524288 + 2116026 * uu) >> 20;
    return clamp(ivec3(r, g, b), 0, 255);
}
#endif

ivec3 frameCode(ivec2 pixel) {
#if defined(FRAME_YUYV)
    uvec4 t = texelFetch(u_frame, ivec2(pixel.x >> 1, pixel.y), 0);
    return yuvToRgb(int((pixel.x & 1) == 0 ? t.x : t.z), int(t.y), int(t.w));
#elif defined(FRAME_NV12)
    int y = int(texelFetch(u_frame, pixel, 0).x);
    uvec2 uv = texelFetch(u_frame_uv, pixel >> 1, 0).xy;
    return yuvToRgb(y, int(uv.x), int(uv.y));
#else
    return ivec3(texelFetch(u_frame, pixel, 0).rgb * 255.0 + 0.5);
#endif
}

// The atlas coordinates (sixteenths of a texel) the proxies' pass left at a layer pixel; 65535: none.
vec2 atlasAt(ivec2 p) {
    vec4 b = floor(texelFetch(u_proxy_atlas, p, 0) * 255.0 + 0.5);
    return vec2(b.x * 256.0 + b.y, b.z * 256.0 + b.w);
}

#if defined(MATCH_NOISE)
uniform vec3 u_noise[16];  // the frame's noise deviation in codes per channel, bins of 16 codes (centres 8, 24, ..)
uniform uint u_seed;       // the frame's number

// PCG hash (O'Neill; Jarzynski and Olano 2020): a random 32-bit word per pixel and frame.
uint pcg(uint v) {
    uint state = v * 747796405u + 2891336453u;
    uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// Three independent standard normal numbers (Box-Muller).
vec3 gaussian3(ivec2 p) {
    uint h1 = pcg(uint(p.x) + pcg(uint(p.y) + pcg(u_seed)));
    uint h2 = pcg(h1);
    uint h3 = pcg(h2);
    uint h4 = pcg(h3);
    vec4 u = (vec4(float(h1), float(h2), float(h3), float(h4)) + 0.5) / 4294967296.0;
    float r1 = sqrt(-2.0 * log(max(u.x, 1e-30)));
    float r2 = sqrt(-2.0 * log(max(u.z, 1e-30)));
    return vec3(r1 * cos(6.2831853 * u.y), r1 * sin(6.2831853 * u.y), r2 * cos(6.2831853 * u.w));
}

vec3 noiseSigma(vec3 code) {
    vec3 x = clamp((code - 8.0) / 16.0, 0.0, 15.0);
    ivec3 i = min(ivec3(x), ivec3(14));
    vec3 f = x - vec3(i);
    return vec3(mix(u_noise[i.r].r, u_noise[i.r + 1].r, f.r), mix(u_noise[i.g].g, u_noise[i.g + 1].g, f.g),
                mix(u_noise[i.b].b, u_noise[i.b + 1].b, f.b));
}
#endif

vec3 toLinear(ivec3 code) { return vec3(u_to_linear[code.r].r, u_to_linear[code.g].g, u_to_linear[code.b].b); }

vec3 encode(vec3 linear) {
    vec3 x = sqrt(clamp(linear, 0.0, 1.0)) * 1023.0;
    ivec3 i = min(ivec3(x), ivec3(1022));
    vec3 a = vec3(u_to_code[i.r].r, u_to_code[i.g].g, u_to_code[i.b].b);
    vec3 b = vec3(u_to_code[i.r + 1].r, u_to_code[i.g + 1].g, u_to_code[i.b + 1].b);
    return mix(a, b, x - vec3(i));
}

void main() {
    ivec2 pixel = ivec2(gl_FragCoord.xy);
    ivec3 code = frameCode(pixel);
#if !defined(MODULATION) && !defined(VIRTUAL)
    o_colour = vec4(vec3(code) / 255.0, 1.0);
#else
    vec2 texel = texelFetch(u_undistort, pixel, 0).xy;  // the ideal position in the layer
    bool in_layer = all(greaterThanEqual(texel, vec2(0.0))) && all(lessThan(texel, vec2(u_size)));
    vec3 m = vec3(1.0);
    vec3 d = vec3(0.0);
    vec3 original = vec3(0.0);
    bool on_face = false;
#if defined(MODULATION)
    // The real surface at the ideal position: the atlas coordinates of the nearest layer pixel,
    // moved by the sub-pixel offset along their gradient towards the next pixel on each axis (the
    // coordinates are affine on a face, so this is exact inside one). Where the next pixel shows
    // another surface (or none), its modulation is blended in by the distance towards it, as a
    // bilinear read of a modulation layer would.
    ivec2 nearest = clamp(ivec2(floor(texel)), ivec2(0), u_size - 1);
    vec2 f = texel - (vec2(nearest) + 0.5);
    vec2 q = atlasAt(nearest);
    vec2 qx = atlasAt(clamp(nearest + ivec2(f.x >= 0.0 ? 1 : -1, 0), ivec2(0), u_size - 1));
    vec2 qy = atlasAt(clamp(nearest + ivec2(0, f.y >= 0.0 ? 1 : -1), ivec2(0), u_size - 1));
    on_face = in_layer && q.x < 65535.0;
    // Same surface: neither a marker nor a jump of more than 4 texels between neighbours.
    bool same_x = qx.x < 65535.0 && all(lessThan(abs(qx - q), vec2(64.0)));
    bool same_y = qy.x < 65535.0 && all(lessThan(abs(qy - q), vec2(64.0)));
    vec2 at = q + (same_x ? abs(f.x) * (qx - q) : vec2(0.0)) + (same_y ? abs(f.y) * (qy - q) : vec2(0.0));
    float wx = !same_x && any(notEqual(qx, q)) ? abs(f.x) : 0.0;
    float wy = !same_y && any(notEqual(qy, q)) ? abs(f.y) : 0.0;
    vec2 other = wx >= wy ? qx : qy;
    bool other_on = in_layer && other.x < 65535.0;
    vec2 atlas_uv = at / 16.0 / u_atlas_size;
    // (The other surface's texel is fetched, not filtered: it only weighs at an edge, and a
    // filtered read of a float texture costs llvmpipe four.)
    ivec2 other_texel = ivec2(other / 16.0);
    m = mix(on_face ? texture(u_atlas_m, atlas_uv).rgb : vec3(1.0), other_on ? texelFetch(u_atlas_m, other_texel, 0).rgb : vec3(1.0), max(wx, wy));
    d = mix(on_face ? texture(u_atlas_d, atlas_uv).rgb : vec3(0.0), other_on ? texelFetch(u_atlas_d, other_texel, 0).rgb : vec3(0.0), max(wx, wy));
#if defined(VIEW_ELEMENTS)
    original = on_face ? texelFetch(u_atlas_o, ivec2(q / 16.0), 0).rgb : vec3(0.0);
#endif
#endif
    vec4 v = vec4(0.0);
#if defined(VIRTUAL)
    bool inside = all(greaterThanEqual(texel, u_layer_rect.xy)) && all(lessThanEqual(texel, u_layer_rect.zw));
    v = inside ? texture(u_layer_v, texel / vec2(u_size)) : vec4(0.0);
#endif
#if defined(VIEW_RATIO)
    o_colour = vec4(clamp(m * 0.5, 0.0, 1.0), 1.0);
#else
    vec3 background = toLinear(code);
    bool forced = false;
#if defined(VIEW_ELEMENTS)
    if (on_face) {  // the model's radiance of the real scene alone instead of the frame
        background = original * u_exposure_gain;
        m = vec3(1.0);
        d = vec3(0.0);
        forced = true;
    }
#endif
    // Nothing changes this pixel: its code, exactly (M within MODULATION_EPSILON of 1 moves a code
    // by at most half: kModulationEpsilon, the same as outside the modulated region).
    bool unchanged = !forced && v.a < 1.0 / 1024.0 && all(lessThan(abs(m - 1.0), vec3(MODULATION_EPSILON))) &&
                     all(lessThan(abs(d * u_exposure_gain), vec3(1e-6)));
    vec3 out_linear = (background * m + d * u_exposure_gain) * (1.0 - v.a) + v.rgb * u_exposure_gain;
    vec3 encoded = encode(out_linear) * 255.0;
#if defined(MATCH_NOISE)
    // The sensor's noise is added after the optics mix the pixel: the frame's part already has its
    // share (1 - a)^2 of the variance; the virtual part gets the rest.
    encoded += noiseSigma(encoded) * gaussian3(pixel) * sqrt(max(0.0, 1.0 - (1.0 - v.a) * (1.0 - v.a)));
#endif
    vec3 result = clamp(floor(encoded + 0.5), 0.0, 255.0) / 255.0;
    o_colour = vec4(unchanged ? vec3(code) / 255.0 : result, 1.0);
#endif
#endif
}
)";

}  // namespace commonlight::render::shaders

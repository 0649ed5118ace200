// LightingSnapshot: what the lighting thread publishes and the renderer draws with.
//
// This header is the only meeting point of `lighting` and `render` (DESIGN.md section 2): it is
// header-only and depends on nothing but Eigen and core/pose.h, so `render` includes it without
// linking the lighting module.
//
// A snapshot is immutable once published and shared by pointer (`SnapshotPtr`); the renderer keeps
// the newest one it has and never waits for the next. `version` increases by one per publication.
//
// Units. Radiance inside lighting and render is linear and *relative* (DESIGN.md section 3): the
// camera value through the inverse response, divided by exposure (seconds) x analog gain. The
// scene file's emissions are in W/(m^2 sr) (radiance), W/sr (intensity) or W/m^2 (irradiance).
// `radiance_scale` converts: relative radiance = radiance_scale x radiance in scene units. Every
// field below says which of the two it is in.
//
// What the renderer does with it (seed 000 sec. 4.3, Debevec's differential rule):
//   - a real surface's pixel, linearised, is multiplied by `ratio` = B / B~ at its texel, where B~
//     is the radiance of the real scene alone and B the radiance with the virtual objects in it;
//   - where the real scene alone is dark (`original` below `kRatioFloor` x the face's mean, see
//     ratioWeight()) the ratio is unreliable, so `difference` = B - B~ is added instead; the two
//     are blended by ratioWeight() so the switch leaves no seam;
//   - virtual objects are shaded by `lights` directly (with shadow maps) plus the indirect
//     irradiance of `probes` (light bounced from real surfaces, and all of the light when the scene
//     names no light), plus their own emission.
#pragma once

#include <array>
#include <cmath>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/pose.h"

namespace commonlight::lighting {

// An RGB value stored per texel (single precision: textures go to the GPU as RGB32F).
using Rgb = Eigen::Vector3f;

// Below this fraction of its face's mean original radiance, a texel's ratio B/B~ gives way to the
// additive difference B - B~ (ratioWeight() blends the two between 1x and 2x the floor).
inline constexpr float kRatioFloor = 0.02f;
// Ratios are clamped to [0, kMaxRatio]: finite even where B~ is zero (the difference carries the
// light there).
inline constexpr float kMaxRatio = 16.0f;

// The modulation of one real proxy face, at the resolution of its finest elements.
//
// The face is a planar polygon (a triangle or a parallelogram) in world coordinates. Its texture
// parametrisation is p(s, t) = corner[0] + s (corner[1] - corner[0]) + t (corner[last] -
// corner[0]), s and t in [0, 1]: for a parallelogram corners go counter-clockwise seen from the
// front (corner[2] = corner[1] + corner[3] - corner[0]); for a triangle corner[2] is at (0, 1) and
// only texels with s + t <= 1 are meaningful. Texel (i, j) covers s in [i, i+1] / width and t in
// [j, j+1] / height; texels are stored row-major in t (index j * width + i). Values are smooth
// across element borders (interpolated from element vertices), so bilinear filtering shows no
// steps.
struct FaceModulation {
    std::string object;       // the real object's name in the scene
    int object_index = 0;     // its index in Scene::real_objects
    int face = 0;             // the face of the object: box 0..5 = +x, -x, +y, -y, +z, -z;
                              // plane 0 (front, +z); mesh: triangle index
    std::vector<Eigen::Vector3d> corners;  // world, metres; 3 (triangle) or 4 (parallelogram)
    Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  // world, unit, the lit (front) side

    int width = 0;   // texels along s
    int height = 0;  // texels along t
    std::vector<Rgb> ratio;        // B / B~, per channel, in [0, kMaxRatio]; 1 where nothing changed
    std::vector<Rgb> difference;   // B - B~, relative radiance (may be negative: a shadow)
    std::vector<Rgb> original;     // B~, relative radiance of the real scene alone
    std::vector<Rgb> reflectance;  // estimated albedo per channel, in [0, 1] (debug views)

    // Leaf elements of the face as (s0, t0, s1, t1) rectangles in texture coordinates (the
    // "proxies as elements" debug view draws their outlines).
    std::vector<Eigen::Vector4f> elements;
    float mean_original = 0.0f;  // area-weighted mean of `original` over the face, luminance
    // Changes whenever the face's texels or elements do (a renderer uploads again only the faces
    // whose revision changed); 0: unknown (always uploaded).
    std::uint64_t revision = 0;

    std::size_t texel(int i, int j) const { return static_cast<std::size_t>(j) * static_cast<std::size_t>(width) + i; }
    bool isTriangle() const { return corners.size() == 3; }
};

// Blend weight of the ratio against the difference at a texel whose original radiance has
// luminance `original_luminance`: 1 (use the ratio) above 2 x kRatioFloor x the face mean, 0 (add
// the difference) below kRatioFloor x the face mean, linear between. A face whose mean is zero
// (never lit) always uses the difference.
inline float ratioWeight(float original_luminance, float face_mean_luminance) {
    const float floor = kRatioFloor * face_mean_luminance;
    if (!(floor > 0.0f)) return 0.0f;  // hard case: an unlit face, or a NaN mean
    const float w = (original_luminance - floor) / floor;
    return w <= 0.0f ? 0.0f : (w >= 1.0f ? 1.0f : w);
}

// Rec. 709 luminance of a linear RGB value.
inline float luminance(const Rgb& rgb) { return 0.2126f * rgb.x() + 0.7152f * rgb.y() + 0.0722f * rgb.z(); }

enum class LightKind : std::uint8_t {
    kArea,         // rectangle in its x-y plane, emitting from +z: `size`, `emission` radiance W/(m^2 sr)
    kDisc,         // disc in its x-y plane, emitting from +z: `radius`, `emission` radiance W/(m^2 sr)
    kPoint,        // at the origin of world_from_object: `emission` intensity W/sr
    kDirectional,  // parallel light along `direction`: `emission` irradiance W/m^2 on a surface facing it
};

// A light as the renderer draws it: shading and shadow maps of the virtual objects. Known lights
// come with their estimated (or given) emission; an unknown distant environment comes as its
// dominant refined directions (kDirectional, each the light of a cone of `solid_angle_sr`), the
// rest of it in the probes' irradiance.
struct EstimatedLight {
    std::string name;                  // the scene's light name; "<name>#k" for the k-th direction of a distant light
    LightKind kind = LightKind::kArea;
    Rigid3d world_from_object;         // area, disc, point
    Eigen::Vector2d size = Eigen::Vector2d::Zero();  // area: full extent along x, y (metres)
    double radius = 0.0;                              // disc (metres)
    Eigen::Vector3d direction = -Eigen::Vector3d::UnitZ();  // directional: unit, the direction light travels (world)
    double solid_angle_sr = 0.0;       // directional light from a distant environment: the cone it stands for (0: a true directional light)
    Eigen::Vector3d emission = Eigen::Vector3d::Zero();  // scene units (see LightKind), per channel, >= 0
    bool estimated = false;            // false: the scene file gave the emission
    double relative_error = 0.0;       // estimated lights: standard error of the emission / emission (luminance), from the fit's residual
    std::string warning;               // non-empty when the fit could not determine this light well
};

// Irradiance arriving at a point from every direction, as the 9 coefficients of its order-2
// spherical-harmonic expansion (Ramamoorthi and Hanrahan 2001, eq. 7-8: the cosine lobe already
// applied), in relative irradiance units (relative radiance x sr). E(n) = sum_k sh[k] Y_k(n).
using IrradianceSh = std::array<Rgb, 9>;

// Real-symmetric SH basis Y_k(n) for k = 0..8 in the order (0,0), (1,-1), (1,0), (1,1), (2,-2),
// (2,-1), (2,0), (2,1), (2,2); n unit, world coordinates.
inline std::array<float, 9> shBasis(const Eigen::Vector3f& n) {
    const float x = n.x(), y = n.y(), z = n.z();
    return {0.282095f,
            0.488603f * y,
            0.488603f * z,
            0.488603f * x,
            1.092548f * x * y,
            1.092548f * y * z,
            0.315392f * (3.0f * z * z - 1.0f),
            1.092548f * x * z,
            0.546274f * (x * x - y * y)};
}

// Irradiance on a surface facing `n` (unit, world), relative units; clamped at 0 (the order-2
// expansion rings slightly negative opposite a strong small source).
inline Rgb evaluateIrradiance(const IrradianceSh& sh, const Eigen::Vector3f& n) {
    const std::array<float, 9> y = shBasis(n);
    Rgb e = Rgb::Zero();
    for (int k = 0; k < 9; ++k) e += sh[k] * y[k];
    return e.cwiseMax(0.0f);
}

// The light arriving at one virtual object, on a regular grid of probes over its world bounds
// (trilinear between probes; a grid of 1 x 1 x 1 is one probe at the centre).
struct VirtualIrradiance {
    std::string object;    // the virtual object's name
    int object_index = 0;  // its index in Scene::virtual_objects
    Eigen::Vector3d bounds_min = Eigen::Vector3d::Zero();  // world, metres
    Eigen::Vector3d bounds_max = Eigen::Vector3d::Zero();
    Eigen::Vector3i dims = Eigen::Vector3i::Ones();        // probes along x, y, z
    // x fastest, then y, then z. `indirect`: from real and virtual surfaces (reflected light, and
    // the emission of surfaces when the scene names no light), the part the renderer adds to its
    // own direct shading. `direct`: from the lights in `lights` alone (with the proxies' shadows),
    // for a renderer without shadow maps and for checks; never add both `direct` and shadow-mapped lights.
    std::vector<IrradianceSh> indirect;
    std::vector<IrradianceSh> direct;
};

// How the radiosity system was solved (DESIGN: "the solve summary is a value").
struct SolveSummary {
    int iterations = 0;
    double residual = 0.0;      // largest unshot/changed radiance left, relative to the largest radiance
    int elements = 0;           // leaf elements
    int links = 0;              // interactions (element pairs with a nonzero form factor)
    double milliseconds = 0.0;  // the whole update that produced this snapshot
    bool converged = false;     // residual below the requested bound
};

struct LightingSnapshot {
    std::uint64_t version = 0;            // 0: nothing estimated yet (every ratio 1)
    std::int64_t frame_timestamp_ns = 0;  // the newest frame whose observation it used
    std::int64_t published_ns = 0;        // CLOCK_MONOTONIC when it was published
    std::uint64_t frames_used = 0;        // observations accumulated so far
    double radiance_scale = 1.0;          // relative radiance per W/(m^2 sr) (see the file comment)
    bool radiance_scale_known = false;    // false: 1 was assumed (the camera is not radiometrically calibrated)
    SolveSummary solve;

    // Faces of real proxies whose light changed or that were estimated; a face absent here has
    // ratio 1 everywhere. Shared and immutable: a face an update did not change is the previous
    // snapshot's (no copy of the textures; a desk's are 10 MB).
    std::vector<std::shared_ptr<const FaceModulation>> faces;
    std::vector<EstimatedLight> lights;
    std::vector<VirtualIrradiance> virtual_objects;
    // The poses of the virtual objects this solution was computed for (world_from_object, by
    // Scene::virtual_objects index): the renderer may draw newer poses, the lag is visible here.
    std::vector<Rigid3d> virtual_poses;
    std::vector<std::string> warnings;  // e.g. a light that could not be estimated

    const FaceModulation* findFace(int object_index, int face) const {
        for (const auto& f : faces) {
            if (f->object_index == object_index && f->face == face) return f.get();
        }
        return nullptr;
    }
    const VirtualIrradiance* findVirtual(int object_index) const {
        for (const VirtualIrradiance& v : virtual_objects) {
            if (v.object_index == object_index) return &v;
        }
        return nullptr;
    }
};

using SnapshotPtr = std::shared_ptr<const LightingSnapshot>;

}  // namespace commonlight::lighting

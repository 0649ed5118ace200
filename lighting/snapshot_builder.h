// From a radiosity solution to what the renderer draws (lighting/snapshot.h): per real face the
// modulation textures, per virtual object the irradiance probes.
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

#include <Eigen/Core>

#include "core/camera_model.h"
#include "core/pose.h"
#include "lighting/direct.h"
#include "lighting/radiosity.h"
#include "lighting/snapshot.h"

namespace commonlight::lighting {

// Modulation textures of the real faces (buildFaceModulations() below): none for a face that takes
// no part in transport (every leaf buried). `without` is B~ (real scene alone), `with` is B, `rho`
// the reflectance, all by element. Texels are as fine as the face's finest leaf, or the camera's
// resolution where the direct light is drawn per texel (at most `max_texels` per side); values are box-filtered over the local leaf size, which
// interpolates linearly between element centres (smooth across element borders).
//
// `texel_direct` (optional): the direct light of the area lights per texel where the virtual
// objects change it (issue 12: per-texel shadow rays measured better than the elements' for the
// direct term, docs/lighting.md). By element, that direct light without and with the objects
// (irradiance); at a texel where they differ (box-filtered), the filtered one is swapped for what
// `at` gives at the texel's point: its direct light without and with the objects.
struct TexelDirect {
    const std::vector<Eigen::Vector3d>* without = nullptr;
    const std::vector<Eigen::Vector3d>* with = nullptr;
    // (face, texel, layout width x height, point) -> direct without, direct with. Called in parallel.
    std::function<void(int, std::size_t, int, int, const Eigen::Vector3d&, Eigen::Vector3d&, Eigen::Vector3d&)> at;
    // (face, texel) -> its answer of the last build stands (no move reached it); empty: never.
    std::function<bool(int, std::size_t)> kept;
    // (face, texels) -> the texels of the face whose answers went since the face's last build
    // (appended to `texels`; the builder visits only them and the texels whose leaves changed), or
    // false: any may have gone (every texel drawn with its own direct light is visited). Empty: false.
    std::function<bool(int, std::vector<std::uint32_t>&)> forgotten;
    double threshold = 0.0;  // |with - without| (irradiance, largest channel) below this: no change
    int oversample = 1;      // texels per finest leaf along each side (the faces of a parallelogram)
    // By face: the texel size (metres) the camera asks for (cameraTexelSize()); 0 or missing: the
    // finest leaf / `oversample`. The elements then need not follow the direct light's penumbrae.
    std::vector<double> face_texel;
};
// The texel size of a face's per-texel direct light for a camera: `pixels` camera pixels at the
// face's nearest point (metres), rounded to a power of two times `quantum` so that the layout (and
// the texels' kept answers) change only when the camera's distance does by a factor, and never below
// half of `quantum`; 0 when no part of the face is in view.
double cameraTexelSize(const Face& face, const CameraModel& camera, const Rigid3d& cam_from_world, double pixels, double quantum);
// What a face's last build keeps, so that the next one computes only the texels that changed: a
// move changes a few hundred texels of a face, and the propagation nudges all its leaves a little.
struct FaceBuild {
    // The face's textures as published: snapshots share them, and they are not written while any
    // holds them. Null: the face takes no part in transport.
    std::shared_ptr<const FaceModulation> modulation;
    // Two buffers by turns: the next build writes into the one published before `modulation` once
    // no snapshot holds it, after bringing over the tiles the last build wrote, so that a move
    // copies only what changed instead of every texel of the faces it reaches (a desk's are 10 MB).
    struct Buffer {
        FaceModulation textures;
        std::atomic<bool> held{false};  // a published pointer to it is alive
    };
    std::shared_ptr<Buffer> current, spare;
    static constexpr int kTile = 16;  // texels per side of the tiles the builds track

    // Move-only: two builds sharing a spare would write into each other's textures.
    FaceBuild() = default;
    FaceBuild(FaceBuild&&) = default;
    FaceBuild& operator=(FaceBuild&&) = default;
    FaceBuild(const FaceBuild&) = delete;
    FaceBuild& operator=(const FaceBuild&) = delete;
    struct Leaf {
        int element = -1;
        bool buried = false;
        Eigen::Vector2d st = Eigen::Vector2d::Zero(), ds = Eigen::Vector2d::Zero(), dt = Eigen::Vector2d::Zero();
        // B~, B, the reflectance, the elements' direct light without and with the objects (zero
        // without per-texel direct light), as the texels last read them.
        std::array<Eigen::Vector3d, 5> fields{};
    };
    std::vector<Leaf> leaves;  // the face's leaves (buried ones too), in the hierarchy's order
    struct Stencil {
        std::array<int, 4> leaf{};  // places in `leaves` the box filter averages
        int n = 0;
    };
    std::vector<int> leaf_of;       // by texel: the place in `leaves` of the leaf under its centre
    std::vector<Stencil> stencils;  // by texel
    std::vector<char> direct;       // by texel: drawn with its own direct light (TexelDirect)
    std::vector<int> written;       // the tiles the last build wrote (row-major, kTile texels a side)
    bool written_all = true;        // ... or every texel
    bool texel_direct = false;
    long texels_built = 0;  // texels computed by the last build (statistics)
};
// Builds the faces `faces` (real face indices) into `builds` (by real face; resized to them). A
// face whose leaves and texel layout are those of its last build keeps every texel whose leaves'
// fields moved by at most `tolerance` (radiance; drift is measured from the values the texels
// read, so a texel stays within twice it) and whose own direct light no move reached
// (TexelDirect::kept); every other face is built in full. `tolerance` 0: every texel whose leaves
// changed at all.
void buildFaceModulations(const Radiosity& radiosity, const Scene& scene, const std::vector<Eigen::Vector3d>& without,
                          const std::vector<Eigen::Vector3d>& with, const std::vector<Eigen::Vector3d>& rho, const std::vector<int>& faces,
                          std::vector<FaceBuild>& builds, double tolerance, int max_texels = 256, const TexelDirect* texel_direct = nullptr);

// A light as the probes see it: its unit-emission source and its emission (relative units, RGB).
// `indirect`: counted in the probes' indirect part (an unknown environment's residual, which the
// renderer does not draw as a light).
struct ProbeLight {
    DirectSource source;
    Eigen::Vector3d emission = Eigen::Vector3d::Zero();
    bool indirect = false;
};

// The irradiance arriving at point `p` (world) as order-2 SH (lighting/snapshot.h IrradianceSh):
// `indirect` from every surface a ray from `p` meets (the leaf's value in `radiance`, by element:
// real leaves and the other virtual objects' faces), and the environment's residual (distant
// cells flagged `indirect`); `direct` from the other `lights`, sampled on their geometry, through
// real and virtual occluders. Virtual object `object` itself is transparent to these rays (the
// point lies inside it); -1: none. `directions`: sampled directions (Fibonacci sphere).
// `other_objects` false: the other virtual objects are not there at all (neither seen nor blocking).
struct ProbeIrradiance {
    IrradianceSh indirect;
    IrradianceSh direct;
};
//
// `memory` (optional): what the probe's real rays met at its last call, kept for the next. A probe
// at the same point (to the bit) with as many directions meets the same real faces at the same
// points (the real scene does not move): its real rays are not traced again, and each hit's leaf is
// found from last time's (Hierarchy::leafAtAgain(): the same leaf through splits and collapses);
// a light sample at the same target keeps its real visibility. The virtual objects are asked
// every time. The answer is the same to the bit as without `memory`. It must be cleared when the
// radiosity's hierarchy or real scene is replaced, or the lights' geometry changes.
struct ProbeMemory {
    bool valid = false;
    Eigen::Vector3d point = Eigen::Vector3d::Zero();
    std::vector<RayHit> real_hits;  // by direction
    std::vector<int> leaves;        // by direction: the real hit's leaf last time (-1: none)
    // The lights' visibility samples in the order they were asked: target, its normal, open to the
    // real scene.
    std::vector<Eigen::Vector3d> sample_target, sample_normal;
    std::vector<char> sample_open;
};
ProbeIrradiance probeIrradiance(const Radiosity& radiosity, const Eigen::Vector3d& p, int object,
                                const std::vector<Eigen::Vector3d>& radiance, const std::vector<ProbeLight>& lights,
                                int directions, std::uint64_t seed, bool other_objects = true, ProbeMemory* memory = nullptr);

// buildProbes()'s memories, by virtual object and probe (ProbeMemory); clear() when the radiosity's
// hierarchy or the lights are replaced (a full update).
struct ProbeMemories {
    const Radiosity* radiosity = nullptr;
    std::vector<std::vector<ProbeMemory>> objects;
    void clear() {
        radiosity = nullptr;
        objects.clear();
    }
};

// Irradiance probes over each virtual object's bounds (lighting/snapshot.h VirtualIrradiance),
// each probeIrradiance() with `radiance` the solution with the virtual objects (B). `memories`
// (optional): kept between calls, so that the probes of an object that did not move trace no real
// ray again (the same probes to the bit).
std::vector<VirtualIrradiance> buildProbes(const Radiosity& radiosity, const Scene& scene, const std::vector<Eigen::Vector3d>& radiance,
                                           const std::vector<ProbeLight>& lights, int directions = 256,
                                           ProbeMemories* memories = nullptr);

}  // namespace commonlight::lighting

// The lighting snapshot on the GPU: every modulated real face's M = w ratio + (1 - w),
// D = (1 - w)(B - B~) and B~ (debug) packed into three atlases, and each virtual object's probe
// grid of SH irradiance as a 3D texture (trilinear between probes by the GL's filtering). Internal
// to render/.
#pragma once

#include <array>
#include <cstdint>
#include <map>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "lighting/snapshot.h"
#include "render/gl_objects.h"

namespace commonlight::render {

// Where one face's modulation is in the atlas.
struct FaceInAtlas {
    // The face's parametrisation p = c0 + s e1 + t e2 inverted: s = (p - c0).du, t = (p - c0).dv.
    Eigen::Vector3f c0 = Eigen::Vector3f::Zero(), du = Eigen::Vector3f::Zero(), dv = Eigen::Vector3f::Zero();
    // Atlas texel coordinates of (s, t) = (0, 0), and the face's texels along s and t: (s, t) is at
    // rect.xy + (s, t) rect.zw. The face's texels are framed by a copy of its edge texels, so
    // filtering at s or t = 0 or 1 reads the face alone (as clamp-to-edge would).
    Eigen::Vector4f rect = Eigen::Vector4f::Zero();
    // The face's edges: p = c0 + s e1 + t e2, (s, t) in [0, 1]^2 (e2 = e1 on a triangle's degenerate side).
    Eigen::Vector3f e1 = Eigen::Vector3f::Zero(), e2 = Eigen::Vector3f::Zero();
    // Where the snapshot changes what the camera sees of the face: (s0, t0, s1, t1) around every
    // texel whose M is more than kModulationEpsilon from 1 or whose D is not zero, one texel wider
    // for the filtering (s0 > s1: nowhere). Elsewhere the final pass leaves the frame's codes.
    Eigen::Vector4f influence = Eigen::Vector4f(1.0f, 1.0f, 0.0f, 0.0f);
    // The same at a finer grain: per block of kInfluenceBlock x kInfluenceBlock texels that holds an
    // influenced texel, the (s0, t0, s1, t1) around its influenced texels, one texel wider (their
    // union is what `influence` bounds). A shadow's penumbra and the light around a virtual object
    // change a fraction of a face's rectangle: the final pass modulates only where these project
    // (render/modulation_tiles.h).
    std::vector<Eigen::Vector4f> influence_blocks;
};

// Texels per side of the blocks of FaceInAtlas::influence_blocks.
inline constexpr int kInfluenceBlock = 8;

// A modulation M within this of 1 is left out (the frame's code is kept): it would move the code by
// at most 0.51 at any level for any concave response (by E'(L) L |M - 1| <= 255 |M - 1|), so the
// composite differs from the modulated one by at most one code there, below the sensor's noise.
// (1e-3, a quarter of a code, modulated 27% more of the sample's frame: 2 CPU ms more a draw.)
inline constexpr float kModulationEpsilon = 2e-3f;

// A virtual object's probe grid.
struct ProbeGrid {
    GLuint texture = 0;  // RGB32F 3D: dims.x x dims.y x 9 dims.z (coefficient k at depths k dims.z ..)
    Eigen::Vector3f bmin = Eigen::Vector3f::Zero(), bmax = Eigen::Vector3f::Zero();  // world bounds
    Eigen::Vector3f scale = Eigen::Vector3f::Zero(), offset = Eigen::Vector3f::Zero();  // texture coordinate = g scale + offset, g in [0, 1]^3
};

class SnapshotTextures {
public:
    // Rebuilds the textures when the snapshot (its address or version) or `lighting` changed (when
    // its faces and their sizes are those of the atlas, only the faces whose
    // FaceModulation::revision changed are uploaded again, into their place):
    // without lighting nothing is modulated and no probe is used. Non-finite values count as no
    // change (ratio 1, difference 0, irradiance 0); degenerate faces are left out. The GL context
    // must be current.
    void update(const lighting::LightingSnapshot& snapshot, std::size_t virtual_objects, bool lighting);
    // Deletes every texture (the GL context must be current).
    void release();

    bool modulates() const noexcept { return !faces_.empty(); }
    const FaceInAtlas* face(int object_index, int face) const;
    const std::map<std::pair<int, int>, FaceInAtlas>& faces() const noexcept { return faces_; }
    GLuint atlasM() const noexcept { return atlas_m_; }
    GLuint atlasD() const noexcept { return atlas_d_; }
    GLuint atlasO() const noexcept { return atlas_o_; }
    Eigen::Vector2f atlasSize() const noexcept { return atlas_size_; }
    const ProbeGrid* probes(std::size_t virtual_index) const;

private:
    void updateProbes(const lighting::LightingSnapshot& snapshot, std::size_t virtual_objects);
    std::uint64_t version_ = ~0ull;
    std::vector<std::array<int, 4>> layout_key_;  // the atlas's faces: object, face, width, height
    std::vector<std::uint64_t> revisions_;        // their revisions uploaded, in the snapshot's order
    const void* address_ = nullptr;
    bool lighting_ = true;
    std::map<std::pair<int, int>, FaceInAtlas> faces_;
    GLuint atlas_m_ = 0, atlas_d_ = 0, atlas_o_ = 0;
    Eigen::Vector2f atlas_size_ = Eigen::Vector2f::Ones();
    std::vector<ProbeGrid> probes_;  // by virtual object index (texture 0: none)
};

}  // namespace commonlight::render

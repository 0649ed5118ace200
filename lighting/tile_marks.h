// The tiles of a face's texture layout that a build of its textures visits, each with the box of
// the texels that marked it (lighting/snapshot_builder.cpp buildFaceModulation()): a build visits
// only the boxes, not whole tiles, and the next build brings over only the tiles it rewrote.
#pragma once

#include <algorithm>
#include <cstddef>
#include <vector>

#include <Eigen/Core>

namespace commonlight::lighting {

class TileMarks {
public:
    // A width x height layout in tiles of `tile` texels a side (the last row and column partial).
    TileMarks(int width, int height, int tile)
        : tile_(tile), tiles_w_((width + tile - 1) / tile),
          box_(static_cast<std::size_t>(tiles_w_) * static_cast<std::size_t>((height + tile - 1) / tile), Eigen::Vector4i(width, height, -1, -1)) {}

    // Marks texels r = (i0, j0, i1, j1), inclusive, within the layout: every tile they meet, its
    // box grown to hold them.
    void mark(const Eigen::Vector4i& r) {
        for (int tj = r[1] / tile_; tj <= r[3] / tile_; ++tj) {
            for (int ti = r[0] / tile_; ti <= r[2] / tile_; ++ti) {
                Eigen::Vector4i& b = box_[static_cast<std::size_t>(tj * tiles_w_ + ti)];
                b[0] = std::min(b[0], std::max(r[0], ti * tile_));
                b[1] = std::min(b[1], std::max(r[1], tj * tile_));
                b[2] = std::max(b[2], std::min(r[2], ti * tile_ + tile_ - 1));
                b[3] = std::max(b[3], std::min(r[3], tj * tile_ + tile_ - 1));
            }
        }
    }
    std::size_t tiles() const noexcept { return box_.size(); }
    bool marked(std::size_t tile) const { return box_[tile][0] <= box_[tile][2]; }
    // The box (i0, j0, i1, j1) of the texels marked in tile `tile` (row-major); empty: i0 > i1.
    const Eigen::Vector4i& box(std::size_t tile) const { return box_[tile]; }

private:
    int tile_, tiles_w_;
    std::vector<Eigen::Vector4i> box_;
};

}  // namespace commonlight::lighting

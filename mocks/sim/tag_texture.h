// Exact textures of AprilTags, drawn by libapriltag (apriltag_to_image), for the simulated scene.
//
// A tag is a square in its x-y plane, centred on its origin, printed side +z, the image's top
// row towards +y (docs/formats-scene.md). The scene's `size` is the edge of the black square,
// which is `width_at_border` cells wide; the texture covers all `total_width` cells of the
// family's image (for tag36h11: 8 cells of black square inside a one-cell white border, 10 in
// all). Lookups are nearest-cell, so the tag's edges are perfectly sharp.
#pragma once

#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/pose.h"
#include "core/result.h"
#include "core/scene.h"

namespace commonlight::mocks::sim {

class TagTexture {
public:
    // Draws tag `id` of `family` ("tag36h11", ... as in the scene file); fails (kBadInput) for an
    // unknown family or an id out of its range.
    static Result<TagTexture> make(const std::string& family, int id);

    int id() const noexcept { return id_; }
    int totalWidth() const noexcept { return total_width_; }         // cells across the whole image
    int widthAtBorder() const noexcept { return width_at_border_; }  // cells across the black square
    // True when the cell (column, row), counted from the image's top-left, is white.
    bool isWhite(int column, int row) const noexcept {
        return cells_[static_cast<std::size_t>(row) * total_width_ + column] != 0;
    }

private:
    int id_ = 0;
    int total_width_ = 0;
    int width_at_border_ = 0;
    std::vector<std::uint8_t> cells_;  // total_width^2, row-major from the top-left, 1 = white
};

// A tag placed in the simulated world.
struct PlacedTag {
    TagTexture texture;
    Rigid3d world_from_tag;
    Rigid3d tag_from_world;
    double size = 0.0;       // edge of the black square, metres
    double half_extent = 0;  // half the edge of the whole printed square (with the white border), metres
    double albedo_black = 0.04;
    double albedo_white = 0.8;
    // Ink spread of the print, in cells: > 0 grows every black region by this distance (each
    // black/white boundary moves into the white cell, as ink bleeding into the paper), < 0 shrinks
    // them (the white grows). In [-0.25, 0.25]; 0 prints the exact pattern.
    double ink_spread_cells = 0.0;

    // Albedo at (x, y) in the tag frame (metres), nearest cell; points outside the printed square
    // are clamped to the border cells. Edge convention: a point exactly on a cell boundary belongs
    // to the cell on its +x / -y side (floor of the cell coordinate). With ink spread, a point is
    // black when a black cell lies within `ink_spread_cells` of it (L-infinity distance; white
    // when ink spread < 0 and a white cell lies within |ink_spread_cells|), so every boundary
    // moves by exactly that distance along its normal.
    double albedoAt(double x, double y) const noexcept;
    // Whether (x, y) in the tag frame lies on the printed square.
    bool contains(double x, double y) const noexcept {
        return std::abs(x) <= half_extent && std::abs(y) <= half_extent;
    }
};

// The tags of a scene, ready to render. Tags of size 0 are skipped. `ink_spread_cells` is every
// tag's PlacedTag::ink_spread_cells (kBadInput outside [-0.25, 0.25]).
Result<std::vector<PlacedTag>> makePlacedTags(const TagSet& tags, double ink_spread_cells = 0.0);

}  // namespace commonlight::mocks::sim

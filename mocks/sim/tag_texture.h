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

    // Albedo at (x, y) in the tag frame (metres), nearest cell; points outside the printed square
    // are clamped to the border cells. Edge convention: a point exactly on a cell boundary belongs
    // to the cell on its +x / -y side (floor of the cell coordinate).
    double albedoAt(double x, double y) const noexcept;
    // Whether (x, y) in the tag frame lies on the printed square.
    bool contains(double x, double y) const noexcept {
        return std::abs(x) <= half_extent && std::abs(y) <= half_extent;
    }
};

// The tags of a scene, ready to render. Tags of size 0 are skipped.
Result<std::vector<PlacedTag>> makePlacedTags(const TagSet& tags);

}  // namespace commonlight::mocks::sim

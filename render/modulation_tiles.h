// The final pass's regions at the grain of camera tiles (the kBlock-pixel blocks of the lens map's
// footprint): which tiles can show a texel the snapshot changes (FaceInAtlas::influence_blocks,
// projected into the layer and through the lens map to the camera), and the tiles as quads, so
// each program of the final pass is one draw over its tiles (llvmpipe has a cost per draw call).
// Internal to render/ (the compositor's units include it through compositor_impl.h).
#pragma once

#include <cstdint>
#include <vector>

#include "render/gl_objects.h"

namespace commonlight::render {

namespace compositor_detail {

// Pixels [x0, x1] x [y0, y1], inclusive, in some framebuffer's GL rows.
struct Rect {
    int x0 = 0, y0 = 0, x1 = -1, y1 = -1;
    bool empty() const { return x1 < x0 || y1 < y0; }
    void scissor() const { glScissor(x0, y0, x1 - x0 + 1, y1 - y0 + 1); }
};

// The smallest rectangle around both.
Rect unite(const Rect& a, const Rect& b);

// Layer pixels marked in square cells of kCoverageCell pixels, then asked about rectangles through
// a summed-area table: "does this rectangle meet a marked cell" in four reads. Conservative by up
// to a cell on each side.
inline constexpr int kCoverageCell = 4;
class CoverageGrid {
public:
    // Nothing marked, over a layer of this size.
    void reset(int width, int height);
    // Marks the cells that meet `r` (layer pixels; clipped to the layer).
    void mark(const Rect& r);
    // Builds the table (after the last mark, before any()).
    void finish();
    // Whether `r` (layer pixels; clipped to the layer) meets a marked cell.
    bool any(const Rect& r) const;

private:
    int width_ = 0, height_ = 0, cols_ = 0, rows_ = 0;
    std::vector<std::uint8_t> marked_;  // cols_ x rows_
    std::vector<int> sum_;              // (cols_ + 1) x (rows_ + 1): marked cells below and left of each corner
};

// Camera tiles as flags, row-major; tile (i, j) covers the camera pixels [i, i + 1) x [j, j + 1)
// times `size` (the last ones cut at the camera's edges); rows are the output's, image rows.
struct TileMask {
    int cols = 0, rows = 0, size = 0;
    std::vector<std::uint8_t> on;

    void reset(int width, int height, int tile_size);
    // Marks every tile that meets the camera pixels `r`.
    void markPixels(const Rect& r);
    int count() const;
    // The camera pixels of the marked tiles' bounding box (empty: none marked).
    Rect bounds(int width, int height) const;
};

// The quads over the tiles whose flag is `on`, leaving out the camera pixels `skip` (whole tiles, or
// empty), as two triangles each of clip-space (x, y) vertices appended to `vertices`: each row's
// runs of tiles merged, and a run merged with the same run of the rows below it. Returns the camera
// pixels they cover.
long appendTileQuads(const TileMask& mask, bool on, const Rect& skip, int width, int height, std::vector<float>& vertices);

}  // namespace compositor_detail

}  // namespace commonlight::render

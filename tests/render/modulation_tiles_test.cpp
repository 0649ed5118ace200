// The final pass's tile helpers on the CPU (render/modulation_tiles.h): the quads over a tile mask
// cover each wanted camera pixel exactly once and nothing else (edge tiles cut at the camera's
// size, the virtual layer's rectangle left out); the layer cells answer "does this rectangle meet
// a marked one" never no where it does, and never yes farther than a cell away.
#include "render/modulation_tiles.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

namespace commonlight::render {
namespace {

using compositor_detail::appendTileQuads;
using compositor_detail::CoverageGrid;
using compositor_detail::kCoverageCell;
using compositor_detail::Rect;
using compositor_detail::TileMask;

// How many quads cover each pixel (row-major), the quads' clip-space vertices back to pixels.
std::vector<int> coverage(const std::vector<float>& vertices, int width, int height) {
    std::vector<int> count(static_cast<std::size_t>(width) * static_cast<std::size_t>(height), 0);
    for (std::size_t q = 0; q + 12 <= vertices.size(); q += 12) {
        const auto px = [&](float v, int size) { return static_cast<int>(std::lround((v + 1.0f) * 0.5f * static_cast<float>(size))); };
        const int x0 = px(vertices[q], width), y0 = px(vertices[q + 1], height), x1 = px(vertices[q + 4], width), y1 = px(vertices[q + 5], height);
        for (int y = y0; y < y1; ++y) {
            for (int x = x0; x < x1; ++x) ++count[static_cast<std::size_t>(y * width + x)];
        }
    }
    return count;
}

TEST(ModulationTiles, QuadsCoverEachWantedPixelOnceAndMergeRuns) {
    const int width = 150, height = 70;  // edge tiles of 6 x 6 px
    std::mt19937 rng(3);
    for (int round = 0; round < 50; ++round) {
        TileMask mask;
        mask.reset(width, height, 16);
        ASSERT_EQ(mask.cols, 10);
        ASSERT_EQ(mask.rows, 5);
        for (auto& t : mask.on) t = (rng() % 3 == 0) ? 1 : 0;
        // Every other round a rectangle of whole tiles left out (the virtual layer's).
        Rect skip;
        if (round % 2 == 1) {
            const int i0 = static_cast<int>(rng() % 10), j0 = static_cast<int>(rng() % 5);
            skip = Rect{16 * i0, 16 * j0, std::min(width, 16 * (i0 + 1 + static_cast<int>(rng() % 3))) - 1,
                        std::min(height, 16 * (j0 + 1 + static_cast<int>(rng() % 2))) - 1};
        }
        std::vector<float> on_quads, off_quads;
        const long on_pixels = appendTileQuads(mask, true, skip, width, height, on_quads);
        const long off_pixels = appendTileQuads(mask, false, skip, width, height, off_quads);
        const std::vector<int> on = coverage(on_quads, width, height), off = coverage(off_quads, width, height);
        long on_count = 0, off_count = 0, wrong = 0;
        for (int y = 0; y < height; ++y) {
            for (int x = 0; x < width; ++x) {
                const std::size_t k = static_cast<std::size_t>(y * width + x);
                const bool skipped = !skip.empty() && x >= skip.x0 && x <= skip.x1 && y >= skip.y0 && y <= skip.y1;
                const bool marked = mask.on[static_cast<std::size_t>(y / 16 * mask.cols + x / 16)] != 0;
                wrong += on[k] != (!skipped && marked ? 1 : 0) ? 1 : 0;
                wrong += off[k] != (!skipped && !marked ? 1 : 0) ? 1 : 0;
                on_count += on[k];
                off_count += off[k];
            }
        }
        EXPECT_EQ(wrong, 0) << "round " << round;
        EXPECT_EQ(on_pixels, on_count);
        EXPECT_EQ(off_pixels, off_count);
    }
    // Runs merged: a frame of one flag is one quad, a column of marked tiles one quad.
    TileMask mask;
    mask.reset(width, height, 16);
    std::vector<float> quads;
    appendTileQuads(mask, false, Rect{}, width, height, quads);
    EXPECT_EQ(quads.size(), 12u);
    for (int j = 0; j < mask.rows; ++j) mask.on[static_cast<std::size_t>(j * mask.cols + 4)] = 1;
    quads.clear();
    appendTileQuads(mask, true, Rect{}, width, height, quads);
    EXPECT_EQ(quads.size(), 12u);
    quads.clear();
    appendTileQuads(mask, false, Rect{}, width, height, quads);
    EXPECT_EQ(quads.size(), 24u);  // left and right of it
    EXPECT_EQ(mask.count(), 5);
    const Rect b = mask.bounds(width, height);
    EXPECT_EQ(b.x0, 64);
    EXPECT_EQ(b.x1, 79);
    EXPECT_EQ(b.y0, 0);
    EXPECT_EQ(b.y1, height - 1);
}

TEST(ModulationTiles, LayerCellsAreConservativeByLessThanACell) {
    const int width = 101, height = 77;
    std::mt19937 rng(9);
    for (int round = 0; round < 30; ++round) {
        CoverageGrid grid;
        grid.reset(width, height);
        std::vector<std::uint8_t> marked(static_cast<std::size_t>(width) * static_cast<std::size_t>(height), 0);
        for (int k = 0; k < 3; ++k) {
            const int x0 = static_cast<int>(rng() % width) - 5, y0 = static_cast<int>(rng() % height) - 5;
            const Rect r{x0, y0, x0 + static_cast<int>(rng() % 12), y0 + static_cast<int>(rng() % 12)};
            grid.mark(r);
            for (int y = std::max(0, r.y0); y <= std::min(height - 1, r.y1); ++y) {
                for (int x = std::max(0, r.x0); x <= std::min(width - 1, r.x1); ++x) marked[static_cast<std::size_t>(y * width + x)] = 1;
            }
        }
        grid.finish();
        // Whether a marked pixel lies in `r` grown by `grow` pixels.
        const auto near = [&](const Rect& r, int grow) {
            for (int y = std::max(0, r.y0 - grow); y <= std::min(height - 1, r.y1 + grow); ++y) {
                for (int x = std::max(0, r.x0 - grow); x <= std::min(width - 1, r.x1 + grow); ++x) {
                    if (marked[static_cast<std::size_t>(y * width + x)]) return true;
                }
            }
            return false;
        };
        int missed = 0, far = 0;
        for (int q = 0; q < 200; ++q) {
            const int x0 = static_cast<int>(rng() % (width + 10)) - 5, y0 = static_cast<int>(rng() % (height + 10)) - 5;
            const Rect r{x0, y0, x0 + static_cast<int>(rng() % 6), y0 + static_cast<int>(rng() % 6)};
            const bool any = grid.any(r);
            missed += near(r, 0) && !any ? 1 : 0;
            far += any && !near(r, kCoverageCell - 1) ? 1 : 0;
        }
        EXPECT_EQ(missed, 0) << "round " << round;
        EXPECT_EQ(far, 0) << "round " << round;
    }
}

}  // namespace
}  // namespace commonlight::render

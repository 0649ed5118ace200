#include "render/modulation_tiles.h"

#include "render/compositor_impl.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>

namespace commonlight::render {

namespace compositor_detail {

Rect unite(const Rect& a, const Rect& b) {
    if (a.empty()) return b;
    if (b.empty()) return a;
    return Rect{std::min(a.x0, b.x0), std::min(a.y0, b.y0), std::max(a.x1, b.x1), std::max(a.y1, b.y1)};
}

void CoverageGrid::reset(int width, int height) {
    width_ = std::max(0, width);
    height_ = std::max(0, height);
    cols_ = (width_ + kCoverageCell - 1) / kCoverageCell;
    rows_ = (height_ + kCoverageCell - 1) / kCoverageCell;
    marked_.assign(static_cast<std::size_t>(cols_) * static_cast<std::size_t>(rows_), 0);
    sum_.assign(static_cast<std::size_t>(cols_ + 1) * static_cast<std::size_t>(rows_ + 1), 0);
}

void CoverageGrid::mark(const Rect& r) {
    const int x0 = std::max(0, r.x0), y0 = std::max(0, r.y0), x1 = std::min(width_ - 1, r.x1), y1 = std::min(height_ - 1, r.y1);
    if (x1 < x0 || y1 < y0) return;
    const int c0 = x0 / kCoverageCell, c1 = x1 / kCoverageCell;
    for (int row = y0 / kCoverageCell; row <= y1 / kCoverageCell; ++row) {
        std::memset(marked_.data() + static_cast<std::size_t>(row) * static_cast<std::size_t>(cols_) + static_cast<std::size_t>(c0), 1,
                    static_cast<std::size_t>(c1 - c0 + 1));
    }
}

void CoverageGrid::finish() {
    const std::size_t stride = static_cast<std::size_t>(cols_ + 1);
    for (int row = 0; row < rows_; ++row) {
        int line = 0;
        for (int col = 0; col < cols_; ++col) {
            line += marked_[static_cast<std::size_t>(row) * static_cast<std::size_t>(cols_) + static_cast<std::size_t>(col)];
            sum_[static_cast<std::size_t>(row + 1) * stride + static_cast<std::size_t>(col + 1)] =
                sum_[static_cast<std::size_t>(row) * stride + static_cast<std::size_t>(col + 1)] + line;
        }
    }
}

bool CoverageGrid::any(const Rect& r) const {
    const int x0 = std::max(0, r.x0), y0 = std::max(0, r.y0), x1 = std::min(width_ - 1, r.x1), y1 = std::min(height_ - 1, r.y1);
    if (x1 < x0 || y1 < y0) return false;
    const std::size_t stride = static_cast<std::size_t>(cols_ + 1);
    const std::size_t c0 = static_cast<std::size_t>(x0 / kCoverageCell), c1 = static_cast<std::size_t>(x1 / kCoverageCell) + 1;
    const std::size_t r0 = static_cast<std::size_t>(y0 / kCoverageCell), r1 = static_cast<std::size_t>(y1 / kCoverageCell) + 1;
    return sum_[r1 * stride + c1] - sum_[r0 * stride + c1] - sum_[r1 * stride + c0] + sum_[r0 * stride + c0] > 0;
}

void TileMask::reset(int width, int height, int tile_size) {
    size = tile_size;
    cols = (width + tile_size - 1) / tile_size;
    rows = (height + tile_size - 1) / tile_size;
    on.assign(static_cast<std::size_t>(cols) * static_cast<std::size_t>(rows), 0);
}

void TileMask::markPixels(const Rect& r) {
    if (r.empty()) return;
    const int i0 = std::max(0, r.x0 / size), i1 = std::min(cols - 1, r.x1 / size);
    const int j0 = std::max(0, r.y0 / size), j1 = std::min(rows - 1, r.y1 / size);
    for (int j = j0; j <= j1; ++j) {
        for (int i = i0; i <= i1; ++i) on[static_cast<std::size_t>(j * cols + i)] = 1;
    }
}

int TileMask::count() const { return static_cast<int>(std::count(on.begin(), on.end(), std::uint8_t{1})); }

Rect TileMask::bounds(int width, int height) const {
    Rect r{1 << 30, 1 << 30, -1, -1};
    for (int j = 0; j < rows; ++j) {
        for (int i = 0; i < cols; ++i) {
            if (!on[static_cast<std::size_t>(j * cols + i)]) continue;
            r.x0 = std::min(r.x0, i * size);
            r.y0 = std::min(r.y0, j * size);
            r.x1 = std::max(r.x1, std::min(width, (i + 1) * size) - 1);
            r.y1 = std::max(r.y1, std::min(height, (j + 1) * size) - 1);
        }
    }
    return r.x1 < 0 ? Rect{} : r;
}

long appendTileQuads(const TileMask& mask, bool on, const Rect& skip, int width, int height, std::vector<float>& vertices) {
    struct Run {
        int i0, i1, j0, j1;  // tiles, inclusive
    };
    std::vector<Run> open, next;  // the runs reaching the previous row, then this row's
    long pixels = 0;
    const auto emit = [&](const Run& run) {
        const int x0 = run.i0 * mask.size, x1 = std::min(width, (run.i1 + 1) * mask.size);
        const int y0 = run.j0 * mask.size, y1 = std::min(height, (run.j1 + 1) * mask.size);
        pixels += static_cast<long>(x1 - x0) * static_cast<long>(y1 - y0);
        const float ax = 2.0f * static_cast<float>(x0) / static_cast<float>(width) - 1.0f;
        const float bx = 2.0f * static_cast<float>(x1) / static_cast<float>(width) - 1.0f;
        const float ay = 2.0f * static_cast<float>(y0) / static_cast<float>(height) - 1.0f;
        const float by = 2.0f * static_cast<float>(y1) / static_cast<float>(height) - 1.0f;
        vertices.insert(vertices.end(), {ax, ay, bx, ay, bx, by, ax, ay, bx, by, ax, by});
    };
    for (int j = 0; j <= mask.rows; ++j) {
        next.clear();
        for (int i = 0; j < mask.rows && i < mask.cols;) {
            const auto wanted = [&](int k) {
                const bool skipped = !skip.empty() && k * mask.size >= skip.x0 && k * mask.size <= skip.x1 && j * mask.size >= skip.y0 &&
                                     j * mask.size <= skip.y1;
                return !skipped && (mask.on[static_cast<std::size_t>(j * mask.cols + k)] != 0) == on;
            };
            if (!wanted(i)) {
                ++i;
                continue;
            }
            int end = i;
            while (end + 1 < mask.cols && wanted(end + 1)) ++end;
            next.push_back({i, end, j, j});
            i = end + 1;
        }
        // A run the same as one of the previous row's continues it; the others end there.
        for (Run& run : next) {
            const auto same = std::find_if(open.begin(), open.end(), [&](const Run& o) { return o.i0 == run.i0 && o.i1 == run.i1; });
            if (same != open.end()) {
                run.j0 = same->j0;
                same->i0 = -1;  // taken
            }
        }
        for (const Run& run : open) {
            if (run.i0 >= 0) emit(run);
        }
        std::swap(open, next);
    }
    return pixels;
}

}  // namespace compositor_detail

// The layer pixels (GL rows) of a quad given in camera coordinates: its part in front of the
// camera's near plane (Sutherland-Hodgman against one plane), projected, with 2 pixels for the
// filtering. Empty when it is all behind; the whole layer when a projection is not finite.
Rect Compositor::Impl::projectedQuad(const std::array<Eigen::Vector3d, 4>& c) const {
    constexpr double kNear = 0.01;
    double x0 = 1e30, y0 = 1e30, x1 = -1e30, y1 = -1e30;
    for (std::size_t k = 0; k < 4; ++k) {
        const Eigen::Vector3d& a = c[k];
        const Eigen::Vector3d& b = c[(k + 1) % 4];
        Eigen::Vector3d kept[2];
        int n = 0;
        if (a.z() >= kNear) kept[n++] = a;
        if ((a.z() >= kNear) != (b.z() >= kNear)) kept[n++] = a + (b - a) * ((kNear - a.z()) / (b.z() - a.z()));
        for (int m = 0; m < n; ++m) {
            const Eigen::Vector3d& p = kept[m];
            const double u = layer_camera.fx * p.x() / p.z() + layer_camera.cx;
            const double v = layer_camera.fy * p.y() / p.z() + layer_camera.cy;
            if (!std::isfinite(u) || !std::isfinite(v)) return Rect{0, 0, layer_width - 1, layer_height - 1};
            x0 = std::min(x0, u);
            x1 = std::max(x1, u);
            y0 = std::min(y0, v);
            y1 = std::max(y1, v);
        }
    }
    if (x0 > x1) return Rect{};
    // Image rows (down) to GL rows (up).
    Rect r;
    r.x0 = static_cast<int>(std::max(0.0, std::floor(std::max(-1.0, x0) - 2.0)));
    r.x1 = static_cast<int>(std::min(layer_width - 1.0, std::ceil(std::min(1e6, x1) + 2.0)));
    r.y0 = static_cast<int>(std::max(0.0, std::floor(layer_height - 1.0 - std::min(1e6, y1) - 2.0)));
    r.y1 = static_cast<int>(std::min(layer_height - 1.0, std::ceil(layer_height - 1.0 - std::max(-1.0, y0) + 2.0)));
    return r;
}

// The layer pixels (GL rows) where the snapshot's modulation can change the frame: the influenced
// part of every face (SnapshotTextures), clipped at the camera's near plane and projected, with 2
// pixels for the filtering. Empty when the snapshot changes nothing.
Rect Compositor::Impl::influenceRect(const Eigen::Matrix4d& cam_from_world) const {
    Rect r;
    for (const auto& [key, face] : snapshot_textures.faces()) {
        const Eigen::Vector4f& in = face.influence;
        if (in[0] > in[2] || in[1] > in[3]) continue;
        const Eigen::Vector2f st[4] = {{in[0], in[1]}, {in[2], in[1]}, {in[2], in[3]}, {in[0], in[3]}};
        std::array<Eigen::Vector3d, 4> c;
        for (std::size_t k = 0; k < 4; ++k) {
            const Eigen::Vector3f w = face.c0 + st[k].x() * face.e1 + st[k].y() * face.e2;
            c[k] = (cam_from_world * Eigen::Vector4d(w.x(), w.y(), w.z(), 1.0)).head<3>();
        }
        r = unite(r, projectedQuad(c));
    }
    return r;
}

// The camera tiles whose pixels can read a layer pixel where the snapshot changes the frame: each
// face's influenced blocks of texels (FaceInAtlas::influence_blocks) projected as influenceRect
// projects the whole, marked in layer cells; a tile is marked when the layer footprint of its
// pixels (block_bounds: their ideal positions, one pixel wider for the filtering's neighbours)
// meets a marked cell. Where a tile is not marked, every pixel's modulation is within
// kModulationEpsilon of 1 and its difference zero, so the modulating program would write the
// frame's code there.
void Compositor::Impl::markInfluenceTiles(const Eigen::Matrix4d& cam_from_world, TileMask& tiles) {
    influence_cells.reset(layer_width, layer_height);
    for (const auto& [key, face] : snapshot_textures.faces()) {
        if (face.influence[0] > face.influence[2] || face.influence[1] > face.influence[3]) continue;
        // The face's parametrisation in camera coordinates: p = c0 + s e1 + t e2.
        const Eigen::Matrix3d r = cam_from_world.topLeftCorner<3, 3>();
        const Eigen::Vector3d c0 = r * face.c0.cast<double>() + cam_from_world.topRightCorner<3, 1>();
        const Eigen::Vector3d e1 = r * face.e1.cast<double>(), e2 = r * face.e2.cast<double>();
        for (const Eigen::Vector4f& in : face.influence_blocks) {
            const Eigen::Vector2f st[4] = {{in[0], in[1]}, {in[2], in[1]}, {in[2], in[3]}, {in[0], in[3]}};
            std::array<Eigen::Vector3d, 4> c;
            for (std::size_t k = 0; k < 4; ++k) c[k] = c0 + static_cast<double>(st[k].x()) * e1 + static_cast<double>(st[k].y()) * e2;
            influence_cells.mark(projectedQuad(c));
        }
    }
    influence_cells.finish();
    for (int by = 0; by < blocks_y && by < tiles.rows; ++by) {
        for (int bx = 0; bx < blocks_x && bx < tiles.cols; ++bx) {
            const Eigen::Vector4f& b = block_bounds[static_cast<std::size_t>(by * blocks_x + bx)];
            if (b[0] > b[2]) continue;  // no pixel of the block has an ideal position: nothing to modulate
            const Rect footprint{static_cast<int>(std::floor(b[0])) - 1, static_cast<int>(std::floor(b[1])) - 1,
                                 static_cast<int>(std::floor(b[2])), static_cast<int>(std::floor(b[3]))};
            if (influence_cells.any(footprint)) tiles.on[static_cast<std::size_t>(by * tiles.cols + bx)] = 1;
        }
    }
}

// The camera tiles the final pass modulates this frame (`modulation_tiles`, reset by the caller),
// by CompositorOptions::modulation_region; the debug views of the modulation show it wherever the
// layer is (as one rectangle).
void Compositor::Impl::markModulationTiles(const Eigen::Matrix4d& cam_from_world, const Rect& virtual_camera_rect) {
    if (options.debug == DebugView::kElements || options.debug == DebugView::kRatio) {
        modulation_tiles.markPixels(unite(virtual_camera_rect, cameraRect(Rect{0, 0, layer_width - 1, layer_height - 1})));
    } else if (options.modulation_region == ModulationRegion::kFrame) {
        modulation_tiles.markPixels(Rect{0, 0, width - 1, height - 1});
    } else if (options.modulation_region == ModulationRegion::kRectangle) {
        modulation_tiles.markPixels(unite(virtual_camera_rect, cameraRect(influenceRect(cam_from_world))));
    } else {
        markInfluenceTiles(cam_from_world, modulation_tiles);
    }
}

void Compositor::Impl::makeTileBuffers() {
    tile_vao = gl::newVertexArray();
    tile_vbo = gl::newBuffer();
    glBindVertexArray(tile_vao);
    glBindBuffer(GL_ARRAY_BUFFER, tile_vbo);
    glEnableVertexAttribArray(0);
    glVertexAttribPointer(0, 2, GL_FLOAT, GL_FALSE, 2 * sizeof(float), nullptr);
    glBindVertexArray(0);
    glBindBuffer(GL_ARRAY_BUFFER, 0);
}

// The quads of the unmarked tiles, then of the marked ones, outside the virtual layer's rectangle,
// into the tile buffer; their vertex counts. Starts `final_area` of this draw.
std::pair<GLsizei, GLsizei> Compositor::Impl::uploadTileQuads(const Rect& virtual_camera_rect) {
    final_area = FinalPassArea{};
    final_area.modulated_tiles = modulation_tiles.count();
    tile_vertices.clear();
    final_area.plain = appendTileQuads(modulation_tiles, false, virtual_camera_rect, width, height, tile_vertices);
    const GLsizei plain = static_cast<GLsizei>(tile_vertices.size() / 2);
    final_area.modulated = appendTileQuads(modulation_tiles, true, virtual_camera_rect, width, height, tile_vertices);
    const GLsizei modulated = static_cast<GLsizei>(tile_vertices.size() / 2) - plain;
    glBindBuffer(GL_ARRAY_BUFFER, tile_vbo);
    glBufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(tile_vertices.size() * sizeof(float)), tile_vertices.data(), GL_STREAM_DRAW);
    glBindBuffer(GL_ARRAY_BUFFER, 0);
    return {plain, modulated};
}

// Quads of the tile buffer (vertices [first, first + count)) with the bound program.
void Compositor::Impl::drawTileQuads(GLint first, GLsizei count) {
    if (count <= 0) return;
    glBindVertexArray(tile_vao);
    glDrawArrays(GL_TRIANGLES, first, count);
    glBindVertexArray(0);
    ++final_area.draws;
}

// The full-screen triangle with the bound program, scissored to the virtual layer's camera pixels.
void Compositor::Impl::drawVirtualRect(const Rect& r) {
    glEnable(GL_SCISSOR_TEST);
    r.scissor();
    glBindVertexArray(empty_vao);
    glDrawArrays(GL_TRIANGLES, 0, 3);
    glBindVertexArray(0);
    glDisable(GL_SCISSOR_TEST);
    ++final_area.draws;
    final_area.with_virtual = static_cast<long>(r.x1 - r.x0 + 1) * static_cast<long>(r.y1 - r.y0 + 1);
}

}  // namespace commonlight::render

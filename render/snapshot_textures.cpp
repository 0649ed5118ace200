#include "render/snapshot_textures.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <numeric>
#include <string>

#include <Eigen/LU>

#include "core/log.h"

namespace commonlight::render {

namespace {

GLuint atlasTexture(int width, int height, const std::vector<float>& rgba, GLenum filter) {
    const GLuint t = gl::newTexture();
    glBindTexture(GL_TEXTURE_2D, t);
    glPixelStorei(GL_UNPACK_ALIGNMENT, 4);
    glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA32F, width, height, 0, GL_RGBA, GL_FLOAT, rgba.data());
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, static_cast<GLint>(filter));
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, static_cast<GLint>(filter));
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
    return t;
}

// One face's texels as the atlas holds them: M, D and B~ (element outlines darkened) as RGBA
// blocks of (width + 2) x (height + 2), the frame copying the edge texels; and where the face is
// influenced (FaceInAtlas::influence).
struct FaceBlock {
    std::vector<float> m, d, o;
    Eigen::Vector4f influence = Eigen::Vector4f(1.0f, 1.0f, 0.0f, 0.0f);
    std::vector<Eigen::Vector4f> influence_blocks;
};

// (s0, t0, s1, t1) around texels [i0, i1] x [j0, j1] of a face, one texel wider for the filtering.
Eigen::Vector4f texelBounds(const lighting::FaceModulation& f, int i0, int j0, int i1, int j1) {
    const float fw = static_cast<float>(f.width), fh = static_cast<float>(f.height);
    return Eigen::Vector4f(std::max(0.0f, static_cast<float>(i0 - 1) / fw), std::max(0.0f, static_cast<float>(j0 - 1) / fh),
                           std::min(1.0f, static_cast<float>(i1 + 2) / fw), std::min(1.0f, static_cast<float>(j1 + 2) / fh));
}

FaceBlock faceBlock(const lighting::FaceModulation& f) {
    const std::size_t n = static_cast<std::size_t>(f.width) * static_cast<std::size_t>(f.height);
    std::vector<float> fm(3 * n), fd(3 * n), fo(3 * n);
    int in_i0 = f.width, in_j0 = f.height, in_i1 = -1, in_j1 = -1;  // the influenced texels' bounds
    // and per block of kInfluenceBlock texels (i0, j0, i1, j1; i1 < 0: none)
    const int blocks_s = (f.width + kInfluenceBlock - 1) / kInfluenceBlock, blocks_t = (f.height + kInfluenceBlock - 1) / kInfluenceBlock;
    std::vector<std::array<int, 4>> blocks(static_cast<std::size_t>(blocks_s) * static_cast<std::size_t>(blocks_t),
                                           std::array<int, 4>{f.width, f.height, -1, -1});
    for (std::size_t k = 0; k < n; ++k) {
        const float w = lighting::ratioWeight(lighting::luminance(f.original[k]), f.mean_original);
        for (std::size_t c = 0; c < 3; ++c) {
            const float ratio = std::isfinite(f.ratio[k][static_cast<int>(c)]) ? f.ratio[k][static_cast<int>(c)] : 1.0f;
            const float diff = std::isfinite(f.difference[k][static_cast<int>(c)]) ? f.difference[k][static_cast<int>(c)] : 0.0f;
            const float orig = f.original[k][static_cast<int>(c)];
            fm[3 * k + c] = w * ratio + (1.0f - w);
            fd[3 * k + c] = (1.0f - w) * diff;
            fo[3 * k + c] = std::isfinite(orig) ? orig : 0.0f;
        }
        bool influenced = false;
        for (std::size_t c = 0; c < 3; ++c) {
            influenced = influenced || std::abs(fm[3 * k + c] - 1.0f) > kModulationEpsilon || fd[3 * k + c] != 0.0f;
        }
        if (influenced) {
            const int i = static_cast<int>(k % static_cast<std::size_t>(f.width)), j = static_cast<int>(k / static_cast<std::size_t>(f.width));
            in_i0 = std::min(in_i0, i);
            in_j0 = std::min(in_j0, j);
            in_i1 = std::max(in_i1, i);
            in_j1 = std::max(in_j1, j);
            std::array<int, 4>& b = blocks[static_cast<std::size_t>(j / kInfluenceBlock * blocks_s + i / kInfluenceBlock)];
            b = {std::min(b[0], i), std::min(b[1], j), std::max(b[2], i), std::max(b[3], j)};
        }
    }
    FaceBlock out;
    if (in_i1 >= 0) out.influence = texelBounds(f, in_i0, in_j0, in_i1, in_j1);
    for (const std::array<int, 4>& b : blocks) {
        if (b[2] >= 0) out.influence_blocks.push_back(texelBounds(f, b[0], b[1], b[2], b[3]));
    }
    // Element outlines in the debug view of B~: a darker rim on the texels at element borders.
    const auto darken = [&](int i, int j) {
        for (std::size_t c = 0; c < 3; ++c) fo[3 * f.texel(i, j) + c] *= 0.6f;
    };
    for (const Eigen::Vector4f& e : f.elements) {
        const int i0 = std::clamp(static_cast<int>(e[0] * static_cast<float>(f.width)), 0, f.width - 1);
        const int j0 = std::clamp(static_cast<int>(e[1] * static_cast<float>(f.height)), 0, f.height - 1);
        const int i1 = std::clamp(static_cast<int>(std::ceil(e[2] * static_cast<float>(f.width))) - 1, 0, f.width - 1);
        const int j1 = std::clamp(static_cast<int>(std::ceil(e[3] * static_cast<float>(f.height))) - 1, 0, f.height - 1);
        for (int i = i0; i <= i1; ++i) {
            darken(i, j0);
            if (j1 != j0) darken(i, j1);
        }
        for (int j = j0 + 1; j < j1; ++j) {
            darken(i0, j);
            if (i1 != i0) darken(i1, j);
        }
    }
    const std::size_t bw = static_cast<std::size_t>(f.width + 2), bh = static_cast<std::size_t>(f.height + 2);
    out.m.assign(4 * bw * bh, 1.0f);
    out.d.assign(4 * bw * bh, 0.0f);
    out.o.assign(4 * bw * bh, 0.0f);
    for (std::size_t j = 0; j < bh; ++j) {
        for (std::size_t i = 0; i < bw; ++i) {
            const std::size_t src = f.texel(std::clamp(static_cast<int>(i) - 1, 0, f.width - 1), std::clamp(static_cast<int>(j) - 1, 0, f.height - 1));
            const std::size_t dst = j * bw + i;
            for (std::size_t c = 0; c < 3; ++c) {
                out.m[4 * dst + c] = fm[3 * src + c];
                out.d[4 * dst + c] = fd[3 * src + c];
                out.o[4 * dst + c] = fo[3 * src + c];
            }
        }
    }
    return out;
}

// The atlas layout a snapshot's faces need again: which faces, in order, at what size.
std::vector<std::array<int, 4>> layoutKey(const lighting::LightingSnapshot& snapshot) {
    std::vector<std::array<int, 4>> key;
    key.reserve(snapshot.faces.size());
    for (const auto& f : snapshot.faces) key.push_back({f->object_index, f->face, f->width, f->height});
    return key;
}

}  // namespace

void SnapshotTextures::release() {
    gl::deleteTexture(atlas_m_);
    gl::deleteTexture(atlas_d_);
    gl::deleteTexture(atlas_o_);
    faces_.clear();
    for (ProbeGrid& p : probes_) gl::deleteTexture(p.texture);
    probes_.clear();
    version_ = ~0ull;
    address_ = nullptr;
}

const FaceInAtlas* SnapshotTextures::face(int object_index, int face) const {
    const auto it = faces_.find({object_index, face});
    return it == faces_.end() ? nullptr : &it->second;
}

const ProbeGrid* SnapshotTextures::probes(std::size_t virtual_index) const {
    return virtual_index < probes_.size() && probes_[virtual_index].texture != 0 ? &probes_[virtual_index] : nullptr;
}

void SnapshotTextures::update(const lighting::LightingSnapshot& snapshot, std::size_t virtual_objects, bool lighting) {
    if (snapshot.version == version_ && &snapshot == address_ && lighting == lighting_) return;
    // The same faces at the same sizes: only the faces whose revision changed are uploaded again,
    // into their place (a move changes a few faces; the atlas of a desk is 10 MB).
    if (lighting && lighting_ && atlas_m_ != 0 && layoutKey(snapshot) == layout_key_ && revisions_.size() == snapshot.faces.size()) {
        for (std::size_t i = 0; i < snapshot.faces.size(); ++i) {
            const lighting::FaceModulation& f = *snapshot.faces[i];
            if (f.revision != 0 && f.revision == revisions_[i]) continue;
            revisions_[i] = f.revision;
            const auto it = faces_.find({f.object_index, f.face});
            if (it == faces_.end()) continue;  // left out of the atlas (degenerate, or did not fit)
            const FaceBlock block = faceBlock(f);
            it->second.influence = block.influence;
            it->second.influence_blocks = block.influence_blocks;
            const int x = static_cast<int>(it->second.rect.x()) - 1, y = static_cast<int>(it->second.rect.y()) - 1;
            glPixelStorei(GL_UNPACK_ALIGNMENT, 4);
            for (const auto& [texture, data] : {std::pair{atlas_m_, &block.m}, std::pair{atlas_d_, &block.d}, std::pair{atlas_o_, &block.o}}) {
                glBindTexture(GL_TEXTURE_2D, texture);
                glTexSubImage2D(GL_TEXTURE_2D, 0, x, y, f.width + 2, f.height + 2, GL_RGBA, GL_FLOAT, data->data());
            }
        }
        version_ = snapshot.version;
        address_ = &snapshot;
        updateProbes(snapshot, virtual_objects);
        return;
    }
    release();
    layout_key_ = layoutKey(snapshot);
    revisions_.clear();
    for (const auto& f : snapshot.faces) revisions_.push_back(f->revision);
    version_ = snapshot.version;
    address_ = &snapshot;
    lighting_ = lighting;
    if (!lighting) return;

    // Step 1: the faces to pack (a usable size and parametrisation).
    struct Item {
        const lighting::FaceModulation* face;
        FaceInAtlas place;
        int x = 0, y = 0;  // atlas texel of the frame's corner
    };
    std::vector<Item> items;
    for (const auto& face : snapshot.faces) {
        const lighting::FaceModulation& f = *face;
        if (f.width <= 0 || f.height <= 0 || f.corners.size() < 3) continue;
        const std::size_t n = static_cast<std::size_t>(f.width) * static_cast<std::size_t>(f.height);
        if (f.ratio.size() != n || f.difference.size() != n || f.original.size() != n) continue;
        // The face's parametrisation p = c0 + s e1 + t e2 inverted by its dual basis.
        const Eigen::Vector3d c0 = f.corners[0], e1 = f.corners[1] - c0, e2 = f.corners.back() - c0;
        Eigen::Matrix2d g;
        g << e1.dot(e1), e1.dot(e2), e1.dot(e2), e2.dot(e2);
        if (!(std::abs(g.determinant()) > 1e-18)) continue;  // hard case: a degenerate face
        const Eigen::Matrix2d gi = g.inverse();
        Item item;
        item.face = &f;
        item.place.c0 = c0.cast<float>();
        item.place.e1 = e1.cast<float>();
        item.place.e2 = e2.cast<float>();
        item.place.du = (gi(0, 0) * e1 + gi(0, 1) * e2).cast<float>();
        item.place.dv = (gi(1, 0) * e1 + gi(1, 1) * e2).cast<float>();
        items.push_back(item);
    }

    // Step 2: shelf packing, tallest first; each face framed by one texel.
    GLint max_size = 4096;
    glGetIntegerv(GL_MAX_TEXTURE_SIZE, &max_size);
    // The proxies' pass addresses the atlas in sixteenths of a texel in 16 bits (all ones: none).
    max_size = std::min<GLint>(max_size, 4094);
    std::vector<std::size_t> order(items.size());
    std::iota(order.begin(), order.end(), std::size_t{0});
    std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return items[a].face->height > items[b].face->height; });
    double area = 0.0;
    int widest = 1;
    for (const Item& it : items) {
        area += static_cast<double>(it.face->width + 2) * (it.face->height + 2);
        widest = std::max(widest, it.face->width + 2);
    }
    const int width = std::min<int>(max_size, std::max(widest, std::max(64, static_cast<int>(std::ceil(std::sqrt(area))))));
    int x = 0, y = 0, shelf = 0;
    std::vector<Item> placed;
    for (std::size_t k : order) {
        Item& it = items[k];
        const int w = it.face->width + 2, h = it.face->height + 2;
        if (w > width) continue;
        if (x + w > width) {
            y += shelf;
            x = 0;
            shelf = 0;
        }
        if (y + h > max_size) {
            log::warning("render: the snapshot's faces do not fit in a " + std::to_string(max_size) + "-texel atlas; face " +
                         std::to_string(it.face->face) + " of " + it.face->object + " left unmodulated");
            continue;
        }
        it.x = x;
        it.y = y;
        it.place.rect = Eigen::Vector4f(static_cast<float>(x + 1), static_cast<float>(y + 1), static_cast<float>(it.face->width),
                                        static_cast<float>(it.face->height));
        x += w;
        shelf = std::max(shelf, h);
        placed.push_back(it);
    }
    const int height = std::max(1, y + shelf);

    // Step 3: the texels (M, D, B~ with element outlines), the frames copying the edges.
    if (!placed.empty()) {
        const std::size_t texels = static_cast<std::size_t>(width) * static_cast<std::size_t>(height);
        std::vector<float> m(4 * texels, 1.0f), d(4 * texels, 0.0f), o(4 * texels, 0.0f);
        for (const Item& it : placed) {
            const lighting::FaceModulation& f = *it.face;
            const FaceBlock block = faceBlock(f);
            FaceInAtlas place = it.place;
            place.influence = block.influence;
            place.influence_blocks = block.influence_blocks;
            const std::size_t bw = static_cast<std::size_t>(f.width + 2);
            for (std::size_t j = 0; j < static_cast<std::size_t>(f.height + 2); ++j) {
                const std::size_t dst = (static_cast<std::size_t>(it.y) + j) * static_cast<std::size_t>(width) + static_cast<std::size_t>(it.x);
                std::copy_n(block.m.begin() + static_cast<std::ptrdiff_t>(4 * j * bw), 4 * bw, m.begin() + static_cast<std::ptrdiff_t>(4 * dst));
                std::copy_n(block.d.begin() + static_cast<std::ptrdiff_t>(4 * j * bw), 4 * bw, d.begin() + static_cast<std::ptrdiff_t>(4 * dst));
                std::copy_n(block.o.begin() + static_cast<std::ptrdiff_t>(4 * j * bw), 4 * bw, o.begin() + static_cast<std::ptrdiff_t>(4 * dst));
            }
            faces_[{f.object_index, f.face}] = place;
        }
        atlas_m_ = atlasTexture(width, height, m, GL_LINEAR);
        atlas_d_ = atlasTexture(width, height, d, GL_LINEAR);
        atlas_o_ = atlasTexture(width, height, o, GL_NEAREST);
        atlas_size_ = Eigen::Vector2f(static_cast<float>(width), static_cast<float>(height));
    }

    updateProbes(snapshot, virtual_objects);
}

void SnapshotTextures::updateProbes(const lighting::LightingSnapshot& snapshot, std::size_t virtual_objects) {
    // Step 4: the probe grids.
    for (ProbeGrid& p : probes_) gl::deleteTexture(p.texture);
    probes_.assign(virtual_objects, ProbeGrid{});
    for (const lighting::VirtualIrradiance& v : snapshot.virtual_objects) {
        if (v.object_index < 0 || static_cast<std::size_t>(v.object_index) >= probes_.size()) continue;
        if ((v.dims.array() < 1).any()) continue;
        const std::size_t count = static_cast<std::size_t>(v.dims.prod());
        if (v.indirect.size() != count) continue;
        const std::size_t nx = static_cast<std::size_t>(v.dims.x()), ny = static_cast<std::size_t>(v.dims.y());
        const std::size_t nz = static_cast<std::size_t>(v.dims.z());
        std::vector<float> data(count * 9 * 3);
        for (std::size_t p = 0; p < count; ++p) {
            const std::size_t px = p % nx, py = (p / nx) % ny, pz = p / (nx * ny);
            for (std::size_t k = 0; k < 9; ++k) {
                const std::size_t texel = ((k * nz + pz) * ny + py) * nx + px;
                for (std::size_t c = 0; c < 3; ++c) {
                    const float value = v.indirect[p][k][static_cast<int>(c)];
                    data[3 * texel + c] = std::isfinite(value) ? value : 0.0f;
                }
            }
        }
        ProbeGrid grid;
        grid.texture = gl::newTexture();
        glBindTexture(GL_TEXTURE_3D, grid.texture);
        glPixelStorei(GL_UNPACK_ALIGNMENT, 4);
        glTexImage3D(GL_TEXTURE_3D, 0, GL_RGB32F, v.dims.x(), v.dims.y(), 9 * v.dims.z(), 0, GL_RGB, GL_FLOAT, data.data());
        glTexParameteri(GL_TEXTURE_3D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
        glTexParameteri(GL_TEXTURE_3D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
        for (GLenum wrap : {GL_TEXTURE_WRAP_S, GL_TEXTURE_WRAP_T, GL_TEXTURE_WRAP_R}) glTexParameteri(GL_TEXTURE_3D, wrap, GL_CLAMP_TO_EDGE);
        grid.bmin = v.bounds_min.cast<float>();
        grid.bmax = v.bounds_max.cast<float>();
        const Eigen::Array3f dims = v.dims.cast<float>().array();
        grid.scale = ((dims - 1.0f) / dims).matrix();
        grid.offset = (0.5f / dims).matrix();
        probes_[static_cast<std::size_t>(v.object_index)] = grid;
    }
}

}  // namespace commonlight::render

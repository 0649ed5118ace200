#include "lighting/snapshot_builder.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <numbers>
#include <numeric>
#include <optional>

#include "lighting/sampling.h"
#include "lighting/tile_marks.h"

namespace commonlight::lighting {

namespace {

constexpr double kPi = std::numbers::pi;

Rgb toRgb(const Eigen::Vector3d& v) { return v.cast<float>(); }

// Fibonacci directions on the sphere: deterministic, near-uniform.
std::vector<Eigen::Vector3d> makeSphereDirections(int n) {
    std::vector<Eigen::Vector3d> dirs;
    dirs.reserve(static_cast<std::size_t>(n));
    const double golden = kPi * (3.0 - std::sqrt(5.0));
    for (int i = 0; i < n; ++i) {
        const double z = 1.0 - 2.0 * (i + 0.5) / n;
        const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
        const double phi = golden * i;
        dirs.emplace_back(r * std::cos(phi), r * std::sin(phi), z);
    }
    return dirs;
}

// The same directions, computed once per count and thread (every probe asks for the same count).
// Kept per count in a map, never replaced: a reference stays valid even if TBB runs another
// probe with another count on this thread while the first one waits.
const std::vector<Eigen::Vector3d>& sphereDirections(int n) {
    thread_local std::map<int, std::vector<Eigen::Vector3d>> cached;
    auto [it, made] = cached.try_emplace(n);
    if (made) it->second = makeSphereDirections(n);
    return it->second;
}

// The same point to the bit (a probe's memory holds for its point alone).
bool sameBits(const Eigen::Vector3d& a, const Eigen::Vector3d& b) { return std::memcmp(a.data(), b.data(), 3 * sizeof(double)) == 0; }

std::array<double, 9> basis(const Eigen::Vector3d& n) {
    const auto y = shBasis(n.cast<float>());
    std::array<double, 9> out{};
    for (int k = 0; k < 9; ++k) out[static_cast<std::size_t>(k)] = y[static_cast<std::size_t>(k)];
    return out;
}

// Cosine-lobe convolution of radiance SH into irradiance SH (Ramamoorthi and Hanrahan 2001).
constexpr double kBand[9] = {kPi, 2.0 * kPi / 3.0, 2.0 * kPi / 3.0, 2.0 * kPi / 3.0, kPi / 4.0,
                             kPi / 4.0, kPi / 4.0, kPi / 4.0, kPi / 4.0};

// (s, t) of a world point on a (posed) face.
Eigen::Vector2d faceCoordinates(const Face& f, const Eigen::Vector3d& p) {
    Eigen::Matrix<double, 3, 2> b;
    b.col(0) = f.edge_s;
    b.col(1) = f.edge_t;
    const Eigen::Matrix2d gram = b.transpose() * b;
    return gram.inverse() * (b.transpose() * (p - f.origin));
}

}  // namespace

double cameraTexelSize(const Face& face, const CameraModel& camera, const Rigid3d& cam_from_world, double pixels, double quantum) {
    const double f = std::max(camera.fx, camera.fy);
    if (!(f > 0.0) || camera.width <= 0 || camera.height <= 0 || !(pixels > 0.0) || !(quantum > 0.0)) return 0.0;
    // In view: a corner in front of the camera, and the projected corners' box meets the image
    // (a face crossing the camera's plane counts as in view).
    bool front = false, behind = false;
    double u0 = 1e300, v0 = 1e300, u1 = -1e300, v1 = -1e300;
    for (const Eigen::Vector3d& c : face.corners()) {
        const Eigen::Vector3d q = cam_from_world * c;
        if (!(q.z() > 1e-3)) {
            behind = true;
            continue;
        }
        front = true;
        const double u = camera.fx * q.x() / q.z() + camera.cx, v = camera.fy * q.y() / q.z() + camera.cy;
        u0 = std::min(u0, u), u1 = std::max(u1, u), v0 = std::min(v0, v), v1 = std::max(v1, v);
    }
    if (!front) return 0.0;
    if (!behind && (u1 < 0.0 || v1 < 0.0 || u0 > camera.width || v0 > camera.height)) return 0.0;
    // The face's point nearest the camera's centre (its plane's foot, clamped to the face).
    const Eigen::Vector3d eye = cam_from_world.inverse().translation;
    Eigen::Vector2d st = faceCoordinates(face, eye).cwiseMax(0.0).cwiseMin(1.0);
    if (face.triangle && st.sum() > 1.0) st = (st.array() - 0.5 * (st.sum() - 1.0)).cwiseMax(0.0).matrix();
    const double nearest = std::max(0.05, (face.point(st.x(), st.y()) - eye).norm());
    // Never finer than half the quantum (the smallest element): at 640 x 480 the sample's desk
    // would take 2.5 mm texels, four times the texels to build and upload for a penumbra that 16
    // pairs per texel resolve no better.
    const double target = std::max(0.5 * quantum, pixels * nearest / f);
    return quantum * std::exp2(std::round(std::log2(target / quantum)));
}

namespace {

bool sameLeaves(const std::vector<FaceBuild::Leaf>& a, const std::vector<FaceBuild::Leaf>& b) {
    if (a.size() != b.size()) return false;
    for (std::size_t i = 0; i < a.size(); ++i) {
        if (a[i].element != b[i].element || a[i].buried != b[i].buried || a[i].st != b[i].st || a[i].ds != b[i].ds || a[i].dt != b[i].dt) {
            return false;
        }
    }
    return true;
}

// The texels (i0, j0, i1, j1, inclusive, clamped to the layout) whose centres lie within `reach`
// texels (and one more) of leaf `l`'s extent.
Eigen::Vector4i texelRect(const FaceBuild::Leaf& l, int width, int height, double reach) {
    const Eigen::Vector2d a = l.st, b = l.st + l.ds, c = l.st + l.dt, d = l.st + l.ds + l.dt;
    const Eigen::Vector2d lo = a.cwiseMin(b).cwiseMin(c).cwiseMin(d), hi = a.cwiseMax(b).cwiseMax(c).cwiseMax(d);
    const double r = reach + 1.0;
    return {std::max(0, static_cast<int>(std::floor(lo.x() * width - 0.5 - r))), std::max(0, static_cast<int>(std::floor(lo.y() * height - 0.5 - r))),
            std::min(width - 1, static_cast<int>(std::ceil(hi.x() * width - 0.5 + r))),
            std::min(height - 1, static_cast<int>(std::ceil(hi.y() * height - 0.5 + r)))};
}

// Brings `to` (a face's spare buffer, FaceBuild) up to `from`: everything but the texels, and of
// those the tiles `tiles` (null: all).
void bringOver(const FaceModulation& from, const std::vector<int>* tiles, FaceModulation& to) {
    if (tiles == nullptr) {
        to = from;
        return;
    }
    to.object = from.object;
    to.object_index = from.object_index;
    to.face = from.face;
    to.corners = from.corners;
    to.normal = from.normal;
    to.elements = from.elements;
    to.mean_original = from.mean_original;
    to.revision = from.revision;
    constexpr int kTile = FaceBuild::kTile;
    const int tiles_w = (from.width + kTile - 1) / kTile;
    for (const int tile : *tiles) {
        const int i0 = (tile % tiles_w) * kTile, j0 = (tile / tiles_w) * kTile;
        const int n = std::min(kTile, from.width - i0);
        for (int j = j0; j < std::min(from.height, j0 + kTile); ++j) {
            const std::size_t k = from.texel(i0, j);
            for (auto field : {&FaceModulation::ratio, &FaceModulation::difference, &FaceModulation::original, &FaceModulation::reflectance}) {
                std::copy_n((from.*field).begin() + static_cast<std::ptrdiff_t>(k), n, (to.*field).begin() + static_cast<std::ptrdiff_t>(k));
            }
        }
    }
}

// One face into `keep` (buildFaceModulations()).
void buildFaceModulation(const Radiosity& radiosity, const Scene& scene, int f, const std::vector<Eigen::Vector3d>& without,
                         const std::vector<Eigen::Vector3d>& with, const std::vector<Eigen::Vector3d>& rho, int max_texels,
                         const TexelDirect* texel_direct, double tolerance, FaceBuild& keep) {
    const Hierarchy& h = radiosity.hierarchy();
    const Face& face = radiosity.face(f);
    const bool direct_on = texel_direct != nullptr && !face.triangle;
    std::vector<int> ids;
    h.leavesUnder(h.root(f), ids);
    // The face's leaves (buried ones too: a texel's centre may fall on one) and their fields:
    // B~, B, the reflectance, the elements' direct light without and with the objects.
    std::vector<FaceBuild::Leaf> leaves;
    leaves.reserve(ids.size());
    double finest = 1e300, area = 0.0, lum = 0.0;
    bool any = false;
    for (int l : ids) {
        const Element& e = h[l];
        const std::size_t u = static_cast<std::size_t>(l);
        FaceBuild::Leaf leaf;
        leaf.element = l;
        leaf.buried = e.buried;
        leaf.st = e.st;
        leaf.ds = e.ds;
        leaf.dt = e.dt;
        leaf.fields = {without[u], with[u], rho[u], direct_on ? (*texel_direct->without)[u] : Eigen::Vector3d::Zero(),
                       direct_on ? (*texel_direct->with)[u] : Eigen::Vector3d::Zero()};
        leaves.push_back(leaf);
        if (e.buried) continue;
        any = true;
        finest = std::min(finest, std::min(e.size_s, e.size_t_));
        area += e.area;
        lum += e.area * luminance(toRgb(without[u]));
    }
    if (!any) {
        keep = FaceBuild{};
        return;
    }
    // Texels as fine as the finest leaf; with per-texel direct light the camera's resolution
    // (TexelDirect::face_texel) or `oversample` per finest leaf along each side.
    double texel_size = finest;
    if (direct_on) {
        const double camera_texel = static_cast<std::size_t>(f) < texel_direct->face_texel.size() ? texel_direct->face_texel[static_cast<std::size_t>(f)] : 0.0;
        texel_size = camera_texel > 0.0 ? camera_texel : finest / std::max(1, texel_direct->oversample);
    }
    const int width = std::clamp(static_cast<int>(std::ceil(face.lengthS() / texel_size)), 2, max_texels);
    const int height = std::clamp(static_cast<int>(std::ceil(face.lengthT() / texel_size)), 2, max_texels);
    const std::size_t texels = static_cast<std::size_t>(width) * static_cast<std::size_t>(height);
    // Three cases: a new layout (everything built); the same leaves (the texels whose leaves'
    // values changed); leaves split or merged (also the texels near them: their leaf and box filter).
    // A texel's box filter reaches a quarter of its leaf's size (stencilAt() below), and half a
    // texel more (the leaf under a texel is the one under its centre): `reach`, in texels, from
    // the largest leaf, old or new.
    double reach = 0.0;
    for (const std::vector<FaceBuild::Leaf>* list : {&leaves, &keep.leaves}) {
        for (const FaceBuild::Leaf& l : *list) {
            reach = std::max(reach, 0.25 * std::max(std::max(std::abs(l.ds.x()), std::abs(l.dt.x())) * width,
                                                    std::max(std::abs(l.ds.y()), std::abs(l.dt.y())) * height));
        }
    }
    const FaceModulation* last = keep.modulation.get();
    const bool same_layout = last != nullptr && last->width == width && last->height == height && keep.texel_direct == direct_on;
    const bool same_leaves = same_layout && sameLeaves(keep.leaves, leaves);
    // The buffer this build writes (FaceBuild::Buffer): a new one for a new layout; the spare
    // brought up to date when no snapshot holds it; else a copy of the last.
    std::shared_ptr<FaceBuild::Buffer> out;
    if (!same_layout) {
        keep = FaceBuild{};
        keep.texel_direct = direct_on;
        out = std::make_shared<FaceBuild::Buffer>();
        FaceModulation& m = out->textures;
        m.object_index = face.object_index;
        m.object = scene.real_objects[static_cast<std::size_t>(face.object_index)].name;
        m.face = face.face_index;
        m.corners = face.corners();
        m.normal = face.normal;
        m.width = width;
        m.height = height;
        m.ratio.resize(texels);
        m.difference.resize(texels);
        m.original.resize(texels);
        m.reflectance.resize(texels);
        keep.leaf_of.assign(texels, -1);
        keep.stencils.resize(texels);
        keep.direct.assign(texels, 0);
    } else if (keep.spare && !keep.spare->held.load(std::memory_order_acquire)) {
        out = std::move(keep.spare);
        bringOver(*last, keep.written_all ? nullptr : &keep.written, out->textures);
    } else {
        out = std::make_shared<FaceBuild::Buffer>();
        out->textures = *last;
    }
    FaceModulation& m = out->textures;
    const float mean_original = area > 0.0 ? static_cast<float>(lum / area) : 0.0f;
    bool revised = !same_leaves || m.mean_original != mean_original;
    m.mean_original = mean_original;
    // The texels whose leaf and box filter are found again: [i0, i1] x [j0, j1] (empty: i0 > i1).
    int i0 = 0, i1 = width - 1, j0 = 0, j1 = height - 1;
    // Each leaf's place in `leaves`, by element (made at the first need: only when leaves changed).
    std::vector<int> place;
    const auto placeOf = [&](int element) {
        if (place.empty()) {
            place.assign(h.elements().size(), -1);
            for (std::size_t q = 0; q < leaves.size(); ++q) place[static_cast<std::size_t>(leaves[q].element)] = static_cast<int>(q);
        }
        return place[static_cast<std::size_t>(element)];
    };
    // Leaves new since the last build, by place in `leaves` (every leaf in a new layout).
    std::vector<char> fresh(leaves.size(), same_leaves ? 0 : 1);
    // Rectangles in texels (i0, j0, i1, j1) of the leaves the last build had and this one has not:
    // the box filters that averaged them are within `reach` of them.
    std::vector<Eigen::Vector4i> gone_rects;
    // The box (i0, j0, i1, j1) of the texels whose leaf is not known (leaf_of -1): every texel in a
    // new layout; with the same layout, those whose leaf went.
    Eigen::Vector4i lost(0, 0, width - 1, height - 1);
    if (same_layout && !same_leaves) {
        // Places of the leaves kept (the same element with the same extent) from the old list to
        // the new; the texels of the rest are rasterised again, and the box filters within a
        // quarter of the largest leaf of the texels that changed leaf are found again.
        std::vector<int> old_to_new(keep.leaves.size(), -1);
        for (std::size_t q = 0; q < keep.leaves.size(); ++q) {
            const FaceBuild::Leaf& o = keep.leaves[q];
            const int p = placeOf(o.element);
            if (p < 0) continue;
            const FaceBuild::Leaf& n = leaves[static_cast<std::size_t>(p)];
            if (n.buried == o.buried && n.st == o.st && n.ds == o.ds && n.dt == o.dt) {
                old_to_new[q] = p;
                fresh[static_cast<std::size_t>(p)] = 0;
                leaves[static_cast<std::size_t>(p)].fields = o.fields;  // compared below, as kept
            }
        }
        for (std::size_t q = 0; q < keep.leaves.size(); ++q) {
            if (old_to_new[q] < 0) gone_rects.push_back(texelRect(keep.leaves[q], width, height, reach));
        }
        // One pass over the texels: their leaves and box filters renumbered, and the box of those
        // whose leaf went (-1: rasterised or found again below).
        i0 = width, i1 = -1, j0 = height, j1 = -1;
        for (int j = 0; j < height; ++j) {
            const std::size_t row = static_cast<std::size_t>(j) * static_cast<std::size_t>(width);
            int* leaf_of = keep.leaf_of.data() + row;
            FaceBuild::Stencil* stencils = keep.stencils.data() + row;
            int lo = width, hi = -1;
            for (int i = 0; i < width; ++i) {
                int& q = leaf_of[i];
                q = q >= 0 ? old_to_new[static_cast<std::size_t>(q)] : -1;
                if (q < 0) lo = std::min(lo, i), hi = i;
                FaceBuild::Stencil& st = stencils[i];
                for (int n = 0; n < st.n; ++n) {
                    int& leaf = st.leaf[static_cast<std::size_t>(n)];
                    leaf = old_to_new[static_cast<std::size_t>(leaf)];
                }
            }
            if (lo <= hi) i0 = std::min(i0, lo), i1 = std::max(i1, hi), j0 = std::min(j0, j), j1 = j;
        }
        lost = {i0, j0, i1, j1};
        if (i0 <= i1) {
            const int r = static_cast<int>(std::ceil(reach)) + 1;
            i0 = std::max(0, i0 - r), i1 = std::min(width - 1, i1 + r), j0 = std::max(0, j0 - r), j1 = std::min(height - 1, j1 + r);
        }
    }
    const auto leafAt = [&](double s, double t) {
        const int i = std::clamp(static_cast<int>(s * width), 0, width - 1);
        const int j = std::clamp(static_cast<int>(t * height), 0, height - 1);
        return keep.leaf_of[m.texel(i, j)];
    };
    // Box filter of the piecewise-constant leaf field around (s, t), over the local leaf's
    // extent: linear between element centres, no steps at element borders. The leaves it averages
    // (the four corners of the box, those not buried; the centre's when all are) are found once
    // per texel and kept.
    const auto stencilAt = [&](const std::vector<FaceBuild::Leaf>& list, int i, int j) {
        const double s = (i + 0.5) / width, t = (j + 0.5) / height;
        const int centre = leafAt(s, t);
        const FaceBuild::Leaf& e = list[static_cast<std::size_t>(centre)];
        const double hs = 0.5 * std::max(std::abs(e.ds.x()), std::abs(e.dt.x()));
        const double ht = 0.5 * std::max(std::abs(e.ds.y()), std::abs(e.dt.y()));
        FaceBuild::Stencil st;
        for (int dj = -1; dj <= 1; dj += 2) {
            for (int di = -1; di <= 1; di += 2) {
                const int q = leafAt(std::clamp(s + 0.5 * di * hs, 0.0, 1.0), std::clamp(t + 0.5 * dj * ht, 0.0, 1.0));
                if (list[static_cast<std::size_t>(q)].buried) continue;
                st.leaf[static_cast<std::size_t>(st.n++)] = q;
            }
        }
        if (st.n == 0) st.leaf[static_cast<std::size_t>(st.n++)] = centre;
        return st;
    };
    if (!same_leaves) {
        m.elements.clear();
        for (const FaceBuild::Leaf& l : leaves) {
            if (l.buried) continue;
            const Eigen::Vector2d a = l.st, b = l.st + l.ds + l.dt;
            m.elements.emplace_back(static_cast<float>(std::min(a.x(), b.x())), static_cast<float>(std::min(a.y(), b.y())),
                                    static_cast<float>(std::max(a.x(), b.x())), static_cast<float>(std::max(a.y(), b.y())));
        }
        // The leaf under every texel centre not known (its place in `leaves`): a parallelogram
        // face's leaves are rectangles in (s, t), rasterised; a triangle's found by descent.
        if (!face.triangle) {
            for (std::size_t q = 0; q < leaves.size(); ++q) {
                if (!fresh[q]) continue;
                const Eigen::Vector2d a = leaves[q].st, b = leaves[q].st + leaves[q].ds + leaves[q].dt;
                const int a0 = std::max(0, static_cast<int>(std::ceil(std::min(a.x(), b.x()) * width - 0.5)));
                const int a1 = std::min(width - 1, static_cast<int>(std::ceil(std::max(a.x(), b.x()) * width - 0.5)) - 1);
                const int b0 = std::max(0, static_cast<int>(std::ceil(std::min(a.y(), b.y()) * height - 0.5)));
                const int b1 = std::min(height - 1, static_cast<int>(std::ceil(std::max(a.y(), b.y()) * height - 0.5)) - 1);
                for (int j = b0; j <= b1; ++j) {
                    for (int i = a0; i <= a1; ++i) keep.leaf_of[m.texel(i, j)] = static_cast<int>(q);
                }
            }
        }
        for (int j = lost[1]; j <= lost[3]; ++j) {
            for (int i = lost[0]; i <= lost[2]; ++i) {
                const std::size_t k = m.texel(i, j);
                if (keep.leaf_of[k] >= 0) continue;
                keep.leaf_of[k] = placeOf(h.leafAt(f, Eigen::Vector2d((i + 0.5) / width, (j + 0.5) / height)));
            }
        }
        if (i0 <= i1) {
            tbb::parallel_for(j0, j1 + 1, [&](int j) {
                for (int i = i0; i <= i1; ++i) keep.stencils[m.texel(i, j)] = stencilAt(leaves, i, j);
            });
        }
    } else {
        i0 = width, i1 = -1;
        for (std::size_t q = 0; q < leaves.size(); ++q) leaves[q].fields = keep.leaves[q].fields;  // compared below, as kept
    }
    // What changed since the last build: new leaves, the leaves whose fields moved by more than
    // `tolerance` of their B~ from the values kept (kept only where they moved: drift cannot build
    // up unseen) and the texels whose own direct light a move reached.
    std::vector<char> changed(fresh);
    {
        const double mean = area > 0.0 ? lum / area : 0.0;
        for (std::size_t q = 0; q < leaves.size(); ++q) {
            if (fresh[q]) continue;
            FaceBuild::Leaf& l = leaves[q];
            // Relative to the leaf's B~ (floored at a twentieth of the face's mean): the ratio's
            // change. (The direct light is irradiance, pi / rho times the radiance: stricter.)
            const double bound = tolerance * std::max(static_cast<double>(luminance(toRgb(l.fields[0]))), 0.05 * mean);
            const std::size_t u = static_cast<std::size_t>(l.element);
            const std::array<Eigen::Vector3d, 5> now{without[u], with[u], rho[u], direct_on ? (*texel_direct->without)[u] : Eigen::Vector3d::Zero(),
                                                     direct_on ? (*texel_direct->with)[u] : Eigen::Vector3d::Zero()};
            for (std::size_t k = 0; k < 5; ++k) {
                if ((now[k] - l.fields[k]).cwiseAbs().maxCoeff() > bound) {
                    changed[q] = 1;
                    l.fields = now;
                    break;
                }
            }
        }
    }
    keep.leaves = std::move(leaves);
    const bool all = !same_layout;
    const std::vector<FaceBuild::Leaf>& kept = keep.leaves;
    const auto filtered = [&](const FaceBuild::Stencil& st, std::size_t field) {
        Eigen::Vector3d sum = Eigen::Vector3d::Zero();
        for (int q = 0; q < st.n; ++q) sum += kept[static_cast<std::size_t>(st.leaf[static_cast<std::size_t>(q)])].fields[field];
        return Eigen::Vector3d(sum / st.n);
    };
    // The tiles to visit: every one in a new layout; else those within reach of a leaf that
    // changed or went, of the region whose box filters were found again, and of a texel whose own
    // direct light went (TexelDirect::forgotten). Of a tile, only the box (i0, j0, i1, j1) of the
    // rectangles and texels that marked it: a texel outside every one of them has no changed or
    // gone leaf in its box filter and its own direct light stands.
    constexpr int kTile = FaceBuild::kTile;
    const int tiles_w = (width + kTile - 1) / kTile, tiles_h = (height + kTile - 1) / kTile;
    std::vector<int> visit;
    std::vector<Eigen::Vector4i> boxes;  // by place in `visit` (empty: whole tiles)
    if (all) {
        visit.resize(static_cast<std::size_t>(tiles_w) * static_cast<std::size_t>(tiles_h));
        std::iota(visit.begin(), visit.end(), 0);
        std::vector<std::uint32_t> went;  // (every texel is built: the list is only emptied)
        if (direct_on && texel_direct->forgotten) texel_direct->forgotten(f, went);
    } else {
        // By tile: the box of what marked it.
        TileMarks mark(width, height, kTile);
        const auto markRect = [&](const Eigen::Vector4i& r) { mark.mark(r); };
        const auto markTexel = [&](std::size_t k) {
            const int i = static_cast<int>(k % static_cast<std::size_t>(width)), j = static_cast<int>(k / static_cast<std::size_t>(width));
            markRect({i, j, i, j});
        };
        if (i0 <= i1) markRect({i0, j0, i1, j1});
        for (const Eigen::Vector4i& r : gone_rects) markRect(r);
        for (std::size_t q = 0; q < kept.size(); ++q) {
            if (changed[q]) markRect(texelRect(kept[q], width, height, reach));
        }
        if (direct_on) {
            std::vector<std::uint32_t> went;
            if (texel_direct->forgotten && texel_direct->forgotten(f, went)) {
                for (const std::uint32_t k : went) {
                    if (k < texels && keep.direct[k]) markTexel(k);
                }
            } else {
                for (std::size_t k = 0; k < texels; ++k) {
                    if (keep.direct[k]) markTexel(k);
                }
            }
        }
        for (std::size_t t = 0; t < mark.tiles(); ++t) {
            if (!mark.marked(t)) continue;
            visit.push_back(static_cast<int>(t));
            boxes.push_back(mark.box(t));
        }
    }
    // By place in `visit`: texels the tile rebuilt (the next build brings over only those tiles).
    std::vector<long> rebuilt(visit.size(), 0);
    tbb::parallel_for(std::size_t{0}, visit.size(), [&](std::size_t v) {
        long count = 0;
        const int ti = visit[v] % tiles_w, tj = visit[v] / tiles_w;
        const Eigen::Vector4i box = boxes.empty() ? Eigen::Vector4i(ti * kTile, tj * kTile, std::min(width, (ti + 1) * kTile) - 1,
                                                                    std::min(height, (tj + 1) * kTile) - 1)
                                                  : boxes[v];
        for (int j = box[1]; j <= box[3]; ++j) for (int i = box[0]; i <= box[2]; ++i) {
            const std::size_t k = m.texel(i, j);
            FaceBuild::Stencil& st = keep.stencils[k];
            bool dirty = all || (i >= i0 && i <= i1 && j >= j0 && j <= j1);
            if (std::any_of(st.leaf.begin(), st.leaf.begin() + st.n, [](int q) { return q < 0; })) {
                // (A leaf it averaged has gone and the region above missed it: found again.)
                st = stencilAt(kept, i, j);
                dirty = true;
            }
            for (int q = 0; q < st.n && !dirty; ++q) dirty = changed[static_cast<std::size_t>(st.leaf[static_cast<std::size_t>(q)])] != 0;
            if (!dirty && keep.direct[k] && !(texel_direct->kept && texel_direct->kept(f, k))) dirty = true;
            if (!dirty) continue;
            ++count;
            const double s = (i + 0.5) / m.width, t = (j + 0.5) / m.height;
            Eigen::Vector3d b0 = filtered(st, 0);
            Eigen::Vector3d b1 = filtered(st, 1);
            const Eigen::Vector3d r = filtered(st, 2);
            keep.direct[k] = 0;
            if (direct_on) {
                // The area lights' direct light at the texel's point instead of the elements' where
                // the objects change it.
                const Eigen::Vector3d e0 = filtered(st, 3);
                const Eigen::Vector3d e1 = filtered(st, 4);
                if ((e1 - e0).cwiseAbs().maxCoeff() > texel_direct->threshold) {
                    Eigen::Vector3d d0 = Eigen::Vector3d::Zero(), d1 = Eigen::Vector3d::Zero();
                    texel_direct->at(f, k, m.width, m.height, face.origin + s * face.edge_s + t * face.edge_t, d0, d1);
                    b0 += r.cwiseProduct(d0 - e0) / kPi;
                    b1 += r.cwiseProduct(d1 - e1) / kPi;
                    keep.direct[k] = 1;
                }
            }
            Rgb ratio;
            for (int c = 0; c < 3; ++c) {
                // Hard case: B~ near zero (an unlit corner): the ratio is capped and the
                // difference, beside it, carries the light (ratioWeight() chooses).
                const double den = b0[c];
                const double q = den > 1e-12 ? b1[c] / den : (b1[c] > 1e-12 ? kMaxRatio : 1.0);
                ratio[c] = static_cast<float>(std::clamp(q, 0.0, static_cast<double>(kMaxRatio)));
            }
            m.ratio[k] = ratio;
            m.difference[k] = toRgb(b1 - b0);
            m.original[k] = toRgb(b0);
            m.reflectance[k] = toRgb(r.cwiseMax(0.0).cwiseMin(1.0));
        }
        rebuilt[v] = count;
    });
    keep.texels_built = std::accumulate(rebuilt.begin(), rebuilt.end(), 0L);
    if (revised || keep.texels_built > 0) {
        static std::atomic<std::uint64_t> revisions{0};
        m.revision = ++revisions;
    }
    // Published: the last one becomes the spare (its deleter below marks it free once no snapshot
    // holds it), this one the face's textures.
    keep.written.clear();
    for (std::size_t v = 0; v < visit.size(); ++v) {
        if (rebuilt[v] > 0) keep.written.push_back(visit[v]);
    }
    keep.written_all = all;
    keep.spare = std::move(keep.current);
    keep.current = out;
    keep.modulation.reset();
    out->held.store(true, std::memory_order_relaxed);
    const FaceModulation* published = &out->textures;
    keep.modulation = std::shared_ptr<const FaceModulation>(published, [buffer = std::move(out)](const FaceModulation*) {
        buffer->held.store(false, std::memory_order_release);
    });
}

}  // namespace

void buildFaceModulations(const Radiosity& radiosity, const Scene& scene, const std::vector<Eigen::Vector3d>& without,
                          const std::vector<Eigen::Vector3d>& with, const std::vector<Eigen::Vector3d>& rho, const std::vector<int>& faces,
                          std::vector<FaceBuild>& builds, double tolerance, int max_texels, const TexelDirect* texel_direct) {
    builds.resize(radiosity.realFaceCount());
    // Faces in parallel (each its own FaceBuild, TexelDirectCache locks per face): most faces that
    // change are small, and one at a time their texels would not fill the threads.
    std::vector<int> list(faces);
    std::sort(list.begin(), list.end());
    list.erase(std::unique(list.begin(), list.end()), list.end());
    tbb::parallel_for(std::size_t{0}, list.size(), [&](std::size_t i) {
        const int f = list[i];
        buildFaceModulation(radiosity, scene, f, without, with, rho, max_texels, texel_direct, tolerance, builds[static_cast<std::size_t>(f)]);
    });
}

ProbeIrradiance probeIrradiance(const Radiosity& radiosity, const Eigen::Vector3d& p, int object,
                                const std::vector<Eigen::Vector3d>& radiance, const std::vector<ProbeLight>& lights,
                                int directions, std::uint64_t seed, bool other_objects, ProbeMemory* memory) {
    const RayScene& rays = radiosity.rays();
    const Hierarchy& h = radiosity.hierarchy();
    const std::vector<Eigen::Vector3d>& dirs = sphereDirections(directions);
    std::array<Eigen::Vector3d, 9> ind{}, dir{};
    for (auto& c : ind) c.setZero();
    for (auto& c : dir) c.setZero();
    // Step 1: radiance from every direction (surfaces and the environment's residual).
    const double d_omega = 4.0 * kPi / static_cast<double>(dirs.size());
    // The real hits first, in packets (the same hits as one ray at a time); or last time's, from
    // the same point.
    const bool again = memory && memory->valid && sameBits(memory->point, p) && memory->real_hits.size() == dirs.size();
    std::vector<RayHit> local_hits;
    std::vector<int> local_leaves;
    std::vector<RayHit>& real_hits = memory ? memory->real_hits : local_hits;
    std::vector<int>& leaves = memory ? memory->leaves : local_leaves;
    if (!again) {
        real_hits.assign(dirs.size(), RayHit{});
        leaves.assign(dirs.size(), -1);
        rays.intersectRealMany(p, dirs.data(), static_cast<int>(dirs.size()), real_hits.data());
        if (memory) {
            memory->valid = true;
            memory->point = p;
            memory->sample_target.clear();
            memory->sample_normal.clear();
            memory->sample_open.clear();
        }
    }
    for (std::size_t di = 0; di < dirs.size(); ++di) {
        const Eigen::Vector3d& w = dirs[di];
        const RayHit& real = real_hits[di];
        const RayHit other = other_objects ? rays.intersectVirtualExcept(p, w, object) : RayHit{};
        Eigen::Vector3d l = Eigen::Vector3d::Zero();
        if (other.kind == HitKind::kVirtual && (real.kind == HitKind::kNone || other.distance < real.distance)) {
            const Eigen::Vector3d hit_point = p + other.distance * w;
            // The other object's face the ray met (an exact sphere: the facet in the hit's
            // direction from its centre).
            int f = -1, k = 0;
            double best = -2.0;
            const Eigen::Vector3d c = radiosity.virtualPoses()[static_cast<std::size_t>(other.index)].translation;
            for (std::size_t g = radiosity.realFaceCount(); g < h.faceCount(); ++g) {
                if (radiosity.virtualObjectOfFace(static_cast<int>(g)) != other.index) continue;
                if (other.primitive >= 0) {
                    if (k++ == other.primitive) f = static_cast<int>(g);
                    continue;
                }
                const double d = radiosity.face(static_cast<int>(g)).normal.dot((hit_point - c).normalized());
                if (d > best) {
                    best = d;
                    f = static_cast<int>(g);
                }
            }
            if (f >= 0) {
                const Face& face = radiosity.face(f);
                const int leaf = h.leafAt(f, faceCoordinates(face, hit_point));
                if (face.normal.dot(-w) > 0.0) l = radiance[static_cast<std::size_t>(leaf)];
            }
        } else if (real.kind == HitKind::kRealFace) {
            const Face& face = radiosity.face(real.index);
            const int leaf = h.leafAtAgain(real.index, faceCoordinates(face, p + real.distance * w), leaves[di]);
            leaves[di] = leaf;
            if (!h[leaf].buried) l = radiance[static_cast<std::size_t>(leaf)];
        } else if (real.kind == HitKind::kNone && w.z() > 0.0) {
            for (const ProbeLight& pl : lights) {
                if (!pl.indirect || pl.source.kind != DirectSource::Kind::kCell) continue;
                const double phi = std::atan2(w.y(), w.x()) < 0.0 ? std::atan2(w.y(), w.x()) + 2.0 * kPi : std::atan2(w.y(), w.x());
                if (w.z() >= pl.source.cos0 && w.z() < pl.source.cos1 && phi >= pl.source.phi0 && phi < pl.source.phi1) {
                    l += pl.emission;
                }
            }
        }
        if (l.isZero()) continue;
        const auto y = basis(w);
        for (int k = 0; k < 9; ++k) ind[static_cast<std::size_t>(k)] += d_omega * y[static_cast<std::size_t>(k)] * l;
    }
    // Step 2: the lights the renderer draws, sampled on their own geometry. The real visibility of
    // a sample asked last time from this point at the same target is last time's.
    std::size_t sample = 0;
    const auto openToReal = [&](const Eigen::Vector3d& target, const Eigen::Vector3d& target_normal, const auto& trace) {
        if (!memory) return !trace();
        const std::size_t k = sample++;
        if (k < memory->sample_open.size() && sameBits(memory->sample_target[k], target) && sameBits(memory->sample_normal[k], target_normal)) {
            return memory->sample_open[k] != 0;
        }
        const bool open = !trace();
        if (k < memory->sample_open.size()) {
            memory->sample_target[k] = target;
            memory->sample_normal[k] = target_normal;
            memory->sample_open[k] = open ? 1 : 0;
        } else {
            memory->sample_target.push_back(target);
            memory->sample_normal.push_back(target_normal);
            memory->sample_open.push_back(open ? 1 : 0);
        }
        return open;
    };
    for (std::size_t li = 0; li < lights.size(); ++li) {
        const ProbeLight& pl = lights[li];
        if (pl.indirect) continue;
        const auto add = [&](const Eigen::Vector3d& towards, const Eigen::Vector3d& radiance_times_omega) {
            const auto y = basis(towards);
            for (int k = 0; k < 9; ++k) dir[static_cast<std::size_t>(k)] += y[static_cast<std::size_t>(k)] * radiance_times_omega;
        };
        const auto visible = [&](const Eigen::Vector3d& target, const Eigen::Vector3d& target_normal) {
            if (!openToReal(target, target_normal, [&] { return rays.occludedReal(p, Eigen::Vector3d::Zero(), target, target_normal); })) {
                return false;
            }
            if (!other_objects) return true;
            const Eigen::Vector3d d = target - p;
            const RayHit hv = rays.intersectVirtualExcept(p, d.normalized(), object, d.norm() - rays.epsilon());
            return hv.kind == HitKind::kNone;
        };
        switch (pl.source.kind) {
            case DirectSource::Kind::kPolygon: {
                const LightGeometry& g = *pl.source.polygon;
                constexpr int kSamples = 16;
                for (int s = 0; s < kSamples; ++s) {
                    const Eigen::Vector2d u = stratified2d(hashCombine(seed, li), s, kSamples);
                    const Eigen::Vector3d y = sampleLight(g, u);
                    const Eigen::Vector3d d = y - p;
                    const double d2 = d.squaredNorm();
                    const double cos_l = g.normal.dot(-d) / std::sqrt(d2);
                    if (cos_l <= 0.0 || !(d2 > 1e-12) || !visible(y, g.normal)) continue;
                    add(d.normalized(), pl.emission * (g.area * cos_l / d2 / kSamples));
                }
                break;
            }
            case DirectSource::Kind::kPoint: {
                const Eigen::Vector3d d = pl.source.position - p;
                const double d2 = d.squaredNorm();
                if (d2 > 1e-12 && visible(pl.source.position, Eigen::Vector3d::Zero())) add(d.normalized(), pl.emission / d2);
                break;
            }
            case DirectSource::Kind::kDirection: {
                const Eigen::Vector3d towards = -pl.source.direction.normalized();
                if (openToReal(towards, Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity()),
                               [&] { return rays.occludedRealRay(p, Eigen::Vector3d::Zero(), towards); }) &&
                    (!other_objects || rays.intersectVirtualExcept(p, towards, object).kind == HitKind::kNone)) {
                    add(towards, pl.emission);
                }
                break;
            }
            case DirectSource::Kind::kCell:
                break;
        }
    }
    ProbeIrradiance out;
    for (int k = 0; k < 9; ++k) {
        out.indirect[static_cast<std::size_t>(k)] = (kBand[k] * ind[static_cast<std::size_t>(k)]).cast<float>();
        out.direct[static_cast<std::size_t>(k)] = (kBand[k] * dir[static_cast<std::size_t>(k)]).cast<float>();
    }
    return out;
}

std::vector<VirtualIrradiance> buildProbes(const Radiosity& radiosity, const Scene& scene, const std::vector<Eigen::Vector3d>& radiance,
                                           const std::vector<ProbeLight>& lights, int directions, ProbeMemories* memories) {
    std::vector<VirtualIrradiance> out;
    const Hierarchy& h = radiosity.hierarchy();
    if (memories) {
        if (memories->radiosity != &radiosity) memories->clear();
        memories->radiosity = &radiosity;
        memories->objects.resize(scene.virtual_objects.size());
    }
    for (std::size_t v = 0; v < scene.virtual_objects.size(); ++v) {
        VirtualIrradiance probe;
        probe.object = scene.virtual_objects[v].name;
        probe.object_index = static_cast<int>(v);
        // Bounds from the object's posed faces.
        Eigen::AlignedBox3d box;
        for (std::size_t f = radiosity.realFaceCount(); f < h.faceCount(); ++f) {
            if (radiosity.virtualObjectOfFace(static_cast<int>(f)) != static_cast<int>(v)) continue;
            for (const Eigen::Vector3d& c : radiosity.face(static_cast<int>(f)).corners()) box.extend(c);
        }
        if (box.isEmpty()) box.extend(radiosity.virtualPoses()[v].translation);
        probe.bounds_min = box.min();
        probe.bounds_max = box.max();
        const Eigen::Vector3d extent = box.sizes();
        for (int a = 0; a < 3; ++a) probe.dims[a] = extent[a] > 0.3 ? 3 : (extent[a] > 0.12 ? 2 : 1);
        const int count = probe.dims.prod();
        probe.indirect.assign(static_cast<std::size_t>(count), IrradianceSh{});
        probe.direct.assign(static_cast<std::size_t>(count), IrradianceSh{});
        std::vector<ProbeMemory>* memory = memories ? &memories->objects[v] : nullptr;
        if (memory) memory->resize(static_cast<std::size_t>(count));
        tbb::parallel_for(0, count, [&](int index) {
            const int ix = index % probe.dims.x(), iy = (index / probe.dims.x()) % probe.dims.y(), iz = index / (probe.dims.x() * probe.dims.y());
            const Eigen::Vector3d frac((probe.dims.x() > 1 ? static_cast<double>(ix) / (probe.dims.x() - 1) : 0.5),
                                       (probe.dims.y() > 1 ? static_cast<double>(iy) / (probe.dims.y() - 1) : 0.5),
                                       (probe.dims.z() > 1 ? static_cast<double>(iz) / (probe.dims.z() - 1) : 0.5));
            const Eigen::Vector3d p = box.min() + frac.cwiseProduct(extent);
            const ProbeIrradiance e = probeIrradiance(radiosity, p, static_cast<int>(v), radiance, lights, directions,
                                                      hashCombine(0xfeedull, static_cast<std::uint64_t>(v * 1000 + index)), true,
                                                      memory ? &(*memory)[static_cast<std::size_t>(index)] : nullptr);
            probe.indirect[static_cast<std::size_t>(index)] = e.indirect;
            probe.direct[static_cast<std::size_t>(index)] = e.direct;
        });
        out.push_back(std::move(probe));
    }
    return out;
}

}  // namespace commonlight::lighting

#include "lighting/observations.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <numbers>

namespace commonlight::lighting {

namespace {

int powerOfTwoCells(double length, double cell_size) {
    int n = 1;
    while (n < 256 && length / n > cell_size) n *= 2;
    return n;
}

// Per-sample result of Step 1.
struct Sample {
    int face = -1;          // -1 nothing, -2 virtual, -3 light
    int cell = -1;
    int tag = -1;           // tag whose printed area it hits
    bool ring = false;      // on that tag's white ring
    bool excluded = false;
    std::uint8_t reason = 0;  // 1 saturated, 2 dark
    Eigen::Vector3d radiance = Eigen::Vector3d::Zero();
    double weight = 0.0;
};

double luma(const Eigen::Vector3d& rgb) { return 0.2126 * rgb.x() + 0.7152 * rgb.y() + 0.0722 * rgb.z(); }

}  // namespace

TagLayout tagLayout(std::string_view family) {
    if (family == "tag36h11" || family == "tag36h10") return {8, 10, true};
    if (family == "tag25h9") return {7, 9, true};
    if (family == "tag16h5") return {6, 8, true};
    if (family == "tagStandard41h12") return {5, 9, true};
    if (family == "tagStandard52h13") return {6, 10, true};
    if (family == "tagCircle21h7") return {5, 9, true};
    if (family == "tagCircle49h12") return {5, 11, true};
    if (family == "tagCustom48h12") return {6, 10, true};
    return {};
}

Observations::Observations(const std::vector<Face>& real_faces, const Scene& scene, const CameraModel& camera,
                           const ResponseCurve& response, int stride, double cell_size, int interleave)
    : faces_(real_faces), camera_(camera), response_(response), stride_(std::max(1, stride)), interleave_(std::max(1, interleave)) {
    // Step 0a: a grid per face.
    for (const Face& f : faces_) {
        Grid g;
        g.triangle = f.triangle;
        g.ns = powerOfTwoCells(f.lengthS(), cell_size);
        g.nt = powerOfTwoCells(f.lengthT(), cell_size);
        g.cells.resize(static_cast<std::size_t>(g.ns) * static_cast<std::size_t>(g.nt));
        Eigen::Matrix<double, 3, 2> basis;
        basis.col(0) = f.edge_s;
        basis.col(1) = f.edge_t;
        const Eigen::Matrix2d gram = basis.transpose() * basis;
        const Eigen::Matrix<double, 2, 3> dual = gram.inverse() * basis.transpose();
        g.ds_star = dual.row(0).transpose();
        g.dt_star = dual.row(1).transpose();
        g.cell_area = (f.triangle ? 2.0 : 1.0) * f.area / (g.ns * g.nt);
        grids_.push_back(std::move(g));
    }
    // Step 0b: the tags' frames and their white rings.
    const TagLayout layout = tagLayout(scene.tags.family);
    for (std::size_t i = 0; i < scene.tags.items.size(); ++i) {
        const TagItem& item = scene.tags.items[i];
        TagFrame tf;
        tf.tag_from_world = item.world_from_tag.inverse();
        tf.cell = item.size / layout.width_at_border;
        tf.half_black = 0.5 * item.size;
        tf.half_total = 0.5 * tf.cell * layout.total_width;
        tf.white_ring = layout.known && layout.total_width == layout.width_at_border + 2;
        tag_frames_.push_back(tf);
        TagReference ref;
        ref.tag = static_cast<int>(i);
        ref.albedo_white = item.albedo_white;
        ref.normal = item.world_from_tag.rotationMatrix().col(2);
        const double r = tf.half_black + 0.5 * tf.cell;  // the ring's middle line
        for (int k = 0; k < 16; ++k) {
            // 16 points round the ring's middle line: 4 per side.
            const int side = k / 4;
            const double u = -r + 2.0 * r * ((k % 4) + 0.5) / 4.0;
            const Eigen::Vector2d p = side == 0 ? Eigen::Vector2d(u, -r)
                                    : side == 1 ? Eigen::Vector2d(r, u)
                                    : side == 2 ? Eigen::Vector2d(-u, r)
                                                : Eigen::Vector2d(-r, -u);
            ref.ring_points.push_back(item.world_from_tag * Eigen::Vector3d(p.x(), p.y(), 0.0));
        }
        tags_.push_back(std::move(ref));
    }
    // Step 0c: the camera rays of the sample grids (the lens inverted once, not per frame).
    const int step = stride_ * interleave_;
    samples_x_ = (camera_.width + step - 1) / step;
    samples_y_ = (camera_.height + step - 1) / step;
    const std::size_t per_phase = static_cast<std::size_t>(samples_x_) * static_cast<std::size_t>(samples_y_);
    const int phases = interleave_ * interleave_;
    rays_in_cam_.resize(per_phase * static_cast<std::size_t>(phases));
    for (int phase = 0; phase < phases; ++phase) {
        for (int j = 0; j < samples_y_; ++j) {
            for (int i = 0; i < samples_x_; ++i) {
                const auto ray = camera_.unproject(samplePixel(phase, i, j).cast<double>());
                rays_in_cam_[static_cast<std::size_t>(phase) * per_phase + static_cast<std::size_t>(j) * samples_x_ + i] =
                    ray ? Eigen::Vector3f(ray->normalized().cast<float>()) : Eigen::Vector3f::Constant(std::nanf(""));
            }
        }
    }
}

Eigen::Vector2i Observations::samplePixel(int phase, int i, int j) const {
    // The offsets in an order that alternates the diagonals: (0, 0), (1, 1), (0, 1), (1, 0) for k = 2.
    const int a = phase % interleave_;
    const int b = (phase / interleave_ + a) % interleave_;
    const int step = stride_ * interleave_;
    return {std::min(i * step + a * stride_ + stride_ / 2, camera_.width - 1),
            std::min(j * step + b * stride_ + stride_ / 2, camera_.height - 1)};
}

const RadianceStats& Observations::cell(int face, int i, int j) const {
    const Grid& g = grids_[static_cast<std::size_t>(face)];
    return g.cells[static_cast<std::size_t>(j) * static_cast<std::size_t>(g.ns) + static_cast<std::size_t>(i)];
}

bool Observations::pixelOnRing(const TagFrame& tf, const Eigen::Vector2d& pixel, const Eigen::Matrix3d& world_from_cam_rotation,
                               const Eigen::Vector3d& camera_origin, const Eigen::Vector3d& centre_in_tag) const {
    // The side of the ring the pixel's centre is on: the strip |a| in (half_black, half_black +
    // cell), |b| < half_black + cell, with a the dominant tag axis.
    const int axis = std::abs(centre_in_tag.x()) >= std::abs(centre_in_tag.y()) ? 0 : 1;
    const double sign = centre_in_tag[axis] >= 0.0 ? 1.0 : -1.0;
    // A small guard for the sub-pixel error of the pose and of the lens model: 5% of a cell.
    const double guard = 0.05 * tf.cell;
    const double outer = tf.half_black + tf.cell;
    const Eigen::Matrix3d r = tf.tag_from_world.rotationMatrix();
    const Eigen::Vector3d o = tf.tag_from_world * camera_origin;
    for (const Eigen::Vector2d& corner : {Eigen::Vector2d(-0.5, -0.5), Eigen::Vector2d(0.5, -0.5), Eigen::Vector2d(-0.5, 0.5),
                                         Eigen::Vector2d(0.5, 0.5)}) {
        const auto ray = camera_.unproject(pixel + corner);
        if (!ray) return false;
        const Eigen::Vector3d d = r * (world_from_cam_rotation * ray->normalized());
        // Hard case: a corner ray parallel to the tag's plane (or leaving it) never meets it.
        if (!(std::abs(d.z()) > 1e-9)) return false;
        const double t = -o.z() / d.z();
        if (!(t > 0.0)) return false;
        const Eigen::Vector3d q = o + t * d;
        const double a = sign * q[axis], b = std::abs(q[1 - axis]);
        if (!(a > tf.half_black + guard && a < outer - guard && b < outer - guard)) return false;
    }
    return true;
}

Result<FrameObservation> Observations::add(const ImageView& rgb8, const Rigid3d& cam_from_world, double exposure_s,
                                           double gain, const RayScene& rays, const Eigen::Vector3d& illuminant) {
    if (rgb8.format != PixelFormat::kRgb8 || rgb8.width != camera_.width || rgb8.height != camera_.height) {
        return fail(ErrorCode::kBadInput, "lighting: observation must be RGB8 at the camera's size");
    }
    if (!cam_from_world.isValid()) return fail(ErrorCode::kBadInput, "lighting: the camera pose is not finite");
    if (!(exposure_s > 0.0 && gain > 0.0 && std::isfinite(exposure_s * gain))) {
        return fail(ErrorCode::kBadInput, "lighting: exposure x gain must be positive and finite");
    }
    const Rigid3d world_from_cam = cam_from_world.inverse();
    const Eigen::Matrix3d rotation = world_from_cam.rotationMatrix();
    const Eigen::Vector3d origin = world_from_cam.translation;
    const double to_relative = 1.0 / (exposure_s * gain);
    const std::size_t per_phase = static_cast<std::size_t>(samples_x_) * static_cast<std::size_t>(samples_y_);
    const int phase = static_cast<int>(frames_ % static_cast<std::uint64_t>(interleave_ * interleave_));
    const Eigen::Vector3f* rays_in_cam = rays_in_cam_.data() + static_cast<std::size_t>(phase) * per_phase;
    std::vector<Sample> samples(per_phase);

    // Step 1: one ray per sample, in parallel; the per-pixel decisions that need no neighbour.
    // (A row's rays from the camera's centre traced together: Embree's packets of 8.)
    tbb::parallel_for(0, samples_y_, [&](int j) {
        thread_local std::vector<int> row;
        thread_local std::vector<Eigen::Vector3d> dirs;
        thread_local std::vector<RayHit> hits;
        row.clear();
        dirs.clear();
        for (int i = 0; i < samples_x_; ++i) {
            const Eigen::Vector3f& d = rays_in_cam[static_cast<std::size_t>(j) * samples_x_ + i];
            if (!d.allFinite()) continue;
            row.push_back(i);
            dirs.push_back(rotation * d.cast<double>());
        }
        hits.resize(row.size());
        rays.intersectAllMany(origin, dirs.data(), static_cast<int>(row.size()), hits.data());
        for (std::size_t r = 0; r < row.size(); ++r) {
            const int i = row[r];
            const std::size_t k = static_cast<std::size_t>(j) * samples_x_ + i;
            Sample& s = samples[k];
            const Eigen::Vector2i pixel = samplePixel(phase, i, j);
            const int px = pixel.x(), py = pixel.y();
            const std::uint8_t* c = rgb8.row(py) + 3 * px;
            const Eigen::Vector3d& dir = dirs[r];
            const RayHit& hit = hits[r];
            if (hit.kind == HitKind::kVirtual) {
                s.face = -2;
                continue;
            }
            if (hit.kind != HitKind::kRealFace) {
                s.face = hit.kind == HitKind::kLight ? -3 : -1;
                continue;
            }
            s.face = hit.index;
            const Eigen::Vector3d p = origin + hit.distance * dir;
            const Face& f = faces_[static_cast<std::size_t>(s.face)];
            const Grid& g = grids_[static_cast<std::size_t>(s.face)];
            const double st_s = std::clamp((p - f.origin).dot(g.ds_star), 0.0, 1.0);
            const double st_t = std::clamp((p - f.origin).dot(g.dt_star), 0.0, 1.0);
            const int ci = std::min(static_cast<int>(st_s * g.ns), g.ns - 1);
            const int cj = std::min(static_cast<int>(st_t * g.nt), g.nt - 1);
            s.cell = cj * g.ns + ci;
            // Tags lie on surfaces as decals: a hit inside a tag's printed square is the tag.
            for (std::size_t t = 0; t < tag_frames_.size(); ++t) {
                const TagFrame& tf = tag_frames_[t];
                const Eigen::Vector3d q = tf.tag_from_world * p;
                if (std::abs(q.z()) > std::max(3e-3, 4.0 * rays.epsilon())) continue;
                const double m = std::max(std::abs(q.x()), std::abs(q.y()));
                if (m > tf.half_total) continue;
                s.tag = static_cast<int>(t);
                // The white ring: a pixel whose whole footprint on the tag (its square's four
                // corners through the lens, met with the tag's plane: a sensor integrates over the
                // pixel) lies in one side's strip of the ring. A pixel that also covers the black
                // square or the background reads darker than white. The footprint is long along
                // the viewing direction and short across it, so at a grazing view the ring's sides
                // across it still give pure pixels where a round margin would give none.
                s.ring = tf.white_ring && m > tf.half_black && m < tf.half_black + tf.cell &&
                         pixelOnRing(tf, Eigen::Vector2d(px, py), rotation, origin, q);
                break;
            }
            if (c[0] >= 250 || c[1] >= 250 || c[2] >= 250) {
                s.excluded = true;
                s.reason = 1;
                continue;
            }
            if (c[0] <= 4 && c[1] <= 4 && c[2] <= 4) {
                s.excluded = true;
                s.reason = 2;
                continue;
            }
            s.radiance = Eigen::Vector3d(response_.toLinear(0, c[0]), response_.toLinear(1, c[1]),
                                         response_.toLinear(2, c[2])) *
                         to_relative;
            const double cos_view = std::abs(f.normal.dot(dir));
            s.weight = std::max(cos_view, 0.1);
        }
    });

    // Step 2: neighbours (mixed pixels at face borders) and highlights.
    FrameObservation obs;
    obs.samples = samples.size();
    const auto face_at = [&](int i, int j) {
        if (i < 0 || j < 0 || i >= samples_x_ || j >= samples_y_) return -1;
        return samples[static_cast<std::size_t>(j) * samples_x_ + i].face;
    };
    std::vector<char> usable(samples.size(), 0);
    for (int j = 0; j < samples_y_; ++j) {
        for (int i = 0; i < samples_x_; ++i) {
            const std::size_t k = static_cast<std::size_t>(j) * samples_x_ + i;
            Sample& s = samples[k];
            if (s.face == -2) {
                ++obs.on_virtual;
                continue;
            }
            if (s.face < 0) {
                ++obs.nothing;
                continue;
            }
            if (s.tag >= 0 && !s.ring) {
                ++obs.on_tag;
                continue;
            }
            if (s.excluded) {
                if (s.tag >= 0) ++obs.on_tag;
                if (s.reason == 1) ++obs.saturated;
                if (s.reason == 2) ++obs.dark;
                continue;
            }
            if (face_at(i - 1, j) != s.face || face_at(i + 1, j) != s.face || face_at(i, j - 1) != s.face ||
                face_at(i, j + 1) != s.face) {
                ++obs.border;
                continue;
            }
            if (s.tag >= 0) continue;  // a ring pixel: a reference, handled below
            usable[k] = 1;
        }
    }
    Eigen::Vector3d illum = illuminant.cwiseMax(0.0);
    illum = illum.sum() > 0.0 ? Eigen::Vector3d(illum / illum.sum()) : Eigen::Vector3d::Constant(1.0 / 3.0);
    // The highlight test (seed 002 sec. 4): a sample brighter than 1.5x the median of its
    // neighbourhood on the same face (its 8 x 8 block of samples) whose chromaticity moved at least
    // 30% of the way from the neighbourhood's mean chromaticity towards the illuminant's.
    std::vector<char> highlight(samples.size(), 0);
    {
        constexpr int kBlock = 8;
        struct Neighbourhood {
            std::vector<double> luma;
            Eigen::Vector3d chroma_sum = Eigen::Vector3d::Zero();
            double median = 0.0;
        };
        const int bx = (samples_x_ + kBlock - 1) / kBlock, by = (samples_y_ + kBlock - 1) / kBlock;
        std::vector<std::map<int, Neighbourhood>> blocks(static_cast<std::size_t>(bx) * static_cast<std::size_t>(by));
        for (int j = 0; j < samples_y_; ++j) {
            for (int i = 0; i < samples_x_; ++i) {
                const std::size_t k = static_cast<std::size_t>(j) * samples_x_ + i;
                if (!usable[k]) continue;
                Neighbourhood& n = blocks[static_cast<std::size_t>(j / kBlock) * bx + i / kBlock][samples[k].face];
                n.luma.push_back(luma(samples[k].radiance));
                const double sum = samples[k].radiance.sum();
                if (sum > 0.0) n.chroma_sum += samples[k].radiance / sum;
            }
        }
        for (auto& block : blocks) {
            for (auto& [face, n] : block) {
                std::vector<double> sorted = n.luma;
                auto mid = sorted.begin() + static_cast<std::ptrdiff_t>(sorted.size() / 2);
                std::nth_element(sorted.begin(), mid, sorted.end());
                n.median = *mid;
            }
        }
        for (int j = 0; j < samples_y_; ++j) {
            for (int i = 0; i < samples_x_; ++i) {
                const std::size_t k = static_cast<std::size_t>(j) * samples_x_ + i;
                if (!usable[k]) continue;
                const Sample& s = samples[k];
                const Neighbourhood& n = blocks[static_cast<std::size_t>(j / kBlock) * bx + i / kBlock].at(s.face);
                if (n.luma.size() < 16 || !(luma(s.radiance) > 1.5 * n.median)) continue;
                const Eigen::Vector3d mean_chroma = n.chroma_sum / static_cast<double>(n.luma.size());
                const double sum = s.radiance.sum();
                const Eigen::Vector3d c = sum > 0.0 ? Eigen::Vector3d(s.radiance / sum) : mean_chroma;
                const Eigen::Vector3d towards = illum - mean_chroma;
                const double reach = towards.squaredNorm();
                // Hard case: a surface of the illuminant's own colour: chromaticity cannot tell; keep it.
                if (reach > 4e-4 && (c - mean_chroma).dot(towards) / reach > 0.3) highlight[k] = 1;
            }
        }
    }

    // Step 3: accumulate.
    for (std::size_t k = 0; k < samples.size(); ++k) {
        Sample& s = samples[k];
        if (s.face < 0) continue;
        if (s.excluded && (s.reason == 1 || s.reason == 2)) {
            if (s.tag >= 0 && s.ring) {
                ++tags_[static_cast<std::size_t>(s.tag)].white.clipped;
            } else if (s.tag < 0 && s.cell >= 0) {
                ++grids_[static_cast<std::size_t>(s.face)].cells[static_cast<std::size_t>(s.cell)].clipped;
            }
            continue;
        }
        if (s.tag >= 0 && s.ring && !s.excluded) {
            const int i = static_cast<int>(k % samples_x_), j = static_cast<int>(k / samples_x_);
            if (face_at(i - 1, j) == s.face && face_at(i + 1, j) == s.face && face_at(i, j - 1) == s.face &&
                face_at(i, j + 1) == s.face) {
                TagReference& ref = tags_[static_cast<std::size_t>(s.tag)];
                ref.white.add(s.radiance, s.weight);
                ref.face = s.face;
                ++obs.tag_reference;
                ++obs.on_tag;
            }
            continue;
        }
        if (!usable[k]) continue;
        if (highlight[k]) {
            ++obs.highlight;
            continue;
        }
        grids_[static_cast<std::size_t>(s.face)].cells[static_cast<std::size_t>(s.cell)].add(s.radiance, s.weight);
        ++obs.used;
    }
    ++frames_;
    totals_.samples += obs.samples;
    totals_.used += obs.used;
    totals_.saturated += obs.saturated;
    totals_.dark += obs.dark;
    totals_.on_virtual += obs.on_virtual;
    totals_.on_tag += obs.on_tag;
    totals_.tag_reference += obs.tag_reference;
    totals_.border += obs.border;
    totals_.highlight += obs.highlight;
    totals_.nothing += obs.nothing;
    return obs;
}

namespace {

// Calls f(cell) for the cells of a face grid whose centres lie inside the element.
template <typename Grid, typename F>
int forCellsInside(const Grid& g, const Element& element, F f) {
    const Eigen::Vector2d corners[4] = {element.st, element.st + element.ds, element.st + element.dt,
                                        element.st + element.ds + element.dt};
    Eigen::Vector2d lo = corners[0], hi = corners[0];
    for (const auto& c : corners) {
        lo = lo.cwiseMin(c);
        hi = hi.cwiseMax(c);
    }
    const int i0 = std::max(0, static_cast<int>(std::floor(lo.x() * g.ns)));
    const int i1 = std::min(g.ns - 1, static_cast<int>(std::ceil(hi.x() * g.ns)));
    const int j0 = std::max(0, static_cast<int>(std::floor(lo.y() * g.nt)));
    const int j1 = std::min(g.nt - 1, static_cast<int>(std::ceil(hi.y() * g.nt)));
    Eigen::Matrix2d m;
    m.col(0) = element.ds;
    m.col(1) = element.dt;
    const Eigen::Matrix2d inv = m.inverse();
    int inside = 0;
    for (int j = j0; j <= j1; ++j) {
        for (int i = i0; i <= i1; ++i) {
            const Eigen::Vector2d centre((i + 0.5) / g.ns, (j + 0.5) / g.nt);
            const Eigen::Vector2d ab = inv * (centre - element.st);
            if (!insideUnit(ab.x(), ab.y(), element.triangle, 1e-9)) continue;
            ++inside;
            f(g.cells[static_cast<std::size_t>(j) * g.ns + i]);
        }
    }
    return inside;
}

}  // namespace

double Observations::spread(const Element& element, int min_pixels) const {
    const Grid& g = grids_[static_cast<std::size_t>(element.face)];
    std::vector<double> values;
    forCellsInside(g, element, [&](const RadianceStats& c) {
        if (c.pixels >= static_cast<std::uint32_t>(min_pixels)) values.push_back(luma(c.mean()));
    });
    if (values.size() < 4) return 0.0;
    std::sort(values.begin(), values.end());
    const double p10 = values[values.size() / 10], p90 = values[values.size() * 9 / 10];
    double mean = 0.0;
    for (double v : values) mean += v;
    mean /= static_cast<double>(values.size());
    return mean > 0.0 ? (p90 - p10) / mean : 0.0;
}

RadianceStats Observations::aggregate(const Element& element) const {
    const Grid& g = grids_[static_cast<std::size_t>(element.face)];
    RadianceStats out;
    const int inside = forCellsInside(g, element, [&](const RadianceStats& c) { out.merge(c); });
    if (inside == 0) {
        // Hard case: an element smaller than a cell: the cell under its centre, weighted by the
        // fraction of the cell it covers.
        const Eigen::Vector2d centre = element.st + (element.triangle ? 1.0 / 3.0 : 0.5) * (element.ds + element.dt);
        const int i = std::clamp(static_cast<int>(centre.x() * g.ns), 0, g.ns - 1);
        const int j = std::clamp(static_cast<int>(centre.y() * g.nt), 0, g.nt - 1);
        const RadianceStats& c = g.cells[static_cast<std::size_t>(j) * g.ns + i];
        const double fraction = g.cell_area > 0.0 ? std::min(1.0, element.area / g.cell_area) : 1.0;
        out.weight = c.weight * fraction;
        out.sum = c.sum * fraction;
        out.sum_sq = c.sum_sq * fraction;
        out.pixels = c.pixels;
        out.clipped = c.clipped;
    }
    return out;
}

}  // namespace commonlight::lighting

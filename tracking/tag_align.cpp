#include "tracking/tag_align.h"

#include <apriltag/apriltag.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <optional>
#include <vector>

#include <Eigen/Cholesky>

#include "tracking/edge_profile.h"
#include "tracking/projection.h"
#include "tracking/tag_detector.h"

namespace commonlight::tracking {

Result<TagPattern> TagPattern::make(const std::string& family, int id) {
    TagDetectorOptions check;
    check.family = family;
    CL_TRY_VOID(check.validate());
    apriltag_family_t* fam = makeApriltagFamily(family);  // destroyed below
    if (!fam) return fail(ErrorCode::kUsage, "unknown tag family '" + family + "'");
    if (id < 0 || static_cast<std::uint32_t>(id) >= fam->ncodes) {
        destroyApriltagFamily(family, fam);
        return fail(ErrorCode::kUsage, "tag id " + std::to_string(id) + " is not in " + family);
    }
    image_u8_t* image = apriltag_to_image(fam, id);  // freed below (image_u8_destroy is not exported)
    const int total = fam->total_width;
    const int border = fam->width_at_border;
    destroyApriltagFamily(family, fam);
    if (!image) return fail(ErrorCode::kInternal, "libapriltag could not draw tag " + std::to_string(id));
    // Cells: row 0 is the image's top (+y in the tag frame). The black square spans `border`
    // cells and is centred; the drawn image spans `total` cells.
    TagPattern pattern;
    pattern.cell_ = 1.0 / border;
    const double half = 0.5 * total * pattern.cell_;
    const auto white = [&](int col, int row) { return image->buf[row * image->stride + col] > 127; };
    // Beyond the drawn tag (its white border) counts as white.
    const auto white_or_out = [&](int col, int row) {
        return col < 0 || row < 0 || col >= total || row >= total || white(col, row);
    };
    pattern.total_ = total;
    pattern.white_.resize(static_cast<std::size_t>(total * total));
    for (int row = 0; row < total; ++row) {
        for (int col = 0; col < total; ++col) pattern.white_[static_cast<std::size_t>(row * total + col)] = white(col, row);
    }
    const auto x = [&](int col) { return -half + col * pattern.cell_; };
    const auto y = [&](int row) { return half - row * pattern.cell_; };
    for (int row = 0; row < total; ++row) {
        for (int col = 0; col < total; ++col) {
            // Boundary with the right neighbour: a vertical segment.
            if (col + 1 < total && white(col, row) != white(col + 1, row)) {
                const Eigen::Vector2d dir = white(col + 1, row) ? Eigen::Vector2d(1, 0) : Eigen::Vector2d(-1, 0);
                // An end is an L junction when the two cells beyond it have one colour.
                pattern.edges_.push_back({{x(col + 1), y(row)},
                                          {x(col + 1), y(row + 1)},
                                          dir,
                                          white_or_out(col, row - 1) == white_or_out(col + 1, row - 1),
                                          white_or_out(col, row + 1) == white_or_out(col + 1, row + 1)});
            }
            // Boundary with the neighbour below: a horizontal segment (below is -y).
            if (row + 1 < total && white(col, row) != white(col, row + 1)) {
                const Eigen::Vector2d dir = white(col, row + 1) ? Eigen::Vector2d(0, -1) : Eigen::Vector2d(0, 1);
                pattern.edges_.push_back({{x(col), y(row + 1)},
                                          {x(col + 1), y(row + 1)},
                                          dir,
                                          white_or_out(col - 1, row) == white_or_out(col - 1, row + 1),
                                          white_or_out(col + 1, row) == white_or_out(col + 1, row + 1)});
            }
        }
    }
    std::free(image->buf);
    std::free(image);
    return pattern;
}

const TagPattern* TagPatternCache::get(int id) {
    auto it = patterns_.find(id);
    if (it == patterns_.end()) {
        auto made = TagPattern::make(family_, id);
        it = patterns_.emplace(id, made ? std::make_unique<TagPattern>(std::move(*made)) : nullptr).first;
    }
    return it->second.get();
}

namespace {

// The tag's black and white levels against its albedos: the pixel nearest each cell's centre (at
// least 1.5 px from the cell's boundaries on cells of 3 px), the lower quartile of the black
// cells' codes and the upper quartile of the white ones'. `exponent`: e with (black / white
// through `lin`)^e = the albedo ratio; `gamma`: g with (black code / white code)^g = the albedo
// ratio. nullopt when too few cells are in the image or the levels say nothing (not darker,
// saturated, zero).
struct ResponseMeasure {
    double exponent, gamma;
};

std::optional<ResponseMeasure> measureResponse(const ImageView& gray8, const CameraModel& camera,
                                               const TagPattern& pattern, double size, const Rigid3d& cam_from_tag,
                                               const Linearizer& lin, const TagAlignOptions& options) {
    if (!(options.albedo_ratio > 0.0 && options.albedo_ratio < 1.0)) return std::nullopt;
    thread_local std::vector<std::uint8_t> black, white;
    black.clear();
    white.clear();
    const int total = pattern.total();
    const double c = pattern.cell(), half = 0.5 * total * c;
    for (int row = 0; row < total; ++row) {
        for (int col = 0; col < total; ++col) {
            const Eigen::Vector3d centre(size * (-half + (col + 0.5) * c), size * (half - (row + 0.5) * c), 0.0);
            const auto px = camera.project(cam_from_tag * centre);
            if (!px) continue;
            const long x = std::lround(px->x()), y = std::lround(px->y());
            if (x < 0 || y < 0 || x >= gray8.width || y >= gray8.height) continue;
            (pattern.white(col, row) ? white : black)
                .push_back(gray8.data[static_cast<std::size_t>(y) * gray8.stride + static_cast<std::size_t>(x)]);
        }
    }
    if (static_cast<int>(black.size()) < options.response_min_cells ||
        static_cast<int>(white.size()) < options.response_min_cells) {
        return std::nullopt;
    }
    // The darker quarter of the black cells and the brighter quarter of the white ones: cells
    // inside larger regions of their colour, which a blur of a small tag does not reach.
    const auto quantile = [](std::vector<std::uint8_t>& v, double q) {
        const auto k = static_cast<std::ptrdiff_t>(q * static_cast<double>(v.size() - 1) + 0.5);
        std::nth_element(v.begin(), v.begin() + k, v.end());
        return v[static_cast<std::size_t>(k)];
    };
    const int b = quantile(black, 0.25), w = quantile(white, 0.75);
    if (w >= 255 || b <= 0 || !(b < w)) return std::nullopt;
    const double lb = lin.lut[b], lw = lin.lut[w];
    if (!(lb > 0.0 && lw > lb)) return std::nullopt;
    const double log_ratio = std::log(options.albedo_ratio);
    const double e = log_ratio / std::log(lb / lw), g = log_ratio / std::log(static_cast<double>(b) / w);
    if (!std::isfinite(e) || !std::isfinite(g)) return std::nullopt;
    return ResponseMeasure{e, std::clamp(g, options.min_response_gamma, options.max_response_gamma)};
}

}  // namespace

TagAlignResult alignTagPose(const ImageView& gray8, const CameraModel& camera, const TagPattern& pattern, double size,
                            const Rigid3d& cam_from_tag, const TagAlignOptions& options) {
    TagAlignResult out;
    out.cam_from_tag = cam_from_tag;
    if (gray8.format != PixelFormat::kGray8 || !cam_from_tag.isValid() || !(size > 0)) {
        out.reason = "bad input";
        return out;
    }
    // Cell size in the image, from the projected black square's side.
    const auto c0 = camera.project(cam_from_tag * Eigen::Vector3d(-0.5 * size, -0.5 * size, 0));
    const auto c1 = camera.project(cam_from_tag * Eigen::Vector3d(0.5 * size, -0.5 * size, 0));
    const auto c3 = camera.project(cam_from_tag * Eigen::Vector3d(-0.5 * size, 0.5 * size, 0));
    if (!c0 || !c1 || !c3) {
        out.reason = "the tag is outside the lens model";
        return out;
    }
    const double cell_px = pattern.cell() * std::min((*c1 - *c0).norm(), (*c3 - *c0).norm());
    if (cell_px < options.min_cell_px) {
        out.reason = "cells of " + std::to_string(cell_px) + " px are too small";
        return out;
    }
    out.measured = true;
    const double range = std::max(options.search_px, 0.35 * cell_px);
    const Linearizer& base_lin = options.linearizer ? *options.linearizer : Linearizer::get(options.srgb);
    // The response mismatch, from the tag's black and white cells against their known albedos:
    // the edges are then found through the corrected linearization (tag_align.h).
    std::optional<Linearizer> corrected;
    if (options.estimate_response && cell_px >= options.response_min_cell_px) {
        if (const auto m = measureResponse(gray8, camera, pattern, size, cam_from_tag, base_lin, options)) {
            out.response_exponent_measured = m->exponent;
            if (std::max(m->exponent, 1.0 / m->exponent) > options.response_min_change) {
                out.response_gamma = m->gamma;
                corrected = Linearizer::gamma(m->gamma);
            }
        }
    }
    const Linearizer& lin = corrected ? *corrected : base_lin;
    using Matrix7d = Eigen::Matrix<double, 7, 7>;
    using Vector7d = Eigen::Matrix<double, 7, 1>;
    // Cells too small for a clearance from the L junctions: the blur reaches every point of a
    // boundary (its middle too), and keeping them all is worth more than dropping some. The same
    // on a strongly foreshortened tag (its sides' ratio under corner_clearance_min_aspect): its
    // short boundaries would keep only their midpoints.
    const double side_a = (*c1 - *c0).norm(), side_b = (*c3 - *c0).norm();
    const double aspect = std::min(side_a, side_b) / std::max(side_a, side_b);
    const bool clear_corners = cell_px >= options.corner_clearance_min_cell_px && aspect >= options.corner_clearance_min_aspect;
    Rigid3d pose = cam_from_tag;
    double dilation = 0.0;  // cells
    // The prior on the dilation, in the normal equations' units (pixels^2 per cell^2).
    const double prior = options.estimate_dilation ? 1.0 / (options.dilation_sigma_cells * options.dilation_sigma_cells) : 0;
    Matrix7d info = Matrix7d::Zero();
    double sum2 = 0.0, sum_cell_px = 0.0;
    int used = 0;
    for (int it = 0; it < options.iterations; ++it) {
        Matrix7d h = Matrix7d::Zero();
        Vector7d g = Vector7d::Zero();
        sum2 = 0.0;
        sum_cell_px = 0.0;
        used = 0;
        for (const TagPattern::Edge& e : pattern.edges()) {
            const Eigen::Vector3d bright_tag(e.to_bright.x(), e.to_bright.y(), 0.0);
            // The boundary where the model puts it: the pattern's, moved `dilation` cells into the white.
            const Eigen::Vector3d shift = (dilation * size * pattern.cell()) * bright_tag;
            // The boundary's direction and one cell of its bright normal, in the camera frame
            // (the same for its three points).
            const Eigen::Vector3d along_tag(size * (e.b - e.a).x(), size * (e.b - e.a).y(), 0.0);
            const Eigen::Vector3d along_cam = pose.rotation * along_tag;
            const Eigen::Vector3d bright_cam = pose.rotation * (size * pattern.cell() * bright_tag);
            // Three points per cell boundary, away from its ends (where other boundaries meet);
            // not one within `corner_clearance_px` of an L junction. A blur rounds a region's
            // convex corner, and the edge found near it lies inside the region (measured on the
            // response cases of `bench tracking`, cells of 4 px: -0.12 % range and a tilt of
            // 0.05-0.15 degrees per tag; with a defocus of 1.5 px, 1.5x the rotation error). A
            // crossing of four cells (point symmetric) and a straight continuation do not bend it.
            for (const double t : {0.25, 0.5, 0.75}) {
                const Eigen::Vector2d q = e.a + t * (e.b - e.a);
                const Eigen::Vector3d p_tag = Eigen::Vector3d(size * q.x(), size * q.y(), 0.0) + shift;
                const Eigen::Vector3d p_cam = pose * p_tag;
                // The clearance is tested before the projection: it needs only the boundary's
                // length in the image, d_pixel_d_p (the projection's, bit for bit) times
                // along_cam, and the points it drops (19 % on `wide`) skip the projection.
                if (clear_corners && ((t < 0.5 && e.corner_a) || (t > 0.5 && e.corner_b))) {
                    const auto d_pixel_d_p = pixelJacobianOfPoint(camera, p_cam);
                    if (!d_pixel_d_p) continue;
                    if (std::min(t, 1.0 - t) * (*d_pixel_d_p * along_cam).norm() < options.corner_clearance_px) continue;
                }
                const auto proj = projectWithJacobian(camera, p_cam);
                if (!proj) continue;
                // Image directions of the boundary and of its dark-to-bright normal: the tag's
                // directions through the projection's Jacobian (one cell of the bright direction).
                const Eigen::Vector2d along_px = proj->d_pixel_d_p * along_cam;
                const Eigen::Vector2d along = along_px.normalized();
                const Eigen::Vector2d bright_px = proj->d_pixel_d_p * bright_cam;
                Eigen::Vector2d n(-along.y(), along.x());
                if (n.dot(bright_px) < 0) n = -n;
                if (!n.allFinite()) continue;
                const auto s = edgeOffset(gray8, lin, proj->pixel, n, along, range);
                if (!s) continue;
                // Residual: signed distance of the projected boundary from the observed one.
                const double r = -*s;
                Eigen::Matrix<double, 1, 7> j;
                j.head<6>() = n.transpose() * proj->d_pixel_d_xi;
                // d r / d dilation: pixels per cell along the normal here.
                const double cell_here = n.dot(bright_px);
                j(6) = options.estimate_dilation ? cell_here : 0.0;
                const double w = std::abs(r) <= options.huber_px ? 1.0 : options.huber_px / std::abs(r);
                // h += w j^T j on the lower triangle only (the LDLT solves below read no other),
                // each element the product Eigen's outer product forms: j(col) * (w j(row)).
                const Vector7d wj = w * j.transpose();
                for (int col = 0; col < 7; ++col) {
                    for (int row = col; row < 7; ++row) h(row, col) += j(col) * wj(row);
                }
                g += wj * r;
                sum2 += r * r;
                sum_cell_px += cell_here;
                ++used;
            }
        }
        if (used < 24) {
            out.reason = "only " + std::to_string(used) + " cell boundaries found in the image";
            return out;
        }
        h.triangularView<Eigen::StrictlyUpper>() = h.transpose();
        // The prior pulls the dilation to 0 (and fixes it there when it is not estimated).
        h(6, 6) += options.estimate_dilation ? prior : 1.0;
        g(6) += options.estimate_dilation ? prior * dilation : 0.0;
        info = h;
        const Vector7d step = -(h + 1e-9 * h.trace() * Matrix7d::Identity()).ldlt().solve(g);
        if (!step.allFinite()) {
            out.reason = "the alignment did not converge";
            return out;
        }
        const Rigid3d next = expSe3(Vector6d(step.head<6>())) * pose;
        // How far the step moves the black square's corners (and, by the dilation, its outline).
        double moved_px = std::abs(step(6)) * cell_px;
        for (int c = 0; c < 4 && moved_px <= options.converged_px; ++c) {
            const Eigen::Vector3d corner = tagCornerInTag(c, size);
            const auto before = camera.project(pose * corner);
            const auto after = camera.project(next * corner);
            moved_px = before && after ? std::max(moved_px, (*after - *before).norm())
                                       : std::numeric_limits<double>::infinity();
        }
        pose = next;
        dilation += step(6);
        if (moved_px <= options.converged_px) break;
    }
    out.points = used;
    out.rms_px = std::sqrt(sum2 / used);
    out.cell_px = cell_px;
    out.dilation_cells = dilation;
    out.dilation_px = dilation * sum_cell_px / used;
    if (out.rms_px > options.max_rms_px || !pose.isValid()) {
        out.reason = "the pattern does not match the image (rms " + std::to_string(out.rms_px) + " px)";
        return out;
    }
    if (!(std::abs(dilation) <= options.max_dilation_cells)) {
        out.reason = "the fitted dilation of " + std::to_string(dilation) + " cells is implausible";
        return out;
    }
    const double s2 = std::max(out.rms_px * out.rms_px, 0.01);
    // The pose's covariance is the pose block of the joint one: the dilation's uncertainty included.
    const Eigen::Matrix<double, 7, 7> joint =
        s2 * (info + 1e-12 * info.trace() * Eigen::Matrix<double, 7, 7>::Identity()).ldlt().solve(
                 Eigen::Matrix<double, 7, 7>::Identity());
    out.covariance = joint.topLeftCorner<6, 6>();
    out.covariance = (0.5 * (out.covariance + out.covariance.transpose())).eval();
    out.cam_from_tag = pose;
    out.ok = out.covariance.allFinite();
    if (!out.ok) out.reason = "the covariance is not finite";
    return out;
}

}  // namespace commonlight::tracking

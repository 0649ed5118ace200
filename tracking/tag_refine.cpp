#include "tracking/tag_refine.h"

#include <algorithm>
#include <cmath>
#include <optional>
#include <vector>

#include <Eigen/Eigenvalues>

namespace commonlight::tracking {
namespace {

// Pixel value to linear intensity (0..255 scale): the sRGB curve inverted, or the identity.
// Edges are found in linear intensity: the optics blur light, not encoded pixel values, and the
// steepest point of a blurred step moves towards the dark side once the sRGB curve is applied
// (measured on the desk sample: about 0.15 px per edge, a scale bias of the whole tag).
struct Linearizer {
    double lut[256];
    explicit Linearizer(bool srgb) {
        for (int v = 0; v < 256; ++v) {
            const double c = v / 255.0;
            lut[v] = 255.0 * (!srgb ? c : c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4));
        }
    }
};

// Bilinear sample of the linearized image; nullopt outside the image (with a one-pixel margin).
std::optional<double> sample(const ImageView& img, const Linearizer& lin, double x, double y) {
    if (!(x >= 0.0) || !(y >= 0.0) || x > img.width - 1.001 || y > img.height - 1.001) return std::nullopt;
    const int x0 = static_cast<int>(x), y0 = static_cast<int>(y);
    const double fx = x - x0, fy = y - y0;
    const std::uint8_t* r0 = img.row(y0) + x0;
    const std::uint8_t* r1 = img.row(y0 + 1) + x0;
    return (1 - fy) * ((1 - fx) * lin.lut[r0[0]] + fx * lin.lut[r0[1]]) +
           fy * ((1 - fx) * lin.lut[r1[0]] + fx * lin.lut[r1[1]]);
}

// Along the line p + s * n, s in [-range, range]: the s of the steepest rise of the intensity
// (dark inside to bright outside), to sub-pixel by a parabola through the peak and its neighbours.
std::optional<double> edgeOffset(const ImageView& img, const Linearizer& lin, const Eigen::Vector2d& p,
                                 const Eigen::Vector2d& n, const Eigen::Vector2d& along, double range) {
    constexpr double kStep = 0.25;
    const int steps = static_cast<int>(std::ceil(range / kStep));
    std::vector<double> values;
    values.reserve(static_cast<std::size_t>(2 * steps + 3));
    for (int k = -steps - 1; k <= steps + 1; ++k) {
        // Three profiles 0.5 px apart along the edge, averaged: less noise, same edge.
        double sum = 0.0;
        for (const double a : {-0.5, 0.0, 0.5}) {
            const Eigen::Vector2d q = p + (k * kStep) * n + a * along;
            const auto v = sample(img, lin, q.x(), q.y());
            if (!v) return std::nullopt;
            sum += *v;
        }
        values.push_back(sum / 3.0);
    }
    // Central differences at k = -steps..steps (index i + 1 in values).
    int best = -1;
    double best_d = 0.0;
    std::vector<double> d(static_cast<std::size_t>(2 * steps + 1));
    for (int i = 0; i < 2 * steps + 1; ++i) {
        d[static_cast<std::size_t>(i)] = values[static_cast<std::size_t>(i + 2)] - values[static_cast<std::size_t>(i)];
        if (d[static_cast<std::size_t>(i)] > best_d) {
            best_d = d[static_cast<std::size_t>(i)];
            best = i;
        }
    }
    // A real edge of a printed tag is a step of tens of grey levels; under a few is noise.
    constexpr double min_step = 3.0;
    if (best <= 0 || best >= 2 * steps || best_d < min_step * 2 * kStep) return std::nullopt;
    // The edge is where the profile crosses halfway between the dark and the bright level
    // (exact for any symmetric blur in linear light, and steadier under noise than the peak of
    // the derivative). Levels: the means of the profile from 1 px beyond the peak to the ends.
    const int peak = best + 1;  // index into values
    const int margin = static_cast<int>(1.0 / kStep);
    double dark = 0, bright = 0;
    int n_dark = 0, n_bright = 0;
    for (int j = 0; j < static_cast<int>(values.size()); ++j) {
        if (j <= peak - margin) {
            dark += values[static_cast<std::size_t>(j)];
            ++n_dark;
        } else if (j >= peak + margin) {
            bright += values[static_cast<std::size_t>(j)];
            ++n_bright;
        }
    }
    if (n_dark == 0 || n_bright == 0) return std::nullopt;
    const double mid = 0.5 * (dark / n_dark + bright / n_bright);
    // The crossing nearest the peak.
    for (int r = 0; r < margin; ++r) {
        for (const int j : {peak - r - 1, peak + r}) {
            if (j < 0 || j + 1 >= static_cast<int>(values.size())) continue;
            const double v0 = values[static_cast<std::size_t>(j)], v1 = values[static_cast<std::size_t>(j + 1)];
            if (v0 <= mid && v1 > mid) {
                const double frac = (mid - v0) / (v1 - v0);
                return (j - steps - 1 + frac) * kStep;
            }
        }
    }
    return std::nullopt;
}

struct Line {  // n . x = c, |n| = 1
    Eigen::Vector2d n;
    double c;
};

std::optional<Line> fitLine(const std::vector<Eigen::Vector2d>& pts) {
    if (pts.size() < 2) return std::nullopt;
    Eigen::Vector2d mean = Eigen::Vector2d::Zero();
    for (const auto& p : pts) mean += p;
    mean /= static_cast<double>(pts.size());
    Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
    for (const auto& p : pts) cov += (p - mean) * (p - mean).transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> es(cov);
    const Eigen::Vector2d n = es.eigenvectors().col(0);  // smallest eigenvalue: the normal
    if (!n.allFinite()) return std::nullopt;
    return Line{n, n.dot(mean)};
}

std::optional<Eigen::Vector2d> intersect(const Line& a, const Line& b) {
    Eigen::Matrix2d m;
    m << a.n.transpose(), b.n.transpose();
    const double det = m.determinant();
    // Adjacent sides of a square seen at up to ~85 degrees are far from parallel; nearly parallel
    // lines mean the fit went wrong.
    if (std::abs(det) < 1e-3) return std::nullopt;
    return m.inverse() * Eigen::Vector2d(a.c, b.c);
}

}  // namespace

bool refineTagCorners(const ImageView& gray8, const CameraModel& camera, std::array<Eigen::Vector2d, 4>& corners,
                      const TagRefineOptions& options) {
    if (gray8.format != PixelFormat::kGray8 || gray8.empty()) return false;
    Eigen::Vector2d centre = Eigen::Vector2d::Zero();
    for (const auto& c : corners) centre += c;
    centre /= 4.0;
    const Linearizer lin(options.srgb);
    std::array<Line, 4> lines;
    for (int side = 0; side < 4; ++side) {
        // Step 1: edge points along the side from corner `side` to corner `side + 1`.
        const Eigen::Vector2d a = corners[side], b = corners[(side + 1) % 4];
        const double length = (b - a).norm();
        if (!(length > 4.0)) return false;
        const Eigen::Vector2d dir = (b - a) / length;
        Eigen::Vector2d normal(-dir.y(), dir.x());
        if (normal.dot(0.5 * (a + b) - centre) < 0) normal = -normal;  // outward
        const double range = std::max(options.search_px, 0.08 * length);
        std::vector<Eigen::Vector2d> ideal;
        const int samples = static_cast<int>(length);
        for (int k = 0; k <= samples; ++k) {
            const double t = static_cast<double>(k) / std::max(samples, 1);
            if (t < 0.12 || t > 0.88) continue;  // away from the corners, where two edges meet
            const Eigen::Vector2d p = a + t * (b - a);
            const auto s = edgeOffset(gray8, lin, p, normal, dir, range);
            if (!s) continue;
            // Step 2 (first half): into the ideal pinhole image.
            if (auto u = camera.undistortPixel(p + *s * normal)) ideal.push_back(*u);
        }
        if (static_cast<int>(ideal.size()) < options.min_points) return false;
        auto line = fitLine(ideal);
        if (!line) return false;
        std::vector<Eigen::Vector2d> inliers;
        for (const auto& p : ideal) {
            if (std::abs(line->n.dot(p) - line->c) < 0.75) inliers.push_back(p);
        }
        if (static_cast<int>(inliers.size()) < options.min_points) return false;
        line = fitLine(inliers);
        if (!line) return false;
        lines[side] = *line;
    }
    // Step 3: corner i is where side i - 1 (from corner i - 1 to i) meets side i.
    std::array<Eigen::Vector2d, 4> refined;
    for (int i = 0; i < 4; ++i) {
        const auto ideal = intersect(lines[(i + 3) % 4], lines[i]);
        if (!ideal) return false;
        refined[i] = camera.distortPixel(*ideal);
        if (!refined[i].allFinite() || (refined[i] - corners[i]).norm() > options.max_shift_px) return false;
    }
    corners = refined;
    return true;
}

}  // namespace commonlight::tracking

#include "tracking/tag_refine.h"

#include "tracking/edge_profile.h"

#include <algorithm>
#include <cmath>
#include <optional>
#include <vector>

#include <Eigen/Eigenvalues>

namespace commonlight::tracking {
namespace {

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
    const Linearizer& lin = options.linearizer ? *options.linearizer : Linearizer::get(options.srgb);
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
            if (auto u = camera.undistortPixel(p + (*s - options.dilation_px) * normal)) ideal.push_back(*u);
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

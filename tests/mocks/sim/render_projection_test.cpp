// Projection: a tag rendered through a strongly distorted lens (k1 = -0.3, nonzero p1, p2) has
// its black square's corners where CameraModel::project puts them, within 0.01 px.
//
// The corners are measured from the rendered radiance alone:
// 1. The tag is lit by a directional light and nothing else is in the scene, so every pixel is
//    exactly (coverage-weighted) albedo x E cos / pi: the only noise is the sampling of each
//    pixel's footprint (256 stratified positions per pixel).
// 2. A pixel is the mean over its square [u - 0.5, u + 0.5] x [v - 0.5, v + 0.5] of the distorted
//    image. So along one row, the sum over a window of the "black fraction" (W - I) / (W - B) is the
//    black area inside the window's band, and the edge's position at the row's centre is the
//    window's end minus that sum (exact for a straight edge; the distorted edge's curvature changes
//    it by x''/24, about 1e-4 px here). W and B are the white and black plateaus, read off the image
//    at the centres of border cells. Columns do the same for the near-horizontal sides.
// 3. The edge points are undistorted with the known lens (CameraModel::undistortPixel), where
//    each side is a straight line; a total-least-squares line is fitted per side, adjacent lines
//    are intersected and the intersection is distorted back (CameraModel::distortPixel).
// Only the windows' approximate placement uses the expected projection; the values come from
// the image. Expected precision: ~0.002 px per corner (edge noise 0.006 px per row, ~150 rows).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Dense>

#include "mocks/sim/render.h"

namespace commonlight::mocks::sim {
namespace {

using Eigen::Vector2d;
using Eigen::Vector3d;

constexpr double kTagSize = 0.16;  // black square, metres (8 cells of 2 cm)

CameraModel distortedCamera() {
    CameraModel camera;
    camera.width = 640;
    camera.height = 480;
    camera.fx = 500.0;
    camera.fy = 502.0;
    camera.cx = 322.3;
    camera.cy = 236.8;
    camera.distortion = {-0.3, 0.1, 0.0012, -0.0015, 0.0};
    return camera;
}

// Camera at `eye` looking at `target`, image y down (OpenCV), world z up.
Rigid3d lookAt(const Vector3d& eye, const Vector3d& target) {
    const Vector3d z = (target - eye).normalized();
    const Vector3d x = z.cross(Vector3d::UnitZ()).normalized();
    const Vector3d y = z.cross(x);
    Eigen::Matrix3d r;
    r.col(0) = x;
    r.col(1) = y;
    r.col(2) = z;
    return {Eigen::Quaterniond(r), eye};
}

struct Line {
    Vector2d point;
    Vector2d direction;  // unit
};

Line fitLine(const std::vector<Vector2d>& points) {
    Vector2d centroid = Vector2d::Zero();
    for (const auto& p : points) centroid += p / static_cast<double>(points.size());
    Eigen::Matrix2d scatter = Eigen::Matrix2d::Zero();
    for (const auto& p : points) scatter += (p - centroid) * (p - centroid).transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> solver(scatter);
    return {centroid, solver.eigenvectors().col(1)};  // largest eigenvalue: along the line
}

Vector2d intersect(const Line& a, const Line& b) {
    Eigen::Matrix2d m;
    m.col(0) = a.direction;
    m.col(1) = -b.direction;
    const Vector2d t = m.colPivHouseholderQr().solve(b.point - a.point);
    return a.point + t.x() * a.direction;
}

TEST(RenderProjection, TagCornersLandWhereProjectSaysWithStrongDistortion) {
    // Step 1: the scene, a tag on its own under a directional light.
    Scene scene;
    scene.tags.family = "tag36h11";
    const Rigid3d world_from_tag = Rigid3d::fromRpyDeg({0.0, 0.0, 0.0}, {0, 0, 10});
    scene.tags.items.push_back({5, kTagSize, world_from_tag, 0.04, 0.8});
    Light sun;
    sun.name = "sun";
    sun.shape = DirectionalLightShape{-Vector3d::UnitZ()};
    sun.emission = RgbOrEstimate::constant(Vector3d::Constant(3.14159));
    scene.lights.push_back(sun);
    auto sim = SimScene::build(scene);
    ASSERT_TRUE(sim) << sim.error().message;

    // The camera looks past the tag so that it lands off-centre, where the lens bends it most.
    const CameraModel camera = distortedCamera();
    // Looking at the tag, then turned (about the camera's y and x axes) so that it appears in the
    // lower right of the image, ~45% of the way to the corner.
    const Rigid3d world_from_cam = lookAt({0.02, -0.13, 0.36}, {0.0, 0.0, 0.0}) *
                                   Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(-0.30, Vector3d::UnitY()) *
                                                              Eigen::AngleAxisd(0.22, Vector3d::UnitX())),
                                           Vector3d::Zero());
    const Rigid3d cam_from_tag = world_from_cam.inverse() * world_from_tag;
    const auto projectTag = [&](double x, double y) {
        const auto pixel = camera.project(cam_from_tag * Vector3d(x, y, 0.0));
        EXPECT_TRUE(pixel);
        return pixel.value_or(Vector2d::Zero());
    };
    const double h = kTagSize / 2;
    const std::vector<Vector2d> corner_xy = {{-h, -h}, {h, -h}, {h, h}, {-h, h}};
    std::vector<Vector2d> expected;
    for (const auto& c : corner_xy) expected.push_back(projectTag(c.x(), c.y()));
    const Vector2d centre_pixel = projectTag(0, 0);
    std::printf("  tag centre at pixel (%.1f, %.1f); corners (%.1f, %.1f) (%.1f, %.1f) (%.1f, %.1f) (%.1f, %.1f)\n",
                centre_pixel.x(), centre_pixel.y(), expected[0].x(), expected[0].y(), expected[1].x(), expected[1].y(),
                expected[2].x(), expected[2].y(), expected[3].x(), expected[3].y());
    std::fflush(stdout);

    // Step 2: a renderer of pixel rectangles into one image. Only the pixels the measurement reads
    // are rendered (the scan windows and the plateau samples); a pixel's value depends only on the
    // seed and its index, so rendering pieces separately gives the same values as one frame.
    RenderRequest request;
    request.scene = &*sim;
    request.camera = camera;
    request.world_from_cam = world_from_cam;
    request.spp = 256;
    request.max_depth = 1;
    std::vector<float> image(static_cast<std::size_t>(camera.width) * camera.height,
                             std::numeric_limits<float>::quiet_NaN());
    std::vector<std::int32_t> object_id(image.size(), -1);
    double seconds = 0.0;
    std::int64_t samples = 0;
    const auto renderRect = [&](int x0, int y0, int x1, int y1) {  // [x0, x1) x [y0, y1)
        x0 = std::clamp(x0, 0, camera.width);
        x1 = std::clamp(x1, x0, camera.width);
        y0 = std::clamp(y0, 0, camera.height);
        y1 = std::clamp(y1, y0, camera.height);
        request.region = PixelRect{x0, y0, x1 - x0, y1 - y0};
        auto out = render(request);
        ASSERT_TRUE(out) << out.error().message;
        ASSERT_EQ(out->nonfinite_samples, 0);
        seconds += out->seconds;
        samples += out->samples;
        for (int v = y0; v < y1; ++v) {
            const auto* row = reinterpret_cast<const float*>(out->radiance.data() + v * out->radiance.stride());
            for (int u = x0; u < x1; ++u) {
                image[static_cast<std::size_t>(v) * camera.width + u] = row[3 * u];
                object_id[static_cast<std::size_t>(v) * camera.width + u] =
                    out->object_id[static_cast<std::size_t>(v) * camera.width + u];
            }
        }
    };
    // Pixels that were not rendered read as NaN, which fails the comparisons below.
    const auto value = [&](int u, int v) {
        if (u < 0 || u >= camera.width || v < 0 || v >= camera.height) return std::numeric_limits<double>::quiet_NaN();
        return static_cast<double>(image[static_cast<std::size_t>(v) * camera.width + u]);
    };
    const auto renderedValue = [&](const Vector2d& p) {
        const int u = static_cast<int>(std::lround(p.x()));
        const int v = static_cast<int>(std::lround(p.y()));
        renderRect(u, v, u + 1, v + 1);
        return value(u, v);
    };
    // The border is the tag: the ray through a pixel in the black border sees the tag.
    const Vector2d border_pixel = projectTag(0.0, 3.5 * kTagSize / 8);
    renderedValue(border_pixel);
    const auto border_index = static_cast<std::size_t>(std::lround(border_pixel.y())) * camera.width +
                              static_cast<std::size_t>(std::lround(border_pixel.x()));
    ASSERT_GE(object_id[border_index], 0);
    EXPECT_EQ(sim->objects()[object_id[border_index]].kind, ObjectKind::kTag);
    // Step 3: the plateaus, at the centres of the white border cells and the black border cells.
    const double cell = kTagSize / 8;
    std::vector<double> white, black;
    for (int i = -4; i <= 4; ++i) {
        const double t = (i + 0.5 * (i < 0 ? 1 : -1)) * cell * (i == 0 ? 0 : 1);
        for (const auto& [x, y] : {std::pair{t, 4.5 * cell}, {t, -4.5 * cell}, {4.5 * cell, t}, {-4.5 * cell, t}}) {
            white.push_back(renderedValue(projectTag(x, y)));
        }
        for (const auto& [x, y] : {std::pair{t, 3.5 * cell}, {t, -3.5 * cell}, {3.5 * cell, t}, {-3.5 * cell, t}}) {
            black.push_back(renderedValue(projectTag(x, y)));
        }
    }
    std::nth_element(white.begin(), white.begin() + white.size() / 2, white.end());
    std::nth_element(black.begin(), black.begin() + black.size() / 2, black.end());
    const double w = white[white.size() / 2];
    const double b = black[black.size() / 2];
    ASSERT_GT(w - b, 0.1) << "W " << w << " B " << b;  // NaN (outside the bands) fails here too

    // Step 4: edge points along each side, undistorted, and a line per side.
    std::vector<Line> lines;
    for (int side = 0; side < 4; ++side) {
        const Vector2d a3 = corner_xy[side];
        const Vector2d b3 = corner_xy[(side + 1) % 4];
        const Vector2d pa = expected[side];
        const Vector2d pb = expected[(side + 1) % 4];
        const bool scan_rows = std::abs(pb.y() - pa.y()) > std::abs(pb.x() - pa.x());
        const int axis = scan_rows ? 0 : 1;  // the coordinate measured along a row (x) or a column (y)
        // Predicted edge position along the scan for each scan line, from the projected side.
        std::vector<Vector2d> polyline;
        for (int k = 0; k <= 2000; ++k) {
            const Vector2d q = a3 + (b3 - a3) * (k / 2000.0);
            polyline.push_back(projectTag(q.x(), q.y()));
        }
        const double cell_px = (pb - pa).norm() / 8.0;
        const double half_window = 0.4 * cell_px;
        const double lo = std::min(pa[1 - axis], pb[1 - axis]) + 0.5 * cell_px;
        const double hi = std::max(pa[1 - axis], pb[1 - axis]) - 0.5 * cell_px;
        std::vector<Vector2d> ideal_points;
        for (int line = static_cast<int>(std::ceil(lo)); line <= static_cast<int>(std::floor(hi)); ++line) {
            // Where the projected side crosses this scan line.
            double predicted = 0.0;
            for (std::size_t k = 0; k + 1 < polyline.size(); ++k) {
                const double s0 = polyline[k][1 - axis] - line;
                const double s1 = polyline[k + 1][1 - axis] - line;
                if ((s0 <= 0) != (s1 <= 0)) {
                    predicted = polyline[k][axis] + (polyline[k + 1][axis] - polyline[k][axis]) * s0 / (s0 - s1);
                    break;
                }
            }
            const int first = static_cast<int>(std::lround(predicted - half_window));
            const int last = static_cast<int>(std::lround(predicted + half_window));
            const bool black_after = centre_pixel[axis] > predicted;  // the black square is towards the centre
            if (scan_rows) {
                renderRect(first, line, last + 1, line + 1);
            } else {
                renderRect(line, first, line + 1, last + 1);
            }
            double black_sum = 0.0;
            for (int t = first; t <= last; ++t) {
                const double v = scan_rows ? value(t, line) : value(line, t);
                black_sum += (w - v) / (w - b);
            }
            const double edge = black_after ? (last + 0.5) - black_sum : (first - 0.5) + black_sum;
            const Vector2d distorted = scan_rows ? Vector2d(edge, line) : Vector2d(line, edge);
            const auto ideal = camera.undistortPixel(distorted);
            ASSERT_TRUE(ideal);
            ideal_points.push_back(*ideal);
        }
        ASSERT_GT(ideal_points.size(), 100u) << "side " << side;
        std::printf("  side %d: %zu edge points\n", side, ideal_points.size());
        lines.push_back(fitLine(ideal_points));
    }

    std::printf("  rendered %lld samples (%d spp) in %.2f s\n", static_cast<long long>(samples), request.spp, seconds);

    // Step 5: corners = intersections of adjacent sides, distorted back; compare with project().
    double worst = 0.0;
    for (int corner = 0; corner < 4; ++corner) {
        const Vector2d ideal = intersect(lines[(corner + 3) % 4], lines[corner]);
        const Vector2d measured = camera.distortPixel(ideal);
        const double error = (measured - expected[corner]).norm();
        worst = std::max(worst, error);
        std::printf("  corner %d: expected (%.4f, %.4f), measured (%.4f, %.4f), error %.4f px\n", corner,
                    expected[corner].x(), expected[corner].y(), measured.x(), measured.y(), error);
        EXPECT_LT(error, 0.01) << "corner " << corner;
    }
    // The lens really bends the tag: the distorted corner is far from the pinhole's.
    const Vector2d ideal_corner = camera.undistortPixel(expected[0]).value_or(Vector2d::Zero());
    std::printf("  worst corner error %.4f px (tolerance 0.01); distortion moves corner 0 by %.1f px\n", worst,
                (ideal_corner - expected[0]).norm());
    EXPECT_GT((ideal_corner - expected[0]).norm(), 5.0);
}

}  // namespace
}  // namespace commonlight::mocks::sim

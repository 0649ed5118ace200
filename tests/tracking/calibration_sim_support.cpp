#include "tests/tracking/calibration_sim_support.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <numbers>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "core/calibration_io.h"
#include "mocks/sim/render.h"
#include "tests/test_support.h"

namespace commonlight::tracking::calibration_sim {

using Eigen::Vector2d;
using Eigen::Vector3d;
using mocks::sim::RenderRequest;
using mocks::sim::SimScene;

namespace {

constexpr double kSunIrradiance = 2.0;
constexpr double kSkyRadiance = 0.1;
constexpr double kBlack = 0.04;  // albedos of the printed board
constexpr double kWhite = 0.8;
constexpr double kTable = 0.25;  // albedo of the table the board lies on

struct Errors {
    double fx, fy, cx, cy, k1, rms;
};

}  // namespace

CameraModel trueCamera() {
    CameraModel camera;
    camera.width = kWidth;
    camera.height = kHeight;
    camera.fx = 600.0;
    camera.fy = 601.5;
    camera.cx = 322.4;
    camera.cy = 236.7;
    camera.distortion = {-0.2, 0.05, 0.001, -0.0005, 0.0};
    return camera;
}

// cam_from_board for a view of a board whose centre is `centre` (board frame, metres). Facing the
// camera, the board's x points right in the image and its y up.
Rigid3d camFromBoard(const ViewSpec& view, const Vector3d& centre) {
    const CameraModel camera = trueCamera();
    using Eigen::AngleAxisd;
    const Eigen::Matrix3d facing = Eigen::Vector3d(1, -1, -1).asDiagonal();
    const Eigen::Matrix3d rotation = (AngleAxisd(view.roll_deg * std::numbers::pi / 180, Vector3d::UnitZ()) *
                                      AngleAxisd(view.tilt_y_deg * std::numbers::pi / 180, Vector3d::UnitY()) *
                                      AngleAxisd(view.tilt_x_deg * std::numbers::pi / 180, Vector3d::UnitX()))
                                         .toRotationMatrix() *
                                     facing;
    const Vector3d ray = Vector3d((view.u - camera.cx) / camera.fx, (view.v - camera.cy) / camera.fy, 1.0).normalized();
    return {Eigen::Quaterniond(rotation), view.distance * ray - rotation * centre};
}

// The board as a scene: the board frame is the world frame (z up, printed side +z), lit evenly by a
// sun along -z (slightly slanted) and a uniform sky.
Scene boardScene(const BoardSpec& board) {
    Scene scene;
    const auto grey = [](double a) { return RgbOrEstimate::constant(Vector3d::Constant(a)); };
    scene.lights.push_back({"sun", DirectionalLightShape{Vector3d(0.1, 0.15, -1).normalized()}, Rigid3d::identity(),
                            RgbOrEstimate::constant(Vector3d::Constant(kSunIrradiance))});
    scene.lights.push_back(
        {"sky", DistantLightShape{16}, Rigid3d::identity(), RgbOrEstimate::constant(Vector3d::Constant(kSkyRadiance))});
    if (board.type == BoardType::kChessboard) {
        // (cols + 1) x (rows + 1) squares; square (i, j) has its lower-left corner at ((i - 1) s, (j - 1) s).
        // The black squares lie exactly in z = 0, so the inner corners are exactly the board's points;
        // the white sheet lies 0.05 mm behind them, with a margin of one square.
        const double s = board.square_m;
        const double w = (board.cols + 3) * s;
        const double h = (board.rows + 3) * s;
        const Vector3d middle((board.cols - 1) * s / 2, (board.rows - 1) * s / 2, -5e-5);
        scene.real_objects.push_back({"sheet", PlaneShape{{w, h}}, Rigid3d({1, 0, 0, 0}, middle), grey(kWhite)});
        scene.real_objects.push_back(
            {"table", PlaneShape{{10, 10}}, Rigid3d({1, 0, 0, 0}, {0, 0, -0.01}), grey(kTable)});
        for (int j = 0; j <= board.rows; ++j) {
            for (int i = 0; i <= board.cols; ++i) {
                if ((i + j) % 2 == 1) continue;
                const Vector3d centre((i - 0.5) * s, (j - 0.5) * s, 0.0);
                scene.real_objects.push_back({"square " + std::to_string(i) + "," + std::to_string(j),
                                              PlaneShape{{s, s}}, Rigid3d({1, 0, 0, 0}, centre), grey(kBlack)});
            }
        }
    } else {
        const double t = board.tag_m;
        const double pitch = (1.0 + board.spacing_ratio) * t;
        const double w = board.cols * pitch + t;
        const double h = board.rows * pitch + t;
        const Vector3d middle((board.cols * pitch - board.spacing_ratio * t) / 2,
                              (board.rows * pitch - board.spacing_ratio * t) / 2, 0.0);
        scene.real_objects.push_back({"sheet", PlaneShape{{w, h}}, Rigid3d({1, 0, 0, 0}, middle), grey(kWhite)});
        scene.real_objects.push_back(
            {"table", PlaneShape{{10, 10}}, Rigid3d({1, 0, 0, 0}, {0, 0, -0.01}), grey(kTable)});
        for (int r = 0; r < board.rows; ++r) {
            for (int c = 0; c < board.cols; ++c) {
                const Vector3d centre(c * pitch + t / 2, r * pitch + t / 2, 0.0);
                scene.tags.items.push_back({r * board.cols + c, t, Rigid3d({1, 0, 0, 0}, centre), kBlack, kWhite});
            }
        }
    }
    return scene;
}

Vector3d boardCentre(const BoardSpec& board) {
    Vector3d lo = Vector3d::Constant(1e9);
    Vector3d hi = Vector3d::Constant(-1e9);
    for (int id = 0; id < board.pointCount(); ++id) {
        lo = lo.cwiseMin(board.point(id));
        hi = hi.cwiseMax(board.point(id));
    }
    return (lo + hi) / 2;
}

// The board points that project into the image with `margin` pixels to spare.
int pointsInView(const BoardSpec& board, const Rigid3d& cam_from_board, double margin) {
    const CameraModel camera = trueCamera();
    int inside = 0;
    for (int id = 0; id < board.pointCount(); ++id) {
        const auto pixel = camera.project(cam_from_board * board.point(id));
        if (pixel && camera.inImage(*pixel, margin)) ++inside;
    }
    return inside;
}

namespace {

// The pixels that can see the board's sheet (with `margin` pixels around them), clipped to the image:
// the bounding box of its outline, sampled densely because distortion bends the edges.
mocks::sim::PixelRect sheetRegion(const Scene& scene, const Rigid3d& cam_from_world, int margin) {
    const CameraModel camera = trueCamera();
    const RealObject& sheet = scene.real_objects.front();
    const Eigen::Vector2d half = std::get<PlaneShape>(sheet.shape).size / 2;
    double lo_u = kWidth, lo_v = kHeight, hi_u = -1, hi_v = -1;
    constexpr int kSteps = 64;
    for (int side = 0; side < 4; ++side) {
        for (int i = 0; i <= kSteps; ++i) {
            const double f = -1.0 + 2.0 * i / kSteps;
            const Vector3d p_in_sheet = side < 2 ? Vector3d(f * half.x(), (side == 0 ? -1 : 1) * half.y(), 0)
                                                 : Vector3d((side == 2 ? -1 : 1) * half.x(), f * half.y(), 0);
            const auto pixel = camera.project(cam_from_world * (sheet.world_from_object * p_in_sheet));
            if (!pixel) continue;
            lo_u = std::min(lo_u, pixel->x());
            lo_v = std::min(lo_v, pixel->y());
            hi_u = std::max(hi_u, pixel->x());
            hi_v = std::max(hi_v, pixel->y());
        }
    }
    const int x0 = std::clamp(static_cast<int>(std::floor(lo_u)) - margin, 0, kWidth);
    const int y0 = std::clamp(static_cast<int>(std::floor(lo_v)) - margin, 0, kHeight);
    const int x1 = std::clamp(static_cast<int>(std::ceil(hi_u)) + margin + 1, 0, kWidth);
    const int y1 = std::clamp(static_cast<int>(std::ceil(hi_v)) + margin + 1, 0, kHeight);
    return {x0, y0, std::max(0, x1 - x0), std::max(0, y1 - y0)};
}

}  // namespace

// Renders the views as 8-bit grey images: linear radiance scaled so that white paper in the sun is
// about 200 (no gamma: the detectors do not care). Only the pixels around the sheet are traced; the
// rest is the table's grey, which is what they would show (less its noise and the sheet's shadow).
std::vector<RenderedView> renderViews(const BoardSpec& board, const std::vector<ViewSpec>& views, int spp) {
    const Scene scene = boardScene(board);
    auto sim = SimScene::build(scene);
    EXPECT_TRUE(sim) << sim.error().message;
    if (!sim) return {};
    const double irradiance =
        kSunIrradiance * -Vector3d(0.1, 0.15, -1).normalized().z() + std::numbers::pi * kSkyRadiance;
    const double white = kWhite * irradiance / std::numbers::pi;
    const auto grey8 = [&](double radiance) {
        return static_cast<std::uint8_t>(std::clamp(std::lround(200.0 * radiance / white), 0L, 255L));
    };
    const std::uint8_t table = grey8(kTable * irradiance / std::numbers::pi);
    std::vector<RenderedView> out;
    const auto start = std::chrono::steady_clock::now();
    for (std::size_t i = 0; i < views.size(); ++i) {
        RenderRequest request;
        request.scene = &*sim;
        request.camera = trueCamera();
        const Rigid3d cam_from_board = camFromBoard(views[i], boardCentre(board));
        request.world_from_cam = cam_from_board.inverse();
        const mocks::sim::PixelRect region = sheetRegion(scene, cam_from_board, 8);
        request.region = region;
        request.spp = spp;
        request.max_depth = 2;
        request.seed = 7;
        request.frame_index = i;
        auto rendered = mocks::sim::render(request);
        EXPECT_TRUE(rendered) << rendered.error().message;
        if (!rendered) return {};
        Image gray(PixelFormat::kGray8, kWidth, kHeight);
        std::fill(gray.data(), gray.data() + gray.sizeBytes(), table);
        for (int v = region.y; v < region.y + region.height; ++v) {
            const auto* row =
                reinterpret_cast<const float*>(rendered->radiance.data() + v * rendered->radiance.stride());
            for (int u = region.x; u < region.x + region.width; ++u)
                gray.data()[v * gray.stride() + u] = grey8(row[3 * u + 1]);
        }
        char name[32];
        std::snprintf(name, sizeof name, "view%02zu.png", i);
        if (const char* dump = std::getenv("COMMONLIGHT_CALIB_TEST_DUMP")) {  // a folder to look at the images in
            const std::string file = std::string(dump) + "/" + board.toString().substr(0, 5) + "-" + name;
            cv::imwrite(file, cv::Mat(kHeight, kWidth, CV_8UC1, gray.data(), gray.stride()));
        }
        out.push_back({name, std::move(gray), cam_from_board});
    }
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::printf("rendered %zu views of %s at %d spp in %.1f s\n", views.size(), board.toString().c_str(), spp, seconds);
    return out;
}

namespace {

Errors report(const char* label, const CalibrationResult& result) {
    const CameraModel truth = trueCamera();
    const CameraModel& m = result.model;
    const Errors e{std::abs(m.fx - truth.fx) / truth.fx,
                   std::abs(m.fy - truth.fy) / truth.fy,
                   std::abs(m.cx - truth.cx) / truth.cx,
                   std::abs(m.cy - truth.cy) / truth.cy,
                   std::abs(m.distortion.k1 - truth.distortion.k1),
                   result.rms_px};
    std::printf("%s: %zu views, %zu corners, %d rounds\n", label, result.view_names.size(), result.corners,
                result.rounds);
    std::printf("  fx %.3f (true %.3f, rel. error %.4f%%, std %.3f)\n", m.fx, truth.fx, 100 * e.fx,
                result.std_deviations[0]);
    std::printf("  fy %.3f (true %.3f, rel. error %.4f%%, std %.3f)\n", m.fy, truth.fy, 100 * e.fy,
                result.std_deviations[1]);
    std::printf("  cx %.3f (true %.3f, rel. error %.4f%%, std %.3f)\n", m.cx, truth.cx, 100 * e.cx,
                result.std_deviations[2]);
    std::printf("  cy %.3f (true %.3f, rel. error %.4f%%, std %.3f)\n", m.cy, truth.cy, 100 * e.cy,
                result.std_deviations[3]);
    std::printf("  k1 %.5f k2 %.5f p1 %.6f p2 %.6f k3 %.5f (k1 error %.5f)\n", m.distortion.k1, m.distortion.k2,
                m.distortion.p1, m.distortion.p2, m.distortion.k3, e.k1);
    std::printf("  RMS %.4f px; coverage %.0f%%%s%s\n", result.rms_px, 100 * result.coverage.fraction,
                result.coverage.warning.empty() ? "" : "; ", result.coverage.warning.c_str());
    for (const RejectedView& r : result.rejected) std::printf("  rejected %s: %s\n", r.name.c_str(), r.reason.c_str());
    return e;
}

}  // namespace

// Calibrates from the views, checks the accuracy and that the bad view was rejected, and that the
// output round-trips through core's reader.
void calibrateAndCheck(const BoardSpec& board, const std::vector<ViewSpec>& good, const ViewSpec& bad,
                       const std::string& bad_reason) {
    std::vector<ViewSpec> all = good;
    all.push_back(bad);
    const std::vector<RenderedView> views = renderViews(board, all, 8);
    ASSERT_EQ(views.size(), all.size());

    auto detector = BoardDetector::create(board);
    ASSERT_TRUE(detector) << detector.error().message;
    Calibrator calibrator(board, CalibrationOptions{});
    const auto start = std::chrono::steady_clock::now();
    std::vector<double> corner_errors;  // detected corner against the true projection, pixels
    for (const RenderedView& view : views) {
        auto detection = detector->detect(view.gray);
        ASSERT_TRUE(detection) << detection.error().message;
        const BoardObservation& obs = detection->observation;
        for (std::size_t k = 0; k < obs.point_ids.size(); ++k) {
            const int id = obs.point_ids[k];
            double error = 0.0;
            if (board.type == BoardType::kAprilGrid) {
                const auto truth = trueCamera().project(view.cam_from_board * board.point(id));
                ASSERT_TRUE(truth);
                error = (obs.pixels[k] - *truth).norm();
            } else {
                // OpenCV labels the corners row by row from the image's top (the scene's +y), starting
                // at either end of the board (two labellings 180 degrees apart): the scene point of
                // id (c, r) is (c, rows - 1 - r) or (cols - 1 - c, r) squares.
                const int c = id % board.cols;
                const int r = id / board.cols;
                const auto a =
                    trueCamera().project(view.cam_from_board * board.point((board.rows - 1 - r) * board.cols + c));
                const auto b =
                    trueCamera().project(view.cam_from_board * board.point(r * board.cols + board.cols - 1 - c));
                ASSERT_TRUE(a && b);
                error = std::min((obs.pixels[k] - *a).norm(), (obs.pixels[k] - *b).norm());
            }
            corner_errors.push_back(error);
            if (error > 0.5) {
                std::printf("  %s point %d at (%.1f, %.1f): %.2f px from the truth\n", view.name.c_str(),
                            obs.point_ids[k], obs.pixels[k].x(), obs.pixels[k].y(), error);
            }
        }
        ASSERT_TRUE(calibrator.add(view.name, kWidth, kHeight, *detection));
        if (&view != &views.back()) {
            EXPECT_TRUE(detection->found) << view.name << ": " << detection->reason;
        }
    }
    auto result = calibrator.calibrate();
    ASSERT_TRUE(result) << result.error().message;
    std::sort(corner_errors.begin(), corner_errors.end());
    ASSERT_FALSE(corner_errors.empty());
    double sum2 = 0.0;
    for (const double e : corner_errors) sum2 += e * e;
    std::printf("corner error against the truth: RMS %.3f px, median %.3f px, p95 %.3f px, max %.3f px\n",
                std::sqrt(sum2 / corner_errors.size()), corner_errors[corner_errors.size() / 2],
                corner_errors[corner_errors.size() * 95 / 100], corner_errors.back());
    std::printf("detected and calibrated in %.2f s\n",
                std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
    const Errors e = report(board.toString().c_str(), *result);
    EXPECT_LT(e.fx, 0.002);
    EXPECT_LT(e.fy, 0.002);
    EXPECT_LT(e.cx, 0.002);
    EXPECT_LT(e.cy, 0.002);
    EXPECT_LT(e.k1, 0.01);
    EXPECT_LT(e.rms, 0.3);
    EXPECT_TRUE(result->coverage.warning.empty()) << result->coverage.warning;

    // Every good view is used; the bad one is rejected with its reason.
    EXPECT_EQ(result->view_names.size(), good.size());
    ASSERT_EQ(result->rejected.size(), 1u);
    EXPECT_EQ(result->rejected[0].name, views.back().name);
    EXPECT_NE(result->rejected[0].reason.find(bad_reason), std::string::npos) << result->rejected[0].reason;

    // The YAML reads back through core's reader to the same camera.
    testing::TempDir dir;
    ASSERT_TRUE(writeCalibrationResult(dir / "calib.yaml", *result, board, "test"));
    auto read = readCalibration(dir / "calib.yaml");
    ASSERT_TRUE(read) << read.error().message;
    EXPECT_EQ(*read, result->model);
}

// Tags whose four corners project into the image with `margin` pixels to spare.
int tagsInView(const BoardSpec& board, const Rigid3d& cam_from_board, double margin) {
    const CameraModel camera = trueCamera();
    int inside = 0;
    for (int tag = 0; tag < board.cols * board.rows; ++tag) {
        bool all = true;
        for (int k = 0; k < 4; ++k) {
            const auto pixel = camera.project(cam_from_board * board.point(4 * tag + k));
            all = all && pixel && camera.inImage(*pixel, margin);
        }
        inside += all ? 1 : 0;
    }
    return inside;
}

// The chessboard's outer squares and half a square of white around them (the quiet zone the
// detector needs), with `margin` pixels to spare.
bool chessboardSquaresInView(const BoardSpec& board, const Rigid3d& cam_from_board, double margin) {
    const CameraModel camera = trueCamera();
    const double s = board.square_m;
    const double lo = -1.5 * s;
    const double x_hi = (board.cols + 0.5) * s;
    const double y_hi = (board.rows + 0.5) * s;
    for (const Vector3d& p :
         {Vector3d(lo, lo, 0), Vector3d(x_hi, lo, 0), Vector3d(lo, y_hi, 0), Vector3d(x_hi, y_hi, 0)}) {
        const auto pixel = camera.project(cam_from_board * p);
        if (!pixel || !camera.inImage(*pixel, margin)) return false;
    }
    return true;
}

CoverageReport designedCoverage(const BoardSpec& board, const std::vector<ViewSpec>& views) {
    const CameraModel camera = trueCamera();
    std::vector<CalibrationView> projected;
    for (const ViewSpec& spec : views) {
        const Rigid3d pose = camFromBoard(spec, boardCentre(board));
        CalibrationView& view = projected.emplace_back();
        for (int id = 0; id < board.pointCount(); ++id) {
            const auto pixel = camera.project(pose * board.point(id));
            if (pixel && camera.inImage(*pixel)) view.observation.pixels.push_back(*pixel);
        }
    }
    return measureCoverage(kWidth, kHeight, projected, CalibrationOptions{});
}

}  // namespace commonlight::tracking::calibration_sim

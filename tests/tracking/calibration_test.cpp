// The calibration itself on synthetic corners (board points projected with a known camera plus
// Gaussian noise): accuracy, rejection of bad views by their residuals, the coverage warning, the
// errors for too few views and mixed image sizes, and the YAML as core's reader and
// cv::FileStorage read it.
#include <cmath>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core/persistence.hpp>

#include "core/calibration_io.h"
#include "core/pose.h"
#include "tests/test_support.h"
#include "tracking/calibration.h"

namespace commonlight::tracking {
namespace {

using Eigen::Vector2d;
using Eigen::Vector3d;

constexpr int kWidth = 640;
constexpr int kHeight = 480;

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

// cam_from_board for a board centred at pixel (u, v) (before distortion), `distance` metres away,
// tilted about the camera's x and y axes and rolled about the view axis (degrees).
Rigid3d camFromBoard(const BoardSpec& board, double u, double v, double distance, double tilt_x, double tilt_y,
                     double roll) {
    const CameraModel camera = trueCamera();
    using Eigen::AngleAxisd;
    const double deg = std::numbers::pi / 180;
    const Eigen::Matrix3d rotation =
        (AngleAxisd(roll * deg, Vector3d::UnitZ()) * AngleAxisd(tilt_y * deg, Vector3d::UnitY()) *
         AngleAxisd(tilt_x * deg, Vector3d::UnitX()))
            .toRotationMatrix() *
        Vector3d(1, -1, -1).asDiagonal();
    Vector3d centre = Vector3d::Zero();
    for (int id = 0; id < board.pointCount(); ++id) centre += board.point(id);
    centre /= board.pointCount();
    const Vector3d ray = Vector3d((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1.0).normalized();
    return {Eigen::Quaterniond(rotation), distance * ray - rotation * centre};
}

// The board's points that project into the image, with Gaussian noise of `sigma` pixels.
BoardDetection observe(const BoardSpec& board, const Rigid3d& cam_from_board, double sigma, std::mt19937& rng) {
    const CameraModel camera = trueCamera();
    std::normal_distribution<double> noise(0.0, sigma);
    BoardDetection detection;
    for (int id = 0; id < board.pointCount(); ++id) {
        const auto pixel = camera.project(cam_from_board * board.point(id));
        if (!pixel || !camera.inImage(*pixel, 2.0)) continue;
        detection.observation.point_ids.push_back(id);
        detection.observation.pixels.push_back(*pixel + Vector2d(noise(rng), noise(rng)));
    }
    detection.found = !detection.observation.pixels.empty();
    return detection;
}

const BoardSpec& grid() {
    static const BoardSpec board = *parseBoardSpec("aprilgrid:6x6:0.04:0.3");
    return board;
}

// Views spread over the image: the centre with strong tilts, the four corners and the four edges.
std::vector<Rigid3d> spreadViews() {
    const BoardSpec& b = grid();
    return {
        camFromBoard(b, 320, 240, 0.60, 0, 0, 0),      camFromBoard(b, 320, 240, 0.55, 40, 0, 5),
        camFromBoard(b, 320, 240, 0.55, 0, -40, -5),   camFromBoard(b, 150, 115, 0.65, 20, -25, 10),
        camFromBoard(b, 490, 115, 0.65, 20, 25, -10),  camFromBoard(b, 150, 365, 0.65, -20, -25, -10),
        camFromBoard(b, 490, 365, 0.65, -25, 20, 10),  camFromBoard(b, 320, 100, 0.65, 30, 0, 0),
        camFromBoard(b, 320, 380, 0.65, -30, 0, 180),  camFromBoard(b, 120, 240, 0.65, 0, -30, 90),
        camFromBoard(b, 520, 240, 0.65, 0, 30, -90),   camFromBoard(b, 320, 240, 0.60, 45, 0, 30),
        camFromBoard(b, 320, 240, 0.60, 0, 45, -30),   camFromBoard(b, 200, 200, 0.60, -30, 30, 45),
        camFromBoard(b, 440, 280, 0.60, 30, -30, -45), camFromBoard(b, 320, 240, 0.45, -20, 20, 0),
    };
}

std::string viewName(std::size_t i) { return "view" + std::to_string(i) + ".png"; }

void expectNear(const CameraModel& model, double relative, double k1) {
    const CameraModel truth = trueCamera();
    EXPECT_NEAR(model.fx, truth.fx, relative * truth.fx);
    EXPECT_NEAR(model.fy, truth.fy, relative * truth.fy);
    EXPECT_NEAR(model.cx, truth.cx, relative * truth.cx);
    EXPECT_NEAR(model.cy, truth.cy, relative * truth.cy);
    EXPECT_NEAR(model.distortion.k1, truth.distortion.k1, k1);
}

TEST(Calibration, RecoversTheCameraFromSyntheticCorners) {
    std::mt19937 rng(1);
    Calibrator calibrator(grid(), CalibrationOptions{});
    const std::vector<Rigid3d> poses = spreadViews();
    for (std::size_t i = 0; i < poses.size(); ++i) {
        ASSERT_TRUE(calibrator.add(viewName(i), kWidth, kHeight, observe(grid(), poses[i], 0.05, rng)));
    }
    auto result = calibrator.calibrate();
    ASSERT_TRUE(result) << result.error().message;
    expectNear(result->model, 0.001, 0.005);
    // OpenCV's RMS is over the corners' 2-D distances: sqrt(2) x the noise per axis.
    EXPECT_NEAR(result->rms_px, 0.05 * std::numbers::sqrt2, 0.01);
    EXPECT_EQ(result->view_names.size(), poses.size());
    EXPECT_EQ(result->per_view_rms_px.size(), poses.size());
    EXPECT_TRUE(result->rejected.empty());
    EXPECT_EQ(result->rounds, 1);
    for (int i = 0; i < 9; ++i) {
        EXPECT_GT(result->std_deviations[i], 0.0) << i;
        EXPECT_TRUE(std::isfinite(result->std_deviations[i])) << i;
    }
    EXPECT_LT(result->std_deviations[0], 0.5);  // fx, pixels
    EXPECT_TRUE(result->coverage.warning.empty()) << result->coverage.warning;
    EXPECT_GE(result->coverage.fraction, 0.9);
}

// A view whose corners are off by pixels (a moving board, a wrong detection) and one that is the
// wrong board altogether (its corners assigned to the wrong points) are rejected by their residuals,
// and the calibration without them is as good as without them at all.
TEST(Calibration, RejectsViewsWithLargeResiduals) {
    std::mt19937 rng(2);
    Calibrator calibrator(grid(), CalibrationOptions{});
    const std::vector<Rigid3d> poses = spreadViews();
    for (std::size_t i = 0; i < poses.size(); ++i) {
        BoardDetection detection = observe(grid(), poses[i], 0.05, rng);
        if (i == 4) {
            std::normal_distribution<double> blur(0.0, 3.0);
            for (Vector2d& p : detection.observation.pixels) p += Vector2d(blur(rng), blur(rng));
        }
        if (i == 9) {
            // Mirrored labelling: the points of the grid's column c are reported as column 5 - c.
            for (int& id : detection.observation.point_ids) {
                const int tag = id / 4;
                id = 4 * ((tag / 6) * 6 + 5 - tag % 6) + id % 4;
            }
        }
        ASSERT_TRUE(calibrator.add(viewName(i), kWidth, kHeight, detection));
    }
    auto result = calibrator.calibrate();
    ASSERT_TRUE(result) << result.error().message;
    ASSERT_EQ(result->rejected.size(), 2u);
    std::vector<std::string> names = {result->rejected[0].name, result->rejected[1].name};
    std::sort(names.begin(), names.end());
    EXPECT_EQ(names[0], "view4.png");
    EXPECT_EQ(names[1], "view9.png");
    for (const RejectedView& view : result->rejected) {
        EXPECT_NE(view.reason.find("reprojection error"), std::string::npos) << view.reason;
        EXPECT_NE(view.reason.find("x the median"), std::string::npos) << view.reason;
    }
    EXPECT_GE(result->rounds, 2);
    EXPECT_EQ(result->view_names.size(), poses.size() - 2);
    expectNear(result->model, 0.001, 0.005);
    EXPECT_LT(result->rms_px, 0.1);
}

// Rejection never leaves fewer views than a calibration needs.
TEST(Calibration, RejectionKeepsTheMinimumNumberOfViews) {
    std::mt19937 rng(3);
    Calibrator calibrator(grid(), CalibrationOptions{});
    const std::vector<Rigid3d> poses = spreadViews();
    for (std::size_t i = 0; i < 3; ++i) {
        BoardDetection detection = observe(grid(), poses[i + 11], 0.05, rng);
        if (i == 0) {
            for (Vector2d& p : detection.observation.pixels) p.x() += (p.y() > 240 ? 4.0 : -4.0);
        }
        ASSERT_TRUE(calibrator.add(viewName(i), kWidth, kHeight, detection));
    }
    auto result = calibrator.calibrate();
    ASSERT_TRUE(result) << result.error().message;
    EXPECT_EQ(result->view_names.size(), 3u);
    EXPECT_TRUE(result->rejected.empty());
}

// All views of a small board in the middle of the image: the calibration runs and warns that
// the corners cover the image poorly, naming the empty borders; the warning goes into the YAML.
TEST(Calibration, WarnsWhenTheViewsClusterInTheCentre) {
    std::mt19937 rng(4);
    Calibrator calibrator(grid(), CalibrationOptions{});
    const BoardSpec& b = grid();
    const std::vector<Rigid3d> poses = {
        camFromBoard(b, 320, 240, 1.6, 0, 0, 0),     camFromBoard(b, 320, 240, 1.5, 40, 0, 0),
        camFromBoard(b, 320, 240, 1.5, 0, 40, 10),   camFromBoard(b, 300, 220, 1.5, -35, 20, -10),
        camFromBoard(b, 340, 260, 1.5, 30, -30, 45), camFromBoard(b, 320, 240, 1.4, -40, -10, 90),
    };
    for (std::size_t i = 0; i < poses.size(); ++i) {
        ASSERT_TRUE(calibrator.add(viewName(i), kWidth, kHeight, observe(b, poses[i], 0.05, rng)));
    }
    auto result = calibrator.calibrate();
    ASSERT_TRUE(result) << result.error().message;
    const CoverageReport& coverage = result->coverage;
    EXPECT_LT(coverage.fraction, 0.6);
    EXPECT_EQ(coverage.cols, 8);
    EXPECT_EQ(coverage.rows, 6);
    EXPECT_EQ(coverage.empty_borders, (std::vector<std::string>{"left", "right", "top", "bottom"}));
    EXPECT_NE(coverage.warning.find("poor coverage: the corners cover only"), std::string::npos) << coverage.warning;
    EXPECT_NE(coverage.warning.find("no corner near the left, right, top and bottom edges"), std::string::npos)
        << coverage.warning;
    const std::string yaml = formatCalibrationResult(*result, b, "now");
    EXPECT_NE(yaml.find("coverage_warning: \"poor coverage"), std::string::npos) << yaml;
}

TEST(Calibration, CoverageCountsCellsAndBorders) {
    CalibrationOptions options;
    std::vector<CalibrationView> views(1);
    // One corner in every cell but the right column of the 8 x 6 grid.
    for (int r = 0; r < 6; ++r) {
        for (int c = 0; c < 7; ++c) views[0].observation.pixels.emplace_back(40.0 + 80 * c, 40.0 + 80 * r);
    }
    CoverageReport report = measureCoverage(kWidth, kHeight, views, options);
    EXPECT_EQ(report.cells_hit, 42);
    EXPECT_DOUBLE_EQ(report.fraction, 42.0 / 48.0);
    EXPECT_EQ(report.empty_borders, std::vector<std::string>{"right"});
    EXPECT_NE(report.warning.find("no corner near the right edge;"), std::string::npos) << report.warning;
    EXPECT_EQ(report.warning.find("cover only"), std::string::npos) << report.warning;
    // Corners on the image's very edge count for the edge cells.
    views[0].observation.pixels.emplace_back(kWidth - 0.5, 0.0);
    report = measureCoverage(kWidth, kHeight, views, options);
    EXPECT_EQ(report.cells_hit, 43);
    EXPECT_TRUE(report.empty_borders.empty());
    EXPECT_TRUE(report.warning.empty()) << report.warning;
}

TEST(Calibration, TooFewViewsIsAnErrorListingTheRejected) {
    std::mt19937 rng(5);
    Calibrator calibrator(grid(), CalibrationOptions{});
    const std::vector<Rigid3d> poses = spreadViews();
    ASSERT_TRUE(calibrator.add("a.png", kWidth, kHeight, observe(grid(), poses[0], 0.05, rng)));
    ASSERT_TRUE(calibrator.add("b.png", kWidth, kHeight, observe(grid(), poses[1], 0.05, rng)));
    BoardDetection missing;
    missing.reason = "only 2 tags of the aprilgrid found (at least 4 needed)";
    ASSERT_TRUE(calibrator.add("c.png", kWidth, kHeight, missing));
    calibrator.reject("d.png", "unreadable: cannot decode image");
    auto result = calibrator.calibrate();
    ASSERT_FALSE(result);
    EXPECT_EQ(result.error().code, ErrorCode::kBadInput);
    const std::string& message = result.error().message;
    EXPECT_NE(message.find("only 2 usable views of the aprilgrid:6x6:0.04:0.3 board, at least 3 needed"),
              std::string::npos)
        << message;
    EXPECT_NE(message.find("c.png (only 2 tags of the aprilgrid found"), std::string::npos) << message;
    EXPECT_NE(message.find("d.png (unreadable: cannot decode image)"), std::string::npos) << message;
}

TEST(Calibration, ImagesOfDifferentSizesAreAnError) {
    Calibrator calibrator(grid(), CalibrationOptions{});
    BoardDetection none;
    none.reason = "nothing";
    ASSERT_TRUE(calibrator.add("first.png", 640, 480, none));
    auto added = calibrator.add("second.png", 800, 600, none);
    ASSERT_FALSE(added);
    EXPECT_EQ(added.error().code, ErrorCode::kBadInput);
    EXPECT_EQ(added.error().message,
              "second.png: image is 800x600 but first.png is 640x480 (calibrate each image size separately)");
}

// Observations a detector never gives but another caller might: too few corners, a NaN, a point id
// that is not on the board. Each is a rejected view, not a failed calibration.
TEST(Calibration, UnusableObservationsAreRejected) {
    Calibrator calibrator(grid(), CalibrationOptions{});
    BoardDetection few;
    few.found = true;
    few.observation.point_ids = {0, 1, 2};
    few.observation.pixels = {{1, 1}, {2, 1}, {2, 2}};
    ASSERT_TRUE(calibrator.add("few.png", kWidth, kHeight, few));
    BoardDetection nan = few;
    nan.observation.point_ids.push_back(3);
    nan.observation.pixels.emplace_back(std::nan(""), 1.0);
    ASSERT_TRUE(calibrator.add("nan.png", kWidth, kHeight, nan));
    BoardDetection foreign = few;
    foreign.observation.point_ids.push_back(grid().pointCount());
    foreign.observation.pixels.emplace_back(1.0, 1.0);
    ASSERT_TRUE(calibrator.add("foreign.png", kWidth, kHeight, foreign));
    EXPECT_EQ(calibrator.viewCount(), 0u);
    ASSERT_EQ(calibrator.rejected().size(), 3u);
    EXPECT_EQ(calibrator.rejected()[0].reason, "only 3 corners (at least 4 needed)");
    EXPECT_EQ(calibrator.rejected()[1].reason, "corner 3 is not finite or not a point of the board");
    EXPECT_EQ(calibrator.rejected()[2].name, "foreign.png");

    // Coverage ignores what is not a pixel and clamps what is far outside the image.
    std::vector<CalibrationView> views(1);
    views[0].observation.pixels = {{std::nan(""), 0.0}, {1e300, -1e300}};
    const CoverageReport report = measureCoverage(kWidth, kHeight, views, CalibrationOptions{});
    EXPECT_EQ(report.cells_hit, 1);
}

TEST(Calibration, OptionsAreValidated) {
    CalibrationOptions options;
    EXPECT_TRUE(options.validate());
    options.reject_ratio = 1.0;
    EXPECT_FALSE(options.validate());
    options = {};
    options.min_views = 2;
    EXPECT_FALSE(options.validate());
    options = {};
    options.min_coverage = 1.5;
    EXPECT_FALSE(options.validate());
    options = {};
    options.coverage_cols = 1;
    EXPECT_FALSE(options.validate());
}

// The YAML: core's reader gives back exactly the model, cv::FileStorage reads every key, and odd
// image names survive the quoting.
TEST(Calibration, YamlReadsBackInCoreAndOpenCv) {
    std::mt19937 rng(6);
    Calibrator calibrator(grid(), CalibrationOptions{});
    const std::vector<Rigid3d> poses = spreadViews();
    const std::vector<std::string> names = {"plain.png",       "with space.png", "quote\"d.png",
                                            "back\\slash.png", "colon: yes.png", "123.png"};
    for (std::size_t i = 0; i < poses.size(); ++i) {
        const std::string name = i < names.size() ? names[i] : viewName(i);
        ASSERT_TRUE(calibrator.add(name, kWidth, kHeight, observe(grid(), poses[i], 0.05, rng)));
    }
    calibrator.reject("broken \"one\".jpg", "unreadable: truncated JPEG (no end-of-image marker)");
    auto result = calibrator.calibrate();
    ASSERT_TRUE(result) << result.error().message;

    testing::TempDir dir;
    const auto file = dir / "calib.yaml";
    ASSERT_TRUE(writeCalibrationResult(file, *result, grid(), "Sun Nov 22 2026"));
    auto model = readCalibration(file);
    ASSERT_TRUE(model) << model.error().message;
    EXPECT_EQ(*model, result->model);

    cv::FileStorage fs(file.string(), cv::FileStorage::READ);
    ASSERT_TRUE(fs.isOpened());
    EXPECT_EQ(static_cast<int>(fs["image_width"]), kWidth);
    EXPECT_EQ(static_cast<int>(fs["image_height"]), kHeight);
    cv::Mat k, d, per_view, stds;
    fs["camera_matrix"] >> k;
    fs["distortion_coefficients"] >> d;
    fs["per_view_reprojection_errors"] >> per_view;
    fs["std_deviations_intrinsics"] >> stds;
    ASSERT_EQ(k.rows, 3);
    EXPECT_DOUBLE_EQ(k.at<double>(0, 0), result->model.fx);
    EXPECT_DOUBLE_EQ(k.at<double>(1, 2), result->model.cy);
    ASSERT_EQ(d.total(), 5u);
    EXPECT_DOUBLE_EQ(d.at<double>(0), result->model.distortion.k1);
    ASSERT_EQ(per_view.total(), poses.size());
    EXPECT_DOUBLE_EQ(per_view.at<double>(3), result->per_view_rms_px[3]);
    EXPECT_EQ(stds.total(), 9u);
    EXPECT_DOUBLE_EQ(static_cast<double>(fs["avg_reprojection_error"]), result->rms_px);
    EXPECT_EQ(static_cast<std::string>(fs["board"]), "aprilgrid:6x6:0.04:0.3");
    EXPECT_EQ(static_cast<int>(fs["nr_of_frames"]), static_cast<int>(poses.size()));
    EXPECT_EQ(static_cast<std::string>(fs["calibration_time"]), "Sun Nov 22 2026");
    const cv::FileNode image_names = fs["image_names"];
    ASSERT_TRUE(image_names.isSeq());
    ASSERT_EQ(image_names.size(), poses.size());
    for (std::size_t i = 0; i < names.size(); ++i) {
        EXPECT_EQ(static_cast<std::string>(image_names[static_cast<int>(i)]), names[i]);
    }
    const cv::FileNode rejected = fs["rejected_views"];
    ASSERT_TRUE(rejected.isSeq());
    ASSERT_EQ(rejected.size(), 1u);
    EXPECT_EQ(static_cast<std::string>(rejected[0]["image"]), "broken \"one\".jpg");
    EXPECT_EQ(static_cast<std::string>(rejected[0]["reason"]), "unreadable: truncated JPEG (no end-of-image marker)");
    EXPECT_DOUBLE_EQ(static_cast<double>(fs["coverage"]), result->coverage.fraction);
    EXPECT_TRUE(fs["coverage_warning"].empty());
}

}  // namespace
}  // namespace commonlight::tracking

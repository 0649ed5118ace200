#include "core/calibration_io.h"

#include <algorithm>
#include <cctype>
#include <string>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "tests/test_support.h"

namespace commonlight {
namespace {

using testing::readText;
using testing::sourceDir;
using testing::TempDir;
using testing::writeText;

std::filesystem::path dataDir() { return sourceDir() / "tests/core/data"; }

// 1-based number of the first line of `text` containing `needle` (0 when absent).
int lineOf(const std::string& text, const std::string& needle) {
    const auto pos = text.find(needle);
    if (pos == std::string::npos) return 0;
    return 1 + static_cast<int>(std::count(text.begin(), text.begin() + static_cast<std::ptrdiff_t>(pos), '\n'));
}

// Replaces the one occurrence of `from` in `text`.
std::string replaced(std::string text, const std::string& from, const std::string& to) {
    const auto pos = text.find(from);
    EXPECT_NE(pos, std::string::npos) << from;
    if (pos != std::string::npos) text.replace(pos, from.size(), to);
    return text;
}

CameraModel sampleModel() {
    CameraModel m;
    m.width = 1280;
    m.height = 720;
    m.fx = 912.3456789012345;
    m.fy = 911.0000000000001;
    m.cx = 639.4999999999999;
    m.cy = 361.12345678901234;
    m.distortion = {-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, -0.0214390712345678};
    return m;
}

// Reads a malformed variant of `text` and checks the error: code kBadInput, the file, the line of
// `line_needle` (when given), the key and a phrase of the problem.
void expectBadInput(const std::string& text, const std::string& key, const std::string& problem,
                    const std::string& line_needle = "") {
    TempDir dir;
    const auto file = dir / "calib.yaml";
    writeText(file, text);
    const auto model = readCalibration(file);
    ASSERT_FALSE(model) << "accepted:\n" << text;
    const std::string& msg = model.error().message;
    EXPECT_EQ(model.error().code, ErrorCode::kBadInput) << msg;
    EXPECT_NE(msg.find(file.string()), std::string::npos) << msg;
    EXPECT_NE(msg.find("key '" + key + "'"), std::string::npos) << msg;
    EXPECT_NE(msg.find(problem), std::string::npos) << msg;
    if (!line_needle.empty()) {
        const int line = lineOf(text, line_needle);
        ASSERT_GT(line, 0) << line_needle;
        EXPECT_NE(msg.find(file.string() + ":" + std::to_string(line) + ":"), std::string::npos)
            << msg << " (expected line " << line << ")";
    }
}

// The distortion block of calib_opencv_sample.yaml.
const std::string kFiveCoefficients =
    "rows: 5\n   cols: 1\n   dt: d\n   data: [ -2.6637260909660682e-01, -3.8588898922304653e-02,\n"
    "       1.7831947042852964e-03, -2.8122100441115472e-04,\n"
    "       2.3839153080878486e-01 ]";

std::string openCvSample() { return readText(dataDir() / "calib_opencv_sample.yaml"); }
std::string rosSample() { return readText(dataDir() / "calib_ros_camera_info.yaml"); }

TEST(CalibrationIo, ReadsOpenCvSampleOutput) {
    const auto model = readCalibration(dataDir() / "calib_opencv_sample.yaml");
    ASSERT_TRUE(model) << model.error().message;
    EXPECT_EQ(model->width, 640);
    EXPECT_EQ(model->height, 480);
    EXPECT_EQ(model->fx, 5.3591573396163199e+02);
    EXPECT_EQ(model->fy, 5.3591573396163199e+02);
    EXPECT_EQ(model->cx, 3.4228315473308373e+02);
    EXPECT_EQ(model->cy, 2.3557082909788173e+02);
    EXPECT_EQ(model->distortion.k1, -2.6637260909660682e-01);
    EXPECT_EQ(model->distortion.k2, -3.8588898922304653e-02);
    EXPECT_EQ(model->distortion.p1, 1.7831947042852964e-03);
    EXPECT_EQ(model->distortion.p2, -2.8122100441115472e-04);
    EXPECT_EQ(model->distortion.k3, 2.3839153080878486e-01);
}

TEST(CalibrationIo, ReadsRosCameraInfo) {
    const auto model = readCalibration(dataDir() / "calib_ros_camera_info.yaml");
    ASSERT_TRUE(model) << model.error().message;
    EXPECT_EQ(model->width, 640);
    EXPECT_EQ(model->height, 480);
    EXPECT_EQ(model->fx, 423.52693);
    EXPECT_EQ(model->fy, 423.86779);
    EXPECT_EQ(model->cx, 318.41806);
    EXPECT_EQ(model->cy, 252.09473);
    EXPECT_EQ(model->distortion, (Distortion{-0.339812, 0.097628, 0.001248, -0.000478, 0.0}));
}

TEST(CalibrationIo, AcceptsFourAndEightCoefficientsAndRowVectors) {
    const std::string five = kFiveCoefficients;
    const std::string four =
        replaced(openCvSample(), five, "rows: 1\n   cols: 4\n   dt: d\n   data: [ -0.25, 0.1, 0.001, 0.002 ]");
    auto model = parseCalibration(four, "four.yaml");
    ASSERT_TRUE(model) << model.error().message;
    EXPECT_EQ(model->distortion, (Distortion{-0.25, 0.1, 0.001, 0.002, 0.0}));

    const std::string eight = replaced(
        openCvSample(), five, "rows: 8\n   cols: 1\n   dt: d\n   data: [ -0.25, 0.1, 0.001, 0.002, 0.03, 0., 0., 0. ]");
    model = parseCalibration(eight, "eight.yaml");
    ASSERT_TRUE(model) << model.error().message;
    EXPECT_EQ(model->distortion, (Distortion{-0.25, 0.1, 0.001, 0.002, 0.03}));

    const std::string rational =
        replaced(replaced(rosSample(), "distortion_model: plumb_bob", "distortion_model: rational_polynomial"),
                 "cols: 5\n  data: [-0.339812, 0.097628, 0.001248, -0.000478, 0.000000]",
                 "cols: 8\n  data: [-0.339812, 0.097628, 0.001248, -0.000478, 0.01, 0, 0, 0]");
    model = parseCalibration(rational, "rational.yaml");
    ASSERT_TRUE(model) << model.error().message;
    EXPECT_EQ(model->distortion.k3, 0.01);
}

TEST(CalibrationIo, OpenCvRoundTripIsExact) {
    TempDir dir;
    const CameraModel model = sampleModel();
    ASSERT_TRUE(writeCalibrationOpenCv(dir / "calib.yaml", model));
    const auto back = readCalibration(dir / "calib.yaml");
    ASSERT_TRUE(back) << back.error().message;
    EXPECT_EQ(*back, model);
    EXPECT_EQ(readText(dir / "calib.yaml").rfind("%YAML:1.0\n---\n", 0), 0u);
}

TEST(CalibrationIo, RosRoundTripIsExact) {
    TempDir dir;
    const CameraModel model = sampleModel();
    ASSERT_TRUE(writeCalibrationRos(dir / "camera_info.yaml", model, "front camera"));
    const std::string text = readText(dir / "camera_info.yaml");
    EXPECT_NE(text.find("camera_name: \"front camera\""), std::string::npos) << text;
    EXPECT_NE(text.find("distortion_model: plumb_bob"), std::string::npos) << text;
    EXPECT_NE(text.find("projection_matrix:"), std::string::npos) << text;
    const auto back = readCalibration(dir / "camera_info.yaml");
    ASSERT_TRUE(back) << back.error().message;
    EXPECT_EQ(*back, model);
}

TEST(CalibrationIo, OpenCvOutputReadsWithCvFileStorage) {
    TempDir dir;
    const CameraModel model = sampleModel();
    CalibrationExtras extras;
    extras.rms_reprojection_error_px = 0.2345678901234567;
    extras.per_view_errors_px = {0.1, 0.25, 0.3333333333333333};
    extras.std_deviations_intrinsics = std::array<double, 9>{0.5, 0.6, 0.7, 0.8, 1e-3, 2e-3, 3e-5, 4e-5, 5e-3};
    extras.calibration_time = "Sat 21 Nov 2026 22:49:01";
    const auto file = dir / "calib.yaml";
    ASSERT_TRUE(writeCalibrationOpenCv(file, model, &extras));

    cv::FileStorage fs(file.string(), cv::FileStorage::READ);
    ASSERT_TRUE(fs.isOpened()) << readText(file);
    EXPECT_EQ(static_cast<int>(fs["image_width"]), model.width);
    EXPECT_EQ(static_cast<int>(fs["image_height"]), model.height);
    cv::Mat k;
    cv::Mat d;
    cv::Mat per_view;
    cv::Mat std_devs;
    fs["camera_matrix"] >> k;
    fs["distortion_coefficients"] >> d;
    fs["per_view_reprojection_errors"] >> per_view;
    fs["std_deviations_intrinsics"] >> std_devs;
    ASSERT_EQ(k.rows, 3);
    ASSERT_EQ(k.cols, 3);
    ASSERT_EQ(k.type(), CV_64F);
    EXPECT_EQ(k.at<double>(0, 0), model.fx);
    EXPECT_EQ(k.at<double>(1, 1), model.fy);
    EXPECT_EQ(k.at<double>(0, 2), model.cx);
    EXPECT_EQ(k.at<double>(1, 2), model.cy);
    EXPECT_EQ(k.at<double>(0, 1), 0.0);
    EXPECT_EQ(k.at<double>(2, 2), 1.0);
    ASSERT_EQ(d.total(), 5u);
    EXPECT_EQ(d.at<double>(0), model.distortion.k1);
    EXPECT_EQ(d.at<double>(1), model.distortion.k2);
    EXPECT_EQ(d.at<double>(2), model.distortion.p1);
    EXPECT_EQ(d.at<double>(3), model.distortion.p2);
    EXPECT_EQ(d.at<double>(4), model.distortion.k3);
    EXPECT_EQ(static_cast<double>(fs["avg_reprojection_error"]), *extras.rms_reprojection_error_px);
    ASSERT_EQ(per_view.total(), 3u);
    EXPECT_EQ(per_view.at<double>(2), extras.per_view_errors_px[2]);
    ASSERT_EQ(std_devs.total(), 9u);
    EXPECT_EQ(std_devs.at<double>(8), 5e-3);
    EXPECT_EQ(static_cast<std::string>(fs["calibration_time"]), extras.calibration_time);

    // And our reader still takes the file with the extras in it.
    const auto back = readCalibration(file);
    ASSERT_TRUE(back) << back.error().message;
    EXPECT_EQ(*back, model);
}

TEST(CalibrationIo, WritersRefuseInvalidModels) {
    TempDir dir;
    CameraModel model = sampleModel();
    model.fx = -1.0;
    const auto written = writeCalibrationOpenCv(dir / "calib.yaml", model);
    ASSERT_FALSE(written);
    EXPECT_NE(written.error().message.find("calib.yaml"), std::string::npos);
    EXPECT_FALSE(std::filesystem::exists(dir / "calib.yaml"));
    EXPECT_FALSE(writeCalibrationRos(dir / "ros.yaml", model, "cam"));
}

TEST(CalibrationIo, MissingFileIsNotFound) {
    TempDir dir;
    const auto model = readCalibration(dir / "nope.yaml");
    ASSERT_FALSE(model);
    EXPECT_EQ(model.error().code, ErrorCode::kNotFound);
    EXPECT_NE(model.error().message.find("nope.yaml"), std::string::npos);
}

TEST(CalibrationIoBadInput, SyntaxErrorGivesLineAndColumn) {
    TempDir dir;
    const std::string text = replaced(openCvSample(), "image_height: 480", "image_height: [480");
    writeText(dir / "calib.yaml", text);
    const auto model = readCalibration(dir / "calib.yaml");
    ASSERT_FALSE(model);
    EXPECT_EQ(model.error().code, ErrorCode::kBadInput);
    // file:line:column
    const std::string prefix = (dir / "calib.yaml").string() + ":";
    ASSERT_EQ(model.error().message.rfind(prefix, 0), 0u) << model.error().message;
    const std::string rest = model.error().message.substr(prefix.size());
    EXPECT_TRUE(std::isdigit(static_cast<unsigned char>(rest[0]))) << model.error().message;
    EXPECT_NE(rest.find(':'), rest.find_last_of(':')) << model.error().message;
}

TEST(CalibrationIoBadInput, MissingImageWidth) {
    expectBadInput(replaced(openCvSample(), "image_width: 640\n", ""), "image_width", "missing");
}

TEST(CalibrationIoBadInput, MissingCameraMatrixInRos) {
    std::string text = rosSample();
    text = replaced(text, "camera_matrix:\n", "camera_matrx:\n");
    expectBadInput(text, "camera_matrix", "missing");
}

TEST(CalibrationIoBadInput, WrongNumberOfCameraMatrixEntries) {
    expectBadInput(
        replaced(rosSample(), "0.00000, 0.00000, 1.00000]\ndistortion_model", "0.00000, 1.00000]\ndistortion_model"),
        "camera_matrix.data", "rows x cols = 3 x 3 = 9 but data has 8 numbers", "data: [423.52693");
}

TEST(CalibrationIoBadInput, CameraMatrixMustBeThreeByThree) {
    expectBadInput(
        replaced(rosSample(), "rows: 3\n  cols: 3\n  data: [423.52693", "rows: 1\n  cols: 9\n  data: [423.52693"),
        "camera_matrix", "expected a 3 x 3 matrix, found 1 x 9", "camera_matrix:");
}

TEST(CalibrationIoBadInput, RowsTimesColsMismatchInDistortion) {
    expectBadInput(replaced(openCvSample(), "rows: 5\n   cols: 1\n   dt: d\n   data: [ -2.66",
                            "rows: 5\n   cols: 2\n   dt: d\n   data: [ -2.66"),
                   "distortion_coefficients.data", "rows x cols = 5 x 2 = 10 but data has 5 numbers", "data: [ -2.66");
}

TEST(CalibrationIoBadInput, UnsupportedCoefficientCount) {
    expectBadInput(replaced(rosSample(), "cols: 5\n  data: [-0.339812, 0.097628, 0.001248, -0.000478, 0.000000]",
                            "cols: 6\n  data: [-0.339812, 0.097628, 0.001248, -0.000478, 0.000000, 0.1]"),
                   "distortion_coefficients.data", "found 6", "data: [-0.339812");
}

TEST(CalibrationIoBadInput, NonNumericEntry) {
    expectBadInput(replaced(rosSample(), "423.86779", "fy"), "camera_matrix.data[4]", "expected a number, found 'fy'",
                   "data: [423.52693");
}

TEST(CalibrationIoBadInput, NaNEntry) {
    expectBadInput(replaced(openCvSample(), "2.3557082909788173e+02, 0., 0., 1. ]", ".nan, 0., 0., 1. ]"),
                   "camera_matrix.data[5]", "must be finite", ".nan");
}

TEST(CalibrationIoBadInput, NonzeroK4IsUnsupported) {
    expectBadInput(replaced(openCvSample(), kFiveCoefficients,
                            "rows: 8\n   cols: 1\n   dt: d\n   data: [ -0.25, 0.1, 0.001, 0.002, 0.03,\n"
                            "       0.5, 0., 0. ]"),
                   "distortion_coefficients.data[5]", "k4 = 0.5: not supported", "0.5, 0., 0. ]");
}

TEST(CalibrationIoBadInput, RosUnsupportedDistortionModel) {
    expectBadInput(replaced(rosSample(), "plumb_bob", "equidistant"), "distortion_model",
                   "'equidistant' is not supported", "distortion_model:");
}

TEST(CalibrationIoBadInput, OpenCvMatrixNeedsDt) {
    expectBadInput(replaced(openCvSample(), "   cols: 3\n   dt: d\n", "   cols: 3\n"), "camera_matrix.dt", "missing");
}

TEST(CalibrationIoBadInput, SkewIsRefused) {
    expectBadInput(replaced(openCvSample(), "[ 5.3591573396163199e+02, 0., ", "[ 5.3591573396163199e+02, 0.5, "),
                   "camera_matrix.data[1]", "skew", "data: [ 5.3591573396163199e+02, 0.5");
}

TEST(CalibrationIoBadInput, PrincipalPointOutsideImage) {
    expectBadInput(replaced(openCvSample(), "image_width: 640", "image_width: 320"), "camera_matrix",
                   "outside the 320x480 image", "camera_matrix:");
}

TEST(CalibrationIoBadInput, NonPositiveImageSize) {
    expectBadInput(replaced(rosSample(), "image_height: 480", "image_height: 0"), "image_height", "must be positive",
                   "image_height:");
}

// Issue 14: a matrix with rows, cols and dt but no data threw YAML::InvalidNode out of the reader
// (an abort in `commonlight track --calib`). Every form of it is an error naming the key.
TEST(CalibrationIoBadInput, OpenCvCameraMatrixWithoutData) {
    expectBadInput(replaced(openCvSample(), "   dt: d\n   data: [ 5.3591573396163199e+02",
                            "   dt: d\n   dat: [ 5.3591573396163199e+02"),
                   "camera_matrix.data", "missing", "camera_matrix:");
}

TEST(CalibrationIoBadInput, OpenCvDistortionWithoutData) {
    expectBadInput(replaced(openCvSample(), kFiveCoefficients, "rows: 5\n   cols: 1\n   dt: d"),
                   "distortion_coefficients.data", "missing", "distortion_coefficients:");
}

TEST(CalibrationIoBadInput, RosMatrixWithoutData) {
    expectBadInput(replaced(rosSample(), "  data: [423.52693", "  unused: [423.52693"), "camera_matrix.data",
                   "missing", "rows: 3\n  cols: 3\n  unused");
}

TEST(CalibrationIoBadInput, MatrixDataThatIsNotAList) {
    expectBadInput(replaced(openCvSample(), kFiveCoefficients, "rows: 5\n   cols: 1\n   dt: d\n   data: { a: 1 }"),
                   "distortion_coefficients.data", "expected a list of numbers", "data: { a: 1 }");
}

// Issue 14: rows x cols was multiplied as int in the error message (signed overflow, UB).
TEST(CalibrationIoBadInput, HugeRowsTimesColsIsReportedWithoutOverflow) {
    expectBadInput(replaced(rosSample(), "rows: 3\n  cols: 3\n  data: [423.52693", "rows: 1735082496\n  cols: 3\n  data: [423.52693"),
                   "camera_matrix.data", "rows x cols = 1735082496 x 3 = 5205247488 but data has 9 numbers",
                   "data: [423.52693");
    expectBadInput(replaced(rosSample(), "rows: 3\n  cols: 3\n  data: [423.52693",
                            "rows: 2147483647\n  cols: 2147483647\n  data: [423.52693"),
                   "camera_matrix.data", "= 4611686014132420609 but data has 9 numbers", "data: [423.52693");
}

}  // namespace
}  // namespace commonlight

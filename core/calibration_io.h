// Camera calibration files: OpenCV FileStorage YAML (as OpenCV's calibration sample writes it) and
// ROS camera_info YAML (camera_calibration_parsers). docs/formats-calibration.md describes both.
//
// Every error has code kBadInput (kNotFound for a missing file) and names the file, the line and
// the key: "calib.yaml:9: key 'camera_matrix.data': expected 9 numbers, found 8".
#pragma once

#include <array>
#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "core/camera_model.h"
#include "core/result.h"

namespace commonlight {

// What a calibration run knows besides the model; written next to it for the record.
struct CalibrationExtras {
    std::optional<double> rms_reprojection_error_px;  // avg_reprojection_error (OpenCV's name)
    std::vector<double> per_view_errors_px;           // per_view_reprojection_errors, one per image
    // Standard deviations of fx, fy, cx, cy (pixels), k1, k2, p1, p2, k3 (unitless): the first nine
    // entries of cv::calibrateCamera's stdDeviationsIntrinsics. Written as std_deviations_intrinsics.
    std::optional<std::array<double, 9>> std_deviations_intrinsics;
    std::string calibration_time;  // free text, written when not empty
};

// Reads either format and validates the model. A file is read as ROS camera_info when it has any of
// camera_name, distortion_model, rectification_matrix or projection_matrix, as OpenCV otherwise
// (then each matrix needs its `dt`). Distortion vectors of
// 0, 4, 5, 8, 12 or 14 coefficients are accepted (OpenCV's orders); terms beyond k3 (k4..k6, thin
// prism, tilt) must be zero. Extra keys (avg_reprojection_error, rectification_matrix, ...) are
// ignored.
Result<CameraModel> readCalibration(const std::filesystem::path& file);
// Same, from text; `name` stands for the file in messages.
Result<CameraModel> parseCalibration(const std::string& text, const std::string& name);

// Writes OpenCV FileStorage YAML that cv::FileStorage reads back (and readCalibration exactly:
// numbers are written with enough digits to round-trip). Atomic: write to a temp file + rename.
Result<void> writeCalibrationOpenCv(const std::filesystem::path& file, const CameraModel& model,
                                    const CalibrationExtras* extras = nullptr);
// Writes a ROS camera_info YAML (plumb_bob, identity rectification, projection = [K | 0]).
Result<void> writeCalibrationRos(const std::filesystem::path& file, const CameraModel& model,
                                 std::string_view camera_name);

// The text the writers write; `model` must be valid (the writers check).
std::string formatCalibrationOpenCv(const CameraModel& model, const CalibrationExtras* extras = nullptr);
std::string formatCalibrationRos(const CameraModel& model, std::string_view camera_name);

}  // namespace commonlight

// Camera calibration from views of a board: cv::calibrateCamera (pinhole + Brown-Conrady k1 k2 p1
// p2 k3), rejection of views with large residuals, a coverage check, and the OpenCV FileStorage
// YAML that core/calibration_io.h reads. docs/calibration.md describes the rules and the output.
//
// Usage: make a Calibrator, add every image's BoardDetection (or a rejection, for an image that
// could not be read) in order, then calibrate().
#pragma once

#include <array>
#include <filesystem>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "core/camera_model.h"
#include "core/result.h"
#include "tracking/calibration_board.h"

namespace commonlight::tracking {

struct CalibrationOptions {
    bool fix_k3 = false;           // hold k3 at 0 (narrow lenses, few views)
    bool zero_tangential = false;  // hold p1 = p2 = 0
    double reject_ratio = 3.0;     // a view whose RMS error exceeds reject_ratio x the median ...
    double reject_min_px = 0.5;    // ... and reject_min_px is dropped, and the calibration repeated
    int max_rejection_rounds = 5;  // calibrate-and-reject rounds at most
    int min_views = 3;             // fewer usable views is an error
    int coverage_cols = 8;         // coverage grid columns; rows follow the image's aspect ratio
    double min_coverage = 0.6;     // warn when corners fall in fewer of the grid's cells

    Result<void> validate() const;  // names the bad field (kUsage)
};

// One image in which the board was found.
struct CalibrationView {
    std::string name;  // the image's file name, for messages and the output
    BoardObservation observation;
};

struct RejectedView {
    std::string name;
    std::string reason;
};

// How well the corners of the views used spread over the image.
struct CoverageReport {
    int cols = 0, rows = 0;  // the grid
    int cells_hit = 0;       // cells holding at least one corner
    double fraction = 0.0;   // cells_hit / (cols * rows)
    // "left", "right", "top", "bottom": an outer column or row of the grid without a corner.
    std::vector<std::string> empty_borders;
    std::string warning;  // empty when the coverage is good
};

// Counts the grid cells of a width x height image that hold a corner of any view.
CoverageReport measureCoverage(int width, int height, std::span<const CalibrationView> views,
                               const CalibrationOptions& options);

struct CalibrationResult {
    CameraModel model;
    double rms_px = 0.0;                     // RMS reprojection error over every corner used
    std::vector<std::string> view_names;     // the views used, in input order
    std::vector<double> per_view_rms_px;     // parallel to view_names
    std::array<double, 9> std_deviations{};  // fx fy cx cy (pixels), k1 k2 p1 p2 k3
    std::vector<RejectedView> rejected;      // input order for detection failures, then by rejection round
    CoverageReport coverage;
    int rounds = 0;           // calibrations run
    int flags = 0;            // cv::calibrateCamera flags used
    std::size_t corners = 0;  // corners used
};

class Calibrator {
public:
    Calibrator(const BoardSpec& board, const CalibrationOptions& options);

    // Records one image: a view when the board was found, a rejection with the reason otherwise.
    // Every image must have the size of the first (else kBadInput, naming both images).
    Result<void> add(const std::string& name, int width, int height, const BoardDetection& detection);
    // Records an image that could not be used at all (unreadable, ...).
    void reject(const std::string& name, const std::string& reason);

    std::size_t viewCount() const noexcept { return views_.size(); }
    std::span<const RejectedView> rejected() const noexcept { return rejected_; }

    // Calibrates from the views: cv::calibrateCamera, then views with RMS error above
    // max(reject_ratio x median, reject_min_px) are rejected and the calibration repeated
    // (at most max_rejection_rounds times, never below min_views). Fails (kBadInput) with fewer
    // than min_views usable views, listing the rejected images, or when OpenCV fails.
    Result<CalibrationResult> calibrate() const;

private:
    BoardSpec board_;
    CalibrationOptions options_;
    int width_ = 0, height_ = 0;
    std::string first_name_;
    std::vector<CalibrationView> views_;
    std::vector<RejectedView> rejected_;
};

// The OpenCV FileStorage YAML of a calibration: what core's writeCalibrationOpenCv writes
// (image_width, image_height, camera_matrix, distortion_coefficients, avg_reprojection_error,
// per_view_reprojection_errors, std_deviations_intrinsics, calibration_time) followed by
// board, nr_of_frames, flags, image_names, rejected_views, coverage and coverage_warning.
std::string formatCalibrationResult(const CalibrationResult& result, const BoardSpec& board,
                                    std::string_view calibration_time);
// Writes it atomically.
Result<void> writeCalibrationResult(const std::filesystem::path& file, const CalibrationResult& result,
                                    const BoardSpec& board, std::string_view calibration_time);

}  // namespace commonlight::tracking

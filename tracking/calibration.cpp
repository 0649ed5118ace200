#include "tracking/calibration.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <limits>
#include <numeric>
#include <sstream>

#include <opencv2/calib3d.hpp>

#include "core/calibration_io.h"
#include "core/file_util.h"
#include "core/yaml_util.h"

namespace commonlight::tracking {
namespace {

// One run of cv::calibrateCamera.
struct Fit {
    CameraModel model;
    double rms_px = 0.0;
    std::vector<double> per_view_rms_px;  // parallel to the views passed
    std::array<double, 9> std_deviations{};
};

Result<Fit> runCalibration(const BoardSpec& board, int width, int height, const std::vector<CalibrationView>& views,
                           const std::vector<std::size_t>& active, int flags) {
    std::vector<std::vector<cv::Point3f>> object_points;
    std::vector<std::vector<cv::Point2f>> image_points;
    for (const std::size_t i : active) {
        const BoardObservation& obs = views[i].observation;
        auto& object = object_points.emplace_back();
        auto& image = image_points.emplace_back();
        for (std::size_t k = 0; k < obs.point_ids.size(); ++k) {
            const Eigen::Vector3d p = board.point(obs.point_ids[k]);
            object.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()), static_cast<float>(p.z()));
            image.emplace_back(static_cast<float>(obs.pixels[k].x()), static_cast<float>(obs.pixels[k].y()));
        }
    }
    cv::Mat camera_matrix = cv::Mat::eye(3, 3, CV_64F);
    cv::Mat dist = cv::Mat::zeros(5, 1, CV_64F);
    std::vector<cv::Mat> rvecs, tvecs;
    cv::Mat std_intrinsics, std_extrinsics, per_view;
    Fit fit;
    try {
        fit.rms_px = cv::calibrateCamera(object_points, image_points, cv::Size(width, height), camera_matrix, dist,
                                         rvecs, tvecs, std_intrinsics, std_extrinsics, per_view, flags,
                                         cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 100,
                                                          std::numeric_limits<double>::epsilon()));
    } catch (const cv::Exception& e) {
        return fail(ErrorCode::kBadInput, std::string("cv::calibrateCamera failed: ") + e.what());
    }
    CameraModel& m = fit.model;
    m.width = width;
    m.height = height;
    m.fx = camera_matrix.at<double>(0, 0);
    m.fy = camera_matrix.at<double>(1, 1);
    m.cx = camera_matrix.at<double>(0, 2);
    m.cy = camera_matrix.at<double>(1, 2);
    const auto coefficient = [&](int i) { return i < static_cast<int>(dist.total()) ? dist.at<double>(i) : 0.0; };
    m.distortion = {coefficient(0), coefficient(1), coefficient(2), coefficient(3), coefficient(4)};
    if (!std::isfinite(fit.rms_px)) {
        return fail(ErrorCode::kBadInput, "cv::calibrateCamera did not converge (the RMS error is not finite)");
    }
    if (auto valid = m.validate(); !valid) {
        return fail(ErrorCode::kBadInput, "cv::calibrateCamera gave an invalid camera (" + valid.error().message +
                                              "): the views are too few or too alike");
    }
    for (int i = 0; i < 9 && i < static_cast<int>(std_intrinsics.total()); ++i) {
        fit.std_deviations[i] = std_intrinsics.at<double>(i);
        // A fixed parameter's deviation is 0; a NaN means the parameter is not determined at all.
        if (!std::isfinite(fit.std_deviations[i])) fit.std_deviations[i] = 0.0;
    }
    fit.per_view_rms_px.assign(per_view.begin<double>(), per_view.end<double>());
    return fit;
}

double median(std::vector<double> values) {
    const std::size_t mid = values.size() / 2;
    std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(mid), values.end());
    const double upper = values[mid];
    if (values.size() % 2 == 1) return upper;
    return 0.5 * (upper + *std::max_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(mid)));
}

std::string formatPx(double value) {
    std::ostringstream out;
    out.precision(value < 10 ? 2 : 3);
    out << (value < 10 ? std::fixed : std::defaultfloat) << value << " px";
    return out.str();
}

// A double-quoted YAML scalar that both yaml-cpp and cv::FileStorage read back.
std::string quote(std::string_view text) {
    std::string out = "\"";
    for (const char c : text) {
        if (c == '"' || c == '\\') {
            out += '\\';
            out += c;
        } else if (static_cast<unsigned char>(c) < 0x20) {
            out += '?';  // control characters have no portable escape in both readers
        } else {
            out += c;
        }
    }
    return out + "\"";
}

std::string joinWords(const std::vector<std::string>& words) {
    std::string out;
    for (std::size_t i = 0; i < words.size(); ++i) {
        if (i > 0) out += i + 1 == words.size() ? " and " : ", ";
        out += words[i];
    }
    return out;
}

}  // namespace

Result<void> CalibrationOptions::validate() const {
    if (!(reject_ratio > 1.0) || !std::isfinite(reject_ratio)) {
        return fail(ErrorCode::kUsage, "reject_ratio must be a number > 1, got " + std::to_string(reject_ratio));
    }
    if (!(reject_min_px >= 0.0) || !std::isfinite(reject_min_px)) {
        return fail(ErrorCode::kUsage, "reject_min_px must be a number >= 0, got " + std::to_string(reject_min_px));
    }
    if (max_rejection_rounds < 1) {
        return fail(ErrorCode::kUsage, "max_rejection_rounds must be at least 1");
    }
    if (min_views < 3) return fail(ErrorCode::kUsage, "min_views must be at least 3 (cv::calibrateCamera)");
    if (coverage_cols < 2 || coverage_cols > 100) return fail(ErrorCode::kUsage, "coverage_cols must be in 2..100");
    if (!(min_coverage >= 0.0 && min_coverage <= 1.0)) return fail(ErrorCode::kUsage, "min_coverage must be in [0, 1]");
    return {};
}

CoverageReport measureCoverage(int width, int height, std::span<const CalibrationView> views,
                               const CalibrationOptions& options) {
    CoverageReport report;
    report.cols = options.coverage_cols;
    report.rows =
        std::max(2, static_cast<int>(std::lround(options.coverage_cols * static_cast<double>(height) / width)));
    std::vector<char> hit(static_cast<std::size_t>(report.cols * report.rows), 0);
    for (const CalibrationView& view : views) {
        for (const Eigen::Vector2d& p : view.observation.pixels) {
            // Pixel centres run from 0 to width - 1; the image's edges are at -0.5 and width - 0.5.
            // Clamped before the conversion: a corner far outside the image must not overflow an int.
            if (!p.allFinite()) continue;
            const int c =
                static_cast<int>(std::clamp(std::floor((p.x() + 0.5) / width * report.cols), 0.0, report.cols - 1.0));
            const int r =
                static_cast<int>(std::clamp(std::floor((p.y() + 0.5) / height * report.rows), 0.0, report.rows - 1.0));
            hit[static_cast<std::size_t>(r * report.cols + c)] = 1;
        }
    }
    report.cells_hit = static_cast<int>(std::count(hit.begin(), hit.end(), 1));
    report.fraction = static_cast<double>(report.cells_hit) / static_cast<double>(hit.size());
    const auto any = [&](int c0, int c1, int r0, int r1) {
        for (int r = r0; r <= r1; ++r) {
            for (int c = c0; c <= c1; ++c) {
                if (hit[static_cast<std::size_t>(r * report.cols + c)]) return true;
            }
        }
        return false;
    };
    const int last_col = report.cols - 1;
    const int last_row = report.rows - 1;
    if (!any(0, 0, 0, last_row)) report.empty_borders.push_back("left");
    if (!any(last_col, last_col, 0, last_row)) report.empty_borders.push_back("right");
    if (!any(0, last_col, 0, 0)) report.empty_borders.push_back("top");
    if (!any(0, last_col, last_row, last_row)) report.empty_borders.push_back("bottom");

    std::vector<std::string> problems;
    if (report.fraction < options.min_coverage) {
        std::ostringstream text;
        text << "the corners cover only " << std::lround(100.0 * report.fraction) << "% of the image ("
             << report.cells_hit << " of " << report.cols * report.rows << " cells of a " << report.cols << "x"
             << report.rows << " grid; " << std::lround(100.0 * options.min_coverage) << "% wanted)";
        problems.push_back(text.str());
    }
    if (!report.empty_borders.empty()) {
        problems.push_back("no corner near the " + joinWords(report.empty_borders) + " edge" +
                           (report.empty_borders.size() > 1 ? "s" : ""));
    }
    if (!problems.empty()) {
        report.warning = "poor coverage: " + joinWords(problems) +
                         "; the distortion is poorly known there: add views with the board near the image's edges "
                         "and corners";
    }
    return report;
}

Calibrator::Calibrator(const BoardSpec& board, const CalibrationOptions& options) : board_(board), options_(options) {}

Result<void> Calibrator::add(const std::string& name, int width, int height, const BoardDetection& detection) {
    if (width <= 0 || height <= 0) {
        return fail(ErrorCode::kBadInput, name + ": empty image");
    }
    if (width_ == 0) {
        width_ = width;
        height_ = height;
        first_name_ = name;
    } else if (width != width_ || height != height_) {
        return fail(ErrorCode::kBadInput, name + ": image is " + std::to_string(width) + "x" + std::to_string(height) +
                                              " but " + first_name_ + " is " + std::to_string(width_) + "x" +
                                              std::to_string(height_) + " (calibrate each image size separately)");
    }
    if (!detection.found) {
        reject(name, detection.reason);
        return {};
    }
    const BoardObservation& obs = detection.observation;
    assert(obs.point_ids.size() == obs.pixels.size());
    // A view's pose needs at least 4 points (cv::calibrateCamera's homography); the detectors
    // never report fewer, nor a non-finite corner, but other callers may.
    if (obs.pixels.size() < 4) {
        reject(name, "only " + std::to_string(obs.pixels.size()) + " corners (at least 4 needed)");
        return {};
    }
    for (std::size_t k = 0; k < obs.pixels.size(); ++k) {
        if (!obs.pixels[k].allFinite() || obs.point_ids[k] < 0 || obs.point_ids[k] >= board_.pointCount()) {
            reject(name, "corner " + std::to_string(k) + " is not finite or not a point of the board");
            return {};
        }
    }
    views_.push_back({name, obs});
    return {};
}

void Calibrator::reject(const std::string& name, const std::string& reason) { rejected_.push_back({name, reason}); }

Result<CalibrationResult> Calibrator::calibrate() const {
    CL_TRY_VOID(options_.validate());
    CalibrationResult result;
    result.rejected = rejected_;
    if (views_.size() < static_cast<std::size_t>(options_.min_views)) {
        std::ostringstream msg;
        msg << "only " << views_.size() << " usable view" << (views_.size() == 1 ? "" : "s") << " of the "
            << board_.toString() << " board, at least " << options_.min_views << " needed";
        if (!rejected_.empty()) {
            msg << "; rejected:";
            constexpr std::size_t kListed = 8;
            for (std::size_t i = 0; i < rejected_.size() && i < kListed; ++i) {
                msg << (i == 0 ? " " : "; ") << rejected_[i].name << " (" << rejected_[i].reason << ")";
            }
            if (rejected_.size() > kListed) msg << "; and " << rejected_.size() - kListed << " more";
        }
        return fail(ErrorCode::kBadInput, msg.str());
    }

    result.flags =
        (options_.fix_k3 ? cv::CALIB_FIX_K3 : 0) | (options_.zero_tangential ? cv::CALIB_ZERO_TANGENT_DIST : 0);
    std::vector<std::size_t> active(views_.size());
    std::iota(active.begin(), active.end(), std::size_t{0});
    Fit fit;
    while (true) {
        // Step 1: calibrate from the active views.
        CL_TRY(fit, runCalibration(board_, width_, height_, views_, active, result.flags));
        ++result.rounds;
        // Step 2: views far worse than the typical one (a wrong detection, a moving board, a blurred
        // image) bias the intrinsics: reject them and calibrate again. The median ignores them; the
        // floor keeps a clean data set (all views at 0.05 px) from losing views to noise.
        const double typical = median(fit.per_view_rms_px);
        const double threshold = std::max(options_.reject_ratio * typical, options_.reject_min_px);
        std::vector<std::size_t> keep;
        std::vector<RejectedView> dropped;
        for (std::size_t k = 0; k < active.size(); ++k) {
            if (fit.per_view_rms_px[k] > threshold) {
                std::ostringstream reason;
                reason << "reprojection error " << formatPx(fit.per_view_rms_px[k]) << " > " << formatPx(threshold)
                       << " (" << options_.reject_ratio << " x the median " << formatPx(typical) << ")";
                dropped.push_back({views_[active[k]].name, reason.str()});
            } else {
                keep.push_back(active[k]);
            }
        }
        if (dropped.empty() || keep.size() < static_cast<std::size_t>(options_.min_views) ||
            result.rounds > options_.max_rejection_rounds) {
            break;
        }
        result.rejected.insert(result.rejected.end(), dropped.begin(), dropped.end());
        active = std::move(keep);
    }

    // Step 3: the result, and how well the views used cover the image.
    result.model = fit.model;
    result.rms_px = fit.rms_px;
    result.std_deviations = fit.std_deviations;
    result.per_view_rms_px = fit.per_view_rms_px;
    std::vector<CalibrationView> used;
    for (const std::size_t i : active) {
        result.view_names.push_back(views_[i].name);
        result.corners += views_[i].observation.pixels.size();
        used.push_back(views_[i]);
    }
    result.coverage = measureCoverage(width_, height_, used, options_);
    return result;
}

std::string formatCalibrationResult(const CalibrationResult& result, const BoardSpec& board,
                                    std::string_view calibration_time) {
    CalibrationExtras extras;
    extras.rms_reprojection_error_px = result.rms_px;
    extras.per_view_errors_px = result.per_view_rms_px;
    extras.std_deviations_intrinsics = result.std_deviations;
    extras.calibration_time = std::string(calibration_time);
    std::ostringstream out;
    out << formatCalibrationOpenCv(result.model, &extras);
    out << "board: " << quote(board.toString()) << "\n";
    out << "nr_of_frames: " << result.view_names.size() << "\n";
    out << "flags: " << result.flags << "\n";
    out << "image_names:" << (result.view_names.empty() ? " []" : "") << "\n";
    for (const std::string& name : result.view_names) out << "   - " << quote(name) << "\n";
    out << "rejected_views:" << (result.rejected.empty() ? " []" : "") << "\n";
    for (const RejectedView& view : result.rejected) {
        out << "   - { image: " << quote(view.name) << ", reason: " << quote(view.reason) << " }\n";
    }
    out << "coverage: " << yaml::formatDouble(result.coverage.fraction) << "\n";
    out << "coverage_grid: [ " << result.coverage.cols << ", " << result.coverage.rows << " ]\n";
    if (!result.coverage.warning.empty()) out << "coverage_warning: " << quote(result.coverage.warning) << "\n";
    return out.str();
}

Result<void> writeCalibrationResult(const std::filesystem::path& file, const CalibrationResult& result,
                                    const BoardSpec& board, std::string_view calibration_time) {
    if (auto valid = result.model.validate(); !valid) {
        return fail(ErrorCode::kBadInput,
                    file.string() + ": refusing to write an invalid camera model: " + valid.error().message);
    }
    return writeTextFileAtomic(file, formatCalibrationResult(result, board, calibration_time));
}

}  // namespace commonlight::tracking

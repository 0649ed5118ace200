#include "tracking/calibration_board.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <limits>
#include <map>
#include <sstream>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "core/yaml_util.h"

namespace commonlight::tracking {
namespace {

constexpr const char* kChessboardUsage = "chessboard:COLSxROWS:SQUARE_M";
constexpr const char* kAprilGridUsage = "aprilgrid:COLSxROWS:TAG_M:SPACING_RATIO";
constexpr int kMaxChessboardCorners = 200;  // per side; far beyond any printable board
constexpr int kTag36h11Count = 587;         // ids of the tag36h11 family
constexpr double kMaxLengthM = 10.0;        // a "length" above this was given in mm, not metres
constexpr double kMaxSpacingRatio = 10.0;

std::vector<std::string_view> split(std::string_view text, char separator) {
    std::vector<std::string_view> parts;
    std::size_t start = 0;
    while (true) {
        const std::size_t end = text.find(separator, start);
        parts.push_back(text.substr(start, end == std::string_view::npos ? std::string_view::npos : end - start));
        if (end == std::string_view::npos) break;
        start = end + 1;
    }
    return parts;
}

template <typename T>
bool parseNumber(std::string_view text, T& out) {
    if (text.empty()) return false;
    const char* end = text.data() + text.size();
    const auto [ptr, ec] = std::from_chars(text.data(), end, out);
    return ec == std::errc() && ptr == end;
}

Error specError(std::string_view spec, const std::string& problem) {
    return Error{ErrorCode::kUsage, "board spec '" + std::string(spec) + "': " + problem};
}

Result<void> parseSize(std::string_view spec, std::string_view field, BoardSpec& board) {
    const auto x = field.find_first_of("xX");
    int cols = 0;
    int rows = 0;
    if (x == std::string_view::npos || !parseNumber(field.substr(0, x), cols) ||
        !parseNumber(field.substr(x + 1), rows)) {
        return fail(specError(spec, "COLSxROWS '" + std::string(field) + "' is not two whole numbers like 9x6"));
    }
    board.cols = cols;
    board.rows = rows;
    return {};
}

Result<double> parseLength(std::string_view spec, std::string_view name, std::string_view field,
                           std::string_view meaning) {
    double value = 0.0;
    if (!parseNumber(field, value) || !std::isfinite(value)) {
        return fail(specError(
            spec, std::string(name) + " '" + std::string(field) + "' is not a number (" + std::string(meaning) + ")"));
    }
    return value;
}

std::string formatLength(double value) { return yaml::formatNumber(value); }

}  // namespace

std::string BoardSpec::toString() const {
    const std::string size = std::to_string(cols) + "x" + std::to_string(rows);
    if (type == BoardType::kChessboard) return "chessboard:" + size + ":" + formatLength(square_m);
    return "aprilgrid:" + size + ":" + formatLength(tag_m) + ":" + formatLength(spacing_ratio);
}

int BoardSpec::pointCount() const { return type == BoardType::kChessboard ? cols * rows : 4 * cols * rows; }

Eigen::Vector3d BoardSpec::point(int id) const {
    if (type == BoardType::kChessboard) {
        return {(id % cols) * square_m, (id / cols) * square_m, 0.0};
    }
    // Kalibr's AprilGrid: tag `tag` at column tag % cols, row tag / cols, rows going up (+y).
    constexpr double kCornerX[4] = {0.0, 1.0, 1.0, 0.0};
    constexpr double kCornerY[4] = {0.0, 0.0, 1.0, 1.0};
    const int tag = id / 4;
    const int corner = id % 4;
    const double pitch = (1.0 + spacing_ratio) * tag_m;
    return {(tag % cols) * pitch + kCornerX[corner] * tag_m, (tag / cols) * pitch + kCornerY[corner] * tag_m, 0.0};
}

Result<void> BoardSpec::validate() const {
    const std::string spec = toString();
    if (type == BoardType::kChessboard) {
        // cv::findChessboardCorners needs more than 2 inner corners along each side.
        if (cols < 3 || cols > kMaxChessboardCorners) {
            return fail(specError(spec, "COLS " + std::to_string(cols) + " must be in 3.." +
                                            std::to_string(kMaxChessboardCorners) + " (inner corners along a row)"));
        }
        if (rows < 3 || rows > kMaxChessboardCorners) {
            return fail(specError(spec, "ROWS " + std::to_string(rows) + " must be in 3.." +
                                            std::to_string(kMaxChessboardCorners) + " (inner corners along a column)"));
        }
        if (!(square_m > 0.0 && square_m <= kMaxLengthM)) {
            return fail(specError(spec, "SQUARE_M " + formatLength(square_m) +
                                            " must be in (0, 10]: the square's edge in metres (e.g. 0.025)"));
        }
        return {};
    }
    if (cols < 1 || rows < 1) {
        return fail(specError(spec, std::string(cols < 1 ? "COLS" : "ROWS") + " must be at least 1 (tags)"));
    }
    if (static_cast<long>(cols) * rows > kTag36h11Count) {
        return fail(specError(spec, "COLS x ROWS = " + std::to_string(static_cast<long>(cols) * rows) +
                                        " tags, more than tag36h11's " + std::to_string(kTag36h11Count) + " ids"));
    }
    if (!(tag_m > 0.0 && tag_m <= kMaxLengthM)) {
        return fail(
            specError(spec, "TAG_M " + formatLength(tag_m) +
                                " must be in (0, 10]: the edge of a tag's black square in metres (e.g. 0.088)"));
    }
    if (!(spacing_ratio > 0.0 && spacing_ratio <= kMaxSpacingRatio)) {
        return fail(specError(spec, "SPACING_RATIO " + formatLength(spacing_ratio) +
                                        " must be in (0, 10]: the gap between tags divided by TAG_M (e.g. 0.3)"));
    }
    return {};
}

Result<BoardSpec> parseBoardSpec(std::string_view text) {
    const std::vector<std::string_view> fields = split(text, ':');
    BoardSpec board;
    if (fields[0] == "chessboard") {
        board.type = BoardType::kChessboard;
        if (fields.size() != 3) {
            return fail(specError(text, "expected " + std::string(kChessboardUsage) + " (3 fields), found " +
                                            std::to_string(fields.size()) + " fields"));
        }
        CL_TRY_VOID(parseSize(text, fields[1], board));
        CL_TRY(board.square_m, parseLength(text, "SQUARE_M", fields[2], "the square's edge in metres, e.g. 0.025"));
    } else if (fields[0] == "aprilgrid") {
        board.type = BoardType::kAprilGrid;
        if (fields.size() != 4) {
            return fail(specError(text, "expected " + std::string(kAprilGridUsage) + " (4 fields), found " +
                                            std::to_string(fields.size()) + " fields"));
        }
        CL_TRY_VOID(parseSize(text, fields[1], board));
        CL_TRY(board.tag_m, parseLength(text, "TAG_M", fields[2], "the edge of a tag's black square in metres"));
        CL_TRY(board.spacing_ratio,
               parseLength(text, "SPACING_RATIO", fields[3], "the gap between tags divided by TAG_M, e.g. 0.3"));
    } else {
        return fail(specError(text, "unknown board type '" + std::string(fields[0]) + "' (expected " +
                                        kChessboardUsage + " or " + kAprilGridUsage + ")"));
    }
    if (auto valid = board.validate(); !valid) {
        // Name the spec as the user wrote it, not as it prints back.
        Error error = std::move(valid).error();
        const std::string canonical = "board spec '" + board.toString() + "': ";
        if (error.message.starts_with(canonical)) error.message.erase(0, canonical.size());
        return fail(specError(text, error.message));
    }
    return board;
}

Result<void> BoardDetectorOptions::validate() const {
    if (min_tags < 1) return fail(ErrorCode::kUsage, "min_tags must be at least 1, got " + std::to_string(min_tags));
    if (tag_threads < 1 || tag_threads > 64) {
        return fail(ErrorCode::kUsage, "tag_threads must be in 1..64, got " + std::to_string(tag_threads));
    }
    if (!(border_margin_px >= 0.0) || !std::isfinite(border_margin_px)) {
        return fail(ErrorCode::kUsage, "border_margin_px must be a number >= 0");
    }
    return {};
}

BoardDetector::BoardDetector(BoardSpec board, BoardDetectorOptions options, std::optional<TagDetector> tags)
    : board_(board), options_(options), tags_(std::move(tags)) {}

Result<BoardDetector> BoardDetector::create(const BoardSpec& board, const BoardDetectorOptions& options) {
    CL_TRY_VOID(board.validate());
    CL_TRY_VOID(options.validate());
    if (board.type == BoardType::kChessboard) return BoardDetector(board, options, std::nullopt);
    if (board.cols * board.rows < options.min_tags) {
        return fail(ErrorCode::kUsage, "board spec '" + board.toString() +
                                           "': " + std::to_string(board.cols * board.rows) + " tags, fewer than the " +
                                           std::to_string(options.min_tags) + " a view needs");
    }
    TagDetectorOptions tag_options;
    tag_options.family = "tag36h11";
    tag_options.decimate = 1.0;  // full resolution: calibration wants every tag and the best corners
    tag_options.sigma = 0.0;
    tag_options.refine_edges = true;
    tag_options.threads = options.tag_threads;
    CL_TRY(TagDetector tags, TagDetector::create(tag_options));
    return BoardDetector(board, options, std::move(tags));
}

Result<BoardDetection> BoardDetector::detect(const ImageView& gray8) {
    if (gray8.format != PixelFormat::kGray8 || gray8.empty() || gray8.width <= 0 || gray8.height <= 0) {
        return fail(ErrorCode::kBadInput, "board detection needs a non-empty 8-bit grey image, got " +
                                              std::string(pixelFormatName(gray8.format)));
    }
    if (board_.type == BoardType::kChessboard) return detectChessboard(gray8);
    return detectAprilGrid(gray8);
}

Result<BoardDetection> BoardDetector::detectChessboard(const ImageView& gray8) const {
    // OpenCV only reads the pixels; the Mat header borrows them.
    const cv::Mat image(gray8.height, gray8.width, CV_8UC1, const_cast<std::uint8_t*>(gray8.data), gray8.stride);
    const cv::Size pattern(board_.cols, board_.rows);
    std::vector<cv::Point2f> corners;
    BoardDetection detection;
    try {
        // Step 1: the grid of inner corners, whole-board only, in OpenCV's row-by-row order. The
        // sector-based detector copes with strong perspective (a board tilted 35 degrees near the
        // image's corner, where the classic one gives up after a second or more); the classic
        // detector is the fallback for what it misses.
        bool found = cv::findChessboardCornersSB(image, pattern, corners, 0);
        if (!found) {
            found = cv::findChessboardCorners(
                image, pattern, corners,
                cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE | cv::CALIB_CB_FAST_CHECK);
        }
        if (!found || corners.size() != static_cast<std::size_t>(board_.pointCount())) {
            detection.reason = "chessboard with " + std::to_string(board_.cols) + "x" + std::to_string(board_.rows) +
                               " inner corners not found (the whole board must be in view)";
            return detection;
        }
        // Step 2: sub-pixel corners by cv::cornerSubPix (more accurate on our test images than
        // findChessboardCornersSB's own CALIB_CB_ACCURACY). The window must not reach the
        // neighbouring corners, whose edges run the other way: its half size is 40% of the
        // smallest corner spacing, 2..15 px. On a razor-sharp image (a box-filtered render, a
        // sharp lens on a sensor without an anti-aliasing filter) cornerSubPix is drawn towards pixel
        // boundaries by up to 0.08 px; a Gaussian blur of 1 px first cuts that to 0.03 px. The blur
        // is point-symmetric, so it does not move the saddle point of a corner.
        double min_spacing = std::numeric_limits<double>::infinity();
        for (int r = 0; r < board_.rows; ++r) {
            for (int c = 0; c < board_.cols; ++c) {
                const cv::Point2f& p = corners[r * board_.cols + c];
                if (c + 1 < board_.cols)
                    min_spacing = std::min(min_spacing, cv::norm(corners[r * board_.cols + c + 1] - p));
                if (r + 1 < board_.rows)
                    min_spacing = std::min(min_spacing, cv::norm(corners[(r + 1) * board_.cols + c] - p));
            }
        }
        const int half = std::clamp(static_cast<int>(0.4 * min_spacing), 2, 15);
        cv::Mat smooth;
        cv::GaussianBlur(image, smooth, cv::Size(0, 0), 1.0);
        cv::cornerSubPix(smooth, corners, cv::Size(half, half), cv::Size(-1, -1),
                         cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 50, 1e-4));
    } catch (const cv::Exception& e) {
        return fail(ErrorCode::kInternal, std::string("chessboard detection failed: ") + e.what());
    }
    detection.found = true;
    BoardObservation& obs = detection.observation;
    obs.point_ids.reserve(corners.size());
    obs.pixels.reserve(corners.size());
    for (std::size_t i = 0; i < corners.size(); ++i) {
        obs.point_ids.push_back(static_cast<int>(i));
        obs.pixels.emplace_back(corners[i].x, corners[i].y);
    }
    return detection;
}

Result<BoardDetection> BoardDetector::detectAprilGrid(const ImageView& gray8) {
    CL_TRY(const std::vector<TagDetection> tags, tags_->detect(gray8));
    const int board_tags = board_.cols * board_.rows;
    // An id seen twice is a stray tag beside the board (or a misdecoding): neither copy is trusted.
    std::map<int, int> seen;
    for (const TagDetection& tag : tags) {
        if (tag.id >= 0 && tag.id < board_tags) ++seen[tag.id];
    }
    const double margin = options_.border_margin_px;
    const auto nearBorder = [&](const Eigen::Vector2d& p) {
        return p.x() < margin - 0.5 || p.y() < margin - 0.5 || p.x() > gray8.width - 0.5 - margin ||
               p.y() > gray8.height - 0.5 - margin;
    };
    std::vector<const TagDetection*> used;
    int cut = 0;
    for (const TagDetection& tag : tags) {
        const auto it = seen.find(tag.id);
        if (it == seen.end() || it->second != 1) continue;
        if (std::any_of(tag.corners.begin(), tag.corners.end(), nearBorder)) {
            ++cut;
            continue;
        }
        used.push_back(&tag);
    }
    std::sort(used.begin(), used.end(), [](const TagDetection* a, const TagDetection* b) { return a->id < b->id; });

    BoardDetection detection;
    if (static_cast<int>(used.size()) < options_.min_tags) {
        std::ostringstream reason;
        reason << "only " << used.size() << " tag" << (used.size() == 1 ? "" : "s")
               << " of the aprilgrid found (at least " << options_.min_tags << " needed)";
        if (cut > 0) reason << "; " << cut << " more at the image's edge";
        const std::size_t other = tags.size() - used.size() - static_cast<std::size_t>(cut);
        if (other > 0)
            reason << "; " << other << " tag" << (other == 1 ? "" : "s") << " not of the board or seen twice";
        detection.reason = reason.str();
        return detection;
    }
    detection.found = true;
    BoardObservation& obs = detection.observation;
    obs.tags = static_cast<int>(used.size());
    for (const TagDetection* tag : used) {
        for (int k = 0; k < 4; ++k) {
            obs.point_ids.push_back(4 * tag->id + k);
            obs.pixels.push_back(tag->corners[k]);
        }
    }
    return detection;
}

}  // namespace commonlight::tracking

// Calibration boards: the spec given on the command line, the board's points in its own frame, and
// finding those points in an 8-bit grey image. docs/calibration.md describes the conventions.
//
//   chessboard:COLSxROWS:SQUARE_M              COLS x ROWS inner corners (OpenCV's patternSize),
//                                              squares of SQUARE_M metres
//   aprilgrid:COLSxROWS:TAG_M:SPACING_RATIO    Kalibr's AprilGrid: COLS x ROWS tag36h11 tags whose
//                                              black squares have edge TAG_M metres, SPACING_RATIO * TAG_M
//                                              apart; tag id = row * COLS + col
//
// Board frames (metres, z = 0 on the board):
// - chessboard: OpenCV's. Point id = r * COLS + c lies at (c * SQUARE_M, r * SQUARE_M, 0), in the
//   order cv::findChessboardCorners reports the corners (row by row).
// - aprilgrid: Kalibr's. The origin is the bottom-left corner of tag 0's black square, x runs along a
//   row of tags (increasing column), y up the rows, z out of the printed side. Point id = 4 * tag + k,
//   k in libapriltag's corner order (bottom-left, bottom-right, top-right, top-left of the upright
//   tag), at (col * (1 + SPACING_RATIO) * TAG_M + {0, 1, 1, 0}[k] * TAG_M,
//             row * (1 + SPACING_RATIO) * TAG_M + {0, 0, 1, 1}[k] * TAG_M, 0).
#pragma once

#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Core>

#include "core/image.h"
#include "core/result.h"
#include "tracking/tag_detector.h"

namespace commonlight::tracking {

enum class BoardType { kChessboard, kAprilGrid };

struct BoardSpec {
    BoardType type = BoardType::kChessboard;
    int cols = 0;                // chessboard: inner corners along a row; aprilgrid: tags along a row
    int rows = 0;                // chessboard: inner corners along a column; aprilgrid: rows of tags
    double square_m = 0.0;       // chessboard: edge of one square, metres
    double tag_m = 0.0;          // aprilgrid: edge of a tag's black square, metres (apriltag's size)
    double spacing_ratio = 0.0;  // aprilgrid: gap between neighbouring black squares / tag_m

    // The spec string this board parses from ("chessboard:9x6:0.025").
    std::string toString() const;
    // Number of board points (chessboard: COLS * ROWS; aprilgrid: 4 per tag).
    int pointCount() const;
    // Board point `id` (0 <= id < pointCount()) in the board frame, metres.
    Eigen::Vector3d point(int id) const;
    // Sizes and lengths in range; messages name the field (COLS, ROWS, SQUARE_M, TAG_M, SPACING_RATIO).
    Result<void> validate() const;
};

// Parses a board spec. Errors have code kUsage and name the spec and the bad field.
Result<BoardSpec> parseBoardSpec(std::string_view text);

// Board points seen in one image.
struct BoardObservation {
    std::vector<int> point_ids;           // BoardSpec::point() ids, each at most once
    std::vector<Eigen::Vector2d> pixels;  // distorted pixels, OpenCV convention (top-left pixel centre at 0, 0)
    int tags = 0;                         // aprilgrid: the tags that gave the points
};

// The outcome of looking for the board in an image. Not finding it is an outcome, not an error.
struct BoardDetection {
    bool found = false;
    std::string reason;  // why the board was not found (empty when found)
    BoardObservation observation;
};

struct BoardDetectorOptions {
    int min_tags = 4;     // aprilgrid: fewer board tags in an image is "not found"
    int tag_threads = 1;  // aprilgrid: libapriltag's worker threads
    // aprilgrid: tags with a corner closer than this to the image's edge are dropped (libapriltag
    // extrapolates a cut-off tag's corners; they are off by pixels), pixels.
    double border_margin_px = 4.0;
    Result<void> validate() const;
};

class BoardDetector {
public:
    // Fails (kUsage) for an invalid board or option.
    static Result<BoardDetector> create(const BoardSpec& board, const BoardDetectorOptions& options = {});

    // Finds the board in an 8-bit grey image (kGray8; other formats fail with kBadInput):
    // - chessboard: cv::findChessboardCornersSB (cv::findChessboardCorners when it fails), then
    //   cv::cornerSubPix with a window that scales with the corner spacing; the whole board must
    //   be in view.
    // - aprilgrid: libapriltag at decimate 1 with edge refinement; tags whose id is not on the board
    //   are ignored, an id seen twice is dropped (a stray tag), so is a tag with a corner within
    //   border_margin_px of the image's edge; fewer than min_tags is "not found".
    Result<BoardDetection> detect(const ImageView& gray8);

    const BoardSpec& board() const noexcept { return board_; }

private:
    BoardDetector(BoardSpec board, BoardDetectorOptions options, std::optional<TagDetector> tags);
    Result<BoardDetection> detectChessboard(const ImageView& gray8) const;
    Result<BoardDetection> detectAprilGrid(const ImageView& gray8);

    BoardSpec board_;
    BoardDetectorOptions options_;
    std::optional<TagDetector> tags_;  // aprilgrid only
};

}  // namespace commonlight::tracking

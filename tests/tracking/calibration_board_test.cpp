// Board specs (good and bad), board points in Kalibr's and OpenCV's conventions, and chessboard
// detection on a drawn image with known corners.
#include <cmath>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "tracking/calibration_board.h"

namespace commonlight::tracking {
namespace {

using Eigen::Vector2d;
using Eigen::Vector3d;

TEST(BoardSpec, ParsesAChessboard) {
    auto board = parseBoardSpec("chessboard:9x6:0.025");
    ASSERT_TRUE(board) << board.error().message;
    EXPECT_EQ(board->type, BoardType::kChessboard);
    EXPECT_EQ(board->cols, 9);
    EXPECT_EQ(board->rows, 6);
    EXPECT_DOUBLE_EQ(board->square_m, 0.025);
    EXPECT_EQ(board->pointCount(), 54);
    EXPECT_EQ(board->toString(), "chessboard:9x6:0.025");
    auto upper = parseBoardSpec("chessboard:7X5:1e-2");
    ASSERT_TRUE(upper) << upper.error().message;
    EXPECT_EQ(upper->cols, 7);
    EXPECT_DOUBLE_EQ(upper->square_m, 0.01);
}

TEST(BoardSpec, ParsesAnAprilGrid) {
    auto board = parseBoardSpec("aprilgrid:6x5:0.088:0.3");
    ASSERT_TRUE(board) << board.error().message;
    EXPECT_EQ(board->type, BoardType::kAprilGrid);
    EXPECT_EQ(board->cols, 6);
    EXPECT_EQ(board->rows, 5);
    EXPECT_DOUBLE_EQ(board->tag_m, 0.088);
    EXPECT_DOUBLE_EQ(board->spacing_ratio, 0.3);
    EXPECT_EQ(board->pointCount(), 120);
    EXPECT_EQ(board->toString(), "aprilgrid:6x5:0.088:0.3");
    auto again = parseBoardSpec(board->toString());
    ASSERT_TRUE(again);
    EXPECT_EQ(again->toString(), board->toString());
}

// Every bad spec is a usage error that quotes the spec and names the field at fault.
TEST(BoardSpec, BadSpecsNameTheField) {
    const struct {
        const char* spec;
        const char* expected;
    } cases[] = {
        {"", "unknown board type ''"},
        {"checkerboard:9x6:0.02", "unknown board type 'checkerboard'"},
        {"chessboard", "chessboard:COLSxROWS:SQUARE_M (3 fields), found 1"},
        {"chessboard:9x6", "(3 fields), found 2"},
        {"chessboard:9x6:0.02:0.3", "(3 fields), found 4"},
        {"chessboard:9-6:0.02", "COLSxROWS '9-6' is not two whole numbers"},
        {"chessboard:9x:0.02", "COLSxROWS '9x'"},
        {"chessboard:ax6:0.02", "COLSxROWS 'ax6'"},
        {"chessboard:2x6:0.02", "COLS 2 must be in 3..200"},
        {"chessboard:9x2:0.02", "ROWS 2 must be in 3..200"},
        {"chessboard:9x6:abc", "SQUARE_M 'abc' is not a number"},
        {"chessboard:9x6:", "SQUARE_M '' is not a number"},
        {"chessboard:9x6:0.02m", "SQUARE_M '0.02m' is not a number"},
        {"chessboard:9x6:nan", "SQUARE_M 'nan' is not a number"},
        {"chessboard:9x6:-0.02", "SQUARE_M -0.02 must be in (0, 10]"},
        {"chessboard:9x6:25", "SQUARE_M 25 must be in (0, 10]: the square's edge in metres"},
        {"aprilgrid:6x6:0.088", "aprilgrid:COLSxROWS:TAG_M:SPACING_RATIO (4 fields), found 3"},
        {"aprilgrid:0x6:0.088:0.3", "COLS must be at least 1"},
        {"aprilgrid:6x0:0.088:0.3", "ROWS must be at least 1"},
        {"aprilgrid:30x30:0.01:0.3", "900 tags, more than tag36h11's 587 ids"},
        {"aprilgrid:6x6:0:0.3", "TAG_M 0 must be in (0, 10]"},
        {"aprilgrid:6x6:x:0.3", "TAG_M 'x' is not a number"},
        {"aprilgrid:6x6:0.088:0", "SPACING_RATIO 0 must be in (0, 10]"},
        {"aprilgrid:6x6:0.088:inf", "SPACING_RATIO 'inf' is not a number"},
        {"aprilgrid:6x6:0.088:30", "SPACING_RATIO 30 must be in (0, 10]"},
    };
    for (const auto& c : cases) {
        auto board = parseBoardSpec(c.spec);
        ASSERT_FALSE(board) << c.spec;
        EXPECT_EQ(board.error().code, ErrorCode::kUsage) << c.spec;
        const std::string& message = board.error().message;
        EXPECT_NE(message.find("board spec '" + std::string(c.spec) + "'"), std::string::npos) << message;
        EXPECT_NE(message.find(c.expected), std::string::npos) << c.spec << " -> " << message;
    }
}

// OpenCV's chessboard: point r * COLS + c at (c, r) squares.
TEST(BoardSpec, ChessboardPointsAreRowMajor) {
    const BoardSpec board = *parseBoardSpec("chessboard:9x6:0.025");
    EXPECT_EQ(board.point(0), Vector3d(0, 0, 0));
    EXPECT_EQ(board.point(1), Vector3d(0.025, 0, 0));
    EXPECT_EQ(board.point(9), Vector3d(0, 0.025, 0));
    EXPECT_TRUE(board.point(53).isApprox(Vector3d(8 * 0.025, 5 * 0.025, 0)));
}

// Kalibr's AprilGrid: origin at the bottom-left corner of tag 0's black square, x along a row of
// tags, y up the rows; tag id = row * COLS + col; corners in libapriltag's order (bottom-left,
// bottom-right, top-right, top-left).
TEST(BoardSpec, AprilGridPointsFollowKalibr) {
    const BoardSpec board = *parseBoardSpec("aprilgrid:6x5:0.1:0.3");
    const double t = 0.1;
    const double pitch = 1.3 * t;
    EXPECT_TRUE(board.point(0).isApprox(Vector3d(0, 0, 0)));
    EXPECT_TRUE(board.point(1).isApprox(Vector3d(t, 0, 0)));
    EXPECT_TRUE(board.point(2).isApprox(Vector3d(t, t, 0)));
    EXPECT_TRUE(board.point(3).isApprox(Vector3d(0, t, 0)));
    EXPECT_TRUE(board.point(4 * 1 + 0).isApprox(Vector3d(pitch, 0, 0)));  // tag 1: next along x
    EXPECT_TRUE(board.point(4 * 6 + 0).isApprox(Vector3d(0, pitch, 0)));  // tag 6: first of row 1, up
    EXPECT_TRUE(board.point(4 * 29 + 2).isApprox(Vector3d(5 * pitch + t, 4 * pitch + t, 0)));  // last tag
    // The corners of one tag go counter-clockwise seen from +z, as tagCornerInTag's do.
    for (int k = 0; k < 4; ++k) {
        const Vector3d centre(0.5 * t, 0.5 * t, 0);
        EXPECT_TRUE((board.point(k) - centre).isApprox(tagCornerInTag(k, t))) << k;
    }
}

// A fronto-parallel chessboard drawn exactly (each pixel's value is the area of it that is white):
// squares of `s` pixels, the first inner corner at `origin`, the squares touching it diagonally black.
Image drawChessboard(int width, int height, int cols, int rows, double s, const Vector2d& origin) {
    const auto isBlack = [&](double x, double y) {  // x, y in squares from the origin
        const int cx = static_cast<int>(std::floor(x));
        const int cy = static_cast<int>(std::floor(y));
        return cx >= -1 && cx <= cols - 1 && cy >= -1 && cy <= rows - 1 && (cx + cy) % 2 == 0;
    };
    // The pixel [u - 0.5, u + 0.5) (OpenCV's pixel centres) split at the grid lines it crosses.
    const auto cuts = [&](double lo, double o) {
        std::vector<double> at = {lo};
        for (double line = std::ceil((lo - o) / s) * s + o; line < lo + 1.0; line += s) {
            if (line > lo) at.push_back(line);
        }
        at.push_back(lo + 1.0);
        return at;
    };
    Image image(PixelFormat::kGray8, width, height);
    for (int v = 0; v < height; ++v) {
        const std::vector<double> ys = cuts(v - 0.5, origin.y());
        for (int u = 0; u < width; ++u) {
            const std::vector<double> xs = cuts(u - 0.5, origin.x());
            double white = 0.0;
            for (std::size_t j = 0; j + 1 < ys.size(); ++j) {
                for (std::size_t i = 0; i + 1 < xs.size(); ++i) {
                    const double x = ((xs[i] + xs[i + 1]) / 2 - origin.x()) / s;
                    const double y = ((ys[j] + ys[j + 1]) / 2 - origin.y()) / s;
                    if (!isBlack(x, y)) white += (xs[i + 1] - xs[i]) * (ys[j + 1] - ys[j]);
                }
            }
            image.data()[v * image.stride() + u] = static_cast<std::uint8_t>(std::lround(20 + 200 * white));
        }
    }
    return image;
}

TEST(BoardDetector, FindsChessboardCornersToSubPixel) {
    const BoardSpec board = *parseBoardSpec("chessboard:7x5:0.03");
    const Vector2d origin(150.3, 120.7);
    const double s = 41.5;
    const Image image = drawChessboard(640, 480, 7, 5, s, origin);
    auto detector = BoardDetector::create(board);
    ASSERT_TRUE(detector) << detector.error().message;
    auto detection = detector->detect(image);
    ASSERT_TRUE(detection) << detection.error().message;
    ASSERT_TRUE(detection->found) << detection->reason;
    const BoardObservation& obs = detection->observation;
    ASSERT_EQ(obs.point_ids.size(), 35u);
    // OpenCV may start at either end of the board: the two labellings are 180 degrees apart.
    const bool reversed = (obs.pixels[0] - origin).norm() > 1.0;
    double worst = 0.0;
    for (std::size_t k = 0; k < obs.point_ids.size(); ++k) {
        EXPECT_EQ(obs.point_ids[k], static_cast<int>(k));
        const int id = reversed ? 34 - obs.point_ids[k] : obs.point_ids[k];
        const Vector2d expected = origin + s * Vector2d(id % 7, id / 7);
        worst = std::max(worst, (obs.pixels[k] - expected).norm());
    }
    EXPECT_LT(worst, 0.05);
}

TEST(BoardDetector, NoBoardIsAnOutcomeWithAReason) {
    Image blank(PixelFormat::kGray8, 320, 240);
    std::fill(blank.data(), blank.data() + blank.sizeBytes(), std::uint8_t{128});
    auto chess = BoardDetector::create(*parseBoardSpec("chessboard:9x6:0.025"));
    ASSERT_TRUE(chess);
    auto detection = chess->detect(blank);
    ASSERT_TRUE(detection) << detection.error().message;
    EXPECT_FALSE(detection->found);
    EXPECT_NE(detection->reason.find("chessboard with 9x6 inner corners not found"), std::string::npos)
        << detection->reason;

    auto grid = BoardDetector::create(*parseBoardSpec("aprilgrid:6x6:0.088:0.3"));
    ASSERT_TRUE(grid) << grid.error().message;
    detection = grid->detect(blank);
    ASSERT_TRUE(detection) << detection.error().message;
    EXPECT_FALSE(detection->found);
    EXPECT_NE(detection->reason.find("only 0 tags of the aprilgrid found (at least 4 needed)"), std::string::npos)
        << detection->reason;
}

TEST(BoardDetector, RejectsBadImagesAndOptions) {
    auto chess = BoardDetector::create(*parseBoardSpec("chessboard:9x6:0.025"));
    ASSERT_TRUE(chess);
    Image rgb(PixelFormat::kRgb8, 32, 32);
    auto detection = chess->detect(rgb);
    ASSERT_FALSE(detection);
    EXPECT_EQ(detection.error().code, ErrorCode::kBadInput);

    // A grid with fewer tags than a view needs can never be found.
    auto tiny = BoardDetector::create(*parseBoardSpec("aprilgrid:1x3:0.05:0.3"));
    ASSERT_FALSE(tiny);
    EXPECT_EQ(tiny.error().code, ErrorCode::kUsage);
    EXPECT_NE(tiny.error().message.find("3 tags, fewer than the 4"), std::string::npos) << tiny.error().message;

    BoardDetectorOptions options;
    options.min_tags = 0;
    EXPECT_FALSE(BoardDetector::create(*parseBoardSpec("aprilgrid:6x6:0.088:0.3"), options));
}

}  // namespace
}  // namespace commonlight::tracking

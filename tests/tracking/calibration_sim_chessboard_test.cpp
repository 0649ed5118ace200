// Calibration end to end on a chessboard rendered by mocks/sim (calibration_sim_support.h): a camera
// with known intrinsics and distortion, 21 views at 0.33-0.94 m, tilted up to 45 degrees about each
// axis, covering the image; fx, fy, cx, cy within 0.2% and k1 within 0.01. One more view shows the
// board mostly out of frame and must be rejected as not found.
#include <cstdio>
#include <vector>

#include <gtest/gtest.h>

#include "tests/tracking/calibration_sim_support.h"

namespace commonlight::tracking::calibration_sim {
namespace {

const BoardSpec kChessboard{BoardType::kChessboard, 11, 8, 0.03, 0.0, 0.0};

// u, v, distance, tilt x, tilt y, roll
// Each as close as the whole board fits: large, tilted views pin down the principal point (views far
// away leave it free to trade with the board's rotation).
const std::vector<ViewSpec> kChessboardViews = {
    {320, 240, 0.36, 0, 0, 0},       {320, 240, 0.48, 45, 0, 5},     {320, 240, 0.54, 0, -45, -5},
    {320, 240, 0.48, -45, 0, 5},     {320, 240, 0.54, 0, 45, -5},    {165, 125, 0.66, -25, 40, 30},
    {475, 125, 0.67, -25, -40, -30}, {165, 355, 0.67, 25, 40, -30},  {475, 355, 0.67, 25, -40, 30},
    {320, 95, 0.47, -40, 0, 0},      {320, 385, 0.47, -40, 0, 180},  {140, 240, 0.88, 0, 40, 90},
    {500, 240, 0.88, 0, -40, -90},   {320, 240, 0.57, 35, 35, 30},   {320, 240, 0.57, 35, -35, -30},
    {200, 200, 0.63, -30, 30, 45},   {440, 280, 0.79, -30, 30, -45}, {165, 125, 0.69, -35, 35, 0},
    {475, 125, 0.69, -35, -35, 0},   {165, 355, 0.70, 35, 35, 0},    {475, 355, 0.70, 35, -35, 0},
};
const ViewSpec kChessboardOutOfFrame{700, 20, 0.6, 10, 10, 0};

// Every view shows the whole board with room to spare, the bad one less than half of it, and
// together they put corners near every edge and corner of the image.
TEST(CalibrationSim, ChessboardViewDesignsShowTheBoard) {
    for (std::size_t i = 0; i < kChessboardViews.size(); ++i) {
        const Rigid3d pose = camFromBoard(kChessboardViews[i], boardCentre(kChessboard));
        EXPECT_EQ(pointsInView(kChessboard, pose, 5.0), kChessboard.pointCount()) << "view " << i;
        EXPECT_TRUE(chessboardSquaresInView(kChessboard, pose, 3.0)) << "view " << i;
    }
    EXPECT_LT(pointsInView(kChessboard, camFromBoard(kChessboardOutOfFrame, boardCentre(kChessboard)), 0.0),
              kChessboard.pointCount() / 2);
    const CoverageReport coverage = designedCoverage(kChessboard, kChessboardViews);
    std::printf("designed coverage %.0f%%\n", 100 * coverage.fraction);
    EXPECT_TRUE(coverage.warning.empty()) << coverage.warning;
}

TEST(CalibrationSim, ChessboardRecoversIntrinsics) {
    calibrateAndCheck(kChessboard, kChessboardViews, kChessboardOutOfFrame, "not found");
}

}  // namespace
}  // namespace commonlight::tracking::calibration_sim

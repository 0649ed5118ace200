// Calibration end to end on a Kalibr AprilGrid rendered by mocks/sim (calibration_sim_support.h):
// a camera with known intrinsics and distortion, 16 views at 0.45-0.65 m, tilted up to 45 degrees
// about each axis, partly out of the image; fx, fy, cx, cy within 0.2% and k1 within 0.01. One more
// view shows only 3 tags and must be rejected.
#include <cstdio>
#include <vector>

#include <gtest/gtest.h>

#include "tests/tracking/calibration_sim_support.h"

namespace commonlight::tracking::calibration_sim {
namespace {

const BoardSpec kAprilGrid{BoardType::kAprilGrid, 6, 6, 0.0, 0.04, 0.3};

const std::vector<ViewSpec> kAprilGridViews = {
    {320, 240, 0.60, 0, 0, 0},     {320, 240, 0.55, 40, 0, 5},    {320, 240, 0.55, 0, -40, -5},
    {150, 115, 0.65, 20, -25, 10}, {490, 115, 0.65, 20, 25, -10}, {150, 365, 0.65, -20, -25, -10},
    {490, 365, 0.65, -25, 20, 10}, {320, 100, 0.65, 30, 0, 0},    {320, 380, 0.65, -30, 0, 180},
    {120, 240, 0.65, 0, -30, 90},  {520, 240, 0.65, 0, 30, -90},  {320, 240, 0.60, 45, 0, 30},
    {320, 240, 0.60, 0, 45, -30},  {200, 200, 0.60, -30, 30, 45}, {440, 280, 0.60, 30, -30, -45},
    {320, 240, 0.45, -20, 20, 0},
};
const ViewSpec kAprilGridOutOfFrame{780, -20, 0.5, 10, 10, 0};

// Every view shows at least 12 whole tags, the bad one fewer than 4, and together they put corners
// near every edge and corner of the image.
TEST(CalibrationSim, AprilGridViewDesignsShowTheBoard) {
    for (std::size_t i = 0; i < kAprilGridViews.size(); ++i) {
        const Rigid3d pose = camFromBoard(kAprilGridViews[i], boardCentre(kAprilGrid));
        EXPECT_GE(tagsInView(kAprilGrid, pose, 3.0), 12) << "view " << i;
    }
    EXPECT_LT(tagsInView(kAprilGrid, camFromBoard(kAprilGridOutOfFrame, boardCentre(kAprilGrid)), 0.0), 4);
    const CoverageReport coverage = designedCoverage(kAprilGrid, kAprilGridViews);
    std::printf("designed coverage %.0f%%\n", 100 * coverage.fraction);
    EXPECT_TRUE(coverage.warning.empty()) << coverage.warning;
}

TEST(CalibrationSim, AprilGridRecoversIntrinsics) {
    calibrateAndCheck(kAprilGrid, kAprilGridViews, kAprilGridOutOfFrame, "tags of the aprilgrid found");
}

}  // namespace
}  // namespace commonlight::tracking::calibration_sim

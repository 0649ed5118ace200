// Shared by the calibration tests on images rendered by mocks/sim (calibration_sim_*_test.cpp):
// the true camera, board scenes, view designs and the check that a calibration recovers the camera.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/camera_model.h"
#include "core/image.h"
#include "core/pose.h"
#include "core/scene.h"
#include "tracking/calibration.h"
#include "tracking/calibration_board.h"

namespace commonlight::tracking::calibration_sim {

constexpr int kWidth = 640;
constexpr int kHeight = 480;

// 640 x 480, fx 600, fy 601.5, cx 322.4, cy 236.7, k1 -0.2, k2 0.05, p1 0.001, p2 -0.0005, k3 0.
CameraModel trueCamera();

// A view: where the board's centre appears (pixels, before distortion), how far it is (metres), and
// how it is turned: tilts about the camera's x and y axes, then a roll about the view axis (degrees).
struct ViewSpec {
    double u, v, distance, tilt_x_deg, tilt_y_deg, roll_deg;
};

// cam_from_board for a view of a board whose centre is `centre` (board frame, metres). Facing the
// camera, the board's x points right in the image and its y up.
Rigid3d camFromBoard(const ViewSpec& view, const Eigen::Vector3d& centre);
// The middle of the board's points.
Eigen::Vector3d boardCentre(const BoardSpec& board);

// The board as a scene: the board frame is the world frame (z up, printed side +z) on a grey
// table, lit evenly by a sun along -z (slightly slanted) and a uniform sky.
Scene boardScene(const BoardSpec& board);

// The board points that project into the image with `margin` pixels to spare.
int pointsInView(const BoardSpec& board, const Rigid3d& cam_from_board, double margin);
// AprilGrid tags whose four corners project into the image with `margin` pixels to spare.
int tagsInView(const BoardSpec& board, const Rigid3d& cam_from_board, double margin);
// The chessboard's outer squares and half a square of white around them (the quiet zone the
// detector needs), with `margin` pixels to spare.
bool chessboardSquaresInView(const BoardSpec& board, const Rigid3d& cam_from_board, double margin);
// How the views' corners would cover the image (no rendering).
CoverageReport designedCoverage(const BoardSpec& board, const std::vector<ViewSpec>& views);

struct RenderedView {
    std::string name;
    Image gray;
    Rigid3d cam_from_board;
};

// Renders the views as 8-bit grey images ("view00.png", ...). COMMONLIGHT_CALIB_TEST_DUMP=<folder>
// writes them there.
std::vector<RenderedView> renderViews(const BoardSpec& board, const std::vector<ViewSpec>& views, int spp);

// Renders the good views and the bad one (last), finds the board, calibrates, and checks: fx, fy, cx,
// cy within 0.2%, k1 within 0.01, RMS below 0.3 px, no coverage warning, every good view used, the
// bad one rejected with a reason containing `bad_reason`, and the YAML read back by core's reader.
void calibrateAndCheck(const BoardSpec& board, const std::vector<ViewSpec>& good, const ViewSpec& bad,
                       const std::string& bad_reason);

}  // namespace commonlight::tracking::calibration_sim

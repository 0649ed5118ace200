// The camera's response from an exposure bracket: several images of a static scene at known
// exposure times, through OpenCV's CalibrateDebevec (Debevec and Malik 1997) or
// CalibrateRobertson (Robertson et al. 2003). `commonlight calibrate-response` writes the result
// as a response file (core/response.h).
#pragma once

#include <string>
#include <vector>

#include "core/image.h"
#include "core/response.h"
#include "core/result.h"

namespace commonlight {

enum class ResponseMethod { kDebevec, kRobertson };

struct BracketImage {
    ImageView rgb8;          // borrowed for the call; all the same size
    double exposure_s = 0.0; // > 0
    std::string name;        // for messages
};

struct ResponseCalibration {
    ResponseCurve curve;        // per channel, code 255 -> 1, non-decreasing
    double best_gamma = 0.0;    // the gamma:G that fits the recovered curve best over codes 20..235
    // RMS of the relative difference between the recovered curve and each model over codes 20..235
    // (green channel): which model the camera is closest to.
    double rms_vs_srgb = 0.0;
    double rms_vs_linear = 0.0;
    double rms_vs_gamma = 0.0;
    double saturated_fraction = 0.0;  // of all pixels in the bracket
    double exposure_ratio = 0.0;      // longest / shortest exposure
    std::vector<std::string> warnings;
};

// Errors (kBadInput naming the image): fewer than 2 images, exposures not positive or all equal,
// images of different sizes or not RGB8.
Result<ResponseCalibration> calibrateResponse(const std::vector<BracketImage>& images, ResponseMethod method,
                                              int samples = 70);

}  // namespace commonlight

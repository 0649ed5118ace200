#include "core/response_calibration.h"

#include <opencv2/core.hpp>
#include <opencv2/photo.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

namespace commonlight {

namespace {

// RMS over codes 20..235 of (k a - b) / b, green channel, with the scale k that fits best: a
// bracket recovers a response up to scale.
double relativeRms(const ResponseCurve& a, const ResponseCurve& b) {
    double num = 0.0, den = 0.0;
    for (int code = 20; code <= 235; ++code) {
        const double q = a.toLinear(1, static_cast<std::uint8_t>(code)) / std::max(1e-12f, b.toLinear(1, static_cast<std::uint8_t>(code)));
        num += q;
        den += q * q;
    }
    const double k = den > 0.0 ? num / den : 1.0;
    double s = 0.0;
    int n = 0;
    for (int code = 20; code <= 235; ++code) {
        const double x = k * a.toLinear(1, static_cast<std::uint8_t>(code)), y = b.toLinear(1, static_cast<std::uint8_t>(code));
        if (!(y > 0.0)) continue;
        s += (x - y) * (x - y) / (y * y);
        ++n;
    }
    return n > 0 ? std::sqrt(s / n) : 0.0;
}

// Least squares line y = slope x + intercept.
std::pair<double, double> fitLine(const std::vector<double>& x, const std::vector<double>& y) {
    const double n = static_cast<double>(x.size());
    double sx = 0, sy = 0, sxx = 0, sxy = 0;
    for (std::size_t i = 0; i < x.size(); ++i) {
        sx += x[i];
        sy += y[i];
        sxx += x[i] * x[i];
        sxy += x[i] * y[i];
    }
    const double d = n * sxx - sx * sx;
    if (!(std::abs(d) > 0.0)) return {1.0, 0.0};
    const double slope = (n * sxy - sx * sy) / d;
    return {slope, (sy - slope * sx) / n};
}

}  // namespace

Result<ResponseCalibration> calibrateResponse(const std::vector<BracketImage>& images, ResponseMethod method, int samples) {
    // Step 1: check the bracket.
    if (images.size() < 2) return fail(ErrorCode::kBadInput, "calibrate-response: an exposure bracket needs at least 2 images");
    double shortest = 1e300, longest = 0.0;
    for (const BracketImage& im : images) {
        if (im.rgb8.format != PixelFormat::kRgb8 || im.rgb8.empty()) {
            return fail(ErrorCode::kBadInput, im.name + ": not an RGB8 image");
        }
        if (im.rgb8.width != images[0].rgb8.width || im.rgb8.height != images[0].rgb8.height) {
            return fail(ErrorCode::kBadInput, im.name + ": " + std::to_string(im.rgb8.width) + "x" + std::to_string(im.rgb8.height) +
                                                  " differs from " + images[0].name + " (" + std::to_string(images[0].rgb8.width) +
                                                  "x" + std::to_string(images[0].rgb8.height) + ")");
        }
        if (!(std::isfinite(im.exposure_s) && im.exposure_s > 0.0)) {
            return fail(ErrorCode::kBadInput, im.name + ": exposure must be positive");
        }
        shortest = std::min(shortest, im.exposure_s);
        longest = std::max(longest, im.exposure_s);
    }
    if (!(longest > shortest * 1.01)) {
        return fail(ErrorCode::kBadInput, "calibrate-response: every image has the same exposure; a bracket needs different ones");
    }
    ResponseCalibration out;
    out.exposure_ratio = longest / shortest;
    // Step 2: OpenCV wants BGR 8-bit images and float exposure times.
    std::vector<cv::Mat> mats;
    std::vector<float> times;
    std::size_t saturated = 0, total = 0;
    for (const BracketImage& im : images) {
        const cv::Mat rgb(im.rgb8.height, im.rgb8.width, CV_8UC3, const_cast<std::uint8_t*>(im.rgb8.data), im.rgb8.stride);
        cv::Mat bgr;
        cv::cvtColor(rgb, bgr, cv::COLOR_RGB2BGR);
        for (int y = 0; y < bgr.rows; ++y) {
            const std::uint8_t* p = bgr.ptr<std::uint8_t>(y);
            for (int x = 0; x < 3 * bgr.cols; ++x) saturated += p[x] >= 250 ? 1 : 0;
        }
        total += static_cast<std::size_t>(bgr.rows) * bgr.cols * 3;
        mats.push_back(bgr);
        times.push_back(static_cast<float>(im.exposure_s));
    }
    out.saturated_fraction = static_cast<double>(saturated) / static_cast<double>(std::max<std::size_t>(total, 1));
    cv::Mat response;
    try {
        if (method == ResponseMethod::kDebevec) {
            cv::createCalibrateDebevec(samples)->process(mats, response, times);
        } else {
            cv::createCalibrateRobertson()->process(mats, response, times);
        }
    } catch (const cv::Exception& e) {
        return fail(ErrorCode::kBadInput, std::string("calibrate-response: OpenCV failed: ") + e.what());
    }
    if (response.rows != 256 || response.type() != CV_32FC3) {
        return fail(ErrorCode::kInternal, "calibrate-response: OpenCV returned an unexpected response");
    }
    // Step 3: a response table per channel (OpenCV's is BGR, relative exposure per code, up to
    // scale): made non-decreasing (a running maximum: noise at the ends can dip), and scaled so
    // that code 255 is 1, the value at 255 extrapolated from the upper mid codes (150..235, a line
    // in log-log) because the top codes are where saturation corrupts the estimate.
    ResponseCurve::Table table{};
    for (int c = 0; c < 3; ++c) {
        const int bgr_channel = 2 - c;
        double running = 0.0;
        std::vector<double> lx, ly;
        for (int code = 0; code < 256; ++code) {
            const double v = response.at<cv::Vec3f>(code, 0)[bgr_channel];
            running = std::max(running, std::isfinite(v) ? v : 0.0);
            table[static_cast<std::size_t>(c)][static_cast<std::size_t>(code)] = static_cast<float>(running);
            if (code >= 150 && code <= 235 && running > 0.0) {
                lx.push_back(std::log(code / 255.0));
                ly.push_back(std::log(running));
            }
        }
        const double top = lx.size() >= 8 ? std::exp(fitLine(lx, ly).second) : table[static_cast<std::size_t>(c)][255];
        if (!(top > 0.0) || !std::isfinite(top)) {
            // Hard case: Robertson's estimate is normalised at code 128 and has no smoothness
            // term, so a bracket whose codes leave gaps (few distinct radiances) gives NaN there.
            return fail(ErrorCode::kBadInput, std::string("calibrate-response: no usable response in the ") + "rgb"[c] +
                                                  " channel (" + (method == ResponseMethod::kRobertson
                                                                      ? "Robertson needs codes spread over the whole range; try --method debevec"
                                                                      : "the bracket may be all black or all saturated") +
                                                  ")");
        }
        for (float& v : table[static_cast<std::size_t>(c)]) v = std::clamp(static_cast<float>(v / top), 0.0f, 1.0f);
    }
    CL_TRY(out.curve, ResponseCurve::fromTable(table, method == ResponseMethod::kDebevec ? "debevec" : "robertson"));
    // Step 4: which model it is closest to: the best gamma is the slope of the curve in log-log
    // over the mid codes (the intercept is the free scale).
    {
        std::vector<double> lx, ly;
        for (int code = 20; code <= 235; ++code) {
            const double v = out.curve.toLinear(1, static_cast<std::uint8_t>(code));
            if (!(v > 0.0)) continue;
            lx.push_back(std::log(code / 255.0));
            ly.push_back(std::log(v));
        }
        out.best_gamma = std::clamp(fitLine(lx, ly).first, 0.2, 5.0);
    }
    out.rms_vs_srgb = relativeRms(out.curve, ResponseCurve::srgb());
    out.rms_vs_linear = relativeRms(out.curve, ResponseCurve::linear());
    out.rms_vs_gamma = relativeRms(out.curve, *ResponseCurve::gamma(out.best_gamma));
    if (out.exposure_ratio < 8.0) {
        char w[160];
        std::snprintf(w, sizeof w, "the bracket spans only %.1fx in exposure; 16x or more recovers the ends of the curve", out.exposure_ratio);
        out.warnings.emplace_back(w);
    }
    if (out.saturated_fraction > 0.3) out.warnings.emplace_back("more than 30% of the pixels are saturated: shorten the exposures");
    return out;
}

}  // namespace commonlight

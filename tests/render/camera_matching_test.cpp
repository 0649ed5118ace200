// The camera-matching estimators on synthetic images with known noise and blur: the sensor noise
// per intensity (constant, and growing with the signal) through flat areas, gradients and edges;
// the Gaussian blur of step edges drawn in linear light, integrated by square pixels, blurred and
// encoded with the sRGB curve. CPU only.
#include "render/camera_matching.h"

#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include <cmath>
#include <random>

namespace commonlight::render {
namespace {

ImageView viewOf(const cv::Mat& rgb) {
    return ImageView{PixelFormat::kRgb8, rgb.cols, rgb.rows, rgb.step, rgb.data, rgb.step * static_cast<std::size_t>(rgb.rows)};
}

// A 640 x 480 scene in codes: a horizontal ramp (20..235), a few flat rectangles of other codes
// (edges), coloured differently per channel.
cv::Mat3f cleanScene() {
    cv::Mat3f scene(480, 640);
    for (int y = 0; y < scene.rows; ++y) {
        for (int x = 0; x < scene.cols; ++x) {
            const float ramp = 20.0f + 215.0f * static_cast<float>(x) / static_cast<float>(scene.cols - 1);
            scene(y, x) = cv::Vec3f(ramp, 0.8f * ramp + 20.0f, 255.0f - ramp);
        }
    }
    cv::rectangle(scene, cv::Rect(60, 60, 150, 120), cv::Scalar(60, 200, 120), cv::FILLED);
    cv::rectangle(scene, cv::Rect(380, 250, 180, 160), cv::Scalar(180, 40, 90), cv::FILLED);
    cv::circle(scene, cv::Point(320, 240), 70, cv::Scalar(140, 140, 30), cv::FILLED);
    return scene;
}

// Gaussian noise of deviation sigma(code) added in codes, rounded and clipped to 8 bits.
template <typename Sigma>
cv::Mat noisy(const cv::Mat3f& clean, Sigma sigma, unsigned seed) {
    std::mt19937 rng(seed);
    std::normal_distribution<float> normal(0.0f, 1.0f);
    cv::Mat out(clean.rows, clean.cols, CV_8UC3);
    for (int y = 0; y < clean.rows; ++y) {
        for (int x = 0; x < clean.cols; ++x) {
            for (int c = 0; c < 3; ++c) {
                const float v = clean(y, x)[c];
                out.at<cv::Vec3b>(y, x)[c] = cv::saturate_cast<std::uint8_t>(std::lround(v + sigma(v) * normal(rng)));
            }
        }
    }
    return out;
}

// Rounding to codes adds 1/12 code^2 of variance to the noise it rounds.
double quantised(double sigma) { return std::sqrt(sigma * sigma + 1.0 / 12.0); }

TEST(CameraMatching, NoiseOfConstantDeviation) {
    for (const double sigma : {0.8, 1.0, 1.5, 3.0, 6.0}) {
        const cv::Mat image = noisy(cleanScene(), [&](float) { return static_cast<float>(sigma); }, 3);
        auto profile = estimateNoise(viewOf(image));
        ASSERT_TRUE(profile) << profile.error().message;
        const double expected = quantised(sigma);
        for (int c = 0; c < 3; ++c) {
            // 6%: the median of about 150 000 residuals, the structure of the ramp and the edges.
            EXPECT_NEAR(profile->overall[c], expected, 0.06 * expected) << "sigma " << sigma << " channel " << c;
        }
        std::printf("constant sigma %.1f: estimated %.3f %.3f %.3f (expected %.3f)\n", sigma, profile->overall[0], profile->overall[1],
                    profile->overall[2], expected);
    }
}

// A sensor's noise grows with the signal: sigma = 1 + 5 code / 255. Each bin that measured enough
// pixels recovers it at its centre.
TEST(CameraMatching, NoiseGrowingWithTheSignal) {
    const auto truth = [](float code) { return 1.0f + 5.0f * code / 255.0f; };
    const cv::Mat image = noisy(cleanScene(), truth, 5);
    auto profile = estimateNoise(viewOf(image));
    ASSERT_TRUE(profile) << profile.error().message;
    int checked = 0;
    double worst = 0.0;
    for (int b = 0; b < NoiseProfile::kBins; ++b) {
        if (profile->pixels[static_cast<std::size_t>(b)] < 2000) continue;
        const float code = 16.0f * static_cast<float>(b) + 8.0f;
        const double expected = quantised(truth(code));
        for (int c = 0; c < 3; ++c) {
            const double got = profile->sigma[static_cast<std::size_t>(b)][c];
            worst = std::max(worst, std::abs(got - expected) / expected);
            // 12%: a bin's local mean spreads over 16 codes (the deviation varies by 0.3 within it).
            EXPECT_NEAR(got, expected, 0.12 * expected) << "bin " << b << " channel " << c;
            EXPECT_NEAR(profile->at(c, code), got, 1e-5);
        }
        ++checked;
    }
    std::printf("growing noise: %d bins checked, worst relative error %.3f\n", checked, worst);
    EXPECT_GE(checked, 8);
}

TEST(CameraMatching, NoiseOfANoiselessImageIsTheRounding) {
    const cv::Mat image = noisy(cleanScene(), [](float) { return 0.0f; }, 1);
    auto profile = estimateNoise(viewOf(image));
    ASSERT_TRUE(profile);
    for (int c = 0; c < 3; ++c) EXPECT_LT(profile->overall[c], 0.5f);
}

// Step edges drawn in linear light at 4 x 4 samples per pixel and averaged (square pixels), blurred
// by a Gaussian of `blur` pixels, sRGB-encoded to 8 bits with 1 code of noise: the estimate is the
// whole PSF, sqrt(blur^2 + 1/12) (a square pixel's own variance is 1/12 px^2).
cv::Mat edgeScene(double blur, unsigned seed) {
    const int s = 4;
    cv::Mat fine(480 * s, 640 * s, CV_32FC1, cv::Scalar(0.05));
    cv::rectangle(fine, cv::Rect(80 * s, 70 * s, 200 * s, 150 * s), cv::Scalar(0.6), cv::FILLED);
    cv::circle(fine, cv::Point(470 * s, 150 * s), 90 * s, cv::Scalar(0.35), cv::FILLED);
    // A rotated square: edges at other angles than the axes.
    const cv::RotatedRect rotated(cv::Point2f(320.0f * s, 360.0f * s), cv::Size2f(160.0f * s, 120.0f * s), 27.0f);
    cv::Point2f corners[4];
    rotated.points(corners);
    std::vector<cv::Point> polygon;
    for (const cv::Point2f& p : corners) polygon.emplace_back(cvRound(p.x), cvRound(p.y));
    cv::fillConvexPoly(fine, polygon, cv::Scalar(0.8));
    cv::Mat linear;
    cv::resize(fine, linear, cv::Size(640, 480), 0, 0, cv::INTER_AREA);
    if (blur > 0.0) cv::GaussianBlur(linear, linear, cv::Size(0, 0), blur, blur, cv::BORDER_REFLECT);
    std::mt19937 rng(seed);
    std::normal_distribution<float> normal(0.0f, 1.0f);
    const ResponseCurve srgb = ResponseCurve::srgb();
    cv::Mat out(480, 640, CV_8UC3);
    for (int y = 0; y < 480; ++y) {
        for (int x = 0; x < 640; ++x) {
            const float code = 255.0f * srgb.toEncoded(1, linear.at<float>(y, x));
            for (int c = 0; c < 3; ++c) out.at<cv::Vec3b>(y, x)[c] = cv::saturate_cast<std::uint8_t>(std::lround(code + normal(rng)));
        }
    }
    return out;
}

TEST(CameraMatching, BlurOfStepEdges) {
    for (const double blur : {0.0, 0.8, 1.5}) {
        const cv::Mat image = edgeScene(blur, 9);
        auto estimate = estimateBlur(viewOf(image), ResponseCurve::srgb());
        ASSERT_TRUE(estimate) << estimate.error().message;
        const double expected = std::sqrt(blur * blur + 1.0 / 12.0);
        std::printf("blur %.1f px: estimated %.3f px (expected %.3f) from %d edges, spread %.3f\n", blur, estimate->sigma_px, expected,
                    estimate->edges, estimate->spread);
        EXPECT_GT(estimate->edges, 30);
        // 0.08 px + 8%: the fit of a Gaussian to a pixel-integrated step, edge curvature, noise.
        EXPECT_NEAR(estimate->sigma_px, expected, 0.08 + 0.08 * expected) << "blur " << blur;
    }
}

TEST(CameraMatching, FlatImagesAndBadInput) {
    const cv::Mat flat(64, 64, CV_8UC3, cv::Scalar(100, 100, 100));
    auto blur = estimateBlur(viewOf(flat), ResponseCurve::srgb());
    ASSERT_TRUE(blur);
    EXPECT_EQ(blur->edges, 0);
    EXPECT_EQ(blur->sigma_px, 0.0);
    const cv::Mat tiny(8, 8, CV_8UC3, cv::Scalar(1, 2, 3));
    auto noise = estimateNoise(viewOf(tiny));
    ASSERT_FALSE(noise);
    EXPECT_EQ(noise.error().code, ErrorCode::kBadInput);
    ImageView gray = viewOf(flat);
    gray.format = PixelFormat::kGray8;
    EXPECT_FALSE(estimateNoise(gray));
}

}  // namespace
}  // namespace commonlight::render

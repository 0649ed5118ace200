#include "render/camera_matching.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <string>
#include <vector>

#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

namespace commonlight::render {

namespace {

constexpr int kMinBinPixels = 100;  // fewer: the bin is interpolated from its neighbours

Result<cv::Mat> rgbMat(const ImageView& rgb, const char* what) {
    if (rgb.format != PixelFormat::kRgb8 || rgb.data == nullptr) {
        return fail(ErrorCode::kBadInput, std::string("render: ") + what + " needs an RGB8 image (got " +
                                              std::string(pixelFormatName(rgb.format)) + ")");
    }
    if (rgb.width < 16 || rgb.height < 16 || rgb.stride < 3 * static_cast<std::size_t>(rgb.width)) {
        return fail(ErrorCode::kBadInput, std::string("render: ") + what + " needs an image of at least 16 x 16 pixels (got " +
                                              std::to_string(rgb.width) + "x" + std::to_string(rgb.height) + ")");
    }
    return cv::Mat(rgb.height, rgb.width, CV_8UC3, const_cast<std::uint8_t*>(rgb.data), rgb.stride);
}

// Median of `values` (reordered).
float median(std::vector<float>& values) {
    const auto mid = values.begin() + static_cast<std::ptrdiff_t>(values.size() / 2);
    std::nth_element(values.begin(), mid, values.end());
    return *mid;
}

// Standard deviation of the noise from the mask's residuals of the flattest half of a set of
// pixels: (gradient, |residual|) pairs, reordered.
float flatSigma(std::vector<std::pair<float, float>>& pixels) {
    const auto half = pixels.begin() + static_cast<std::ptrdiff_t>(pixels.size() / 2);
    std::nth_element(pixels.begin(), half, pixels.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
    std::vector<float> residuals;
    residuals.reserve(pixels.size() / 2 + 1);
    for (auto it = pixels.begin(); it != half; ++it) residuals.push_back(it->second);
    if (residuals.empty()) return 0.0f;
    // The residuals of 8-bit codes are integers: the median of their absolute values is taken
    // between integers, as for grouped data (the value k - 1/2 + (n/2 - below) / at k), or small
    // deviations would come out in steps of 0.25 codes.
    const float k = median(residuals);
    std::size_t below = 0, at = 0;
    for (const float r : residuals) {
        below += r < k - 0.5f ? 1 : 0;
        at += std::abs(r - k) <= 0.5f ? 1 : 0;
    }
    const float middle = 0.5f * static_cast<float>(residuals.size());
    const float interpolated = at > 0 ? std::max(0.0f, k - 0.5f + (middle - static_cast<float>(below)) / static_cast<float>(at)) : k;
    // Pure noise of deviation s: the residual is normal with deviation 6 s (the mask's squared
    // weights sum to 36); its median absolute value is 0.6745 x 6 s.
    return 1.4826f * interpolated / 6.0f;
}

// The blurred step a + b Phi((d - d0) / sigma) against samples (d_i, value_i).
class EdgeFit : public cv::LMSolver::Callback {
public:
    EdgeFit(const std::vector<double>& d, const std::vector<double>& value) : d_(d), value_(value) {}
    bool compute(cv::InputArray param, cv::OutputArray err, cv::OutputArray jacobian) const override {
        const cv::Mat p = param.getMat();
        const double a = p.at<double>(0), b = p.at<double>(1), d0 = p.at<double>(2), sigma = std::max(p.at<double>(3), 1e-3);
        const int n = static_cast<int>(d_.size());
        err.create(n, 1, CV_64F);
        cv::Mat e = err.getMat();
        cv::Mat j;
        if (jacobian.needed()) {
            jacobian.create(n, 4, CV_64F);
            j = jacobian.getMat();
        }
        for (int i = 0; i < n; ++i) {
            const double x = (d_[static_cast<std::size_t>(i)] - d0) / sigma;
            const double phi = 0.5 * std::erfc(-x / std::numbers::sqrt2);
            const double density = std::exp(-0.5 * x * x) / std::sqrt(2.0 * std::numbers::pi);
            e.at<double>(i) = a + b * phi - value_[static_cast<std::size_t>(i)];
            if (!j.empty()) {
                j.at<double>(i, 0) = 1.0;
                j.at<double>(i, 1) = phi;
                j.at<double>(i, 2) = -b * density / sigma;
                j.at<double>(i, 3) = -b * density * x / sigma;
            }
        }
        return true;
    }

private:
    const std::vector<double>& d_;
    const std::vector<double>& value_;
};

}  // namespace

float NoiseProfile::at(int channel, float code) const {
    const float x = std::clamp((code - 8.0f) / 16.0f, 0.0f, static_cast<float>(kBins - 1));
    const int i0 = std::min(static_cast<int>(x), kBins - 2);
    const float f = x - static_cast<float>(i0);
    return (1.0f - f) * sigma[static_cast<std::size_t>(i0)][channel] + f * sigma[static_cast<std::size_t>(i0 + 1)][channel];
}

Result<NoiseProfile> estimateNoise(const ImageView& rgb) {
    CL_TRY(const cv::Mat image, rgbMat(rgb, "the noise estimate"));
    std::vector<cv::Mat> channels;
    cv::split(image, channels);
    const cv::Mat mask = (cv::Mat_<float>(3, 3) << 1, -2, 1, -2, 4, -2, 1, -2, 1);
    NoiseProfile out;
    out.pixels.fill(image.rows * image.cols);
    for (int c = 0; c < 3; ++c) {
        cv::Mat value, residual, mean, gx, gy;
        channels[static_cast<std::size_t>(c)].convertTo(value, CV_32F);
        cv::filter2D(value, residual, CV_32F, mask, cv::Point(-1, -1), 0.0, cv::BORDER_REFLECT);
        cv::blur(value, mean, cv::Size(5, 5), cv::Point(-1, -1), cv::BORDER_REFLECT);
        cv::Sobel(mean, gx, CV_32F, 1, 0, 3, 1.0, 0.0, cv::BORDER_REFLECT);
        cv::Sobel(mean, gy, CV_32F, 0, 1, 3, 1.0, 0.0, cv::BORDER_REFLECT);
        std::array<std::vector<std::pair<float, float>>, NoiseProfile::kBins> bins;
        std::vector<std::pair<float, float>> all;
        all.reserve(static_cast<std::size_t>(image.rows) * static_cast<std::size_t>(image.cols));
        // Every other pixel of every other row: a quarter of the work, still tens of thousands of
        // residuals per estimate.
        for (int y = 2; y < image.rows - 2; y += 2) {
            for (int x = 2; x < image.cols - 2; x += 2) {
                const float g = std::hypot(gx.at<float>(y, x), gy.at<float>(y, x));
                const std::pair<float, float> p(g, std::abs(residual.at<float>(y, x)));
                const int bin = std::clamp(static_cast<int>(mean.at<float>(y, x) / 16.0f), 0, NoiseProfile::kBins - 1);
                bins[static_cast<std::size_t>(bin)].push_back(p);
                all.push_back(p);
            }
        }
        out.overall[c] = flatSigma(all);
        // Measured bins, then the others interpolated between their measured neighbours.
        std::array<bool, NoiseProfile::kBins> measured{};
        for (int b = 0; b < NoiseProfile::kBins; ++b) {
            auto& pixels = bins[static_cast<std::size_t>(b)];
            out.pixels[static_cast<std::size_t>(b)] = std::min(out.pixels[static_cast<std::size_t>(b)], static_cast<int>(pixels.size()));
            measured[static_cast<std::size_t>(b)] = static_cast<int>(pixels.size()) >= kMinBinPixels;
            if (measured[static_cast<std::size_t>(b)]) out.sigma[static_cast<std::size_t>(b)][c] = flatSigma(pixels);
        }
        for (int b = 0; b < NoiseProfile::kBins; ++b) {
            if (measured[static_cast<std::size_t>(b)]) continue;
            int lo = b - 1, hi = b + 1;
            while (lo >= 0 && !measured[static_cast<std::size_t>(lo)]) --lo;
            while (hi < NoiseProfile::kBins && !measured[static_cast<std::size_t>(hi)]) ++hi;
            float s = out.overall[c];
            if (lo >= 0 && hi < NoiseProfile::kBins) {
                const float f = static_cast<float>(b - lo) / static_cast<float>(hi - lo);
                s = (1.0f - f) * out.sigma[static_cast<std::size_t>(lo)][c] + f * out.sigma[static_cast<std::size_t>(hi)][c];
            } else if (lo >= 0) {
                s = out.sigma[static_cast<std::size_t>(lo)][c];
            } else if (hi < NoiseProfile::kBins) {
                s = out.sigma[static_cast<std::size_t>(hi)][c];
            }
            out.sigma[static_cast<std::size_t>(b)][c] = s;
        }
    }
    return out;
}

Result<BlurEstimate> estimateBlur(const ImageView& rgb, const ResponseCurve& response) {
    CL_TRY(const cv::Mat image, rgbMat(rgb, "the blur estimate"));
    // Step 1: linear luminance (the blur acts on light, before the response curve).
    cv::Mat linear(image.rows, image.cols, CV_32F);
    std::array<std::array<float, 256>, 3> lut{};
    for (int c = 0; c < 3; ++c) {
        for (int k = 0; k < 256; ++k) lut[static_cast<std::size_t>(c)][static_cast<std::size_t>(k)] = response.toLinear(c, static_cast<std::uint8_t>(k));
    }
    for (int y = 0; y < image.rows; ++y) {
        const cv::Vec3b* in = image.ptr<cv::Vec3b>(y);
        float* out = linear.ptr<float>(y);
        for (int x = 0; x < image.cols; ++x) {
            out[x] = 0.2126f * lut[0][in[x][0]] + 0.7152f * lut[1][in[x][1]] + 0.0722f * lut[2][in[x][2]];
        }
    }
    // Step 2: strong edges (Canny on the 8-bit luminance, thresholds at the 90th and 97th
    // percentiles of its gradient), their normals from the smoothed linear image.
    cv::Mat gray, gx8, gy8, magnitude;
    cv::cvtColor(image, gray, cv::COLOR_RGB2GRAY);
    cv::Sobel(gray, gx8, CV_32F, 1, 0);
    cv::Sobel(gray, gy8, CV_32F, 0, 1);
    cv::magnitude(gx8, gy8, magnitude);
    std::vector<float> values(magnitude.begin<float>(), magnitude.end<float>());
    std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(values.size() * 97 / 100), values.end());
    const float high = values[values.size() * 97 / 100];
    std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(values.size() * 90 / 100), values.end());
    const float low = values[values.size() * 90 / 100];
    BlurEstimate out;
    if (!(high > 0.0f)) return out;  // hard case: a flat image has no edge to measure
    cv::Mat edges;
    cv::Canny(gray, edges, static_cast<double>(low), static_cast<double>(high), 3, true);
    cv::Mat smooth, nx, ny;
    cv::GaussianBlur(linear, smooth, cv::Size(0, 0), 1.0);
    cv::Sobel(smooth, nx, CV_32F, 1, 0);
    cv::Sobel(smooth, ny, CV_32F, 0, 1);
    std::vector<cv::Point> candidates;
    cv::findNonZero(edges, candidates);
    // About 400 edge points: their median is steady to a few hundredths of a pixel.
    const std::size_t step = std::max<std::size_t>(1, candidates.size() / 400);

    // Step 3: per edge, the pixels of a strip across it (|along| <= 2 px, |across| <= 7 px), fitted.
    constexpr int kHalf = 7;
    std::vector<double> sigmas;
    std::vector<double> d, value;
    for (std::size_t k = 0; k < candidates.size(); k += step) {
        const cv::Point p = candidates[k];
        if (p.x < kHalf || p.y < kHalf || p.x >= image.cols - kHalf || p.y >= image.rows - kHalf) continue;
        Eigen::Vector2d n(nx.at<float>(p), ny.at<float>(p));
        if (!(n.norm() > 0.0)) continue;
        n.normalize();
        d.clear();
        value.clear();
        for (int dy = -kHalf; dy <= kHalf; ++dy) {
            for (int dx = -kHalf; dx <= kHalf; ++dx) {
                const double across = dx * n.x() + dy * n.y(), along = -dx * n.y() + dy * n.x();
                if (std::abs(along) > 2.0 || std::abs(across) > kHalf) continue;
                d.push_back(across);
                value.push_back(linear.at<float>(p.y + dy, p.x + dx));
            }
        }
        const auto [lo_it, hi_it] = std::minmax_element(value.begin(), value.end());
        const double contrast = *hi_it - *lo_it;
        if (!(contrast > 1e-3)) continue;
        cv::Mat param = (cv::Mat_<double>(4, 1) << *lo_it, contrast, 0.0, 1.0);
        cv::Ptr<cv::LMSolver> solver = cv::LMSolver::create(cv::makePtr<EdgeFit>(d, value), 30);
        solver->run(param);
        const double b = param.at<double>(1), d0 = param.at<double>(2), sigma = std::abs(param.at<double>(3));
        // Accepted: a rising step (the normal points up the gradient) near the pixel, a sigma the
        // strip can hold, and a residual small against the step (no second edge, no corner).
        cv::Mat err;
        EdgeFit(d, value).compute(param, err, cv::noArray());
        const double rms = std::sqrt(err.dot(err) / static_cast<double>(err.rows));
        if (b > 0.5 * contrast && std::abs(d0) <= 1.0 && sigma >= 0.1 && sigma <= kHalf / 3.0 && rms <= 0.03 * b) sigmas.push_back(sigma);
    }
    if (sigmas.empty()) return out;
    std::vector<double> sorted = sigmas;
    std::nth_element(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(sorted.size() / 2), sorted.end());
    out.sigma_px = sorted[sorted.size() / 2];
    std::vector<double> deviations;
    for (double s : sigmas) deviations.push_back(std::abs(s - out.sigma_px));
    std::nth_element(deviations.begin(), deviations.begin() + static_cast<std::ptrdiff_t>(deviations.size() / 2), deviations.end());
    out.spread = 1.4826 * deviations[deviations.size() / 2];
    out.edges = static_cast<int>(sigmas.size());
    return out;
}

}  // namespace commonlight::render

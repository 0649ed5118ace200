#include "tracking/edge_profile.h"

#include "tracking/edge_profile_kernels.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <vector>

namespace commonlight::tracking {

Linearizer::Linearizer(bool srgb) {
    for (int v = 0; v < 256; ++v) {
        const double c = v / 255.0;
        lut[v] = 255.0 * (!srgb ? c : c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4));
    }
}

Linearizer::Linearizer(const std::array<float, 256>& linear_of_code) {
    for (int v = 0; v < 256; ++v) lut[v] = 255.0 * linear_of_code[static_cast<std::size_t>(v)];
}

const Linearizer& Linearizer::get(bool srgb) {
    static const Linearizer kSrgb(true), kLinear(false);
    return srgb ? kSrgb : kLinear;
}

Linearizer Linearizer::gamma(double g) {
    std::array<float, 256> linear_of_code{};
    for (int v = 0; v < 256; ++v) {
        linear_of_code[static_cast<std::size_t>(v)] = static_cast<float>(std::pow(v / 255.0, g));
    }
    return Linearizer(linear_of_code);
}

namespace {

// Whether the bilinear sample at (x, y) is inside the image (with a one-pixel margin).
bool inside(const ImageView& img, double x, double y) {
    return x >= 0.0 && y >= 0.0 && x <= img.width - 1.001 && y <= img.height - 1.001;
}

}  // namespace

std::optional<double> edgeOffset(const ImageView& img, const Linearizer& lin, const Eigen::Vector2d& p,
                                 const Eigen::Vector2d& n, const Eigen::Vector2d& along, double range) {
    constexpr double kStep = 0.25;
    const int steps = static_cast<int>(std::ceil(range / kStep));
    const int count = 2 * steps + 3;
    // Called for every boundary point of every tag in every frame: the profile lives on the stack
    // (up to 16 px each way), a longer one in a buffer kept per thread.
    constexpr int kStack = 131;
    double stack[kStack];
    thread_local std::vector<double> heap;
    if (count > kStack) heap.resize(static_cast<std::size_t>(count));
    double* const values = count > kStack ? heap.data() : stack;
    // The samples are affine in (k, a): all are inside the image when the four extreme ones are
    // (the image's sampling rectangle is convex), so the bounds are checked once per profile.
    for (const double k : {-steps - 1.0, steps + 1.0}) {
        for (const double a : {-0.5, 0.5}) {
            const Eigen::Vector2d q = p + (k * kStep) * n + a * along;
            if (!inside(img, q.x(), q.y())) return std::nullopt;
        }
    }
    // Three profiles 0.5 px apart along the edge, averaged: less noise, same edge. Four steps at
    // once where the CPU has AVX2, else two (SSE2): the same values (edge_profile_kernels.h); the
    // profile is most of the alignment's time (docs/tracking.md, "Speed (issue 13)").
    static const bool avx2 = detail::avx2Available();
    if (avx2 && img.stride * static_cast<std::size_t>(img.height) < (std::size_t{1} << 31)) {
        detail::sampleProfileAvx2(img, lin.lut, p, n, along, steps, values);
    } else {
        detail::sampleProfileSse2(img, lin.lut, p, n, along, steps, values);
    }
    // Central differences at k = -steps..steps (index i + 1 in values).
    int best = -1;
    double best_d = 0.0;
    for (int i = 0; i < 2 * steps + 1; ++i) {
        const double d = values[i + 2] - values[i];
        if (d > best_d) {
            best_d = d;
            best = i;
        }
    }
    // A real edge of a printed tag is a step of tens of grey levels; under a few is noise.
    constexpr double min_step = 3.0;
    if (best <= 0 || best >= 2 * steps || best_d < min_step * 2 * kStep) return std::nullopt;
    // The edge is where the profile crosses halfway between the dark and the bright level
    // (exact for any symmetric blur in linear light, and steadier under noise than the peak of
    // the derivative). Levels: the means of the profile from 1 px beyond the peak to the ends.
    const int peak = best + 1;  // index into values
    const int margin = static_cast<int>(1.0 / kStep);
    double dark = 0, bright = 0;
    const int dark_end = std::min(peak - margin, count - 1);  // the last dark index
    const int bright_begin = std::max(peak + margin, 0);
    for (int j = 0; j <= dark_end; ++j) dark += values[j];
    for (int j = bright_begin; j < count; ++j) bright += values[j];
    const int n_dark = std::max(dark_end + 1, 0), n_bright = std::max(count - bright_begin, 0);
    if (n_dark == 0 || n_bright == 0) return std::nullopt;
    const double mid = 0.5 * (dark / n_dark + bright / n_bright);
    // The crossing nearest the peak.
    for (int r = 0; r < margin; ++r) {
        for (const int j : {peak - r - 1, peak + r}) {
            if (j < 0 || j + 1 >= count) continue;
            const double v0 = values[j], v1 = values[j + 1];
            if (v0 <= mid && v1 > mid) {
                const double frac = (mid - v0) / (v1 - v0);
                return (j - steps - 1 + frac) * kStep;
            }
        }
    }
    return std::nullopt;
}

}  // namespace commonlight::tracking

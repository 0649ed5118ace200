#include "tracking/edge_profile.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <vector>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

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
    // Three profiles 0.5 px apart along the edge, averaged: less noise, same edge.
    const std::array<Eigen::Vector2d, 3> offsets = {-0.5 * along, 0.0 * along, 0.5 * along};
    const double* lut = lin.lut;
#if defined(__SSE2__)
    // Two steps at once (k, k + 1; the last alone in both lanes), each lane the scalar loop's
    // operations in its order (below), so the same values: the profile is most of the
    // alignment's time (docs/tracking.md, "Speed (issue 13)", pass 9).
    const std::size_t stride = img.stride;
    const __m128d px = _mm_set1_pd(p.x()), py = _mm_set1_pd(p.y()), nx = _mm_set1_pd(n.x()), ny = _mm_set1_pd(n.y());
    const __m128d one = _mm_set1_pd(1.0);
    for (int k = -steps - 1; k <= steps + 1; k += 2) {
        const int k1 = std::min(k + 1, steps + 1);
        const __m128d s = _mm_mul_pd(_mm_set_pd(k1, k), _mm_set1_pd(kStep));
        const __m128d ax = _mm_add_pd(px, _mm_mul_pd(s, nx)), ay = _mm_add_pd(py, _mm_mul_pd(s, ny));
        __m128d sum = _mm_setzero_pd();
        for (const Eigen::Vector2d& offset : offsets) {
            const __m128d qx = _mm_add_pd(ax, _mm_set1_pd(offset.x())), qy = _mm_add_pd(ay, _mm_set1_pd(offset.y()));
            const __m128i ix = _mm_cvttpd_epi32(qx), iy = _mm_cvttpd_epi32(qy);
            const __m128d fx = _mm_sub_pd(qx, _mm_cvtepi32_pd(ix)), fy = _mm_sub_pd(qy, _mm_cvtepi32_pd(iy));
            const std::uint8_t* ra = img.data + static_cast<std::size_t>(_mm_cvtsi128_si32(iy)) * stride +
                                     _mm_cvtsi128_si32(ix);
            const std::uint8_t* rb = img.data + static_cast<std::size_t>(_mm_cvtsi128_si32(_mm_shuffle_epi32(iy, 1))) * stride +
                                     _mm_cvtsi128_si32(_mm_shuffle_epi32(ix, 1));
            const __m128d v00 = _mm_loadh_pd(_mm_load_sd(lut + ra[0]), lut + rb[0]);
            const __m128d v01 = _mm_loadh_pd(_mm_load_sd(lut + ra[1]), lut + rb[1]);
            const __m128d v10 = _mm_loadh_pd(_mm_load_sd(lut + ra[stride]), lut + rb[stride]);
            const __m128d v11 = _mm_loadh_pd(_mm_load_sd(lut + ra[stride + 1]), lut + rb[stride + 1]);
            const __m128d gx = _mm_sub_pd(one, fx);
            const __m128d top = _mm_add_pd(_mm_mul_pd(gx, v00), _mm_mul_pd(fx, v01));
            const __m128d bottom = _mm_add_pd(_mm_mul_pd(gx, v10), _mm_mul_pd(fx, v11));
            sum = _mm_add_pd(sum, _mm_add_pd(_mm_mul_pd(_mm_sub_pd(one, fy), top), _mm_mul_pd(fy, bottom)));
        }
        double two[2];
        _mm_storeu_pd(two, _mm_div_pd(sum, _mm_set1_pd(3.0)));
        values[k + steps + 1] = two[0];
        if (k1 > k) values[k1 + steps + 1] = two[1];
    }
#else
    for (int k = -steps - 1; k <= steps + 1; ++k) {
        const Eigen::Vector2d across = p + (k * kStep) * n;
        double sum = 0.0;
        for (const Eigen::Vector2d& offset : offsets) {
            const Eigen::Vector2d q = across + offset;
            const int x0 = static_cast<int>(q.x()), y0 = static_cast<int>(q.y());
            const double fx = q.x() - x0, fy = q.y() - y0;
            const std::uint8_t* r0 = img.data + static_cast<std::size_t>(y0) * img.stride + x0;
            const std::uint8_t* r1 = r0 + img.stride;
            sum += (1 - fy) * ((1 - fx) * lut[r0[0]] + fx * lut[r0[1]]) + fy * ((1 - fx) * lut[r1[0]] + fx * lut[r1[1]]);
        }
        values[k + steps + 1] = sum / 3.0;
    }
#endif
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

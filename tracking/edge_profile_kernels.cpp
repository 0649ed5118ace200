#include "tracking/edge_profile_kernels.h"

#include <algorithm>
#include <array>
#include <cstdint>
#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#define COMMONLIGHT_PROFILE_X86 1
#endif

namespace commonlight::tracking::detail {

namespace {
constexpr double kStep = 0.25;  // edgeOffset's step along the normal, pixels
}  // namespace

void sampleProfilePlain(const ImageView& img, const double* lut, const Eigen::Vector2d& p, const Eigen::Vector2d& n,
                        const Eigen::Vector2d& along, int steps, double* values) {
    const std::array<Eigen::Vector2d, 3> offsets = {-0.5 * along, 0.0 * along, 0.5 * along};
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
}

void sampleProfileSse2(const ImageView& img, const double* lut, const Eigen::Vector2d& p, const Eigen::Vector2d& n,
                       const Eigen::Vector2d& along, int steps, double* values) {
#if defined(COMMONLIGHT_PROFILE_X86)
    // Two steps at once (k, k + 1; the last alone in both lanes), each lane the plain loop's
    // operations in its order, so the same values (issue 13, pass 9).
    const std::array<Eigen::Vector2d, 3> offsets = {-0.5 * along, 0.0 * along, 0.5 * along};
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
    sampleProfilePlain(img, lut, p, n, along, steps, values);
#endif
}

bool avx2Available() {
#if defined(COMMONLIGHT_PROFILE_X86)
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2");
#else
    return false;
#endif
}

#if defined(COMMONLIGHT_PROFILE_X86)
namespace {

// lut[row_i[offset]] for the four lanes' rows, as one vector (lane i from row_i).
__attribute__((target("avx2"))) inline __m256d lutOf4(const double* lut, const std::uint8_t* const rows[4],
                                                      std::size_t offset) {
    const __m128d lo = _mm_loadh_pd(_mm_load_sd(lut + rows[0][offset]), lut + rows[1][offset]);
    const __m128d hi = _mm_loadh_pd(_mm_load_sd(lut + rows[2][offset]), lut + rows[3][offset]);
    return _mm256_insertf128_pd(_mm256_castpd128_pd256(lo), hi, 1);
}

// The four lanes' pixels (r[0], r[1]) and (r[stride], r[stride + 1]) by two 32-bit gathers at
// r and r + stride (each reads r[0..3]: the caller makes sure the two bytes beyond are inside
// the image's buffer), then their lut values by four gathers: six gathers and six integer
// operations where the loads one by one take about 40 instructions (issue 13, track35), the same
// values.
struct Corners4 {
    __m256d v00, v01, v10, v11;
};

__attribute__((target("avx2"))) inline Corners4 gatherCorners(const std::uint8_t* data, const double* lut,
                                                              std::size_t stride, __m128i index) {
    // The masked forms with a defined source (GCC 12's unmasked _mm256_i32gather_pd passes an
    // undefined one and warns): every lane loaded.
    const __m128i byte = _mm_set1_epi32(0xff), all = _mm_set1_epi32(-1);
    const __m256d all_pd = _mm256_castsi256_pd(_mm256_set1_epi64x(-1)), zero = _mm256_setzero_pd();
    const __m128i top =
        _mm_mask_i32gather_epi32(_mm_setzero_si128(), reinterpret_cast<const int*>(data), index, all, 1);
    const __m128i bottom =
        _mm_mask_i32gather_epi32(_mm_setzero_si128(), reinterpret_cast<const int*>(data + stride), index, all, 1);
    return {_mm256_mask_i32gather_pd(zero, lut, _mm_and_si128(top, byte), all_pd, 8),
            _mm256_mask_i32gather_pd(zero, lut, _mm_and_si128(_mm_srli_epi32(top, 8), byte), all_pd, 8),
            _mm256_mask_i32gather_pd(zero, lut, _mm_and_si128(bottom, byte), all_pd, 8),
            _mm256_mask_i32gather_pd(zero, lut, _mm_and_si128(_mm_srli_epi32(bottom, 8), byte), all_pd, 8)};
}

// Not "fma": a fused multiply-add would round once where the plain loop rounds twice.
template <bool kGather>
__attribute__((target("avx2"))) void sampleProfileAvx2Impl(const ImageView& img, const double* lut,
                                                           const Eigen::Vector2d& p, const Eigen::Vector2d& n,
                                                           const Eigen::Vector2d& along, int steps, double* values) {
    // Four steps at once (k .. k + 3; past the last step, the last again), each lane the plain
    // loop's operations in its order. The pixel's index, row * stride + column, in 32-bit lanes
    // (the caller checks that the image's bytes fit).
    const std::array<Eigen::Vector2d, 3> offsets = {-0.5 * along, 0.0 * along, 0.5 * along};
    const std::size_t stride = img.stride;
    const __m128i stride4 = _mm_set1_epi32(static_cast<int>(stride));
    const __m256d px = _mm256_set1_pd(p.x()), py = _mm256_set1_pd(p.y());
    const __m256d nx = _mm256_set1_pd(n.x()), ny = _mm256_set1_pd(n.y());
    const __m256d one = _mm256_set1_pd(1.0);
    const int last = steps + 1;
    for (int k = -steps - 1; k <= last; k += 4) {
        const int k1 = std::min(k + 1, last), k2 = std::min(k + 2, last), k3 = std::min(k + 3, last);
        const __m256d s = _mm256_mul_pd(_mm256_set_pd(k3, k2, k1, k), _mm256_set1_pd(kStep));
        const __m256d ax = _mm256_add_pd(px, _mm256_mul_pd(s, nx)), ay = _mm256_add_pd(py, _mm256_mul_pd(s, ny));
        __m256d sum = _mm256_setzero_pd();
        for (const Eigen::Vector2d& offset : offsets) {
            const __m256d qx = _mm256_add_pd(ax, _mm256_set1_pd(offset.x()));
            const __m256d qy = _mm256_add_pd(ay, _mm256_set1_pd(offset.y()));
            const __m128i ix = _mm256_cvttpd_epi32(qx), iy = _mm256_cvttpd_epi32(qy);
            const __m256d fx = _mm256_sub_pd(qx, _mm256_cvtepi32_pd(ix));
            const __m256d fy = _mm256_sub_pd(qy, _mm256_cvtepi32_pd(iy));
            const __m128i index = _mm_add_epi32(_mm_mullo_epi32(iy, stride4), ix);
            Corners4 v;
            if constexpr (kGather) {
                v = gatherCorners(img.data, lut, stride, index);
            } else {
                const std::uint8_t* const rows[4] = {
                    img.data + static_cast<std::uint32_t>(_mm_cvtsi128_si32(index)),
                    img.data + static_cast<std::uint32_t>(_mm_extract_epi32(index, 1)),
                    img.data + static_cast<std::uint32_t>(_mm_extract_epi32(index, 2)),
                    img.data + static_cast<std::uint32_t>(_mm_extract_epi32(index, 3))};
                v = {lutOf4(lut, rows, 0), lutOf4(lut, rows, 1), lutOf4(lut, rows, stride),
                     lutOf4(lut, rows, stride + 1)};
            }
            const __m256d gx = _mm256_sub_pd(one, fx);
            const __m256d top = _mm256_add_pd(_mm256_mul_pd(gx, v.v00), _mm256_mul_pd(fx, v.v01));
            const __m256d bottom = _mm256_add_pd(_mm256_mul_pd(gx, v.v10), _mm256_mul_pd(fx, v.v11));
            sum = _mm256_add_pd(sum,
                                _mm256_add_pd(_mm256_mul_pd(_mm256_sub_pd(one, fy), top), _mm256_mul_pd(fy, bottom)));
        }
        double four[4];
        _mm256_storeu_pd(four, _mm256_div_pd(sum, _mm256_set1_pd(3.0)));
        double* const out = values + (k + steps + 1);
        out[0] = four[0];
        if (k1 > k) out[1] = four[1];
        if (k2 > k1) out[2] = four[2];
        if (k3 > k2) out[3] = four[3];
    }
}

}  // namespace

void sampleProfileAvx2(const ImageView& img, const double* lut, const Eigen::Vector2d& p, const Eigen::Vector2d& n,
                       const Eigen::Vector2d& along, int steps, double* values) {
    // The gathers read two bytes beyond each sample's right-hand pixel: inside the buffer unless
    // the sample's lower row is the image's last (its end is the buffer's). The samples are affine
    // in (k, a): the lowest is one of the four extreme ones. Clear of the last two rows (a margin
    // for the rounding of the kernel's own sums) they all are.
    double lowest = 0.0;
    for (const double k : {-steps - 1.0, steps + 1.0}) {
        for (const double a : {-0.5, 0.5}) lowest = std::max(lowest, p.y() + (k * kStep) * n.y() + a * along.y());
    }
    if (lowest < img.height - 3.0) {
        sampleProfileAvx2Impl<true>(img, lut, p, n, along, steps, values);
    } else {
        sampleProfileAvx2Impl<false>(img, lut, p, n, along, steps, values);
    }
}
#else
void sampleProfileAvx2(const ImageView& img, const double* lut, const Eigen::Vector2d& p, const Eigen::Vector2d& n,
                       const Eigen::Vector2d& along, int steps, double* values) {
    sampleProfileSse2(img, lut, p, n, along, steps, values);
}
#endif

}  // namespace commonlight::tracking::detail

// edgeOffset samples its profile two steps at a time (SSE2): it must give exactly what the plain
// scalar loop gives (the reference below is the function as it was before issue 13's pass 9),
// on random images, edges, directions and ranges, including profiles that leave the image.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <optional>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#if defined(__linux__)
#include <sys/mman.h>
#include <unistd.h>
#endif

#include "tracking/edge_profile.h"
#include "tracking/edge_profile_kernels.h"

namespace commonlight::tracking {
namespace {

std::optional<double> referenceEdgeOffset(const ImageView& img, const Linearizer& lin, const Eigen::Vector2d& p,
                                          const Eigen::Vector2d& n, const Eigen::Vector2d& along, double range) {
    constexpr double kStep = 0.25;
    const int steps = static_cast<int>(std::ceil(range / kStep));
    const int count = 2 * steps + 3;
    std::vector<double> values(static_cast<std::size_t>(count));
    const auto inside = [&](double x, double y) {
        return x >= 0.0 && y >= 0.0 && x <= img.width - 1.001 && y <= img.height - 1.001;
    };
    for (const double k : {-steps - 1.0, steps + 1.0}) {
        for (const double a : {-0.5, 0.5}) {
            const Eigen::Vector2d q = p + (k * kStep) * n + a * along;
            if (!inside(q.x(), q.y())) return std::nullopt;
        }
    }
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
            sum += (1 - fy) * ((1 - fx) * lin.lut[r0[0]] + fx * lin.lut[r0[1]]) +
                   fy * ((1 - fx) * lin.lut[r1[0]] + fx * lin.lut[r1[1]]);
        }
        values[static_cast<std::size_t>(k + steps + 1)] = sum / 3.0;
    }
    int best = -1;
    double best_d = 0.0;
    for (int i = 0; i < 2 * steps + 1; ++i) {
        const double d = values[static_cast<std::size_t>(i + 2)] - values[static_cast<std::size_t>(i)];
        if (d > best_d) best_d = d, best = i;
    }
    if (best <= 0 || best >= 2 * steps || best_d < 3.0 * 2 * kStep) return std::nullopt;
    const int peak = best + 1, margin = 4;
    double dark = 0, bright = 0;
    const int dark_end = std::min(peak - margin, count - 1), bright_begin = std::max(peak + margin, 0);
    for (int j = 0; j <= dark_end; ++j) dark += values[static_cast<std::size_t>(j)];
    for (int j = bright_begin; j < count; ++j) bright += values[static_cast<std::size_t>(j)];
    const int n_dark = std::max(dark_end + 1, 0), n_bright = std::max(count - bright_begin, 0);
    if (n_dark == 0 || n_bright == 0) return std::nullopt;
    const double mid = 0.5 * (dark / n_dark + bright / n_bright);
    for (int r = 0; r < margin; ++r) {
        for (const int j : {peak - r - 1, peak + r}) {
            if (j < 0 || j + 1 >= count) continue;
            const double v0 = values[static_cast<std::size_t>(j)], v1 = values[static_cast<std::size_t>(j + 1)];
            if (v0 <= mid && v1 > mid) return (j - steps - 1 + (mid - v0) / (v1 - v0)) * kStep;
        }
    }
    return std::nullopt;
}

TEST(EdgeProfile, VectorizedSamplingGivesTheScalarLoopsOffsets) {
    std::mt19937 rng(13);
    std::uniform_real_distribution<double> uni(0.0, 1.0);
    constexpr int kW = 61, kH = 47;
    std::vector<std::uint8_t> pixels(static_cast<std::size_t>(kW * kH));
    const ImageView img{PixelFormat::kGray8, kW, kH, kW, pixels.data(), pixels.size()};
    int found = 0, refused = 0, outside = 0;
    for (int image = 0; image < 40; ++image) {
        // A blurred straight edge (dark 20-60, bright 150-250) plus noise; every tenth image flat.
        const double angle = 2 * M_PI * uni(rng), offset = 10 + 27 * uni(rng), blur = 0.3 + 1.5 * uni(rng);
        const double dark = 20 + 40 * uni(rng), bright = 150 + 100 * uni(rng), noise = 4 * uni(rng);
        const Eigen::Vector2d normal(std::cos(angle), std::sin(angle));
        for (int y = 0; y < kH; ++y) {
            for (int x = 0; x < kW; ++x) {
                const double s = normal.dot(Eigen::Vector2d(x - 30.0, y - 23.0)) + 30.0 - offset;
                const double v = image % 10 == 9 ? 100.0
                                                 : dark + (bright - dark) * 0.5 * (1 + std::erf(s / (blur * std::sqrt(2.0)))) +
                                                       noise * (uni(rng) - 0.5);
                pixels[static_cast<std::size_t>(y * kW + x)] = static_cast<std::uint8_t>(std::clamp(std::lround(v), 0L, 255L));
            }
        }
        for (const bool srgb : {true, false}) {
            const Linearizer& lin = Linearizer::get(srgb);
            for (int trial = 0; trial < 50; ++trial) {
                // Points near the edge (and some anywhere, some near the border), the normal
                // within 30 degrees of the true one, ranges of 1 to 7 px.
                const double a = angle + (uni(rng) - 0.5) * 1.0;
                const Eigen::Vector2d n(std::cos(a), std::sin(a)), along(-n.y(), n.x());
                Eigen::Vector2d p(kW * uni(rng), kH * uni(rng));
                if (trial % 4 != 0) p += (offset - 30.0 - normal.dot(p - Eigen::Vector2d(30.0, 23.0)) + uni(rng) - 0.5) * normal;
                const double range = 1.0 + 6.0 * uni(rng);
                const auto got = edgeOffset(img, lin, p, n, along, range);
                const auto want = referenceEdgeOffset(img, lin, p, n, along, range);
                ASSERT_EQ(got.has_value(), want.has_value()) << "image " << image << " trial " << trial;
                if (want) {
                    ASSERT_EQ(*got, *want) << "image " << image << " trial " << trial;  // bit for bit
                    ++found;
                } else {
                    ++refused;
                }
                const Eigen::Vector2d far = p + (std::ceil(range / 0.25) + 1) * 0.25 * n;
                if (far.x() < 0 || far.y() < 0 || far.x() > kW - 1.001 || far.y() > kH - 1.001) ++outside;
            }
        }
    }
    // The comparison covered both outcomes and profiles that leave the image.
    EXPECT_GT(found, 1000);
    EXPECT_GT(refused, 300);
    EXPECT_GT(outside, 50);
}

// Each sampling kernel (SSE2, and AVX2 where the CPU has it: edgeOffset takes that one) gives the
// plain loop's values bit for bit, for every profile length (the last vector's lanes past the
// profile's end written nowhere), on random images, points and directions.
TEST(EdgeProfile, EveryKernelGivesThePlainLoopsValues) {
    std::mt19937 rng(29);
    std::uniform_real_distribution<double> uni(0.0, 1.0);
    constexpr int kW = 97, kH = 71, kStride = 101;
    std::vector<std::uint8_t> pixels(static_cast<std::size_t>(kStride * kH));
    for (std::uint8_t& v : pixels) v = static_cast<std::uint8_t>(rng() & 0xff);
    const ImageView img{PixelFormat::kGray8, kW, kH, kStride, pixels.data(), pixels.size()};
    const Linearizer& lin = Linearizer::get(true);
    std::printf("  AVX2 kernel %s\n", detail::avx2Available() ? "tested" : "not available on this CPU");
    int compared = 0;
    for (int trial = 0; trial < 2000; ++trial) {
        const int steps = 1 + trial % 27;
        const double a = 2 * M_PI * uni(rng);
        const Eigen::Vector2d n(std::cos(a), std::sin(a)), along(-n.y(), n.x());
        const double reach = (steps + 1) * 0.25 + 1.0;
        const Eigen::Vector2d p(reach + (kW - 1.001 - 2 * reach) * uni(rng), reach + (kH - 1.001 - 2 * reach) * uni(rng));
        const std::size_t count = static_cast<std::size_t>(2 * steps + 3);
        constexpr double kUnset = -12345.0;
        std::vector<double> plain(count + 4, kUnset), sse2(count + 4, kUnset), avx2(count + 4, kUnset);
        detail::sampleProfilePlain(img, lin.lut, p, n, along, steps, plain.data());
        detail::sampleProfileSse2(img, lin.lut, p, n, along, steps, sse2.data());
        if (detail::avx2Available()) {
            detail::sampleProfileAvx2(img, lin.lut, p, n, along, steps, avx2.data());
        } else {
            avx2 = plain;
        }
        for (std::size_t i = 0; i < count + 4; ++i) {
            ASSERT_EQ(sse2[i], plain[i]) << "trial " << trial << " steps " << steps << " index " << i;
            ASSERT_EQ(avx2[i], plain[i]) << "trial " << trial << " steps " << steps << " index " << i;
            if (i >= count) {
                ASSERT_EQ(plain[i], kUnset);
            }
        }
        compared += static_cast<int>(count);
    }
    EXPECT_GT(compared, 50000);
}

#if defined(__linux__)
// The AVX2 kernel reads each sample's two pixels per row by a 4-byte gather, two bytes beyond
// them: it must not do so where that leaves the buffer. An image whose last byte is the last one
// before an unreadable page, profiles reaching its bottom-right pixels: the kernel gives the
// plain loop's values and reads nothing beyond (a read there ends the test with SIGSEGV).
TEST(EdgeProfile, AvxKernelReadsNothingBeyondTheImage) {
    if (!detail::avx2Available()) GTEST_SKIP() << "no AVX2 on this CPU";
    const auto page = static_cast<std::size_t>(sysconf(_SC_PAGESIZE));
    constexpr int kW = 64, kH = 48;  // stride = width: the last row ends the buffer
    const std::size_t bytes = static_cast<std::size_t>(kW * kH), pages = (bytes + page - 1) / page + 1;
    void* const map = mmap(nullptr, pages * page, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    ASSERT_NE(map, MAP_FAILED);
    auto* const guard = static_cast<std::uint8_t*>(map) + (pages - 1) * page;
    ASSERT_EQ(mprotect(guard, page, PROT_NONE), 0);
    std::uint8_t* const pixels = guard - bytes;
    std::mt19937 rng(41);
    for (std::size_t i = 0; i < bytes; ++i) pixels[i] = static_cast<std::uint8_t>(rng() & 0xff);
    const ImageView img{PixelFormat::kGray8, kW, kH, kW, pixels, bytes};
    const Linearizer& lin = Linearizer::get(true);
    std::uniform_real_distribution<double> uni(0.0, 1.0);
    int last_pixels = 0, compared = 0;
    for (int trial = 0; trial < 10000; ++trial) {
        const int steps = 1 + trial % 6;
        const double a = 2 * M_PI * uni(rng);
        const Eigen::Vector2d n(std::cos(a), std::sin(a)), along(-n.y(), n.x());
        // Centres within a few pixels of the bottom-right corner; profiles that leave the image
        // are skipped, as edgeOffset skips them.
        const Eigen::Vector2d p(kW - 1.001 - 4.0 * uni(rng), kH - 1.001 - 4.0 * uni(rng));
        bool inside = true, reaches = false;
        for (const double k : {-steps - 1.0, steps + 1.0}) {
            for (const double o : {-0.5, 0.5}) {
                const Eigen::Vector2d q = p + (k * 0.25) * n + o * along;
                inside = inside && q.x() >= 0 && q.y() >= 0 && q.x() <= kW - 1.001 && q.y() <= kH - 1.001;
                reaches = reaches || (q.x() >= kW - 2 && q.y() >= kH - 2);
            }
        }
        if (!inside) continue;
        last_pixels += reaches ? 1 : 0;
        const std::size_t count = static_cast<std::size_t>(2 * steps + 3);
        std::vector<double> plain(count), avx2(count);
        detail::sampleProfilePlain(img, lin.lut, p, n, along, steps, plain.data());
        detail::sampleProfileAvx2(img, lin.lut, p, n, along, steps, avx2.data());
        for (std::size_t i = 0; i < count; ++i) ASSERT_EQ(avx2[i], plain[i]) << "trial " << trial << " index " << i;
        ++compared;
    }
    std::printf("  %d profiles compared, %d of them reach the last two pixels\n", compared, last_pixels);
    munmap(map, pages * page);
    EXPECT_GT(compared, 1000);
    EXPECT_GT(last_pixels, 200);  // profiles whose samples use the last row's last two pixels
}
#endif

}  // namespace
}  // namespace commonlight::tracking

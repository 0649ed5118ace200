#include "mocks/sim/sampling.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <numbers>

namespace commonlight::mocks::sim {

std::uint64_t mixBits(std::uint64_t x) noexcept {
    // Each step is invertible (xor with a right shift of itself, multiplication by an odd number).
    x ^= x >> 31;
    x *= 0x7fb5d329728ea185ULL;
    x ^= x >> 27;
    x *= 0x81dadef4bc2dd44dULL;
    x ^= x >> 33;
    return x;
}

std::uint64_t hashCombine(std::uint64_t a, std::uint64_t b) noexcept {
    return mixBits(a ^ (mixBits(b) + 0x9e3779b97f4a7c15ULL + (a << 6) + (a >> 2)));
}

std::uint32_t permuteIndex(std::uint32_t index, std::uint32_t n, std::uint64_t key) noexcept {
    if (n <= 1) return 0;
    // Smallest all-ones mask covering n - 1: the hash below is a bijection of [0, mask].
    const std::uint32_t mask = static_cast<std::uint32_t>((std::uint64_t{1} << std::bit_width(n - 1)) - 1);
    const auto k0 = static_cast<std::uint32_t>(key);
    const auto k1 = static_cast<std::uint32_t>(key >> 32) | 1u;  // odd multiplier
    std::uint32_t x = index;
    // Cycle walking: the orbit of a value < n under a bijection of [0, mask] returns below n, so
    // the restriction is a bijection of [0, n). Fewer than two rounds on average (n > mask / 2).
    do {
        x ^= k0;
        x &= mask;
        x *= k1;
        x &= mask;
        x ^= (x & mask) >> 3;
        x += k0 >> 7;
        x &= mask;
        x *= 0x2c1b3c6du;
        x &= mask;
        x ^= x >> 5;
    } while (x >= n);
    return x;
}

double radicalInverse2(std::uint32_t index) noexcept {
    std::uint32_t bits = index;
    bits = (bits << 16) | (bits >> 16);
    bits = ((bits & 0x00ff00ffu) << 8) | ((bits & 0xff00ff00u) >> 8);
    bits = ((bits & 0x0f0f0f0fu) << 4) | ((bits & 0xf0f0f0f0u) >> 4);
    bits = ((bits & 0x33333333u) << 2) | ((bits & 0xccccccccu) >> 2);
    bits = ((bits & 0x55555555u) << 1) | ((bits & 0xaaaaaaaau) >> 1);
    return static_cast<double>(bits) * (1.0 / 4294967296.0);
}

PixelSampler::PixelSampler(std::uint64_t pixel_seed, int samples_per_pixel) noexcept
    : seed_(pixel_seed), count_(static_cast<std::uint32_t>(std::max(samples_per_pixel, 1))) {}

std::uint64_t PixelSampler::pixelSeed(std::uint64_t seed, std::uint64_t frame, std::uint64_t pixel_index) noexcept {
    return hashCombine(hashCombine(mixBits(seed + 0x51ed270b27a3c4f1ULL), frame), pixel_index);
}

namespace {

// Wraps a shifted coordinate back into [0, 1). Hard case: 1 - epsilon + shift can round to
// exactly 1.0 or 2.0; the result must stay below 1.
double wrapUnit(double x) noexcept {
    x -= std::floor(x);
    return x < 1.0 ? x : std::nextafter(1.0, 0.0);
}

}  // namespace

Eigen::Vector2d PixelSampler::get2D(int sample_index, int dimension) const noexcept {
    const std::uint64_t dim_key = hashCombine(seed_, static_cast<std::uint64_t>(dimension));
    const std::uint32_t j = permuteIndex(static_cast<std::uint32_t>(sample_index), count_, dim_key);
    const std::uint64_t shift_bits = mixBits(dim_key ^ 0xd6e8feb86659fd93ULL);
    const double shift_x = toUnitDouble(shift_bits);
    const double shift_y = toUnitDouble(mixBits(shift_bits));
    const double x = static_cast<double>(j) / static_cast<double>(count_);
    // For N = 1 the shifted point is a plain uniform random point; for N > 1 the N points of a
    // dimension are a toroidally shifted Hammersley set, stratified in both coordinates.
    const double y = radicalInverse2(j);
    return {wrapUnit(x + shift_x), wrapUnit(y + shift_y)};
}

double PixelSampler::get1D(int sample_index, int dimension) const noexcept {
    return get2D(sample_index, dimension).x();
}

Eigen::Vector2d concentricDisc(const Eigen::Vector2d& u) noexcept {
    const double a = 2.0 * u.x() - 1.0;
    const double b = 2.0 * u.y() - 1.0;
    // Hard case: the centre maps to itself (the angle below would divide by zero).
    if (a == 0.0 && b == 0.0) return Eigen::Vector2d::Zero();
    constexpr double kQuarterPi = std::numbers::pi / 4.0;
    double r;
    double phi;
    if (std::abs(a) > std::abs(b)) {
        r = a;
        phi = kQuarterPi * (b / a);
    } else {
        r = b;
        phi = 2.0 * kQuarterPi - kQuarterPi * (a / b);
    }
    return {r * std::cos(phi), r * std::sin(phi)};
}

Eigen::Vector3d cosineHemisphere(const Eigen::Vector2d& u) noexcept {
    const Eigen::Vector2d d = concentricDisc(u);
    // Hard case: rounding can push x^2 + y^2 a hair above 1.
    const double z = std::sqrt(std::max(0.0, 1.0 - d.squaredNorm()));
    return {d.x(), d.y(), z};
}

ShadingFrame ShadingFrame::fromNormal(const Eigen::Vector3d& n) noexcept {
    const double sign = std::copysign(1.0, n.z());
    const double a = -1.0 / (sign + n.z());  // |sign + n.z| >= 1: no division by zero
    const double b = n.x() * n.y() * a;
    ShadingFrame frame;
    frame.t = Eigen::Vector3d(1.0 + sign * n.x() * n.x() * a, sign * b, -sign * n.x());
    frame.b = Eigen::Vector3d(b, sign + n.y() * n.y() * a, -n.y());
    frame.n = n;
    return frame;
}

double powerHeuristic(double pdf_a, double pdf_b) noexcept {
    const double a2 = pdf_a * pdf_a;
    const double b2 = pdf_b * pdf_b;
    const double sum = a2 + b2;
    return sum > 0.0 ? a2 / sum : 0.0;
}

}  // namespace commonlight::mocks::sim

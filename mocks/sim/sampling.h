// Random numbers for the path tracer: a hash-seeded, per-pixel low-discrepancy sampler and the
// warps from the unit square to the domains the integrator samples (hemisphere, disc).
//
// Determinism: every value depends only on (seed, frame, pixel index, sample index, dimension),
// never on which thread computes it or in which order, so a render is the same bytes for the same
// seed whatever the number of threads.
#pragma once

#include <cstdint>

#include <Eigen/Core>

namespace commonlight::mocks::sim {

// A 64-bit finaliser (xor-shift-multiply): a bijection that spreads every input bit over the output.
std::uint64_t mixBits(std::uint64_t x) noexcept;
// Hash of an ordered pair, for deriving independent seeds from (seed, frame, pixel, ...).
std::uint64_t hashCombine(std::uint64_t a, std::uint64_t b) noexcept;

// A uniform double in [0, 1) from the top 53 bits of a 64-bit value.
inline double toUnitDouble(std::uint64_t bits) noexcept {
    return static_cast<double>(bits >> 11) * (1.0 / 9007199254740992.0);
}

// A bijection of [0, n) chosen by `key` (cycle-walking an invertible hash on the next power of two).
std::uint32_t permuteIndex(std::uint32_t index, std::uint32_t n, std::uint64_t key) noexcept;
// Van der Corput radical inverse in base 2: the bits of `index` mirrored behind the binary point.
double radicalInverse2(std::uint32_t index) noexcept;

// Sample points for the `samples_per_pixel` samples of one pixel (or one irradiance probe).
//
// Each dimension d (an index the integrator assigns to one decision: pixel jitter, the light
// sample at bounce 2, ...) gets the 2D Hammersley set of `samples_per_pixel` points
// (j / N, radicalInverse2(j)), with the sample indices permuted and the set shifted toroidally
// (Cranley-Patterson) by hashes of (pixel seed, d). So across the N samples of a pixel every
// dimension is stratified, while different dimensions are decorrelated. 1D values are the first
// coordinate: a jittered stratification of [0, 1).
class PixelSampler {
public:
    // `pixel_seed` identifies the pixel (see pixelSeed); samples_per_pixel >= 1.
    PixelSampler(std::uint64_t pixel_seed, int samples_per_pixel) noexcept;

    // The seed of a pixel: depends only on the render seed, the frame and the pixel index.
    static std::uint64_t pixelSeed(std::uint64_t seed, std::uint64_t frame, std::uint64_t pixel_index) noexcept;

    // Values in [0, 1) for sample `sample_index` (0 <= sample_index < samples_per_pixel) in
    // dimension `dimension`.
    Eigen::Vector2d get2D(int sample_index, int dimension) const noexcept;
    double get1D(int sample_index, int dimension) const noexcept;

    int samplesPerPixel() const noexcept { return static_cast<int>(count_); }

private:
    std::uint64_t seed_;
    std::uint32_t count_;
};

// Maps the unit square to the unit disc, area-preserving (Shirley-Chiu concentric mapping).
Eigen::Vector2d concentricDisc(const Eigen::Vector2d& u) noexcept;
// Cosine-weighted direction on the hemisphere z > 0 (local frame); its pdf is cos(theta) / pi.
Eigen::Vector3d cosineHemisphere(const Eigen::Vector2d& u) noexcept;

// An orthonormal frame around a unit normal n (z axis of the local frame).
struct ShadingFrame {
    Eigen::Vector3d t;  // tangent
    Eigen::Vector3d b;  // bitangent
    Eigen::Vector3d n;  // normal

    // Any frame with n as its z axis; n must be unit length. Continuous everywhere except the
    // branch at n.z = 0 (Duff et al.'s construction, rewritten here).
    static ShadingFrame fromNormal(const Eigen::Vector3d& n) noexcept;
    Eigen::Vector3d toLocal(const Eigen::Vector3d& v) const noexcept { return {v.dot(t), v.dot(b), v.dot(n)}; }
    Eigen::Vector3d toWorld(const Eigen::Vector3d& v) const noexcept { return v.x() * t + v.y() * b + v.z() * n; }
};

// Veach's power heuristic (beta = 2) weight of technique a, one sample from each technique.
// Hard case: both pdfs zero (or underflowing to zero when squared) gives 0, not NaN.
double powerHeuristic(double pdf_a, double pdf_b) noexcept;

}  // namespace commonlight::mocks::sim

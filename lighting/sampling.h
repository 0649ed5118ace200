// Deterministic sample numbers: a hash of (stream, index) instead of a random generator's state,
// so a sample depends on nothing else and results are the same for any number of threads and any
// scheduling (the lighting thread's --sync output is bit-identical run to run).
#pragma once

#include <cstdint>

#include <Eigen/Core>

namespace commonlight::lighting {

// PCG-style 64-bit integer hash (Jarzynski and Olano 2020's pcg3d idea, one dimension).
inline std::uint64_t hash64(std::uint64_t x) {
    x ^= x >> 33;
    x *= 0xff51afd7ed558ccdull;
    x ^= x >> 33;
    x *= 0xc4ceb9fe1a85ec53ull;
    x ^= x >> 33;
    return x;
}

inline std::uint64_t hashCombine(std::uint64_t a, std::uint64_t b) { return hash64(a ^ (hash64(b) + 0x9e3779b97f4a7c15ull)); }

// Uniform in [0, 1) from a hash.
inline double unitFromHash(std::uint64_t h) { return static_cast<double>(h >> 11) * 0x1.0p-53; }

// Sample k of n stratified over [0,1)^2 (an m x m grid, m = ceil(sqrt(n)), jittered within its
// cell), for stream `seed`.
inline Eigen::Vector2d stratified2d(std::uint64_t seed, int k, int n) {
    int m = 1;
    while (m * m < n) ++m;
    const int i = k % m, j = (k / m) % m;
    const std::uint64_t h = hashCombine(seed, static_cast<std::uint64_t>(k));
    return {(i + unitFromHash(h)) / m, (j + unitFromHash(hash64(h))) / m};
}

}  // namespace commonlight::lighting

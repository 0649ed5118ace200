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
// The grid's side m for n samples (stratified2d()).
inline int stratifiedSide(int n) {
    int m = 1;
    while (m * m < n) ++m;
    return m;
}
// stratified2d(seed, k, n) with its grid's side m = stratifiedSide(n) given (many samples of one n).
inline Eigen::Vector2d stratified2dOnSide(std::uint64_t seed, int k, int m) {
    const int i = k % m, j = (k / m) % m;
    const std::uint64_t h = hashCombine(seed, static_cast<std::uint64_t>(k));
    return {(i + unitFromHash(h)) / m, (j + unitFromHash(hash64(h))) / m};
}
inline Eigen::Vector2d stratified2d(std::uint64_t seed, int k, int n) { return stratified2dOnSide(seed, k, stratifiedSide(n)); }

// Image of k under a pseudo-random permutation of [0, n) keyed by `seed` (n <= 2^20): a bijection
// of [0, 2^b) (b the bits of n; rounds of xor with a key, multiplication by an odd key and a right
// xorshift, each invertible modulo 2^b), applied again until the value lands below n (cycle
// walking keeps it a bijection of [0, n)).
inline int permuted(int k, int n, std::uint64_t seed) {
    if (n <= 1) return 0;
    int bits = 1;
    while ((1 << bits) < n) ++bits;
    const std::uint64_t mask = (std::uint64_t{1} << bits) - 1;
    const int shift = (bits + 1) / 2;
    std::uint64_t x = static_cast<std::uint64_t>(k) & mask;
    do {
        std::uint64_t key = seed;
        for (int round = 0; round < 3; ++round) {
            key = hash64(key + static_cast<std::uint64_t>(round));
            x = (x ^ key) & mask;
            x = (x * ((key >> 24) | 1u)) & mask;
            x ^= x >> shift;
        }
    } while (x >= static_cast<std::uint64_t>(n));
    return static_cast<int>(x);
}

// Pair k of n for a visibility estimate between two surfaces: each end stratified over [0,1)^2
// on its own, the strata of the two ends paired by a pseudo-random permutation (the padded 2D
// samples of pbrt's stratified sampler). A fixed pairing such as k -> (7k + 3) mod n ties the
// strata of one end to those of the other (with n = 16: the first axis exactly reversed), and a
// shadow cast along that axis goes unseen: measured on the room, a floor element 26% in the
// chair's shadow read as fully lit.
struct SamplePair {
    Eigen::Vector2d first;
    Eigen::Vector2d second;
};
inline SamplePair stratifiedPair(std::uint64_t seed, int k, int n) {
    return {stratified2d(seed, k, n), stratified2d(hash64(seed), permuted(k, n, hash64(seed ^ 0x2545f4914f6cdd1dull)), n)};
}

}  // namespace commonlight::lighting

#include "core/percentiles.h"

#include <algorithm>
#include <cassert>
#include <cmath>

namespace commonlight {

double nearestRank(const std::vector<double>& sorted, double p) noexcept {
    if (sorted.empty()) return 0.0;
    const double n = static_cast<double>(sorted.size());
    // rank = ceil(p/100 * n), clamped to [1, n]. The small epsilon keeps 95% of 20 at rank 19
    // despite rounding in p / 100 * n.
    const double rank = std::ceil(p / 100.0 * n - 1e-9);
    const auto index = static_cast<std::size_t>(std::clamp(rank, 1.0, n)) - 1;
    return sorted[index];
}

SampleReservoir::SampleReservoir(std::size_t capacity, std::uint64_t seed) : seed_(seed), state_(seed) {
    assert(capacity > 0);
    samples_.reserve(capacity);
}

std::uint64_t SampleReservoir::nextRandom() noexcept {
    // SplitMix64: small, fast, and good enough to pick reservoir slots.
    std::uint64_t z = (state_ += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

void SampleReservoir::add(double value) noexcept {
    max_ = count_ == 0 ? value : std::max(max_, value);
    ++count_;
    if (samples_.size() < samples_.capacity()) {
        samples_.push_back(value);  // within the reserved capacity: no allocation
        return;
    }
    // Algorithm R: the count_-th sample replaces a kept one with probability capacity / count_.
    const std::uint64_t j = nextRandom() % count_;
    if (j < samples_.size()) samples_[static_cast<std::size_t>(j)] = value;
}

void SampleReservoir::clear() noexcept {
    samples_.clear();
    count_ = 0;
    max_ = 0.0;
    state_ = seed_;
}

Percentiles SampleReservoir::percentiles() const {
    Percentiles out;
    out.count = count_;
    if (count_ == 0) return out;
    std::vector<double> sorted = samples_;
    std::sort(sorted.begin(), sorted.end());
    out.p50 = nearestRank(sorted, 50.0);
    out.p95 = nearestRank(sorted, 95.0);
    out.max = max_;
    return out;
}

}  // namespace commonlight

// Percentiles of a stream of samples, from a fixed-capacity buffer allocated up front.
//
// Up to `capacity` samples are kept exactly; beyond that the buffer is a uniform random sample
// of everything added (reservoir sampling, Algorithm R) driven by a fixed-seed generator, so the
// same input always gives the same percentiles. The maximum is exact whatever the count.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace commonlight {

// p50 / p95 / max of a set of samples, in the samples' unit (milliseconds throughout capture, lighting and
// in the app's metrics JSON: "stages_ms", "latency_ms"). All zero when there were no samples.
struct Percentiles {
    double p50 = 0.0;
    double p95 = 0.0;
    double max = 0.0;
    std::uint64_t count = 0;  // samples added (not only those kept)
};

// The nearest-rank percentile (p in [0, 100]) of sorted values: the smallest value with at least
// p% of the values at or below it. 0 for an empty set.
double nearestRank(const std::vector<double>& sorted, double p) noexcept;

class SampleReservoir {
public:
    static constexpr std::size_t kDefaultCapacity = 4096;

    explicit SampleReservoir(std::size_t capacity = kDefaultCapacity, std::uint64_t seed = 0x9E3779B97F4A7C15ull);

    // Never allocates.
    void add(double value) noexcept;
    void clear() noexcept;

    std::uint64_t count() const noexcept { return count_; }
    std::size_t capacity() const noexcept { return samples_.capacity(); }
    // Sorts a copy of the kept samples (allocates: call it for a report, not per sample).
    Percentiles percentiles() const;

private:
    std::uint64_t nextRandom() noexcept;

    std::vector<double> samples_;  // capacity fixed in the constructor
    std::uint64_t count_ = 0;
    double max_ = 0.0;
    std::uint64_t seed_;
    std::uint64_t state_;
};

}  // namespace commonlight

// Per-stage timings of a pipeline ("capture", "convert", "detect", ...): p50 / p95 / max in ms.
//
// Stages are registered up front, by name, in the constructor; the hot path records by a small
// integer id, never by name, and never allocates (each stage keeps a SampleReservoir). Thread
// safe: stages may be recorded from several threads (a short internal lock).
//
//   StageTimings timings({"capture", "convert", "track"});
//   const auto convert = timings.id("convert");
//   { StageTimer timer(timings, convert); converter.convert(...); }   // records on scope exit
#pragma once

#include <cstddef>
#include <cstdint>
#include <initializer_list>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "core/percentiles.h"
#include "core/clock.h"

namespace commonlight::capture {

class StageTimings {
public:
    using StageId = std::size_t;

    struct Stage {
        std::string name;
        Percentiles ms;
    };

    // Names must be unique and non-empty (asserted).
    explicit StageTimings(std::initializer_list<std::string_view> names,
                          std::size_t samples_per_stage = SampleReservoir::kDefaultCapacity);
    explicit StageTimings(std::span<const std::string> names,
                          std::size_t samples_per_stage = SampleReservoir::kDefaultCapacity);
    StageTimings(const StageTimings&) = delete;
    StageTimings& operator=(const StageTimings&) = delete;

    std::size_t size() const noexcept { return names_.size(); }
    // The id of a registered stage; std::nullopt for a name never registered.
    std::optional<StageId> find(std::string_view name) const noexcept;
    // The id of a registered stage (asserts that it is registered).
    StageId id(std::string_view name) const noexcept;
    const std::string& name(StageId stage) const noexcept { return names_[stage]; }

    // Any thread; never allocates.
    void add(StageId stage, double ms) noexcept;
    void addNs(StageId stage, std::int64_t ns) noexcept { add(stage, static_cast<double>(ns) / 1e6); }

    // Every stage in registration order (allocates: for reports).
    std::vector<Stage> summary() const;
    Percentiles percentiles(StageId stage) const;
    void clear() noexcept;

private:
    void init(std::size_t samples_per_stage);

    std::vector<std::string> names_;
    mutable std::mutex mutex_;
    std::vector<SampleReservoir> samples_;  // one per stage
};

// Times one run of a stage on a clock: from construction to stop() or destruction. Lives on one
// thread. The timings and the clock are borrowed and must outlive the timer.
class StageTimer {
public:
    StageTimer(StageTimings& timings, StageTimings::StageId stage, const Clock& clock = SteadyClock::instance())
        : timings_(&timings), clock_(&clock), stage_(stage), start_ns_(clock.nowNs()) {}
    ~StageTimer() { stop(); }
    StageTimer(const StageTimer&) = delete;
    StageTimer& operator=(const StageTimer&) = delete;

    // Records the elapsed time (once) and returns it in ms; later calls return 0 and record nothing.
    double stop() noexcept;

private:
    StageTimings* timings_;
    const Clock* clock_;
    StageTimings::StageId stage_;
    std::int64_t start_ns_;
    bool stopped_ = false;
};

}  // namespace commonlight::capture

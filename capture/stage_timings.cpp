#include "capture/stage_timings.h"

#include <algorithm>
#include <cassert>

namespace commonlight::capture {

StageTimings::StageTimings(std::initializer_list<std::string_view> names, std::size_t samples_per_stage)
    : names_(names.begin(), names.end()) {
    init(samples_per_stage);
}

StageTimings::StageTimings(std::span<const std::string> names, std::size_t samples_per_stage)
    : names_(names.begin(), names.end()) {
    init(samples_per_stage);
}

void StageTimings::init(std::size_t samples_per_stage) {
    for (std::size_t i = 0; i < names_.size(); ++i) {
        assert(!names_[i].empty() && "a stage needs a name");
        assert(std::find(names_.begin(), names_.begin() + static_cast<std::ptrdiff_t>(i), names_[i]) ==
                   names_.begin() + static_cast<std::ptrdiff_t>(i) &&
               "stage registered twice");
    }
    samples_.reserve(names_.size());
    for (std::size_t i = 0; i < names_.size(); ++i) samples_.emplace_back(samples_per_stage);
}

std::optional<StageTimings::StageId> StageTimings::find(std::string_view name) const noexcept {
    const auto it = std::find(names_.begin(), names_.end(), name);
    if (it == names_.end()) return std::nullopt;
    return static_cast<StageId>(it - names_.begin());
}

StageTimings::StageId StageTimings::id(std::string_view name) const noexcept {
    const auto found = find(name);
    assert(found && "stage not registered");
    return found.value_or(0);
}

void StageTimings::add(StageId stage, double ms) noexcept {
    assert(stage < samples_.size());
    std::lock_guard lock(mutex_);
    samples_[stage].add(ms);
}

std::vector<StageTimings::Stage> StageTimings::summary() const {
    std::vector<Stage> out;
    out.reserve(names_.size());
    std::lock_guard lock(mutex_);
    for (std::size_t i = 0; i < names_.size(); ++i) out.push_back({names_[i], samples_[i].percentiles()});
    return out;
}

Percentiles StageTimings::percentiles(StageId stage) const {
    assert(stage < samples_.size());
    std::lock_guard lock(mutex_);
    return samples_[stage].percentiles();
}

void StageTimings::clear() noexcept {
    std::lock_guard lock(mutex_);
    for (auto& s : samples_) s.clear();
}

double StageTimer::stop() noexcept {
    if (stopped_) return 0.0;
    stopped_ = true;
    const double ms = static_cast<double>(clock_->nowNs() - start_ns_) / 1e6;
    timings_->add(stage_, ms);
    return ms;
}

}  // namespace commonlight::capture

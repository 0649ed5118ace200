#include "pipeline/quality_governor.h"

#include <algorithm>
#include <cmath>

namespace commonlight::pipeline {

QualityGovernor::QualityGovernor(const render::CompositorOptions& configured) {
    Level level{std::max(1, configured.msaa_samples), std::max(1, configured.area_light_samples)};
    levels_.push_back(level);
    if (level.msaa_samples > 1) {
        level.msaa_samples = 1;
        levels_.push_back(level);
    }
    if (level.area_light_samples > 1) {
        level.area_light_samples = std::max(1, level.area_light_samples / 2);
        levels_.push_back(level);
    }
    frames_at_.assign(levels_.size(), 0);
}

bool QualityGovernor::step(double composite_ns, double period_ns) {
    ++frames_at_[static_cast<std::size_t>(level_)];
    // Hard case: no period yet (the first frame) or a nonsense time: nothing to judge by.
    if (!(period_ns > 0.0) || !std::isfinite(composite_ns) || composite_ns < 0.0) return false;
    const double load = composite_ns / period_ns;
    load_ = load_ > 0.0 ? 0.8 * load_ + 0.2 * load : load;
    frames_heavy_ = load_ > kStepDownLoad ? frames_heavy_ + 1 : 0;
    frames_light_ = load_ < kStepUpLoad ? frames_light_ + 1 : 0;
    int next = level_;
    if (frames_heavy_ >= kStepDownFrames && level_ + 1 < static_cast<int>(levels_.size())) {
        next = level_ + 1;
    } else if (frames_light_ >= kStepUpFrames && level_ > 0) {
        next = level_ - 1;
    }
    if (next == level_) return false;
    level_ = next;
    frames_heavy_ = 0;
    frames_light_ = 0;
    ++changes_;
    return true;
}

int QualityGovernor::startAt(const std::vector<double>& draw_ns, double period_ns) {
    if (!(period_ns > 0.0) || !std::isfinite(period_ns)) return level_;
    const int levels = static_cast<int>(levels_.size());
    level_ = levels - 1;
    for (int l = 0; l < levels; ++l) {
        const double t = static_cast<std::size_t>(l) < draw_ns.size() ? draw_ns[static_cast<std::size_t>(l)] : -1.0;
        if (std::isfinite(t) && t >= 0.0 && t / period_ns <= kStepUpLoad) {
            level_ = l;
            break;
        }
    }
    load_ = 0.0;
    frames_heavy_ = 0;
    frames_light_ = 0;
    return level_;
}

render::CompositorOptions QualityGovernor::applyLevel(render::CompositorOptions options, int level) const {
    const Level& l = levels_[static_cast<std::size_t>(std::clamp(level, 0, static_cast<int>(levels_.size()) - 1))];
    options.msaa_samples = l.msaa_samples;
    options.area_light_samples = l.area_light_samples;
    return options;
}

nlohmann::json QualityGovernor::json() const {
    nlohmann::json levels = nlohmann::json::array();
    for (std::size_t i = 0; i < levels_.size(); ++i) {
        levels.push_back({{"msaa_samples", levels_[i].msaa_samples},
                          {"area_light_samples", levels_[i].area_light_samples},
                          {"frames", frames_at_[i]}});
    }
    return {{"levels", levels}, {"changes", changes_}, {"level", level_}};
}

std::string QualityGovernor::summary() const {
    std::string text;
    for (std::size_t i = 0; i < levels_.size(); ++i) {
        if (frames_at_[i] == 0) continue;
        if (!text.empty()) text += "; ";
        text += "MSAA " + std::to_string(levels_[i].msaa_samples) + ", " + std::to_string(levels_[i].area_light_samples) +
                " light samples: " + std::to_string(frames_at_[i]) + " frames";
    }
    return text + " (" + std::to_string(changes_) + (changes_ == 1 ? " change)" : " changes)");
}

}  // namespace commonlight::pipeline

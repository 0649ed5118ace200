#include "pipeline/lighting_pacer.h"

#include <algorithm>

namespace commonlight::pipeline {

std::optional<int> LightingPacer::step(std::uint64_t dropped, bool lighting_published) {
    ++frames_;
    ++frames_at_[static_cast<std::size_t>(every_ - 1)];
    const bool counts = lighting_published && frames_ > static_cast<std::uint64_t>(kGraceFrames);
    int next = every_;
    if (dropped > 0 && counts) {
        next = std::min(every_ + 1, kMaxEvery);
        calm_ = 0;
    } else if (++calm_ >= kCalmFrames) {
        next = std::max(every_ - 1, 1);
        calm_ = 0;
    }
    if (next == every_) return std::nullopt;
    every_ = next;
    ++changes_;
    return every_;
}

nlohmann::json LightingPacer::json() const {
    nlohmann::json frames = nlohmann::json::object();
    for (std::size_t i = 0; i < frames_at_.size(); ++i) {
        if (frames_at_[i] > 0) frames[std::to_string(i + 1)] = frames_at_[i];
    }
    return {{"every", every_}, {"changes", changes_}, {"frames", frames}};
}

std::string LightingPacer::summary() const {
    std::string out;
    for (std::size_t i = 0; i < frames_at_.size(); ++i) {
        if (frames_at_[i] == 0) continue;
        if (!out.empty()) out += ", ";
        out += i == 0 ? std::string("every frame") : "every " + std::to_string(i + 1) + (i == 1 ? "nd" : i == 2 ? "rd" : "th") + " frame";
        out += ": " + std::to_string(frames_at_[i]) + " frames";
    }
    if (out.empty()) out = "no frame";
    return out + " (" + std::to_string(changes_) + (changes_ == 1 ? " change)" : " changes)");
}

}  // namespace commonlight::pipeline

#include "pipeline/lighting_pacer.h"

#include <algorithm>

namespace commonlight::pipeline {

std::optional<int> LightingPacer::step(std::uint64_t dropped, bool lighting_published, std::uint64_t full_updates) {
    ++frames_;
    ++frames_at_[static_cast<std::size_t>(every_ - 1)];
    // A full update that ended since the last frame: a drop held pending is its, and so is one
    // seen within kRefitFrames after it.
    const bool refit_ended = full_updates != full_updates_;
    full_updates_ = full_updates;
    if (refit_ended) {
        since_refit_ = 0;
        pending_ = -1;
    } else if (since_refit_ < kRefitFrames) {
        ++since_refit_;
    }
    const bool counts = lighting_published && frames_ > static_cast<std::uint64_t>(kGraceFrames) && since_refit_ >= kRefitFrames;
    if (dropped > 0 && counts && pending_ < 0) pending_ = 0;
    int next = every_;
    if (pending_ >= 0 && ++pending_ > kRefitFrames) {
        // No full update ended within kRefitFrames of the drop: the pace's.
        pending_ = -1;
        next = std::min(every_ + 1, kMaxEvery);
        calm_ = 0;
    } else if (dropped > 0 || pending_ >= 0) {
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

#include "apps/report.h"

#include <cstdio>

#include "core/file_util.h"

namespace commonlight::apps {

nlohmann::json toJson(const Percentiles& p) {
    return {{"p50", p.p50}, {"p95", p.p95}, {"max", p.max}};
}

std::uint64_t droppedFrames(const capture::CaptureStats& stats) {
    return stats.drops.device + stats.drops.no_slot + stats.drops.mailbox;
}

nlohmann::json captureJson(const capture::CaptureStats& stats) {
    return {{"frames", stats.frames_delivered},
            {"frames_received", stats.frames_received},
            {"fps", stats.fps},
            {"wall_fps", stats.wall_fps},
            {"jitter_ms", stats.jitter_ms},
            {"dropped_frames", droppedFrames(stats)},
            {"dropped", {{"device", stats.drops.device}, {"no_slot", stats.drops.no_slot}, {"mailbox", stats.drops.mailbox}}},
            {"corrupt_frames", stats.drops.corrupt},
            {"frames_discarded", stats.frames_discarded},
            {"latency_ms", toJson(stats.latency_ms)}};
}

nlohmann::json stagesJson(const capture::StageTimings& timings) {
    nlohmann::json stages = nlohmann::json::object();
    for (const auto& stage : timings.summary()) stages[stage.name] = toJson(stage.ms);
    return stages;
}

std::string poseColumns(const Rigid3d& pose) {
    char buf[256];
    std::snprintf(buf, sizeof buf, "%.9g,%.9g,%.9g,%.12g,%.12g,%.12g,%.12g", pose.translation.x(), pose.translation.y(),
                  pose.translation.z(), pose.rotation.w(), pose.rotation.x(), pose.rotation.y(), pose.rotation.z());
    return buf;
}

void printCaptureStats(const capture::CaptureStats& stats) {
    std::printf("  rate      %.2f fps (wall clock %.2f fps), inter-frame jitter %.3f ms\n", stats.fps, stats.wall_fps,
                stats.jitter_ms);
    std::printf("  dropped   %llu (at the device %llu, no free buffer %llu, replaced in the mailbox %llu); corrupt %llu\n",
                static_cast<unsigned long long>(droppedFrames(stats)),
                static_cast<unsigned long long>(stats.drops.device),
                static_cast<unsigned long long>(stats.drops.no_slot),
                static_cast<unsigned long long>(stats.drops.mailbox),
                static_cast<unsigned long long>(stats.drops.corrupt));
    if (stats.frames_discarded > 0) {
        std::printf("  discarded %llu made after the consumer stopped taking frames (not dropped)\n",
                    static_cast<unsigned long long>(stats.frames_discarded));
    }
    std::printf("  latency   p50 %.3f ms, p95 %.3f ms, max %.3f ms (frame arrival to hand-over)\n", stats.latency_ms.p50,
                stats.latency_ms.p95, stats.latency_ms.max);
}

void printStages(const capture::StageTimings& timings) {
    for (const auto& stage : timings.summary()) {
        std::printf("  stage %-9s p50 %.3f ms, p95 %.3f ms, max %.3f ms (%llu frames)\n", stage.name.c_str(), stage.ms.p50,
                    stage.ms.p95, stage.ms.max, static_cast<unsigned long long>(stage.ms.count));
    }
}

Result<void> writeJson(const std::filesystem::path& file, const nlohmann::json& json) {
    std::error_code ec;
    if (file.has_parent_path()) std::filesystem::create_directories(file.parent_path(), ec);
    return writeTextFileAtomic(file, json.dump(2) + "\n");
}

}  // namespace commonlight::apps

// Printing and JSON of capture statistics, shared by record, play and (later) live.
#pragma once

#include <filesystem>

#include <nlohmann/json.hpp>

#include "core/percentiles.h"
#include "capture/stage_timings.h"
#include "capture/stats.h"
#include "core/pose.h"
#include "core/result.h"

namespace commonlight::apps {

nlohmann::json toJson(const Percentiles& p);
// The capture part of the metrics JSON (docs/cli.md): frames, fps, dropped_frames, latency_ms...
nlohmann::json captureJson(const capture::CaptureStats& stats);
nlohmann::json stagesJson(const capture::StageTimings& timings);
// Frames lost before the consumer saw them (device gaps, no free slot, mailbox overwrites).
std::uint64_t droppedFrames(const capture::CaptureStats& stats);

// Two indented lines: rates and drops, then latency.
void printCaptureStats(const capture::CaptureStats& stats);
void printStages(const capture::StageTimings& timings);

// "tx,ty,tz,qw,qx,qy,qz" of a pose, for the CSVs of track and live.
std::string poseColumns(const Rigid3d& pose);

// Writes JSON atomically (pretty-printed, trailing newline).
Result<void> writeJson(const std::filesystem::path& file, const nlohmann::json& json);

}  // namespace commonlight::apps

#include "pipeline/frame_pipeline.h"

#include <algorithm>
#include <cstdio>

#include "core/percentiles.h"
#include "core/frame_file.h"

namespace commonlight::pipeline {

std::uint64_t pixelHash(const ImageView& view) noexcept {
    constexpr std::uint64_t kPrime = 0x100000001b3ull;
    std::uint64_t h = 0xcbf29ce484222325ull;
    const auto mix = [&](std::uint64_t value) {
        for (int i = 0; i < 8; ++i) {
            h = (h ^ ((value >> (8 * i)) & 0xFF)) * kPrime;
        }
    };
    mix(static_cast<std::uint64_t>(view.format));
    mix(static_cast<std::uint64_t>(view.width));
    mix(static_cast<std::uint64_t>(view.height));
    if (isCompressed(view.format)) {
        for (std::size_t i = 0; i < view.size_bytes; ++i) h = (h ^ view.data[i]) * kPrime;
        return h;
    }
    const std::size_t row_bytes = minStride(view.format, view.width);
    const std::size_t rows = view.stride == 0 ? 0 : imageBytes(view.format, view.width, view.height, view.stride) / view.stride;
    for (std::size_t y = 0; y < rows; ++y) {
        const std::uint8_t* row = view.data + y * view.stride;
        for (std::size_t x = 0; x < row_bytes; ++x) h = (h ^ row[x]) * kPrime;
    }
    return h;
}

Result<GroundTruth> GroundTruth::fromSequence(const Sequence& sequence, bool by_content) {
    if (sequence.groundtruth_poses.empty()) {
        return fail(ErrorCode::kBadInput, (sequence.root / "groundtruth" / "cam_poses.csv").string() +
                                              ": no ground-truth poses in this sequence");
    }
    GroundTruth truth;
    // Each frame's truth at the instant the tracker reports its pose for (the middle of its exposure).
    for (std::size_t i = 0; i < sequence.frames.size(); ++i) {
        if (auto pose = groundTruthOfFrame(sequence, i)) truth.by_timestamp_.emplace(sequence.frames[i].timestamp_ns, *pose);
    }
    if (by_content) {
        // A camera serving the recording sends its frames as stored, or decoded to RGB8 or GRAY8
        // when its protocol cannot carry the stored format (GigE Vision has no JPEG): all three
        // name the frame.
        FrameFileReader reader;
        capture::PixelConverter converter;
        Image image;
        Image decoded;
        for (std::size_t i = 0; i < sequence.frames.size(); ++i) {
            const auto pose = truth.atTimestamp(sequence.frames[i].timestamp_ns);
            if (!pose) continue;
            CL_TRY_VOID(reader.read(sequence.framePath(i), sequence.sensor.pixel_format, sequence.sensor.width,
                                    sequence.sensor.height, image));
            truth.by_hash_.emplace(pixelHash(image.view()), *pose);
            for (PixelFormat format : {PixelFormat::kRgb8, PixelFormat::kGray8}) {
                if (image.format() == format || !capture::PixelConverter::canConvert(image.format(), format)) continue;
                if (auto converted = converter.convert(image.view(), format, decoded); !converted) {
                    return fail(ErrorCode::kBadInput, sequence.framePath(i).string() + ": " + converted.error().message);
                }
                truth.by_hash_.emplace(pixelHash(decoded.view()), *pose);
            }
        }
    }
    return truth;
}

std::optional<Rigid3d> GroundTruth::atTimestamp(std::int64_t timestamp_ns) const {
    const auto it = by_timestamp_.find(timestamp_ns);
    if (it == by_timestamp_.end()) return std::nullopt;
    return it->second;
}

std::optional<Rigid3d> GroundTruth::ofPixels(const ImageView& view) const {
    const auto it = by_hash_.find(pixelHash(view));
    if (it == by_hash_.end()) return std::nullopt;
    return it->second;
}

void PoseErrors::add(const Rigid3d& cam_from_world, const Rigid3d& world_from_cam_true) {
    rot_deg_.push_back(rotationErrorDeg(cam_from_world, world_from_cam_true.inverse()));
    trans_mm_.push_back(1000.0 * translationError(cam_from_world.inverse(), world_from_cam_true));
}

namespace {

nlohmann::json percentilesOf(std::vector<double> values) {
    std::sort(values.begin(), values.end());
    return {{"p50", nearestRank(values, 50.0)},
            {"p95", nearestRank(values, 95.0)},
            {"max", values.empty() ? 0.0 : values.back()}};
}

}  // namespace

nlohmann::json PoseErrors::json() const {
    return {{"rot_deg", percentilesOf(rot_deg_)}, {"trans_mm", percentilesOf(trans_mm_)}, {"frames", count()}};
}

std::string PoseErrors::summary() const {
    const nlohmann::json j = json();
    char line[256];
    std::snprintf(line, sizeof line,
                  "pose error against ground truth (%zu frames): rotation p50 %.3f p95 %.3f max %.3f deg; camera "
                  "position p50 %.2f p95 %.2f max %.2f mm",
                  count(), j["rot_deg"]["p50"].get<double>(), j["rot_deg"]["p95"].get<double>(),
                  j["rot_deg"]["max"].get<double>(), j["trans_mm"]["p50"].get<double>(),
                  j["trans_mm"]["p95"].get<double>(), j["trans_mm"]["max"].get<double>());
    return line;
}

Result<FramePipeline> FramePipeline::create(const CameraModel& camera, const Scene& scene,
                                            const PipelineOptions& options, capture::StageTimings& timings) {
    if (scene.tags.items.empty()) {
        return fail(ErrorCode::kUsage, "the scene places no tags: tracking needs at least one (docs/formats-scene.md)");
    }
    if (!timings.find("convert") || !timings.find("track")) {
        return fail(ErrorCode::kInternal, "the pipeline's stage timings need the stages convert and track");
    }
    tracking::TrackerOptions tracker_options = options.tracker;
    tracker_options.detector.family = scene.tags.family;
    CL_TRY(tracking::Tracker tracker, tracking::Tracker::create(camera, scene.tags, &scene, tracker_options));
    return FramePipeline(std::move(tracker), camera, scene, tracker_options, options, timings);
}

FramePipeline::FramePipeline(tracking::Tracker tracker, const CameraModel& camera, const Scene& scene,
                             const tracking::TrackerOptions& tracker_options, const PipelineOptions& options,
                             capture::StageTimings& timings)
    : tracker_(std::move(tracker)),
      camera_(camera),
      scene_(&scene),
      tracker_options_(tracker_options),
      options_(options),
      timings_(&timings),
      convert_stage_(timings.id("convert")),
      track_stage_(timings.id("track")) {}

Result<void> FramePipeline::restart() {
    CL_TRY(tracker_, tracking::Tracker::create(camera_, scene_->tags, scene_, tracker_options_));
    return {};
}

Result<tracking::FrameTrack> FramePipeline::process(const Frame& frame) {
    {
        capture::StageTimer timer(*timings_, convert_stage_);
        CL_TRY_VOID(converter_.convert(frame.image.view(), PixelFormat::kGray8, gray_));
    }
    capture::StageTimer timer(*timings_, track_stage_);
    CL_TRY(tracking::FrameTrack track, tracker_.process(gray_.view(), frame.meta));
    if (track.cam_from_world) {
        ++with_pose_;
        if (options_.ground_truth != nullptr) {
            const std::optional<Rigid3d> truth = options_.ground_truth->byContent()
                                                     ? options_.ground_truth->ofPixels(frame.image.view())
                                                     : options_.ground_truth->atTimestamp(frame.meta.timestamp_ns);
            if (truth) {
                errors_.add(*track.cam_from_world, *truth);
            } else {
                ++without_truth_;
            }
        }
    }
    return track;
}

}  // namespace commonlight::pipeline

#include "mocks/replay_camera.h"

#include <algorithm>

#include "core/log.h"

namespace commonlight::mocks {

namespace fs = std::filesystem;

namespace {

std::vector<fs::path> framePaths(const Sequence& sequence) {
    std::vector<fs::path> paths;
    paths.reserve(sequence.frames.size());
    for (std::size_t i = 0; i < sequence.frames.size(); ++i) paths.push_back(sequence.framePath(i));
    return paths;
}

// meta.csv's sequence number where a row exists; a frame without a row (a recorder killed
// between the two appends) continues from the previous one.
std::vector<std::uint64_t> sequenceNumbers(const Sequence& sequence) {
    std::vector<std::uint64_t> numbers(sequence.frames.size());
    for (std::size_t i = 0; i < numbers.size(); ++i) {
        if (i < sequence.meta.size() && sequence.meta[i]) {
            numbers[i] = sequence.meta[i]->sequence;
        } else {
            numbers[i] = i == 0 ? 0 : numbers[i - 1] + 1;
        }
    }
    return numbers;
}

// sensor.yaml may leave pixel_format out (EuRoC datasets do): then the first readable frame
// file decides, as FrameFileReader does with kInvalid.
Result<PixelFormat> storedFormat(const Sequence& sequence) {
    if (sequence.sensor.pixel_format != PixelFormat::kInvalid) return sequence.sensor.pixel_format;
    FrameFileReader reader;
    Image probe;
    constexpr std::size_t kProbeFrames = 10;
    Error last{ErrorCode::kBadInput, (sequence.cam_dir / "data.csv").string() + ": lists no frames"};
    for (std::size_t i = 0; i < std::min(kProbeFrames, sequence.frames.size()); ++i) {
        auto read = reader.read(sequence.framePath(i), PixelFormat::kInvalid, sequence.sensor.width,
                                sequence.sensor.height, probe);
        if (read) return probe.format();
        last = std::move(read.error());
    }
    return fail(std::move(last).prepend((sequence.cam_dir / "sensor.yaml").string() +
                                        ": no pixel_format, and the first frames do not tell it"));
}

}  // namespace

Result<std::unique_ptr<ReplayCamera>> ReplayCamera::open(const fs::path& dir, PlaybackOptions options, Clock& clock) {
    CL_TRY_VOID(options.validate());
    CL_TRY(Sequence sequence, readSequence(dir));
    if (sequence.frames.empty()) {
        return fail(ErrorCode::kBadInput, (sequence.cam_dir / "data.csv").string() + ": lists no frames");
    }
    hal::StreamFormat format;
    CL_TRY(format.format, storedFormat(sequence));
    format.width = sequence.sensor.width;
    format.height = sequence.sensor.height;
    if (sequence.sensor.rate_hz > 0) format.frame_rates = {sequence.sensor.rate_hz};
    return std::unique_ptr<ReplayCamera>(
        new ReplayCamera("replay:" + dir.string(), std::move(sequence), std::move(format), options, clock));
}

Result<std::unique_ptr<ReplayCamera>> ReplayCamera::open(const hal::CameraUri& uri, Clock& clock) {
    if (uri.path.empty()) {
        return fail(ErrorCode::kUsage, "camera URI '" + uri.text + "': expected replay:<sequence folder>");
    }
    CL_TRY(const PlaybackOptions options, PlaybackOptions::fromUri(uri));
    return open(fs::path(uri.path), options, clock);
}

ReplayCamera::ReplayCamera(std::string id, Sequence sequence, hal::StreamFormat format, PlaybackOptions options,
                           Clock& clock)
    : PacedCamera(std::move(id), clock, options),
      sequence_(std::move(sequence)),
      paths_(framePaths(sequence_)),
      sequence_numbers_(sequenceNumbers(sequence_)),
      format_(std::move(format)) {}

ReplayCamera::~ReplayCamera() { stop(); }

Result<hal::StreamFormat> ReplayCamera::doConfigure(const hal::StreamConfig& config) {
    return hal::negotiate({format_}, config, id());
}

Result<void> ReplayCamera::doSetControl(hal::Control control, double) {
    return fail(ErrorCode::kUnsupported, id() + ": " + std::string(hal::controlName(control)) +
                                             " is recorded metadata of each frame and cannot be set");
}

void ReplayCamera::run(std::stop_token stop) {
    const auto& frames = sequence_.frames;
    const std::int64_t interval_ns = nominalIntervalNs(sequence_.sensor.rate_hz, frames.front().timestamp_ns,
                                                       frames.back().timestamp_ns, frames.size());
    const std::int64_t time_period_ns =
        loopPeriodNs(frames.front().timestamp_ns, frames.back().timestamp_ns, interval_ns);
    // Recorded sequence numbers normally increase; if they do not, count frames instead.
    const std::uint64_t sequence_period = sequence_numbers_.back() >= sequence_numbers_.front()
                                              ? sequence_numbers_.back() - sequence_numbers_.front() + 1
                                              : sequence_numbers_.size();

    std::int64_t time_offset_ns = 0;
    std::uint64_t sequence_offset = 0;
    for (;;) {
        for (std::size_t i = 0; i < frames.size(); ++i) {
            const std::int64_t timestamp_ns = frames[i].timestamp_ns + time_offset_ns;
            if (!pacer().waitUntilDue(timestamp_ns, stop)) return;
            emitOne(i, timestamp_ns, sequence_offset);
        }
        if (!pacer().options().loop) break;
        time_offset_ns += time_period_ns;
        sequence_offset += sequence_period;
    }
    emitEvent(hal::CameraEvent{hal::CameraEvent::Type::kEndOfStream, {}});
}

void ReplayCamera::emitOne(std::size_t index, std::int64_t timestamp_ns, std::uint64_t sequence_offset) {
    FrameHandle frame = acquireFrame();
    if (!frame) return;  // no free slot: the base class counted it, the recording goes on
    FrameMetadata& meta = frame->meta;
    meta = recordedMeta(index, timestamp_ns, sequence_offset);
    if (auto read = reader_.read(paths_[index], format_.format, format_.width, format_.height, frame->image); !read) {
        frame->image.clear();
        meta.status = FrameStatus::kCorrupt;
        corrupt_frames_.fetch_add(1, std::memory_order_relaxed);
        log::warning(id() + ": frame " + std::to_string(index) + " delivered as corrupt: " + read.error().message);
    }
    meta.arrival_ns = clock().nowNs();
    emitFrame(std::move(frame));
}

FrameMetadata ReplayCamera::recordedMeta(std::size_t index, std::int64_t timestamp_ns, std::uint64_t sequence_offset) const {
    FrameMetadata meta;
    meta.sequence = sequence_numbers_[index] + sequence_offset;
    meta.timestamp_ns = timestamp_ns;
    meta.timestamp_source = TimestampSource::kRecording;
    if (index < sequence_.meta.size() && sequence_.meta[index]) {
        const FrameMetaRecord& recorded = *sequence_.meta[index];
        meta.exposure_us = recorded.exposure_us;
        meta.analog_gain = recorded.analog_gain;
        meta.status = recorded.status;
    }
    return meta;
}

Result<void> ReplayCamera::readFrame(std::size_t index, Frame& out) const {
    if (index >= paths_.size()) {
        return fail(ErrorCode::kUsage, id() + ": frame " + std::to_string(index) + " of " + std::to_string(paths_.size()));
    }
    out.meta = recordedMeta(index, sequence_.frames[index].timestamp_ns, 0);
    FrameFileReader reader;
    return reader.read(paths_[index], format_.format, format_.width, format_.height, out.image);
}

std::string ReplayCamera::doResponseSpec() const {
    const std::string& r = sequence_.sensor.response;
    if (r == "srgb" || r == "linear" || r.starts_with("gamma:")) return r;
    const std::filesystem::path file(r);
    return file.is_relative() ? (sequence_.cam_dir / file).string() : r;
}

}  // namespace commonlight::mocks

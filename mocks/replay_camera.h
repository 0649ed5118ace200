// replay:<SEQ>: a recorded sequence (core/sequence_io.h) played back as a camera.
//
//   replay:data/sample                      realtime, once
//   replay:data/sample?rate=max&loop=1      as fast as possible, forever
//   replay:data/sample?rate=step            one frame per trigger()
//
// The camera offers exactly one format: the sequence's pixel_format at its resolution (and
// rate_hz). Frames carry the recorded timestamps (TimestampSource::kRecording), the recorded
// sequence numbers, exposure, gain and status when meta.csv exists (else the frame's index), and
// arrival_ns = the injected clock when the frame is handed over. A frame whose file is missing,
// corrupt or truncated is delivered with status kCorrupt and an empty image, a warning naming
// the file is logged, and playback goes on. When looping, every pass is offset by the length of
// the recording plus one frame interval, so timestamps and sequence numbers keep increasing.
// Without loop, the end of the recording emits CameraEvent::kEndOfStream once.
#pragma once

#include <atomic>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <thread>
#include <vector>

#include "core/clock.h"
#include "core/frame_file.h"
#include "core/sequence_io.h"
#include "hal/camera.h"
#include "hal/camera_uri.h"
#include "mocks/pacer.h"
#include "mocks/paced_camera.h"

namespace commonlight::mocks {

class ReplayCamera final : public PacedCamera {
public:
    // Reads the sequence at `dir` (SEQ, SEQ/cam0 or a EuRoC mav0 folder). Errors name the file:
    // kNotFound for a missing folder, kBadInput for a malformed sequence. `clock` paces playback
    // and stamps arrival_ns; it is borrowed and must outlive the camera.
    static Result<std::unique_ptr<ReplayCamera>> open(const std::filesystem::path& dir, PlaybackOptions options,
                                                      Clock& clock);
    // The same from a "replay:<SEQ>?rate=&loop=&speed=" URI (options already validated by the
    // registry or not: unknown ones are ignored here).
    static Result<std::unique_ptr<ReplayCamera>> open(const hal::CameraUri& uri, Clock& clock);

    ~ReplayCamera() override;

    const Sequence& sequence() const noexcept { return sequence_; }
    // Frames delivered with status kCorrupt because their file could not be read (counted on
    // the camera thread; read it from any thread).
    std::uint64_t corruptFrames() const noexcept { return corrupt_frames_.load(std::memory_order_relaxed); }
    // Frame `index` as the camera delivers it on its first pass (the recorded timestamp and
    // metadata), read on the caller's thread: e.g. to prepare the pipeline before playing. Errors:
    // kUsage for an index past the end, the reader's (naming the file) for a bad file.
    Result<void> readFrame(std::size_t index, Frame& out) const;

private:
    ReplayCamera(std::string id, Sequence sequence, hal::StreamFormat format, PlaybackOptions options, Clock& clock);

    std::vector<hal::StreamFormat> doFormats() const override { return {format_}; }
    // The recording's sensor.yaml `response`: relative files are made absolute (against cam0/).
    std::string doResponseSpec() const override;
    // sensor.yaml's intrinsics and distortion, when it has them.
    std::optional<CameraModel> doCalibration() const override { return sequence_.sensor.camera; }
    Result<hal::StreamFormat> doConfigure(const hal::StreamConfig& config) override;
    Result<void> doSetControl(hal::Control control, double value) override;

    // The camera thread: paces and emits every frame, pass after pass when looping.
    void run(std::stop_token stop) override;
    void emitOne(std::size_t index, std::int64_t timestamp_ns, std::uint64_t sequence_offset);
    // The metadata frame `index` is delivered with (arrival_ns left 0).
    FrameMetadata recordedMeta(std::size_t index, std::int64_t timestamp_ns, std::uint64_t sequence_offset) const;

    const Sequence sequence_;
    const std::vector<std::filesystem::path> paths_;     // one per frame, built once
    const std::vector<std::uint64_t> sequence_numbers_;  // meta.csv's, or the frame index
    const hal::StreamFormat format_;
    FrameFileReader reader_;  // camera thread only; keeps its buffers between frames
    std::atomic<std::uint64_t> corrupt_frames_{0};
};

}  // namespace commonlight::mocks

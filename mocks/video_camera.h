// video:<file>: a video file (mp4, avi, mkv: whatever Debian's OpenCV reads through FFmpeg)
// played back as a camera, with the same rate=realtime|max|step, loop=0|1 and speed= options and
// the same pacing as replay: (mocks/pacer.h).
//
// Formats: RGB8 (the default) and BGR8 (format=bgr8 skips the colour conversion), at the
// video's size and frame rate. Timestamps are the decoder's presentation times
// (CAP_PROP_POS_MSEC, TimestampSource::kRecording); a container without usable times gets one
// nominal interval (1 / fps) after the previous frame. Sequence numbers count frames from 0 and
// keep counting across loops; looping offsets timestamps as replay: does.
//
// Errors: a missing file is kNotFound and a file FFmpeg cannot open or decode a first frame of is
// kBadInput, both at open and naming the file. A frame that fails to decode in the middle (a
// truncated file) ends the pass early: a warning names the frame index, then the stream ends with
// kEndOfStream (or the next loop pass starts), not with kDeviceError.
#pragma once

#include <atomic>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <thread>

#include <opencv2/core/mat.hpp>
#include <opencv2/videoio.hpp>

#include "core/clock.h"
#include "hal/camera.h"
#include "hal/camera_uri.h"
#include "mocks/pacer.h"
#include "mocks/paced_camera.h"

namespace commonlight::mocks {

class VideoCamera final : public PacedCamera {
public:
    // Opens `file` and decodes its first frame to learn the format. `clock` paces playback and
    // stamps arrival_ns; it is borrowed and must outlive the camera.
    static Result<std::unique_ptr<VideoCamera>> open(const std::filesystem::path& file, PlaybackOptions options,
                                                     Clock& clock);
    // The same from a "video:<file>?rate=&loop=&speed=" URI.
    static Result<std::unique_ptr<VideoCamera>> open(const hal::CameraUri& uri, Clock& clock);

    ~VideoCamera() override;

    // Frames the container announces (CAP_PROP_FRAME_COUNT; 0 when it does not say).
    std::int64_t announcedFrames() const noexcept { return announced_frames_; }

private:
    VideoCamera(std::filesystem::path file, int width, int height, double fps, std::int64_t frames,
                PlaybackOptions options, Clock& clock);

    std::vector<hal::StreamFormat> doFormats() const override;
    Result<hal::StreamFormat> doConfigure(const hal::StreamConfig& config) override;
    Result<void> beforeStart() override;
    void afterStop() noexcept override;

    // The camera thread: decodes, paces and emits every frame, pass after pass when looping.
    void run(std::stop_token stop) override;
    void emitOne(std::int64_t timestamp_ns);

    const std::filesystem::path file_;
    const int width_;
    const int height_;
    const double fps_;  // 0 when the container does not say
    const std::int64_t announced_frames_;
    const std::int64_t interval_ns_;  // nominal frame interval
    // Camera thread only while streaming (control thread before start).
    cv::VideoCapture capture_;
    cv::Mat bgr_;  // decoder output, reused between frames
    std::uint64_t next_sequence_ = 0;
};

}  // namespace commonlight::mocks

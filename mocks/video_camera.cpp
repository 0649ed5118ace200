#include "mocks/video_camera.h"

#include <cmath>

#include <opencv2/imgproc.hpp>

#include "core/log.h"

namespace commonlight::mocks {

namespace fs = std::filesystem;

namespace {

// FFmpeg only: the other OpenCV backends (GStreamer, image sequences) would read "%d" in a
// name as a pattern or print their own errors for a plain file.
Result<void> openCapture(cv::VideoCapture& capture, const fs::path& file) {
    bool opened = false;
    try {
        opened = capture.open(file.string(), cv::CAP_FFMPEG);
    } catch (const cv::Exception& e) {
        return fail(ErrorCode::kBadInput, file.string() + ": cannot open as a video: " + e.what());
    }
    if (!opened) {
        return fail(ErrorCode::kBadInput,
                    file.string() + ": cannot open as a video (corrupt, or a container or codec FFmpeg does not read)");
    }
    return {};
}

}  // namespace

Result<std::unique_ptr<VideoCamera>> VideoCamera::open(const fs::path& file, PlaybackOptions options, Clock& clock) {
    CL_TRY_VOID(options.validate());
    std::error_code ec;
    if (!fs::exists(file, ec)) return fail(ErrorCode::kNotFound, file.string() + ": no such file");
    if (!fs::is_regular_file(file, ec)) return fail(ErrorCode::kBadInput, file.string() + ": not a video file");
    cv::VideoCapture capture;
    CL_TRY_VOID(openCapture(capture, file));
    cv::Mat first;
    bool decoded = false;
    try {
        decoded = capture.read(first);
    } catch (const cv::Exception&) {
        decoded = false;
    }
    if (!decoded || first.empty()) return fail(ErrorCode::kBadInput, file.string() + ": no decodable video frame");
    if (first.type() != CV_8UC3) {
        return fail(ErrorCode::kBadInput, file.string() + ": the decoder gave " + std::to_string(first.channels()) +
                                              "-channel frames, expected BGR");
    }
    double fps = capture.get(cv::CAP_PROP_FPS);
    if (!std::isfinite(fps) || fps <= 0 || fps > 1000) fps = 0.0;
    const double count = capture.get(cv::CAP_PROP_FRAME_COUNT);
    const std::int64_t frames = std::isfinite(count) && count > 0 ? std::llround(count) : 0;
    return std::unique_ptr<VideoCamera>(new VideoCamera(file, first.cols, first.rows, fps, frames, options, clock));
}

Result<std::unique_ptr<VideoCamera>> VideoCamera::open(const hal::CameraUri& uri, Clock& clock) {
    if (uri.path.empty()) return fail(ErrorCode::kUsage, "camera URI '" + uri.text + "': expected video:<file>");
    CL_TRY(const PlaybackOptions options, PlaybackOptions::fromUri(uri));
    return open(fs::path(uri.path), options, clock);
}

VideoCamera::VideoCamera(fs::path file, int width, int height, double fps, std::int64_t frames, PlaybackOptions options,
                         Clock& clock)
    : PacedCamera("video:" + file.string(), clock, options),
      file_(std::move(file)),
      width_(width),
      height_(height),
      fps_(fps),
      announced_frames_(frames),
      interval_ns_(nominalIntervalNs(fps, 0, 0, 1)) {}

VideoCamera::~VideoCamera() { stop(); }

std::vector<hal::StreamFormat> VideoCamera::doFormats() const {
    std::vector<double> rates;
    if (fps_ > 0) rates.push_back(fps_);
    return {hal::StreamFormat{PixelFormat::kRgb8, width_, height_, rates, 0.0},
            hal::StreamFormat{PixelFormat::kBgr8, width_, height_, rates, 0.0}};
}

Result<hal::StreamFormat> VideoCamera::doConfigure(const hal::StreamConfig& config) {
    return hal::negotiate(doFormats(), config, id());
}

Result<void> VideoCamera::beforeStart() {
    // Every start() plays from the first frame.
    CL_TRY_VOID(openCapture(capture_, file_));
    next_sequence_ = 0;
    return {};
}

void VideoCamera::afterStop() noexcept { capture_.release(); }

void VideoCamera::run(std::stop_token stop) {
    std::int64_t time_offset_ns = 0;
    std::int64_t first_ns = 0;
    std::int64_t last_ns = 0;
    std::int64_t in_pass = 0;  // frames decoded in this pass
    while (!stop.stop_requested()) {
        bool decoded = false;
        try {
            decoded = capture_.read(bgr_);
        } catch (const cv::Exception& e) {
            log::warning(id() + ": decoder failed: " + e.what());
        }
        if (!decoded) {
            // Step 1: a pass ended; say so when it ended before the container's announced end.
            if (announced_frames_ > 0 && in_pass < announced_frames_) {
                log::warning(id() + ": frame " + std::to_string(in_pass) +
                             " could not be decoded (the file announces " + std::to_string(announced_frames_) +
                             " frames); the video ends early");
            }
            if (!pacer().options().loop || in_pass == 0) break;
            // Step 2: loop from the start, timestamps offset past this pass.
            time_offset_ns += loopPeriodNs(first_ns, last_ns, interval_ns_);
            in_pass = 0;
            if (auto reopened = openCapture(capture_, file_); !reopened) {
                emitEvent(hal::CameraEvent{
                    hal::CameraEvent::Type::kDeviceError,
                    Error{ErrorCode::kIo, id() + ": cannot reopen for the next loop: " + reopened.error().message}});
                return;
            }
            continue;
        }
        // Step 3: the frame's time, strictly increasing within a pass.
        const double msec = capture_.get(cv::CAP_PROP_POS_MSEC);
        std::int64_t t_ns = std::isfinite(msec) ? std::llround(msec * 1e6) : 0;
        if (in_pass > 0 && t_ns <= last_ns) t_ns = last_ns + interval_ns_;
        if (in_pass == 0) first_ns = t_ns;
        last_ns = t_ns;
        ++in_pass;
        // Step 4: wait until it is due, then hand it over.
        if (!pacer().waitUntilDue(t_ns + time_offset_ns, stop)) return;
        emitOne(t_ns + time_offset_ns);
    }
    if (!stop.stop_requested()) emitEvent(hal::CameraEvent{hal::CameraEvent::Type::kEndOfStream, {}});
}

void VideoCamera::emitOne(std::int64_t timestamp_ns) {
    const std::uint64_t sequence = next_sequence_++;
    FrameHandle frame = acquireFrame();
    if (!frame) return;  // no free slot: the base class counted it
    FrameMetadata& meta = frame->meta;
    meta = FrameMetadata{};
    meta.sequence = sequence;
    meta.timestamp_ns = timestamp_ns;
    meta.timestamp_source = TimestampSource::kRecording;
    const PixelFormat format = activeFormat().format;
    if (bgr_.type() != CV_8UC3 || bgr_.cols != width_ || bgr_.rows != height_) {
        frame->image.clear();
        meta.status = FrameStatus::kCorrupt;
        log::warning(id() + ": frame " + std::to_string(sequence) + " is " + std::to_string(bgr_.cols) + "x" +
                     std::to_string(bgr_.rows) + ", not " + std::to_string(width_) + "x" + std::to_string(height_) +
                     "; delivered as corrupt");
    } else {
        frame->image.reshape(format, width_, height_);
        cv::Mat out(height_, width_, CV_8UC3, frame->image.data(), frame->image.stride());
        if (format == PixelFormat::kRgb8) {
            cv::cvtColor(bgr_, out, cv::COLOR_BGR2RGB);
        } else {
            bgr_.copyTo(out);
        }
    }
    meta.arrival_ns = clock().nowNs();
    emitFrame(std::move(frame));
}

}  // namespace commonlight::mocks

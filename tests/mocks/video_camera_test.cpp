#include "mocks/video_camera.h"

#include <cmath>

#include <gtest/gtest.h>
#include <opencv2/videoio.hpp>

#include "hal/registry.h"
#include "mocks/register.h"
#include "tests/mocks/mock_test_support.h"
#include "tests/test_support.h"

namespace commonlight::mocks {
namespace {

namespace fs = std::filesystem;
using testing::FrameSink;
using testing::TempDir;
using testing::TestFramePool;

constexpr int kWidth = 64;
constexpr int kHeight = 48;
constexpr double kFps = 25.0;

// The colour (BGR) of frame i: distinct, flat, so JPEG keeps it to within a few levels.
cv::Vec3b frameColour(int i) {
    return cv::Vec3b(static_cast<std::uint8_t>(20 + 20 * i), static_cast<std::uint8_t>(200 - 15 * i),
                     static_cast<std::uint8_t>(i % 2 ? 60 : 180));
}

// Writes `count` flat-coloured frames as MJPG in an AVI (always available through FFmpeg).
fs::path writeVideo(const fs::path& dir, int count) {
    const fs::path file = dir / "clip.avi";
    cv::VideoWriter writer(file.string(), cv::CAP_FFMPEG, cv::VideoWriter::fourcc('M', 'J', 'P', 'G'), kFps,
                           cv::Size(kWidth, kHeight));
    if (!writer.isOpened()) throw std::runtime_error("cannot write " + file.string());
    for (int i = 0; i < count; ++i) writer.write(cv::Mat(kHeight, kWidth, CV_8UC3, cv::Scalar(frameColour(i))));
    writer.release();
    return file;
}

std::unique_ptr<VideoCamera> openVideo(const fs::path& file, PlaybackOptions options, Clock& clock) {
    auto camera = VideoCamera::open(file, options, clock);
    if (!camera) ADD_FAILURE() << camera.error().message;
    return camera ? std::move(*camera) : nullptr;
}

void start(hal::Camera& camera, FrameSink& sink, TestFramePool& pool, hal::StreamConfig config = {}) {
    sink.attach(camera, pool);
    auto configured = camera.configure(config);
    ASSERT_TRUE(configured) << configured.error().message;
    auto started = camera.start();
    ASSERT_TRUE(started) << started.error().message;
}

// Mean of a channel over an RGB8/BGR8 image.
double channelMean(const Image& image, int channel) {
    double sum = 0;
    for (int y = 0; y < image.height(); ++y) {
        for (int x = 0; x < image.width(); ++x) sum += image.view().row(y)[x * 3 + channel];
    }
    return sum / (image.width() * image.height());
}

TEST(VideoCamera, ReplaysAWrittenVideoFrameByFrame) {
    TempDir dir;
    const fs::path file = writeVideo(dir.path(), 10);
    ManualClock clock(7);
    TestFramePool pool(3);
    FrameSink sink({.keep_images = true});
    auto camera = openVideo(file, {PlaybackRate::kMax, false, 1.0}, clock);
    ASSERT_TRUE(camera);
    EXPECT_EQ(camera->id(), "video:" + file.string());
    EXPECT_EQ(camera->announcedFrames(), 10);
    const auto formats = camera->formats();
    ASSERT_EQ(formats.size(), 2u);
    EXPECT_EQ(formats[0].format, PixelFormat::kRgb8);
    EXPECT_EQ(formats[1].format, PixelFormat::kBgr8);
    EXPECT_EQ(formats[0].width, kWidth);
    EXPECT_EQ(formats[0].height, kHeight);
    ASSERT_EQ(formats[0].frame_rates.size(), 1u);
    EXPECT_NEAR(formats[0].frame_rates[0], kFps, 0.01);
    start(*camera, sink, pool);
    EXPECT_EQ(camera->activeFormat().format, PixelFormat::kRgb8);
    ASSERT_TRUE(sink.waitForEvents(1));
    camera->stop();

    ASSERT_EQ(sink.frames().size(), 10u);
    EXPECT_EQ(sink.events()[0].type, hal::CameraEvent::Type::kEndOfStream);
    for (int i = 0; i < 10; ++i) {
        const auto& frame = sink.frames()[static_cast<std::size_t>(i)];
        EXPECT_EQ(frame.meta.sequence, static_cast<std::uint64_t>(i));
        EXPECT_EQ(frame.meta.status, FrameStatus::kOk);
        EXPECT_EQ(frame.meta.timestamp_source, TimestampSource::kRecording);
        EXPECT_NEAR(static_cast<double>(frame.meta.timestamp_ns), i * 1e9 / kFps, 1e6) << "frame " << i;
        EXPECT_EQ(frame.meta.arrival_ns, 7);
        ASSERT_EQ(frame.image.format(), PixelFormat::kRgb8);
        ASSERT_EQ(frame.image.width(), kWidth);
        ASSERT_EQ(frame.image.height(), kHeight);
        const cv::Vec3b bgr = frameColour(i);
        for (int c = 0; c < 3; ++c)
            EXPECT_NEAR(channelMean(frame.image, c), bgr[2 - c], 4.0) << "frame " << i << " channel " << c;
    }
}

TEST(VideoCamera, Bgr8SkipsTheColourConversion) {
    TempDir dir;
    const fs::path file = writeVideo(dir.path(), 3);
    ManualClock clock;
    TestFramePool pool(2);
    FrameSink sink({.keep_images = true});
    auto camera = openVideo(file, {PlaybackRate::kMax, false, 1.0}, clock);
    ASSERT_TRUE(camera);
    start(*camera, sink, pool, {PixelFormat::kBgr8, 0, 0, 0});
    ASSERT_TRUE(sink.waitForEvents(1));
    camera->stop();
    ASSERT_EQ(sink.frames().size(), 3u);
    const auto& frame = sink.frames()[2];
    ASSERT_EQ(frame.image.format(), PixelFormat::kBgr8);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(channelMean(frame.image, c), frameColour(2)[c], 4.0);
}

TEST(VideoCamera, RealtimePacingSharesTheReplayPacer) {
    TempDir dir;
    const fs::path file = writeVideo(dir.path(), 3);
    ManualClock clock;
    TestFramePool pool(2);
    FrameSink sink;
    auto camera = openVideo(file, {}, clock);
    ASSERT_TRUE(camera);
    start(*camera, sink, pool);
    ASSERT_TRUE(sink.waitForFrames(1));
    clock.waitForSleepers(1);
    EXPECT_EQ(sink.frameCount(), 1u);
    clock.advance(40'000'000);  // one frame at 25 fps
    ASSERT_TRUE(sink.waitForFrames(2));
    clock.waitForSleepers(1);
    EXPECT_EQ(sink.frameCount(), 2u);
    camera->stop();
}

TEST(VideoCamera, StepAndLoop) {
    TempDir dir;
    const fs::path file = writeVideo(dir.path(), 3);
    ManualClock clock;
    TestFramePool pool(2);
    FrameSink sink;
    auto camera = openVideo(file, {PlaybackRate::kStep, true, 1.0}, clock);
    ASSERT_TRUE(camera);
    start(*camera, sink, pool);
    for (std::size_t n = 1; n <= 7; ++n) {
        ASSERT_TRUE(camera->trigger());
        ASSERT_TRUE(sink.waitForFrames(n));
    }
    camera->stop();
    EXPECT_EQ(sink.frameCount(), 7u);
    EXPECT_EQ(sink.eventCount(), 0u);
    const auto metas = sink.metas();
    for (std::size_t i = 1; i < metas.size(); ++i) {
        EXPECT_EQ(metas[i].sequence, i);
        EXPECT_NEAR(static_cast<double>(metas[i].timestamp_ns - metas[i - 1].timestamp_ns), 1e9 / kFps, 1e6) << i;
    }
}

TEST(VideoCamera, MissingAndCorruptFilesFailToOpenNamingTheFile) {
    TempDir dir;
    ManualClock clock;
    const auto missing = VideoCamera::open(dir.path() / "none.mp4", {}, clock);
    ASSERT_FALSE(missing);
    EXPECT_EQ(missing.error().code, ErrorCode::kNotFound);
    EXPECT_NE(missing.error().message.find("none.mp4"), std::string::npos);

    const fs::path junk = dir.path() / "junk.mp4";
    testing::writeText(junk, std::string(4096, 'x'));
    const auto corrupt = VideoCamera::open(junk, {}, clock);
    ASSERT_FALSE(corrupt);
    EXPECT_EQ(corrupt.error().code, ErrorCode::kBadInput);
    EXPECT_NE(corrupt.error().message.find(junk.string()), std::string::npos) << corrupt.error().message;

    const auto folder = VideoCamera::open(dir.path(), {}, clock);
    ASSERT_FALSE(folder);
    EXPECT_EQ(folder.error().code, ErrorCode::kBadInput);
}

TEST(VideoCamera, TruncatedFileEndsEarlyWithAWarningAndEndOfStream) {
    TempDir dir;
    const fs::path file = writeVideo(dir.path(), 20);
    // Cut a quarter off: FFmpeg still opens it (with half cut, it no longer does) and stops early.
    fs::resize_file(file, fs::file_size(file) * 3 / 4);
    ManualClock clock;
    TestFramePool pool(2);
    FrameSink sink;
    ::testing::internal::CaptureStderr();
    auto camera = openVideo(file, {PlaybackRate::kMax, false, 1.0}, clock);
    if (camera) {
        start(*camera, sink, pool);
        EXPECT_TRUE(sink.waitForEvents(1));
        camera->stop();
    }
    const std::string log = ::testing::internal::GetCapturedStderr();
    ASSERT_TRUE(camera);
    EXPECT_GT(sink.frameCount(), 0u);
    EXPECT_LT(sink.frameCount(), 20u);
    ASSERT_EQ(sink.events().size(), 1u);
    EXPECT_EQ(sink.events()[0].type, hal::CameraEvent::Type::kEndOfStream);
    EXPECT_EQ(camera->announcedFrames(), 20) << "the AVI header still announces every frame";
    EXPECT_NE(log.find(camera->id() + ": frame " + std::to_string(sink.frameCount()) + " could not be decoded"),
              std::string::npos)
        << log;
}

TEST(VideoCamera, OpensThroughTheRegistry) {
    TempDir dir;
    const fs::path file = writeVideo(dir.path(), 2);
    ManualClock clock;
    hal::CameraRegistry registry;
    registerMockBackends(registry, clock);
    auto camera = registry.openConfigured("video:" + file.string() + "?rate=max&format=bgr8");
    ASSERT_TRUE(camera) << camera.error().message;
    EXPECT_EQ((*camera)->activeFormat().format, PixelFormat::kBgr8);
    const auto bad = registry.openConfigured("video:" + file.string() + "?format=gray8");
    ASSERT_FALSE(bad);
    EXPECT_EQ(bad.error().code, ErrorCode::kUnsupported);
}

}  // namespace
}  // namespace commonlight::mocks

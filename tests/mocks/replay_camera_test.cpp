#include "mocks/replay_camera.h"

#include <gtest/gtest.h>

#include "hal/registry.h"
#include "mocks/register.h"
#include "tests/mocks/replay_test_support.h"
#include "tests/test_support.h"

namespace commonlight::mocks {
namespace {

namespace fs = std::filesystem;
using testing::configureAndStart;
using testing::FrameSink;
using testing::kInterval;
using testing::openReplay;
using testing::rate;
using testing::TempDir;
using testing::TestFramePool;
using testing::writeTestSequence;

// ---- pixels and metadata --------------------------------------------------------------------

class ReplayBitIdentical : public ::testing::TestWithParam<PixelFormat> {};

TEST_P(ReplayBitIdentical, FramesComeOutAsWrittenWithTheirMetadata) {
    const PixelFormat format = GetParam();
    TempDir dir;
    const auto written = writeTestSequence(dir.path(), format, 4, kInterval, 30.0, 32, 24, 100);
    ManualClock clock;
    TestFramePool pool(2);
    FrameSink sink({.keep_images = true});
    auto camera = openReplay(dir.path(), rate(PlaybackRate::kMax), clock);
    ASSERT_TRUE(camera);
    const auto formats = camera->formats();
    ASSERT_EQ(formats.size(), 1u);
    EXPECT_EQ(formats[0].format, format);
    EXPECT_EQ(formats[0].width, 32);
    EXPECT_EQ(formats[0].height, 24);
    EXPECT_EQ(formats[0].frame_rates, std::vector<double>{30.0});
    configureAndStart(*camera, sink, pool);
    EXPECT_EQ(camera->activeFormat().fps, 30.0);
    ASSERT_TRUE(sink.waitForEvents(1));
    camera->stop();
    ASSERT_EQ(sink.frames().size(), 4u);
    for (std::size_t i = 0; i < 4; ++i) {
        const auto& got = sink.frames()[i];
        EXPECT_TRUE(samePixels(got.image, written.images[i])) << "frame " << i;
        EXPECT_EQ(got.meta.sequence, 100 + i);
        EXPECT_EQ(got.meta.timestamp_ns, written.metas[i].timestamp_ns);
        EXPECT_EQ(got.meta.timestamp_source, TimestampSource::kRecording);
        EXPECT_EQ(got.meta.exposure_us, written.metas[i].exposure_us);
        EXPECT_EQ(got.meta.analog_gain, 1.5);
        EXPECT_EQ(got.meta.status, FrameStatus::kOk);
    }
    EXPECT_EQ(camera->corruptFrames(), 0u);
}

INSTANTIATE_TEST_SUITE_P(Formats, ReplayBitIdentical,
                         ::testing::Values(PixelFormat::kRgb8, PixelFormat::kGray16, PixelFormat::kYuyv,
                                           PixelFormat::kMjpeg),
                         [](const auto& param_info) { return std::string(pixelFormatName(param_info.param)); });

TEST(ReplayMetadata, WithoutMetaCsvSequenceIsTheIndexAndExposureUnknown) {
    TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kGray8, 3, kInterval, 30.0, 32, 24, 50);
    fs::remove(dir.path() / "cam0" / "meta.csv");
    ManualClock clock;
    TestFramePool pool(2);
    FrameSink sink;
    auto camera = openReplay(dir.path(), rate(PlaybackRate::kMax), clock);
    ASSERT_TRUE(camera);
    configureAndStart(*camera, sink, pool);
    ASSERT_TRUE(sink.waitForEvents(1));
    camera->stop();
    EXPECT_EQ(sink.sequences(), (std::vector<std::uint64_t>{0, 1, 2}));
    EXPECT_EQ(sink.metas()[1].exposure_us, 0.0);
}

TEST(ReplayMetadata, SensorWithoutPixelFormatIsReadByContent) {
    // EuRoC sensor.yaml files have no pixel_format: the first frame tells it.
    TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kGray8, 2, kInterval);
    const fs::path sensor = dir.path() / "cam0" / "sensor.yaml";
    std::string text = testing::readText(sensor);
    text.erase(text.find("pixel_format"));
    testing::writeText(sensor, text);
    ManualClock clock;
    auto camera = openReplay(dir.path(), rate(PlaybackRate::kMax), clock);
    ASSERT_TRUE(camera);
    ASSERT_EQ(camera->formats().size(), 1u);
    EXPECT_EQ(camera->formats()[0].format, PixelFormat::kGray8);
}

TEST(ReplayFormats, ConfigureRejectsAnythingElseListingTheOffer) {
    TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kYuyv, 2, kInterval);
    ManualClock clock;
    auto camera = openReplay(dir.path(), rate(PlaybackRate::kMax), clock);
    ASSERT_TRUE(camera);
    for (const hal::StreamConfig& wrong :
         {hal::StreamConfig{PixelFormat::kRgb8, 0, 0, 0}, hal::StreamConfig{PixelFormat::kInvalid, 64, 48, 0},
          hal::StreamConfig{PixelFormat::kInvalid, 0, 0, 60}}) {
        const auto configured = camera->configure(wrong);
        ASSERT_FALSE(configured);
        EXPECT_EQ(configured.error().code, ErrorCode::kUnsupported);
        EXPECT_NE(configured.error().message.find("yuyv 32x24 @30 fps"), std::string::npos)
            << configured.error().message;
        EXPECT_NE(configured.error().message.find(camera->id()), std::string::npos);
    }
    EXPECT_EQ(camera->state(), hal::Camera::State::kOpened);
    const auto exact = camera->configure({PixelFormat::kYuyv, 32, 24, 30});
    ASSERT_TRUE(exact) << exact.error().message;
}

TEST(ReplayFormats, ExposureAndGainCannotBeSet) {
    TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kRgb8, 2, kInterval);
    ManualClock clock;
    auto camera = openReplay(dir.path(), rate(PlaybackRate::kMax), clock);
    ASSERT_TRUE(camera);
    for (hal::Control control : {hal::Control::kExposureUs, hal::Control::kAnalogGain}) {
        const auto set = camera->setControl(control, 100.0);
        ASSERT_FALSE(set);
        EXPECT_EQ(set.error().code, ErrorCode::kUnsupported);
    }
}

// ---- pool exhaustion ------------------------------------------------------------------------

TEST(ReplayPool, FramesWithoutASlotAreSkippedAndCounted) {
    TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kRgb8, 6, kInterval);
    ManualClock clock;
    TestFramePool pool(1);
    FrameHandle held = pool.acquire();  // the test holds the only slot
    ASSERT_TRUE(held);
    FrameSink sink;
    auto camera = openReplay(dir.path(), rate(PlaybackRate::kMax), clock);
    ASSERT_TRUE(camera);
    configureAndStart(*camera, sink, pool);
    ASSERT_TRUE(sink.waitForEvents(1));
    camera->stop();
    EXPECT_EQ(sink.frameCount(), 0u);
    EXPECT_EQ(camera->framesWithoutSlot(), 6u);
}

TEST(ReplayPool, AConsumerHoldingFramesStarvesTheRest) {
    TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kRgb8, 6, kInterval);
    ManualClock clock;
    TestFramePool pool(2);
    FrameSink sink({.hold = 2});
    auto camera = openReplay(dir.path(), rate(PlaybackRate::kMax), clock);
    ASSERT_TRUE(camera);
    configureAndStart(*camera, sink, pool);
    ASSERT_TRUE(sink.waitForEvents(1));
    camera->stop();
    EXPECT_EQ(sink.sequences(), (std::vector<std::uint64_t>{0, 1}));
    EXPECT_EQ(camera->framesWithoutSlot(), 4u);
    sink.releaseHeld();
    EXPECT_EQ(pool.available(), 2u);
}

// ---- through the registry -------------------------------------------------------------------

TEST(ReplayRegistry, OpensFromAUriWithOptions) {
    TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kRgb8, 3, kInterval);
    ManualClock clock;
    hal::CameraRegistry registry;
    registerMockBackends(registry, clock);
    TestFramePool pool(2);
    FrameSink sink;
    auto camera = registry.openConfigured("replay:" + dir.path().string() + "?rate=max&format=rgb8");
    ASSERT_TRUE(camera) << camera.error().message;
    EXPECT_EQ((*camera)->id(), "replay:" + dir.path().string());
    sink.attach(**camera, pool);
    ASSERT_TRUE((*camera)->start());
    ASSERT_TRUE(sink.waitForEvents(1));
    (*camera)->stop();
    EXPECT_EQ(sink.frameCount(), 3u);
}

TEST(ReplayRegistry, BadOptionValuesAreUsageErrors) {
    TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kRgb8, 2, kInterval);
    ManualClock clock;
    hal::CameraRegistry registry;
    registerMockBackends(registry, clock);
    const std::string seq = "replay:" + dir.path().string();
    for (const std::string& uri : {seq + "?rate=fast", seq + "?loop=maybe", seq + "?speed=0", seq + "?speed=x",
                                   seq + "?rate=max&speed=2", seq + "?exposure_us=100", std::string("replay:")}) {
        const auto camera = registry.openConfigured(uri);
        ASSERT_FALSE(camera) << uri;
        EXPECT_TRUE(camera.error().code == ErrorCode::kUsage || camera.error().code == ErrorCode::kUnsupported)
            << uri << ": " << camera.error().message;
    }
    const auto missing = registry.open("replay:" + (dir.path() / "missing").string());
    ASSERT_FALSE(missing);
    EXPECT_EQ(missing.error().code, ErrorCode::kNotFound);
    EXPECT_TRUE(registry.enumerate().cameras.empty()) << "replay cannot enumerate";
}

}  // namespace
}  // namespace commonlight::mocks

namespace commonlight::mocks {
namespace {

// The recording's sensor.yaml says which response its camera applied; a response file is named
// relative to cam0/ and comes back as a path that opens from anywhere.
TEST(ReplayResponse, ReportsTheSequencesResponse) {
    testing::TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kGray8, 2, kInterval, 30.0, 32, 24, 50);
    ManualClock clock;
    for (const auto& [written, expected] : std::vector<std::pair<std::string, std::string>>{
             {"linear", "linear"}, {"gamma:2.2", "gamma:2.2"}, {"curve.yaml", (dir.path() / "cam0" / "curve.yaml").string()}}) {
        std::string yaml = testing::readText(dir.path() / "cam0" / "sensor.yaml");
        const auto at = yaml.find("response:");
        if (at != std::string::npos) yaml.erase(at, yaml.find('\n', at) - at + 1);
        testing::writeText(dir.path() / "cam0" / "sensor.yaml", yaml + "response: " + written + "\n");
        auto camera = openReplay(dir.path(), rate(PlaybackRate::kMax), clock);
        ASSERT_TRUE(camera);
        EXPECT_EQ(camera->responseSpec(), expected);
    }
}

}  // namespace
}  // namespace commonlight::mocks

namespace commonlight::mocks {
namespace {

// The recording's sensor.yaml intrinsics travel with the camera (live needs no --calib for a
// recording); a recording without them reports none.
TEST(ReplayCalibration, ReportsTheSequencesIntrinsics) {
    ManualClock clock;
    {
        testing::TempDir dir;
        writeTestSequence(dir.path(), PixelFormat::kGray8, 2, kInterval);
        auto camera = openReplay(dir.path(), rate(PlaybackRate::kMax), clock);
        ASSERT_TRUE(camera);
        EXPECT_FALSE(camera->calibration().has_value());
    }
    testing::TempDir dir;
    CameraModel model;
    model.width = 32;
    model.height = 24;
    model.fx = 40.0;
    model.fy = 41.0;
    model.cx = 15.5;
    model.cy = 11.25;
    model.distortion.k1 = -0.1;
    SensorInfo sensor;
    sensor.rate_hz = 30.0;
    sensor.camera = model;
    {
        auto writer = SequenceWriter::create(dir.path(), sensor, SequenceWriterOptions{.sync = false});
        ASSERT_TRUE(writer) << writer.error().message;
        FrameMetadata meta;
        meta.timestamp_ns = 1'000'000'000;
        ASSERT_TRUE(writer->write(testing::patternImage(PixelFormat::kGray8, 32, 24, 0), meta));
    }
    auto camera = openReplay(dir.path(), rate(PlaybackRate::kMax), clock);
    ASSERT_TRUE(camera);
    ASSERT_TRUE(camera->calibration().has_value());
    const CameraModel got = *camera->calibration();
    EXPECT_EQ(got.width, 32);
    EXPECT_EQ(got.height, 24);
    EXPECT_NEAR(got.fx, 40.0, 1e-9);
    EXPECT_NEAR(got.fy, 41.0, 1e-9);
    EXPECT_NEAR(got.cx, 15.5, 1e-9);
    EXPECT_NEAR(got.cy, 11.25, 1e-9);
    EXPECT_NEAR(got.distortion.k1, -0.1, 1e-9);
}

}  // namespace
}  // namespace commonlight::mocks

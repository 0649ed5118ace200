#include "hal/camera.h"

#include <cmath>
#include <limits>

#include <gtest/gtest.h>

#include "tests/hal/fake_camera.h"
#include "tests/mocks/mock_test_support.h"

namespace commonlight::hal {
namespace {

using testing::FakeCamera;
using testing::FrameSink;
using testing::TestFramePool;

// Only the required functions: the base class's defaults answer the rest.
class MinimalCamera final : public Camera {
public:
    MinimalCamera() : Camera("minimal:0") {}

private:
    std::vector<StreamFormat> doFormats() const override { return {{PixelFormat::kGray8, 8, 8, {}, 0}}; }
    Result<StreamFormat> doConfigure(const StreamConfig& config) override {
        return negotiate(doFormats(), config, id());
    }
    Result<void> doStart() override { return {}; }
    void doStop() noexcept override {}
};

// ---- state machine --------------------------------------------------------------------------

TEST(CameraStateMachine, StartBeforeConfigureIsAUsageError) {
    TestFramePool pool(2);
    FrameSink sink;
    FakeCamera camera;
    sink.attach(camera, pool);
    const auto started = camera.start();
    ASSERT_FALSE(started);
    EXPECT_EQ(started.error().code, ErrorCode::kUsage);
    EXPECT_EQ(started.error().message, "fake:0: configure() before start()");
    EXPECT_EQ(camera.start_calls, 0);
    EXPECT_EQ(camera.state(), Camera::State::kOpened);
}

TEST(CameraStateMachine, StartNeedsAnAllocatorAndAFrameCallback) {
    TestFramePool pool(1);  // declared before the camera: it must outlive streaming
    FakeCamera camera;
    ASSERT_TRUE(camera.configure({}));
    auto started = camera.start();
    ASSERT_FALSE(started);
    EXPECT_EQ(started.error().code, ErrorCode::kUsage);
    EXPECT_NE(started.error().message.find("frame allocator"), std::string::npos);
    camera.setFrameAllocator(&pool);
    EXPECT_FALSE(camera.start()) << "still no frame callback";
    camera.setFrameCallback([](FrameHandle) {});
    EXPECT_TRUE(camera.start());
    EXPECT_EQ(camera.start_calls, 1);
    EXPECT_EQ(camera.state(), Camera::State::kStreaming);
}

TEST(CameraStateMachine, ConfigureWhileStreamingIsAUsageError) {
    TestFramePool pool(2);
    FrameSink sink;
    FakeCamera camera;
    sink.attach(camera, pool);
    ASSERT_TRUE(camera.configure({PixelFormat::kYuyv, 640, 480, 0}));
    ASSERT_TRUE(camera.start());
    const auto configured = camera.configure({PixelFormat::kMjpeg, 0, 0, 0});
    ASSERT_FALSE(configured);
    EXPECT_EQ(configured.error().code, ErrorCode::kUsage);
    EXPECT_EQ(configured.error().message, "fake:0: cannot configure while streaming");
    EXPECT_EQ(camera.configure_calls, 1);
    EXPECT_EQ(camera.activeFormat().format, PixelFormat::kYuyv);
    EXPECT_EQ(camera.state(), Camera::State::kStreaming);
}

TEST(CameraStateMachine, StartTwiceIsAUsageError) {
    TestFramePool pool(2);
    FrameSink sink;
    FakeCamera camera;
    sink.attach(camera, pool);
    ASSERT_TRUE(camera.configure({}));
    ASSERT_TRUE(camera.start());
    const auto again = camera.start();
    ASSERT_FALSE(again);
    EXPECT_EQ(again.error().message, "fake:0: already streaming");
    EXPECT_EQ(camera.start_calls, 1);
}

TEST(CameraStateMachine, StopTwiceAndStopWhenNotStreamingDoNothing) {
    TestFramePool pool(2);
    FrameSink sink;
    FakeCamera camera;
    camera.stop();
    EXPECT_EQ(camera.stop_calls, 0);
    EXPECT_EQ(camera.state(), Camera::State::kOpened);
    sink.attach(camera, pool);
    ASSERT_TRUE(camera.configure({}));
    camera.stop();
    EXPECT_EQ(camera.stop_calls, 0);
    ASSERT_TRUE(camera.start());
    camera.stop();
    camera.stop();
    EXPECT_EQ(camera.stop_calls, 1);
    EXPECT_EQ(camera.state(), Camera::State::kConfigured);
    ASSERT_TRUE(camera.start()) << "Configured again after stop()";
    camera.stop();
    EXPECT_EQ(camera.stop_calls, 2);
}

TEST(CameraStateMachine, FailedConfigureKeepsTheStateAndTheFormat) {
    FakeCamera camera;
    const auto wrong = camera.configure({PixelFormat::kRgb8, 0, 0, 0});
    ASSERT_FALSE(wrong);
    EXPECT_EQ(wrong.error().code, ErrorCode::kUnsupported);
    EXPECT_EQ(camera.state(), Camera::State::kOpened);
    ASSERT_TRUE(camera.configure({PixelFormat::kMjpeg, 0, 0, 0}));
    const StreamFormat before = camera.activeFormat();
    camera.fail_configure = true;
    const auto failed = camera.configure({PixelFormat::kYuyv, 0, 0, 0});
    ASSERT_FALSE(failed);
    EXPECT_EQ(failed.error().code, ErrorCode::kDevice);
    EXPECT_EQ(camera.state(), Camera::State::kConfigured);
    EXPECT_EQ(camera.activeFormat(), before);
}

TEST(CameraStateMachine, ReconfigureWhileConfiguredIsAllowed) {
    FakeCamera camera;
    ASSERT_TRUE(camera.configure({PixelFormat::kMjpeg, 0, 0, 0}));
    const auto second = camera.configure({PixelFormat::kYuyv, 320, 240, 0});
    ASSERT_TRUE(second);
    EXPECT_EQ(camera.activeFormat(), *second);
    EXPECT_EQ(camera.activeFormat().width, 320);
}

TEST(CameraStateMachine, FailedStartStaysConfigured) {
    TestFramePool pool(2);
    FrameSink sink;
    FakeCamera camera;
    sink.attach(camera, pool);
    ASSERT_TRUE(camera.configure({}));
    camera.fail_start = true;
    const auto started = camera.start();
    ASSERT_FALSE(started);
    EXPECT_EQ(started.error().code, ErrorCode::kDevice);
    EXPECT_EQ(camera.state(), Camera::State::kConfigured);
    camera.stop();
    EXPECT_EQ(camera.stop_calls, 0) << "nothing to stop";
}

TEST(CameraStateMachine, TriggerNeedsAStreamingCamera) {
    TestFramePool pool(2);
    FrameSink sink;
    FakeCamera camera;
    const auto early = camera.trigger();
    ASSERT_FALSE(early);
    EXPECT_EQ(early.error().code, ErrorCode::kUsage);
    EXPECT_EQ(camera.trigger_calls, 0);
    sink.attach(camera, pool);
    ASSERT_TRUE(camera.configure({}));
    ASSERT_TRUE(camera.start());
    EXPECT_TRUE(camera.trigger());
    EXPECT_EQ(camera.trigger_calls, 1);
}

TEST(CameraStateMachine, DefaultsSayUnsupportedNamingTheCameraAndControl) {
    TestFramePool pool(1);
    FrameSink sink;
    MinimalCamera camera;
    sink.attach(camera, pool);
    ASSERT_TRUE(camera.configure({}));
    ASSERT_TRUE(camera.start());
    const auto triggered = camera.trigger();
    ASSERT_FALSE(triggered);
    EXPECT_EQ(triggered.error().code, ErrorCode::kUnsupported);
    EXPECT_EQ(triggered.error().message, "minimal:0: software trigger is not supported");
    const auto set = camera.setControl(Control::kAnalogGain, 2.0);
    ASSERT_FALSE(set);
    EXPECT_EQ(set.error().code, ErrorCode::kUnsupported);
    EXPECT_EQ(set.error().message, "minimal:0: control gain is not supported");
    EXPECT_EQ(camera.getControl(Control::kFrameRate).error().code, ErrorCode::kUnsupported);
    EXPECT_TRUE(camera.controls().empty());
    camera.stop();
}

TEST(CameraStateMachine, ControlsRejectNonFiniteValues) {
    FakeCamera camera;
    for (double bad : {std::nan(""), std::numeric_limits<double>::infinity()}) {
        const auto set = camera.setControl(Control::kExposureUs, bad);
        ASSERT_FALSE(set);
        EXPECT_EQ(set.error().code, ErrorCode::kUsage);
        EXPECT_NE(set.error().message.find("exposure_us"), std::string::npos);
    }
    ASSERT_TRUE(camera.setControl(Control::kExposureUs, 500));
    EXPECT_EQ(camera.getControl(Control::kExposureUs).value(), 500);
    ASSERT_EQ(camera.controls().size(), 1u);
}

TEST(CameraStateMachine, FramesAndEventsArriveOnTheCameraThread) {
    TestFramePool pool(8);
    FrameSink sink;
    FakeCamera camera;
    camera.frames_per_stream = 5;
    sink.attach(camera, pool);
    ASSERT_TRUE(camera.configure({}));
    ASSERT_TRUE(camera.start());
    ASSERT_TRUE(sink.waitForEvents(1));
    camera.stop();
    EXPECT_EQ(sink.sequences(), (std::vector<std::uint64_t>{0, 1, 2, 3, 4}));
    EXPECT_EQ(sink.events()[0].type, CameraEvent::Type::kEndOfStream);
    EXPECT_EQ(camera.framesWithoutSlot(), 0u);
    EXPECT_EQ(pool.available(), 8u) << "every slot came back";
}

TEST(CameraStateMachine, AnExhaustedPoolIsCounted) {
    TestFramePool pool(1);
    FrameHandle held = pool.acquire();
    FrameSink sink;
    FakeCamera camera;
    camera.frames_per_stream = 4;
    sink.attach(camera, pool);
    ASSERT_TRUE(camera.configure({}));
    ASSERT_TRUE(camera.start());
    ASSERT_TRUE(sink.waitForEvents(1));
    camera.stop();
    EXPECT_EQ(sink.frameCount(), 0u);
    EXPECT_EQ(camera.framesWithoutSlot(), 4u);
}

// ---- negotiation ----------------------------------------------------------------------------

const std::vector<StreamFormat> kOffers = {{PixelFormat::kYuyv, 640, 480, {30, 15}, 0},
                                           {PixelFormat::kMjpeg, 1280, 720, {30}, 0},
                                           {PixelFormat::kYuyv, 320, 240, {60, 30}, 0},
                                           {PixelFormat::kGray8, 800, 600, {}, 0}};

TEST(Negotiate, FreeSizePicksTheLargestMatch) {
    auto any = negotiate(kOffers, {}, "dev");
    ASSERT_TRUE(any);
    EXPECT_EQ(any->format, PixelFormat::kMjpeg);
    EXPECT_EQ(any->fps, 30.0) << "the highest offered rate when none is asked";
    auto yuyv = negotiate(kOffers, {PixelFormat::kYuyv, 0, 0, 0}, "dev");
    ASSERT_TRUE(yuyv);
    EXPECT_EQ(yuyv->width, 640);
}

TEST(Negotiate, SizeAndRateMustMatch) {
    auto small = negotiate(kOffers, {PixelFormat::kInvalid, 320, 240, 0}, "dev");
    ASSERT_TRUE(small);
    EXPECT_EQ(small->format, PixelFormat::kYuyv);
    EXPECT_EQ(small->fps, 60.0);
    auto at60 = negotiate(kOffers, {PixelFormat::kYuyv, 0, 0, 60}, "dev");
    ASSERT_TRUE(at60);
    EXPECT_EQ(at60->width, 320);
    EXPECT_EQ(at60->fps, 60.0);
    auto gray = negotiate(kOffers, {PixelFormat::kGray8, 0, 0, 24}, "dev");
    ASSERT_TRUE(gray) << "a format without listed rates takes any rate";
    EXPECT_EQ(gray->fps, 24.0);
}

TEST(Negotiate, ARateWithinOnePercentGetsTheRateTheDeviceOffers) {
    auto ntsc = negotiate(kOffers, {PixelFormat::kMjpeg, 0, 0, 29.97}, "dev");
    ASSERT_TRUE(ntsc);
    EXPECT_EQ(ntsc->fps, 30.0) << "the device runs at 30, not at 29.97";
    EXPECT_FALSE(negotiate(kOffers, {PixelFormat::kMjpeg, 0, 0, 29.0}, "dev"));
}

TEST(Negotiate, TheErrorListsTheOffersAndNamesTheDevice) {
    const auto none = negotiate(kOffers, {PixelFormat::kRgb8, 1920, 1080, 30}, "v4l2:/dev/video0");
    ASSERT_FALSE(none);
    EXPECT_EQ(none.error().code, ErrorCode::kUnsupported);
    EXPECT_EQ(none.error().message,
              "v4l2:/dev/video0: cannot stream rgb8 1920x1080 @30 fps; the device offers:\n"
              "  yuyv 640x480 @30/15 fps\n"
              "  mjpeg 1280x720 @30 fps\n"
              "  yuyv 320x240 @60/30 fps\n"
              "  gray8 800x600");
    const auto empty = negotiate({}, {}, "dev");
    ASSERT_FALSE(empty);
    EXPECT_NE(empty.error().message.find("offers: nothing"), std::string::npos);
}

TEST(Negotiate, DescribeAndControlNames) {
    EXPECT_EQ(describe({PixelFormat::kNv12, 1920, 1080, {}, 25}), "nv12 1920x1080 @25 fps");
    EXPECT_EQ(controlName(Control::kExposureUs), "exposure_us");
    EXPECT_EQ(controlName(Control::kAnalogGain), "gain");
    EXPECT_EQ(controlName(Control::kFrameRate), "fps");
}

}  // namespace
}  // namespace commonlight::hal

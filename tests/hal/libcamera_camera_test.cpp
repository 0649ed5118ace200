// LibcameraCamera against a fake libcamera device (tests/hal/fake_libcamera_device.h): the
// state machine, negotiation and validation, streaming with requeued requests, controls on
// requests, metadata, cancelled requests on stop, disconnect, and no allocation per frame.
#include "hal/libcamera/libcamera_camera.h"

#include <memory>

#include <gtest/gtest.h>

#include "bench/alloc_counter.h"
#include "tests/hal/fake_libcamera_device.h"
#include "tests/mocks/mock_test_support.h"

namespace commonlight::hal::libcamera_backend {
namespace {

using testing::FakeLibcameraDevice;
using testing::FrameSink;
using testing::TestFramePool;

struct Rig {
    explicit Rig(LibcameraOptions options = {}) {
        auto owned = std::make_unique<FakeLibcameraDevice>();
        device = owned.get();
        camera = std::make_unique<LibcameraCamera>("libcamera:0", std::move(owned), options);
    }
    FakeLibcameraDevice* device = nullptr;
    std::unique_ptr<LibcameraCamera> camera;
};

TEST(LibcameraCamera, FormatsAreWhatTheRoleOffersInOurTerms) {
    Rig rig;
    const auto formats = rig.camera->formats();
    ASSERT_EQ(formats.size(), 5u) << "the packed Bayer format is left out";
    EXPECT_EQ(formats[0], (StreamFormat{PixelFormat::kYuyv, 640, 480, {}, 0}));
    EXPECT_EQ(formats[4], (StreamFormat{PixelFormat::kBgr8, 32, 24, {}, 0}));
}

TEST(LibcameraCamera, ConfigurePassesRoleFormatAndBufferCount) {
    Rig rig({StreamRole::kVideoRecording, 6});
    const auto configured = rig.camera->configure({PixelFormat::kYuyv, 320, 240, 0});
    ASSERT_TRUE(configured) << configured.error().message;
    EXPECT_EQ(*configured, (StreamFormat{PixelFormat::kYuyv, 320, 240, {}, 0}));
    EXPECT_EQ(rig.device->last_role, StreamRole::kVideoRecording);
    EXPECT_EQ(rig.device->last_wanted.format.fourcc, kFourccYuyv);
    EXPECT_EQ(rig.device->last_wanted.width, 320);
    EXPECT_EQ(rig.device->last_wanted.buffer_count, 6u);
    EXPECT_EQ(rig.camera->deviceConfig().stride, 640u);
}

TEST(LibcameraCamera, UnavailableFormatListsTheOffer) {
    Rig rig;
    const auto configured = rig.camera->configure({PixelFormat::kGray8, 0, 0, 0});
    ASSERT_FALSE(configured);
    EXPECT_EQ(configured.error().code, ErrorCode::kUnsupported);
    EXPECT_NE(configured.error().message.find("libcamera:0: cannot stream gray8; the device offers:\n  yuyv 640x480"),
              std::string::npos)
        << configured.error().message;
    EXPECT_EQ(rig.device->configure_calls, 0);
}

TEST(LibcameraCamera, FrameRateOutsideTheLimitsIsRejected) {
    Rig rig;
    const auto configured = rig.camera->configure({PixelFormat::kYuyv, 640, 480, 120});
    ASSERT_FALSE(configured);
    EXPECT_EQ(configured.error().code, ErrorCode::kUsage);
    EXPECT_NE(configured.error().message.find("fps 120 is outside the camera's range [0.99, 30.3"), std::string::npos)
        << configured.error().message;
}

TEST(LibcameraCamera, InvalidConfigurationIsAUsageError) {
    Rig rig;
    rig.device->configure_override = ConfigureResult{ValidationStatus::kInvalid, {}};
    const auto configured = rig.camera->configure({PixelFormat::kYuyv, 640, 480, 0});
    ASSERT_FALSE(configured);
    EXPECT_EQ(configured.error().code, ErrorCode::kUsage);
    EXPECT_NE(configured.error().message.find("libcamera rejected the configuration yuyv 640x480; the camera offers:"),
              std::string::npos);
    EXPECT_EQ(rig.camera->state(), Camera::State::kOpened);
}

TEST(LibcameraCamera, AdjustedConfigurationBecomesTheActiveFormat) {
    Rig rig;
    DeviceStreamConfig adjusted{{kFourccYuyv, 0}, 320, 240, 640, 640 * 240, 4};
    rig.device->configure_override = ConfigureResult{ValidationStatus::kAdjusted, adjusted};
    const auto configured = rig.camera->configure({PixelFormat::kYuyv, 640, 480, 0});
    ASSERT_TRUE(configured);
    EXPECT_EQ(configured->width, 320);
    EXPECT_EQ(rig.camera->activeFormat().height, 240);
}

TEST(LibcameraCamera, StreamsFramesWithDeviceMetadataAndRequeuesEveryRequest) {
    TestFramePool pool(8);
    FrameSink sink(FrameSink::Options{.keep_images = true});
    Rig rig({StreamRole::kViewfinder, 3});
    rig.device->row_padding = 16;
    rig.device->first_sequence = 100;
    rig.device->drop_sequences = {103, 104};
    rig.device->max_frames = 20;
    sink.attach(*rig.camera, pool);
    ASSERT_TRUE(rig.camera->configure({PixelFormat::kYuyv, 320, 240, 0}));
    ASSERT_TRUE(rig.camera->start());
    ASSERT_TRUE(sink.waitForFrames(20));
    rig.camera->stop();

    EXPECT_EQ(rig.device->allocate_calls, 1);
    EXPECT_EQ(rig.device->indicesSeen(), (std::set<unsigned>{0, 1, 2}));
    // 3 initial queues + one requeue per completed request.
    EXPECT_EQ(rig.device->queueCalls(), 3u + 20u);
    EXPECT_EQ(rig.device->cancelledOnStop(), 3u) << "the three requeued requests come back cancelled";
    EXPECT_EQ(rig.device->queueCallsAfterStop(), 0u) << "cancelled requests are not requeued";
    ASSERT_EQ(sink.frameCount(), 20u) << "cancelled requests are not frames";

    const auto& frames = sink.frames();
    EXPECT_EQ(frames[0].meta.sequence, 100u);
    EXPECT_EQ(frames[2].meta.sequence, 102u);
    EXPECT_EQ(frames[3].meta.sequence, 105u) << "the gap shows the frames the device lost";
    for (const auto& f : frames) {
        EXPECT_EQ(f.meta.timestamp_source, TimestampSource::kSensor);
        EXPECT_EQ(f.meta.timestamp_ns, 4'990'000'000ll + static_cast<std::int64_t>(f.meta.sequence) * 33'333'333ll);
        EXPECT_EQ(f.meta.exposure_us, 10000.0);
        EXPECT_EQ(f.meta.analog_gain, 2.0);
        EXPECT_EQ(f.meta.status, FrameStatus::kOk);
        EXPECT_GT(f.meta.arrival_ns, 0);
        ASSERT_EQ(f.image.format(), PixelFormat::kYuyv);
        ASSERT_EQ(f.image.width(), 320);
        ASSERT_EQ(f.image.stride(), 640u) << "the device's 16 bytes of row padding are dropped";
        // Row 1 starts at byte 656 of the device buffer (stride 640 + 16).
        const auto seq = static_cast<std::uint8_t>(f.meta.sequence);
        EXPECT_EQ(f.image.view().row(1)[0], static_cast<std::uint8_t>(656 * 7 + seq));
        EXPECT_EQ(f.image.view().row(239)[639], static_cast<std::uint8_t>((239 * 656 + 639) * 7 + seq));
    }
    EXPECT_EQ(pool.available(), 8u);
}

TEST(LibcameraCamera, DriverTimestampWhenNoSensorTimestamp) {
    TestFramePool pool(4);
    FrameSink sink;
    Rig rig;
    rig.device->report_sensor_timestamp = false;
    rig.device->max_frames = 2;
    sink.attach(*rig.camera, pool);
    ASSERT_TRUE(rig.camera->configure({PixelFormat::kNv12, 0, 0, 0}));
    ASSERT_TRUE(rig.camera->start());
    ASSERT_TRUE(sink.waitForFrames(2));
    rig.camera->stop();
    const auto metas = sink.metas();
    EXPECT_EQ(metas[1].timestamp_source, TimestampSource::kDriver);
    EXPECT_EQ(metas[1].timestamp_ns, 5'000'000'000ll + 33'333'333ll);
}

TEST(LibcameraCamera, FailedBuffersAreMarkedCorrupt) {
    TestFramePool pool(4);
    FrameSink sink;
    Rig rig;
    rig.device->fail_frames = true;
    rig.device->max_frames = 3;
    sink.attach(*rig.camera, pool);
    ASSERT_TRUE(rig.camera->configure({PixelFormat::kMjpeg, 0, 0, 0}));
    ASSERT_TRUE(rig.camera->start());
    ASSERT_TRUE(sink.waitForFrames(3));
    rig.camera->stop();
    for (const auto& m : sink.metas()) EXPECT_EQ(m.status, FrameStatus::kCorrupt);
    EXPECT_EQ(rig.camera->failedRequests(), 3u);
}

TEST(LibcameraCamera, ControlsGoOutOnTheNextRequestAndComeBackInMetadata) {
    TestFramePool pool(4);
    FrameSink sink;
    Rig rig;
    rig.device->max_frames = 2;
    sink.attach(*rig.camera, pool);
    ASSERT_TRUE(rig.camera->configure({PixelFormat::kYuyv, 640, 480, 15}));
    ASSERT_TRUE(rig.camera->setControl(Control::kAutoExposure, 1));
    ASSERT_TRUE(rig.camera->start());
    EXPECT_EQ(rig.device->start_controls.frame_duration_us, 66667) << "the URI's fps goes out with start()";
    EXPECT_EQ(rig.device->start_controls.ae_enable, true);
    ASSERT_TRUE(sink.waitForFrames(2));

    // Lock the exposure the way `live` does: read what AE chose, then fix it.
    const auto chosen = rig.camera->getControl(Control::kExposureUs);
    ASSERT_TRUE(chosen);
    EXPECT_EQ(*chosen, 10000.0) << "the value the last request's metadata reported";
    ASSERT_TRUE(rig.camera->setControl(Control::kAutoExposure, 0));
    ASSERT_TRUE(rig.camera->setControl(Control::kExposureUs, 20000));
    ASSERT_TRUE(rig.camera->setControl(Control::kAnalogGain, 4));
    ASSERT_TRUE(rig.camera->setControl(Control::kAutoWhiteBalance, 0));
    rig.device->allowMore(4);
    ASSERT_TRUE(sink.waitForFrames(6));
    rig.camera->stop();

    const auto applied = rig.device->applied();
    EXPECT_EQ(applied.ae_enable, false);
    EXPECT_EQ(applied.awb_enable, false);
    EXPECT_EQ(applied.exposure_time_us, 20000);
    EXPECT_EQ(applied.analogue_gain, 4.0f);
    EXPECT_EQ(rig.device->queuesWithControls(), 1u) << "pending controls go out once";
    const auto metas = sink.metas();
    EXPECT_EQ(metas.back().exposure_us, 20000.0);
    EXPECT_EQ(metas.back().analog_gain, 4.0);
    EXPECT_EQ(rig.camera->getControl(Control::kExposureUs).value(), 20000.0);
    EXPECT_EQ(rig.camera->getControl(Control::kAnalogGain).value(), 4.0);
    EXPECT_EQ(rig.camera->getControl(Control::kAutoExposure).value(), 0.0);
    EXPECT_EQ(rig.camera->getControl(Control::kAutoWhiteBalance).value(), 0.0);
    EXPECT_NEAR(rig.camera->getControl(Control::kFrameRate).value(), 15.0, 0.01);
}

TEST(LibcameraCamera, ControlsTheCameraLacksAreUnsupported) {
    auto owned = std::make_unique<FakeLibcameraDevice>();
    owned->controls_ = DeviceControls{};
    owned->controls_.analogue_gain = DeviceRange{1, 8, 1};
    LibcameraCamera camera("libcamera:usb-cam", std::move(owned));
    ASSERT_EQ(camera.controls().size(), 1u);
    const auto set = camera.setControl(Control::kExposureUs, 1000);
    ASSERT_FALSE(set);
    EXPECT_EQ(set.error().code, ErrorCode::kUnsupported);
    EXPECT_EQ(set.error().message, "libcamera:usb-cam: control exposure_us is not supported by this camera");
    EXPECT_FALSE(camera.getControl(Control::kAutoExposure));
    EXPECT_EQ(camera.getControl(Control::kAnalogGain).value(), 1.0) << "the default before any frame";
    const auto fps = camera.configure({PixelFormat::kYuyv, 640, 480, 30});
    ASSERT_FALSE(fps);
    EXPECT_EQ(fps.error().code, ErrorCode::kUnsupported);
}

TEST(LibcameraCamera, DisconnectEndsTheStreamWithADeviceErrorNamingTheCamera) {
    TestFramePool pool(4);
    FrameSink sink;
    Rig rig;
    rig.device->max_frames = 3;
    sink.attach(*rig.camera, pool);
    ASSERT_TRUE(rig.camera->configure({}));
    ASSERT_TRUE(rig.camera->start());
    ASSERT_TRUE(sink.waitForFrames(3));
    rig.device->disconnect();
    ASSERT_TRUE(sink.waitForEvents(1));
    rig.device->allowMore(10);  // a late completion after the disconnect is not delivered
    rig.device->disconnect();   // and a second signal raises no second event
    rig.camera->stop();
    const auto events = sink.events();
    ASSERT_EQ(events.size(), 1u);
    EXPECT_EQ(events[0].type, CameraEvent::Type::kDeviceError);
    EXPECT_EQ(events[0].error.code, ErrorCode::kDevice);
    EXPECT_EQ(events[0].error.message, "libcamera:0: camera disconnected (libcamera camera /base/fake/sensor@10)");
    EXPECT_EQ(sink.frameCount(), 3u);

    // The camera can be started again (a reconnect reopens it; the state machine allows it).
    ASSERT_TRUE(rig.camera->start());
    rig.camera->stop();
}

TEST(LibcameraCamera, FullPoolCountsFramesWithoutSlotAndKeepsRequeueing) {
    TestFramePool pool(2);
    FrameSink sink(FrameSink::Options{.hold = 2});  // the consumer keeps both slots
    Rig rig;
    rig.device->max_frames = 10;
    sink.attach(*rig.camera, pool);
    ASSERT_TRUE(rig.camera->configure({PixelFormat::kYuyv, 320, 240, 0}));
    ASSERT_TRUE(rig.camera->start());
    ASSERT_TRUE(sink.waitForFrames(2));
    // Every completion requeues (4 initial queues + 10): then all 10 were handled.
    while (rig.device->queueCalls() < 14) std::this_thread::yield();
    rig.camera->stop();
    EXPECT_EQ(sink.frameCount(), 2u);
    EXPECT_EQ(rig.camera->framesWithoutSlot(), 8u);
    EXPECT_EQ(rig.device->queueCalls(), 4u + 10u) << "requests went back even without a slot";
    sink.releaseHeld();
}

TEST(LibcameraCamera, NoAllocationPerFrameInSteadyState) {
    for (PixelFormat format : {PixelFormat::kYuyv, PixelFormat::kNv12, PixelFormat::kMjpeg}) {
        SCOPED_TRACE(std::string(pixelFormatName(format)));
        TestFramePool pool(4);
        std::atomic<std::size_t> frames{0};
        Rig rig;
        rig.device->max_frames = 20;
        rig.camera->setFrameAllocator(&pool);
        rig.camera->setFrameCallback([&](FrameHandle) { frames.fetch_add(1); });
        ASSERT_TRUE(rig.camera->configure({format, 0, 0, 0}));
        ASSERT_TRUE(rig.camera->start());
        while (frames.load() < 20) std::this_thread::yield();  // warm-up sizes every slot
        ASSERT_TRUE(rig.camera->setControl(Control::kExposureUs, 5000));
        const std::uint64_t before = bench::allocationCount();
        rig.device->allowMore(200);
        while (frames.load() < 220) std::this_thread::yield();
        const std::uint64_t allocations = bench::allocationCount() - before;
        rig.camera->stop();
        EXPECT_EQ(allocations, 0u);
        EXPECT_EQ(rig.device->applied().exposure_time_us, 5000);
    }
}

}  // namespace
}  // namespace commonlight::hal::libcamera_backend

#include "mocks/fault_injecting_camera.h"

#include <gtest/gtest.h>

#include "hal/registry.h"
#include "mocks/register.h"
#include "mocks/replay_camera.h"
#include "tests/mocks/mock_test_support.h"
#include "tests/test_support.h"

namespace commonlight::mocks {
namespace {

namespace fs = std::filesystem;
using testing::FrameSink;
using testing::TempDir;
using testing::TestFramePool;

constexpr std::int64_t kInterval = 33'333'333;

// A ten-frame sequence whose recorded sequence numbers are 1..10, opened through the registry
// (so the fault_* options travel in the URI, as on the command line).
class FaultInjection : public ::testing::Test {
protected:
    void SetUp() override {
        written_ = testing::writeTestSequence(dir_.path(), PixelFormat::kRgb8, 10, kInterval, 30.0, 32, 24, 1);
        registerMockBackends(registry_, clock_);
    }

    // Opens "replay:SEQ?rate=max&<options>", configured, with the sink attached.
    std::unique_ptr<hal::Camera> open(const std::string& options, const std::string& rate = "max") {
        auto camera = registry_.openConfigured("replay:" + dir_.path().string() + "?rate=" + rate + "&" + options);
        if (!camera) {
            ADD_FAILURE() << camera.error().message;
            return nullptr;
        }
        sink_.attach(**camera, pool_);
        return std::move(*camera);
    }
    static FaultInjectingCamera& faults(hal::Camera& camera) {
        auto* wrapper = dynamic_cast<FaultInjectingCamera*>(&camera);
        if (wrapper == nullptr) throw std::runtime_error("not a fault injecting camera");
        return *wrapper;
    }

    TempDir dir_;
    testing::TestSequence written_;
    ManualClock clock_;
    hal::CameraRegistry registry_;
    TestFramePool pool_{3};
    FrameSink sink_{{.keep_images = true}};
};

TEST_F(FaultInjection, DropEveryThirdLeavesSequenceGaps) {
    auto camera = open("fault_drop_every=3");
    ASSERT_TRUE(camera);
    ASSERT_TRUE(camera->start());
    ASSERT_TRUE(sink_.waitForEvents(1));
    camera->stop();
    EXPECT_EQ(sink_.sequences(), (std::vector<std::uint64_t>{1, 2, 4, 5, 7, 8, 10}));
    EXPECT_EQ(faults(*camera).framesDropped(), 3u);
    EXPECT_EQ(faults(*camera).framesDelivered(), 7u);
    EXPECT_EQ(camera->framesWithoutSlot(), 0u) << "a drop at the device is not a pool shortage";
    EXPECT_EQ(sink_.events()[0].type, hal::CameraEvent::Type::kEndOfStream)
        << "the end of the recording passes through";
}

TEST_F(FaultInjection, StallBlocksTheCameraThreadOnTheClock) {
    auto camera = open("fault_stall_at=4&fault_stall_ms=500");
    ASSERT_TRUE(camera);
    ASSERT_TRUE(camera->start());
    // Frames 1-3 come at once (rate=max), then the thread parks on the clock before frame 4.
    clock_.waitForSleepers(1);
    EXPECT_EQ(sink_.frameCount(), 3u);
    EXPECT_EQ(faults(*camera).framesStalled(), 1u);
    clock_.advance(499'999'999);
    clock_.waitForSleepers(1);
    EXPECT_EQ(sink_.frameCount(), 3u);
    clock_.advance(1);
    ASSERT_TRUE(sink_.waitForEvents(1));
    camera->stop();
    const auto metas = sink_.metas();
    ASSERT_EQ(metas.size(), 10u);
    EXPECT_EQ(metas[2].arrival_ns, 0);
    EXPECT_EQ(metas[3].arrival_ns, 500'000'000) << "the stalled frame arrives late";
    EXPECT_EQ(metas[3].sequence, 4u);
    EXPECT_EQ(faults(*camera).framesStalled(), 1u);
}

TEST_F(FaultInjection, StopInterruptsAStall) {
    auto camera = open("fault_stall_at=2&fault_stall_ms=3600000");
    ASSERT_TRUE(camera);
    ASSERT_TRUE(camera->start());
    clock_.waitForSleepers(1);
    camera->stop();
    EXPECT_EQ(sink_.frameCount(), 1u);
    EXPECT_EQ(sink_.eventCount(), 0u);
}

TEST_F(FaultInjection, CorruptAtKMarksAndScramblesExactlyThatFrame) {
    auto camera = open("fault_corrupt_at=5");
    ASSERT_TRUE(camera);
    ASSERT_TRUE(camera->start());
    ASSERT_TRUE(sink_.waitForEvents(1));
    camera->stop();
    ASSERT_EQ(sink_.frames().size(), 10u);
    for (std::size_t i = 0; i < 10; ++i) {
        const auto& frame = sink_.frames()[i];
        if (i == 4) {
            EXPECT_EQ(frame.meta.status, FrameStatus::kCorrupt);
            EXPECT_FALSE(samePixels(frame.image, written_.images[i]));
            EXPECT_EQ(frame.image.sizeBytes(), written_.images[i].sizeBytes());
        } else {
            EXPECT_EQ(frame.meta.status, FrameStatus::kOk) << i;
            EXPECT_TRUE(samePixels(frame.image, written_.images[i])) << i;
        }
    }
    EXPECT_EQ(faults(*camera).framesCorrupted(), 1u);
}

TEST_F(FaultInjection, DisconnectAfterNGivesNFramesThenOneDeviceError) {
    auto camera = open("fault_disconnect_after=5");
    ASSERT_TRUE(camera);
    ASSERT_TRUE(camera->start());
    ASSERT_TRUE(sink_.waitForEvents(1));
    auto& wrapper = faults(*camera);
    EXPECT_TRUE(wrapper.disconnected());
    const auto triggered = camera->trigger();
    ASSERT_FALSE(triggered);
    EXPECT_EQ(triggered.error().code, ErrorCode::kDevice);
    camera->stop();
    EXPECT_EQ(sink_.sequences(), (std::vector<std::uint64_t>{1, 2, 3, 4, 5}));
    const auto events = sink_.events();
    ASSERT_EQ(events.size(), 1u) << "no end of stream after the device went away";
    EXPECT_EQ(events[0].type, hal::CameraEvent::Type::kDeviceError);
    EXPECT_EQ(events[0].error.code, ErrorCode::kDevice);
    EXPECT_EQ(events[0].error.message, "replay:" + dir_.path().string() + ": device disconnected (fault injection)");
    EXPECT_EQ(wrapper.inner().state(), hal::Camera::State::kConfigured) << "the wrapped camera was stopped";
    EXPECT_EQ(camera->state(), hal::Camera::State::kConfigured);
}

TEST_F(FaultInjection, DisconnectInRealtimeLeavesNothingOnTheClock) {
    auto camera = open("fault_disconnect_after=2", "realtime");
    ASSERT_TRUE(camera);
    ASSERT_TRUE(camera->start());
    ASSERT_TRUE(sink_.waitForFrames(1));
    clock_.waitForSleepers(1);
    clock_.advance(kInterval);
    ASSERT_TRUE(sink_.waitForEvents(1));
    camera->stop();
    EXPECT_EQ(clock_.sleepers(), 0);
    EXPECT_EQ(sink_.frameCount(), 2u);
    EXPECT_EQ(sink_.eventCount(), 1u);
    EXPECT_EQ(faults(*camera).inner().state(), hal::Camera::State::kConfigured);
}

TEST_F(FaultInjection, RestartAfterADisconnectReconnects) {
    auto camera = open("fault_disconnect_after=2");
    ASSERT_TRUE(camera);
    ASSERT_TRUE(camera->start());
    ASSERT_TRUE(sink_.waitForEvents(1));
    camera->stop();
    ASSERT_TRUE(camera->start());
    ASSERT_TRUE(sink_.waitForEvents(2));
    camera->stop();
    EXPECT_EQ(sink_.sequences(), (std::vector<std::uint64_t>{1, 2, 1, 2}));
}

TEST_F(FaultInjection, FaultsCombineInArrivalOrder) {
    auto camera = open("fault_drop_every=2&fault_corrupt_at=3&fault_disconnect_after=3");
    ASSERT_TRUE(camera);
    ASSERT_TRUE(camera->start());
    ASSERT_TRUE(sink_.waitForEvents(1));
    camera->stop();
    // Arrivals 1..: 2, 4 dropped; 3 corrupt; the third delivered frame is arrival 5.
    EXPECT_EQ(sink_.sequences(), (std::vector<std::uint64_t>{1, 3, 5}));
    EXPECT_EQ(sink_.metas()[1].status, FrameStatus::kCorrupt);
    EXPECT_EQ(sink_.events().at(0).type, hal::CameraEvent::Type::kDeviceError);
}

TEST_F(FaultInjection, FormatsConfigureAndTriggerAreForwarded) {
    auto camera = open("fault_drop_every=100", "step");
    ASSERT_TRUE(camera);
    auto& wrapper = faults(*camera);
    EXPECT_EQ(camera->id(), wrapper.inner().id());
    EXPECT_EQ(camera->formats(), wrapper.inner().formats());
    EXPECT_EQ(camera->activeFormat(), wrapper.inner().activeFormat());
    EXPECT_EQ(camera->setControl(hal::Control::kExposureUs, 10).error().code, ErrorCode::kUnsupported);
    const auto wrong = camera->configure({PixelFormat::kGray16, 0, 0, 0});
    ASSERT_FALSE(wrong);
    EXPECT_NE(wrong.error().message.find("rgb8 32x24"), std::string::npos) << wrong.error().message;
    ASSERT_TRUE(camera->start());
    ASSERT_TRUE(camera->trigger());
    ASSERT_TRUE(camera->trigger());
    ASSERT_TRUE(sink_.waitForFrames(2));
    camera->stop();
    EXPECT_EQ(sink_.sequences(), (std::vector<std::uint64_t>{1, 2}));
}

TEST_F(FaultInjection, PoolShortageIsCountedOnTheWrapper) {
    FrameHandle a = pool_.acquire();
    FrameHandle b = pool_.acquire();
    FrameHandle c = pool_.acquire();
    auto camera = open("fault_drop_every=2");
    ASSERT_TRUE(camera);
    ASSERT_TRUE(camera->start());
    ASSERT_TRUE(sink_.waitForEvents(1));
    camera->stop();
    EXPECT_EQ(camera->framesWithoutSlot(), 10u);
    EXPECT_EQ(sink_.frameCount(), 0u);
}

TEST_F(FaultInjection, BadOptionsAreUsageErrors) {
    const std::string seq = "replay:" + dir_.path().string() + "?";
    for (const std::string options : {"fault_stall_ms=100", "fault_stall_at=3", "fault_drop_every=-1",
                                      "fault_corrupt_at=x", "fault_disconnect_after=1.5", "fault_bogus=1"}) {
        const auto camera = registry_.open(seq + options);
        ASSERT_FALSE(camera) << options;
        EXPECT_EQ(camera.error().code, ErrorCode::kUsage) << options;
        EXPECT_NE(camera.error().message.find("fault_"), std::string::npos) << camera.error().message;
    }
}

TEST(FaultInjectionDirect, WrapsAnyCameraWithoutTheRegistry) {
    TempDir dir;
    testing::writeTestSequence(dir.path(), PixelFormat::kGray8, 4, kInterval);
    ManualClock clock;
    auto replay = ReplayCamera::open(dir.path(), PlaybackOptions{PlaybackRate::kMax, false, 1.0}, clock);
    ASSERT_TRUE(replay);
    FaultOptions options;
    options.drop_every = 2;
    auto wrapped = FaultInjectingCamera::wrap(std::move(*replay), options, clock);
    ASSERT_TRUE(wrapped) << wrapped.error().message;
    TestFramePool pool(2);
    FrameSink sink;
    sink.attach(**wrapped, pool);
    ASSERT_TRUE((*wrapped)->configure({}));
    ASSERT_TRUE((*wrapped)->start());
    ASSERT_TRUE(sink.waitForEvents(1));
    (*wrapped)->stop();
    EXPECT_EQ(sink.sequences(), (std::vector<std::uint64_t>{0, 2}));

    FaultOptions bad;
    bad.stall_ms = 10;
    EXPECT_FALSE(bad.validate());
    EXPECT_EQ(FaultInjectingCamera::wrap(nullptr, options, clock).error().code, ErrorCode::kInternal);
}

}  // namespace
}  // namespace commonlight::mocks

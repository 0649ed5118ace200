#include "mocks/replay_camera.h"

#include <chrono>

#include <gtest/gtest.h>

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

// ---- pacing ---------------------------------------------------------------------------------

TEST(ReplayPacing, RealtimeOneIntervalReleasesExactlyOneFrame) {
    TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kRgb8, 5, kInterval);
    ManualClock clock(5'000);
    TestFramePool pool(4);
    FrameSink sink;
    auto camera = openReplay(dir.path(), rate(PlaybackRate::kRealtime), clock);
    ASSERT_TRUE(camera);
    configureAndStart(*camera, sink, pool);

    // The first frame is due at once; then the thread parks on the clock until the next one.
    ASSERT_TRUE(sink.waitForFrames(1));
    clock.waitForSleepers(1);
    EXPECT_EQ(sink.frameCount(), 1u);
    for (std::size_t n = 2; n <= 5; ++n) {
        clock.advance(kInterval - 1);
        clock.waitForSleepers(1);
        EXPECT_EQ(sink.frameCount(), n - 1) << "one nanosecond early";
        clock.advance(1);
        ASSERT_TRUE(sink.waitForFrames(n));
        if (n < 5) {
            clock.waitForSleepers(1);
            EXPECT_EQ(sink.frameCount(), n);
        }
    }
    ASSERT_TRUE(sink.waitForEvents(1));
    camera->stop();
    const auto metas = sink.metas();
    ASSERT_EQ(metas.size(), 5u);
    for (std::size_t i = 0; i < metas.size(); ++i) {
        EXPECT_EQ(metas[i].arrival_ns, 5'000 + static_cast<std::int64_t>(i) * kInterval);
        EXPECT_EQ(metas[i].timestamp_ns, 1'000'000'000 + static_cast<std::int64_t>(i) * kInterval);
        EXPECT_EQ(metas[i].timestamp_source, TimestampSource::kRecording);
    }
    EXPECT_EQ(sink.events().at(0).type, hal::CameraEvent::Type::kEndOfStream);
}

TEST(ReplayPacing, SpeedTwoHalvesTheInterval) {
    TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kGray8, 4, kInterval);
    ManualClock clock;
    TestFramePool pool(4);
    FrameSink sink;
    auto camera = openReplay(dir.path(), rate(PlaybackRate::kRealtime, false, 2.0), clock);
    ASSERT_TRUE(camera);
    configureAndStart(*camera, sink, pool);
    ASSERT_TRUE(sink.waitForFrames(1));
    for (std::size_t n = 2; n <= 4; ++n) {
        clock.waitForSleepers(1);
        EXPECT_EQ(sink.frameCount(), n - 1);
        clock.advance(kInterval / 2);
        ASSERT_TRUE(sink.waitForFrames(n));
    }
    ASSERT_TRUE(sink.waitForEvents(1));
    camera->stop();
    const auto metas = sink.metas();
    EXPECT_EQ(metas[3].arrival_ns, 3 * kInterval / 2);
    EXPECT_EQ(metas[3].timestamp_ns - metas[0].timestamp_ns, 3 * kInterval) << "recorded times are not rescaled";
}

TEST(ReplayPacing, MaxEmitsEverythingWithoutTheClockMoving) {
    TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kRgb8, 20, kInterval);
    ManualClock clock(42);
    TestFramePool pool(4);
    FrameSink sink;
    auto camera = openReplay(dir.path(), rate(PlaybackRate::kMax), clock);
    ASSERT_TRUE(camera);
    configureAndStart(*camera, sink, pool);
    ASSERT_TRUE(sink.waitForEvents(1));
    camera->stop();
    EXPECT_EQ(sink.frameCount(), 20u);
    EXPECT_EQ(clock.nowNs(), 42);
    EXPECT_EQ(camera->framesWithoutSlot(), 0u);
    ASSERT_EQ(sink.events().size(), 1u);
    EXPECT_EQ(sink.events()[0].type, hal::CameraEvent::Type::kEndOfStream);
}

TEST(ReplayPacing, StepEmitsOneFramePerTrigger) {
    TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kRgb8, 4, kInterval);
    ManualClock clock;
    TestFramePool pool(4);
    FrameSink sink;
    auto camera = openReplay(dir.path(), rate(PlaybackRate::kStep), clock);
    ASSERT_TRUE(camera);
    EXPECT_EQ(camera->trigger().error().code, ErrorCode::kUsage) << "not streaming yet";
    configureAndStart(*camera, sink, pool);
    for (std::size_t n = 1; n <= 3; ++n) {
        ASSERT_TRUE(camera->trigger());
        ASSERT_TRUE(sink.waitForFrames(n));
        EXPECT_EQ(sink.frameCount(), n);
        EXPECT_EQ(sink.eventCount(), 0u);
    }
    ASSERT_TRUE(camera->trigger());
    ASSERT_TRUE(sink.waitForEvents(1)) << "the last frame ends the stream";
    camera->stop();
    EXPECT_EQ(sink.frameCount(), 4u);
    EXPECT_EQ(sink.sequences(), (std::vector<std::uint64_t>{0, 1, 2, 3}));
}

TEST(ReplayPacing, TriggerIsUnsupportedUnlessStepping) {
    TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kRgb8, 3, kInterval);
    ManualClock clock;
    TestFramePool pool(4);
    FrameSink sink;
    auto camera = openReplay(dir.path(), rate(PlaybackRate::kRealtime), clock);
    ASSERT_TRUE(camera);
    configureAndStart(*camera, sink, pool);
    const auto triggered = camera->trigger();
    ASSERT_FALSE(triggered);
    EXPECT_EQ(triggered.error().code, ErrorCode::kUnsupported);
    EXPECT_NE(triggered.error().message.find("rate=step"), std::string::npos);
}

TEST(ReplayPacing, LoopKeepsTimestampsAndSequencesIncreasing) {
    TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kRgb8, 3, kInterval, 30.0, 32, 24, /*first_sequence=*/7);
    ManualClock clock;
    TestFramePool pool(4);
    FrameSink sink;
    auto camera = openReplay(dir.path(), rate(PlaybackRate::kMax, true), clock);
    ASSERT_TRUE(camera);
    configureAndStart(*camera, sink, pool);
    ASSERT_TRUE(sink.waitForFrames(10));
    camera->stop();
    EXPECT_EQ(sink.eventCount(), 0u) << "a loop never ends";
    const auto metas = sink.metas();
    const std::int64_t nominal = std::llround(1e9 / 30.0);
    for (std::size_t i = 1; i < metas.size(); ++i) {
        EXPECT_GT(metas[i].timestamp_ns, metas[i - 1].timestamp_ns) << i;
        EXPECT_EQ(metas[i].sequence, metas[i - 1].sequence + 1) << i;
        const std::int64_t step = metas[i].timestamp_ns - metas[i - 1].timestamp_ns;
        EXPECT_EQ(step, i % 3 == 0 ? nominal : kInterval) << i;
    }
    EXPECT_EQ(metas[0].sequence, 7u);
}

TEST(ReplayPacing, LoopInRealtimeFollowsTheClock) {
    TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kRgb8, 2, kInterval, /*rate_hz=*/0.0);
    ManualClock clock;
    TestFramePool pool(4);
    FrameSink sink;
    auto camera = openReplay(dir.path(), rate(PlaybackRate::kRealtime, true), clock);
    ASSERT_TRUE(camera);
    configureAndStart(*camera, sink, pool);
    // Without rate_hz the mean interval is the nominal one: every frame, passes included, is
    // one interval after the previous.
    for (std::size_t n = 1; n <= 5; ++n) {
        ASSERT_TRUE(sink.waitForFrames(n));
        clock.waitForSleepers(1);
        EXPECT_EQ(sink.frameCount(), n);
        clock.advance(kInterval);
    }
    camera->stop();
}

TEST(ReplayPacing, StopDuringALongWaitReturnsAtOnce) {
    TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kRgb8, 2, 3'600'000'000'000);  // an hour apart
    ManualClock clock;
    TestFramePool pool(4);
    FrameSink sink;
    auto camera = openReplay(dir.path(), rate(PlaybackRate::kRealtime), clock);
    ASSERT_TRUE(camera);
    configureAndStart(*camera, sink, pool);
    ASSERT_TRUE(sink.waitForFrames(1));
    clock.waitForSleepers(1);
    camera->stop();
    EXPECT_EQ(camera->state(), hal::Camera::State::kConfigured);
    EXPECT_EQ(sink.frameCount(), 1u);
    EXPECT_EQ(sink.eventCount(), 0u) << "a stop the user asked for is not an event";
}

TEST(ReplayPacing, StopInterruptsTheSteadyClockToo) {
    TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kRgb8, 2, 3'600'000'000'000);
    TestFramePool pool(4);
    FrameSink sink;
    auto camera = openReplay(dir.path(), rate(PlaybackRate::kRealtime), SteadyClock::instance());
    ASSERT_TRUE(camera);
    configureAndStart(*camera, sink, pool);
    ASSERT_TRUE(sink.waitForFrames(1));
    const auto before = std::chrono::steady_clock::now();
    camera->stop();
    EXPECT_LT(std::chrono::steady_clock::now() - before, std::chrono::seconds(10));
}

TEST(ReplayPacing, StepWaitIsInterruptedByStop) {
    TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kRgb8, 2, kInterval);
    ManualClock clock;
    TestFramePool pool(4);
    FrameSink sink;
    auto camera = openReplay(dir.path(), rate(PlaybackRate::kStep), clock);
    ASSERT_TRUE(camera);
    configureAndStart(*camera, sink, pool);
    camera->stop();
    EXPECT_EQ(sink.frameCount(), 0u);
}

TEST(ReplayPacing, RestartPlaysFromTheFirstFrame) {
    TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kRgb8, 3, kInterval);
    ManualClock clock;
    TestFramePool pool(4);
    FrameSink sink;
    auto camera = openReplay(dir.path(), rate(PlaybackRate::kMax), clock);
    ASSERT_TRUE(camera);
    configureAndStart(*camera, sink, pool);
    ASSERT_TRUE(sink.waitForEvents(1));
    camera->stop();
    ASSERT_TRUE(camera->start());
    ASSERT_TRUE(sink.waitForEvents(2));
    camera->stop();
    EXPECT_EQ(sink.sequences(), (std::vector<std::uint64_t>{0, 1, 2, 0, 1, 2}));
}

}  // namespace
}  // namespace commonlight::mocks

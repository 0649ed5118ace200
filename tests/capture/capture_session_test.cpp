#include "capture/capture_session.h"

#include <chrono>
#include <condition_variable>
#include <mutex>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "core/clock.h"

namespace commonlight::capture {
namespace {

using namespace std::chrono_literals;
constexpr std::chrono::nanoseconds kLongWait = 30s;  // a safety net only: tests never wait for it
constexpr std::int64_t kMs = 1'000'000;
constexpr std::int64_t kPeriodNs = 10 * kMs;

// What the fake camera sends: frames with these device sequence numbers (timestamp = sequence *
// 10 ms, arrival = 1 s + index * 10 ms), then the end of stream or a device error.
struct Script {
    std::vector<std::uint64_t> sequences;
    std::optional<Error> error_at_end;
    std::vector<FrameStatus> statuses;  // optional, parallel to sequences
    bool hold_open = false;             // after the frames, send nothing until stopped
};

std::int64_t arrivalOf(std::size_t index) { return 1000 * kMs + static_cast<std::int64_t>(index) * kPeriodNs; }

// A camera whose thread plays a Script as fast as the session takes it.
class FakeCamera final : public hal::Camera {
public:
    FakeCamera(std::string id, Script script) : Camera(std::move(id)), script_(std::move(script)) {}
    ~FakeCamera() override { doStop(); }

private:
    std::vector<hal::StreamFormat> doFormats() const override {
        return {hal::StreamFormat{PixelFormat::kGray8, 16, 8, {100.0}, 0.0}};
    }
    Result<hal::StreamFormat> doConfigure(const hal::StreamConfig& config) override {
        return hal::negotiate(doFormats(), config, id());
    }
    Result<void> doStart() override {
        thread_ = std::jthread([this](std::stop_token stop) { run(stop); });
        return {};
    }
    void doStop() noexcept override {
        if (!thread_.joinable()) return;
        thread_.request_stop();
        thread_.join();
    }

    // The camera thread.
    void run(std::stop_token stop) {
        for (std::size_t i = 0; i < script_.sequences.size(); ++i) {
            if (stop.stop_requested()) return;
            FrameHandle frame = acquireFrame();
            if (!frame) continue;  // counted by the base class; the sequence number is used up
            frame->meta.sequence = script_.sequences[i];
            frame->meta.timestamp_ns = static_cast<std::int64_t>(script_.sequences[i]) * kPeriodNs;
            frame->meta.timestamp_source = TimestampSource::kSensor;
            frame->meta.arrival_ns = arrivalOf(i);
            if (i < script_.statuses.size()) frame->meta.status = script_.statuses[i];
            std::fill(frame->image.data(), frame->image.data() + frame->image.sizeBytes(),
                      static_cast<std::uint8_t>(i));
            emitFrame(std::move(frame));
        }
        if (script_.hold_open) {
            std::mutex mutex;
            std::condition_variable_any stopped;
            std::unique_lock lock(mutex);
            stopped.wait(lock, stop, [] { return false; });  // wakes on the stop request
            return;
        }
        if (script_.error_at_end) {
            emitEvent(hal::CameraEvent{hal::CameraEvent::Type::kDeviceError, *script_.error_at_end});
        } else {
            emitEvent(hal::CameraEvent{hal::CameraEvent::Type::kEndOfStream, {}});
        }
    }

    Script script_;
    std::jthread thread_;
};

std::unique_ptr<CaptureSession> makeSession(Script script, CaptureOptions options, Clock& clock,
                                            std::string id = "fake:0") {
    auto camera = std::make_unique<FakeCamera>(std::move(id), std::move(script));
    EXPECT_TRUE(camera->configure({}));
    auto session = CaptureSession::create(std::move(camera), options, clock);
    EXPECT_TRUE(session) << session.error().message;
    return session ? std::move(*session) : nullptr;
}

TEST(CaptureSession, SyncModeDeliversEveryFrameWithExactStatsThenTheEnd) {
    ManualClock clock(0);
    CaptureOptions options;
    options.sync = true;  // lossless: deterministic
    const std::vector<std::uint64_t> sequences = {0, 1, 2, 5, 6, 7, 10};  // gaps: 2 and 2 lost at the device
    auto session = makeSession({sequences, std::nullopt, {}}, options, clock);
    ASSERT_TRUE(session);
    ASSERT_TRUE(session->start());
    ASSERT_NE(session->pool(), nullptr);
    EXPECT_EQ(session->pool()->slotCount(), 4u);
    EXPECT_EQ(session->pool()->format(), PixelFormat::kGray8);

    for (std::size_t i = 0; i < sequences.size(); ++i) {
        clock.set(arrivalOf(i) + static_cast<std::int64_t>(i + 1) * kMs);  // latency i+1 ms at hand-over
        NextFrame next = session->next({}, kLongWait);
        ASSERT_TRUE(next) << next.error().message;
        ASSERT_TRUE(next->has_value());
        const FrameHandle& frame = **next;
        EXPECT_EQ(frame->meta.sequence, sequences[i]);
        EXPECT_EQ(frame->image.data()[0], static_cast<std::uint8_t>(i));
    }
    for (int i = 0; i < 2; ++i) {  // the end repeats
        NextFrame end = session->next({}, kLongWait);
        ASSERT_TRUE(end) << end.error().message;
        EXPECT_FALSE(end->has_value());
    }

    const CaptureStats stats = session->stats();
    EXPECT_EQ(stats.frames_received, 7u);
    EXPECT_EQ(stats.frames_delivered, 7u);
    EXPECT_EQ(stats.drops.device, 4u);
    EXPECT_EQ(stats.drops.no_slot, 0u);
    EXPECT_EQ(stats.drops.mailbox, 0u);
    EXPECT_EQ(stats.drops.corrupt, 0u);
    EXPECT_NEAR(stats.fps, 1e9 / (10.0 * kPeriodNs / 6.0), 1e-6);  // 6 intervals over 10 periods
    EXPECT_EQ(stats.latency_ms.count, 7u);
    EXPECT_DOUBLE_EQ(stats.latency_ms.p50, 4.0);
    EXPECT_DOUBLE_EQ(stats.latency_ms.p95, 7.0);
    EXPECT_DOUBLE_EQ(stats.latency_ms.max, 7.0);
    session->stop();
    EXPECT_EQ(session->pool()->inUse(), 0u);
}

TEST(CaptureSession, DeviceErrorMidStreamNamesTheCameraAfterTheLastFrame) {
    ManualClock clock(0);
    CaptureOptions options;
    options.sync = true;
    Script script{{0, 1, 2}, Error{ErrorCode::kIo, "VIDIOC_DQBUF: No such device"}, {}};
    script.statuses = {FrameStatus::kOk, FrameStatus::kIncomplete, FrameStatus::kOk};
    auto session = makeSession(script, options, clock, "v4l2:/dev/video7");
    ASSERT_TRUE(session);
    ASSERT_TRUE(session->start());
    for (std::uint64_t i = 0; i < 3; ++i) {
        NextFrame next = session->next({}, kLongWait);
        ASSERT_TRUE(next) << next.error().message;
        ASSERT_TRUE(next->has_value());
        EXPECT_EQ((**next)->meta.sequence, i);
    }
    NextFrame failed = session->next({}, kLongWait);
    ASSERT_FALSE(failed);
    EXPECT_EQ(failed.error().code, ErrorCode::kDevice);
    EXPECT_NE(failed.error().message.find("v4l2:/dev/video7"), std::string::npos) << failed.error().message;
    EXPECT_NE(failed.error().message.find("No such device"), std::string::npos) << failed.error().message;
    EXPECT_EQ(session->stats().drops.corrupt, 1u);  // the incomplete frame reached us without usable pixels
}

// Newest-wins with a consumer on another thread: every frame the camera produced is delivered,
// replaced in the mailbox, or lost for want of a slot, exactly once.
TEST(CaptureSession, LiveModeAccountsForEveryFrame) {
    constexpr std::uint64_t kFrames = 3000;
    std::vector<std::uint64_t> sequences(kFrames);
    for (std::uint64_t i = 0; i < kFrames; ++i) sequences[i] = 100 + i;  // contiguous: no device loss
    ManualClock clock(5000 * kMs);
    CaptureOptions options;
    options.slots = 3;
    auto session = makeSession({sequences, std::nullopt, {}}, options, clock);
    ASSERT_TRUE(session);
    ASSERT_TRUE(session->start());

    std::uint64_t taken = 0;
    std::uint64_t last = 0;
    bool in_order = true;
    bool clean_end = false;
    std::thread consumer([&] {
        for (;;) {
            NextFrame next = session->next({}, kLongWait);
            if (!next) return;
            if (!next->has_value()) {
                clean_end = true;
                return;
            }
            in_order = in_order && (**next)->meta.sequence > last;
            last = (**next)->meta.sequence;
            ++taken;
        }
    });
    consumer.join();
    session->stop();

    EXPECT_TRUE(clean_end);
    EXPECT_TRUE(in_order);
    EXPECT_EQ(last, 100 + kFrames - 1);  // the newest frame before the end always arrives
    const CaptureStats stats = session->stats();
    EXPECT_EQ(stats.frames_delivered, taken);
    EXPECT_EQ(stats.frames_received + stats.drops.no_slot, kFrames);
    EXPECT_EQ(stats.frames_delivered + stats.drops.mailbox, stats.frames_received);
    EXPECT_EQ(stats.drops.device, 0u);  // slotless frames leave gaps, but are not the device's
    EXPECT_EQ(session->pool()->inUse(), 0u);
}

TEST(CaptureSession, StopWakesACameraWaitingOnASyncConsumer) {
    std::vector<std::uint64_t> sequences(100);
    for (std::uint64_t i = 0; i < 100; ++i) sequences[i] = i;
    ManualClock clock(0);
    CaptureOptions options;
    options.sync = true;
    auto session = makeSession({sequences, std::nullopt, {}}, options, clock);
    ASSERT_TRUE(session);
    ASSERT_TRUE(session->start());
    {
        NextFrame first = session->next({}, kLongWait);
        ASSERT_TRUE(first && first->has_value());
        session->stop();  // the camera thread is blocked in put(): stop() must not deadlock
        EXPECT_FALSE(session->streaming());
    }
    // After stop the consumer gets what was already in the mailbox, then the end.
    for (;;) {
        NextFrame next = session->next({}, kLongWait);
        ASSERT_TRUE(next);
        if (!next->has_value()) break;
    }
    EXPECT_EQ(session->pool()->inUse(), 0u);

    // And the session starts again with fresh counters.
    ASSERT_TRUE(session->start());
    NextFrame again = session->next({}, kLongWait);
    ASSERT_TRUE(again && again->has_value());
    EXPECT_EQ((**again)->meta.sequence, 0u);
    EXPECT_EQ(session->stats().frames_delivered, 1u);
    again->reset();
    session->stop();
}

TEST(CaptureSession, ContractChecksAndTimeouts) {
    ManualClock clock(0);
    EXPECT_FALSE(CaptureSession::create(nullptr, {}, clock));
    CaptureOptions bad;
    bad.slots = 0;
    auto rejected = CaptureSession::create(std::make_unique<FakeCamera>("fake:1", Script{}), bad, clock);
    ASSERT_FALSE(rejected);
    EXPECT_EQ(rejected.error().code, ErrorCode::kUsage);
    EXPECT_NE(rejected.error().message.find("fake:1"), std::string::npos) << rejected.error().message;

    // Not configured: start() refuses; next() before start() is the end.
    auto unconfigured = CaptureSession::create(std::make_unique<FakeCamera>("fake:2", Script{}), {}, clock);
    ASSERT_TRUE(unconfigured);
    auto started = (*unconfigured)->start();
    ASSERT_FALSE(started);
    EXPECT_EQ(started.error().code, ErrorCode::kUsage);
    NextFrame before = (*unconfigured)->next({}, kLongWait);
    ASSERT_TRUE(before);
    EXPECT_FALSE(before->has_value());

    // A frame held across stop() blocks a restart until it is released.
    CaptureOptions sync;
    sync.sync = true;
    auto session = makeSession({{0, 1}, std::nullopt, {}}, sync, clock, "fake:3");
    ASSERT_TRUE(session);
    ASSERT_TRUE(session->start());
    EXPECT_FALSE(session->start());  // already streaming
    NextFrame held = session->next({}, kLongWait);
    ASSERT_TRUE(held && held->has_value());
    session->stop();
    auto restart = session->start();
    ASSERT_FALSE(restart);
    EXPECT_NE(restart.error().message.find("still held"), std::string::npos) << restart.error().message;
    held->reset();
    ASSERT_TRUE(session->start());
    session->stop();
}

TEST(CaptureSession, NextTimesOutNamingTheCamera) {
    ManualClock clock(0);
    Script silent;
    silent.hold_open = true;  // streams, but sends nothing until stopped
    auto session = makeSession(silent, {}, clock, "fake:silent");
    ASSERT_TRUE(session);
    ASSERT_TRUE(session->start());
    NextFrame next = session->next({}, 0ns);
    ASSERT_FALSE(next);
    EXPECT_EQ(next.error().code, ErrorCode::kTimeout);
    EXPECT_NE(next.error().message.find("fake:silent"), std::string::npos) << next.error().message;

    std::stop_source stop;
    stop.request_stop();
    NextFrame cancelled = session->next(stop.get_token(), kLongWait);
    ASSERT_FALSE(cancelled);
    EXPECT_EQ(cancelled.error().code, ErrorCode::kCancelled);
    session->stop();
    NextFrame end = session->next({}, kLongWait);  // stop() ended the stream
    ASSERT_TRUE(end);
    EXPECT_FALSE(end->has_value());
}

}  // namespace
}  // namespace commonlight::capture

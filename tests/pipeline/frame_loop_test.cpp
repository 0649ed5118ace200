// The pipeline's threads (pipeline/frame_loop.h, FrameRunner::run): the hand-over between the
// pipeline thread and the main thread (newest wins, the end and the error delivered after the last
// frame, just-in-time demand), and whole runs on the bundled sample: in real time tracking frame
// n+1 overlaps compositing frame n on another thread, every tracked frame is either shown or
// replaced by a newer one, in order; with sync everything runs on the caller's thread in order;
// a callback can end the run; a failing source ends it with its error; frames that cannot be
// converted are counted; virtual objects moved from the main thread reach the pipeline thread.
// No compositor here (no GL needed): frame_loop_gl_test.cpp composites. Labelled `threads`: the
// suite runs it under ThreadSanitizer.
#include "pipeline/frame_loop.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <thread>

#include "pipeline/runner.h"
#include "tests/pipeline/sample_source.h"

namespace commonlight::pipeline {
namespace {

using namespace std::chrono_literals;

// Fills a tracked frame so that its contents name it: index and every pixel byte.
void fill(TrackedFrame& f, std::uint64_t index) {
    f.index = index;
    f.rgb.reshape(PixelFormat::kRgb8, 8, 4);
    for (int y = 0; y < 4; ++y) std::fill_n(f.rgb.mutableView().row(y), 24, static_cast<std::uint8_t>(index & 0xff));
}

TEST(TrackedFrameHandoff, TheNewestWinsAndOlderFramesAreCountedAsReplaced) {
    TrackedFrameHandoff handoff;
    for (std::uint64_t i = 1; i <= 3; ++i) {
        fill(handoff.writable(), i);
        handoff.publish();
    }
    const TrackedFrame* frame = nullptr;
    ASSERT_EQ(handoff.take(0ms, frame), TrackedFrameHandoff::Taken::kFrame);
    EXPECT_EQ(frame->index, 3u);
    EXPECT_EQ(handoff.replaced(), 2u);
    EXPECT_EQ(handoff.published(), 3u);
    // Nothing newer: a timeout, and the frame taken stays valid.
    const TrackedFrame* none = nullptr;
    EXPECT_EQ(handoff.take(1ms, none), TrackedFrameHandoff::Taken::kTimeout);
    EXPECT_EQ(frame->index, 3u);
    EXPECT_EQ(frame->rgb.view().row(3)[23], 3);
}

TEST(TrackedFrameHandoff, TheLastFrameComesBeforeTheEndAndItsError) {
    TrackedFrameHandoff handoff;
    fill(handoff.writable(), 7);
    handoff.publish();
    handoff.close(Error{ErrorCode::kDevice, "cam: device disconnected"});
    const TrackedFrame* frame = nullptr;
    ASSERT_EQ(handoff.take(0ms, frame), TrackedFrameHandoff::Taken::kFrame);
    EXPECT_EQ(frame->index, 7u);
    EXPECT_EQ(handoff.take(0ms, frame), TrackedFrameHandoff::Taken::kEnd);
    ASSERT_TRUE(handoff.error());
    EXPECT_EQ(handoff.error()->code, ErrorCode::kDevice);
    // Only the first close counts.
    handoff.close();
    EXPECT_TRUE(handoff.error());
}

// A producer and a consumer on two threads: every frame taken is whole (its pixels name the same
// frame as its index), indices only increase, the last one published is the last one taken, and
// taken + replaced = published. With and without just-in-time demand.
TEST(TrackedFrameHandoff, FramesCrossThreadsWholeAndInOrder) {
    for (const bool demand : {false, true}) {
        TrackedFrameHandoff handoff;
        constexpr std::uint64_t kFrames = 5000;
        std::jthread producer([&](std::stop_token stop) {
            for (std::uint64_t i = 1; i <= kFrames; ++i) {
                if (demand && !handoff.waitForDemand(0, stop)) break;
                fill(handoff.writable(), i);
                handoff.publish();
            }
            handoff.close();
        });
        std::uint64_t last = 0, taken = 0;
        while (true) {
            const TrackedFrame* frame = nullptr;
            const auto got = handoff.take(10s, frame);
            ASSERT_NE(got, TrackedFrameHandoff::Taken::kTimeout);
            if (got == TrackedFrameHandoff::Taken::kEnd) break;
            ASSERT_GT(frame->index, last);
            for (int y = 0; y < 4; ++y) {
                for (int x = 0; x < 24; ++x) ASSERT_EQ(frame->rgb.view().row(y)[x], frame->index & 0xff) << frame->index;
            }
            last = frame->index;
            ++taken;
        }
        producer.join();
        EXPECT_EQ(last, kFrames) << "demand " << demand;
        EXPECT_EQ(taken + handoff.replaced(), kFrames);
        if (demand) {
            EXPECT_EQ(handoff.replaced(), 0u) << "just in time: the producer never overtakes the consumer";
        }
        EXPECT_FALSE(handoff.error());
    }
}

TEST(TrackedFrameHandoff, TheProducerWaitsForTheConsumersDemand) {
    TrackedFrameHandoff handoff;
    // Nothing published, the consumer never said it is busy: demand at once.
    std::stop_source never;
    EXPECT_TRUE(handoff.waitForDemand(0, never.get_token()));
    // A frame waits untaken: the producer waits until the consumer takes it.
    fill(handoff.writable(), 1);
    handoff.publish();
    std::atomic<bool> returned{false};
    constexpr std::int64_t kLongerThanBusy = 20'000'000'000;  // the producer's time per frame, ns
    std::jthread producer([&](std::stop_token stop) {
        EXPECT_TRUE(handoff.waitForDemand(kLongerThanBusy, stop));
        returned = true;
    });
    std::this_thread::sleep_for(50ms);
    EXPECT_FALSE(returned) << "the producer went on while a frame was still waiting";
    // The consumer takes it and says it will be busy for a long time; the producer's own time per
    // frame (lead) is longer still, so it starts now.
    const TrackedFrame* frame = nullptr;
    ASSERT_EQ(handoff.take(0ms, frame, 10'000'000'000), TrackedFrameHandoff::Taken::kFrame);
    producer.join();
    EXPECT_TRUE(returned);
    // With no lead, it waits for the busy consumer until stopped.
    std::jthread waiting([&](std::stop_token stop) { EXPECT_FALSE(handoff.waitForDemand(0, stop)); });
    std::this_thread::sleep_for(20ms);
    waiting.request_stop();
    waiting.join();
    // The consumer asks again (it is free): demand at once.
    const TrackedFrame* none = nullptr;
    EXPECT_EQ(handoff.take(0ms, none), TrackedFrameHandoff::Taken::kTimeout);
    EXPECT_TRUE(handoff.waitForDemand(0, never.get_token()));
}

TEST(FrameRunnerRun, InRealTimeTrackingTheNextFrameOverlapsTheMainThreadsStage) {
    auto runner = makeRunner(/*sync=*/false, /*lighting=*/true);
    ASSERT_TRUE(runner);
    SampleSource source(sample().frames.size());
    const std::thread::id main_thread = std::this_thread::get_id();
    std::atomic<std::uint64_t> tracked_index{0};
    std::atomic<bool> tracked_on_main{false};
    std::vector<std::uint64_t> shown;
    bool overlapped = false;
    LoopCallbacks callbacks;
    callbacks.on_tracked = [&](const TrackedFrame& f) {
        if (std::this_thread::get_id() == main_thread) tracked_on_main = true;
        tracked_index = f.index;
    };
    callbacks.on_frame = [&](const TrackedFrame& f) {
        EXPECT_EQ(std::this_thread::get_id(), main_thread);
        if (shown.empty()) {
            // While this thread holds frame 0, the pipeline thread tracks frame 1.
            for (int i = 0; i < 6000 && tracked_index.load() < 1; ++i) std::this_thread::sleep_for(10ms);
            overlapped = tracked_index.load() >= 1;
        }
        shown.push_back(f.index);
        return true;
    };
    const LoopStats stats = runner->run(source, callbacks, std::stop_token());
    runner->stop();
    ASSERT_FALSE(stats.failure) << stats.failure->message;
    EXPECT_TRUE(overlapped) << "frame 1 was not tracked while frame 0 was on the main thread";
    EXPECT_FALSE(tracked_on_main);
    EXPECT_NE(source.thread(), main_thread);
    EXPECT_EQ(stats.tracked, sample().frames.size());
    EXPECT_EQ(runner->tracking().framesWithPose(), sample().frames.size());
    // Every tracked frame was shown or replaced by a newer one; in order; the last one shown.
    EXPECT_EQ(stats.composited + stats.replaced, stats.tracked);
    ASSERT_EQ(shown.size(), stats.composited);
    for (std::size_t i = 1; i < shown.size(); ++i) EXPECT_GT(shown[i], shown[i - 1]);
    EXPECT_EQ(shown.back(), sample().frames.size() - 1);
    EXPECT_FALSE(stats.stopped);
}

// In real time the lighting stage measures the ratio error against the sample's ground truth on
// its own thread (every 5th frame, newest wins; lighting_stage.h): after the run it is measured,
// and stopping the runner joins that thread (under TSan: no race with the metrics read after).
TEST(FrameRunnerRun, InRealTimeTheRatioErrorIsMeasuredOnTheStagesOwnThread) {
    auto runner = makeRunner(/*sync=*/false, /*lighting=*/true, /*composite=*/false, /*with_truth=*/true);
    ASSERT_TRUE(runner);
    SampleSource source(sample().frames.size());
    const LoopStats stats = runner->run(source, LoopCallbacks{}, std::stop_token());
    runner->stop();
    ASSERT_FALSE(stats.failure) << stats.failure->message;
    ASSERT_NE(runner->lighting(), nullptr);
    const nlohmann::json lit = runner->lighting()->metricsJson();
    ASSERT_TRUE(lit.contains("shadow_ratio_error")) << lit.dump();
    const int frames = lit["shadow_ratio_error"]["frames"].get<int>();
    EXPECT_GE(frames, 1);
    // Every fourth pixel of every fourth row in real time: 450-500 of the changed region's a frame.
    EXPECT_GT(lit["shadow_ratio_error"]["pixels"].get<int>(), 250 * frames);
    // (Fed as fast as it tracks, the run is over within the lighting's first updates: a measurement,
    // not the accuracy of a settled estimate, is what this asserts.)
    EXPECT_LT(lit["shadow_ratio_error"]["rms"].get<double>(), 1.0);
}

TEST(FrameRunnerRun, WithSyncEveryStageRunsInOrderOnTheCallersThread) {
    auto runner = makeRunner(/*sync=*/true, /*lighting=*/false);
    ASSERT_TRUE(runner);
    constexpr std::size_t kFrames = 12;
    SampleSource source(kFrames);
    const std::thread::id main_thread = std::this_thread::get_id();
    std::vector<std::uint64_t> tracked, shown;
    LoopCallbacks callbacks;
    callbacks.on_tracked = [&](const TrackedFrame& f) {
        EXPECT_EQ(std::this_thread::get_id(), main_thread);
        EXPECT_EQ(tracked.size(), shown.size()) << "a frame was tracked before the previous one was shown";
        tracked.push_back(f.index);
    };
    callbacks.on_frame = [&](const TrackedFrame& f) {
        shown.push_back(f.index);
        return true;
    };
    callbacks.on_idle = [](const TrackedFrame*) {
        ADD_FAILURE() << "on_idle in sync mode";
        return true;
    };
    const LoopStats stats = runner->run(source, callbacks, std::stop_token());
    ASSERT_FALSE(stats.failure);
    EXPECT_EQ(source.thread(), main_thread);
    ASSERT_EQ(shown.size(), kFrames);
    for (std::size_t i = 0; i < kFrames; ++i) EXPECT_EQ(shown[i], i);
    EXPECT_EQ(tracked, shown);
    EXPECT_EQ(stats.replaced, 0u);
}

TEST(FrameRunnerRun, ACallbackEndsTheRun) {
    for (const bool sync : {false, true}) {
        auto runner = makeRunner(sync, /*lighting=*/false);
        ASSERT_TRUE(runner);
        SampleSource source(sample().frames.size());
        std::uint64_t shown = 0;
        LoopCallbacks callbacks;
        callbacks.on_frame = [&](const TrackedFrame&) { return ++shown < 3; };
        const LoopStats stats = runner->run(source, callbacks, std::stop_token());
        EXPECT_TRUE(stats.stopped);
        EXPECT_FALSE(stats.failure);
        EXPECT_EQ(shown, 3u);
        // The pipeline thread stopped too: it took at most the frames it was tracking meanwhile.
        EXPECT_LT(source.given(), sample().frames.size()) << "sync " << sync;
    }
}

TEST(FrameRunnerRun, AStopRequestEndsTheRunWithoutAFailure) {
    auto runner = makeRunner(/*sync=*/false, /*lighting=*/false);
    ASSERT_TRUE(runner);
    SampleSource source(sample().frames.size());
    std::stop_source stop;
    LoopCallbacks callbacks;
    callbacks.on_tracked = [&](const TrackedFrame& f) {
        if (f.index == 4) stop.request_stop();  // as Ctrl-C would, from another thread
    };
    const LoopStats stats = runner->run(source, callbacks, stop.get_token());
    EXPECT_FALSE(stats.failure);
    EXPECT_LE(stats.tracked, 5u);
}

TEST(FrameRunnerRun, ASourceErrorEndsTheRunAndBadFramesAreCounted) {
    for (const bool sync : {false, true}) {
        auto runner = makeRunner(sync, /*lighting=*/false);
        ASSERT_TRUE(runner);
        SampleSource source(6, Error{ErrorCode::kDevice, "cam0: device disconnected"});
        source.bad_at_ = 2;
        std::vector<std::string> bad;
        LoopCallbacks callbacks;
        callbacks.on_bad_frame = [&](const Frame&, const Error& e) { bad.push_back(e.message); };
        const LoopStats stats = runner->run(source, callbacks, std::stop_token());
        ASSERT_TRUE(stats.failure) << "sync " << sync;
        EXPECT_EQ(stats.failure->code, ErrorCode::kDevice);
        EXPECT_EQ(stats.failure->message, "cam0: device disconnected");
        EXPECT_EQ(stats.bad_frames, 1u);
        EXPECT_EQ(bad.size(), 1u);
        EXPECT_EQ(stats.tracked, 5u);
        EXPECT_GE(stats.composited, 1u);
    }
}

// The arrow keys move a virtual object on the main thread while the pipeline thread reads the
// objects' poses for each frame it tracks: every move reaches the frames tracked after it.
TEST(FrameRunnerRun, VirtualObjectsMovedOnTheMainThreadReachThePipelineThread) {
    auto runner = makeRunner(/*sync=*/false, /*lighting=*/false);
    ASSERT_TRUE(runner);
    ASSERT_FALSE(sample().scene.virtual_objects.empty());
    SampleSource source(30);
    const std::optional<Rigid3d> start = runner->virtualPoses(0.0)[0];
    ASSERT_TRUE(start);
    std::vector<double> tracked_x;
    int moves = 0;
    LoopCallbacks callbacks;
    callbacks.on_tracked = [&](const TrackedFrame& f) { tracked_x.push_back(f.virtual_poses[0]->translation.x()); };
    callbacks.on_frame = [&](const TrackedFrame&) {
        runner->moveVirtualObject(0, Eigen::Vector3d(0.01, 0, 0));
        ++moves;
        return true;
    };
    const LoopStats stats = runner->run(source, callbacks, std::stop_token());
    ASSERT_FALSE(stats.failure);
    ASSERT_EQ(tracked_x.size(), 30u);
    for (std::size_t i = 1; i < tracked_x.size(); ++i) EXPECT_GE(tracked_x[i], tracked_x[i - 1]);
    EXPECT_GT(tracked_x.back(), tracked_x.front());
    EXPECT_NEAR(runner->virtualPoses(0.0)[0]->translation.x() - start->translation.x(), 0.01 * moves, 1e-9);
}

}  // namespace
}  // namespace commonlight::pipeline

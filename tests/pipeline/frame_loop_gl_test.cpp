// FrameRunner::run with the compositor (offscreen, EGL surfaceless): in real time the main thread
// composites what the pipeline thread tracked, the overlay's figures (latency, lighting version)
// are there, redraw() shows a moved virtual object without counting a frame, and the metrics
// report how the threads ran. Without any GL context the test exits 77 (skip).
#include <gtest/gtest.h>

#include <cstdlib>
#include <thread>

#include "render/gl_context.h"
#include "tests/pipeline/sample_source.h"

namespace commonlight::pipeline {
namespace {

void skipWithoutGl() {
    auto context = render::GlContext::create({});
    if (!context) {
        std::fprintf(stderr, "skipped: no offscreen GL context: %s\n", context.error().message.c_str());
        std::exit(77);
    }
}

std::size_t differingPixels(const Image& a, const Image& b) {
    std::size_t n = 0;
    for (int y = 0; y < a.height(); ++y) {
        for (int x = 0; x < 3 * a.width(); ++x) n += a.view().row(y)[x] != b.view().row(y)[x];
    }
    return n;
}

TEST(FrameRunnerRunGl, TheMainThreadCompositesWhatThePipelineThreadTracked) {
    skipWithoutGl();
    auto runner = makeRunner(/*sync=*/false, /*lighting=*/true, /*composite=*/true);
    ASSERT_TRUE(runner);
    SampleSource source(20);
    const std::thread::id main_thread = std::this_thread::get_id();
    std::uint64_t shown = 0;
    LoopCallbacks callbacks;
    callbacks.on_frame = [&](const TrackedFrame& f) {
        EXPECT_EQ(std::this_thread::get_id(), main_thread);
        EXPECT_EQ(runner->compositeImage().width(), f.rgb.width());
        EXPECT_GT(runner->lastComposite().latency_ms, 0.0);
        ++shown;
        return true;
    };
    const LoopStats stats = runner->run(source, callbacks, std::stop_token());
    runner->stop();
    ASSERT_FALSE(stats.failure) << stats.failure->message;
    EXPECT_EQ(stats.tracked, 20u);
    EXPECT_EQ(stats.composited, shown);
    EXPECT_EQ(stats.composited + stats.replaced, stats.tracked);
    EXPECT_EQ(runner->timings().percentiles(runner->timings().id("composite")).count, shown);
    const nlohmann::json metrics = runner->metricsJson();
    EXPECT_EQ(metrics["compositor"]["frames"].get<std::uint64_t>(), shown);
    EXPECT_EQ(metrics["compositor"]["replaced"].get<std::uint64_t>(), stats.replaced);
    EXPECT_EQ(metrics["compositor"]["threads"].get<std::string>(), "pipeline thread + main thread");
    EXPECT_TRUE(metrics["compositor"].contains("latency_ms"));
}

TEST(FrameRunnerRunGl, RedrawShowsAMovedObjectWithoutCountingAFrame) {
    skipWithoutGl();
    auto runner = makeRunner(/*sync=*/true, /*lighting=*/false, /*composite=*/true);
    ASSERT_TRUE(runner);
    SampleSource source(1);
    std::optional<TrackedFrame> kept;
    Image before;
    LoopCallbacks callbacks;
    callbacks.on_frame = [&](const TrackedFrame& f) {
        before = runner->compositeImage().clone();
        // Moved 5 cm along x: the object's pixels change; drawn again from the same frame.
        runner->moveVirtualObject(0, Eigen::Vector3d(0.05, 0, 0));
        auto redrawn = runner->redraw(f);
        EXPECT_TRUE(redrawn) << (redrawn ? "" : redrawn.error().message);
        return true;
    };
    const LoopStats stats = runner->run(source, callbacks, std::stop_token());
    ASSERT_FALSE(stats.failure);
    ASSERT_EQ(stats.composited, 1u);
    EXPECT_GT(differingPixels(before, runner->compositeImage()), 500u);
    EXPECT_EQ(runner->metricsJson()["compositor"]["frames"].get<std::uint64_t>(), 1u);
}

}  // namespace
}  // namespace commonlight::pipeline

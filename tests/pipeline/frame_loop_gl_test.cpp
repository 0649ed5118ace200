// FrameRunner::run with the compositor (offscreen, EGL surfaceless): in real time the main thread
// composites what the pipeline thread tracked, the overlay's figures (latency, lighting version)
// are there, redraw() shows a moved virtual object without counting a frame, and the metrics
// report how the threads ran. Without any GL context the test exits 77 (skip).
#include <gtest/gtest.h>

#include <cstdlib>
#include <thread>

#include <opencv2/imgproc.hpp>


#include "capture/convert.h"
#include "render/gl_context.h"
#include "tests/pipeline/sample_source.h"

namespace commonlight::pipeline {
namespace {

std::size_t differingPixels(const Image& a, const Image& b) {
    std::size_t n = 0;
    for (int y = 0; y < a.height(); ++y) {
        for (int x = 0; x < 3 * a.width(); ++x) n += a.view().row(y)[x] != b.view().row(y)[x];
    }
    return n;
}

// With the recording's ground truth: the composites are measured against it on the measuring
// thread (pipeline/composite_measurer.h), every one by the time run() returns.
TEST(FrameRunnerRunGl, TheMainThreadCompositesWhatThePipelineThreadTracked) {
    skipWithoutGl();
    auto runner = makeRunner(/*sync=*/false, /*lighting=*/true, /*composite=*/true, /*with_truth=*/true);
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
    ASSERT_TRUE(metrics.contains("composite_error"));
    EXPECT_EQ(metrics["composite_error"]["frames"].get<std::uint64_t>() + metrics["composite_error"]["unmeasured"].get<std::uint64_t>(),
              shown);
    EXPECT_GT(metrics["composite_error"]["psnr_db"].get<double>(), 30.0);
}

// play's warm-up: the first frame goes to the lighting thread before run(), which waits for its
// first update, so the very first frame composited is drawn lit; nothing of it is counted (no
// frame tracked or composited, no stage time). In sync mode there is nothing to warm up.
TEST(FrameRunnerRunGl, WarmUpMakesTheFirstCompositedFrameLitAndCountsNothing) {
    skipWithoutGl();
    auto sync = makeRunner(/*sync=*/true, /*lighting=*/true, /*composite=*/true);
    ASSERT_TRUE(sync);
    auto sync_warmed = sync->warmUp(sample().frames[0]);
    ASSERT_TRUE(sync_warmed) << sync_warmed.error().message;
    EXPECT_FALSE(*sync_warmed);
    sync->stop();

    auto runner = makeRunner(/*sync=*/false, /*lighting=*/true, /*composite=*/true);
    ASSERT_TRUE(runner);
    auto warmed = runner->warmUp(sample().frames[0]);
    ASSERT_TRUE(warmed) << warmed.error().message;
    EXPECT_TRUE(*warmed);
    EXPECT_GE(runner->lighting()->latest()->version, 1u);
    EXPECT_EQ(runner->timings().percentiles(runner->timings().id("composite")).count, 0u);
    EXPECT_EQ(runner->timings().percentiles(runner->timings().id("track")).count, 0u);
    SampleSource source(5);
    std::uint64_t first_version = 0;
    bool first = true;
    LoopCallbacks callbacks;
    callbacks.on_frame = [&](const TrackedFrame&) {
        if (first) first_version = runner->lastComposite().lighting_version;
        first = false;
        return true;
    };
    const LoopStats stats = runner->run(source, callbacks, std::stop_token());
    runner->stop();
    ASSERT_FALSE(stats.failure) << stats.failure->message;
    EXPECT_EQ(stats.tracked, 5u);
    EXPECT_GE(first_version, 1u);
    EXPECT_EQ(runner->metricsJson()["compositor"]["frames"].get<std::uint64_t>(), stats.composited);
    EXPECT_EQ(runner->metricsJson()["compositor"]["quality"]["levels"][0]["frames"].get<std::uint64_t>() +
                  runner->metricsJson()["compositor"]["quality"]["levels"][1]["frames"].get<std::uint64_t>() +
                  runner->metricsJson()["compositor"]["quality"]["levels"][2]["frames"].get<std::uint64_t>(),
              stats.composited);
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

// A camera that sends YUYV or NV12: the compositor gets the camera's own bytes (converted in its
// final pass), and the composite matches the one drawn from the same frame converted to RGB on
// the CPU (the same BT.601 conversion).
class OneFrameSource final : public FrameSource {
public:
    explicit OneFrameSource(Frame frame) : frame_(std::move(frame)) {}
    Result<std::optional<FrameHandle>> next(std::stop_token) override {
        if (given_) return std::optional<FrameHandle>();
        given_ = true;
        frame_.meta.arrival_ns = monotonicNowNs();
        return std::optional<FrameHandle>(FrameHandle(&frame_, nullptr));
    }

private:
    Frame frame_;
    bool given_ = false;
};

// The sample's first frame as RGB8, and as a camera would send it in `format` (YUYV: each row
// pair's chroma; NV12: the I420 planes, chroma interleaved).
std::pair<Frame, Frame> firstFrameAs(PixelFormat format) {
    capture::PixelConverter converter;
    Image rgb;
    EXPECT_TRUE(converter.convert(sample().frames[0].image.view(), PixelFormat::kRgb8, rgb));
    const int w = rgb.width(), h = rgb.height();
    const cv::Mat rgb_mat(h, w, CV_8UC3, rgb.data(), rgb.stride());
    cv::Mat i420;
    cv::cvtColor(rgb_mat, i420, cv::COLOR_RGB2YUV_I420);
    const std::uint8_t* y = i420.data;
    const std::uint8_t* u = y + static_cast<std::size_t>(w * h);
    const std::uint8_t* v = u + static_cast<std::size_t>(w * h / 4);
    Frame yuv;
    yuv.image.reshape(format, w, h);
    for (int r = 0; r < h; ++r) {
        std::uint8_t* row = yuv.image.data() + static_cast<std::size_t>(r) * yuv.image.stride();
        for (int x = 0; x < w; x += 2) {
            const std::size_t p = static_cast<std::size_t>(r * w + x), c = static_cast<std::size_t>((r / 2) * (w / 2) + x / 2);
            if (format == PixelFormat::kYuyv) {
                row[2 * x] = y[p];
                row[2 * x + 1] = u[c];
                row[2 * x + 2] = y[p + 1];
                row[2 * x + 3] = v[c];
            } else {
                row[x] = y[p];
                row[x + 1] = y[p + 1];
                if (r % 2 == 0) {
                    std::uint8_t* uv = yuv.image.data() + static_cast<std::size_t>(h + r / 2) * yuv.image.stride();
                    uv[x] = u[c];
                    uv[x + 1] = v[c];
                }
            }
        }
    }
    Frame converted;
    EXPECT_TRUE(converter.convert(yuv.image.view(), PixelFormat::kRgb8, converted.image));
    yuv.meta = converted.meta = sample().frames[0].meta;
    return {std::move(yuv), std::move(converted)};
}

Image compositeOf(Frame frame, bool expect_raw) {
    auto runner = makeRunner(/*sync=*/true, /*lighting=*/false, /*composite=*/true);
    EXPECT_TRUE(runner);
    if (!runner) return Image();
    OneFrameSource source(std::move(frame));
    LoopCallbacks callbacks;
    callbacks.on_frame = [&](const TrackedFrame& f) {
        EXPECT_EQ(!f.raw.view().empty(), expect_raw);
        EXPECT_FALSE(f.rgb.view().empty());  // the lighting and the side by side still get RGB
        return true;
    };
    const LoopStats stats = runner->run(source, callbacks, std::stop_token());
    EXPECT_FALSE(stats.failure) << (stats.failure ? stats.failure->message : "");
    EXPECT_EQ(stats.composited, 1u);
    return runner->compositeImage().clone();
}

TEST(FrameRunnerRunGl, YuvFramesGoToTheCompositorAsTheCameraSentThem) {
    skipWithoutGl();
    ASSERT_FALSE(sample().frames.empty());
    for (const PixelFormat format : {PixelFormat::kYuyv, PixelFormat::kNv12}) {
        SCOPED_TRACE(pixelFormatName(format));
        auto [yuv, rgb] = firstFrameAs(format);
        const Image from_yuv = compositeOf(std::move(yuv), /*expect_raw=*/true);
        const Image from_rgb = compositeOf(std::move(rgb), /*expect_raw=*/false);
        ASSERT_EQ(from_yuv.width(), from_rgb.width());
        ASSERT_EQ(from_yuv.height(), from_rgb.height());
        // The GPU's conversion against OpenCV's: the same to a code or two (rounding, and the
        // chroma sampled bilinearly or by nearest sample).
        double sum = 0.0;
        int worse = 0;
        for (int y = 0; y < from_rgb.height(); ++y) {
            for (int x = 0; x < 3 * from_rgb.width(); ++x) {
                const int d = std::abs(int(from_yuv.view().row(y)[x]) - int(from_rgb.view().row(y)[x]));
                sum += d;
                worse += d > 8;
            }
        }
        const double pixels = 3.0 * from_rgb.width() * from_rgb.height();
        EXPECT_LT(sum / pixels, 1.0);
        EXPECT_LT(worse / pixels, 0.01);
    }
}

}  // namespace
}  // namespace commonlight::pipeline

// In steady state the capture pipeline allocates nothing per frame: camera thread (slot fill),
// mailbox, session statistics, consumer conversion. Counted over every thread of the process.
//
// OpenCV's parallel backend (TBB) sets up per-thread state (its RNG, in TLS) the first time a
// worker thread runs an OpenCV kernel: a one-time cost per thread, not per frame, but which
// worker joins which frame is up to TBB, so it could land in the measured window. The test runs
// OpenCV's kernels on the calling thread (cv::setNumThreads(0)) to measure our pipeline exactly;
// bench_capture measures with the default backend.
#include <chrono>
#include <memory>

#include <gtest/gtest.h>
#include <opencv2/core/utility.hpp>

#include "bench/alloc_counter.h"
#include "capture/capture_session.h"
#include "capture/convert.h"
#include "mocks/memory_camera.h"

namespace commonlight::capture {
namespace {

Image pattern(PixelFormat format) {
    Image image(format, 320, 240);
    for (std::size_t i = 0; i < image.sizeBytes(); ++i) image.data()[i] = static_cast<std::uint8_t>(i * 13);
    return image;
}

class SteadyState : public ::testing::TestWithParam<PixelFormat> {};

TEST_P(SteadyState, NoAllocationPerFrame) {
    cv::setNumThreads(0);
    mocks::PlaybackOptions max_rate;
    max_rate.rate = mocks::PlaybackRate::kMax;
    for (bool sync : {true, false}) {
        auto camera = std::make_unique<mocks::MemoryCamera>(pattern(GetParam()), 30.0, max_rate);
        ASSERT_TRUE(camera->configure({}));
        CaptureOptions options;
        options.sync = sync;
        auto session = CaptureSession::create(std::move(camera), options);
        ASSERT_TRUE(session);
        ASSERT_TRUE((*session)->start());
        PixelConverter converter;
        Image rgb;
        std::stop_source never;
        auto take = [&] {
            auto next = (*session)->next(never.get_token(), std::chrono::seconds(30));
            ASSERT_TRUE(next && next->has_value());
            ASSERT_TRUE(converter.convert((**next)->image, PixelFormat::kRgb8, rgb));
        };
        for (int i = 0; i < 10; ++i) take();  // warm-up sizes every buffer
        const std::uint64_t before = bench::allocationCount();
        for (int i = 0; i < 200; ++i) take();
        const std::uint64_t allocations = bench::allocationCount() - before;
        (*session)->stop();
        EXPECT_EQ(allocations, 0u) << (sync ? "sync" : "newest-wins") << " mode";
        EXPECT_GE((*session)->stats().frames_delivered, 210u);
    }
}

INSTANTIATE_TEST_SUITE_P(Formats, SteadyState,
                         ::testing::Values(PixelFormat::kRgb8, PixelFormat::kYuyv, PixelFormat::kNv12, PixelFormat::kGray8),
                         [](const auto& p) { return std::string(pixelFormatName(p.param)); });

}  // namespace
}  // namespace commonlight::capture

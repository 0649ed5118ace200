// In steady state the V4L2 backend allocates nothing per frame: poll, DQBUF, copy into a pool
// slot, QBUF, the hand-over through the session, and the periodic exposure/gain refresh with auto
// exposure on. Counted over every thread of the process (the test thread producing frames into
// the fake device and consuming them included).
#include <linux/videodev2.h>

#include <chrono>
#include <memory>

#include <gtest/gtest.h>

#include "bench/alloc_counter.h"
#include "capture/capture_session.h"
#include "hal/v4l2/v4l2_camera.h"
#include "mocks/fake_v4l2_device.h"

namespace commonlight::hal::v4l2 {
namespace {

class V4l2SteadyState : public ::testing::TestWithParam<PixelFormat> {};

TEST_P(V4l2SteadyState, NoAllocationPerFrame) {
    mocks::FakeV4l2System system;
    mocks::FakeV4l2Config config = mocks::FakeV4l2Config::webcam();
    config.line_padding = 32;
    mocks::FakeV4l2Device& device = system.add("/dev/video0", config);
    V4l2Options options;
    options.timeout_ms = 0;
    options.ae_refresh_frames = 4;  // auto exposure is on in the webcam: refresh often
    auto camera = V4l2Camera::open(system, "/dev/video0", options);
    ASSERT_TRUE(camera);
    ASSERT_TRUE((*camera)->configure({GetParam(), 640, 480, 0}));
    auto session = capture::CaptureSession::create(std::move(*camera), {});
    ASSERT_TRUE(session);
    ASSERT_TRUE((*session)->start());
    ASSERT_TRUE(device.waitStreaming(std::chrono::seconds(20)));
    std::stop_source never;
    auto frame = [&] {
        ASSERT_TRUE(device.waitAllQueued(std::chrono::seconds(20)));
        ASSERT_TRUE(device.produceFrame());
        auto next = (*session)->next(never.get_token(), std::chrono::seconds(20));
        ASSERT_TRUE(next && next->has_value());
    };
    for (int i = 0; i < 10; ++i) frame();  // warm-up
    const std::uint64_t before = bench::allocationCount();
    for (int i = 0; i < 200; ++i) frame();
    const std::uint64_t allocations = bench::allocationCount() - before;
    (*session)->stop();
    EXPECT_EQ(allocations, 0u);
    EXPECT_EQ((*session)->stats().frames_delivered, 210u);
}

INSTANTIATE_TEST_SUITE_P(Formats, V4l2SteadyState,
                         ::testing::Values(PixelFormat::kYuyv, PixelFormat::kMjpeg, PixelFormat::kNv12, PixelFormat::kGray8),
                         [](const auto& p) { return std::string(pixelFormatName(p.param)); });

}  // namespace
}  // namespace commonlight::hal::v4l2

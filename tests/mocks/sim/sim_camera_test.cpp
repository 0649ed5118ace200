#include "mocks/sim/sim_camera.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include "capture/capture_session.h"
#include "core/scene_io.h"
#include "tests/test_support.h"

namespace commonlight::mocks::sim {
namespace {

namespace fs = std::filesystem;
using testing::TempDir;

void writeScene(const fs::path& dir) {
    testing::writeText(dir / "calib.yaml", R"(%YAML:1.0
image_width: 48
image_height: 32
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 40., 0., 23.5, 0., 40., 15.5, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
   data: [ 0., 0., 0., 0., 0. ]
)");
    testing::writeText(dir / "scene.yaml", R"(
camera: calib.yaml
real:
  - {name: floor, plane: {size: [2, 2]}, albedo: 0.5}
lights:
  - {name: panel, area: {size: [0.5, 0.5]}, world_from_object: {t: [0, 0, 1.5], rpy_deg: [180, 0, 0]}, radiance: 20}
)");
    testing::writeText(dir / "traj.yaml",
                       "rate_hz: 10\npan: {eye: [0, -1, 1], from: [-0.1, 0, 0], to: [0.1, 0, 0], duration: 0.2}\n");
}

TEST(SimCamera, DeliversEveryFrameOfTheTrajectoryThenEnds) {
    // This test is about the camera's own thread and the capture session (it runs under TSan).
    // The renderer's TBB parallelism is kept to the calling thread: libtbb is not instrumented,
    // so TSan would report the scheduler's internals; render_determinism tests the parallel
    // renderer.
    tbb::global_control one_thread(tbb::global_control::max_allowed_parallelism, 1);
    TempDir dir;
    writeScene(dir.path());
    hal::CameraRegistry registry;
    registerSimBackend(registry);
    const std::string uri = "sim:" + (dir / "scene.yaml").string() + "?trajectory=" + (dir / "traj.yaml").string() +
                            "&spp=2&rate=max&exposure_us=5000";
    auto camera = registry.openConfigured(uri);
    ASSERT_TRUE(camera) << camera.error().message;
    EXPECT_EQ((*camera)->activeFormat().format, PixelFormat::kRgb8);
    EXPECT_EQ((*camera)->activeFormat().width, 48);
    capture::CaptureOptions options;
    options.sync = true;
    auto session = capture::CaptureSession::create(std::move(*camera), options);
    ASSERT_TRUE(session);
    auto started = (*session)->start();
    ASSERT_TRUE(started) << started.error().message;
    std::stop_source never;
    std::vector<std::int64_t> timestamps;
    while (true) {
        auto next = (*session)->next(never.get_token(), std::chrono::seconds(60));
        ASSERT_TRUE(next) << next.error().message;
        if (!next->has_value()) break;
        const Frame& frame = ***next;
        EXPECT_EQ(frame.meta.status, FrameStatus::kOk);
        EXPECT_EQ(frame.meta.timestamp_source, TimestampSource::kSimulated);
        EXPECT_EQ(frame.meta.exposure_us, 5000.0);
        EXPECT_EQ(frame.image.width(), 48);
        // The floor is lit: the image is not black.
        std::uint64_t sum = 0;
        for (std::size_t i = 0; i < frame.image.sizeBytes(); ++i) sum += frame.image.data()[i];
        EXPECT_GT(sum, frame.image.sizeBytes() * 10);
        timestamps.push_back(frame.meta.timestamp_ns);
    }
    EXPECT_EQ(timestamps, (std::vector<std::int64_t>{0, 100'000'000, 200'000'000}));
}

TEST(SimCamera, BadUrisAreUsageErrors) {
    TempDir dir;
    writeScene(dir.path());
    hal::CameraRegistry registry;
    registerSimBackend(registry);
    auto missing = registry.open("sim:" + (dir / "scene.yaml").string());
    ASSERT_FALSE(missing);
    EXPECT_EQ(missing.error().code, ErrorCode::kUsage);
    EXPECT_NE(missing.error().message.find("trajectory"), std::string::npos);
    auto bad = registry.open("sim:" + (dir / "nope.yaml").string() + "?trajectory=" + (dir / "traj.yaml").string());
    ASSERT_FALSE(bad);
    EXPECT_NE(bad.error().message.find("nope.yaml"), std::string::npos);
}

}  // namespace
}  // namespace commonlight::mocks::sim

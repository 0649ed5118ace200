#include "mocks/sim/simulation.h"

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/frame_file.h"
#include "core/scene_io.h"
#include "core/sequence_io.h"
#include "tests/test_support.h"

namespace commonlight::mocks::sim {
namespace {

namespace fs = std::filesystem;
using testing::TempDir;

// A floor under a ceiling light, a ball hovering over it: the ball's shadow is the changed region.
constexpr const char* kScene = R"(
tags:
  items:
    - {id: 5, size: 0.1, world_from_tag: {t: [-0.25, 0, 0]}}
real:
  - {name: floor, plane: {size: [2, 2]}, albedo: 0.5}
lights:
  - {name: panel, area: {size: [0.5, 0.5]}, world_from_object: {t: [0, 0, 1.5], rpy_deg: [180, 0, 0]}, radiance: 20}
virtual:
  - {name: ball, sphere: {radius: 0.1}, material: {albedo: [0.8, 0.2, 0.2]}, world_from_object: {t: [0.1, 0, 0.3]}}
)";

Scene testScene() {
    auto scene = parseScene(kScene, "test_scene.yaml");
    EXPECT_TRUE(scene) << scene.error().message;
    return *scene;
}

Trajectory testTrajectory() {
    auto trajectory = Trajectory::parse("rate_hz: 10\nkeyframes:\n"
                                        "  - {t: 0, eye: [0, -0.9, 1.0], target: [0, 0, 0]}\n"
                                        "  - {t: 0.2, eye: [0.1, -0.9, 1.0], target: [0, 0, 0]}\n",
                                        "traj.yaml");
    EXPECT_TRUE(trajectory) << trajectory.error().message;
    return *trajectory;
}

SimulationOptions smallOptions(const fs::path& out) {
    SimulationOptions options;
    options.out = out;
    options.spp = 4;
    options.max_depth = 3;
    CameraModel cam;
    cam.width = 80;
    cam.height = 60;
    cam.fx = cam.fy = 70.0;
    cam.cx = 39.5;
    cam.cy = 29.5;
    cam.distortion.k1 = -0.1;
    options.camera = cam;
    return options;
}

TEST(Simulation, WritesASequenceWithItsGroundTruth) {
    TempDir dir;
    const fs::path seq_dir = dir / "seq";
    int progress_calls = 0;
    auto summary = simulate(testScene(), testTrajectory(), smallOptions(seq_dir),
                            [&](int done, int total) {
                                ++progress_calls;
                                EXPECT_EQ(total, 3);
                                EXPECT_EQ(done, progress_calls);
                            });
    ASSERT_TRUE(summary) << summary.error().message;
    EXPECT_EQ(summary->frames_written, 3);
    EXPECT_EQ(summary->nonfinite_samples, 0);

    auto seq = readSequence(seq_dir);
    ASSERT_TRUE(seq) << seq.error().message;
    ASSERT_EQ(seq->frames.size(), 3u);
    EXPECT_EQ(seq->frames[1].timestamp_ns, 100'000'000);
    ASSERT_TRUE(seq->sensor.camera);
    EXPECT_EQ(*seq->sensor.camera, *smallOptions(seq_dir).camera);
    EXPECT_EQ(seq->sensor.rate_hz, 10.0);
    ASSERT_EQ(seq->groundtruth_poses.size(), 3u);
    EXPECT_LT(translationError(seq->groundtruth_poses[2].world_from_cam, testTrajectory().worldFromCam(0.2)), 1e-12);
    ASSERT_TRUE(seq->meta[0]);
    EXPECT_EQ(seq->meta[0]->exposure_us, SensorParams{}.exposure_us);
    // The pose at the middle of each exposure: the instant the frames were rendered at.
    const double half_exposure_s = 0.5e-6 * SensorParams{}.exposure_us;
    ASSERT_EQ(seq->groundtruth_mid_exposure_poses.size(), 3u);
    EXPECT_EQ(seq->groundtruth_mid_exposure_poses[1].timestamp_ns, 100'000'000 + std::llround(half_exposure_s * 1e9));
    const Rigid3d mid = testTrajectory().worldFromCam(0.1 + half_exposure_s);
    EXPECT_GT(translationError(mid, testTrajectory().worldFromCam(0.1)), 1e-4);  // it moves
    EXPECT_LT(translationError(seq->groundtruth_mid_exposure_poses[1].world_from_cam, mid), 1e-12);
    EXPECT_LT(translationError(*groundTruthOfFrame(*seq, 1), mid), 1e-12);

    // The estimator's scene hides the truth; the ground truth keeps it.
    auto estimator = readScene(seq_dir / "scene.yaml");
    ASSERT_TRUE(estimator) << estimator.error().message;
    EXPECT_TRUE(estimator->real_objects[0].albedo.isEstimate());
    EXPECT_TRUE(estimator->lights[0].emission.isEstimate());
    EXPECT_EQ(estimator->virtual_objects.size(), 1u);
    auto truth = readScene(seq_dir / "groundtruth" / "scene.yaml");
    ASSERT_TRUE(truth);
    EXPECT_EQ(truth->real_objects[0].albedo.value, Eigen::Vector3d::Constant(0.5));
    auto lights = readScene(seq_dir / "groundtruth" / "lights.yaml");
    ASSERT_TRUE(lights);
    ASSERT_EQ(lights->lights.size(), 1u);
    EXPECT_EQ(lights->lights[0].emission.value, Eigen::Vector3d::Constant(20));

    // The composite shows the ball; the masks mark it and its shadow.
    const std::string stem = std::to_string(seq->frames[0].timestamp_ns);
    const cv::Mat frame = cv::imread(seq->framePath(0).string());
    const cv::Mat composite = cv::imread((seq_dir / "groundtruth/composite" / (stem + ".png")).string());
    const cv::Mat virtual_mask = cv::imread((seq_dir / "groundtruth/masks/virtual" / (stem + ".png")).string(), cv::IMREAD_GRAYSCALE);
    const cv::Mat changed = cv::imread((seq_dir / "groundtruth/masks/changed" / (stem + ".png")).string(), cv::IMREAD_GRAYSCALE);
    const cv::Mat radiance = cv::imread((seq_dir / "groundtruth/radiance" / (stem + ".exr")).string(), cv::IMREAD_UNCHANGED);
    ASSERT_FALSE(frame.empty());
    ASSERT_FALSE(composite.empty());
    ASSERT_FALSE(virtual_mask.empty());
    ASSERT_FALSE(changed.empty());
    ASSERT_EQ(radiance.type(), CV_32FC3);
    EXPECT_GT(cv::countNonZero(virtual_mask), 20);
    EXPECT_GT(cv::countNonZero(changed), 20);
    // Outside both masks the composite is the frame: same samples, same sensor noise. Only the
    // few paths that bounce off the ball differ there (by less than the 1% of the changed mask,
    // after its 9x9 filter).
    cv::Mat outside = (virtual_mask == 0) & (changed == 0);
    cv::Mat diff;
    cv::absdiff(frame, composite, diff);
    cv::Mat diff_gray;
    cv::cvtColor(diff, diff_gray, cv::COLOR_BGR2GRAY);
    const int outside_pixels = cv::countNonZero(outside);
    const int differing_outside = cv::countNonZero((diff_gray > 2) & outside);
    EXPECT_GT(outside_pixels, 3000);
    EXPECT_LT(differing_outside, outside_pixels / 50);
    EXPECT_LT(cv::mean(diff_gray, outside)[0], 0.3);
    // Inside the virtual mask it does not.
    double max_inside = 0.0;
    cv::minMaxLoc(diff_gray, nullptr, &max_inside, nullptr, nullptr, virtual_mask == 255);
    EXPECT_GT(max_inside, 30.0);
}

TEST(Simulation, SameSeedSameBytes) {
    TempDir dir;
    SimulationOptions options = smallOptions(dir / "a");
    options.write_masks = options.write_radiance = false;
    ASSERT_TRUE(simulate(testScene(), testTrajectory(), options));
    options.out = dir / "b";
    ASSERT_TRUE(simulate(testScene(), testTrajectory(), options));
    options.out = dir / "c";
    options.seed = 2;
    ASSERT_TRUE(simulate(testScene(), testTrajectory(), options));
    const std::string a = testing::readText(dir / "a/cam0/data/100000000.png");
    EXPECT_EQ(a, testing::readText(dir / "b/cam0/data/100000000.png"));
    EXPECT_EQ(testing::readText(dir / "a/groundtruth/composite/0.png"), testing::readText(dir / "b/groundtruth/composite/0.png"));
    EXPECT_NE(a, testing::readText(dir / "c/cam0/data/100000000.png"));
}

TEST(Simulation, AStopLeavesAReadableSequenceOfTheFramesDone) {
    TempDir dir;
    std::stop_source stop;
    SimulationOptions options = smallOptions(dir / "seq");
    options.frame_format = FrameFileFormat::kJpeg;
    auto summary = simulate(testScene(), testTrajectory(), options,
                            [&](int done, int) {
                                if (done == 2) stop.request_stop();
                            },
                            stop.get_token());
    ASSERT_TRUE(summary);
    EXPECT_TRUE(summary->stopped);
    EXPECT_EQ(summary->frames_written, 2);
    auto seq = readSequence(dir / "seq");
    ASSERT_TRUE(seq) << seq.error().message;
    EXPECT_EQ(seq->frames.size(), 2u);
    EXPECT_EQ(seq->groundtruth_poses.size(), 2u);
    EXPECT_EQ(seq->sensor.pixel_format, PixelFormat::kMjpeg);
    Image image;
    EXPECT_TRUE(FrameFileReader().read(seq->framePath(1), seq->sensor.pixel_format, 80, 60, image));
}

TEST(Simulation, DefocusInkSpreadAndGammaConditions) {
    // The conditions of `bench tracking`'s response cases: the defocused frame is the sharp
    // frame's radiance convolved with the disc; ink spread changes the tag's pixels; a gamma
    // response is written into the sequence as core/response.h spells it.
    TempDir dir;
    const auto renderOne = [&](const std::string& name, double defocus, double ink) {
        SimulationOptions options = smallOptions(dir / name);
        options.frames = 1;
        options.write_composite = false;
        options.write_masks = false;
        options.defocus_radius_px = defocus;
        options.tag_ink_spread_cells = ink;
        options.sensor.response = SensorResponse::kGamma;
        options.sensor.gamma = 2.6;
        EXPECT_TRUE(simulate(testScene(), testTrajectory(), options));
        return cv::imread((dir / name / "groundtruth/radiance/0.exr").string(), cv::IMREAD_UNCHANGED);
    };
    const cv::Mat sharp = renderOne("sharp", 0.0, 0.0);
    const cv::Mat blurred = renderOne("defocus", 1.5, 0.0);
    const cv::Mat inked = renderOne("ink", 0.0, 0.2);
    ASSERT_FALSE(sharp.empty() || blurred.empty() || inked.empty());
    // The disc of radius 1.5: a 5 x 5 kernel whose weights are the disc's area in each pixel.
    cv::Mat kernel(5, 5, CV_32F, cv::Scalar(0));
    for (int y = -2; y <= 2; ++y) {
        for (int x = -2; x <= 2; ++x) {
            int inside = 0;
            for (int sy = 0; sy < 64; ++sy) {
                for (int sx = 0; sx < 64; ++sx) {
                    const double px = x - 0.5 + (sx + 0.5) / 64, py = y - 0.5 + (sy + 0.5) / 64;
                    inside += px * px + py * py <= 2.25;
                }
            }
            kernel.at<float>(y + 2, x + 2) = static_cast<float>(inside) / (64 * 64);
        }
    }
    EXPECT_NEAR(cv::sum(kernel)[0], M_PI * 2.25, 0.01);
    cv::Mat expected;
    cv::filter2D(sharp, expected, -1, kernel / cv::sum(kernel)[0], cv::Point(-1, -1), 0.0, cv::BORDER_REPLICATE);
    EXPECT_LT(cv::norm(blurred, expected, cv::NORM_INF), 0.02 * cv::norm(sharp, cv::NORM_INF));
    EXPECT_GT(cv::norm(blurred, sharp, cv::NORM_INF), 0.1 * cv::norm(sharp, cv::NORM_INF));
    // Black grown by a fifth of a cell darkens the frame where the tag is.
    EXPECT_LT(cv::sum(inked)[0], cv::sum(sharp)[0] - 1e-3 * cv::sum(sharp)[0]);
    auto seq = readSequence(dir / "sharp");
    ASSERT_TRUE(seq) << seq.error().message;
    EXPECT_EQ(seq->sensor.response, "gamma:2.6");

    SimulationOptions bad = smallOptions(dir / "bad");
    bad.defocus_radius_px = -1;
    EXPECT_FALSE(simulate(testScene(), testTrajectory(), bad));
    bad = smallOptions(dir / "bad");
    bad.tag_ink_spread_cells = 0.5;
    EXPECT_FALSE(simulate(testScene(), testTrajectory(), bad));
}

TEST(Simulation, RefusesBadOptionsAndAnExistingSequence) {
    TempDir dir;
    SimulationOptions options = smallOptions(dir / "seq");
    options.spp = 0;
    auto r = simulate(testScene(), testTrajectory(), options);
    ASSERT_FALSE(r);
    EXPECT_EQ(r.error().code, ErrorCode::kUsage);
    options = smallOptions(dir / "seq");
    options.frames = 1;
    ASSERT_TRUE(simulate(testScene(), testTrajectory(), options));
    r = simulate(testScene(), testTrajectory(), options);
    ASSERT_FALSE(r);
    EXPECT_NE(r.error().message.find("refusing to overwrite"), std::string::npos);
    Scene no_camera = testScene();
    options = smallOptions(dir / "other");
    options.camera.reset();
    r = simulate(no_camera, testTrajectory(), options);
    ASSERT_FALSE(r);
    EXPECT_NE(r.error().message.find("no camera"), std::string::npos);
}

}  // namespace
}  // namespace commonlight::mocks::sim

// Tag pattern alignment: the pattern's cell boundaries, and poses against the true poses of the
// bundled sample (the desk scene rendered by mocks/sim).
#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <map>

#include <gtest/gtest.h>

#include "capture/convert.h"
#include "core/frame_file.h"
#include "core/scene_io.h"
#include "core/sequence_io.h"
#include "tracking/tag_align.h"
#include "tracking/tag_detector.h"
#include "tracking/tag_pose.h"
#include "tracking/tag_refine.h"

namespace commonlight::tracking {
namespace {

namespace fs = std::filesystem;

TEST(TagPattern, BoundariesOfTag36h11) {
    auto pattern = TagPattern::make("tag36h11", 0);
    ASSERT_TRUE(pattern) << pattern.error().message;
    EXPECT_DOUBLE_EQ(pattern->cell(), 1.0 / 8.0);
    // The black square's outline: 8 cells per side, all dark inside, bright outside.
    int outline = 0;
    for (const auto& e : pattern->edges()) {
        const Eigen::Vector2d mid = 0.5 * (e.a + e.b);
        EXPECT_NEAR((e.b - e.a).norm(), 1.0 / 8.0, 1e-12);
        EXPECT_NEAR(std::abs(e.to_bright.dot(e.b - e.a)), 0.0, 1e-12);
        if (std::abs(std::abs(mid.x()) - 0.5) < 1e-9 || std::abs(std::abs(mid.y()) - 0.5) < 1e-9) {
            ++outline;
            EXPECT_GT(e.to_bright.dot(mid), 0.0) << "the outline's bright side is outside";
        }
    }
    EXPECT_EQ(outline, 32);
    EXPECT_GT(pattern->edges().size(), 60u);
    EXPECT_FALSE(TagPattern::make("tag36h11", 587));
    EXPECT_FALSE(TagPattern::make("tag99h99", 0));
    TagPatternCache cache("tag36h11");
    EXPECT_EQ(cache.get(3), cache.get(3));
    EXPECT_EQ(cache.get(-1), nullptr);
}

TEST(TagAlign, BeatsTheCornerPoseOnTheDeskSample) {
    const char* src = std::getenv("COMMONLIGHT_SOURCE_DIR");
    const fs::path root = src ? fs::path(src) : fs::current_path();
    auto seq = readSequence(root / "data/sample");
    auto scene = readScene(root / "data/sample/scene.yaml");
    ASSERT_TRUE(seq && scene);
    const CameraModel cam = *seq->sensor.camera;
    std::map<std::int64_t, Rigid3d> truth;
    for (const auto& p : seq->groundtruth_poses) truth[p.timestamp_ns] = p.world_from_cam.inverse();
    auto detector = TagDetector::create({});
    ASSERT_TRUE(detector);
    TagPatternCache patterns("tag36h11");
    FrameFileReader reader;
    capture::PixelConverter converter;
    Image raw, grey;
    std::vector<double> corner_rot, aligned_rot;
    double max_corner_change = 0.0;  // stopping at convergence against every iteration
    for (std::size_t i = 0; i < seq->frames.size(); i += 2) {
        ASSERT_TRUE(reader.read(seq->framePath(i), seq->sensor.pixel_format, 0, 0, raw));
        ASSERT_TRUE(converter.convert(raw.view(), PixelFormat::kGray8, grey));
        auto detections = detector->detect(grey.view());
        ASSERT_TRUE(detections);
        for (const TagDetection& d : *detections) {
            const TagItem* item = scene->tags.find(d.id);
            ASSERT_NE(item, nullptr);
            auto corners = d.corners;
            refineTagCorners(grey.view(), cam, corners);
            auto pose = solveTagPose(d.id, corners, item->size, cam);
            ASSERT_TRUE(pose);
            const Rigid3d true_pose = truth.at(seq->frames[i].timestamp_ns) * item->world_from_tag;
            const TagAlignResult a = alignTagPose(grey.view(), cam, *patterns.get(d.id), item->size, pose->cam_from_tag);
            ASSERT_TRUE(a.ok) << a.reason;
            EXPECT_GT(a.points, 100);
            EXPECT_TRUE(a.covariance.allFinite());
            // Stopping once a step moves the corners by under converged_px (0.01 px) ends where
            // every iteration would: within a few thousandths of a pixel.
            TagAlignOptions every_iteration;
            every_iteration.converged_px = 0.0;
            const TagAlignResult all =
                alignTagPose(grey.view(), cam, *patterns.get(d.id), item->size, pose->cam_from_tag, every_iteration);
            ASSERT_TRUE(all.ok) << all.reason;
            for (int c = 0; c < 4; ++c) {
                const auto p = cam.project(a.cam_from_tag * tagCornerInTag(c, item->size));
                const auto q = cam.project(all.cam_from_tag * tagCornerInTag(c, item->size));
                ASSERT_TRUE(p && q);
                max_corner_change = std::max(max_corner_change, (*p - *q).norm());
            }
            EXPECT_NEAR(a.rms_px, all.rms_px, 0.01);
            corner_rot.push_back(rotationErrorDeg(pose->cam_from_tag, true_pose));
            aligned_rot.push_back(rotationErrorDeg(a.cam_from_tag, true_pose));
        }
    }
    ASSERT_GT(corner_rot.size(), 100u);
    const auto median = [](std::vector<double> v) {
        std::sort(v.begin(), v.end());
        return v[v.size() / 2];
    };
    std::printf("  %zu tags: rotation error median %.3f deg from corners, %.3f deg aligned\n", corner_rot.size(),
                median(corner_rot), median(aligned_rot));
    EXPECT_LT(median(aligned_rot), 0.75 * median(corner_rot));
    std::printf("  stopping at convergence moves the aligned corners by at most %.4f px\n", max_corner_change);
    EXPECT_LT(max_corner_change, 0.01);
}

TEST(TagAlign, RefusesTinyTagsAndBadInput) {
    CameraModel cam;
    cam.width = 640;
    cam.height = 480;
    cam.fx = cam.fy = 500;
    cam.cx = 319.5;
    cam.cy = 239.5;
    auto pattern = TagPattern::make("tag36h11", 1);
    ASSERT_TRUE(pattern);
    Image grey(PixelFormat::kGray8, 640, 480);
    std::fill_n(grey.data(), grey.sizeBytes(), std::uint8_t{100});
    const Rigid3d far(Eigen::Quaterniond(Eigen::AngleAxisd(3.14159265358979, Eigen::Vector3d::UnitX())),
                      Eigen::Vector3d(0, 0, 5.0));  // 0.1 m at 5 m: 10 px, cells of 1.25 px
    TagAlignResult small = alignTagPose(grey.view(), cam, *pattern, 0.1, far);
    EXPECT_FALSE(small.ok);
    EXPECT_NE(small.reason.find("too small"), std::string::npos) << small.reason;
    EXPECT_FALSE(small.measured);  // refused before any fit: no evidence against the pose
    EXPECT_TRUE(small.cam_from_tag.isValid());
    // Close enough, but a blank image: nothing to align with.
    const Rigid3d near(far.rotation, Eigen::Vector3d(0, 0, 0.5));
    TagAlignResult blank = alignTagPose(grey.view(), cam, *pattern, 0.1, near);
    EXPECT_FALSE(blank.ok);
    EXPECT_TRUE(blank.measured);  // the fit ran and found nothing
    EXPECT_FALSE(blank.reason.empty());
    Rigid3d nan_pose = near;
    nan_pose.translation.x() = std::nan("");
    EXPECT_FALSE(alignTagPose(grey.view(), cam, *pattern, 0.1, nan_pose).ok);
}

}  // namespace
}  // namespace commonlight::tracking

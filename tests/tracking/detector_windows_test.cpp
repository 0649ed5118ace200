// The decimated detector on a window of the frame (TagDetector::detectInWindows, tracking mode's
// step 1) finds what it finds on the whole frame, wherever the window starts. libapriltag
// decimates by sampling every other pixel from the image's origin and thresholds in tiles from
// it: a window starting at an odd pixel once saw the other pixels of a 2 px cell and missed tags
// the full frame found (bench case `wide`, docs/tracking.md "Windows"). Ground truth: the
// full-frame detection of the same image, and the tags' projected corners.
#include <set>

#include <gtest/gtest.h>

#include "tracking/tag_detector.h"
#include "tracking/tracker_support.h"
#include "tests/tracking/synthetic_tags.h"

namespace commonlight::tracking {
namespace {

using Eigen::Vector2d;
using Eigen::Vector3d;

// 24 tags 1 m in front of the camera in a 6 x 4 grid, black squares of 26-37 px (cells of 1.6-2.3
// px at decimate 2: where the decimated detector's success depends on which pixels it samples),
// turned in the image by 0-50 degrees and tilted by 0-30 degrees.
std::vector<testing::SyntheticTag> grid() {
    std::vector<testing::SyntheticTag> tags;
    for (int k = 0; k < 24; ++k) {
        const double size = 0.052 + 0.001 * ((7 * k) % 23);
        const Eigen::Quaterniond turn(Eigen::AngleAxisd(M_PI, Vector3d::UnitX()) *
                                      Eigen::AngleAxisd(0.035 * ((5 * k) % 15), Vector3d::UnitZ()) *
                                      Eigen::AngleAxisd(0.1 * (k % 6), Vector3d::UnitY()));
        tags.push_back({k, size, Rigid3d(turn, Vector3d(-0.5 + 0.2 * (k % 6), -0.3 + 0.2 * (k / 6), 1.0))});
    }
    return tags;
}

std::array<Vector2d, 4> projectedCorners(const CameraModel& camera, const testing::SyntheticTag& tag) {
    std::array<Vector2d, 4> corners;
    for (int c = 0; c < 4; ++c) corners[static_cast<std::size_t>(c)] = *camera.project(tag.cam_from_tag * tagCornerInTag(c, tag.size));
    return corners;
}

TEST(DetectorWindows, AWindowFindsWhatTheFullFrameFindsAtAnyOrigin) {
    const CameraModel camera = testing::syntheticCamera();
    const auto tags = grid();
    TagDetectorOptions options;
    options.decimate = 2.0;
    auto detector = TagDetector::create(options);
    ASSERT_TRUE(detector) << detector.error().message;

    int compared = 0, differing = 0, full_found = 0;
    for (const std::uint64_t seed : {1u, 2u}) {
        const Image image =
            testing::renderSyntheticTags(camera, tags, {.supersample = 3, .blur_sigma_px = 0.8, .noise_sigma = 1.5, .seed = seed});
        auto full = detector->detect(image.view());
        ASSERT_TRUE(full) << full.error().message;
        for (const auto& tag : tags) {
            const auto in_full = std::find_if(full->begin(), full->end(), [&](const TagDetection& d) { return d.id == tag.id; });
            full_found += in_full != full->end() ? 1 : 0;
            // Tracking mode's window around the tag (half its size, at least 12 px), started at
            // every phase of the decimation and of the threshold's 8 px tiles.
            const PixelWindow box = tracker_support::grownBox(projectedCorners(camera, tag), 0.5, 12);
            for (int shift = 0; shift < 8; ++shift) {
                const PixelWindow w{box.x - shift, box.y - (shift * 3) % 8, box.width + shift, box.height + (shift * 3) % 8};
                auto windowed = detector->detectInWindows(image.view(), std::span<const PixelWindow>(&w, 1));
                ASSERT_TRUE(windowed) << windowed.error().message;
                const auto in_window =
                    std::find_if(windowed->begin(), windowed->end(), [&](const TagDetection& d) { return d.id == tag.id; });
                ++compared;
                const bool same = (in_full == full->end()) == (in_window == windowed->end());
                differing += same ? 0 : 1;
                EXPECT_TRUE(same) << "tag " << tag.id << " (seed " << seed << "), window at (" << w.x << ", " << w.y
                                  << "): full frame " << (in_full != full->end() ? "found" : "missed") << " it, the window "
                                  << (in_window != windowed->end() ? "found" : "missed") << " it";
                if (same && in_full != full->end()) {
                    for (std::size_t c = 0; c < 4; ++c) {
                        EXPECT_NEAR((in_window->corners[c] - in_full->corners[c]).norm(), 0.0, 0.2)
                            << "tag " << tag.id << " corner " << c << ", window at (" << w.x << ", " << w.y << ")";
                    }
                }
            }
        }
    }
    // The set must hold tags the decimated detector finds and tags it misses, or it tests nothing.
    EXPECT_GT(full_found, 8);
    EXPECT_LT(full_found, 48);
    std::printf("full frame found %d of 48 tags; %d of %d windows disagreed with it\n", full_found, differing, compared);
}

}  // namespace
}  // namespace commonlight::tracking

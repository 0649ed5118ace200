// The tracking stage end to end on the bundled sample (the desk scene rendered by mocks/sim,
// with its true camera poses), and its contract on frames without tags and bad frames.
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <map>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "capture/convert.h"
#include "core/frame_file.h"
#include "core/scene_io.h"
#include "core/sequence_io.h"
#include "tracking/tracker.h"

namespace commonlight::tracking {
namespace {

namespace fs = std::filesystem;

struct Sample {
    Sequence seq;
    Scene scene;
    std::vector<Image> grey;
    std::vector<Rigid3d> cam_from_world_true;
};

const Sample& sample() {
    static const Sample s = [] {
        Sample out;
        const char* src = std::getenv("COMMONLIGHT_SOURCE_DIR");
        const fs::path root = src ? fs::path(src) : fs::current_path();
        auto seq = readSequence(root / "data/sample");
        EXPECT_TRUE(seq) << seq.error().message;
        out.seq = std::move(*seq);
        auto scene = readScene(root / "data/sample/scene.yaml");
        EXPECT_TRUE(scene) << scene.error().message;
        out.scene = std::move(*scene);
        FrameFileReader reader;
        capture::PixelConverter converter;
        std::map<std::int64_t, Rigid3d> truth;
        for (const auto& p : out.seq.groundtruth_poses) truth[p.timestamp_ns] = p.world_from_cam.inverse();
        for (std::size_t i = 0; i < out.seq.frames.size(); ++i) {
            Image raw, grey;
            EXPECT_TRUE(reader.read(out.seq.framePath(i), out.seq.sensor.pixel_format, 0, 0, raw));
            EXPECT_TRUE(converter.convert(raw.view(), PixelFormat::kGray8, grey));
            out.grey.push_back(std::move(grey));
            out.cam_from_world_true.push_back(truth.at(out.seq.frames[i].timestamp_ns));
        }
        return out;
    }();
    return s;
}

Tracker makeTracker(const TrackerOptions& options) {
    const Sample& s = sample();
    auto tracker = Tracker::create(*s.seq.sensor.camera, s.scene.tags, &s.scene, options);
    EXPECT_TRUE(tracker) << tracker.error().message;
    return std::move(*tracker);
}

TEST(Tracker, TracksTheDeskSampleAgainstItsGroundTruth) {
    const Sample& s = sample();
    ASSERT_GE(s.grey.size(), 60u);
    for (const bool filter : {false, true}) {
        TrackerOptions options;
        options.filter = filter;
        Tracker tracker = makeTracker(options);
        double worst_rot = 0, worst_mm = 0;
        for (std::size_t i = 0; i < s.grey.size(); ++i) {
            auto track = tracker.process(s.grey[i].view(), s.seq.frames[i].timestamp_ns);
            ASSERT_TRUE(track) << track.error().message;
            ASSERT_EQ(track->status, TrackStatus::kTracked) << "frame " << i;
            ASSERT_TRUE(track->cam_from_world && track->bundle);
            EXPECT_EQ(track->bundle->tags_used.size(), 4u) << "frame " << i;
            worst_rot = std::max(worst_rot, rotationErrorDeg(*track->cam_from_world, s.cam_from_world_true[i]));
            worst_mm = std::max(worst_mm, 1000 * (track->cam_from_world->inverse().translation -
                                                  s.cam_from_world_true[i].inverse().translation)
                                                     .norm());
        }
        std::printf("  filter %s: worst rotation error %.3f deg, worst camera position error %.1f mm\n",
                    filter ? "on" : "off", worst_rot, worst_mm);
        EXPECT_LT(worst_rot, 0.3);
        EXPECT_LT(worst_mm, 8.0);
    }
}

TEST(Tracker, TrackingModeDetectsInWindowsWithTheSamePoses) {
    const Sample& s = sample();
    TrackerOptions full, windowed;
    windowed.tracking_mode = true;
    windowed.redetect_every = 10;
    Tracker a = makeTracker(full), b = makeTracker(windowed);
    int full_frames = 0;
    double worst = 0;
    for (std::size_t i = 0; i < s.grey.size(); ++i) {
        auto ta = a.process(s.grey[i].view(), s.seq.frames[i].timestamp_ns);
        auto tb = b.process(s.grey[i].view(), s.seq.frames[i].timestamp_ns);
        ASSERT_TRUE(ta && tb);
        ASSERT_TRUE(ta->cam_from_world && tb->cam_from_world) << "frame " << i;
        EXPECT_EQ(ta->tags.size(), tb->tags.size()) << "frame " << i;
        if (tb->full_frame_detection) ++full_frames;
        worst = std::max(worst, rotationErrorDeg(*ta->cam_from_world, *tb->cam_from_world));
    }
    // Frame 0 and every 10th after it; the windows find every tag in between.
    EXPECT_LE(full_frames, static_cast<int>(s.grey.size()) / 10 + 2);
    EXPECT_LT(worst, 0.05) << "windowed detection should find the same corners";
}

// A folder of photos: each image gives what it gives alone, in any order (nothing carried over).
TEST(Tracker, IndependentFramesGiveWhatEachGivesAlone) {
    const Sample& s = sample();
    TrackerOptions options;
    options.filter = false;
    options.independent_frames = true;
    Tracker together = makeTracker(options);
    for (const std::size_t i : {std::size_t{50}, std::size_t{10}, std::size_t{30}, std::size_t{11}}) {
        auto t = together.process(s.grey[i].view(), 0);
        ASSERT_TRUE(t && t->cam_from_world) << "image " << i;
        EXPECT_FALSE(together.predict(0)) << "nothing is predicted from the images before";
        Tracker alone = makeTracker(options);
        auto a = alone.process(s.grey[i].view(), 0);
        ASSERT_TRUE(a && a->cam_from_world) << "image " << i;
        EXPECT_EQ(t->cam_from_world->translation, a->cam_from_world->translation) << "image " << i;
        EXPECT_EQ(t->cam_from_world->rotation.coeffs(), a->cam_from_world->rotation.coeffs()) << "image " << i;
        ASSERT_EQ(t->tags.size(), a->tags.size());
        for (std::size_t k = 0; k < t->tags.size(); ++k) {
            ASSERT_EQ(t->tags[k].pose.has_value(), a->tags[k].pose.has_value());
            if (t->tags[k].pose) {
                EXPECT_EQ(t->tags[k].pose->cam_from_tag.translation, a->tags[k].pose->cam_from_tag.translation);
            }
        }
    }
    // With a filter or tracking mode the option is a usage error.
    options.filter = true;
    EXPECT_FALSE(Tracker::create(*s.seq.sensor.camera, s.scene.tags, &s.scene, options));
}

TEST(Tracker, FramesWithoutTagsArePredictedThenLost) {
    const Sample& s = sample();
    Tracker tracker = makeTracker({});
    Image blank(PixelFormat::kGray8, s.grey[0].width(), s.grey[0].height());
    std::fill_n(blank.data(), blank.sizeBytes(), std::uint8_t{128});
    // Nothing seen yet: no pose, not an error.
    auto first = tracker.process(blank.view(), 0);
    ASSERT_TRUE(first) << first.error().message;
    EXPECT_EQ(first->status, TrackStatus::kNoPose);
    EXPECT_FALSE(first->cam_from_world);
    EXPECT_FALSE(tracker.predict(0));
    // Tracked, then the tags vanish: predicted while recent, then no pose.
    for (int i = 0; i < 5; ++i) {
        auto t = tracker.process(s.grey[i].view(), s.seq.frames[i].timestamp_ns + 1);
        ASSERT_TRUE(t && t->status == TrackStatus::kTracked);
    }
    const std::int64_t last = s.seq.frames[4].timestamp_ns + 1;
    auto gone = tracker.process(blank.view(), last + 33'333'333);
    ASSERT_TRUE(gone);
    EXPECT_EQ(gone->status, TrackStatus::kPredicted);
    ASSERT_TRUE(gone->cam_from_world);
    EXPECT_LT(rotationErrorDeg(*gone->cam_from_world, s.cam_from_world_true[5]), 0.5);
    auto long_gone = tracker.process(blank.view(), last + 2'000'000'000);
    ASSERT_TRUE(long_gone);
    EXPECT_EQ(long_gone->status, TrackStatus::kNoPose);
    // The renderer asks for any timestamp: between two frames, the pose is in between.
    ASSERT_TRUE(tracker.predict(last + 16'000'000));
}

// The frame with every tag painted over in the colour of the table around it.
Image withoutTags(const Image& grey, const Rigid3d& cam_from_world, const CameraModel& camera, const TagSet& tags) {
    Image out = Image::copyOf(grey.view());
    cv::Mat m(out.height(), out.width(), CV_8UC1, out.data(), out.stride());
    std::vector<cv::Point> hull_input;
    for (const TagItem& item : tags.items) {
        for (int c = 0; c < 4; ++c) {
            // The printed square with its white border and a margin: 1.5 x the black square.
            const auto px = camera.project(cam_from_world * (item.world_from_tag * (1.5 * tagCornerInTag(c, item.size))));
            if (px) hull_input.emplace_back(static_cast<int>(std::lround(px->x())), static_cast<int>(std::lround(px->y())));
        }
    }
    std::vector<cv::Point> hull;
    cv::convexHull(hull_input, hull);
    // The table's grey: the median of a ring just outside the hull.
    cv::Mat inside(m.size(), CV_8UC1, cv::Scalar(0)), grown;
    cv::fillConvexPoly(inside, hull, cv::Scalar(255));
    cv::dilate(inside, grown, cv::Mat(), cv::Point(-1, -1), 6);
    std::vector<std::uint8_t> ring;
    for (int y = 0; y < m.rows; ++y) {
        for (int x = 0; x < m.cols; ++x) {
            if (grown.at<std::uint8_t>(y, x) && !inside.at<std::uint8_t>(y, x)) ring.push_back(m.at<std::uint8_t>(y, x));
        }
    }
    std::nth_element(ring.begin(), ring.begin() + static_cast<std::ptrdiff_t>(ring.size() / 2), ring.end());
    cv::fillConvexPoly(m, hull, cv::Scalar(ring[ring.size() / 2]));
    return out;
}

// A looping replay (or a fast move): the sample to its end, then its first frame again one frame
// period later, 0.57 m and 24 degrees away from where the motion model expects the camera. Four
// tags agree on the new pose, so it is reported at once (tracked), not the filter's extrapolation
// of the old motion while its gate refuses the measurement. A single tag that disagrees with the
// prediction is still refused, and the frame says it reports the prediction.
TEST(Tracker, AJumpSeenByTwoOrMoreTagsIsTakenAtOnce) {
    const Sample& s = sample();
    TrackerOptions options;
    options.tracking_mode = true;  // as play and live run it
    Tracker tracker = makeTracker(options);
    const std::size_t n = s.grey.size();
    for (std::size_t i = 0; i < n; ++i) ASSERT_TRUE(tracker.process(s.grey[i].view(), s.seq.frames[i].timestamp_ns));
    const std::int64_t period = s.seq.frames[1].timestamp_ns - s.seq.frames[0].timestamp_ns;
    for (std::size_t k = 0; k < 4; ++k) {
        const std::int64_t t = s.seq.frames[n - 1].timestamp_ns + static_cast<std::int64_t>(k + 1) * period;
        auto track = tracker.process(s.grey[k].view(), t);
        ASSERT_TRUE(track) << track.error().message;
        ASSERT_EQ(track->status, TrackStatus::kTracked) << "frame " << k << " after the jump";
        ASSERT_TRUE(track->cam_from_world);
        const double mm = 1000 * (track->cam_from_world->inverse().translation - s.cam_from_world_true[k].inverse().translation).norm();
        EXPECT_LT(rotationErrorDeg(*track->cam_from_world, s.cam_from_world_true[k]), 0.3) << "frame " << k << " after the jump";
        EXPECT_LT(mm, 8.0) << "frame " << k << " after the jump";
    }

    // One tag only (the others painted over): beyond the gate, refused; the prediction, said so.
    Tracker single = makeTracker(options);
    for (std::size_t i = 0; i < n; ++i) ASSERT_TRUE(single.process(s.grey[i].view(), s.seq.frames[i].timestamp_ns));
    Image first_only = Image::copyOf(s.grey[0].view());
    for (std::size_t k = 1; k < s.scene.tags.items.size(); ++k) {  // each tag but the first, one at a time
        TagSet one = s.scene.tags;
        one.items = {s.scene.tags.items[k]};
        first_only = withoutTags(first_only, s.cam_from_world_true[0], *s.seq.sensor.camera, one);
    }
    auto refused = single.process(first_only.view(), s.seq.frames[n - 1].timestamp_ns + period);
    ASSERT_TRUE(refused) << refused.error().message;
    ASSERT_TRUE(refused->bundle);
    EXPECT_EQ(refused->bundle->tags_used.size(), 1u);
    EXPECT_EQ(refused->status, TrackStatus::kPredicted);
    ASSERT_TRUE(refused->cam_from_world);
    EXPECT_GT(rotationErrorDeg(*refused->cam_from_world, s.cam_from_world_true[0]), 5.0) << "the prediction, not the measurement";
}

TEST(Tracker, EdgesCarryThePoseWhileTheTagsAreHidden) {
    const Sample& s = sample();
    TrackerOptions options;
    options.edges = true;
    Tracker tracker = makeTracker(options);
    const CameraModel& camera = *s.seq.sensor.camera;
    double worst_rot = 0, worst_mm = 0;
    int edges_only = 0;
    for (std::size_t i = 0; i < 40; ++i) {
        // Frames 10 to 39: no tag in view (the tracker does not know the truth used to hide them).
        const Image frame = i < 10 ? Image::copyOf(s.grey[i].view())
                                   : withoutTags(s.grey[i], s.cam_from_world_true[i], camera, s.scene.tags);
        auto track = tracker.process(frame.view(), s.seq.frames[i].timestamp_ns);
        ASSERT_TRUE(track) << track.error().message;
        if (i >= 10) {
            EXPECT_TRUE(track->tags.empty()) << "frame " << i << ": a tag survived the paint";
            ASSERT_EQ(track->status, TrackStatus::kEdgesOnly) << "frame " << i << ": "
                                                             << (track->edges ? track->edges->reason : "no edges");
            ++edges_only;
        }
        ASSERT_TRUE(track->cam_from_world);
        worst_rot = std::max(worst_rot, rotationErrorDeg(*track->cam_from_world, s.cam_from_world_true[i]));
        worst_mm = std::max(worst_mm, 1000 * (track->cam_from_world->inverse().translation -
                                              s.cam_from_world_true[i].inverse().translation)
                                                 .norm());
    }
    std::printf("  %d frames on edges alone: worst rotation error %.3f deg, camera position %.2f mm\n", edges_only,
                worst_rot, worst_mm);
    EXPECT_LT(worst_rot, 0.1);
    EXPECT_LT(worst_mm, 3.0);
    // A frame with nothing to go on: the edges say they cannot, and the pose is only predicted.
    Image blank(PixelFormat::kGray8, camera.width, camera.height);
    std::fill_n(blank.data(), blank.sizeBytes(), std::uint8_t{90});
    auto nothing = tracker.process(blank.view(), s.seq.frames[40].timestamp_ns);
    ASSERT_TRUE(nothing);
    ASSERT_TRUE(nothing->edges);
    EXPECT_FALSE(nothing->edges->ok);
    EXPECT_FALSE(nothing->edges->reason.empty());
    EXPECT_EQ(nothing->status, TrackStatus::kPredicted);
}

TEST(Tracker, BadFramesAreErrorsNamingTheProblem) {
    const Sample& s = sample();
    Tracker tracker = makeTracker({});
    Image rgb(PixelFormat::kRgb8, s.grey[0].width(), s.grey[0].height());
    auto wrong_format = tracker.process(rgb.view(), 0);
    ASSERT_FALSE(wrong_format);
    EXPECT_EQ(wrong_format.error().code, ErrorCode::kBadInput);
    Image small(PixelFormat::kGray8, 320, 240);
    auto wrong_size = tracker.process(small.view(), 0);
    ASSERT_FALSE(wrong_size);
    EXPECT_EQ(wrong_size.error().code, ErrorCode::kBadInput);
    ASSERT_TRUE(tracker.process(s.grey[0].view(), 1000));
    auto backwards = tracker.process(s.grey[1].view(), 999);
    ASSERT_FALSE(backwards);
    EXPECT_NE(backwards.error().message.find("earlier"), std::string::npos);
}

TEST(Tracker, InvalidOptionsAreUsageErrors) {
    const Sample& s = sample();
    TrackerOptions bad;
    bad.detector.family = "tag99h99";
    auto t = Tracker::create(*s.seq.sensor.camera, s.scene.tags, &s.scene, bad);
    ASSERT_FALSE(t);
    EXPECT_EQ(t.error().code, ErrorCode::kUsage);
    EXPECT_NE(t.error().message.find("tag99h99"), std::string::npos);
    TrackerOptions edges_without_scene;
    edges_without_scene.edges = true;
    EXPECT_FALSE(Tracker::create(*s.seq.sensor.camera, s.scene.tags, nullptr, edges_without_scene));
    TrackerOptions nan_rms;
    nan_rms.jump_max_rms_px = std::nan("");
    auto n = Tracker::create(*s.seq.sensor.camera, s.scene.tags, &s.scene, nan_rms);
    ASSERT_FALSE(n);
    EXPECT_NE(n.error().message.find("jump_max_rms_px"), std::string::npos);
}

}  // namespace
}  // namespace commonlight::tracking

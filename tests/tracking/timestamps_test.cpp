// What instant a pose is for (docs/tracking.md, "Timestamps"): a frame's timestamp is the start
// of its exposure, its image the light gathered over the exposure, so the tracker reports the
// pose for the middle of the exposure, and its filter is updated at, and predicts to, that
// instant. Synthetic frames of a tag seen by a camera moving with a constant twist, each the mean
// of the images at 8 instants spread over a 30 ms exposure (motion blur), against the exact
// poses.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <vector>

#include "core/frame.h"
#include "core/scene.h"
#include "tests/tracking/synthetic_tags.h"
#include "tracking/tracker.h"

namespace commonlight::tracking {
namespace {

using testing::SyntheticTag;

constexpr int kId = 3;
constexpr double kSize = 0.1;
constexpr double kExposureUs = 30000;
constexpr std::int64_t kFrameNs = 33'333'333;

// The camera moves with a constant twist in its own frame (the filter's model): 70 degrees per
// second (mostly about the optical axis: the smear of a fast pan biases the pattern alignment,
// see docs/tracking.md, "Timestamps") and 0.05 m/s.
Vector6d twist() {
    Vector6d nu;
    nu << 0.05, 0.2, 1.2, 0.0, 0.0, 0.05;
    return nu;
}

// The tag at the world origin, 0.4 m in front of the camera at t = 0, a little turned.
Rigid3d camFromWorldAt(double t_s) {
    const Eigen::Matrix3d r = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix() *
                              Eigen::AngleAxisd(0.35, Eigen::Vector3d::UnitY()).toRotationMatrix();
    const Rigid3d start(Eigen::Quaterniond(r), Eigen::Vector3d(-0.04, 0.0, 0.4));
    return expSe3(t_s * twist()) * start;
}

TagSet sceneTags() {
    TagSet tags;
    tags.family = "tag36h11";
    TagItem item;
    item.id = kId;
    item.size = kSize;
    item.world_from_tag = Rigid3d::identity();
    tags.items.push_back(item);
    return tags;
}

// Frame i: exposure [t_i, t_i + exposure].
Image blurredFrame(int i, double exposure_us = kExposureUs) {
    const double t0 = i * kFrameNs * 1e-9;
    return testing::renderSyntheticTagsBlurred(
        testing::syntheticCamera(),
        [&](double s) {
            return std::vector<SyntheticTag>{{kId, kSize, camFromWorldAt(t0 + s * exposure_us * 1e-6)}};
        },
        8, {.supersample = 3, .blur_sigma_px = 0.7, .noise_sigma = 1.0, .seed = static_cast<std::uint64_t>(i + 1)});
}

FrameMetadata metaOf(int i, double exposure_us = kExposureUs) {
    FrameMetadata meta;
    meta.timestamp_ns = i * kFrameNs;
    meta.timestamp_source = TimestampSource::kSensor;
    meta.exposure_us = exposure_us;
    return meta;
}

Tracker makeTracker(bool filter) {
    TrackerOptions options;
    options.filter = filter;
    auto tracker = Tracker::create(testing::syntheticCamera(), sceneTags(), nullptr, options);
    EXPECT_TRUE(tracker) << tracker.error().message;
    return std::move(*tracker);
}

TEST(Timestamps, MidExposureConvention) {
    EXPECT_EQ(midExposureNs(1'000'000'000, 20000.0), 1'010'000'000);
    // Unknown exposure: the timestamp itself.
    EXPECT_EQ(midExposureNs(5, 0.0), 5);
    EXPECT_EQ(midExposureNs(5, -3.0), 5);
    EXPECT_EQ(midExposureNs(5, NAN), 5);
    EXPECT_EQ(midExposureNs(5, INFINITY), 5);
    // End-of-frame timestamps (V4L2 without the start-of-exposure flag, host arrival times).
    FrameMetadata meta;
    meta.timestamp_ns = 1'000'000'000;
    meta.exposure_us = 20000.0;
    meta.timestamp_source = TimestampSource::kDriver;
    EXPECT_EQ(midExposureNs(meta), 990'000'000);
    meta.timestamp_source = TimestampSource::kHost;
    EXPECT_EQ(midExposureNs(meta), 990'000'000);
    for (const auto source : {TimestampSource::kSensor, TimestampSource::kRecording, TimestampSource::kSimulated,
                              TimestampSource::kUnknown}) {
        meta.timestamp_source = source;
        EXPECT_EQ(midExposureNs(meta), 1'010'000'000) << timestampSourceName(source);
    }
}

// The pose of a motion-blurred frame is the mid-exposure pose: closer to it than to the pose at
// the frame's timestamp (1.0 degree apart here), on every frame.
TEST(Timestamps, ReportedPoseIsForTheMiddleOfTheExposure) {
    Tracker tracker = makeTracker(false);
    double sum_mid = 0, sum_start = 0;
    constexpr int kFrames = 6;
    for (int i = 0; i < kFrames; ++i) {
        const Image image = blurredFrame(i);
        auto track = tracker.process(image.view(), metaOf(i));
        ASSERT_TRUE(track) << track.error().message;
        ASSERT_TRUE(track->cam_from_world) << "frame " << i;
        EXPECT_EQ(track->timestamp_ns, i * kFrameNs);
        EXPECT_EQ(track->pose_timestamp_ns, i * kFrameNs + 15'000'000);
        const double t_start = i * kFrameNs * 1e-9;
        const double t_mid = t_start + 0.5 * kExposureUs * 1e-6;
        const double err_mid = rotationErrorDeg(*track->cam_from_world, camFromWorldAt(t_mid));
        const double err_start = rotationErrorDeg(*track->cam_from_world, camFromWorldAt(t_start));
        std::printf("  frame %d: rotation error against mid-exposure %.3f deg, against the start %.3f deg\n", i,
                    err_mid, err_start);
        EXPECT_LT(err_mid, err_start) << "frame " << i;
        sum_mid += err_mid;
        sum_start += err_start;
    }
    EXPECT_LT(sum_mid / kFrames, 0.35);
    EXPECT_GT(sum_start / kFrames, 0.7);
    // The exposure unknown: the pose is for the timestamp itself.
    Tracker unknown = makeTracker(false);
    const Image image = blurredFrame(0);
    auto track = unknown.process(image.view(), std::int64_t{7});
    ASSERT_TRUE(track);
    EXPECT_EQ(track->pose_timestamp_ns, 7);
}

// The filter is updated at each frame's middle and predicts to the next frame's: a frame without
// the tag gets the prediction for its own mid-exposure instant. The exposure changes (auto
// exposure: 30 ms while the tag is seen, then 2 ms), so that the middle is not a constant offset
// from the timestamp: a filter run on the timestamps predicts the pose 14 ms late here (measured:
// 1.0 degree off).
TEST(Timestamps, FilterPredictsToTheMiddleOfTheExposure) {
    Tracker tracker = makeTracker(true);
    constexpr int kFrames = 8;
    for (int i = 0; i < kFrames; ++i) {
        const Image image = blurredFrame(i);
        auto track = tracker.process(image.view(), metaOf(i));
        ASSERT_TRUE(track && track->status == TrackStatus::kTracked) << "frame " << i;
    }
    // The tag is gone (a blank frame): the filter's prediction, for 1 ms after the timestamp.
    const CameraModel cam = testing::syntheticCamera();
    Image blank(PixelFormat::kGray8, cam.width, cam.height);
    std::fill(blank.data(), blank.data() + blank.stride() * cam.height, std::uint8_t{128});
    const FrameMetadata meta = metaOf(kFrames, 2000);
    auto track = tracker.process(blank.view(), meta);
    ASSERT_TRUE(track);
    ASSERT_EQ(track->status, TrackStatus::kPredicted);
    ASSERT_TRUE(track->cam_from_world);
    EXPECT_EQ(track->pose_timestamp_ns, meta.timestamp_ns + 1'000'000);
    const double t_start = meta.timestamp_ns * 1e-9;
    const double err_mid = rotationErrorDeg(*track->cam_from_world, camFromWorldAt(t_start + 0.001));
    const double err_late = rotationErrorDeg(*track->cam_from_world, camFromWorldAt(t_start + 0.015));
    std::printf("  predicted frame: rotation error against mid-exposure %.3f deg, against 14 ms later %.3f deg\n",
                err_mid, err_late);
    EXPECT_LT(err_mid, 0.3);
    EXPECT_LT(err_mid, 0.5 * err_late);
    // predict() at that instant is the same pose.
    const auto predicted = tracker.predict(track->pose_timestamp_ns);
    ASSERT_TRUE(predicted);
    EXPECT_LT(rotationErrorDeg(*predicted, *track->cam_from_world), 1e-9);
}

// Metadata whose exposure shrinks faster than time passes would put this frame's middle before
// the last one's: the instant is held at the last one (the filter needs non-decreasing times).
TEST(Timestamps, PoseInstantNeverGoesBack) {
    Tracker tracker = makeTracker(true);
    const Image image = blurredFrame(0);
    FrameMetadata meta = metaOf(0);
    meta.exposure_us = 100000;  // middle at 50 ms
    auto first = tracker.process(image.view(), meta);
    ASSERT_TRUE(first && first->cam_from_world);
    EXPECT_EQ(first->pose_timestamp_ns, 50'000'000);
    meta.timestamp_ns = 10'000'000;
    meta.exposure_us = 1000;  // middle at 10.5 ms: before the last one
    auto second = tracker.process(image.view(), meta);
    ASSERT_TRUE(second) << second.error().message;
    EXPECT_EQ(second->pose_timestamp_ns, 50'000'000);
    EXPECT_EQ(second->status, TrackStatus::kTracked);
}

}  // namespace
}  // namespace commonlight::tracking

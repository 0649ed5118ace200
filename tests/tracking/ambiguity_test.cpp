// Ambiguous single tags (docs/tracking.md, "Ambiguous single tags"): a small tag seen nearly
// head-on has two poses (tilted one way or the other) that its image cannot tell apart. With
// nothing to predict from, the tracker reports such a tag, and a camera pose resting on it alone,
// as ambiguous with both candidates instead of choosing; where another tag of the scene is in
// view, the bundle chooses. Synthetic frames (tests/tracking/synthetic_tags.h) with exact poses.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "core/scene.h"
#include "tests/tracking/synthetic_tags.h"
#include "tracking/tag_align.h"
#include "tracking/tracker.h"

namespace commonlight::tracking {
namespace {

using testing::SyntheticTag;

constexpr double kSize = 0.1;

TagSet board(bool second_tag) {
    TagSet tags;
    tags.family = "tag36h11";
    tags.items.push_back({3, kSize, Rigid3d::identity(), 0.04, 0.8});
    if (second_tag) {
        tags.items.push_back(
            {5, kSize, Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0.3, 0.05, 0)), 0.04, 0.8});
    }
    return tags;
}

// The board seen head-on (tilt 0) or nearly, tag 3 `px` pixels wide, a little off centre.
Rigid3d camFromWorld(double px, double tilt_deg, double axis_deg, double offset_x) {
    const CameraModel cam = testing::syntheticCamera();
    const double d = kSize * cam.fx / px;
    const Eigen::Vector3d axis(std::cos(axis_deg * M_PI / 180), std::sin(axis_deg * M_PI / 180), 0);
    const Eigen::Matrix3d r = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix() *
                              Eigen::AngleAxisd(tilt_deg * M_PI / 180, axis).toRotationMatrix();
    return Rigid3d(Eigen::Quaterniond(r), Eigen::Vector3d(offset_x * d, -0.05 * d, d));
}

Image render(const TagSet& tags, const Rigid3d& cam_from_world, std::uint64_t seed) {
    std::vector<SyntheticTag> placed;
    for (const TagItem& item : tags.items) placed.push_back({item.id, item.size, cam_from_world * item.world_from_tag});
    return testing::renderSyntheticTags(testing::syntheticCamera(), placed,
                                        {.supersample = 3, .blur_sigma_px = 0.8, .noise_sigma = 1.5, .seed = seed});
}

Tracker makeTracker(const TagSet& tags, bool independent) {
    TrackerOptions options;
    options.filter = !independent;
    options.independent_frames = independent;
    auto tracker = Tracker::create(testing::syntheticCamera(), tags, nullptr, options);
    EXPECT_TRUE(tracker) << tracker.error().message;
    return std::move(*tracker);
}

struct View {
    double px, tilt_deg, axis_deg, offset_x;
    std::uint64_t seed;
};

// Head-on and nearly head-on views of a 19-20 px tag: measured, most are ambiguous.
std::vector<View> smallViews() {
    std::vector<View> views;
    for (std::uint64_t seed = 1; seed <= 8; ++seed) {
        views.push_back({19.0 + 0.15 * seed, seed % 2 ? 0.0 : 3.0, 40.0 * seed, -0.3 + 0.02 * seed, seed});
    }
    return views;
}

// Alone, a tag is either right (within 5 degrees) or reported ambiguous with its alternative, and
// so is the camera pose that rests on it; an ambiguous frame does not feed the filter, so the next
// frame is not chosen by it either.
TEST(Ambiguity, ASmallHeadOnTagAloneIsReportedAmbiguous) {
    const TagSet tags = board(false);
    int ambiguous = 0, gross = 0;
    for (const View& v : smallViews()) {
        const Rigid3d truth = camFromWorld(v.px, v.tilt_deg, v.axis_deg, v.offset_x);
        const Image image = render(tags, truth, v.seed);
        Tracker tracker = makeTracker(tags, true);
        auto track = tracker.process(image.view(), std::int64_t{0});
        ASSERT_TRUE(track) << track.error().message;
        ASSERT_EQ(track->tags.size(), 1u) << "seed " << v.seed;
        ASSERT_TRUE(track->tags[0].pose);
        ASSERT_TRUE(track->cam_from_world);
        const TagPose& pose = *track->tags[0].pose;
        const double err = rotationErrorDeg(*track->cam_from_world, truth);
        std::printf("  %.2f px, tilt %.0f deg, seed %llu: error %.2f deg, ratio %.3f, %s, frame %s\n", v.px, v.tilt_deg,
                    static_cast<unsigned long long>(v.seed), err, pose.ambiguity_ratio,
                    pose.ambiguous ? "ambiguous" : poseChoiceName(pose.choice), trackStatusName(track->status));
        if (err > 5.0) {
            ++gross;
            EXPECT_TRUE(pose.ambiguous) << "a gross error not reported as ambiguous, seed " << v.seed;
        }
        EXPECT_EQ(pose.ambiguous, track->status == TrackStatus::kAmbiguous);
        if (!pose.ambiguous) continue;
        ++ambiguous;
        if (pose.candidates.size() > 1) {
            // The alternative: the other candidate, as a camera pose too.
            ASSERT_TRUE(track->alternative_cam_from_world);
            EXPECT_LT(rotationErrorDeg(*track->alternative_cam_from_world,
                                       pose.candidates[1].cam_from_tag * tags.items[0].world_from_tag.inverse()),
                      1e-6);
            EXPECT_GT(rotationErrorDeg(pose.candidates[0].cam_from_tag, pose.candidates[1].cam_from_tag), 2.0);
            // Either candidate may be the truth: one of them is within 5 degrees.
            const Rigid3d& tag_truth = truth;  // the tag is at the world origin
            EXPECT_LT(std::min(rotationErrorDeg(pose.candidates[0].cam_from_tag, tag_truth),
                               rotationErrorDeg(pose.candidates[1].cam_from_tag, tag_truth)),
                      5.0)
                << "seed " << v.seed;
        }
        // In a sequence, an ambiguous frame does not feed the filter: the same image again is
        // still ambiguous, not chosen by the first one's guess.
        Tracker sequence = makeTracker(tags, false);
        ASSERT_TRUE(sequence.process(image.view(), std::int64_t{0}));
        auto again = sequence.process(image.view(), std::int64_t{33'000'000});
        ASSERT_TRUE(again);
        EXPECT_EQ(again->status, TrackStatus::kAmbiguous);
        EXPECT_FALSE(sequence.predict(33'000'000));
    }
    std::printf("  %d of %zu views ambiguous, %d with a gross error\n", ambiguous, smallViews().size(), gross);
    EXPECT_GE(ambiguous, 3) << "these views were chosen because the tag alone is ambiguous in most of them";
}

// The same views with a second tag of the board in view: the bundle chooses every candidate, and
// no pose is grossly wrong.
TEST(Ambiguity, ASecondTagInViewChoosesTheCandidate) {
    const TagSet tags = board(true);
    int stale = 0;
    for (const View& v : smallViews()) {
        const Rigid3d truth = camFromWorld(v.px, v.tilt_deg, v.axis_deg, v.offset_x);
        const Image image = render(tags, truth, v.seed);
        Tracker tracker = makeTracker(tags, true);
        auto track = tracker.process(image.view(), std::int64_t{0});
        ASSERT_TRUE(track) << track.error().message;
        ASSERT_EQ(track->tags.size(), 2u) << "seed " << v.seed;
        EXPECT_EQ(track->status, TrackStatus::kTracked) << "seed " << v.seed;
        ASSERT_TRUE(track->cam_from_world);
        const double err = rotationErrorDeg(*track->cam_from_world, truth);
        EXPECT_LT(err, 5.0) << "seed " << v.seed;
        for (const TrackedTag& t : track->tags) {
            ASSERT_TRUE(t.pose);
            EXPECT_FALSE(t.pose->ambiguous) << "tag " << t.detection.id << ", seed " << v.seed;
            const TagItem* item = tags.find(t.detection.id);
            const double tag_err = rotationErrorDeg(t.pose->cam_from_tag, truth * item->world_from_tag);
            EXPECT_LT(tag_err, 5.0) << "tag " << t.detection.id << " (" << poseChoiceName(t.pose->choice) << "), seed "
                                    << v.seed;
            // The tag's corners are its chosen candidate's: where that candidate's aligned pose
            // puts them, not the other candidate's the tag had before the scene chose.
            if (t.aligned) {
                double off = 0;
                for (int c = 0; c < 4; ++c) {
                    const auto px = testing::syntheticCamera().project(t.pose->candidates[0].cam_from_tag *
                                                                       tagCornerInTag(c, item->size));
                    ASSERT_TRUE(px);
                    off = std::max(off, (*px - t.detection.corners[c]).norm());
                }
                EXPECT_LT(off, 1e-6) << "tag " << t.detection.id << ", seed " << v.seed;
                if (t.pose->choice == PoseChoice::kScene && off > 1e-6) ++stale;
            }
        }
        std::printf("  seed %llu: camera rotation error %.2f deg; tag choices %s, %s\n",
                    static_cast<unsigned long long>(v.seed), err, poseChoiceName(track->tags[0].pose->choice),
                    poseChoiceName(track->tags[1].pose->choice));
    }
    std::printf("  scene-chosen tags whose corners were another candidate's: %d\n", stale);
}

// A steeply tilted tag alone in a sequence: its corners leave one plausible candidate, and once
// the filter predicts, the prediction confirms it (its planar mirror is over 40 degrees away) and
// chooses it without aligning the mirror too; the pose is the one the same image gives alone
// (where the mirror's alignment is tried and loses).
TEST(Ambiguity, APredictedSingleCandidateFarFromItsMirrorIsChosenByThePrediction) {
    const TagSet tags = board(false);
    Tracker sequence = makeTracker(tags, false);
    int predicted = 0;
    for (int frame = 0; frame < 4; ++frame) {
        const Rigid3d truth = camFromWorld(70.0, 65.0 + 0.3 * frame, 20.0, -0.2 + 0.01 * frame);
        const Image image = render(tags, truth, 40 + static_cast<std::uint64_t>(frame));
        Tracker alone = makeTracker(tags, true);
        auto single = alone.process(image.view(), std::int64_t{0});
        auto track = sequence.process(image.view(), std::int64_t{frame} * 33'000'000);
        ASSERT_TRUE(single && track);
        ASSERT_EQ(track->tags.size(), 1u) << "frame " << frame;
        ASSERT_EQ(single->tags.size(), 1u) << "frame " << frame;
        const TrackedTag& t = track->tags[0];
        ASSERT_TRUE(t.pose && single->tags[0].pose);
        EXPECT_TRUE(t.aligned);
        EXPECT_LT(rotationErrorDeg(t.pose->cam_from_tag, truth), 1.0) << "frame " << frame;
        std::printf("  frame %d: %s, %zu candidate(s); alone: %s\n", frame, poseChoiceName(t.pose->choice),
                    t.pose->candidates.size(), poseChoiceName(single->tags[0].pose->choice));
        if (frame == 0) continue;  // nothing to predict from yet
        ++predicted;
        EXPECT_EQ(t.pose->choice, PoseChoice::kPrediction) << "frame " << frame;
        EXPECT_FALSE(t.pose->ambiguous);
        EXPECT_EQ(single->tags[0].pose->choice, PoseChoice::kPattern);
        EXPECT_LT(rotationErrorDeg(t.pose->cam_from_tag, single->tags[0].pose->cam_from_tag), 1e-6);
        EXPECT_LT(translationError(t.pose->cam_from_tag, single->tags[0].pose->cam_from_tag), 1e-9);
    }
    EXPECT_EQ(predicted, 3);
}

// The measurement behind the thresholds (TagPoseOptions::ambiguous_*; docs/tracking.md): single
// tags of 12-42 px at random poses (a quarter head-on, the rest tilted up to 40 degrees), each
// alone in an independent frame. Not run by default (about 30 s for 600 views):
//   test_tracking_ambiguity --gtest_also_run_disabled_tests --gtest_filter='*Measure*'
TEST(Ambiguity, DISABLED_MeasureSingleTags) {
    const CameraModel cam = testing::syntheticCamera();
    const TagSet tags = board(false);
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u01(0, 1);
    struct Row {
        double px, ratio, sigma_deg, err;
        bool ambiguous;
    };
    std::vector<Row> rows;
    int missed = 0;
    const int n = 600;
    for (int k = 0; k < n; ++k) {
        const double px = 12 + 30 * u01(rng);
        const double d = kSize * cam.fx / px;
        const double tilt = (k % 4 == 0) ? 0.0 : 40.0 * u01(rng) * u01(rng);
        const double axis_angle = 2 * M_PI * u01(rng);
        const Eigen::Vector3d axis(std::cos(axis_angle), std::sin(axis_angle), 0);
        const Eigen::Matrix3d r = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix() *
                                  Eigen::AngleAxisd(tilt * M_PI / 180, axis).toRotationMatrix() *
                                  Eigen::AngleAxisd(2 * M_PI * u01(rng), Eigen::Vector3d::UnitZ()).toRotationMatrix();
        const Eigen::Vector3d t((u01(rng) - 0.5) * 0.6 * d, (u01(rng) - 0.5) * 0.5 * d, d);
        const Rigid3d truth(Eigen::Quaterniond(r), t);
        const Image image = render(tags, truth, static_cast<std::uint64_t>(k + 1));
        Tracker tracker = makeTracker(tags, true);
        auto track = tracker.process(image.view(), std::int64_t{0});
        ASSERT_TRUE(track);
        if (track->tags.empty() || !track->tags[0].pose) {
            ++missed;
            continue;
        }
        const TagPose& p = *track->tags[0].pose;
        rows.push_back({px, p.candidates.size() > 1 ? p.ambiguity_ratio : 0.0, rotationSigmaDeg(p.covariance),
                        rotationErrorDeg(p.cam_from_tag, truth), p.ambiguous});
    }
    std::printf("%d views, %d without a detected tag\n", n, missed);
    std::printf("| tag size | tags | ambiguous | gross (> 5 deg) | gross, not ambiguous |\n");
    for (const auto& [lo, hi] : {std::pair{12.0, 20.0}, {20.0, 30.0}, {30.0, 43.0}}) {
        int count = 0, amb = 0, gross = 0, silent = 0;
        for (const Row& row : rows) {
            if (row.px < lo || row.px >= hi) continue;
            ++count;
            amb += row.ambiguous;
            gross += row.err > 5;
            silent += row.err > 5 && !row.ambiguous;
        }
        std::printf("| %.0f-%.0f px | %d | %d | %d | %d |\n", lo, hi, count, amb, gross, silent);
    }
    std::printf("| ratio (pattern or corners) | tags | gross |\n");
    const double edges[] = {0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.01};
    for (int b = 0; b + 1 < 11; ++b) {
        int count = 0, gross = 0;
        for (const Row& row : rows) {
            if (row.ratio < edges[b] || row.ratio >= edges[b + 1]) continue;
            ++count;
            gross += row.err > 5;
        }
        std::printf("| %.1f-%.1f | %d | %d |\n", edges[b], edges[b + 1], count, gross);
    }
    std::printf("| rotation sigma | tags | gross |\n");
    const double sig[] = {0, 0.5, 1, 1.5, 2, 3, 100};
    for (int b = 0; b + 1 < 7; ++b) {
        int count = 0, gross = 0;
        for (const Row& row : rows) {
            if (row.sigma_deg < sig[b] || row.sigma_deg >= sig[b + 1]) continue;
            ++count;
            gross += row.err > 5;
        }
        std::printf("| %.1f-%.1f deg | %d | %d |\n", sig[b], sig[b + 1], count, gross);
    }
}

// A one-sided alignment: the corners' choice can be aligned, the other candidate's cells are
// under min_cell_px, so its pattern cannot be measured. That is no choice between two measured
// fits: the tag keeps the corners' choice and ratio (aligned), not PoseChoice::kPattern.
TEST(Ambiguity, AOneSidedAlignmentIsNotThePatternsChoice) {
    const TagSet tags = board(false);
    const CameraModel cam = testing::syntheticCamera();
    auto pattern = TagPattern::make("tag36h11", 3);
    ASSERT_TRUE(pattern);
    // The alignment's cell size: the shorter of the two sides from corner 0, over the cells.
    const auto cellPx = [&](const Rigid3d& cam_from_tag) {
        const auto c0 = cam.project(cam_from_tag * tagCornerInTag(0, kSize));
        const auto c1 = cam.project(cam_from_tag * tagCornerInTag(1, kSize));
        const auto c3 = cam.project(cam_from_tag * tagCornerInTag(3, kSize));
        return c0 && c1 && c3 ? pattern->cell() * std::min((*c1 - *c0).norm(), (*c3 - *c0).norm()) : 0.0;
    };
    int one_sided = 0;
    for (std::uint64_t seed = 1; seed <= 12; ++seed) {
        const Rigid3d truth = camFromWorld(36.0 + static_cast<double>(seed), 50.0 + 2.0 * static_cast<double>(seed), 30.0 * static_cast<double>(seed), -0.2);
        const Image image = render(tags, truth, seed);
        Tracker first = makeTracker(tags, true);
        auto track = first.process(image.view(), std::int64_t{0});
        ASSERT_TRUE(track);
        if (track->tags.size() != 1 || !track->tags[0].pose) continue;
        const TagPose& p = *track->tags[0].pose;
        // A view where the pattern chose between two measured fits, the chosen one's cells larger.
        if (p.choice != PoseChoice::kPattern || p.candidates.size() < 2) continue;
        const double own = cellPx(p.candidates[0].cam_from_tag), other = cellPx(p.candidates[1].cam_from_tag);
        if (own < other + 0.05) continue;
        // Only the chosen candidate's cells are at least min_cell_px.
        TrackerOptions options;
        options.filter = false;
        options.independent_frames = true;
        options.align.min_cell_px = 0.5 * (own + other);
        auto tracker = Tracker::create(cam, tags, nullptr, options);
        ASSERT_TRUE(tracker);
        auto again = tracker->process(image.view(), std::int64_t{0});
        ASSERT_TRUE(again);
        ASSERT_EQ(again->tags.size(), 1u);
        const TrackedTag& t = again->tags[0];
        ASSERT_TRUE(t.pose);
        std::printf("  seed %llu: cells %.2f / %.2f px, min %.2f: choice %s, ratio %.3f, aligned %d, %.2f deg off\n",
                    static_cast<unsigned long long>(seed), own, other, options.align.min_cell_px,
                    poseChoiceName(t.pose->choice), t.pose->ambiguity_ratio, t.aligned ? 1 : 0,
                    rotationErrorDeg(t.pose->cam_from_tag, truth));
        // Which candidate the corners chose is theirs to say; the pattern measured one side only.
        if (rotationErrorDeg(t.pose->candidates[0].cam_from_tag, p.candidates[0].cam_from_tag) > 2.0) continue;
        ++one_sided;
        EXPECT_NE(t.pose->choice, PoseChoice::kPattern) << "seed " << seed;
        EXPECT_TRUE(t.aligned) << "seed " << seed;
        EXPECT_GT(t.pose->ambiguity_ratio, 0.0) << "the corners' ratio, seed " << seed;
        EXPECT_EQ(t.pose->candidates.size(), 2u);
    }
    EXPECT_GE(one_sided, 1) << "no view made a one-sided alignment: the test would pass without checking";
}

}  // namespace
}  // namespace commonlight::tracking

// Tiny tags in a sequence (docs/tracking.md, "Speed (issue 13)", sixth round): a predicted tag
// the last frame reported where it is predicted now is verified on its pattern's correlation
// alone (tag_verify.h `known_at_px`, TrackerOptions::verify_trust_last_frame); the plain square
// and the other ids are compared only for a tag not seen there a frame ago. A foreshortened tag
// the decimated detector missed but the last frame detected is aligned from its prediction
// instead of detected again at full resolution (TrackerOptions::redetect_align_known). The
// correlation's search climbs its grid from the prediction (seventh round). Synthetic
// frames (tests/tracking/synthetic_tags.h) with exact poses.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <cmath>
#include <cstdio>
#include <vector>

#include "core/scene.h"
#include "tests/tracking/synthetic_tags.h"
#include "tracking/tag_verify.h"
#include "tracking/tracker.h"

namespace commonlight::tracking {
namespace {

using testing::SyntheticTag;

Rigid3d at(double x, double y) { return Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(x, y, 0)); }

// Two 0.1 m anchor tags (ids 0 and 1) and six small ones (ids 2-7, 24-34 mm) on one plane.
TagSet scene() {
    TagSet tags;
    tags.family = "tag36h11";
    tags.items.push_back({0, 0.1, at(-0.25, 0.0), 0.04, 0.8});
    tags.items.push_back({1, 0.1, at(0.25, 0.0), 0.04, 0.8});
    for (int k = 0; k < 6; ++k) {
        tags.items.push_back({2 + k, 0.024 + 0.002 * k, at(-0.25 + 0.1 * k, (k % 2 ? 0.15 : -0.15)), 0.04, 0.8});
    }
    return tags;
}

// Frame k of a slow move: the board's plane 1.5 m away, tilted 20 degrees, drifting sideways.
Rigid3d camFromWorld(int k) {
    const Eigen::Vector3d axis(std::cos(0.6), std::sin(0.6), 0);
    const Eigen::Matrix3d r = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix() *
                              Eigen::AngleAxisd((20.0 + 0.3 * k) * M_PI / 180, axis).toRotationMatrix();
    return Rigid3d(Eigen::Quaterniond(r), Eigen::Vector3d(-0.01 + 0.002 * k, 0.01, 1.5 + 0.004 * k));
}

// The tags as printed, with `swap` (when >= 0) showing id 40 in the place of tag `swap`.
std::vector<SyntheticTag> placed(const TagSet& tags, const Rigid3d& cam_from_world, int swap = -1) {
    std::vector<SyntheticTag> out;
    for (const TagItem& item : tags.items) {
        out.push_back({item.id == swap ? 40 : item.id, item.size, cam_from_world * item.world_from_tag});
    }
    return out;
}

Image render(const std::vector<SyntheticTag>& tags, std::uint64_t seed) {
    return testing::renderSyntheticTags(testing::syntheticCamera(), tags,
                                        {.supersample = 3, .blur_sigma_px = 0.8, .noise_sigma = 1.5, .seed = seed});
}

// Covers a tag's drawn square (and a little more) with a grey card.
void coverTag(Image& image, const TagItem& item, const Rigid3d& cam_from_world) {
    const CameraModel cam = testing::syntheticCamera();
    double xmin = 1e9, xmax = -1e9, ymin = 1e9, ymax = -1e9;
    for (int k = 0; k < 4; ++k) {
        const auto p = cam.project(cam_from_world * (item.world_from_tag * tagCornerInTag(k, 1.4 * item.size)));
        xmin = std::min(xmin, p->x()), xmax = std::max(xmax, p->x());
        ymin = std::min(ymin, p->y()), ymax = std::max(ymax, p->y());
    }
    MutableImageView v = image.mutableView();
    for (int y = static_cast<int>(std::floor(ymin)); y <= static_cast<int>(std::ceil(ymax)); ++y) {
        for (int x = static_cast<int>(std::floor(xmin)); x <= static_cast<int>(std::ceil(xmax)); ++x)
            v.row(y)[x] = static_cast<std::uint8_t>(150 + ((x * 7 + y * 3) % 3));
    }
}

Eigen::Vector2d predictedCentre(const TagItem& item, const Rigid3d& cam_from_world) {
    const CameraModel cam = testing::syntheticCamera();
    Eigen::Vector2d c = Eigen::Vector2d::Zero();
    for (int k = 0; k < 4; ++k) c += 0.25 * *cam.project(cam_from_world * (item.world_from_tag * tagCornerInTag(k, item.size)));
    return c;
}

// The verification tests' frames: the scene seen from the start of the path, and the same with
// every tag's id shifted by 4 and tag 5 covered by a card.
struct VerifyScene {
    TagSet tags = scene();
    CameraModel cam = testing::syntheticCamera();
    Rigid3d truth = camFromWorld(0);
    Image image = render(placed(tags, truth), 11);
    Image wrong = render(placed(tags, truth, 4), 12);
    VerifyScene() { coverTag(wrong, *tags.find(5), truth); }
};

const TrackedTag* findTag(const FrameTrack& f, int id) {
    for (const TrackedTag& t : f.tags) {
        if (t.detection.id == id) return &t;
    }
    return nullptr;
}

// verifyPredictedTag: with the tag known where it is predicted, the alternatives are not
// compared and the outcome (accepted, corners, correlation) is the full verification's; known
// elsewhere (more than half its span away), the full verification runs. Known where it is
// predicted but covered, or another id printed there: refused by the pattern's own correlation.
TEST(TinyTagsSequence, AKnownTagSkipsTheAlternativesOnlyWhereItWasReported) {
    const VerifyScene vs;
    const TagSet& tags = vs.tags;
    const CameraModel& cam = vs.cam;
    TagPatternCache patterns("tag36h11");
    const Rigid3d& truth = vs.truth;
    const Image& image = vs.image;
    const Image& wrong = vs.wrong;
    int tried = 0, skipped = 0, refused_known = 0;
    for (const TagItem& item : tags.items) {
        if (item.id < 2) continue;
        std::vector<const TagPattern*> others;
        for (int k = 1; k <= 8; ++k) others.push_back(patterns.get(item.id + 100 + k));
        const Rigid3d cam_from_tag = truth * item.world_from_tag;
        const TagVerifyResult full = verifyPredictedTag(image.view(), cam, *patterns.get(item.id), others, item.size, cam_from_tag);
        if (!full.ok) continue;
        ++tried;
        EXPECT_FALSE(full.alternatives_skipped);
        EXPECT_GT(full.ncc_square, 0.0) << item.id;  // measured
        const Eigen::Vector2d here = predictedCentre(item, truth) + Eigen::Vector2d(0.3, -0.2);
        const TagVerifyResult known =
            verifyPredictedTag(image.view(), cam, *patterns.get(item.id), others, item.size, cam_from_tag, {}, &here);
        EXPECT_TRUE(known.ok) << item.id;
        EXPECT_TRUE(known.alternatives_skipped) << item.id;
        skipped += known.alternatives_skipped ? 1 : 0;
        EXPECT_EQ(known.ncc, full.ncc);
        for (int c = 0; c < 4; ++c) EXPECT_EQ(known.corners[static_cast<std::size_t>(c)], full.corners[static_cast<std::size_t>(c)]);
        // Reported elsewhere (a whole span away): the full verification.
        const Eigen::Vector2d away = here + Eigen::Vector2d(full.span_px, 0.0);
        const TagVerifyResult far =
            verifyPredictedTag(image.view(), cam, *patterns.get(item.id), others, item.size, cam_from_tag, {}, &away);
        EXPECT_TRUE(far.ok && !far.alternatives_skipped) << item.id;
        EXPECT_EQ(far.ncc_square, full.ncc_square);
        // Gone since: another id in its place (tag 4), covered (tag 5).
        if (item.id == 4 || item.id == 5) {
            const TagVerifyResult v =
                verifyPredictedTag(wrong.view(), cam, *patterns.get(item.id), others, item.size, cam_from_tag, {}, &here);
            std::printf("tag %d %s: pattern NCC %.3f (min 0.9), %s\n", item.id, item.id == 4 ? "replaced by id 40" : "covered",
                        v.ncc, v.ok ? "accepted" : "refused");
            EXPECT_FALSE(v.ok) << item.id;
            refused_known += v.ok ? 0 : 1;
        }
    }
    std::printf("small tags verified: %d; with the tag known where predicted, alternatives skipped for %d\n", tried, skipped);
    EXPECT_GE(tried, 5);
    EXPECT_EQ(skipped, tried);
    EXPECT_EQ(refused_known, 2);
}

// The tracker over a slow sequence: from the second frame on, every verified tag that the last
// frame reported is verified as known (`verified_known`), and the tags and their corners are the
// same as with verify_trust_last_frame off (where no tag is). A tag replaced by another id and a
// tag covered after several frames of being verified are refused either way; independent frames
// never carry the last frame's tags.
TEST(TinyTagsSequence, TheTrackerTrustsOnlyTagsTheLastFrameReported) {
    const TagSet tags = scene();
    const auto make = [&](bool trust, bool independent) {
        TrackerOptions options;
        options.filter = false;
        options.independent_frames = independent;
        options.verify_trust_last_frame = trust;
        auto tracker = Tracker::create(testing::syntheticCamera(), tags, nullptr, options);
        EXPECT_TRUE(tracker) << tracker.error().message;
        return std::move(*tracker);
    };
    Tracker trusting = make(true, false), full = make(false, false), independent = make(true, true);
    int verified = 0, known = 0, known_first = 0, known_independent = 0, known_full = 0, same = 0;
    constexpr int kFrames = 6;
    for (int k = 0; k <= kFrames; ++k) {
        const Rigid3d truth = camFromWorld(k);
        // The last frame: tag 4 replaced by another id, tag 5 covered.
        Image image = render(placed(tags, truth, k == kFrames ? 4 : -1), 40 + static_cast<std::uint64_t>(k));
        if (k == kFrames) coverTag(image, *tags.find(5), truth);
        auto a = trusting.process(image, k * 33'000'000LL);
        auto b = full.process(image, k * 33'000'000LL);
        auto c = independent.process(image, k * 33'000'000LL);
        ASSERT_TRUE(a && b && c);
        ASSERT_TRUE(findTag(*a, 0) && findTag(*a, 1)) << k;
        for (const TagItem& item : tags.items) {
            if (item.id < 2) continue;
            const TrackedTag* ta = findTag(*a, item.id);
            const TrackedTag* tb = findTag(*b, item.id);
            const TrackedTag* tc = findTag(*c, item.id);
            if (k == kFrames && (item.id == 4 || item.id == 5)) {
                EXPECT_EQ(ta, nullptr) << "tag " << item.id << " accepted after it was replaced or covered";
                EXPECT_EQ(tb, nullptr) << item.id;
                continue;
            }
            ASSERT_EQ(ta != nullptr, tb != nullptr) << "frame " << k << ", tag " << item.id;
            if (!ta || !ta->verified) continue;
            ++verified;
            known += ta->verified_known ? 1 : 0;
            known_first += k == 0 && ta->verified_known ? 1 : 0;
            known_full += tb->verified_known ? 1 : 0;
            known_independent += tc && tc->verified_known ? 1 : 0;
            bool corners_same = true;
            for (int q = 0; q < 4; ++q) {
                corners_same &= ta->detection.corners[static_cast<std::size_t>(q)] == tb->detection.corners[static_cast<std::size_t>(q)];
            }
            same += corners_same ? 1 : 0;
        }
    }
    std::printf("verified small tags over %d frames: %d, %d of them as known (first frame %d); the same corners "
                "without the trust: %d\n",
                kFrames + 1, verified, known, known_first, same);
    EXPECT_GE(verified, 4 * kFrames);
    EXPECT_EQ(known_first, 0);
    EXPECT_GE(known, verified - 6);  // all but the first frame's
    EXPECT_EQ(known_full, 0);
    EXPECT_EQ(known_independent, 0);
    EXPECT_EQ(same, verified);
}

// Foreshortened tags (turned 55-57.5 degrees, 50-78 mm) between two anchors, seen by a decimated
// detector that misses them: in the first frame each is detected again at full resolution in a
// window around its prediction; from the second on, a tag the last frame detected is aligned
// from the prediction without the detector (`aligned_known`, TrackerOptions::redetect_align_known),
// with corners about as close to the truth. A tag covered since is not found; with the option off
// or in independent frames no tag is aligned that way.
TEST(TinyTagsSequence, ATagDetectedInTheLastFrameIsAlignedWithoutTheDetector) {
    TagSet tags;
    tags.family = "tag36h11";
    tags.items.push_back({0, 0.1, at(-0.3, 0.0), 0.04, 0.8});
    tags.items.push_back({1, 0.1, at(0.3, 0.0), 0.04, 0.8});
    testing::addForeshortenedGrid(tags, 55.0, 1.25, 0.045, 0.003);
    const auto make = [&](bool trust, bool independent) {
        TrackerOptions options;
        options.filter = false;
        options.independent_frames = independent;
        options.detector.decimate = 2.0;
        options.redetect_align_known = trust;
        auto tracker = Tracker::create(testing::syntheticCamera(), tags, nullptr, options);
        EXPECT_TRUE(tracker) << tracker.error().message;
        return std::move(*tracker);
    };
    Tracker trusting = make(true, false), full = make(false, false), independent = make(true, true);
    const CameraModel cam = testing::syntheticCamera();
    const auto cornerError = [&](const TrackedTag& t, const TagItem& item, const Rigid3d& truth) {
        double worst = 0;
        for (int q = 0; q < 4; ++q) {
            const auto p = cam.project(truth * (item.world_from_tag * tagCornerInTag(q, item.size)));
            worst = std::max(worst, (t.detection.corners[static_cast<std::size_t>(q)] - *p).norm());
        }
        return worst;
    };
    int late = 0, aligned_known = 0, aligned_known_first = 0, aligned_known_other = 0, same_found = 0, compared = 0;
    double worst_known = 0, worst_detected = 0, sum_known = 0, sum_known_full = 0;
    constexpr int kFrames = 6;
    for (int k = 0; k <= kFrames; ++k) {
        const Rigid3d truth = Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX())),
                                      Eigen::Vector3d(0.002 * k, 0.01, 0.8 + 0.003 * k));
        std::vector<SyntheticTag> shown;
        for (const TagItem& item : tags.items) shown.push_back({item.id, item.size, truth * item.world_from_tag});
        Image image = testing::renderSyntheticTags(cam, shown, {.supersample = 3, .blur_sigma_px = 1.2, .noise_sigma = 1.5,
                                                                .seed = 60 + static_cast<std::uint64_t>(k)});
        if (k == kFrames) coverTag(image, *tags.find(31), truth);  // covered in the last frame
        auto a = trusting.process(image, k * 33'000'000LL);
        auto b = full.process(image, k * 33'000'000LL);
        auto c = independent.process(image, k * 33'000'000LL);
        ASSERT_TRUE(a && b && c);
        for (const TagItem& item : tags.items) {
            if (item.id < 30) continue;
            const TrackedTag* ta = findTag(*a, item.id);
            const TrackedTag* tb = findTag(*b, item.id);
            const TrackedTag* tc = findTag(*c, item.id);
            if (k == kFrames && item.id == 31) {
                EXPECT_EQ(ta, nullptr) << "a tag covered since the last frame was accepted";
                continue;
            }
            ++compared;
            same_found += (ta != nullptr) == (tb != nullptr) ? 1 : 0;
            aligned_known_other += (tb && tb->aligned_known) || (tc && tc->aligned_known) ? 1 : 0;
            if (!ta || !ta->detected_late) continue;
            ++late;
            const double err = cornerError(*ta, item, truth);
            if (ta->aligned_known) {
                ++aligned_known;
                aligned_known_first += k == 0 ? 1 : 0;
                worst_known = std::max(worst_known, err);
                sum_known += err;
                sum_known_full += tb ? cornerError(*tb, item, truth) : 0.0;
            } else {
                worst_detected = std::max(worst_detected, err);
            }
        }
    }
    const double mean_known = sum_known / std::max(aligned_known, 1), mean_full = sum_known_full / std::max(aligned_known, 1);
    std::printf("foreshortened tags found late: %d, %d of them aligned from the prediction (first frame %d): corners "
                "%.3f px from the truth (mean; %.3f px where the option off detects them again), worst %.3f px "
                "(detected again: %.3f px); found the same as without the trust: %d of %d\n",
                late, aligned_known, aligned_known_first, mean_known, mean_full, worst_known, worst_detected, same_found,
                compared);
    EXPECT_GE(late, 4);
    EXPECT_GE(aligned_known, late / 2);
    EXPECT_LE(mean_known, mean_full + 0.1);
    EXPECT_EQ(aligned_known_first, 0);
    EXPECT_EQ(aligned_known_other, 0);
    EXPECT_EQ(same_found, compared);
    EXPECT_LE(worst_known, 0.5);
}

// verifyPredictedTag's search climbs its grid of 0.25 px from the prediction (TagVerifyOptions::
// search_ascent): wherever the tag is predicted within the search (up to 0.9 px off either way),
// it ends on the whole grid's decision, and where it accepts on the grid's shift and correlation,
// and the shift it reports undoes the
// prediction's error (to within the fine step): the template moves by the shift the corners move
// by. A climb that stopped after the first 3 x 3 shifts would differ from the grid beyond 0.375 px,
// and a template moved by half the shift (as until the seventh round) would leave the corners off
// by half the prediction's error. Where the prediction is within 0.2 px, it tries a quarter of the
// grid's 81 shifts or fewer. Tags replaced by another id or covered are refused either way.
TEST(TinyTagsSequence, TheSearchClimbsToTheGridsShiftFromAnyPredictionWithinIt) {
    const VerifyScene vs;
    const TagSet& tags = vs.tags;
    const CameraModel& cam = vs.cam;
    TagPatternCache patterns("tag36h11");
    const Rigid3d& truth = vs.truth;
    const Image& image = vs.image;
    const Image& wrong = vs.wrong;
    TagVerifyOptions grid;
    grid.search_ascent = false;
    int compared = 0, accepted = 0, near = 0, near_tried = 0, beyond_first_ring = 0, far = 0, far_found = 0;
    double worst_undo = 0.0;
    for (const TagItem& item : tags.items) {
        if (item.id < 2) continue;
        std::vector<const TagPattern*> others;
        for (int k = 1; k <= 8; ++k) others.push_back(patterns.get(item.id + 100 + k));
        const Rigid3d cam_from_tag = truth * item.world_from_tag;
        const double z = cam_from_tag.translation.z();
        for (const double dy : {-0.9, -0.4, 0.0, 0.2, 0.6}) {
            for (const double dx : {-0.6, -0.2, 0.0, 0.4, 0.9}) {
                // The tag predicted (dx, dy) px off in the image: moved across the line of sight.
                const Rigid3d off(Eigen::Quaterniond::Identity(),
                                  Eigen::Vector3d(dx * z / cam.fx, dy * z / cam.fy, 0.0));
                const Rigid3d predicted = off * cam_from_tag;
                const TagVerifyResult all =
                    verifyPredictedTag(image.view(), cam, *patterns.get(item.id), others, item.size, predicted, grid);
                const TagVerifyResult climbed =
                    verifyPredictedTag(image.view(), cam, *patterns.get(item.id), others, item.size, predicted);
                ++compared;
                EXPECT_EQ(climbed.ok, all.ok) << item.id << " " << dx << " " << dy;
                EXPECT_EQ(all.grid_shifts_tried, 81);
                if (!climbed.ok) continue;
                // Refused, the climb may end on a lower peak than the grid's (a correlation under
                // min_ncc has more than one); accepted, on the grid's.
                EXPECT_EQ(climbed.ncc, all.ncc) << item.id << " " << dx << " " << dy;
                EXPECT_EQ(climbed.shift_px, all.shift_px) << item.id << " " << dx << " " << dy;
                EXPECT_EQ(climbed.ncc_square, all.ncc_square) << item.id << " " << dx << " " << dy;
                ++accepted;
                if (std::abs(dx) <= 0.2 && std::abs(dy) <= 0.2) {
                    ++near;
                    near_tried += climbed.grid_shifts_tried;
                }
                const double undo = (climbed.shift_px + Eigen::Vector2d(dx, dy)).norm();
                worst_undo = std::max(worst_undo, undo);
                // The grid's best beyond its first ring (+-0.25 px; the fine step adds at most 0.125).
                beyond_first_ring += climbed.shift_px.cwiseAbs().maxCoeff() > 0.375 + 1e-9 ? 1 : 0;
                if (std::abs(dx) >= 0.9 || std::abs(dy) >= 0.9) {
                    ++far;
                    far_found += undo <= 0.4 ? 1 : 0;
                }
            }
        }
        if (item.id == 4 || item.id == 5) {
            const TagVerifyResult v =
                verifyPredictedTag(wrong.view(), cam, *patterns.get(item.id), others, item.size, cam_from_tag);
            const TagVerifyResult g =
                verifyPredictedTag(wrong.view(), cam, *patterns.get(item.id), others, item.size, cam_from_tag, grid);
            EXPECT_FALSE(v.ok) << item.id;
            EXPECT_EQ(v.ncc, g.ncc) << item.id;
        }
    }
    std::printf("predictions compared: %d, accepted %d; the prediction's error undone to %.3f px at worst; within "
                "0.2 px: %.1f grid shifts tried on average (of 81); best shift beyond the first 3 x 3: %d; 0.9 px off: "
                "%d, found there %d\n",
                compared, accepted, worst_undo, near ? static_cast<double>(near_tried) / near : 0.0, beyond_first_ring,
                far, far_found);
    EXPECT_GE(accepted, compared * 7 / 10);
    EXPECT_LE(worst_undo, 0.4);
    EXPECT_GE(near, 6);
    EXPECT_LE(near_tried, 20 * near);
    EXPECT_GE(beyond_first_ring, 20);
    EXPECT_GE(far, 10);
    EXPECT_EQ(far_found, far);
}

// The verification's NCC through its vectorized blur passes (three levels at once, two pixels at
// a time), its one-pass sums and its pixels of one colour under every shift of a search rendered
// once equals the plain scalar loops, two-pass scores and every pixel rendered at every shift
// (TagVerifyOptions::reference_ncc): every correlation within 1e-12, every other field exactly,
// over predictions off by up to a pixel, blur level sets that make groups of one, two and three,
// the frame with a tag replaced and one covered, a noisy copy, and a flat image (no contrast:
// refused, no NaN).
TEST(TinyTagsSequence, TheVectorizedNccEqualsThePlainLoops) {
    const VerifyScene vs;
    TagPatternCache patterns("tag36h11");
    Image noisy = vs.image.clone(), flat = vs.image.clone();
    std::uint64_t state = 7;
    const auto next = [&] { return (state = state * 6364136223846793005ull + 1442695040888963407ull) >> 33; };
    for (std::size_t i = 0; i < noisy.sizeBytes(); ++i) {
        noisy.data()[i] =
            static_cast<std::uint8_t>(std::clamp(static_cast<int>(noisy.data()[i]) + static_cast<int>(next() % 41) - 20, 0, 255));
        flat.data()[i] = 128;
    }
    const std::vector<std::vector<double>> level_sets = {{0.0, 0.5, 0.75, 1.0}, {0.5}, {0.75, 0.0, 1.0}, {0.0, 0.4, 0.6, 0.8, 1.0, 1.2}};
    int compared = 0, accepted = 0, flat_refused = 0;
    for (const TagItem& item : vs.tags.items) {
        if (item.id < 2) continue;
        std::vector<const TagPattern*> others;
        for (int k = 1; k <= 8; ++k) others.push_back(patterns.get(item.id + 100 + k));
        for (int trial = 0; trial < 4; ++trial) {
            // The prediction off by up to about a pixel at the tags' distance.
            const Eigen::Vector3d off(1e-3 * (static_cast<double>(next() % 2001) / 1000.0 - 1.0),
                                      1e-3 * (static_cast<double>(next() % 2001) / 1000.0 - 1.0), 0.0);
            const Rigid3d cam_from_tag = Rigid3d(Eigen::Quaterniond::Identity(), off) * vs.truth * item.world_from_tag;
            for (const Image* img : std::array<const Image*, 4>{&vs.image, &vs.wrong, &noisy, &flat}) {
                TagVerifyOptions fast;
                fast.blur_sigma_px = level_sets[static_cast<std::size_t>(trial)];
                TagVerifyOptions plain = fast;
                plain.reference_ncc = true;
                const TagVerifyResult a = verifyPredictedTag(img->view(), vs.cam, *patterns.get(item.id), others, item.size, cam_from_tag, fast);
                const TagVerifyResult b = verifyPredictedTag(img->view(), vs.cam, *patterns.get(item.id), others, item.size, cam_from_tag, plain);
                ++compared;
                EXPECT_EQ(a.ok, b.ok) << item.id;
                EXPECT_EQ(a.reason, b.reason) << item.id;
                EXPECT_NEAR(a.ncc, b.ncc, 1e-12) << item.id;
                EXPECT_NEAR(a.ncc_square, b.ncc_square, 1e-12) << item.id;
                EXPECT_NEAR(a.ncc_other, b.ncc_other, 1e-12) << item.id;
                EXPECT_EQ(a.shift_px, b.shift_px) << item.id;
                EXPECT_EQ(a.grid_shifts_tried, b.grid_shifts_tried) << item.id;
                EXPECT_FALSE(std::isnan(a.ncc)) << item.id;
                accepted += a.ok ? 1 : 0;
                if (img == &flat) {
                    EXPECT_FALSE(a.ok);
                    flat_refused += a.ok ? 0 : 1;
                }
            }
        }
    }
    std::printf("verifications compared: %d (%d accepted, %d on the flat image refused)\n", compared, accepted, flat_refused);
    EXPECT_GT(accepted, 10);
}

}  // namespace
}  // namespace commonlight::tracking

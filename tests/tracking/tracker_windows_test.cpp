// Tracking mode's detection windows (tracker_support::trackingWindows): a window around each
// predicted scene tag the decimated detector can find, none around a smaller one unless the last
// frame detected it. Ground truth: the tags' corners projected by a pinhole camera.
#include <numbers>

#include <gtest/gtest.h>

#include "core/scene.h"
#include "tracking/edge_model.h"
#include "tracking/tracker_support.h"

namespace commonlight::tracking {
namespace {

using Eigen::Vector2d;
using Eigen::Vector3d;
constexpr double kPi = std::numbers::pi;

CameraModel camera() {
    CameraModel c;
    c.width = 640;
    c.height = 480;
    c.fx = c.fy = 500;
    c.cx = 319.5;
    c.cy = 239.5;
    return c;
}

// Turned by pi about x: the printed side (+z) towards a camera at the origin looking along +z.
const Eigen::Quaterniond kFacing(0, 1, 0, 0);

// Two tags 1 m in front of the camera, facing it: id 0 (10 cm, a black square 50 px across) at
// x = -0.2 m, id 1 (1.5 cm, 7.5 px) at x = +0.2 m; their windows do not overlap.
TagSet tags() {
    TagSet t;
    t.items.push_back({0, 0.10, Rigid3d(kFacing, Vector3d(-0.2, 0, 1))});
    t.items.push_back({1, 0.015, Rigid3d(kFacing, Vector3d(0.2, 0, 1))});
    return t;
}

Vector2d centre(const TagItem& item) { return *camera().project(item.world_from_tag.translation); }

bool inside(const PixelWindow& w, const Vector2d& p) {
    return p.x() >= w.x && p.x() < w.x + w.width && p.y() >= w.y && p.y() < w.y + w.height;
}

int windowsHolding(const std::vector<PixelWindow>& windows, const Vector2d& p) {
    int n = 0;
    for (const PixelWindow& w : windows) n += inside(w, p) ? 1 : 0;
    return n;
}

TEST(TrackingWindows, OnlyWhereTheDecimatedDetectorCanFindTheTag) {
    const TagSet t = tags();
    const Vector2d big = centre(t.items[0]), small = centre(t.items[1]);
    TrackerOptions options;
    options.detector.decimate = 2.0;
    options.window_min_span_px = 5.0;  // 10 px of the frame at decimate 2
    const std::optional<Rigid3d> predicted = Rigid3d::identity();

    auto w = tracker_support::trackingWindows(camera(), t, predicted, {}, options);
    ASSERT_EQ(w.size(), 1u);
    EXPECT_EQ(windowsHolding(w, big), 1);
    EXPECT_EQ(windowsHolding(w, small), 0) << "7.5 px at decimate 2: left to the verification";

    // At full resolution (5 px) it gets one, and with the threshold off too.
    options.detector.decimate = 1.0;
    w = tracker_support::trackingWindows(camera(), t, predicted, {}, options);
    EXPECT_EQ(w.size(), 2u);
    EXPECT_EQ(windowsHolding(w, small), 1);
    options.detector.decimate = 2.0;
    options.window_min_span_px = 0.0;
    w = tracker_support::trackingWindows(camera(), t, predicted, {}, options);
    EXPECT_EQ(w.size(), 2u);
    EXPECT_EQ(windowsHolding(w, small), 1);

    // The last frame detected the small one: its window stays, where it was.
    options.window_min_span_px = 5.0;
    TagDetection last;
    last.id = 1;
    for (int c = 0; c < 4; ++c) {
        last.corners[static_cast<std::size_t>(c)] = *camera().project(
            t.items[1].world_from_tag * tagCornerInTag(c, t.items[1].size));
    }
    last.center = small;
    w = tracker_support::trackingWindows(camera(), t, predicted, {last}, options);
    EXPECT_EQ(w.size(), 2u);
    EXPECT_EQ(windowsHolding(w, small), 1);
    EXPECT_EQ(windowsHolding(w, big), 1);

    // A tag beside the camera, seen edge-on from 2-12 cm (its corners from x = 528 to 1569 px, y
    // +-1250 px): no window, rather than a box over the whole frame; one whose corners are 5 px out
    // of the image (x 594-645 px) keeps its.
    TagSet beside = t;
    beside.items.push_back(
        {2, 0.10, Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(-0.5 * kPi, Vector3d::UnitY())), Vector3d(0.05, 0, 0.07))});
    beside.items.push_back({3, 0.10, Rigid3d(kFacing, Vector3d(0.6, 0, 1))});
    w = tracker_support::trackingWindows(camera(), beside, predicted, {}, options);
    ASSERT_EQ(w.size(), 2u);
    EXPECT_EQ(windowsHolding(w, big), 1);
    for (const PixelWindow& win : w) EXPECT_LT(win.width, 200) << "a window over the whole frame";
    EXPECT_EQ(windowsHolding(w, centre(beside.items[3])), 1) << "the tag at the edge keeps its window";

    // Without a prediction: only where the last frame's tags were.
    w = tracker_support::trackingWindows(camera(), t, std::nullopt, {last}, options);
    ASSERT_EQ(w.size(), 1u);
    EXPECT_EQ(windowsHolding(w, small), 1);
}

// A predicted tag with its back to the camera, or behind a proxy, is not in view: no window (the
// detector could not find it; the verification skips the hidden ones too), unless the last frame
// detected it. Ground truth: the geometry (the camera centre behind the tag's plane; a box on the
// line of sight).
TEST(TrackingWindows, NoneForATagFacingAwayOrHiddenByTheProxies) {
    TagSet t = tags();
    t.items.resize(1);  // the big one, 50 px across
    const Vector2d big = centre(t.items[0]);
    TrackerOptions options;
    options.detector.decimate = 2.0;
    const std::optional<Rigid3d> predicted = Rigid3d::identity();
    ASSERT_EQ(tracker_support::trackingWindows(camera(), t, predicted, {}, options).size(), 1u);

    // Turned by 100 degrees about y: its printed side looks 10 degrees away from the camera.
    TagSet away = t;
    away.items[0].world_from_tag.rotation =
        Eigen::Quaterniond(Eigen::AngleAxisd(100.0 / 180.0 * kPi, Vector3d::UnitY())) * kFacing;
    EXPECT_TRUE(tracker_support::facesAway(*predicted * away.items[0].world_from_tag));
    EXPECT_FALSE(tracker_support::facesAway(*predicted * t.items[0].world_from_tag));
    EXPECT_EQ(tracker_support::trackingWindows(camera(), away, predicted, {}, options).size(), 0u);

    // A 20 cm box half way to it hides it; one beside the line of sight does not.
    Scene scene;
    scene.real_objects.push_back({"box", BoxShape{{0.2, 0.2, 0.2}}, Rigid3d({1, 0, 0, 0}, Vector3d(-0.1, 0, 0.5)),
                                  RgbOrEstimate::constant(Vector3d::Constant(0.5))});
    auto hiding = EdgeModel::fromScene(scene);
    ASSERT_TRUE(hiding) << hiding.error().message;
    scene.real_objects[0].world_from_object.translation = Vector3d(0.3, 0, 0.5);
    auto beside = EdgeModel::fromScene(scene);
    ASSERT_TRUE(beside) << beside.error().message;
    EXPECT_EQ(tracker_support::trackingWindows(camera(), t, predicted, {}, options, &*hiding).size(), 0u);
    const auto w = tracker_support::trackingWindows(camera(), t, predicted, {}, options, &*beside);
    ASSERT_EQ(w.size(), 1u);
    EXPECT_EQ(windowsHolding(w, big), 1);

    // The last frame detected it: its window stays, where it was.
    TagDetection last;
    last.id = 0;
    for (int c = 0; c < 4; ++c) {
        last.corners[static_cast<std::size_t>(c)] = *camera().project(t.items[0].world_from_tag * tagCornerInTag(c, t.items[0].size));
    }
    last.center = big;
    EXPECT_EQ(windowsHolding(tracker_support::trackingWindows(camera(), t, predicted, {last}, options, &*hiding), big), 1);
}

}  // namespace
}  // namespace commonlight::tracking

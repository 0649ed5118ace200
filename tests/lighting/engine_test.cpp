// The lighting thread: sync mode processes every observation in order; real-time mode never
// blocks the producer, skips to the newest input and reports it; TSan-clean with a producer
// feeding observations and poses at 120 Hz while a reader polls snapshots.
#include "lighting/engine.h"

#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <thread>

namespace commonlight::lighting {
namespace {

Scene smallScene() {
    Scene scene;
    RealObject floor;
    floor.name = "floor";
    floor.shape = PlaneShape{Eigen::Vector2d(2.0, 2.0)};
    floor.albedo = RgbOrEstimate::constant(Eigen::Vector3d::Constant(0.5));
    scene.real_objects.push_back(floor);
    Light panel;
    panel.name = "panel";
    panel.shape = AreaLightShape{Eigen::Vector2d(0.4, 0.4)};
    panel.world_from_object = Rigid3d::fromRpyDeg(Eigen::Vector3d(0, 0, 1.5), Eigen::Vector3d(180, 0, 0));
    panel.emission = RgbOrEstimate::constant(Eigen::Vector3d::Constant(10.0));
    scene.lights.push_back(panel);
    VirtualObject ball;
    ball.name = "ball";
    ball.shape = SphereShape{0.1};
    ball.placement = FixedPlacement{Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0, 0, 0.1))};
    scene.virtual_objects.push_back(ball);
    return scene;
}

CameraModel smallCamera() {
    CameraModel camera;
    camera.width = 64;
    camera.height = 48;
    camera.fx = camera.fy = 60.0;
    camera.cx = 31.5;
    camera.cy = 23.5;
    return camera;
}

Rigid3d lookingDown() {
    // Camera 1 m above the floor looking straight down (OpenCV axes: z forward = world -z).
    return Rigid3d::fromRpyDeg(Eigen::Vector3d(0, 0, 1.0), Eigen::Vector3d(180, 0, 0)).inverse();
}

Image greyFrame(const CameraModel& camera, std::uint8_t value) {
    Image image(PixelFormat::kRgb8, camera.width, camera.height);
    std::fill(image.data(), image.data() + image.sizeBytes(), value);
    return image;
}

// A frame seen from lookingDown() at 10 ms exposure, unit gain.
Observation seenFromAbove(const Image& frame, std::int64_t timestamp_ns) {
    Observation obs;
    obs.rgb8 = frame.view();
    obs.timestamp_ns = timestamp_ns;
    obs.cam_from_world = lookingDown();
    obs.exposure_us = 10000;
    obs.analog_gain = 1;
    return obs;
}

// Waits (a minute at most) until `count` of the engine's stats reaches `n`.
void waitUntil(const LightingEngine& e, std::uint64_t EngineStats::*count, std::uint64_t n) {
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    while (e.stats().*count < n && std::chrono::steady_clock::now() < deadline) std::this_thread::sleep_for(std::chrono::milliseconds(1));
}

TEST(LightingEngine, FirstSnapshotIsVersionZeroAndNeverNull) {
    auto engine = LightingEngine::create(smallScene(), smallCamera(), {});
    ASSERT_TRUE(engine) << engine.error().message;
    SnapshotPtr s = (*engine)->latest();
    ASSERT_NE(s, nullptr);
    EXPECT_EQ(s->version, 0u);
    EXPECT_TRUE(s->faces.empty());
}

TEST(LightingEngine, SyncModeProcessesEveryObservationInOrder) {
    EngineOptions options;
    options.sync = true;
    auto engine = LightingEngine::create(smallScene(), smallCamera(), options);
    ASSERT_TRUE(engine) << engine.error().message;
    (*engine)->start();
    const Image frame = greyFrame(smallCamera(), 128);
    for (int i = 0; i < 5; ++i) {
        const Observation obs = seenFromAbove(frame, 1000 + i);
        ASSERT_TRUE((*engine)->submit(obs));
        // Sync: the snapshot of this very frame is published when submit returns.
        EXPECT_EQ((*engine)->latest()->version, static_cast<std::uint64_t>(i + 1));
        EXPECT_EQ((*engine)->latest()->frame_timestamp_ns, 1000 + i);
    }
    (*engine)->stop();
    const EngineStats stats = (*engine)->stats();
    EXPECT_EQ(stats.submitted, 5u);
    EXPECT_EQ(stats.processed, 5u);
    EXPECT_EQ(stats.skipped, 0u);
    EXPECT_EQ(stats.updates, 5u);
    EXPECT_EQ(stats.update_ms.count(), 5u);
}

TEST(LightingEngine, FrameWithoutPoseIsCountedAndBadInputIsRejected) {
    EngineOptions options;
    options.sync = true;
    auto engine = LightingEngine::create(smallScene(), smallCamera(), options);
    ASSERT_TRUE(engine);
    (*engine)->start();
    const Image frame = greyFrame(smallCamera(), 100);
    Observation obs;
    obs.rgb8 = frame.view();
    obs.timestamp_ns = 1;
    ASSERT_TRUE((*engine)->submit(obs));  // no pose
    Rigid3d nan_pose = lookingDown();
    nan_pose.translation.x() = std::nan("");
    obs.cam_from_world = nan_pose;
    obs.timestamp_ns = 2;
    ASSERT_TRUE((*engine)->submit(obs));  // a NaN pose counts as no pose
    EXPECT_EQ((*engine)->stats().without_pose, 2u);

    const Image wrong(PixelFormat::kRgb8, 32, 24);
    obs.rgb8 = wrong.view();
    auto rejected = (*engine)->submit(obs);
    ASSERT_FALSE(rejected);
    EXPECT_EQ(rejected.error().code, ErrorCode::kBadInput);
    EXPECT_NE(rejected.error().message.find("64x48"), std::string::npos) << rejected.error().message;
    (*engine)->stop();
}

TEST(LightingEngine, RealTimeProducerAt120HzNeverWaitsAndReaderSeesIncreasingVersions) {
    auto engine = LightingEngine::create(smallScene(), smallCamera(), {});
    ASSERT_TRUE(engine);
    LightingEngine& e = **engine;
    e.start();
    std::atomic<bool> done{false};
    std::atomic<bool> versions_monotonic{true};
    std::thread reader([&] {
        std::uint64_t last = 0;
        while (!done.load()) {
            SnapshotPtr s = e.latest();
            if (s->version < last) versions_monotonic = false;
            last = s->version;
            std::this_thread::sleep_for(std::chrono::milliseconds(2));
        }
    });
    const Image frame = greyFrame(smallCamera(), 90);
    const auto period = std::chrono::microseconds(8333);
    auto next = std::chrono::steady_clock::now();
    double worst_submit_ms = 0.0;
    for (int i = 0; i < 120; ++i) {
        const Observation obs = seenFromAbove(frame, i * 8333333LL);
        std::vector<Rigid3d> poses{Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0.001 * i, 0, 0.1))};
        e.setVirtualPoses(poses);
        const auto t0 = std::chrono::steady_clock::now();
        ASSERT_TRUE(e.submit(obs));
        worst_submit_ms = std::max(
            worst_submit_ms, std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
        next += period;
        std::this_thread::sleep_until(next);
    }
    done = true;
    reader.join();
    e.stop();
    const EngineStats stats = e.stats();
    EXPECT_TRUE(versions_monotonic.load());
    EXPECT_EQ(stats.submitted, 120u);
    // Every observation is either processed or skipped as replaced by a newer one (the last
    // one may still have been pending at stop()).
    EXPECT_GE(stats.processed + stats.skipped + 1, 120u);
    EXPECT_GE(stats.updates, 1u);
    EXPECT_FALSE(e.lastError().has_value());
    RecordProperty("worst_submit_ms", std::to_string(worst_submit_ms));
}

// Real time with update_every 2: the thread solves for the first observation and then for one
// submitted at least two after the last one solved; the others are accumulated only. Each
// observation is submitted once the thread has taken the previous one (no skips), so the count is
// exact: 7 observations, solved for tickets 1, 3, 5 and 7.
TEST(LightingEngine, UpdateEverySecondObservationAccumulatesTheOthersOnly) {
    for (const int every : {1, 2}) {
        EngineOptions options;
        options.update_every = every;
        auto engine = LightingEngine::create(smallScene(), smallCamera(), options);
        ASSERT_TRUE(engine) << engine.error().message;
        LightingEngine& e = **engine;
        e.start();
        const Image frame = greyFrame(smallCamera(), 100);
        for (int i = 0; i < 7; ++i) {
            const Observation obs = seenFromAbove(frame, 1000 + i);
            ASSERT_TRUE(e.submit(obs));
            waitUntil(e, &EngineStats::processed, static_cast<std::uint64_t>(i + 1));
        }
        e.stop();
        const EngineStats stats = e.stats();
        EXPECT_EQ(stats.processed, 7u) << "every " << every;
        EXPECT_EQ(stats.skipped, 0u) << "every " << every;
        EXPECT_EQ(stats.updates, every == 1 ? 7u : 4u) << "every " << every;
        EXPECT_EQ(e.latest()->frame_timestamp_ns, 1006) << "every " << every;
        EXPECT_FALSE(e.lastError().has_value());
    }
    EngineOptions bad;
    bad.update_every = 0;
    EXPECT_FALSE(LightingEngine::create(smallScene(), smallCamera(), bad));
}

// setUpdateEvery() between observations: 1 for tickets 1-3 (solved for 1, 2, 3), then 3 (solved
// for 6 and 9 of 4-10), then 1 again (11 and 12): 7 updates for 12 observations.
TEST(LightingEngine, SetUpdateEveryChangesThePaceFromTheNextObservation) {
    auto engine = LightingEngine::create(smallScene(), smallCamera(), EngineOptions{});
    ASSERT_TRUE(engine) << engine.error().message;
    LightingEngine& e = **engine;
    EXPECT_EQ(e.updateEvery(), 1);
    e.start();
    const Image frame = greyFrame(smallCamera(), 100);
    for (int i = 0; i < 12; ++i) {
        if (i == 3) e.setUpdateEvery(3);
        if (i == 10) e.setUpdateEvery(1);
        ASSERT_TRUE(e.submit(seenFromAbove(frame, 2000 + i)));
        waitUntil(e, &EngineStats::processed, static_cast<std::uint64_t>(i + 1));
    }
    e.stop();
    const EngineStats stats = e.stats();
    EXPECT_EQ(stats.processed, 12u);
    EXPECT_EQ(stats.updates, 7u);
    EXPECT_EQ(e.latest()->frame_timestamp_ns, 2011);
    e.setUpdateEvery(0);  // clamped
    EXPECT_EQ(e.updateEvery(), 1);
}

// A full update (the lights refitted) comes when the observations have doubled, and with
// refit_min_frames no sooner than that many observations after the last one: in sync mode over
// 20 observations, full updates after 1, 2, 4, 8 and 16 by default, after 1, 9 and 18 with 8.
TEST(LightingEngine, FullUpdatesComeNoSoonerThanRefitMinFramesApart) {
    for (const int min_frames : {0, 8}) {
        EngineOptions options;
        options.sync = true;
        options.refit_min_frames = min_frames;
        auto engine = LightingEngine::create(smallScene(), smallCamera(), options);
        ASSERT_TRUE(engine) << engine.error().message;
        LightingEngine& e = **engine;
        e.start();
        const Image frame = greyFrame(smallCamera(), 100);
        for (int i = 0; i < 20; ++i) ASSERT_TRUE(e.submit(seenFromAbove(frame, 1000 + i)));
        e.stop();
        EXPECT_EQ(e.stats().updates, 20u) << min_frames;
        EXPECT_EQ(e.stats().full_updates, min_frames == 0 ? 5u : 3u) << min_frames;
        EXPECT_EQ(e.fullUpdates(), e.stats().full_updates) << min_frames;
        EXPECT_FALSE(e.lastError().has_value());
    }
    EngineOptions bad;
    bad.refit_min_frames = -2;
    EXPECT_FALSE(LightingEngine::create(smallScene(), smallCamera(), bad));
}

// In real time a full update after the first runs in an arena of full_update_threads (default 1),
// so it leaves the other core to tracking and compositing; the first (nothing drawn lit yet) and
// every full update in sync mode use every core. Full updates after observations 1 and 9.
TEST(LightingEngine, FullUpdatesAfterTheFirstUseFullUpdateThreadsInRealTime) {
    const int every_core = tbb::this_task_arena::max_concurrency();
    for (const int threads : {0, 2}) {
        EngineOptions options;
        options.full_update_threads = threads;
        auto engine = LightingEngine::create(smallScene(), smallCamera(), options);
        ASSERT_TRUE(engine) << engine.error().message;
        LightingEngine& e = **engine;
        e.start();
        const Image frame = greyFrame(smallCamera(), 100);
        for (int i = 0; i < 10; ++i) {
            ASSERT_TRUE(e.submit(seenFromAbove(frame, 3000 + i)));
            waitUntil(e, &EngineStats::updates, static_cast<std::uint64_t>(i + 1));
            if (i == 0) {
                EXPECT_EQ(e.stats().full_updates, 1u);
                EXPECT_EQ(e.stats().full_update_threads, every_core) << threads;
            }
        }
        e.stop();
        EXPECT_EQ(e.stats().full_updates, 2u) << threads;
        EXPECT_EQ(e.stats().full_update_threads, threads == 0 ? 1 : threads);
        EXPECT_FALSE(e.lastError().has_value());
    }
    EngineOptions sync;
    sync.sync = true;
    auto engine = LightingEngine::create(smallScene(), smallCamera(), sync);
    ASSERT_TRUE(engine);
    (*engine)->start();
    const Image frame = greyFrame(smallCamera(), 100);
    for (int i = 0; i < 10; ++i) ASSERT_TRUE((*engine)->submit(seenFromAbove(frame, 4000 + i)));
    (*engine)->stop();
    EXPECT_EQ((*engine)->stats().full_updates, 4u);  // after 1, 2, 4 and 8
    EXPECT_EQ((*engine)->stats().full_update_threads, every_core);
    EngineOptions bad;
    bad.full_update_threads = -1;
    EXPECT_FALSE(LightingEngine::create(smallScene(), smallCamera(), bad));
}

// Between full updates (when the observations double) the engine only brings the virtual
// objects' influence up to date (lighting/influence.h): a ball moving across the floor in sync
// mode gets a snapshot per frame, most of them incremental, and its shadow (the floor texel with
// the lowest ratio B/B~) follows it.
TEST(LightingEngine, MovingObjectUpdatesIncrementallyAndItsShadowFollows) {
    EngineOptions options;
    options.sync = true;
    auto engine = LightingEngine::create(smallScene(), smallCamera(), options);
    ASSERT_TRUE(engine);
    LightingEngine& e = **engine;
    e.start();
    const Image frame = greyFrame(smallCamera(), 90);
    for (int i = 0; i < 12; ++i) {
        const double x = -0.3 + 0.05 * i;
        e.setVirtualPoses({Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(x, 0.2, 0.1))});
        const Observation obs = seenFromAbove(frame, i * 33333333LL);
        ASSERT_TRUE(e.submit(obs));
        const SnapshotPtr s = e.latest();
        ASSERT_EQ(s->version, static_cast<std::uint64_t>(i + 1));
        const FaceModulation* floor = s->findFace(0, 0);
        ASSERT_NE(floor, nullptr);
        // The floor plane spans [-1, 1] in x and y; the panel is straight above the origin at
        // 1.5 m, so the shadow (the centroid of 1 - ratio over the floor's texels) lies near the
        // ball's position scaled by 1.5 / (1.5 - 0.1).
        std::size_t darkest = 0;
        double weight = 0.0, moment = 0.0;
        for (std::size_t k = 0; k < floor->ratio.size(); ++k) {
            if (floor->ratio[k].y() < floor->ratio[darkest].y()) darkest = k;
            const double s_coord = (static_cast<double>(k % static_cast<std::size_t>(floor->width)) + 0.5) / floor->width;
            const double w = std::max(0.0, 1.0 - static_cast<double>(floor->ratio[k].y()));
            weight += w;
            moment += w * (floor->corners[0].x() + s_coord * (floor->corners[1].x() - floor->corners[0].x()));
        }
        ASSERT_GT(weight, 0.0);
        EXPECT_NEAR(moment / weight, x * 1.5 / 1.4, 0.03) << "frame " << i;
        EXPECT_LT(floor->ratio[darkest].y(), 0.5f);
    }
    e.stop();
    const EngineStats stats = e.stats();
    EXPECT_EQ(stats.updates, 12u);
    // Full updates when the observations have doubled: after frames 1, 2, 4 and 8.
    EXPECT_EQ(stats.full_updates, 4u);
    EXPECT_EQ(stats.incremental_ms.count(), 8u);
}

// realRatioImage(): the ratio of the real surface behind a virtual object too (the floor under
// the ball, in its shadow), the same as ratioImage() wherever that sees a real surface; and it is
// read beside the lighting thread's updates while the ball moves (race-free under TSan: it reads
// only the real scene and the snapshot).
TEST(LightingEngine, RealRatioImageSeesThroughTheObjectsAndRunsBesideUpdates) {
    EngineOptions sync_options;
    sync_options.sync = true;
    auto sync = LightingEngine::create(smallScene(), smallCamera(), sync_options);
    ASSERT_TRUE(sync) << sync.error().message;
    (*sync)->start();
    const Image frame = greyFrame(smallCamera(), 100);
    for (int i = 0; i < 3; ++i) ASSERT_TRUE((*sync)->submit(seenFromAbove(frame, 3000 + i)));
    const SnapshotPtr snapshot = (*sync)->latest();
    auto all = (*sync)->ratioImage(*snapshot, lookingDown());
    auto real = (*sync)->realRatioImage(*snapshot, lookingDown());
    (*sync)->stop();
    ASSERT_TRUE(all && real);
    int behind = 0, same = 0;
    for (int y = 0; y < smallCamera().height; ++y) {
        const auto* a = reinterpret_cast<const float*>(all->view().row(y));
        const auto* r = reinterpret_cast<const float*>(real->view().row(y));
        for (int x = 0; x < 3 * smallCamera().width; x += 3) {
            ASSERT_TRUE(std::isfinite(r[x + 1])) << x / 3 << "," << y;  // the floor fills the view
            if (std::isfinite(a[x + 1])) {
                EXPECT_EQ(a[x + 1], r[x + 1]) << x / 3 << "," << y;
                ++same;
            } else {
                EXPECT_LT(r[x + 1], 0.9f) << x / 3 << "," << y;  // under the ball: its contact shadow
                ++behind;
            }
        }
    }
    EXPECT_GT(behind, 20);
    EXPECT_GT(same, 1000);

    auto engine = LightingEngine::create(smallScene(), smallCamera(), {});
    ASSERT_TRUE(engine);
    LightingEngine& e = **engine;
    e.start();
    std::atomic<bool> done{false};
    std::atomic<int> traced{0};
    std::thread reader([&] {
        while (!done.load()) {
            if (e.realRatioImage(*e.latest(), lookingDown(), 2)) ++traced;
        }
    });
    for (int i = 0; i < 20; ++i) {
        e.setVirtualPoses({Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0.01 * i, 0, 0.1))});
        ASSERT_TRUE(e.submit(seenFromAbove(frame, 4000 + i)));
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    while (e.stats().updates < 2 && std::chrono::steady_clock::now() < deadline) std::this_thread::sleep_for(std::chrono::milliseconds(1));
    done = true;
    reader.join();
    e.stop();
    EXPECT_GE(e.stats().updates, 2u);
    EXPECT_GT(traced.load(), 0);
    EXPECT_FALSE(e.lastError().has_value());
}

TEST(LightingEngine, StopIsIdempotentAndSubmitAfterStopFails) {
    auto engine = LightingEngine::create(smallScene(), smallCamera(), {});
    ASSERT_TRUE(engine);
    (*engine)->start();
    (*engine)->start();
    (*engine)->stop();
    (*engine)->stop();
    const Image frame = greyFrame(smallCamera(), 90);
    Observation obs;
    obs.rgb8 = frame.view();
    EXPECT_FALSE((*engine)->submit(obs));
}

}  // namespace
}  // namespace commonlight::lighting

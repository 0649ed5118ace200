// LightingEngine: the lighting thread (DESIGN.md section 1).
//
// It takes the newest observed frame with its camera pose, and the virtual objects' poses,
// accumulates what the frames show of the real proxies (lighting/observations.h), estimates the
// real lights and reflectances, solves radiosity with and without the virtual objects, and
// publishes an immutable LightingSnapshot (lighting/snapshot.h) by shared-pointer swap.
//
// Threads. submit() and setVirtualPoses() are called by one producer (the pipeline thread);
// latest() and stats() by anyone (the renderer on the main thread). In real-time mode submit()
// copies the pixels into a free buffer and returns at once: an observation the engine has not
// started on is replaced by a newer one (newest wins, counted as skipped), and the renderer
// never waits (latest() is one atomic load). In sync mode (`EngineOptions::sync`) submit() returns
// only once the engine has processed that observation and published its snapshot, so every frame
// is processed, in order, and the output is deterministic.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/camera_model.h"
#include "core/image.h"
#include "core/percentiles.h"
#include "core/pose.h"
#include "core/response.h"
#include "core/percentiles.h"
#include "core/result.h"
#include "core/scene.h"
#include "lighting/snapshot.h"

namespace commonlight::lighting {

struct EngineOptions {
    bool sync = false;  // process every observation in order; submit() waits for its snapshot
    ResponseCurve response = ResponseCurve::srgb();  // how the frames' codes became linear
    // Relative radiance per W/(m^2 sr) (sensor.yaml `radiance_scale`); nullopt: the camera is not
    // radiometrically calibrated, 1 is assumed (estimated emissions are then in relative units,
    // and a virtual emitter's radiance is taken as relative radiance).
    std::optional<double> radiance_scale;
    // Solve at most this often in real-time mode (observations in between are still accumulated
    // when the engine is idle); 0: as often as it can.
    double max_update_hz = 0.0;
    // In real-time mode, solve only for an observation submitted at least this many submissions
    // after the one last solved for (1: every observation the thread takes). Observations in
    // between are still accumulated when the thread is idle. With 2 at the camera's rate the thread
    // updates every second frame and leaves the rest of the CPU to tracking and compositing.
    int update_every = 1;
    // Observations are ray cast on every `observation_stride`-th pixel in x and y (1: all).
    int observation_stride = 2;
    // Each observation casts one of k x k offsets of the lattice of every (k stride)-th pixel, in
    // turn (lighting/observations.h): k x k observations sample what one samples at k = 1, for
    // 1 / k^2 of the work. 0: 2 in real-time mode (where observations are a sample over time
    // anyway: newest wins), 1 in sync mode.
    int observation_interleave = 0;
    // A full update (the lights and reflectances refitted: 100-150 ms on the sample, against 15-20
    // for the others) no sooner than this many observations after the last one, so that the
    // doubling schedule's early refits (after 2, 4, 8 ... observations) do not hold the lighting
    // back for several frames in a row. -1: 8 in real-time mode, 0 (whenever they double) in sync.
    int refit_min_frames = -1;
    // The threads a full update may use (a TBB arena of that many). It takes 75-140 ms of both
    // cores on the sample: at one thread it takes about twice as long but leaves the other core to
    // tracking and compositing, so frames are not dropped around it. The first full update (before
    // any snapshot) always uses every core. 0: 1 in real-time mode, every core in sync mode.
    int full_update_threads = 0;
};

// One frame as the lighting thread sees it.
struct Observation {
    ImageView rgb8;                          // the distorted frame, RGB8, the camera model's size (copied by submit)
    std::int64_t timestamp_ns = 0;
    std::optional<Rigid3d> cam_from_world;   // nullopt: no pose; counted, contributes nothing
    double exposure_us = 0.0;                // 0: unknown (the frame's metadata did not say); 1 assumed with gain
    double analog_gain = 0.0;                // linear; 0: unknown
};

struct EngineStats {
    std::uint64_t submitted = 0;      // observations given to submit()
    std::uint64_t processed = 0;      // observations the engine accumulated
    std::uint64_t skipped = 0;        // replaced by a newer one before the engine took them (real time)
    std::uint64_t without_pose = 0;   // submitted without a camera pose
    std::uint64_t updates = 0;        // snapshots published
    std::uint64_t full_updates = 0;   // of them, full (light fit, B~ and the influence from scratch)
    int full_update_threads = 0;      // the threads the last full update could use (0: none yet)
    // Per-update times in ms, in fixed-size reservoirs (an hour of live use allocates nothing more):
    SampleReservoir update_ms;        // accumulation + estimation + solve + publication
    SampleReservoir incremental_ms;   // the same, incremental updates only (the virtual objects' influence)
    SampleReservoir lag_ms;           // publication time - the observation's submit time
    double elapsed_s = 0.0;           // since start()

    double updateRateHz() const { return elapsed_s > 0.0 ? static_cast<double>(updates) / elapsed_s : 0.0; }
};

class LightingEngine {
public:
    // Meshes the scene's real proxies and virtual objects and builds the Embree scenes. Errors:
    // a proxy with zero area, a degenerate mesh or an inside-out box (kBadInput naming the object),
    // an invalid camera model. `scene` is copied.
    static Result<std::unique_ptr<LightingEngine>> create(const Scene& scene, const CameraModel& camera,
                                                          const EngineOptions& options);
    ~LightingEngine();  // stops the thread
    LightingEngine(const LightingEngine&) = delete;
    LightingEngine& operator=(const LightingEngine&) = delete;

    // Starts the lighting thread. Idempotent.
    void start();
    // Stops it after the update under way; never fails. Idempotent.
    void stop() noexcept;

    // Hands over an observation (see the file comment for the two modes). Errors: an image of the
    // wrong size or format (kBadInput), a non-finite pose (kBadInput, and the frame is counted as
    // without pose), a failed update in sync mode (its error).
    Result<void> submit(const Observation& observation);
    // The virtual objects' poses from now on (by Scene::virtual_objects index; world_from_object).
    // A size other than the scene's count is a contract violation.
    void setVirtualPoses(const std::vector<Rigid3d>& world_from_object);

    // From now on, solve for every n-th submission at most (EngineOptions::update_every; n >= 1,
    // clamped). Any thread; the lighting thread reads it at its next observation.
    void setUpdateEvery(int n) noexcept;
    int updateEvery() const noexcept;

    // The newest snapshot; never null (version 0 before the first update: every ratio 1).
    SnapshotPtr latest() const noexcept;
    EngineStats stats() const;
    // stats().full_updates alone (no copy of the time reservoirs: for a caller's every frame).
    std::uint64_t fullUpdates() const;
    // The ratio B/B~ a snapshot predicts per pixel for a camera pose (kRgbF32, NaN where no real
    // proxy is seen): for metrics against ground truth. Waits while an update is under way.
    Result<Image> ratioImage(const LightingSnapshot& snapshot, const Rigid3d& cam_from_world, int stride = 1) const;
    // The same for the real surfaces behind the virtual objects too (a caller that leaves their
    // pixels out by other means, e.g. the ground truth's coverage mask). It never waits and never
    // holds an update up: it reads the real scene and the snapshot only.
    Result<Image> realRatioImage(const LightingSnapshot& snapshot, const Rigid3d& cam_from_world, int stride = 1) const;
    // The same without waiting: nullopt when the thread is in the middle of an update (a real-time
    // caller must not stall behind it).
    Result<std::optional<Image>> tryRatioImage(const LightingSnapshot& snapshot, const Rigid3d& cam_from_world,
                                               int stride = 1) const;

    // The first error the thread met in real-time mode (the thread keeps running and retries on
    // the next observation); nullopt when none.
    std::optional<Error> lastError() const;

private:
    struct Impl;
    explicit LightingEngine(std::unique_ptr<Impl> impl);
    std::unique_ptr<Impl> impl_;
};

// The metrics JSON's `lighting` section (docs/cli.md): update ms p50/p95/max, rate, lag, elements,
// links, residual, and the estimated lights by name with their emission.
nlohmann::json lightingMetricsJson(const EngineStats& stats, const LightingSnapshot& snapshot);

}  // namespace commonlight::lighting

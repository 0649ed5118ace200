#include "lighting/engine.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <condition_variable>
#include <mutex>
#include <thread>

#include "core/clock.h"
#include "core/log.h"
#include "lighting/scene_lighting.h"

#include <tbb/task_arena.h>

namespace commonlight::lighting {

namespace {

// An observation owned by the engine: the pixels are copied into `rgb`, whose capacity is reused
// (three of these rotate between the producer and the thread: no allocation per frame).
struct OwnedObservation {
    Image rgb;
    std::int64_t timestamp_ns = 0;
    std::optional<Rigid3d> cam_from_world;
    double exposure_s = 1.0;
    double analog_gain = 1.0;
    std::int64_t submitted_ns = 0;  // CLOCK_MONOTONIC at submit()
    std::uint64_t ticket = 0;       // submit order, from 1
};


}  // namespace

struct LightingEngine::Impl {
    Scene scene;
    CameraModel camera;
    EngineOptions options;
    std::unique_ptr<SceneLighting> model;

    // Producer side: only submit() touches `spare`.
    OwnedObservation spare;

    mutable std::mutex mutex;
    std::condition_variable wake;       // the thread: an observation is pending, or stop
    std::condition_variable processed;  // sync producers: an observation was processed
    OwnedObservation pending;           // guarded by mutex
    bool has_pending = false;
    bool stopping = false;
    bool running = false;
    std::uint64_t next_ticket = 1;
    std::uint64_t done_ticket = 0;            // the newest ticket processed (or skipped)
    std::optional<Error> sync_error;          // the error of done_ticket in sync mode
    std::optional<Error> last_error;
    std::vector<Rigid3d> virtual_poses;
    EngineStats stats;
    std::int64_t started_ns = 0;
    std::int64_t last_update_ns = 0;
    std::uint64_t last_update_ticket = 0;  // the observation the newest snapshot was solved for
    std::atomic<int> update_every{1};      // options.update_every, then setUpdateEvery()'s
    std::uint64_t version = 0;
    int full_update_threads = 0;  // options.full_update_threads resolved: 0 every core

    mutable std::mutex model_mutex;     // held by the thread during an update, and by ratioImage()
    mutable std::mutex snapshot_mutex;  // held only to copy the pointer
    SnapshotPtr snapshot;

    std::thread thread;

    void run();
    // One observation: accumulate, then (rate permitting) update and publish.
    Result<void> process(OwnedObservation& observation, const std::vector<Rigid3d>& poses);
};

LightingEngine::LightingEngine(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

LightingEngine::~LightingEngine() { stop(); }

Result<std::unique_ptr<LightingEngine>> LightingEngine::create(const Scene& scene, const CameraModel& camera,
                                                               const EngineOptions& options) {
    CL_TRY_VOID(camera.validate());
    if (options.observation_stride < 1) {
        return fail(ErrorCode::kUsage, "lighting: observation_stride must be at least 1");
    }
    if (options.update_every < 1) return fail(ErrorCode::kUsage, "lighting: update_every must be at least 1");
    if (options.refit_min_frames < -1) {
        return fail(ErrorCode::kUsage, "lighting: refit_min_frames must be -1 (automatic) or at least 0");
    }
    if (options.observation_interleave < 0) {
        return fail(ErrorCode::kUsage, "lighting: observation_interleave must be 0 (automatic) or at least 1");
    }
    if (options.full_update_threads < 0) {
        return fail(ErrorCode::kUsage, "lighting: full_update_threads must be 0 (automatic) or at least 1");
    }
    if (options.radiance_scale && !(std::isfinite(*options.radiance_scale) && *options.radiance_scale > 0.0)) {
        return fail(ErrorCode::kBadInput, "lighting: radiance_scale must be positive and finite");
    }
    auto impl = std::make_unique<Impl>();
    impl->scene = scene;
    impl->camera = camera;
    impl->options = options;
    SceneLightingOptions model_options;
    model_options.response = options.response;
    model_options.radiance_scale = options.radiance_scale;
    model_options.observation_stride = options.observation_stride;
    model_options.observation_interleave =
        options.observation_interleave > 0 ? options.observation_interleave : (options.sync ? 1 : 2);
    model_options.refit_min_frames = options.refit_min_frames >= 0 ? options.refit_min_frames : (options.sync ? 0 : 8);
    impl->full_update_threads = options.full_update_threads > 0 ? options.full_update_threads : (options.sync ? 0 : 1);
    CL_TRY(impl->model, SceneLighting::create(impl->scene, camera, model_options));
    impl->update_every.store(options.update_every);
    impl->virtual_poses = SceneLighting::scenePoses(impl->scene, 0.0);
    auto first = std::make_shared<LightingSnapshot>();
    first->radiance_scale = options.radiance_scale.value_or(1.0);
    first->radiance_scale_known = options.radiance_scale.has_value();
    first->virtual_poses = impl->virtual_poses;
    impl->snapshot = std::move(first);
    return std::unique_ptr<LightingEngine>(new LightingEngine(std::move(impl)));
}

void LightingEngine::start() {
    std::lock_guard lock(impl_->mutex);
    if (impl_->running) return;
    impl_->running = true;
    impl_->stopping = false;
    impl_->started_ns = monotonicNowNs();
    impl_->thread = std::thread([impl = impl_.get()] { impl->run(); });
}

void LightingEngine::stop() noexcept {
    {
        std::lock_guard lock(impl_->mutex);
        if (!impl_->running) return;
        impl_->stopping = true;
    }
    impl_->wake.notify_all();
    impl_->thread.join();
    std::lock_guard lock(impl_->mutex);
    impl_->running = false;
    impl_->stats.elapsed_s = static_cast<double>(monotonicNowNs() - impl_->started_ns) / 1e9;
    // A sync producer still waiting (it cannot be: submit() holds the only producer) is released.
    impl_->done_ticket = impl_->next_ticket - 1;
    impl_->processed.notify_all();
}

Result<void> LightingEngine::submit(const Observation& observation) {
    Impl& d = *impl_;
    const ImageView& view = observation.rgb8;
    if (view.format != PixelFormat::kRgb8 || view.width != d.camera.width || view.height != d.camera.height ||
        view.empty()) {
        return fail(ErrorCode::kBadInput, "lighting: observation must be RGB8 of " + std::to_string(d.camera.width) +
                                              "x" + std::to_string(d.camera.height) + " (got " +
                                              std::string(pixelFormatName(view.format)) + " " +
                                              std::to_string(view.width) + "x" + std::to_string(view.height) + ")");
    }
    bool bad_pose = false;
    std::optional<Rigid3d> pose = observation.cam_from_world;
    if (pose && !pose->isValid()) {
        pose.reset();
        bad_pose = true;
    }
    // Step 1: copy into the producer's spare buffer (outside the lock).
    d.spare.rgb.assign(view);
    d.spare.timestamp_ns = observation.timestamp_ns;
    d.spare.cam_from_world = pose;
    // Hard case: a camera that does not report exposure or gain; relative radiance then assumes 1.
    d.spare.exposure_s = observation.exposure_us > 0.0 && std::isfinite(observation.exposure_us)
                             ? observation.exposure_us * 1e-6
                             : 1.0;
    d.spare.analog_gain = observation.analog_gain > 0.0 && std::isfinite(observation.analog_gain)
                              ? observation.analog_gain
                              : 1.0;
    d.spare.submitted_ns = monotonicNowNs();

    // Step 2: hand it over (newest wins).
    std::unique_lock lock(d.mutex);
    if (!d.running) return fail(ErrorCode::kInternal, "lighting: submit() before start() or after stop()");
    ++d.stats.submitted;
    if (!pose) ++d.stats.without_pose;
    d.spare.ticket = d.next_ticket++;
    const std::uint64_t ticket = d.spare.ticket;
    if (d.has_pending) {
        ++d.stats.skipped;  // never taken: replaced by this newer one
    }
    std::swap(d.spare, d.pending);
    d.has_pending = true;
    d.wake.notify_one();
    if (bad_pose) {
        log::warning("lighting: frame " + std::to_string(observation.timestamp_ns) +
                     ": camera pose is not finite; the frame contributes nothing");
    }
    if (!d.options.sync) return {};
    // Step 3 (sync): wait until the thread has processed this very observation.
    d.processed.wait(lock, [&] { return d.done_ticket >= ticket || d.stopping; });
    if (d.done_ticket < ticket) return fail(ErrorCode::kCancelled, "lighting: stopped");
    if (d.sync_error) {
        Error e = *d.sync_error;
        d.sync_error.reset();
        return fail(std::move(e));
    }
    return {};
}

void LightingEngine::setVirtualPoses(const std::vector<Rigid3d>& world_from_object) {
    std::lock_guard lock(impl_->mutex);
    if (world_from_object.size() != impl_->scene.virtual_objects.size()) {
        log::error("lighting: setVirtualPoses with " + std::to_string(world_from_object.size()) + " poses for " +
                   std::to_string(impl_->scene.virtual_objects.size()) + " virtual objects (ignored)");
        return;
    }
    impl_->virtual_poses = world_from_object;
}

void LightingEngine::setUpdateEvery(int n) noexcept { impl_->update_every.store(std::clamp(n, 1, 1000)); }

int LightingEngine::updateEvery() const noexcept { return impl_->update_every.load(); }

SnapshotPtr LightingEngine::latest() const noexcept {
    std::lock_guard lock(impl_->snapshot_mutex);
    return impl_->snapshot;
}

EngineStats LightingEngine::stats() const {
    std::lock_guard lock(impl_->mutex);
    EngineStats s = impl_->stats;
    if (impl_->running) s.elapsed_s = static_cast<double>(monotonicNowNs() - impl_->started_ns) / 1e9;
    return s;
}

std::uint64_t LightingEngine::fullUpdates() const {
    std::lock_guard lock(impl_->mutex);
    return impl_->stats.full_updates;
}

Result<Image> LightingEngine::ratioImage(const LightingSnapshot& snapshot, const Rigid3d& cam_from_world, int stride) const {
    std::lock_guard lock(impl_->model_mutex);
    return impl_->model->ratioImage(snapshot, cam_from_world, stride);
}

Result<Image> LightingEngine::realRatioImage(const LightingSnapshot& snapshot, const Rigid3d& cam_from_world, int stride) const {
    return impl_->model->ratioImage(snapshot, cam_from_world, stride, /*through_virtual=*/true);
}

Result<std::optional<Image>> LightingEngine::tryRatioImage(const LightingSnapshot& snapshot, const Rigid3d& cam_from_world,
                                                            int stride) const {
    std::unique_lock lock(impl_->model_mutex, std::try_to_lock);
    if (!lock.owns_lock()) return std::optional<Image>();
    CL_TRY(Image image, impl_->model->ratioImage(snapshot, cam_from_world, stride));
    return std::optional<Image>(std::move(image));
}

std::optional<Error> LightingEngine::lastError() const {
    std::lock_guard lock(impl_->mutex);
    return impl_->last_error;
}

void LightingEngine::Impl::run() {
    OwnedObservation working;
    while (true) {
        std::vector<Rigid3d> poses;
        {
            std::unique_lock lock(mutex);
            wake.wait(lock, [&] { return has_pending || stopping; });
            if (stopping) return;
            std::swap(working, pending);
            has_pending = false;
            poses = virtual_poses;
        }
        Result<void> result = [&] {
            std::lock_guard model_lock(model_mutex);
            return process(working, poses);
        }();
        std::lock_guard lock(mutex);
        done_ticket = working.ticket;
        if (!result) {
            if (options.sync) sync_error = result.error();
            if (!last_error) last_error = result.error();
            log::error("lighting: frame " + std::to_string(working.timestamp_ns) + ": " + result.error().message);
        }
        processed.notify_all();
    }
}

Result<void> LightingEngine::Impl::process(OwnedObservation& observation, const std::vector<Rigid3d>& poses) {
    const std::int64_t start_ns = monotonicNowNs();
    // Step 1: accumulate what the frame shows (a frame without a pose contributes nothing).
    model->setVirtualPoses(poses);
    if (observation.cam_from_world) {
        CL_TRY_VOID(model->observe(observation.rgb.view(), *observation.cam_from_world, observation.exposure_s,
                                   observation.analog_gain, observation.timestamp_ns));
    }
    {
        std::lock_guard lock(mutex);
        ++stats.processed;
    }
    // Step 2: in real time, solve no more often than max_update_hz, and for every update_every-th
    // submission at most.
    if (!options.sync && options.max_update_hz > 0.0 && last_update_ns != 0 &&
        static_cast<double>(start_ns - last_update_ns) < 1e9 / options.max_update_hz) {
        return {};
    }
    if (!options.sync && last_update_ticket != 0 && observation.ticket - last_update_ticket < static_cast<std::uint64_t>(update_every.load())) {
        return {};
    }
    // Step 3: estimate and solve. A full update after the first in an arena of
    // full_update_threads (EngineOptions), so that it leaves the rest of the machine alone.
    int threads = 0;
    Result<LightingSnapshot> solved = fail(ErrorCode::kInternal, "lighting: no update ran");
    const auto solve = [&] {
        threads = tbb::this_task_arena::max_concurrency();
        solved = model->update(poses);
    };
    if (full_update_threads > 0 && version > 0 && model->nextUpdateFull()) {
        tbb::task_arena arena(full_update_threads);
        arena.execute(solve);
    } else {
        solve();
    }
    CL_TRY(LightingSnapshot next, std::move(solved));
    const std::int64_t end_ns = monotonicNowNs();
    next.version = ++version;
    next.frame_timestamp_ns = observation.timestamp_ns;
    next.published_ns = end_ns;
    next.solve.milliseconds = static_cast<double>(end_ns - start_ns) / 1e6;
    next.virtual_poses = poses;
    last_update_ns = end_ns;
    last_update_ticket = observation.ticket;
    // Step 4: publish.
    {
        std::lock_guard lock(snapshot_mutex);
        snapshot = std::make_shared<const LightingSnapshot>(std::move(next));
    }
    std::lock_guard lock(mutex);
    ++stats.updates;
    const bool full = model->lastUpdateFull();
    if (full) {
        ++stats.full_updates;
        stats.full_update_threads = threads;
    }
    stats.update_ms.add(static_cast<double>(end_ns - start_ns) / 1e6);
    stats.lag_ms.add(static_cast<double>(end_ns - observation.submitted_ns) / 1e6);
    if (!full) stats.incremental_ms.add(static_cast<double>(end_ns - start_ns) / 1e6);
    return {};
}

namespace {

nlohmann::json percentilesJson(const SampleReservoir& samples) {
    const Percentiles p = samples.percentiles();
    return {{"p50", p.p50}, {"p95", p.p95}, {"max", p.max}};
}

}  // namespace

nlohmann::json lightingMetricsJson(const EngineStats& stats, const LightingSnapshot& snapshot) {
    nlohmann::json j;
    j["update_ms"] = percentilesJson(stats.update_ms);
    j["lag_ms"] = percentilesJson(stats.lag_ms);
    j["updates"] = stats.updates;
    j["full_updates"] = stats.full_updates;
    j["full_update_threads"] = stats.full_update_threads;
    j["incremental_update_ms"] = percentilesJson(stats.incremental_ms);
    j["update_rate_hz"] = stats.updateRateHz();
    j["observations"] = {{"submitted", stats.submitted},
                         {"processed", stats.processed},
                         {"skipped", stats.skipped},
                         {"without_pose", stats.without_pose}};
    j["elements"] = snapshot.solve.elements;
    j["links"] = snapshot.solve.links;
    j["iterations"] = snapshot.solve.iterations;
    j["residual"] = snapshot.solve.residual;
    j["converged"] = snapshot.solve.converged;
    j["radiance_scale"] = snapshot.radiance_scale;
    j["radiance_scale_known"] = snapshot.radiance_scale_known;
    nlohmann::json lights = nlohmann::json::object();
    for (const EstimatedLight& light : snapshot.lights) {
        lights[light.name] = {{"emission", {light.emission.x(), light.emission.y(), light.emission.z()}},
                              {"estimated", light.estimated},
                              {"relative_error", light.relative_error}};
        if (light.kind == LightKind::kDirectional) {
            lights[light.name]["direction"] = {light.direction.x(), light.direction.y(), light.direction.z()};
        }
        if (!light.warning.empty()) lights[light.name]["warning"] = light.warning;
    }
    j["lights"] = lights;
    j["warnings"] = snapshot.warnings;
    return j;
}

}  // namespace commonlight::lighting

#include "pipeline/runner.h"

#include <algorithm>
#include <cmath>
#include <thread>

#include "core/clock.h"
#include "core/log.h"

namespace commonlight::pipeline {

namespace {

// The lighting thread's poses of the virtual objects: every object has one (identity for an
// object the scene cannot place now).
std::vector<Rigid3d> lightingPoses(const std::vector<std::optional<Rigid3d>>& poses) {
    std::vector<Rigid3d> out;
    out.reserve(poses.size());
    for (const auto& pose : poses) out.push_back(pose.value_or(Rigid3d::identity()));
    return out;
}

// Exposure (s) x analog gain of a frame; 1 for what the metadata does not say.
double exposureGain(const FrameMetadata& meta) {
    const double exposure_s = meta.exposure_us > 0.0 && std::isfinite(meta.exposure_us) ? meta.exposure_us * 1e-6 : 1.0;
    const double gain = meta.analog_gain > 0.0 && std::isfinite(meta.analog_gain) ? meta.analog_gain : 1.0;
    return exposure_s * gain;
}

}  // namespace

FrameRunner::FrameRunner(const Scene& scene, const CameraModel& camera, const RunnerOptions& options)
    : scene_(scene),
      camera_(camera),
      options_(options),
      timings_({"convert", "track", "lighting", "composite", "pipeline"}),
      offsets_(scene.virtual_objects.size(), Eigen::Vector3d::Zero()) {}

FrameRunner::~FrameRunner() { stop(); }

Result<std::unique_ptr<FrameRunner>> FrameRunner::create(const Scene& scene, const CameraModel& camera,
                                                         const RunnerOptions& options) {
    auto runner = std::unique_ptr<FrameRunner>(new FrameRunner(scene, camera, options));
    PipelineOptions tracking_options;
    tracking_options.tracker = options.tracker;
    tracking_options.ground_truth = options.ground_truth;
    // The tracker borrows the scene: the runner's own copy, which lives as long as it does.
    CL_TRY(FramePipeline tracking, FramePipeline::create(runner->camera_, runner->scene_, tracking_options, runner->timings_));
    runner->tracking_.emplace(std::move(tracking));
    if (options.lighting && !scene.real_objects.empty()) {
        CL_TRY(runner->lighting_, LightingStage::create(runner->scene_, camera, options.response, options.radiance_scale,
                                                        options.sync, options.sequence, std::max(1, options.lighting_every)));
        if (options.lighting_every <= 0 && !options.sync) runner->pacer_.emplace();
    } else if (options.lighting) {
        log::info("lighting off: the scene has no real proxy geometry to light");
    }
    if (options.composite) {
        render::ContextOptions context_options;
        context_options.kind = options.context;
        context_options.width = camera.width;
        context_options.height = camera.height;
        context_options.title = "commonlight";
        CL_TRY(runner->context_, render::GlContext::create(context_options));
        CL_TRY(runner->compositor_, render::Compositor::create(*runner->context_, runner->scene_, camera, options.response,
                                                               options.compositor));
        // The pipelined real-time loop adapts its quality (sync and one-thread loops draw as configured).
        if (options.adapt_quality && !options.sync && options.pipeline_thread) runner->governor_.emplace(options.compositor);
        if (!options.side_by_side.empty()) CL_TRY_VOID(checkImagePath(options.side_by_side, "side-by-side picture"));
        if (!options.frames_dir.empty() || !options.video.empty()) {
            CL_TRY(runner->writer_, CompositeWriter::open(options.frames_dir, options.video, camera.width, camera.height, options.fps));
        }
        if (options.sequence) {
            CompositeMeasurerOptions measurer_options;
            measurer_options.background = !options.sync;
            runner->measurer_ = std::make_unique<CompositeMeasurer>(*options.sequence, options.response, measurer_options);
        }
    }
    return runner;
}

double FrameRunner::sceneTime(std::int64_t timestamp_ns) {
    if (!first_timestamp_) first_timestamp_ = timestamp_ns;
    return static_cast<double>(timestamp_ns - *first_timestamp_) / 1e9;
}

std::vector<std::optional<Rigid3d>> FrameRunner::virtualPoses(double t_s) const {
    std::vector<std::optional<Rigid3d>> poses;
    poses.reserve(scene_.virtual_objects.size());
    std::lock_guard lock(offsets_mutex_);
    for (std::size_t i = 0; i < scene_.virtual_objects.size(); ++i) {
        std::optional<Rigid3d> pose = worldFromObject(scene_.virtual_objects[i], scene_.tags, t_s);
        if (pose) pose->translation += offsets_[i];
        poses.push_back(pose);
    }
    return poses;
}

void FrameRunner::moveVirtualObject(std::size_t index, const Eigen::Vector3d& delta) {
    std::lock_guard lock(offsets_mutex_);
    if (index < offsets_.size() && delta.allFinite()) offsets_[index] += delta;
}

LoopStats FrameRunner::run(FrameSource& source, const LoopCallbacks& callbacks, std::stop_token stop) {
    LoopStats stats = options_.sync || !options_.pipeline_thread ? runInOrder(source, callbacks, stop)
                                                                  : runPipelined(source, callbacks, stop);
    // The composites still waiting to be measured.
    if (measurer_) {
        if (Result<void> measured = measurer_->finish(); !measured && !stats.failure) stats.failure = measured.error();
    }
    loop_stats_ = stats;
    return stats;
}

LoopStats FrameRunner::runInOrder(FrameSource& source, const LoopCallbacks& callbacks, std::stop_token stop) {
    LoopStats stats;
    while (true) {
        // Step 1: the next frame.
        Result<std::optional<FrameHandle>> next = source.next(stop);
        if (!next) {
            if (next.error().code != ErrorCode::kCancelled) stats.failure = next.error();
            break;
        }
        if (!next->has_value()) break;
        FrameHandle frame = std::move(**next);
        if (frame->meta.status != FrameStatus::kOk) continue;  // counted by the source
        // Step 2: track it (and, in sync mode, wait for its lighting update).
        if (Result<void> tracked = track(*frame, sync_frame_); !tracked) {
            if (tracked.error().code != ErrorCode::kBadInput) {
                stats.failure = tracked.error();
                break;
            }
            ++stats.bad_frames;
            if (callbacks.on_bad_frame) callbacks.on_bad_frame(*frame, tracked.error());
            continue;
        }
        ++stats.tracked;
        if (callbacks.on_tracked) callbacks.on_tracked(sync_frame_);
        frame.reset();  // the pool slot goes back to the camera
        // Step 3: composite it.
        if (Result<void> done = composite(sync_frame_); !done) {
            stats.failure = done.error();
            break;
        }
        ++stats.composited;
        if (callbacks.on_frame && !callbacks.on_frame(sync_frame_)) {
            stats.stopped = true;
            break;
        }
    }
    return stats;
}

LoopStats FrameRunner::runPipelined(FrameSource& source, const LoopCallbacks& callbacks, std::stop_token stop) {
    TrackedFrameHandoff handoff;
    // The pipeline thread's counts; read once it has been joined.
    std::uint64_t tracked_count = 0, bad_count = 0;
    std::jthread pipeline_thread([&](std::stop_token thread_stop) {
        std::optional<Error> failure;
        double track_ns = 0.0;  // the pipeline stage's time per frame, smoothed
        while (true) {
            // Step 1: take a camera frame just in time for the compositor (frame_loop.h).
            if (!handoff.waitForDemand(static_cast<std::int64_t>(track_ns), thread_stop)) break;
            Result<std::optional<FrameHandle>> next = source.next(thread_stop);
            if (!next) {
                if (next.error().code != ErrorCode::kCancelled) failure = next.error();
                break;
            }
            if (!next->has_value()) break;
            FrameHandle frame = std::move(**next);
            if (frame->meta.status != FrameStatus::kOk) continue;
            // Step 2: track it.
            const std::int64_t started = monotonicNowNs();
            TrackedFrame& out = handoff.writable();
            if (Result<void> tracked = track(*frame, out); !tracked) {
                if (tracked.error().code != ErrorCode::kBadInput) {
                    failure = tracked.error();
                    break;
                }
                ++bad_count;
                if (callbacks.on_bad_frame) callbacks.on_bad_frame(*frame, tracked.error());
                continue;
            }
            ++tracked_count;
            if (callbacks.on_tracked) callbacks.on_tracked(out);
            frame.reset();  // the pool slot goes back to the camera before the hand-over
            // Step 3: hand it over (newest wins).
            handoff.publish();
            const double took = static_cast<double>(monotonicNowNs() - started);
            track_ns = track_ns > 0.0 ? 0.8 * track_ns + 0.2 * took : took;
        }
        handoff.close(std::move(failure));
    });
    // Ctrl-C (or the caller's stop) stops the pipeline thread, which then closes the hand-over.
    std::stop_callback forward(stop, [&pipeline_thread] { pipeline_thread.request_stop(); });

    LoopStats stats;
    const TrackedFrame* last = nullptr;
    double busy_ns = 0.0;  // this thread's time per frame (composite and callbacks), smoothed
    while (true) {
        const TrackedFrame* frame = nullptr;
        const TrackedFrameHandoff::Taken taken = handoff.take(callbacks.idle_period, frame, static_cast<std::int64_t>(busy_ns));
        if (taken == TrackedFrameHandoff::Taken::kEnd) break;
        if (taken == TrackedFrameHandoff::Taken::kTimeout) {
            if (callbacks.on_idle && !callbacks.on_idle(last)) {
                stats.stopped = true;
                break;
            }
            continue;
        }
        const std::int64_t started = monotonicNowNs();
        const double period_ns = frame->frame_period_ns;
        if (Result<void> done = composite(*frame); !done) {
            stats.failure = done.error();
            break;
        }
        ++stats.composited;
        last = frame;
        if (callbacks.on_frame && !callbacks.on_frame(*frame)) {
            stats.stopped = true;
            break;
        }
        const double took = static_cast<double>(monotonicNowNs() - started);
        busy_ns = busy_ns > 0.0 ? 0.8 * busy_ns + 0.2 * took : took;
        if (governor_ && governor_->step(took, period_ns)) {
            compositor_->setOptions(governor_->apply(compositor_->options()));
            const QualityGovernor::Level& l = governor_->levels()[static_cast<std::size_t>(governor_->level())];
            log::info("compositor: MSAA " + std::to_string(l.msaa_samples) + ", " + std::to_string(l.area_light_samples) +
                      " light samples (a frame took " + std::to_string(static_cast<int>(took / 1e6)) + " ms of " +
                      std::to_string(static_cast<int>(period_ns / 1e6)) + ")");
        }
    }
    pipeline_thread.request_stop();
    pipeline_thread.join();
    stats.tracked = tracked_count;
    stats.bad_frames = bad_count;
    stats.replaced = handoff.replaced();
    if (!stats.failure) stats.failure = handoff.error();
    return stats;
}

Result<void> FrameRunner::track(const Frame& frame, TrackedFrame& out) {
    capture::StageTimer pipeline_timer(timings_, timings_.id("pipeline"));
    // Step 1: grey conversion and tracking (stages convert and track).
    auto tracked = tracking_->process(frame);
    if (!tracked) {
        if (tracked.error().code == ErrorCode::kBadInput) ++bad_frames_;
        return fail(tracked.error());
    }
    out.meta = frame.meta;
    out.track = std::move(*tracked);
    // Step 2: where the virtual objects are at the frame's time.
    out.scene_time_s = sceneTime(frame.meta.timestamp_ns);
    out.virtual_poses = virtualPoses(out.scene_time_s);
    // The camera's frame period (frames dropped in between are counted by their sequence numbers).
    std::uint64_t dropped = 0;
    if (last_frame_ns_ > 0 && frame.meta.sequence > last_sequence_ + 1) dropped = frame.meta.sequence - last_sequence_ - 1;
    if (last_frame_ns_ > 0 && frame.meta.timestamp_ns > last_frame_ns_) {
        const double frames = frame.meta.sequence > last_sequence_ ? static_cast<double>(frame.meta.sequence - last_sequence_) : 1.0;
        const double period = static_cast<double>(frame.meta.timestamp_ns - last_frame_ns_) / frames;
        frame_period_ns_ = frame_period_ns_ > 0.0 ? 0.9 * frame_period_ns_ + 0.1 * period : period;
    }
    last_frame_ns_ = frame.meta.timestamp_ns;
    last_sequence_ = frame.meta.sequence;
    out.frame_period_ns = frame_period_ns_;
    out.index = tracked_++;
    // Step 3: the colour frame, for the lighting and the compositor.
    if (lighting_ || compositor_) {
        CL_TRY_VOID(converter_.convert(frame.image, PixelFormat::kRgb8, out.rgb));
    } else {
        out.rgb = Image();
    }
    // YUYV and NV12 go to the compositor as the camera sent them (converted on the GPU, the same
    // BT.601 conversion as capture::PixelConverter).
    const PixelFormat format = frame.image.view().format;
    if (compositor_ && (format == PixelFormat::kYuyv || format == PixelFormat::kNv12)) {
        out.raw = Image::copyOf(frame.image.view());
    } else {
        out.raw = Image();
    }
    // Step 4: the frame to the lighting thread (sync: its update is published before we go on),
    // at the pace the dropped frames allow.
    if (lighting_ && pacer_) {
        if (const std::optional<int> every = pacer_->step(dropped, lighting_->latest()->version > 0, lighting_->fullUpdates())) {
            lighting_->setUpdateEvery(*every);
            log::info(*every == 1 ? std::string("lighting: solving for every frame again")
                                  : "lighting: solving for one frame in " + std::to_string(*every) + " (frames were dropped)");
        }
    }
    if (lighting_) {
        const std::vector<Rigid3d> lighting_poses = lightingPoses(out.virtual_poses);
        capture::StageTimer lighting_timer(timings_, timings_.id("lighting"));
        CL_TRY_VOID(lighting_->process(out.rgb.view(), frame.meta, out.track.cam_from_world, lighting_poses));
    }
    return {};
}

Result<bool> FrameRunner::warmUp(const Frame& first, double timeout_s) {
    if (!lighting_ || options_.sync) return false;
    CL_TRY(tracking::Tracker tracker, tracking::Tracker::create(camera_, scene_.tags, &scene_, options_.tracker));
    capture::PixelConverter converter;
    Image gray;
    CL_TRY_VOID(converter.convert(first.image.view(), PixelFormat::kGray8, gray));
    TrackedFrame frame;
    CL_TRY(frame.track, tracker.process(gray.view(), first.meta));
    if (!frame.track.cam_from_world) return false;
    CL_TRY_VOID(converter.convert(first.image.view(), PixelFormat::kRgb8, frame.rgb));
    frame.meta = first.meta;
    frame.virtual_poses = virtualPoses(0.0);
    CL_TRY_VOID(lighting_->warmUp(frame.rgb.view(), first.meta, *frame.track.cam_from_world, lightingPoses(frame.virtual_poses),
                                  timeout_s));
    // The compositor draws the frame lit once at each of the governor's levels: llvmpipe compiles
    // a program the first time it draws with it (100-170 ms), which would otherwise fall on the
    // first frames played and on the first frame after a change of level. Then it draws once more
    // at each level, best first, timed, until one leaves room in the frame period: the governor
    // starts there (QualityGovernor::startAt) instead of stepping down from the configured level
    // over the first frames played, each late. Not counted.
    if (compositor_) {
        const PixelFormat format = first.image.view().format;
        if (format == PixelFormat::kYuyv || format == PixelFormat::kNv12) frame.raw = Image::copyOf(first.image.view());
        const render::CompositorOptions configured = compositor_->options();
        const int levels = governor_ ? static_cast<int>(governor_->levels().size()) : 1;
        for (int level = levels - 1; level >= 0; --level) {
            if (governor_) compositor_->setOptions(governor_->applyLevel(configured, level));
            CL_TRY_VOID(draw(frame, frame.virtual_poses, nullptr));
        }
        compositor_->setOptions(configured);
        if (governor_ && options_.fps > 0.0) {
            const double period_ns = 1e9 / options_.fps;
            std::vector<double> draw_ns;
            for (int level = 0; level < levels; ++level) {
                compositor_->setOptions(governor_->applyLevel(configured, level));
                const std::int64_t started = monotonicNowNs();
                CL_TRY_VOID(draw(frame, frame.virtual_poses, nullptr));
                draw_ns.push_back(static_cast<double>(monotonicNowNs() - started));
                if (draw_ns.back() <= QualityGovernor::kStepUpLoad * period_ns) break;
            }
            governor_->startAt(draw_ns, period_ns);
            compositor_->setOptions(governor_->apply(configured));
            const QualityGovernor::Level& l = governor_->levels()[static_cast<std::size_t>(governor_->level())];
            std::string took;
            for (const double ns : draw_ns) took += (took.empty() ? "" : ", ") + std::to_string(static_cast<int>(ns / 1e6));
            log::info("compositor: starting at MSAA " + std::to_string(l.msaa_samples) + ", " + std::to_string(l.area_light_samples) +
                      " light samples (a frame took " + took + " ms of " + std::to_string(static_cast<int>(period_ns / 1e6)) +
                      " from the best level down)");
        }
    }
    return true;
}

Result<tracking::FrameTrack> FrameRunner::process(const Frame& frame) {
    CL_TRY_VOID(track(frame, sync_frame_));
    CL_TRY_VOID(composite(sync_frame_));
    return sync_frame_.track;
}

void FrameRunner::setLightingShown(bool shown) {
    if (!compositor_) return;
    render::CompositorOptions o = compositor_->options();
    o.lighting = shown;
    compositor_->setOptions(o);
}

Result<void> FrameRunner::draw(const TrackedFrame& frame, const std::vector<std::optional<Rigid3d>>& poses,
                               lighting::SnapshotPtr* used) {
    // The newest snapshot: in sync mode the one of this very frame; in real time whatever the
    // lighting thread has published (its lag is measured).
    static const lighting::LightingSnapshot kNothing{};
    const lighting::SnapshotPtr snapshot = lighting_ ? lighting_->latest() : nullptr;
    render::FrameInput input;
    input.image = frame.raw.view().empty() ? frame.rgb.view() : frame.raw.view();
    input.exposure_gain = exposureGain(frame.meta);
    input.cam_from_world = frame.track.cam_from_world;
    input.virtual_poses = poses;
    CL_TRY_VOID(compositor_->draw(input, snapshot ? *snapshot : kNothing));
    CL_TRY(composite_, compositor_->read());
    if (used) *used = snapshot;
    return {};
}

Result<void> FrameRunner::redraw(const TrackedFrame& frame) {
    if (!compositor_ || frame.rgb.view().empty()) return {};
    return draw(frame, virtualPoses(frame.scene_time_s), nullptr);
}

Result<void> FrameRunner::composite(const TrackedFrame& frame) {
    if (!compositor_) {
        ++processed_;
        return {};
    }
    std::optional<capture::StageTimer> timer;
    timer.emplace(timings_, timings_.id("composite"));
    lighting::SnapshotPtr snapshot;
    CL_TRY_VOID(draw(frame, frame.virtual_poses, &snapshot));
    timer.reset();  // outputs and ground truth are not the compositor's time
    last_composite_ = CompositeInfo{};
    if (frame.meta.arrival_ns > 0) {
        last_composite_.latency_ms = static_cast<double>(monotonicNowNs() - frame.meta.arrival_ns) / 1e6;
        latency_ms_.add(last_composite_.latency_ms);
    }
    if (snapshot && snapshot->version > 0) {
        last_composite_.lighting_version = snapshot->version;
        const double lag_ms = static_cast<double>(frame.meta.timestamp_ns - snapshot->frame_timestamp_ns) / 1e6;
        last_composite_.lighting_lag_ms = lag_ms;
        lag_ms_.add(lag_ms);
        if (frame.frame_period_ns > 0.0) {
            last_composite_.lighting_lag_frames = lag_ms * 1e6 / frame.frame_period_ns;
            lag_frames_.add(*last_composite_.lighting_lag_frames);
        }
    }
    ++processed_;

    // Outputs and the error against ground truth.
    std::string stem = std::to_string(frame.meta.timestamp_ns);
    if (options_.sequence) {
        for (const SequenceFrame& f : options_.sequence->frames) {
            if (f.timestamp_ns == frame.meta.timestamp_ns) stem = std::filesystem::path(f.filename).stem().string();
        }
    }
    if (writer_) CL_TRY_VOID(writer_->write(composite_.view(), stem));
    if (measurer_) CL_TRY_VOID(measurer_->add(composite_.view(), frame.meta.timestamp_ns, exposureGain(frame.meta)));
    if (!options_.side_by_side.empty() && !side_by_side_done_ && frame.index >= options_.side_by_side_frame) {
        std::optional<FrameTruth> truth;
        if (options_.sequence) {
            CL_TRY(truth, readFrameTruth(*options_.sequence, frame.meta.timestamp_ns));
        }
        const ImageView truth_view = truth ? truth->composite.view() : ImageView{};
        CL_TRY_VOID(writeSideBySide(options_.side_by_side, frame.rgb.view(), composite_.view(), truth ? &truth_view : nullptr));
        side_by_side_done_ = true;
    }
    return {};
}

Result<void> FrameRunner::restart() { return tracking_->restart(); }

void FrameRunner::stop() {
    if (lighting_) lighting_->stop();
    if (writer_) writer_->finish();
}

nlohmann::json FrameRunner::metricsJson() const {
    nlohmann::json metrics;
    metrics["frames_with_pose"] = tracking_->framesWithPose();
    if (options_.ground_truth) {
        metrics["pose_error"] = tracking_->poseErrors().json();
        metrics["frames_without_truth"] = tracking_->framesWithoutTruth();
    }
    if (lighting_) {
        metrics["lighting"] = lighting_->metricsJson();
        if (pacer_) metrics["lighting"]["pacing"] = pacer_->json();
    }
    if (compositor_) {
        nlohmann::json c;
        c["frames"] = processed_;
        // Real time: frames tracked while the compositor was busy, replaced by newer ones before it
        // took them (newest wins between the pipeline thread and the main thread).
        c["threads"] = options_.sync              ? "in order (sync)"
                       : options_.pipeline_thread ? "pipeline thread + main thread"
                                                  : "one thread";
        if (loop_stats_) c["replaced"] = loop_stats_->replaced;
        c["msaa_samples"] = compositor_->options().msaa_samples;
        if (governor_) c["quality"] = governor_->json();
        c["renderer"] = context_->renderer();
        if (lag_ms_.count() > 0) {
            const Percentiles lag = lag_ms_.percentiles();
            c["lighting_lag_ms"] = {{"p50", lag.p50}, {"p95", lag.p95}, {"max", lag.max}};
        }
        if (latency_ms_.count() > 0) {
            const Percentiles latency = latency_ms_.percentiles();
            c["latency_ms"] = {{"p50", latency.p50}, {"p95", latency.p95}, {"max", latency.max}};
        }
        if (lag_frames_.count() > 0) {
            const Percentiles lag = lag_frames_.percentiles();
            c["lighting_lag_frames"] = {{"p50", lag.p50}, {"p95", lag.p95}, {"max", lag.max}};
        }
        metrics["compositor"] = c;
        if (measurer_ && measurer_->errors().frames() > 0) {
            metrics["composite_error"] = measurer_->errors().json();
            // Real time: composites left unmeasured because the measurement was behind.
            metrics["composite_error"]["unmeasured"] = measurer_->unmeasured();
        }
    }
    return metrics;
}

std::string FrameRunner::summary() const {
    std::string text;
    if (tracking_->poseErrors().count() > 0) text += tracking_->poseErrors().summary() + "\n";
    if (lighting_) text += lighting_->summary() + "\n";
    if (pacer_ && lighting_) text += "lighting pace: " + pacer_->summary() + "\n";
    if (governor_ && processed_ > 0) text += "compositor quality: " + governor_->summary() + "\n";
    if (measurer_ && measurer_->errors().frames() > 0) {
        const nlohmann::json e = measurer_->errors().json();
        char line[256];
        std::snprintf(line, sizeof line,
                      "composite against ground truth (%zu frames): PSNR %.2f dB; linear RMSE %.4f (frame), %.4f (where the virtual objects change it)\n",
                      measurer_->errors().frames(), e["psnr_db"].get<double>(), e["rmse_linear"].get<double>(),
                      e["rmse_linear_changed"].get<double>());
        text += line;
        if (measurer_->unmeasured() > 0) {
            text += "  (" + std::to_string(measurer_->unmeasured()) + " composites not measured: the measurement fell behind)\n";
        }
    }
    return text;
}

}  // namespace commonlight::pipeline

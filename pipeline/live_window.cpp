#include "pipeline/live_window.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <thread>

#include "core/clock.h"
#include "core/log.h"

namespace commonlight::pipeline {

namespace fs = std::filesystem;

namespace {

// GLFW key codes (GLFW/glfw3.h; render/ keeps GLFW to itself).
constexpr int kKeySpace = 32, kKeyD = 'D', kKeyL = 'L', kKeyR = 'R', kKeyS = 'S', kKeyTab = 258;
constexpr int kKeyRight = 262, kKeyLeft = 263, kKeyDown = 264, kKeyUp = 265, kKeyPageUp = 266, kKeyPageDown = 267;

std::string format(const char* fmt, auto... args) {
    char text[256];
    std::snprintf(text, sizeof text, fmt, args...);
    return text;
}

}  // namespace

LiveWindow::LiveWindow(FrameRunner& runner, CameraSource& camera, const LiveWindowOptions& options)
    : runner_(&runner), camera_(&camera), window_(runner.glContext()), options_(options) {}

Result<std::unique_ptr<LiveWindow>> LiveWindow::create(FrameRunner& runner, CameraSource& camera, const LiveWindowOptions& options) {
    if (!runner.glContext() || runner.glContext()->kind() != render::ContextKind::kWindow || !runner.compositor()) {
        return fail(ErrorCode::kInternal, "live window: the runner composites into no window");
    }
    auto window = std::unique_ptr<LiveWindow>(new LiveWindow(runner, camera, options));
    CL_TRY(window->overlay_, render::Overlay::create(*runner.glContext()));
    if (camera.recording().on) window->recording_started_ns_ = monotonicNowNs();
    return window;
}

render::OverlayContent LiveWindow::overlayContent(const TrackedFrame* frame) const {
    render::OverlayContent content;
    const render::DebugView view = runner_->compositor()->options().debug;
    // fps and latency (frame arrival to composite ready), in ms and in frames.
    const FrameRunner::CompositeInfo& info = runner_->lastComposite();
    const double period_ms = frame && frame->frame_period_ns > 0.0 ? frame->frame_period_ns / 1e6 : 0.0;
    const double fps = interval_ns_ > 0.0 ? 1e9 / interval_ns_ : 0.0;
    content.lines.push_back(period_ms > 0.0 ? format("%.1f fps, latency %.0f ms (%.1f frames)", fps, info.latency_ms, info.latency_ms / period_ms)
                                            : format("%.1f fps, latency %.0f ms", fps, info.latency_ms));
    // Tracking.
    if (frame) {
        content.lines.push_back(format("tracking: %s, %zu tag%s", tracking::trackStatusName(frame->track.status),
                                       frame->track.tags.size(), frame->track.tags.size() == 1 ? "" : "s"));
    } else {
        content.lines.push_back("tracking: no frame yet");
    }
    // Lighting: the snapshot drawn with and how old its frame is.
    if (!runner_->lighting()) {
        content.lines.push_back("lighting: none (no real proxies, or --no-lighting)");
    } else if (info.lighting_version == 0) {
        content.lines.push_back(lighting_shown_ ? "lighting: waiting for the first update" : "lighting: off (l)");
    } else {
        std::string line = format("lighting: v%llu", static_cast<unsigned long long>(info.lighting_version));
        if (info.lighting_lag_frames) {
            line += format(", lag %.1f frames", *info.lighting_lag_frames);
        } else if (info.lighting_lag_ms) {
            line += format(", lag %.0f ms", *info.lighting_lag_ms);
        }
        if (!lighting_shown_) line += " (off: l)";
        content.lines.push_back(line);
    }
    // Stage times.
    const capture::StageTimings& timings = runner_->timings();
    content.lines.push_back(format("pipeline %.0f ms, composite %.0f ms (p50)", timings.percentiles(timings.id("pipeline")).p50,
                                   timings.percentiles(timings.id("composite")).p50));
    content.lines.push_back(std::string("view: ") + render::debugViewName(view) + (paused_ ? "  [paused]" : ""));
    // The camera.
    const CameraState camera = camera_->state();
    switch (camera.kind) {
        case CameraState::Kind::kStreaming:
            content.lines.push_back(camera.reconnects == 0 ? std::string("camera: streaming")
                                                           : format("camera: streaming (reconnected %llu times)",
                                                                    static_cast<unsigned long long>(camera.reconnects)));
            break;
        case CameraState::Kind::kReconnecting:
            content.lines.push_back(format("camera lost: reconnecting (attempt %d)", camera.attempts + 1));
            content.banner = "camera lost: reconnecting";
            content.banner_detail = format("attempt %d, back-off %.2f s: ", camera.attempts + 1, camera.next_attempt_s) + camera.lost_reason;
            break;
        case CameraState::Kind::kGone:
            content.lines.push_back("camera lost");
            content.banner = "camera lost";
            content.banner_detail = camera.lost_reason;
            break;
    }
    // Recording.
    const RecordingState recording = camera_->recording();
    if (recording.on) {
        content.recording = true;
        const double seconds = recording_started_ns_ > 0 ? static_cast<double>(monotonicNowNs() - recording_started_ns_) / 1e9 : 0.0;
        content.recording_text = format("REC %.0f s, %llu frames", seconds, static_cast<unsigned long long>(recording.frames));
    }
    // The tag detections view: each tag's corners and id, as the tracker found them.
    if (view == render::DebugView::kTags && frame) {
        content.image_width = runner_->camera().width;
        content.image_height = runner_->camera().height;
        for (const tracking::TrackedTag& tag : frame->track.tags) {
            render::OverlayTag t;
            t.corners_px = tag.detection.corners;
            t.id = tag.detection.id;
            const auto& items = runner_->scene().tags.items;
            t.in_scene = std::any_of(items.begin(), items.end(), [&](const auto& item) { return item.id == tag.detection.id; });
            content.tags.push_back(t);
        }
    }
    return content;
}

bool LiveWindow::onFrame(const TrackedFrame& frame) {
    const std::int64_t now = monotonicNowNs();
    if (last_frame_ns_ > 0) {
        const double interval = static_cast<double>(now - last_frame_ns_);
        interval_ns_ = interval_ns_ > 0.0 ? 0.8 * interval_ns_ + 0.2 * interval : interval;
    }
    last_frame_ns_ = now;
    if (!show(&frame, true)) return false;
    // Paused: the same frame stays, keys still work (moves redraw it), until space again.
    while (paused_) {
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
        bool fresh = false;
        if (redraw_) {
            redraw_ = false;
            if (auto drawn = runner_->redraw(frame); !drawn) log::warning("redraw: " + drawn.error().message);
            fresh = true;
        }
        if (!show(&frame, fresh)) return false;
    }
    last_frame_ns_ = monotonicNowNs();  // a pause is not a slow frame
    return true;
}

bool LiveWindow::onIdle(const TrackedFrame* last) {
    bool fresh = false;
    if (redraw_ && last) {
        redraw_ = false;
        if (auto drawn = runner_->redraw(*last); !drawn) log::warning("redraw: " + drawn.error().message);
        fresh = true;
    }
    return show(last, fresh);
}

bool LiveWindow::show(const TrackedFrame* frame, bool fresh_composite) {
    // Step 1: the picture under the overlay: the composite just drawn, or the last one again (the
    // window's back buffer is undefined after a swap).
    if (!fresh_composite) {
        const Image& last = runner_->compositeImage();
        if (last.empty()) {
            overlay_->clearWindow();
        } else if (auto drawn = overlay_->drawImageOnWindow(last.view()); !drawn) {
            log::warning("overlay: " + drawn.error().message);
        }
    }
    // Step 2: the overlay, window only (the composite that goes to files is the compositor's).
    if (auto drawn = overlay_->drawOnWindow(overlayContent(frame)); !drawn) log::warning("overlay: " + drawn.error().message);
    // Step 3: the keys (a screenshot reads the back buffer: what is about to be shown).
    for (int key : window_->pollKeys()) handleKey(key);
    if (window_->shouldClose()) return false;
    // Step 4: the title keeps the figures too.
    const FrameRunner::CompositeInfo& info = runner_->lastComposite();
    const Percentiles pipeline = runner_->timings().percentiles(runner_->timings().id("pipeline"));
    std::string title = format("commonlight | %s | %.1f fps | pipeline p50 %.0f ms | lighting v%llu%s | %s",
                               frame ? tracking::trackStatusName(frame->track.status) : "no frame",
                               interval_ns_ > 0.0 ? 1e9 / interval_ns_ : 0.0, pipeline.p50,
                               static_cast<unsigned long long>(info.lighting_version), lighting_shown_ ? "" : " (off)",
                               render::debugViewName(runner_->compositor()->options().debug));
    if (camera_->state().kind != CameraState::Kind::kStreaming) title += " | camera lost";
    if (camera_->recording().on) title += " | REC";
    window_->setTitle(title);
    window_->present();
    return true;
}

void LiveWindow::handleKey(int key) {
    const double step = 0.01;  // metres
    Eigen::Vector3d move = Eigen::Vector3d::Zero();
    switch (key) {
        case kKeySpace:
            paused_ = !paused_;
            log::info(paused_ ? "paused" : "resumed");
            break;
        case kKeyL:
            lighting_shown_ = !lighting_shown_;
            runner_->setLightingShown(lighting_shown_);
            log::info(std::string("lighting ") + (lighting_shown_ ? "on" : "off"));
            redraw_ = true;
            break;
        case kKeyD: {
            render::CompositorOptions o = runner_->compositor()->options();
            o.debug = render::nextDebugView(o.debug);
            runner_->compositor()->setOptions(o);
            log::info(std::string("view: ") + render::debugViewName(o.debug));
            redraw_ = true;
            break;
        }
        case kKeyR: toggleRecording(); break;
        case kKeyS: screenshot(); break;
        case kKeyTab:
            if (!runner_->scene().virtual_objects.empty()) {
                selected_ = (selected_ + 1) % runner_->scene().virtual_objects.size();
                log::info("selected: " + runner_->scene().virtual_objects[selected_].name);
            }
            break;
        case kKeyRight: move.x() = step; break;
        case kKeyLeft: move.x() = -step; break;
        case kKeyUp: move.y() = step; break;
        case kKeyDown: move.y() = -step; break;
        case kKeyPageUp: move.z() = step; break;
        case kKeyPageDown: move.z() = -step; break;
        default: break;
    }
    if (!move.isZero()) {
        runner_->moveVirtualObject(selected_, move);
        redraw_ = true;
    }
}

void LiveWindow::toggleRecording() {
    if (camera_->recording().on) {
        if (std::optional<capture::RecorderSummary> summary = camera_->stopRecording()) {
            log::info(format("recording stopped: %zu frames written to %s (dropped by the recorder %llu, refused by the sequence %llu)",
                             summary->frames_written, summary->root.c_str(), static_cast<unsigned long long>(summary->dropped),
                             static_cast<unsigned long long>(summary->rejected)));
            if (summary->write_error) log::error("recording: " + summary->write_error->message);
        }
        return;
    }
    const fs::path folder = freeRecordingFolder(options_.record);
    if (auto started = camera_->startRecording(folder, options_.sensor); !started) {
        log::error("cannot record: " + started.error().message);
        return;
    }
    recording_started_ns_ = monotonicNowNs();
    log::info("recording to " + folder.string());
}

void LiveWindow::screenshot() {
    auto shot = window_->readWindow();
    const fs::path file = options_.screenshots / ("screenshot-" + std::to_string(screenshot_count_++) + ".png");
    if (shot && writePng(file, shot->view())) {
        log::info("screenshot: " + file.string());
    } else {
        log::warning("cannot write the screenshot " + file.string());
    }
}

}  // namespace commonlight::pipeline

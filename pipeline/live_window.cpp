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
constexpr int kKeySpace = 32, kKeyD = 'D', kKeyL = 'L', kKeyS = 'S', kKeyTab = 258;
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
    return std::unique_ptr<LiveWindow>(new LiveWindow(runner, camera, options));
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
    // Step 1: the keys (a screenshot reads the back buffer: the composite about to be shown).
    for (int key : window_->pollKeys()) handleKey(key);
    if (window_->shouldClose()) return false;
    // Step 2: the figures, in the title; a fresh composite is shown.
    const FrameRunner::CompositeInfo& info = runner_->lastComposite();
    const capture::Percentiles pipeline = runner_->timings().percentiles(runner_->timings().id("pipeline"));
    std::string title = format("commonlight | %s | %.1f fps | pipeline p50 %.0f ms | lighting v%llu%s | %s",
                               frame ? tracking::trackStatusName(frame->track.status) : "no frame",
                               interval_ns_ > 0.0 ? 1e9 / interval_ns_ : 0.0, pipeline.p50,
                               static_cast<unsigned long long>(info.lighting_version), lighting_shown_ ? "" : " (off)",
                               render::debugViewName(runner_->compositor()->options().debug));
    if (camera_->state().kind != CameraState::Kind::kStreaming) title += " | camera lost";
    if (camera_->recording().on) title += " | REC";
    window_->setTitle(title);
    if (fresh_composite) window_->present();
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

// The live window (`live` without --headless): the composite, the figures in the title (fps,
// tracking state, pipeline time, lighting version, the view, the camera's state), and the keys
// (docs/cli.md):
//
//   space pause / resume          l lighting on / off           d next debug view
//   s screenshot of the window    tab select the next virtual object
//   arrows, page up / down: move the selected virtual object 1 cm along world x, y, z
//
// Main thread (it owns GL): onFrame() and onIdle() are FrameRunner::run()'s callbacks.
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>

#include "core/sequence_io.h"
#include "pipeline/camera_source.h"
#include "pipeline/runner.h"

namespace commonlight::pipeline {

struct LiveWindowOptions {
    std::filesystem::path screenshots;  // folder of key s's screenshots
};

class LiveWindow {
public:
    // The runner's context must be a window.
    static Result<std::unique_ptr<LiveWindow>> create(FrameRunner& runner, CameraSource& camera, const LiveWindowOptions& options);

    // After each composite: the keys, the title; while paused, waits here. False when the window
    // was closed.
    bool onFrame(const TrackedFrame& frame);
    // No new frame for a while (the camera is lost, or slow): the keys and the title. False when
    // the window was closed.
    bool onIdle(const TrackedFrame* last);

private:
    LiveWindow(FrameRunner& runner, CameraSource& camera, const LiveWindowOptions& options);
    // Reads the keys, sets the title and presents a fresh composite. False when the window was
    // closed.
    bool show(const TrackedFrame* frame, bool fresh_composite);
    void handleKey(int key);
    void screenshot();

    FrameRunner* runner_;
    CameraSource* camera_;
    render::GlContext* window_;
    LiveWindowOptions options_;
    std::size_t selected_ = 0;
    bool lighting_shown_ = true;
    bool paused_ = false;
    bool redraw_ = false;  // a key changed what the composite shows
    int screenshot_count_ = 0;
    std::int64_t last_frame_ns_ = 0;  // monotonic time of the last composite shown
    double interval_ns_ = 0.0;        // between composites, smoothed (fps = 1e9 / interval)
};

}  // namespace commonlight::pipeline

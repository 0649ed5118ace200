// The live window (`live` without --headless): the composite with its overlay (render/overlay.h:
// fps, latency, tracking state, lighting version and lag, the view, recording, the camera's
// state), the figures in the title too, and the keys (docs/cli.md):
//
//   space pause / resume          l lighting on / off           d next debug view
//   r start / stop recording      s screenshot of the window    tab select the next virtual object
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
#include "render/overlay.h"

namespace commonlight::pipeline {

struct LiveWindowOptions {
    std::filesystem::path screenshots;  // folder of key s's screenshots
    std::filesystem::path record;       // where key r records (a free name beside it when taken)
    SensorInfo sensor;                  // sensor.yaml of a recording
};

class LiveWindow {
public:
    // The runner's context must be a window. Errors: the overlay's GL objects (kDevice).
    static Result<std::unique_ptr<LiveWindow>> create(FrameRunner& runner, CameraSource& camera, const LiveWindowOptions& options);

    // After each composite: the overlay, the keys, the title; while paused, waits here. False
    // when the window was closed.
    bool onFrame(const TrackedFrame& frame);
    // No new frame for a while (the camera is lost, or slow): the last composite again with the
    // overlay as it is now, and the keys. False when the window was closed.
    bool onIdle(const TrackedFrame* last);

    // The overlay's contents for this frame (null: none yet), as drawn.
    render::OverlayContent overlayContent(const TrackedFrame* frame) const;

private:
    LiveWindow(FrameRunner& runner, CameraSource& camera, const LiveWindowOptions& options);
    // Draws the overlay (over the fresh composite, or over the last one redrawn), reads the keys,
    // sets the title and presents. False when the window was closed.
    bool show(const TrackedFrame* frame, bool fresh_composite);
    void handleKey(int key);
    void toggleRecording();
    void screenshot();

    FrameRunner* runner_;
    CameraSource* camera_;
    render::GlContext* window_;
    LiveWindowOptions options_;
    std::unique_ptr<render::Overlay> overlay_;
    std::size_t selected_ = 0;
    bool lighting_shown_ = true;
    bool paused_ = false;
    bool redraw_ = false;  // a key changed what the composite shows
    int screenshot_count_ = 0;
    std::int64_t last_frame_ns_ = 0;  // monotonic time of the last composite shown
    double interval_ns_ = 0.0;        // between composites, smoothed (fps = 1e9 / interval)
    std::int64_t recording_started_ns_ = 0;
};

}  // namespace commonlight::pipeline

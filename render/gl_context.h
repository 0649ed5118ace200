// A GL context to composite in: a GLFW window (OpenGL 3.3 core) when a display is there, or an
// offscreen context on EGL's surfaceless platform (Mesa), which needs neither a display nor a GPU.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "core/image.h"
#include "core/result.h"

namespace commonlight::render {

enum class ContextKind { kOffscreen, kWindow };

struct ContextOptions {
    ContextKind kind = ContextKind::kOffscreen;
    int width = 640;   // window size (the compositor renders at the camera's size and scales)
    int height = 480;
    std::string title = "commonlight";
};

class GlContext {
public:
    // Errors (kDevice, exit 4) name what is missing: no display for a window (DISPLAY and
    // WAYLAND_DISPLAY unset, or GLFW cannot open it), no EGL surfaceless platform, no GL 3.3 core.
    static Result<std::unique_ptr<GlContext>> create(const ContextOptions& options);
    ~GlContext();
    GlContext(const GlContext&) = delete;
    GlContext& operator=(const GlContext&) = delete;

    ContextKind kind() const noexcept { return kind_; }
    void makeCurrent();
    bool shouldClose() const;       // the window was closed (always false offscreen)
    void present();                 // swaps the window's buffers; nothing offscreen
    std::vector<int> pollKeys();    // GLFW key codes pressed since the last call (window)
    void windowSize(int& width, int& height) const;  // framebuffer size (offscreen: the options')
    std::string renderer() const;   // GL_RENDERER
    void setTitle(const std::string& title);  // window title (the live overlay's figures)
    // What the window shows (its back buffer before present()), RGB8 top row first: screenshots.
    // kUnsupported offscreen.
    Result<Image> readWindow() const;

private:
    GlContext() = default;
    struct Impl;
    std::unique_ptr<Impl> impl_;
    ContextKind kind_ = ContextKind::kOffscreen;
};

}  // namespace commonlight::render

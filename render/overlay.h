// The live window's overlay: a panel of figures (fps, latency, tracking, lighting, camera), a
// recording mark, a warning banner (camera lost) and, in the tag-detections debug view, the tags'
// corners and ids, blended over the composite in the window after the compositor drew it.
//
// The text and lines are drawn by OpenCV (cv::putText, cv::polylines) into an RGBA image the size
// of the target, premultiplied by alpha (anti-aliased edges blend correctly), uploaded as a GL
// texture and blended over the target with (1, 1 - alpha). The overlay only ever draws into the
// window's framebuffer: the compositor's own output (Compositor::read(), the frames written to
// disk) never contains it.
//
// Threads: the thread that owns the GL context, which must be current.
#pragma once

#include <array>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/image.h"
#include "core/result.h"
#include "render/gl_context.h"

namespace commonlight::render {

// A detected tag in the camera image: its corners (distorted pixels, OpenCV convention: the
// centre of the top-left pixel is (0, 0)) in the detector's order, and its id.
struct OverlayTag {
    std::array<Eigen::Vector2d, 4> corners_px;
    int id = -1;
    bool in_scene = true;  // false: a tag the scene does not place (drawn in another colour)
};

struct OverlayContent {
    std::vector<std::string> lines;  // the panel, top left, one figure per line
    std::string banner;              // a warning across the middle (camera lost); empty: none
    std::string banner_detail;       // a smaller second line under it
    bool recording = false;          // a red dot and `recording_text`, top right
    std::string recording_text;
    std::vector<OverlayTag> tags;    // drawn when non-empty
    int image_width = 0;             // the camera image the tags' corners are in (scaled to the
    int image_height = 0;            // target); 0: the target's size
};

class Overlay {
public:
    // The shader and the texture (errors kDevice: the GL cannot make them).
    static Result<std::unique_ptr<Overlay>> create(GlContext& context);
    // Deletes its GL objects (the context must still be alive and current).
    ~Overlay();
    Overlay(const Overlay&) = delete;
    Overlay& operator=(const Overlay&) = delete;

    // Rasterises `content` at `width` x `height` and blends it over the framebuffer `target`
    // (0: the window's back buffer), which is that size.
    Result<void> draw(const OverlayContent& content, unsigned target, int width, int height);
    // Fills `target` with an RGB8 image scaled to it: the last composite, when there is no new
    // frame to composite (the camera is lost) but the overlay must change.
    Result<void> drawImage(const ImageView& rgb8, unsigned target, int width, int height);
    // In the window: draw(content) over the window's back buffer at its framebuffer size.
    Result<void> drawOnWindow(const OverlayContent& content);
    Result<void> drawImageOnWindow(const ImageView& rgb8);
    // Black under the overlay before there is any composite to show.
    void clearWindow();

    // The last rasterised overlay: RGBA8, premultiplied, top row first (tests).
    const Image& rasterised() const noexcept { return rgba_; }

private:
    Overlay() = default;
    Result<void> blit(unsigned texture, bool blend, unsigned target, int width, int height);

    GlContext* context_ = nullptr;
    unsigned program_ = 0;
    unsigned vao_ = 0;
    unsigned overlay_texture_ = 0;
    unsigned image_texture_ = 0;
    int overlay_w_ = 0, overlay_h_ = 0;  // the overlay texture's size
    int image_w_ = 0, image_h_ = 0;
    Image rgba_;
};

// Rasterises `content` into an RGBA8 image (premultiplied alpha) of `width` x `height`, reusing
// `out`'s buffer. No GL: Overlay::draw uses it, and tests check it directly.
void rasteriseOverlay(const OverlayContent& content, int width, int height, Image& out);

}  // namespace commonlight::render

// The live window's overlay (render/overlay.h): the rasterised RGBA image (premultiplied alpha,
// nothing outside what it draws, the tags' corners where the camera image has them after scaling),
// its blending over a framebuffer (untouched pixels keep their value exactly, the translucent
// panel darkens by its alpha), an image drawn as is, no leaked GL objects, and in a window (under
// Xvfb) the compositor's own output stays clean of it. Offscreen tests skip (77) without EGL.
#include "render/overlay.h"

#include <gtest/gtest.h>

#define GL_GLEXT_PROTOTYPES
#include <GL/glcorearb.h>

#include <cmath>
#include <cstdlib>

#include "render/compositor.h"
#include "tests/render/gl_suite.h"

namespace commonlight::render {
namespace {

const std::uint8_t* px(const Image& image, int x, int y) { return image.view().row(y) + 4 * x; }

OverlayContent panel() {
    OverlayContent c;
    c.lines = {"12.3 fps, latency 45 ms (1.4 frames)", "tracking: tracked, 4 tags", "lighting: v12, lag 1.0 frames"};
    return c;
}

TEST(OverlayRaster, NothingDrawnIsTransparentAndEveryPixelIsPremultiplied) {
    Image image;
    rasteriseOverlay(OverlayContent{}, 64, 48, image);
    ASSERT_EQ(image.format(), PixelFormat::kRgba8);
    for (int y = 0; y < 48; ++y) {
        for (int x = 0; x < 64; ++x) ASSERT_EQ(px(image, x, y)[3], 0);
    }
    OverlayContent all = panel();
    all.banner = "camera lost: reconnecting";
    all.banner_detail = "attempt 2, back-off 0.50 s: replay:x: device disconnected";
    all.recording = true;
    all.recording_text = "REC 3 s, 90 frames";
    rasteriseOverlay(all, 640, 480, image);
    int white = 0, banner_red = 0, rec_red = 0;
    for (int y = 0; y < 480; ++y) {
        for (int x = 0; x < 640; ++x) {
            const std::uint8_t* p = px(image, x, y);
            ASSERT_LE(p[0], p[3]);
            ASSERT_LE(p[1], p[3]);
            ASSERT_LE(p[2], p[3]);
            if (p[0] > 240 && p[1] > 240 && p[2] > 240) ++white;
            if (p[3] == 215 && p[0] > 150 && p[1] < 30) ++banner_red;
            if (p[3] == 255 && p[0] > 200 && p[1] < 40 && x > 400 && y < 60) ++rec_red;
        }
    }
    EXPECT_GT(white, 500) << "the panel's and banner's text";
    EXPECT_GT(banner_red, 10000) << "the banner's box";
    EXPECT_GT(rec_red, 20) << "the recording dot";
    // The panel sits top left; the middle of the picture is the banner's; the bottom-left corner
    // is untouched.
    EXPECT_EQ(px(image, 8, 12)[3], 150);
    EXPECT_EQ(px(image, 5, 470)[3], 0);
    EXPECT_EQ(px(image, 635, 470)[3], 0);
}

// A long reason (a device path) is wrapped onto more lines inside the banner, not cut at the edge.
TEST(OverlayRaster, TheBannersDetailIsWrappedToTheWidth) {
    const auto banner_rows = [](const std::string& detail) {
        OverlayContent content;
        content.banner = "camera lost: reconnecting";
        content.banner_detail = detail;
        Image image;
        rasteriseOverlay(content, 320, 240, image);
        int rows = 0;
        for (int y = 0; y < 240; ++y) rows += px(image, 160, y)[3] >= 215;
        return rows;
    };
    const int one_line = banner_rows("attempt 2: cam0 lost");
    const int wrapped = banner_rows(
        "attempt 2, back-off 0.50 s: replay:/tmp/some/very/long/folder/name/of/a/recording: device disconnected (fault injection)");
    const int line_h = static_cast<int>(std::lround(36.0 * 0.3));  // the raster's line height at 240 rows
    EXPECT_GE(wrapped - one_line, 2 * line_h - 1) << one_line << " rows for one line, " << wrapped << " wrapped";
}

// A tag in a 320x240 camera image drawn on a 640x480 target: its edges pass where the corners
// land after scaling ((x + 0.5) * 2 - 0.5), and nowhere near the old, unscaled place.
TEST(OverlayRaster, TagCornersAreScaledFromTheCameraImageToTheTarget) {
    OverlayContent content;
    content.image_width = 320;
    content.image_height = 240;
    OverlayTag tag;
    tag.corners_px = {Eigen::Vector2d(100, 150), Eigen::Vector2d(200, 150), Eigen::Vector2d(200, 50), Eigen::Vector2d(100, 50)};
    tag.id = 7;
    content.tags.push_back(tag);
    Image image;
    rasteriseOverlay(content, 640, 480, image);
    // The middle of the bottom edge: (150, 150) -> (300.5, 300.5).
    const auto green = [&](int x, int y) {
        const std::uint8_t* p = px(image, x, y);
        return p[3] > 200 && p[1] > 200 && p[0] < 120;
    };
    bool on_edge = false;
    for (int dy = -1; dy <= 1; ++dy) on_edge = on_edge || green(300, 300 + dy) || green(301, 300 + dy);
    EXPECT_TRUE(on_edge);
    // The left edge's middle (100, 100) -> (200.5, 200.5); right edge (200, 100) -> (400.5, 200.5).
    EXPECT_TRUE(green(200, 200) || green(201, 200));
    EXPECT_TRUE(green(400, 200) || green(401, 200));
    // Unscaled, the bottom edge would be at y 150: nothing there.
    EXPECT_EQ(px(image, 150, 150)[3], 0);
    // The id is written near the centre (300.5, 200.5).
    int id_pixels = 0;
    for (int y = 185; y < 215; ++y) {
        for (int x = 285; x < 315; ++x) id_pixels += px(image, x, y)[3] > 0;
    }
    EXPECT_GT(id_pixels, 30);
}

class OverlayGl : public GlSuite {
protected:
    // An RGBA8 framebuffer of w x h filled with `fill`.
    struct Target {
        GLuint fbo = 0, texture = 0;
        int w = 0, h = 0;
        ~Target() {
            glDeleteFramebuffers(1, &fbo);
            glDeleteTextures(1, &texture);
        }
        std::vector<std::uint8_t> read() const {
            std::vector<std::uint8_t> out(static_cast<std::size_t>(w * h * 4));
            glBindFramebuffer(GL_READ_FRAMEBUFFER, fbo);
            glPixelStorei(GL_PACK_ALIGNMENT, 1);
            glReadPixels(0, 0, w, h, GL_RGBA, GL_UNSIGNED_BYTE, out.data());
            glBindFramebuffer(GL_READ_FRAMEBUFFER, 0);
            return out;
        }
        // The pixel at (x, y) counted from the top row.
        const std::uint8_t* at(const std::vector<std::uint8_t>& pixels, int x, int y) const {
            return pixels.data() + 4 * (static_cast<std::size_t>(h - 1 - y) * static_cast<std::size_t>(w) + static_cast<std::size_t>(x));
        }
    };
    static std::unique_ptr<Target> target(int w, int h, const std::array<float, 4>& fill) {
        auto t = std::make_unique<Target>();
        t->w = w;
        t->h = h;
        glGenTextures(1, &t->texture);
        glBindTexture(GL_TEXTURE_2D, t->texture);
        glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA8, w, h, 0, GL_RGBA, GL_UNSIGNED_BYTE, nullptr);
        glGenFramebuffers(1, &t->fbo);
        glBindFramebuffer(GL_FRAMEBUFFER, t->fbo);
        glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, t->texture, 0);
        glClearColor(fill[0], fill[1], fill[2], fill[3]);
        glClear(GL_COLOR_BUFFER_BIT);
        glBindFramebuffer(GL_FRAMEBUFFER, 0);
        return t;
    }
};

TEST_F(OverlayGl, BlendsOverTheTargetWithPremultipliedAlpha) {
    auto overlay = Overlay::create(*context_);
    ASSERT_TRUE(overlay) << overlay.error().message;
    auto t = target(320, 240, {100 / 255.0f, 150 / 255.0f, 200 / 255.0f, 1.0f});
    OverlayContent content = panel();
    ASSERT_TRUE((*overlay)->draw(content, t->fbo, t->w, t->h));
    const std::vector<std::uint8_t> pixels = t->read();
    const Image& raster = (*overlay)->rasterised();
    ASSERT_EQ(raster.width(), 320);
    int checked_clear = 0, checked_box = 0;
    for (int y = 0; y < t->h; ++y) {
        for (int x = 0; x < t->w; ++x) {
            const std::uint8_t* o = px(raster, x, y);
            const std::uint8_t* got = t->at(pixels, x, y);
            const double a = o[3] / 255.0;
            for (int k = 0; k < 3; ++k) {
                // out = overlay + (1 - alpha) target, in 8 bits.
                const double want = o[k] + (1.0 - a) * std::array<double, 3>{100, 150, 200}[k];
                ASSERT_NEAR(got[k], want, 1.0) << x << "," << y << " channel " << k;
            }
            if (o[3] == 0) {
                ++checked_clear;
                ASSERT_EQ(got[0], 100);
                ASSERT_EQ(got[1], 150);
                ASSERT_EQ(got[2], 200);
            }
            checked_box += o[3] == 150;
        }
    }
    EXPECT_GT(checked_clear, 30000);
    EXPECT_GT(checked_box, 3000);
}

TEST_F(OverlayGl, DrawsAnImageAsIsAndLeaksNoGlObjects) {
    const GlObjectCounts before = liveGlObjects();
    {
        auto overlay = Overlay::create(*context_);
        ASSERT_TRUE(overlay);
        Image image(PixelFormat::kRgb8, 64, 48);
        for (int y = 0; y < 48; ++y) {
            for (int x = 0; x < 64; ++x) {
                std::uint8_t* p = image.mutableView().row(y) + 3 * x;
                p[0] = static_cast<std::uint8_t>(4 * x);
                p[1] = static_cast<std::uint8_t>(5 * y);
                p[2] = 77;
            }
        }
        auto t = target(64, 48, {0, 0, 0, 1});
        ASSERT_TRUE((*overlay)->drawImage(image.view(), t->fbo, 64, 48));
        const std::vector<std::uint8_t> pixels = t->read();
        for (int y = 0; y < 48; ++y) {
            for (int x = 0; x < 64; ++x) {
                const std::uint8_t* got = t->at(pixels, x, y);
                ASSERT_EQ(got[0], 4 * x);
                ASSERT_EQ(got[1], 5 * y);
                ASSERT_EQ(got[2], 77);
            }
        }
        // A second draw at another size re-allocates the overlay's texture.
        ASSERT_TRUE((*overlay)->draw(panel(), t->fbo, 64, 48));
        ASSERT_TRUE((*overlay)->draw(panel(), t->fbo, 32, 24));
        EXPECT_FALSE((*overlay)->drawImage(ImageView{}, t->fbo, 64, 48));
        EXPECT_FALSE((*overlay)->draw(panel(), t->fbo, 0, 24));
    }
    EXPECT_EQ(liveGlObjects(), before);
}

// In a window (under Xvfb): the overlay is in what the window shows, not in the compositor's
// output (the frames written to disk).
TEST(OverlayWindow, TheWindowShowsItAndTheCompositeStaysClean) {
    if (std::getenv("DISPLAY") == nullptr) GTEST_SKIP() << "no DISPLAY (run under xvfb-run)";
    auto window = testWindow("overlay-test", 320, 240);
    ASSERT_TRUE(window) << window.error().message;
    CameraModel camera;
    camera.width = 320;
    camera.height = 240;
    camera.fx = camera.fy = 300;
    camera.cx = 159.5;
    camera.cy = 119.5;
    auto compositor = Compositor::create(**window, Scene{}, camera, ResponseCurve::linear(), {});
    ASSERT_TRUE(compositor) << compositor.error().message;
    auto overlay = Overlay::create(**window);
    ASSERT_TRUE(overlay) << overlay.error().message;
    Image frame(PixelFormat::kRgb8, 320, 240);
    for (int y = 0; y < 240; ++y) std::fill_n(frame.mutableView().row(y), 3 * 320, static_cast<std::uint8_t>(90));
    FrameInput in;
    in.image = frame.view();
    ASSERT_TRUE((*compositor)->draw(in, lighting::LightingSnapshot{}));
    auto clean = (*compositor)->read();
    ASSERT_TRUE(clean);
    ASSERT_TRUE((*overlay)->drawOnWindow(panel()));
    auto shown = (*window)->readWindow();
    ASSERT_TRUE(shown) << shown.error().message;
    auto after = (*compositor)->read();
    ASSERT_TRUE(after);
    // The composite is the frame, byte for byte, before and after the overlay.
    for (int y = 0; y < 240; ++y) {
        for (int x = 0; x < 3 * 320; ++x) {
            ASSERT_EQ(clean->view().row(y)[x], 90);
            ASSERT_EQ(after->view().row(y)[x], 90);
        }
    }
    // The window shows the panel: darker than the frame under its box, white text in it.
    int w = 0, h = 0;
    (*window)->windowSize(w, h);
    ASSERT_EQ(shown->width(), w);
    int darker = 0, white = 0;
    for (int y = 0; y < h / 4; ++y) {
        for (int x = 0; x < w / 2; ++x) {
            const std::uint8_t v = shown->view().row(y)[3 * x];
            darker += v < 60;
            white += v > 200;
        }
    }
    EXPECT_GT(darker, 500);
    EXPECT_GT(white, 50);
    EXPECT_EQ(shown->view().row(h - 2)[3 * (w - 2)], 90) << "the window elsewhere shows the composite";
    (*window)->present();
    overlay->reset();
    compositor->reset();
}

}  // namespace
}  // namespace commonlight::render

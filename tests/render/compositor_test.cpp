// The compositor on small hand-made scenes: an unchanged frame comes back byte for byte, the
// ratio and the differential rule on a proxy, 3D points land where CameraModel::project puts them
// through lens distortion, real proxies hide virtual objects, the shading's scale, shadow maps
// with real and virtual occluders, no leaked GL objects, bad input. Offscreen (EGL surfaceless);
// the window test needs a display (xvfb-run). Without any GL context the test exits 77 (skip).
#include "render/compositor.h"

#include <gtest/gtest.h>

#include "capture/convert.h"
#include "core/mesh_io.h"
#include "render/light_samples.h"
#include "tests/test_support.h"

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <limits>
#include <numbers>
#include <random>

namespace commonlight::render {
namespace {

CameraModel smallCamera(int w = 160, int h = 120) {
    CameraModel c;
    c.width = w;
    c.height = h;
    c.fx = c.fy = 0.9 * w;
    c.cx = 0.5 * w - 0.5 + 0.37;  // off-centre on purpose: the principal point must be honoured
    c.cy = 0.5 * h - 0.5 - 0.21;
    return c;
}

// Camera at (0, 0, 2) looking down -z (world z up), image x along world x.
Rigid3d lookingDown() {
    // cam_from_world: x_cam = x, y_cam = -y, z_cam = 2 - z.
    Eigen::Matrix3d r;
    r << 1, 0, 0, 0, -1, 0, 0, 0, -1;
    return Rigid3d(Eigen::Quaterniond(r), Eigen::Vector3d(0, 0, 2));
}

Image constantFrame(int w, int h, std::uint8_t value) {
    Image image(PixelFormat::kRgb8, w, h);
    for (int y = 0; y < h; ++y) std::fill_n(image.mutableView().row(y), 3 * w, value);
    return image;
}

Image noiseFrame(int w, int h, unsigned seed) {
    Image image(PixelFormat::kRgb8, w, h);
    std::mt19937 rng(seed);
    for (int y = 0; y < h; ++y) {
        for (int x = 0; x < 3 * w; ++x) image.mutableView().row(y)[x] = static_cast<std::uint8_t>(rng() & 0xff);
    }
    return image;
}

class CompositorTest : public ::testing::Test {
protected:
    static void SetUpTestSuite() {
        auto ctx = GlContext::create({});
        if (!ctx) {
            std::fprintf(stderr, "skipped: no offscreen GL context: %s\n", ctx.error().message.c_str());
            std::exit(77);
        }
        context_ = std::move(*ctx);
    }
    static void TearDownTestSuite() { context_.reset(); }
    static std::unique_ptr<GlContext> context_;

    std::unique_ptr<Compositor> make(const Scene& scene, const CameraModel& camera, const ResponseCurve& response,
                                     CompositorOptions options = {}) {
        auto c = Compositor::create(*context_, scene, camera, response, options);
        EXPECT_TRUE(c) << (c ? "" : c.error().message);
        return c ? std::move(*c) : nullptr;
    }
    static Image render(Compositor& c, const ImageView& frame, const std::optional<Rigid3d>& pose,
                        const lighting::LightingSnapshot& snapshot, std::vector<std::optional<Rigid3d>> poses = {},
                        double eg = 1.0) {
        FrameInput in;
        in.image = frame;
        in.cam_from_world = pose;
        in.virtual_poses = std::move(poses);
        in.exposure_gain = eg;
        auto drawn = c.draw(in, snapshot);
        EXPECT_TRUE(drawn) << (drawn ? "" : drawn.error().message);
        auto out = c.read();
        EXPECT_TRUE(out);
        return out ? std::move(*out) : Image();
    }
};
std::unique_ptr<GlContext> CompositorTest::context_;

RealObject floorPlane(double size = 4.0) {
    RealObject o;
    o.name = "floor";
    o.shape = PlaneShape{Eigen::Vector2d(size, size)};
    return o;
}

VirtualObject sphere(const std::string& name, double radius, const Eigen::Vector3d& at, const Eigen::Vector3d& albedo,
                     std::optional<Eigen::Vector3d> emission = std::nullopt) {
    VirtualObject v;
    v.name = name;
    v.shape = SphereShape{radius};
    v.material.albedo = albedo;
    v.emission = emission;
    v.placement = FixedPlacement{Rigid3d(Eigen::Quaterniond::Identity(), at)};
    return v;
}

// Nothing virtual and no modulation: every pixel keeps its code, whatever the response.
TEST_F(CompositorTest, AnUnchangedFrameComesBackByteForByte) {
    Scene scene;
    scene.real_objects.push_back(floorPlane());
    const CameraModel camera = smallCamera();
    const Image frame = noiseFrame(camera.width, camera.height, 5);
    for (const char* spec : {"srgb", "linear", "gamma:2.2"}) {
        auto response = ResponseCurve::parse(spec);
        ASSERT_TRUE(response);
        auto c = make(scene, camera, *response);
        ASSERT_TRUE(c);
        const Image out = render(*c, frame.view(), lookingDown(), lighting::LightingSnapshot{});
        int differing = 0;
        for (int y = 0; y < camera.height; ++y) {
            for (int x = 0; x < 3 * camera.width; ++x) differing += out.view().row(y)[x] != frame.view().row(y)[x] ? 1 : 0;
        }
        EXPECT_EQ(differing, 0) << spec;
        // Without a pose, too.
        const Image lost = render(*c, frame.view(), std::nullopt, lighting::LightingSnapshot{});
        EXPECT_EQ(std::memcmp(lost.view().row(0), frame.view().row(0), 3 * static_cast<std::size_t>(camera.width)), 0);
    }
}

// The bytes of a YUYV or NV12 frame, random (every code, the out-of-range ones included), rows
// padded by `padding` bytes, and the frame's view of them.
std::vector<std::uint8_t> randomYuv(PixelFormat format, int w, int h, std::size_t padding, unsigned seed) {
    std::vector<std::uint8_t> bytes(imageBytes(format, w, h, minStride(format, w) + padding));
    std::mt19937 rng(seed);
    for (auto& b : bytes) b = static_cast<std::uint8_t>(rng() & 0xff);
    return bytes;
}

ImageView yuvView(const std::vector<std::uint8_t>& bytes, PixelFormat format, int w, int h, std::size_t padding) {
    return ImageView{format, w, h, minStride(format, w) + padding, bytes.data(), bytes.size()};
}

// A YUYV or NV12 frame is converted in the final pass exactly as capture::PixelConverter converts
// it on the CPU (OpenCV's BT.601 limited range): nothing changed, the composite is that RGB image,
// within 1 code (measured: identical), with and without a pose, on padded rows too. With the
// background modulated and a virtual object in view, the composite of the raw frame is the
// composite of the converted frame.
TEST_F(CompositorTest, YuyvAndNv12FramesAreConvertedAsTheCpuConvertsThem) {
    const CameraModel camera = smallCamera();
    Scene scene;
    scene.real_objects.push_back(floorPlane());
    auto c = make(scene, camera, ResponseCurve::srgb());
    ASSERT_TRUE(c);
    capture::PixelConverter converter;
    for (PixelFormat format : {PixelFormat::kYuyv, PixelFormat::kNv12}) {
        for (std::size_t padding : {std::size_t{0}, std::size_t{12}}) {
            const std::vector<std::uint8_t> bytes = randomYuv(format, camera.width, camera.height, padding, 7u + static_cast<unsigned>(padding));
            const ImageView raw = yuvView(bytes, format, camera.width, camera.height, padding);
            Image rgb;
            ASSERT_TRUE(converter.convert(raw, PixelFormat::kRgb8, rgb));
            for (const std::optional<Rigid3d>& pose : {std::optional<Rigid3d>(lookingDown()), std::optional<Rigid3d>()}) {
                const Image out = render(*c, raw, pose, lighting::LightingSnapshot{});
                int worst = 0, differing = 0;
                for (int y = 0; y < camera.height; ++y) {
                    for (int x = 0; x < 3 * camera.width; ++x) {
                        const int d = std::abs(static_cast<int>(out.view().row(y)[x]) - static_cast<int>(rgb.view().row(y)[x]));
                        worst = std::max(worst, d);
                        differing += d != 0 ? 1 : 0;
                    }
                }
                EXPECT_LE(worst, 1) << pixelFormatName(format) << " padding " << padding;
                RecordProperty(std::string(pixelFormatName(format)) + "_codes_differing", differing);
            }
        }
    }
    // Something changes: the floor's left half at ratio 0.5, and a virtual ball.
    scene.virtual_objects.push_back(sphere("ball", 0.3, {0.5, 0.3, 0.3}, Eigen::Vector3d::Constant(0.5), Eigen::Vector3d::Constant(0.1)));
    lighting::LightingSnapshot snapshot;
    snapshot.version = 1;
    lighting::FaceModulation f;
    f.corners = {{-2, -2, 0}, {2, -2, 0}, {2, 2, 0}, {-2, 2, 0}};
    f.width = 2;
    f.height = 1;
    f.ratio = {lighting::Rgb::Constant(0.5f), lighting::Rgb::Constant(1.0f)};
    f.difference = {lighting::Rgb::Constant(-0.1f), lighting::Rgb::Zero()};
    f.original = {lighting::Rgb::Constant(0.5f), lighting::Rgb::Constant(0.5f)};
    f.mean_original = 0.5f;
    snapshot.faces.push_back(std::make_shared<const lighting::FaceModulation>(f));
    auto changed = make(scene, camera, ResponseCurve::srgb());
    ASSERT_TRUE(changed);
    for (PixelFormat format : {PixelFormat::kYuyv, PixelFormat::kNv12}) {
        const std::vector<std::uint8_t> bytes = randomYuv(format, camera.width, camera.height, 0, 11);
        const ImageView raw = yuvView(bytes, format, camera.width, camera.height, 0);
        Image rgb;
        ASSERT_TRUE(converter.convert(raw, PixelFormat::kRgb8, rgb));
        const Image from_raw = render(*changed, raw, lookingDown(), snapshot);
        const Image from_rgb = render(*changed, rgb.view(), lookingDown(), snapshot);
        int worst = 0, changed_pixels = 0;
        for (int y = 0; y < camera.height; ++y) {
            for (int x = 0; x < 3 * camera.width; ++x) {
                worst = std::max(worst, std::abs(static_cast<int>(from_raw.view().row(y)[x]) - static_cast<int>(from_rgb.view().row(y)[x])));
                changed_pixels += from_rgb.view().row(y)[x] != rgb.view().row(y)[x] ? 1 : 0;
            }
        }
        EXPECT_GT(changed_pixels, camera.width * camera.height / 4) << "the scene should change much of the frame";
        EXPECT_LE(worst, 1) << pixelFormatName(format);
    }
    // Odd sizes are bad input for these formats.
    const CameraModel odd = smallCamera(161, 120);
    auto c_odd = make(Scene{}, odd, ResponseCurve::srgb());
    ASSERT_TRUE(c_odd);
    std::vector<std::uint8_t> zeros(imageBytes(PixelFormat::kYuyv, 162, 120, minStride(PixelFormat::kYuyv, 162)));
    FrameInput in;
    in.image = ImageView{PixelFormat::kYuyv, 161, 120, minStride(PixelFormat::kYuyv, 162), zeros.data(), zeros.size()};
    auto drawn = c_odd->draw(in, lighting::LightingSnapshot{});
    ASSERT_FALSE(drawn);
    EXPECT_EQ(drawn.error().code, ErrorCode::kBadInput);
}

// A floor whose left half has ratio 0.5: those pixels' linear value halves; the right half is
// unchanged; where B~ is (nearly) zero the difference B - B~ is added instead (Debevec's rule).
TEST_F(CompositorTest, TheRatioDarkensAndTheDifferenceBrightensTheBackground) {
    Scene scene;
    scene.real_objects.push_back(floorPlane(4.0));
    const CameraModel camera = smallCamera();
    const ResponseCurve response = ResponseCurve::srgb();
    lighting::LightingSnapshot snapshot;
    snapshot.version = 1;
    lighting::FaceModulation f;
    f.object_index = 0;
    f.face = 0;
    f.corners = {{-2, -2, 0}, {2, -2, 0}, {2, 2, 0}, {-2, 2, 0}};
    f.width = 8;
    f.height = 8;
    for (int j = 0; j < 8; ++j) {
        for (int i = 0; i < 8; ++i) {
            const bool left = i < 4;
            const bool dark = j >= 5;  // top rows (y > 0.5 m): B~ = 0, a virtual light adds 0.1
            f.ratio.push_back(lighting::Rgb::Constant(left ? 0.5f : 1.0f));
            f.original.push_back(lighting::Rgb::Constant(dark ? 0.0f : 1.0f));
            f.difference.push_back(lighting::Rgb::Constant(dark ? 0.1f : (left ? -0.5f : 0.0f)));
            f.reflectance.push_back(lighting::Rgb::Constant(0.5f));
        }
    }
    f.mean_original = 0.75f;
    snapshot.faces.push_back(std::make_shared<const lighting::FaceModulation>(f));
    auto c = make(scene, camera, response);
    ASSERT_TRUE(c);
    const Image frame = constantFrame(camera.width, camera.height, 180);
    const Image out = render(*c, frame.view(), lookingDown(), snapshot);
    const double in_linear = response.toLinear(1, std::uint8_t{180});
    // World (x, y) to the pixel (looking down from 2 m): u = cx + fx x / 2, v = cy - fy y / 2.
    const auto at = [&](double x, double y) {
        const Eigen::Vector2d p = *camera.project(lookingDown().rotation * Eigen::Vector3d(x, y, 0) + lookingDown().translation);
        const std::uint8_t code = out.view().row(static_cast<int>(std::lround(p.y())))[3 * static_cast<int>(std::lround(p.x())) + 1];
        return static_cast<double>(response.toLinear(1, code));
    };
    EXPECT_NEAR(at(-0.6, 0.0), 0.5 * in_linear, 0.02 * in_linear);  // left: halved
    EXPECT_NEAR(at(0.6, 0.0), in_linear, 0.01 * in_linear);         // right: unchanged
    EXPECT_NEAR(at(0.6, 0.75), in_linear + 0.1, 0.02 * (in_linear + 0.1));  // B~ = 0: + (B - B~)
}

// A new snapshot whose faces keep their sizes uploads only the faces whose revision changed, into
// their place in the atlas: after a snapshot that darkens the left half, one that darkens the right
// half (a new revision) draws what a fresh compositor draws from it; the same revision again keeps
// what was uploaded (the renderer trusts it).
TEST_F(CompositorTest, AFaceWithANewRevisionIsUploadedAgainInItsPlace) {
    Scene scene;
    scene.real_objects.push_back(floorPlane(4.0));
    const CameraModel camera = smallCamera();
    const ResponseCurve response = ResponseCurve::srgb();
    const auto snapshotWith = [](bool left_dark, std::uint64_t version, std::uint64_t revision) {
        lighting::LightingSnapshot snapshot;
        snapshot.version = version;
        lighting::FaceModulation f;
        f.corners = {{-2, -2, 0}, {2, -2, 0}, {2, 2, 0}, {-2, 2, 0}};
        f.width = 8;
        f.height = 8;
        for (int j = 0; j < 8; ++j) {
            for (int i = 0; i < 8; ++i) {
                const bool dark = (i < 4) == left_dark;
                f.ratio.push_back(lighting::Rgb::Constant(dark ? 0.5f : 1.0f));
                f.original.push_back(lighting::Rgb::Constant(1.0f));
                f.difference.push_back(lighting::Rgb::Constant(dark ? -0.5f : 0.0f));
                f.reflectance.push_back(lighting::Rgb::Constant(0.5f));
            }
        }
        f.mean_original = 1.0f;
        f.revision = revision;
        snapshot.faces.push_back(std::make_shared<const lighting::FaceModulation>(f));
        return snapshot;
    };
    const auto maxAbsDiff = [&](const ImageView& a, const ImageView& b) {
        int worst = 0;
        for (int y = 0; y < camera.height; ++y) {
            for (int x = 0; x < 3 * camera.width; ++x) worst = std::max(worst, std::abs(int{a.row(y)[x]} - int{b.row(y)[x]}));
        }
        return worst;
    };
    auto c = make(scene, camera, response);
    ASSERT_TRUE(c);
    auto fresh = make(scene, camera, response);
    ASSERT_TRUE(fresh);
    const Image frame = constantFrame(camera.width, camera.height, 180);
    const Image left = render(*c, frame.view(), lookingDown(), snapshotWith(true, 1, 1));
    const Image right = render(*c, frame.view(), lookingDown(), snapshotWith(false, 2, 2));
    const Image expected = render(*fresh, frame.view(), lookingDown(), snapshotWith(false, 1, 2));
    EXPECT_EQ(maxAbsDiff(right.view(), expected.view()), 0) << "uploaded again in place";
    EXPECT_GT(maxAbsDiff(left.view(), right.view()), 40) << "the shadow moved";
    const Image kept = render(*c, frame.view(), lookingDown(), snapshotWith(true, 3, 2));
    EXPECT_EQ(maxAbsDiff(kept.view(), right.view()), 0) << "an unchanged revision is not uploaded";
}

// A closed proxy is drawn without its back faces only when the camera is outside it: a room
// modelled as a box around the camera still gets its floor modulated (seen from inside, the floor
// turns its back to the camera), and a box seen from outside hides what is behind its front.
TEST_F(CompositorTest, AClosedProxyAroundTheCameraIsSeenFromInside) {
    const CameraModel camera = smallCamera();
    const ResponseCurve response = ResponseCurve::srgb();
    const Image frame = constantFrame(camera.width, camera.height, 180);
    const double in_linear = response.toLinear(1, std::uint8_t{180});
    const auto centreLinear = [&](const Image& out) {
        const std::uint8_t code = out.view().row(camera.height / 2)[3 * (camera.width / 2) + 1];
        return static_cast<double>(response.toLinear(1, code));
    };
    // Face 5 (-z) of a box, at z = `z`, 4 m wide, ratio `ratio` everywhere.
    const auto floorFace = [](double z, float ratio) {
        lighting::FaceModulation f;
        f.object_index = 0;
        f.face = 5;
        f.corners = {{-2, -2, z}, {2, -2, z}, {2, 2, z}, {-2, 2, z}};
        f.width = f.height = 4;
        for (int k = 0; k < 16; ++k) {
            f.ratio.push_back(lighting::Rgb::Constant(ratio));
            f.original.push_back(lighting::Rgb::Constant(1.0f));
            f.difference.push_back(lighting::Rgb::Constant(0.0f));
            f.reflectance.push_back(lighting::Rgb::Constant(0.5f));
        }
        f.mean_original = 1.0f;
        return f;
    };
    // The linear value at the image centre with one box proxy (size, centre height), its floor face
    // at z = 0 with ratio 0.5.
    const auto centreWithBox = [&](const Eigen::Vector3d& size, double centre_z) {
        Scene scene;
        RealObject box;
        box.name = "box";
        box.shape = BoxShape{size};
        box.world_from_object = Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0, 0, centre_z));
        scene.real_objects.push_back(box);
        lighting::LightingSnapshot snapshot;
        snapshot.version = 1;
        snapshot.faces.push_back(std::make_shared<const lighting::FaceModulation>(floorFace(0.0, 0.5f)));
        auto c = make(scene, camera, response);
        return c ? centreLinear(render(*c, frame.view(), lookingDown(), snapshot)) : -1.0;
    };
    // The room: 4 m on a side, floor at z = 0, the camera 2 m above it, inside: the floor halved.
    EXPECT_NEAR(centreWithBox(Eigen::Vector3d(4.0, 4.0, 4.0), 2.0), 0.5 * in_linear, 0.02 * in_linear);
    // A 1 m block below the camera, its bottom (ratio 0.5) behind its top (unmodulated).
    EXPECT_NEAR(centreWithBox(Eigen::Vector3d(4.0, 4.0, 1.0), 0.5), in_linear, 0.01 * in_linear);
}

// The final pass modulates only where the snapshot changes something: a 2 x 2 texel patch of
// ratio 0.5 near a corner of a strongly distorted view halves the frame there, every texel of it
// (the modulated region is not cut short), while every pixel away from it and from the virtual
// ball keeps its code byte for byte, also where a texel's ratio is 1.0015 (within the 2e-3
// that moves no code).
TEST_F(CompositorTest, TheModulationIsDrawnWhereTheSnapshotChangesSomethingAndOnlyThere) {
    Scene scene;
    scene.real_objects.push_back(floorPlane(4.0));
    scene.virtual_objects.push_back(sphere("ball", 0.1, Eigen::Vector3d(-0.3, 0.0, 0.1), Eigen::Vector3d(0.5, 0.5, 0.5)));
    CameraModel camera = smallCamera();
    camera.distortion.k1 = -0.25;
    camera.distortion.k2 = 0.08;
    const ResponseCurve response = ResponseCurve::srgb();
    lighting::LightingSnapshot snapshot;
    snapshot.version = 1;
    lighting::FaceModulation f;
    f.object_index = 0;
    f.face = 0;
    f.corners = {{-2, -2, 0}, {2, -2, 0}, {2, 2, 0}, {-2, 2, 0}};
    f.width = f.height = 32;  // 0.125 m a texel
    for (int j = 0; j < 32; ++j) {
        for (int i = 0; i < 32; ++i) {
            const bool patch = (i == 22 || i == 23) && (j == 20 || j == 21);  // x in [0.75, 1], y in [0.5, 0.75]
            const bool faint = i == 10 && j == 12;
            f.ratio.push_back(lighting::Rgb::Constant(patch ? 0.5f : faint ? 1.0015f : 1.0f));
            f.original.push_back(lighting::Rgb::Constant(1.0f));
            f.difference.push_back(lighting::Rgb::Constant(patch ? -0.5f : 0.0f));
            f.reflectance.push_back(lighting::Rgb::Constant(0.5f));
        }
    }
    f.mean_original = 1.0f;
    snapshot.faces.push_back(std::make_shared<const lighting::FaceModulation>(f));
    auto c = make(scene, camera, response);
    ASSERT_TRUE(c);
    const Image frame = noiseFrame(camera.width, camera.height, 11);
    const Image out = render(*c, frame.view(), lookingDown(), snapshot, {});
    // The pixel of a floor point, and the bounding box of a world rectangle's outline (sampled).
    const auto pixelOf = [&](double x, double y) {
        return *camera.project(lookingDown().rotation * Eigen::Vector3d(x, y, 0) + lookingDown().translation);
    };
    const auto box = [&](double x0, double y0, double x1, double y1) {
        Eigen::AlignedBox2d b;
        for (int k = 0; k <= 40; ++k) {
            const double t = k / 40.0;
            for (const Eigen::Vector2d& w : {Eigen::Vector2d(x0 + t * (x1 - x0), y0), Eigen::Vector2d(x0 + t * (x1 - x0), y1),
                                             Eigen::Vector2d(x0, y0 + t * (y1 - y0)), Eigen::Vector2d(x1, y0 + t * (y1 - y0))}) {
                b.extend(pixelOf(w.x(), w.y()));
            }
        }
        return b;
    };
    // Where the bilinear read of the patch can reach (one texel around it), and the ball's reach.
    const Eigen::AlignedBox2d reach = box(0.625, 0.375, 1.125, 0.875);
    const Eigen::AlignedBox2d ball = box(-0.45, -0.15, -0.15, 0.15);
    // Where it reads 0.5 alone: between the patch texels' centres.
    const Eigen::AlignedBox2d inner = box(0.8125, 0.5625, 0.9375, 0.6875);
    int unchanged_checked = 0, unchanged_differing = 0, halved_checked = 0, halved_wrong = 0;
    for (int y = 0; y < camera.height; ++y) {
        for (int x = 0; x < camera.width; ++x) {
            const Eigen::Vector2d p(x, y);
            const Eigen::Vector2d margin(2.0, 2.0);
            const bool near_patch = Eigen::AlignedBox2d(reach.min() - margin, reach.max() + margin).contains(p);
            const bool near_ball = Eigen::AlignedBox2d(ball.min() - margin, ball.max() + margin).contains(p);
            const std::uint8_t* in_px = frame.view().row(y) + 3 * x;
            const std::uint8_t* out_px = out.view().row(y) + 3 * x;
            if (!near_patch && !near_ball) {
                ++unchanged_checked;
                unchanged_differing += std::memcmp(in_px, out_px, 3) != 0 ? 1 : 0;
            }
            if (Eigen::AlignedBox2d(inner.min() + margin, inner.max() - margin).contains(p)) {
                ++halved_checked;
                for (int ch = 0; ch < 3; ++ch) {
                    const double expected = 0.5 * response.toLinear(ch, in_px[ch]);
                    const double got = response.toLinear(ch, out_px[ch]);
                    // One code of rounding at the expected level.
                    const double code_step = response.toLinear(ch, std::uint8_t{255}) / 255.0 * 4.0;
                    halved_wrong += std::abs(got - expected) > std::max(0.02 * expected, code_step) ? 1 : 0;
                }
            }
        }
    }
    EXPECT_GT(unchanged_checked, camera.width * camera.height / 2);
    EXPECT_EQ(unchanged_differing, 0) << "of " << unchanged_checked;
    EXPECT_GT(halved_checked, 4);
    EXPECT_EQ(halved_wrong, 0) << "of " << 3 * halved_checked;
}

// Registration measured directly: the world point the composite shows at each camera pixel (its
// surface's interpolated world position, read through the same layer and lens warp as the
// composite, surfacePoints()) projects with CameraModel::project onto that pixel's centre, within
// 0.05 px at every pixel a surface fully covers: the principal point, the pixel-centre convention,
// the layer's margin and the distortion map together. A plane that fills the view (tilted, so the
// mapping is a true perspective) and a virtual box; no distortion, and a strong barrel distortion
// with tangential terms.
TEST_F(CompositorTest, EveryPixelShowsTheWorldPointTheCameraModelProjectsThere) {
    for (const bool distorted : {false, true}) {
        CameraModel camera = smallCamera(320, 240);
        if (distorted) {
            camera.distortion.k1 = -0.25;
            camera.distortion.k2 = 0.08;
            camera.distortion.p1 = 0.002;
            camera.distortion.p2 = -0.001;
        }
        Scene scene;
        RealObject wall;
        wall.name = "wall";
        wall.shape = PlaneShape{Eigen::Vector2d(8.0, 8.0)};
        wall.world_from_object = Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitX())), Eigen::Vector3d(0, 0, -0.2));
        scene.real_objects.push_back(wall);
        VirtualObject box;
        box.name = "box";
        box.shape = BoxShape{Eigen::Vector3d(0.3, 0.2, 0.25)};
        box.placement = FixedPlacement{Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.5, Eigen::Vector3d(1, 2, 3).normalized())),
                                               Eigen::Vector3d(0.35, -0.2, 0.5))};
        scene.virtual_objects.push_back(box);
        auto c = make(scene, camera, ResponseCurve::linear());
        ASSERT_TRUE(c);
        const Image frame = constantFrame(camera.width, camera.height, 0);
        FrameInput in;
        in.image = frame.view();
        const Rigid3d pose(Eigen::Quaterniond(Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitY())) * lookingDown().rotation,
                           Eigen::Vector3d(0.1, -0.05, 1.8));
        in.cam_from_world = pose;
        auto points = c->surfacePoints(in);
        ASSERT_TRUE(points) << points.error().message;
        double worst = 0.0, sum = 0.0;
        int measured = 0, corners = 0;
        for (int y = 0; y < camera.height; ++y) {
            for (int x = 0; x < camera.width; ++x) {
                const Eigen::Vector4f& p = (*points)[static_cast<std::size_t>(y) * static_cast<std::size_t>(camera.width) + static_cast<std::size_t>(x)];
                if (p.w() != 1.0f) continue;  // an edge, or nothing
                const auto q = camera.project(pose.rotation * p.head<3>().cast<double>() + pose.translation);
                ASSERT_TRUE(q) << x << " " << y;
                const double error = (*q - Eigen::Vector2d(x, y)).norm();
                worst = std::max(worst, error);
                sum += error;
                ++measured;
                corners += (x < 8 || x >= camera.width - 8) && (y < 8 || y >= camera.height - 8) ? 1 : 0;
            }
        }
        std::printf("%s: %d pixels measured (%d in the corners), error mean %.4f px, max %.4f px\n", distorted ? "distorted" : "pinhole",
                    measured, corners, sum / std::max(measured, 1), worst);
        RecordProperty(distorted ? "distorted_max_error_px" : "pinhole_max_error_px", std::to_string(worst));
        EXPECT_GT(measured, camera.width * camera.height * 9 / 10);  // the plane fills the view, corners included
        EXPECT_EQ(corners, 4 * 64);
        EXPECT_LT(worst, 0.05) << (distorted ? "distorted" : "pinhole");
    }
}

// The rasterised coverage of small squares: centred and sized where CameraModel::project puts the
// squares, through a strong distortion, within the rasteriser's coverage error (the registration
// itself is the test above).
// small emitting squares parallel to the image plane on black; the centroid of each in linear
// light against the centroid of the square's image under CameraModel::project (a fine grid on
// the square, each cell weighted by its projected area: exact to second order in the cell size,
// whatever the distortion does across the square).
TEST_F(CompositorTest, PointsLandWhereTheCameraModelProjectsThemThroughDistortion) {
    CameraModel camera = smallCamera(320, 240);
    camera.distortion.k1 = -0.25;
    camera.distortion.k2 = 0.08;
    camera.distortion.p1 = 0.002;
    camera.distortion.p2 = -0.001;
    Scene scene;
    const std::vector<Eigen::Vector3d> points{{0.0, 0.0, 0.0}, {0.55, 0.35, 0.0}, {-0.6, -0.4, 0.05}, {0.3, -0.45, -0.1}, {-0.5, 0.3, 0.1}};
    const double half = 0.05;
    for (std::size_t i = 0; i < points.size(); ++i) {
        VirtualObject v;
        v.name = "p";
        v.name += std::to_string(i);  // ("p" + to_string: GCC 12's -Wrestrict false positive at -O3)
        v.shape = PlaneShape{Eigen::Vector2d(2 * half, 2 * half)};
        v.material.albedo = Eigen::Vector3d::Zero();
        v.emission = Eigen::Vector3d::Ones();
        v.placement = FixedPlacement{Rigid3d(Eigen::Quaterniond::Identity(), points[i])};
        scene.virtual_objects.push_back(v);
    }
    auto c = make(scene, camera, ResponseCurve::linear());
    ASSERT_TRUE(c);
    const Image black = constantFrame(camera.width, camera.height, 0);
    const Image out = render(*c, black.view(), lookingDown(), lighting::LightingSnapshot{});
    const Rigid3d pose = lookingDown();
    for (const Eigen::Vector3d& p : points) {
        // The expected centroid: the projected square, by a 64 x 64 grid of cells.
        const int n = 64;
        double area = 0.0;
        Eigen::Vector2d weighted = Eigen::Vector2d::Zero();
        const auto proj = [&](double a, double b) {
            return *camera.project(pose.rotation * (p + Eigen::Vector3d(a, b, 0.0)) + pose.translation);
        };
        for (int i = 0; i < n; ++i) {
            for (int j = 0; j < n; ++j) {
                const double a0 = -half + 2 * half * i / n, a1 = -half + 2 * half * (i + 1) / n;
                const double b0 = -half + 2 * half * j / n, b1 = -half + 2 * half * (j + 1) / n;
                const Eigen::Vector2d q00 = proj(a0, b0), q10 = proj(a1, b0), q11 = proj(a1, b1), q01 = proj(a0, b1);
                const double cell = 0.5 * std::abs((q11 - q00).x() * (q01 - q10).y() - (q11 - q00).y() * (q01 - q10).x());
                area += cell;
                weighted += cell * proj(0.5 * (a0 + a1), 0.5 * (b0 + b1));
            }
        }
        const Eigen::Vector2d expected = weighted / area;
        double sw = 0.0, sx = 0.0, sy = 0.0;
        for (int y = static_cast<int>(expected.y()) - 20; y <= static_cast<int>(expected.y()) + 20; ++y) {
            for (int x = static_cast<int>(expected.x()) - 20; x <= static_cast<int>(expected.x()) + 20; ++x) {
                const double w = out.view().row(y)[3 * x];
                sw += w;
                sx += w * x;
                sy += w * y;
            }
        }
        ASSERT_GT(sw, 0.0);
        const Eigen::Vector2d centroid(sx / sw, sy / sw);
        // Measured 0.02-0.07 px, the same with the distortion set to zero: the
        // residual is the rasteriser's coverage of the squares' edges (they come out about 0.1 px
        // inside, 3% of the area), not the registration (measured per pixel above: within 0.01 px).
        const double error = (centroid - expected).norm();
        RecordProperty("centroid_error_px", std::to_string(error));
        std::printf("point (%.2f, %.2f, %.2f): centroid error %.3f px, area %.1f of %.1f px^2\n", p.x(), p.y(), p.z(), error,
                    sw / 255.0, area);
        EXPECT_LT(error, 0.1) << "point " << p.transpose() << " expected " << expected.transpose() << " got " << centroid.transpose();
        // And the area: the square's image covers what the camera model says.
        EXPECT_NEAR(sw / 255.0, area, 0.05 * area);
    }
}

// A real box in front of a virtual sphere hides it (the frame shows through unchanged there); the
// sphere's edge over the floor is antialiased and leaves the floor's modulation alone.
TEST_F(CompositorTest, RealProxiesHideVirtualObjects) {
    Scene scene;
    scene.real_objects.push_back(floorPlane());
    RealObject box;
    box.name = "box";
    box.shape = BoxShape{Eigen::Vector3d(0.3, 0.3, 0.3)};
    box.world_from_object = Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0.0, 0.0, 0.6));  // above the sphere, towards the camera
    scene.real_objects.push_back(box);
    scene.virtual_objects.push_back(sphere("ball", 0.25, {0.0, 0.0, 0.25}, Eigen::Vector3d::Zero(), Eigen::Vector3d::Constant(0.5)));
    const CameraModel camera = smallCamera();
    auto c = make(scene, camera, ResponseCurve::linear());
    ASSERT_TRUE(c);
    const Image frame = constantFrame(camera.width, camera.height, 40);
    const Image out = render(*c, frame.view(), lookingDown(), lighting::LightingSnapshot{});
    const auto pixel = [&](double x, double y, double z) {
        const Eigen::Vector2d p = *camera.project(lookingDown().rotation * Eigen::Vector3d(x, y, z) + lookingDown().translation);
        return static_cast<int>(out.view().row(static_cast<int>(std::lround(p.y())))[3 * static_cast<int>(std::lround(p.x()))]);
    };
    EXPECT_EQ(pixel(0.0, 0.0, 0.75), 40);  // the box's top: the frame unchanged
    EXPECT_NEAR(pixel(0.23, 0.0, 0.25), 0.5 * 255, 2);  // the sphere beside the box
    EXPECT_EQ(pixel(0.6, 0.0, 0.0), 40);   // the floor far from both
    // The sphere's silhouette over the floor has intermediate values (MSAA).
    int partial = 0;
    for (int y = 0; y < camera.height; ++y) {
        for (int x = 0; x < camera.width; ++x) {
            const int v = out.view().row(y)[3 * x];
            partial += v > 45 && v < 122 ? 1 : 0;
        }
    }
    EXPECT_GT(partial, 10);
}

// A textured unit quad in glTF (positions in [0, 1]^2 at z = 0 facing +z, texture coordinates
// with v down from the top edge), its base colour texture `image` (a file beside it) and factor.
std::string texturedQuadGltf(const std::string& image, const std::string& factor) {
    std::vector<float> floats = {0, 0, 0, 1, 0, 0, 0, 1, 0, 1, 1, 0,   // positions
                                 0, 0, 1, 0, 0, 1, 0, 0, 1, 0, 0, 1,   // normals
                                 0, 1, 1, 1, 0, 0, 1, 0};              // texture coordinates
    const std::vector<std::uint16_t> indices = {0, 1, 2, 2, 1, 3};
    std::vector<std::uint8_t> bytes(floats.size() * 4 + indices.size() * 2);
    std::memcpy(bytes.data(), floats.data(), floats.size() * 4);
    std::memcpy(bytes.data() + floats.size() * 4, indices.data(), indices.size() * 2);
    std::string hex;  // the buffer as a data URI (base64)
    static const char* kAlphabet = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    for (std::size_t i = 0; i < bytes.size(); i += 3) {
        const std::uint32_t v = (std::uint32_t{bytes[i]} << 16) | (i + 1 < bytes.size() ? std::uint32_t{bytes[i + 1]} << 8 : 0u) |
                                (i + 2 < bytes.size() ? std::uint32_t{bytes[i + 2]} : 0u);
        hex += kAlphabet[(v >> 18) & 63];
        hex += kAlphabet[(v >> 12) & 63];
        hex += i + 1 < bytes.size() ? kAlphabet[(v >> 6) & 63] : '=';
        hex += i + 2 < bytes.size() ? kAlphabet[v & 63] : '=';
    }
    return std::string(R"({"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
"meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2}, "indices": 3, "material": 0}]}],
"materials": [{"pbrMetallicRoughness": {"baseColorFactor": )") + factor + R"(, "baseColorTexture": {"index": 0}}}],
"textures": [{"source": 0}], "images": [{"uri": ")" + image + R"("}],
"buffers": [{"byteLength": )" + std::to_string(bytes.size()) + R"(, "uri": "data:application/octet-stream;base64,)" + hex + R"("}],
"bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 48}, {"buffer": 0, "byteOffset": 48, "byteLength": 48},
                {"buffer": 0, "byteOffset": 96, "byteLength": 32}, {"buffer": 0, "byteOffset": 128, "byteLength": 12}],
"accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3"},
              {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"},
              {"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC2"},
              {"bufferView": 3, "componentType": 5123, "count": 6, "type": "SCALAR"}]})";
}

// A glTF quad with a 2 x 2 base colour texture (top row red, green; bottom row sRGB grey 128,
// blue) and baseColorFactor (0.5, 1, 1), lit by a directional light of irradiance pi straight
// down, composited with a linear response: each quadrant's centre shows factor x the texel decoded
// from sRGB to linear (grey 128 is 0.2158, not 0.5), in the image where the glTF puts it.
TEST_F(CompositorTest, VirtualMeshesShowTheirBaseColourTexture) {
    testing::TempDir dir;
    cv::Mat bgr(2, 2, CV_8UC3);
    bgr.at<cv::Vec3b>(0, 0) = {0, 0, 255};
    bgr.at<cv::Vec3b>(0, 1) = {0, 255, 0};
    bgr.at<cv::Vec3b>(1, 0) = {128, 128, 128};
    bgr.at<cv::Vec3b>(1, 1) = {255, 0, 0};
    ASSERT_TRUE(cv::imwrite((dir / "checker.png").string(), bgr));
    testing::writeText(dir / "quad.gltf", texturedQuadGltf("checker.png", "[0.5, 1.0, 1.0, 1.0]"));
    auto mesh = readMesh(dir / "quad.gltf");
    ASSERT_TRUE(mesh) << mesh.error().message;
    Scene scene;
    VirtualObject quad;
    quad.name = "quad";
    quad.shape = MeshShape{dir / "quad.gltf", std::make_shared<const Mesh>(std::move(*mesh))};
    quad.material.albedo = Eigen::Vector3d::Constant(0.3);  // not used where the file has a base colour
    quad.placement = FixedPlacement{Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(-0.5, -0.5, 0.0))};
    scene.virtual_objects.push_back(quad);
    lighting::LightingSnapshot snapshot;
    snapshot.version = 1;
    lighting::EstimatedLight sun;
    sun.kind = lighting::LightKind::kDirectional;
    sun.direction = Eigen::Vector3d(0, 0, -1);
    sun.emission = Eigen::Vector3d::Constant(std::numbers::pi);
    snapshot.lights.push_back(sun);
    const CameraModel camera = smallCamera();
    auto c = make(scene, camera, ResponseCurve::linear());
    ASSERT_TRUE(c);
    const Image frame = constantFrame(camera.width, camera.height, 0);
    const Image out = render(*c, frame.view(), lookingDown(), snapshot);
    if (std::getenv("CL_RENDER_DUMP")) {
        cv::Mat rgb(out.height(), out.width(), CV_8UC3, const_cast<std::uint8_t*>(out.view().data)), shown;
        cv::cvtColor(rgb, shown, cv::COLOR_RGB2BGR);
        cv::imwrite("/tmp/textured_quad.png", shown);
    }
    const auto at = [&](double x, double y) {
        const Eigen::Vector2d p = *camera.project(lookingDown().rotation * Eigen::Vector3d(x, y, 0) + lookingDown().translation);
        const std::uint8_t* px = out.view().row(static_cast<int>(std::lround(p.y()))) + 3 * static_cast<int>(std::lround(p.x()));
        return Eigen::Vector3i(px[0], px[1], px[2]);
    };
    const double grey = 255.0 * std::pow((128.0 / 255.0 + 0.055) / 1.055, 2.4);  // sRGB 128 in linear codes: 55.0
    // 4 codes: the nearest pixel's centre is up to 0.7 px from the texel's centre, and a texel spans
    // about 72 px, so the filter mixes in up to 1% of the neighbour.
    const auto near = [](const Eigen::Vector3i& got, const Eigen::Vector3d& expected) {
        return (got.cast<double>() - expected).cwiseAbs().maxCoeff() <= 4.0;
    };
    EXPECT_TRUE(near(at(-0.25, 0.25), Eigen::Vector3d(127.5, 0, 0))) << at(-0.25, 0.25).transpose();  // top-left: red x 0.5
    EXPECT_TRUE(near(at(0.25, 0.25), Eigen::Vector3d(0, 255, 0))) << at(0.25, 0.25).transpose();       // top-right: green
    EXPECT_TRUE(near(at(-0.25, -0.25), Eigen::Vector3d(0.5 * grey, grey, grey))) << at(-0.25, -0.25).transpose();
    EXPECT_TRUE(near(at(0.25, -0.25), Eigen::Vector3d(0, 0, 255))) << at(0.25, -0.25).transpose();     // bottom-right: blue
}

// Where one virtual object passes in front of another, the edge is antialiased as a silhouette
// over the frame is (the objects are shaded once per pixel and each sample takes the colour of
// the surface that covers it): with 4 samples, pixels between the two objects' values exist; with
// one sample, none.
TEST_F(CompositorTest, EdgesBetweenVirtualObjectsAreAntialiased) {
    Scene scene;
    scene.virtual_objects.push_back(sphere("back", 0.4, {0.0, 0.0, 0.0}, Eigen::Vector3d::Zero(), Eigen::Vector3d::Constant(0.2)));
    scene.virtual_objects.push_back(sphere("front", 0.2, {0.25, 0.1, 0.5}, Eigen::Vector3d::Zero(), Eigen::Vector3d::Constant(0.8)));
    const CameraModel camera = smallCamera();
    const Image frame = constantFrame(camera.width, camera.height, 0);
    for (int samples : {4, 1}) {
        CompositorOptions options;
        options.msaa_samples = samples;
        auto c = make(scene, camera, ResponseCurve::linear(), options);
        ASSERT_TRUE(c);
        const Image out = render(*c, frame.view(), lookingDown(), lighting::LightingSnapshot{});
        // Pixels strictly between the two emissions (51 and 204), away from the frame (0): the
        // front sphere's edge over the back one.
        int between = 0, back = 0, front = 0;
        for (int y = 0; y < camera.height; ++y) {
            for (int x = 0; x < camera.width; ++x) {
                const int v = out.view().row(y)[3 * x];
                between += v > 56 && v < 199 ? 1 : 0;
                back += std::abs(v - 51) <= 1 ? 1 : 0;
                front += std::abs(v - 204) <= 1 ? 1 : 0;
            }
        }
        EXPECT_GT(back, 1000) << samples;
        EXPECT_GT(front, 500) << samples;
        if (samples == 4) {
            EXPECT_GT(between, 20) << "the edge between the objects is not antialiased";
        } else {
            EXPECT_EQ(between, 0) << "one sample: every pixel is one object or the other";
        }
    }
}

// A Lambertian sphere under one directional light of irradiance E: the brightest pixel's relative
// radiance is albedo / pi x E x radiance_scale.
TEST_F(CompositorTest, VirtualObjectsAreShadedInRelativeRadiance) {
    Scene scene;
    scene.virtual_objects.push_back(sphere("ball", 0.3, {0, 0, 0.3}, Eigen::Vector3d::Constant(0.6)));
    lighting::LightingSnapshot snapshot;
    snapshot.version = 1;
    snapshot.radiance_scale = 2.0;
    lighting::EstimatedLight sun;
    sun.name = "sun";
    sun.kind = lighting::LightKind::kDirectional;
    sun.direction = Eigen::Vector3d(0, 0, -1);
    sun.emission = Eigen::Vector3d::Constant(0.5);
    snapshot.lights.push_back(sun);
    const CameraModel camera = smallCamera();
    auto c = make(scene, camera, ResponseCurve::linear());
    ASSERT_TRUE(c);
    const Image frame = constantFrame(camera.width, camera.height, 0);
    const double eg = 2.0;
    const Image out = render(*c, frame.view(), lookingDown(), snapshot, {}, eg);
    int brightest = 0;
    for (int y = 0; y < camera.height; ++y) {
        for (int x = 0; x < camera.width; ++x) brightest = std::max(brightest, static_cast<int>(out.view().row(y)[3 * x + 1]));
    }
    const double expected = 0.6 / std::numbers::pi * 0.5 * 2.0 * eg * 255.0;
    EXPECT_NEAR(brightest, expected, 0.02 * expected + 1.0);
}

// A snapshot with one point lamp (relative intensity `intensity`) and nothing else.
lighting::LightingSnapshot pointLampSnapshot(const Eigen::Vector3d& at, double intensity) {
    lighting::LightingSnapshot snapshot;
    snapshot.version = 1;
    lighting::EstimatedLight lamp;
    lamp.name = "lamp";
    lamp.kind = lighting::LightKind::kPoint;
    lamp.world_from_object = Rigid3d(Eigen::Quaterniond::Identity(), at);
    lamp.emission = Eigen::Vector3d::Constant(intensity);
    snapshot.lights.push_back(lamp);
    return snapshot;
}

// A 2 m x 2 m virtual tile at the origin with a GGX material.
VirtualObject ggxTile(const Eigen::Vector3d& f0, double roughness) {
    VirtualObject tile;
    tile.name = "tile";
    tile.shape = PlaneShape{Eigen::Vector2d(2.0, 2.0)};
    tile.material.type = MaterialType::kGgx;
    tile.material.albedo = f0;
    tile.material.roughness = roughness;
    return tile;
}

// A GGX virtual tile (`material: {type: ggx}`) under one point lamp, seen from above: every pixel's
// relative radiance is the GGX BRDF (written here from its definition: D G F / (4 cos_o cos_i),
// Trowbridge-Reitz D, separable Smith G, Schlick F with F0 = the albedo) times the lamp's
// irradiance I cos_i / d^2, a highlight where the lamp's mirror image is. (With nothing
// estimated around it there is no indirect light.)
TEST_F(CompositorTest, GgxObjectsReflectTheLightThroughTheirLobe) {
    Scene scene;
    const VirtualObject tile = ggxTile(Eigen::Vector3d(0.9, 0.6, 0.3), 0.5);
    scene.virtual_objects.push_back(tile);
    const Eigen::Vector3d lamp(0.3, 0.1, 0.8);
    const double intensity = 0.5;
    const lighting::LightingSnapshot snapshot = pointLampSnapshot(lamp, intensity);
    const CameraModel camera = smallCamera();
    auto c = make(scene, camera, ResponseCurve::linear());
    ASSERT_TRUE(c);
    const Eigen::Vector3d eye(0, 0, 2);
    const double a = 0.25, a2 = a * a;  // roughness 0.5
    const auto radiance = [&](const Eigen::Vector3d& p) {  // relative radiance towards the eye, per channel
        const Eigen::Vector3d wo = (eye - p).normalized(), wi = (lamp - p).normalized();
        const double d2 = (lamp - p).squaredNorm();
        const Eigen::Vector3d h = (wo + wi).normalized();
        const double co = wo.z(), ci = wi.z(), ch = h.z();
        const double den = ch * ch * (a2 - 1.0) + 1.0;
        const double d = a2 / (std::numbers::pi * den * den);
        const auto g1 = [&](double x) { return 2.0 * x / (x + std::sqrt(a2 + (1.0 - a2) * x * x)); };
        const double fresnel_weight = std::pow(1.0 - wi.dot(h), 5);
        const Eigen::Vector3d f = (tile.material.albedo * (1.0 - fresnel_weight) + Eigen::Vector3d::Constant(fresnel_weight)) *
                                  (d * g1(co) * g1(ci) / (4.0 * co * ci));
        return Eigen::Vector3d(f * intensity * ci / d2);
    };
    // The exposure that puts the brightest point (the mirror image of the lamp) at about 200 codes.
    const Eigen::Vector3d mirror = eye + (Eigen::Vector3d(lamp.x(), lamp.y(), -lamp.z()) - eye) * (eye.z() / (eye.z() + lamp.z()));
    const double eg = 200.0 / (255.0 * radiance(mirror).maxCoeff());
    const Image frame = constantFrame(camera.width, camera.height, 0);
    const Image out = render(*c, frame.view(), lookingDown(), snapshot, {}, eg);
    int compared = 0, wrong = 0, brightest = 0;
    Eigen::Vector2i brightest_at(-1, -1);
    for (int y = 2; y < camera.height - 2; ++y) {
        for (int x = 2; x < camera.width - 2; ++x) {
            // The pixel centre's ray from (0, 0, 2) meets the tile (z = 0) at twice its direction.
            const Eigen::Vector3d p(2.0 * (x - camera.cx) / camera.fx, -2.0 * (y - camera.cy) / camera.fy, 0.0);
            const Eigen::Vector3d expected = radiance(p) * eg * 255.0;
            for (int ch = 0; ch < 3; ++ch) {
                const int code = out.view().row(y)[3 * x + ch];
                if (ch == 0 && code > brightest) {
                    brightest = code;
                    brightest_at = {x, y};
                }
                if (expected[ch] < 8.0 || expected[ch] > 250.0) continue;
                ++compared;
                if (std::abs(code - expected[ch]) > 0.02 * expected[ch] + 1.0) {
                    if (wrong++ < 5) ADD_FAILURE() << "pixel " << x << "," << y << " channel " << ch << ": " << code << ", expected " << expected[ch];
                }
            }
        }
    }
    EXPECT_GT(compared, 10000);
    EXPECT_EQ(wrong, 0) << "of " << compared;
    // The highlight is where the lamp's mirror image is.
    const auto at = camera.project(lookingDown() * mirror);
    ASSERT_TRUE(at);
    EXPECT_LT((brightest_at.cast<double>() - *at).norm(), 3.0);
}

// An area light is drawn with a few point samples (4 by default); a GGX lobe narrower than the
// light would show each of them as a highlight of its own. The lobe is widened by the patch each
// sample stands for, so a glossy tile under a 0.5 m panel shows one highlight: along the row through
// it and the column, no valley between the samples' images.
TEST_F(CompositorTest, AnAreaLightGivesAGgxObjectOneHighlight) {
    Scene scene;
    scene.virtual_objects.push_back(ggxTile(Eigen::Vector3d::Constant(0.9), 0.2));
    lighting::LightingSnapshot snapshot;
    snapshot.version = 1;
    lighting::EstimatedLight panel;
    panel.name = "panel";
    panel.kind = lighting::LightKind::kArea;
    panel.size = {0.5, 0.5};
    // Facing down (its +z along world -z), 1 m above the tile.
    panel.world_from_object = Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(std::numbers::pi, Eigen::Vector3d::UnitX())), Eigen::Vector3d(0, 0, 1.0));
    panel.emission = Eigen::Vector3d::Constant(1.0);
    snapshot.lights.push_back(panel);
    const CameraModel camera = smallCamera();
    auto c = make(scene, camera, ResponseCurve::linear());
    ASSERT_TRUE(c);
    const Image frame = constantFrame(camera.width, camera.height, 0);
    // The exposure that keeps the highlight below the top code: probe once, then draw again.
    Image out = render(*c, frame.view(), lookingDown(), snapshot, {}, 1.0);
    int peak = 0;
    for (int y = 0; y < camera.height; ++y) {
        for (int x = 0; x < camera.width; ++x) peak = std::max(peak, static_cast<int>(out.view().row(y)[3 * x + 1]));
    }
    ASSERT_GT(peak, 0);
    if (peak >= 255 || peak < 100) out = render(*c, frame.view(), lookingDown(), snapshot, {}, peak >= 255 ? 0.05 : 180.0 / peak);
    if (std::getenv("CL_RENDER_DUMP")) cv::imwrite("/tmp/ggx_area.png", cv::Mat(out.height(), out.width(), CV_8UC3, const_cast<std::uint8_t*>(out.view().data)));
    // The row and the column through the brightest pixel.
    int bx = 0, by = 0, best = -1;
    for (int y = 0; y < camera.height; ++y) {
        for (int x = 0; x < camera.width; ++x) {
            const int v = out.view().row(y)[3 * x + 1];
            if (v > best) best = v, bx = x, by = y;
        }
    }
    ASSERT_LT(best, 255);
    ASSERT_GT(best, 50);
    // No valley: every point is at least 95% of the lower of the highest points on either side of
    // it (the four samples' images, without the widening, leave valleys at a quarter of the peak;
    // a panel's true reflection is a plateau).
    const auto oneHighlight = [&](const std::vector<int>& line) {
        for (std::size_t k = 1; k + 1 < line.size(); ++k) {
            const int left = *std::max_element(line.begin(), line.begin() + static_cast<std::ptrdiff_t>(k));
            const int right = *std::max_element(line.begin() + static_cast<std::ptrdiff_t>(k) + 1, line.end());
            if (line[k] + 1 < 0.95 * std::min(left, right)) return false;
        }
        return true;
    };
    std::vector<int> row, column;
    for (int x = 0; x < camera.width; ++x) row.push_back(out.view().row(by)[3 * x + 1]);
    for (int y = 0; y < camera.height; ++y) column.push_back(out.view().row(y)[3 * bx + 1]);
    EXPECT_TRUE(oneHighlight(row)) << "row " << by;
    EXPECT_TRUE(oneHighlight(column)) << "column " << bx;
}

// Shadow maps: a virtual floor tile under a point light is darker under a virtual box and under a
// real box (real proxies are occluders too) than in the open.
TEST_F(CompositorTest, ShadowMapsHaveRealAndVirtualOccluders) {
    Scene scene;
    VirtualObject tile;
    tile.name = "tile";
    tile.shape = PlaneShape{Eigen::Vector2d(1.6, 1.0)};
    tile.material.albedo = Eigen::Vector3d::Constant(0.8);
    scene.virtual_objects.push_back(tile);
    VirtualObject cube;
    cube.name = "cube";
    cube.shape = BoxShape{Eigen::Vector3d(0.2, 0.2, 0.2)};
    cube.placement = FixedPlacement{Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(-0.4, 0.0, 0.4))};
    scene.virtual_objects.push_back(cube);
    RealObject block;
    block.name = "block";
    block.shape = BoxShape{Eigen::Vector3d(0.2, 0.2, 0.2)};
    block.world_from_object = Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0.4, 0.0, 0.4));
    scene.real_objects.push_back(block);
    const lighting::LightingSnapshot snapshot = pointLampSnapshot(Eigen::Vector3d(0, 0, 1.2), 0.8);
    // A camera off to the side so the tile under the boxes is in view.
    const Rigid3d pose(Eigen::Quaterniond(Eigen::AngleAxisd(std::numbers::pi, Eigen::Vector3d::UnitX())) *
                           Eigen::Quaterniond(Eigen::AngleAxisd(0.35, Eigen::Vector3d::UnitX())),
                       Eigen::Vector3d(0, 0, 2.2));
    const CameraModel camera = smallCamera(240, 180);
    auto c = make(scene, camera, ResponseCurve::linear());
    ASSERT_TRUE(c);
    const Image frame = constantFrame(camera.width, camera.height, 0);
    const Image out = render(*c, frame.view(), pose, snapshot);
    if (std::getenv("CL_RENDER_DUMP")) cv::imwrite("/tmp/shadow_test.png", cv::Mat(out.height(), out.width(), CV_8UC3, const_cast<std::uint8_t*>(out.view().data)));
    const auto value = [&](double x, double y) {
        const auto p = camera.project(pose.rotation * Eigen::Vector3d(x, y, 0.0) + pose.translation);
        EXPECT_TRUE(p && camera.inImage(*p, 2.0));
        if (!p || !camera.inImage(*p, 2.0)) return -1;
        return static_cast<int>(out.view().row(static_cast<int>(std::lround(p->y())))[3 * static_cast<int>(std::lround(p->x())) + 1]);
    };
    // Shadows fall away from the light at (0, 0, 1.2): under an occluder at x = +-0.4, height 0.4,
    // the shadow centre is at x = +-0.4 x 1.2 / 0.8 = +-0.6.
    const int open = value(0.0, 0.35), under_virtual = value(-0.6, 0.0), under_real = value(0.6, 0.0), open_side = value(0.6, 0.42);
    EXPECT_GT(open, 20);
    EXPECT_LT(under_virtual, 0.2 * open_side);
    EXPECT_LT(under_real, 0.2 * open_side);
}

// The real proxies' shadow maps cover a sphere around the virtual objects and are kept while the
// objects move inside it (fitted again when they leave it or shrink in it): a virtual tile sliding
// under a real block, in steps of 5 cm over 1.2 m, shows the block's shadow as a compositor drawing
// that pose for the first time does, at every step.
// The virtual objects' maps are as fine as the objects' pixels, no finer (they only shade the
// objects), within [64, the option's size], and keep their size while the objects move a little.
TEST(VirtualShadowMapSize, FollowsTheObjectsWidthInPixels) {
    EXPECT_EQ(virtualShadowMapSize(233.7, 0, 512), 256);
    EXPECT_EQ(virtualShadowMapSize(300.0, 0, 512), 512);
    EXPECT_EQ(virtualShadowMapSize(10.0, 0, 512), 64);
    EXPECT_EQ(virtualShadowMapSize(3000.0, 0, 512), 512);
    EXPECT_EQ(virtualShadowMapSize(std::numeric_limits<double>::infinity(), 0, 1024), 1024);
    EXPECT_EQ(virtualShadowMapSize(std::numeric_limits<double>::quiet_NaN(), 256, 1024), 1024);
    // Hysteresis: 512 in use stays for objects 205-512 px wide, and goes when it is too coarse
    // or more than 2.5x what is needed.
    EXPECT_EQ(virtualShadowMapSize(250.0, 512, 1024), 512);
    EXPECT_EQ(virtualShadowMapSize(520.0, 512, 1024), 1024);
    EXPECT_EQ(virtualShadowMapSize(190.0, 512, 1024), 256);
    EXPECT_EQ(virtualShadowMapSize(250.0, 256, 1024), 256);
    // A smaller largest size than what is in use.
    EXPECT_EQ(virtualShadowMapSize(250.0, 512, 256), 256);
}

TEST_F(CompositorTest, RealShadowsFollowAVirtualObjectThatMoves) {
    Scene scene;
    VirtualObject tile;
    tile.name = "tile";
    tile.shape = PlaneShape{Eigen::Vector2d(0.4, 0.4)};
    tile.material.albedo = Eigen::Vector3d::Constant(0.8);
    scene.virtual_objects.push_back(tile);
    RealObject block;
    block.name = "block";
    block.shape = BoxShape{Eigen::Vector3d(0.1, 0.1, 0.1)};
    block.world_from_object = Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0.0, 0.0, 0.45));
    scene.real_objects.push_back(block);
    const lighting::LightingSnapshot snapshot = pointLampSnapshot(Eigen::Vector3d(0, 0, 1.2), 0.8);
    const CameraModel camera = smallCamera(200, 150);
    auto moving = make(scene, camera, ResponseCurve::linear());
    ASSERT_TRUE(moving);
    const Image frame = constantFrame(camera.width, camera.height, 0);
    int shadowed_steps = 0;
    for (int step = 0; step <= 24; ++step) {
        const double x = -0.6 + 0.05 * step;
        const std::vector<std::optional<Rigid3d>> poses = {Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(x, 0.0, 0.0))};
        const Image out = render(*moving, frame.view(), lookingDown(), snapshot, poses);
        auto fresh = make(scene, camera, ResponseCurve::linear());
        ASSERT_TRUE(fresh);
        const Image expected = render(*fresh, frame.view(), lookingDown(), snapshot, poses);
        int differing = 0;
        for (int y = 0; y < camera.height; ++y) {
            for (int k = 0; k < 3 * camera.width; ++k) differing += std::abs(out.view().row(y)[k] - expected.view().row(y)[k]) > 8 ? 1 : 0;
        }
        // Only texels along the shadow's edge may differ (the two maps' texels lie differently).
        EXPECT_LT(differing, 3 * 40) << "step " << step;
        // Under the block (x = 0, the lamp straight above), when the tile is there: in shadow.
        if (std::abs(x) < 0.15) {
            const Eigen::Vector2d p = *camera.project(lookingDown().rotation * Eigen::Vector3d(0.0, 0.0, 0.0) + lookingDown().translation);
            const Eigen::Vector2d q = *camera.project(lookingDown().rotation * Eigen::Vector3d(x + 0.15 * (x > 0 ? -1 : 1), 0.15, 0.0) +
                                                      lookingDown().translation);
            const int under = out.view().row(static_cast<int>(std::lround(p.y())))[3 * static_cast<int>(std::lround(p.x())) + 1];
            const int lit = out.view().row(static_cast<int>(std::lround(q.y())))[3 * static_cast<int>(std::lround(q.x())) + 1];
            EXPECT_GT(lit, 20) << "step " << step;
            EXPECT_LT(under, 0.2 * lit) << "step " << step;
            ++shadowed_steps;
        }
    }
    EXPECT_GE(shadowed_steps, 5);
}

// Camera matching (off by default): a frame with 4 codes of sensor noise; the virtual ball's
// interior (flat emission) has no noise without matching and about the frame's deviation with it,
// the frame's own pixels are unchanged, the noise changes from frame to frame and two compositors
// give the same bytes.
TEST_F(CompositorTest, CameraMatchingGivesTheVirtualLayerTheFramesNoise) {
    Scene scene;
    scene.virtual_objects.push_back(sphere("ball", 0.5, {0, 0, 0.5}, Eigen::Vector3d::Zero(), Eigen::Vector3d::Constant(0.6)));
    const CameraModel camera = smallCamera(320, 240);
    Image frame(PixelFormat::kRgb8, camera.width, camera.height);
    std::mt19937 rng(17);
    std::normal_distribution<float> normal(0.0f, 4.0f);
    for (int y = 0; y < camera.height; ++y) {
        for (int x = 0; x < 3 * camera.width; ++x) frame.mutableView().row(y)[x] = static_cast<std::uint8_t>(std::lround(std::clamp(90.0f + normal(rng), 0.0f, 255.0f)));
    }
    const auto interior = [&](const Image& out, double& mean, double& deviation) {
        // Pixels well inside the ball's image (radius about 60 px): within 30 px of its centre.
        const Eigen::Vector2d c = *camera.project(lookingDown().rotation * Eigen::Vector3d(0, 0, 1.0) + lookingDown().translation);
        double sum = 0, sum2 = 0;
        int n = 0;
        for (int y = 0; y < camera.height; ++y) {
            for (int x = 0; x < camera.width; ++x) {
                if ((Eigen::Vector2d(x, y) - c).norm() > 30.0) continue;
                const double v = out.view().row(y)[3 * x + 1];
                sum += v;
                sum2 += v * v;
                ++n;
            }
        }
        mean = sum / n;
        deviation = std::sqrt(std::max(0.0, sum2 / n - mean * mean));
    };
    CompositorOptions off;
    auto plain = make(scene, camera, ResponseCurve::linear(), off);
    ASSERT_TRUE(plain);
    const Image without = render(*plain, frame.view(), lookingDown(), lighting::LightingSnapshot{});
    double mean_off = 0, dev_off = 0;
    interior(without, mean_off, dev_off);
    EXPECT_NEAR(mean_off, 0.6 * 255, 1.0);
    EXPECT_LT(dev_off, 0.6);
    EXPECT_FALSE(plain->cameraMatch());

    CompositorOptions on;
    on.camera_matching = true;
    auto matched = make(scene, camera, ResponseCurve::linear(), on);
    ASSERT_TRUE(matched);
    const Image first = render(*matched, frame.view(), lookingDown(), lighting::LightingSnapshot{});
    const Image second = render(*matched, frame.view(), lookingDown(), lighting::LightingSnapshot{});
    ASSERT_TRUE(matched->cameraMatch());
    const CameraMatch& m = *matched->cameraMatch();
    const double frame_sigma = std::sqrt(16.0 + 1.0 / 12.0);
    EXPECT_NEAR(m.noise.overall[1], frame_sigma, 0.1 * frame_sigma);
    double mean_on = 0, dev_on = 0;
    interior(first, mean_on, dev_on);
    std::printf("ball interior: deviation %.2f codes without matching, %.2f with (frame %.2f)\n", dev_off, dev_on, frame_sigma);
    EXPECT_NEAR(mean_on, mean_off, 1.0);
    // 15%: about 2800 pixels, and the profile's bin around code 153 is interpolated from the frame's.
    EXPECT_NEAR(dev_on, frame_sigma, 0.15 * frame_sigma);
    // The frame's own pixels, far from the ball, are the frame's.
    EXPECT_EQ(first.view().row(2)[6], frame.view().row(2)[6]);
    EXPECT_EQ(first.view().row(camera.height - 3)[3 * (camera.width - 3)], frame.view().row(camera.height - 3)[3 * (camera.width - 3)]);
    EXPECT_NE(std::memcmp(first.view().row(camera.height / 2), second.view().row(camera.height / 2), 3 * static_cast<std::size_t>(camera.width)), 0)
        << "the noise should change from frame to frame";
    auto again = make(scene, camera, ResponseCurve::linear(), on);
    ASSERT_TRUE(again);
    const Image repeat = render(*again, frame.view(), lookingDown(), lighting::LightingSnapshot{});
    for (int y = 0; y < camera.height; ++y) {
        ASSERT_EQ(std::memcmp(first.view().row(y), repeat.view().row(y), 3 * static_cast<std::size_t>(camera.width)), 0) << "row " << y;
    }
}

// Camera matching blurs the virtual layer to the frame's PSF: a frame whose edges are blurred by
// 1.5 px (left half) and a virtual box face-on (right half, over a flat part of the frame): the box's
// edges measure about the frame's sigma with matching; without, they are too sharp to measure as a
// Gaussian (the 4-sample coverage steps along them) or well under 0.5 px.
TEST_F(CompositorTest, CameraMatchingBlursTheVirtualLayerLikeTheFrame) {
    const CameraModel camera = smallCamera(320, 240);
    cv::Mat fine(240 * 4, 160 * 4, CV_32FC1, cv::Scalar(0.05));
    for (int k = 0; k < 4; ++k) cv::rectangle(fine, cv::Rect((10 + 35 * k) * 4, (20 + 40 * k) * 4, 25 * 4, 30 * 4), cv::Scalar(0.7), cv::FILLED);
    cv::Mat linear;
    cv::resize(fine, linear, cv::Size(160, 240), 0, 0, cv::INTER_AREA);
    cv::GaussianBlur(linear, linear, cv::Size(0, 0), 1.5);
    Image frame = constantFrame(camera.width, camera.height, 0);
    const ResponseCurve srgb = ResponseCurve::srgb();
    for (int y = 0; y < camera.height; ++y) {
        for (int x = 0; x < 160; ++x) {
            const auto code = static_cast<std::uint8_t>(std::lround(255.0f * srgb.toEncoded(1, linear.at<float>(y, x))));
            for (int c = 0; c < 3; ++c) frame.mutableView().row(y)[3 * x + c] = code;
        }
        for (int x = 160; x < camera.width; ++x) {
            for (int c = 0; c < 3; ++c) frame.mutableView().row(y)[3 * x + c] = static_cast<std::uint8_t>(std::lround(255.0f * srgb.toEncoded(1, 0.05f)));
        }
    }
    Scene scene;
    VirtualObject box;
    box.name = "box";
    box.shape = BoxShape{Eigen::Vector3d(0.35, 0.5, 0.1)};
    box.material.albedo = Eigen::Vector3d::Zero();
    box.emission = Eigen::Vector3d::Constant(0.7);
    box.placement = FixedPlacement{Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ())), Eigen::Vector3d(0.55, 0.0, 0.05))};
    scene.virtual_objects.push_back(box);
    double measured[2] = {0.0, 0.0};
    for (const bool matching : {false, true}) {
        CompositorOptions options;
        options.camera_matching = matching;
        auto c = make(scene, camera, srgb, options);
        ASSERT_TRUE(c);
        const Image out = render(*c, frame.view(), lookingDown(), lighting::LightingSnapshot{});
        if (matching) {
            ASSERT_TRUE(c->cameraMatch());
            EXPECT_NEAR(c->cameraMatch()->blur.sigma_px, std::sqrt(1.5 * 1.5 + 1.0 / 12.0), 0.15);
            EXPECT_GT(c->cameraMatch()->added_sigma_px, 1.3);
        }
        // The right half alone: the virtual box's edges.
        cv::Mat right = cv::Mat(out.height(), out.width(), CV_8UC3, const_cast<std::uint8_t*>(out.view().data), out.stride())(cv::Rect(170, 0, 150, 240)).clone();
        if (std::getenv("CL_RENDER_DUMP")) cv::imwrite(matching ? "/tmp/matching_on.png" : "/tmp/matching_off.png", right);
        auto blur = estimateBlur(ImageView{PixelFormat::kRgb8, right.cols, right.rows, right.step, right.data, right.step * static_cast<std::size_t>(right.rows)}, srgb);
        ASSERT_TRUE(blur);
        if (matching) {
            EXPECT_GT(blur->edges, 20);
        }
        measured[matching ? 1 : 0] = blur->sigma_px;
    }
    std::printf("virtual box edges: %.3f px without matching, %.3f px with (frame %.3f px)\n", measured[0], measured[1],
                std::sqrt(1.5 * 1.5 + 1.0 / 12.0));
    EXPECT_LT(measured[0], 0.5);  // 0: no edge fitted as a Gaussian
    EXPECT_NEAR(measured[1], std::sqrt(1.5 * 1.5 + 1.0 / 12.0), 0.2);
}

// Creation and destruction leave no GL object behind, and drawing with new snapshot versions
// does not accumulate any.
TEST_F(CompositorTest, NoGlObjectIsLeaked) {
    testing::TempDir dir;
    cv::Mat bgr(4, 4, CV_8UC3, cv::Scalar(30, 60, 90));
    ASSERT_TRUE(cv::imwrite((dir / "plain.png").string(), bgr));
    testing::writeText(dir / "quad.gltf", texturedQuadGltf("plain.png", "[1, 1, 1, 1]"));
    auto mesh = readMesh(dir / "quad.gltf");
    ASSERT_TRUE(mesh) << mesh.error().message;
    const GlObjectCounts before = liveGlObjects();
    {
        Scene scene;
        scene.real_objects.push_back(floorPlane());
        scene.virtual_objects.push_back(sphere("ball", 0.2, {0, 0, 0.2}, Eigen::Vector3d::Constant(0.5)));
        VirtualObject quad;
        quad.name = "quad";
        quad.shape = MeshShape{dir / "quad.gltf", std::make_shared<const Mesh>(std::move(*mesh))};
        quad.placement = FixedPlacement{Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0.3, 0.0, 0.1))};
        scene.virtual_objects.push_back(quad);
        const CameraModel camera = smallCamera();
        auto c = make(scene, camera, ResponseCurve::srgb());
        ASSERT_TRUE(c);
        const Image frame = constantFrame(camera.width, camera.height, 100);
        lighting::LightingSnapshot snapshot;
        lighting::FaceModulation f;
        f.corners = {{-2, -2, 0}, {2, -2, 0}, {2, 2, 0}, {-2, 2, 0}};
        f.width = f.height = 2;
        f.ratio.assign(4, lighting::Rgb::Constant(0.8f));
        f.difference.assign(4, lighting::Rgb::Constant(-0.1f));
        f.original.assign(4, lighting::Rgb::Constant(0.5f));
        f.mean_original = 0.5f;
        snapshot.faces.push_back(std::make_shared<const lighting::FaceModulation>(f));
        lighting::EstimatedLight lamp;
        lamp.kind = lighting::LightKind::kArea;
        lamp.size = {0.3, 0.3};
        lamp.world_from_object = Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(std::numbers::pi, Eigen::Vector3d::UnitX())), Eigen::Vector3d(0, 0, 1.5));
        lamp.emission = Eigen::Vector3d::Constant(3.0);
        snapshot.lights.push_back(lamp);
        snapshot.version = 1;
        render(*c, frame.view(), lookingDown(), snapshot);
        const GlObjectCounts after_first = liveGlObjects();
        for (int k = 2; k < 7; ++k) {
            snapshot.version = static_cast<std::uint64_t>(k);
            render(*c, frame.view(), lookingDown(), snapshot);
        }
        EXPECT_EQ(liveGlObjects(), after_first);
    }
    EXPECT_EQ(liveGlObjects(), before);
}

TEST_F(CompositorTest, BadInputIsAnErrorNamingIt) {
    Scene scene;
    scene.virtual_objects.push_back(sphere("ball", 0.2, {0, 0, 0.2}, Eigen::Vector3d::Constant(0.5)));
    const CameraModel camera = smallCamera();
    auto c = make(scene, camera, ResponseCurve::srgb());
    ASSERT_TRUE(c);
    const Image small = constantFrame(camera.width / 2, camera.height, 10);
    FrameInput in;
    in.image = small.view();
    in.cam_from_world = lookingDown();
    auto drawn = c->draw(in, lighting::LightingSnapshot{});
    ASSERT_FALSE(drawn);
    EXPECT_EQ(drawn.error().code, ErrorCode::kBadInput);
    EXPECT_NE(drawn.error().message.find("80x120"), std::string::npos) << drawn.error().message;
    const Image frame = constantFrame(camera.width, camera.height, 10);
    in.image = frame.view();
    in.virtual_poses = {std::nullopt, std::nullopt};  // two poses for one object
    EXPECT_FALSE(c->draw(in, lighting::LightingSnapshot{}));
    // A NaN pose draws the frame unchanged.
    in.virtual_poses.clear();
    in.cam_from_world = Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(std::nan(""), 0, 0));
    ASSERT_TRUE(c->draw(in, lighting::LightingSnapshot{}));
    auto out = c->read();
    ASSERT_TRUE(out);
    EXPECT_EQ(out->view().row(60)[3 * 80], 10);
    // A window without a display.
    const char* display = std::getenv("DISPLAY");
    const std::string saved = display ? display : "";
    unsetenv("DISPLAY");
    const char* wayland = std::getenv("WAYLAND_DISPLAY");
    const std::string saved_wayland = wayland ? wayland : "";
    unsetenv("WAYLAND_DISPLAY");
    ContextOptions window;
    window.kind = ContextKind::kWindow;
    auto w = GlContext::create(window);
    ASSERT_FALSE(w);
    EXPECT_EQ(w.error().code, ErrorCode::kDevice);
    EXPECT_NE(w.error().message.find("DISPLAY"), std::string::npos);
    if (!saved.empty()) setenv("DISPLAY", saved.c_str(), 1);
    if (!saved_wayland.empty()) setenv("WAYLAND_DISPLAY", saved_wayland.c_str(), 1);
}

// The window (under Xvfb): the same composite as offscreen, shown and read back.
TEST(CompositorWindow, ShowsTheCompositeInAWindow) {
    if (std::getenv("DISPLAY") == nullptr) GTEST_SKIP() << "no DISPLAY (run under xvfb-run)";
    ContextOptions options;
    options.kind = ContextKind::kWindow;
    options.title = "compositor-test";  // not "commonlight": e2e/live_window looks for that one
    options.width = 160;
    options.height = 120;
    auto window = GlContext::create(options);
    ASSERT_TRUE(window) << window.error().message;
    Scene scene;
    scene.virtual_objects.push_back(sphere("ball", 0.3, {0, 0, 0.3}, Eigen::Vector3d::Zero(), Eigen::Vector3d::Constant(0.7)));
    // Off-centre, so an image upside down or mirrored differs.
    scene.virtual_objects.push_back(sphere("marker", 0.1, {0.55, 0.45, 0.1}, Eigen::Vector3d::Zero(), Eigen::Vector3d::Constant(0.3)));
    const CameraModel camera = smallCamera();
    auto c = Compositor::create(**window, scene, camera, ResponseCurve::linear(), {});
    ASSERT_TRUE(c) << c.error().message;
    const Image frame = constantFrame(camera.width, camera.height, 20);
    FrameInput in;
    in.image = frame.view();
    in.cam_from_world = lookingDown();
    ASSERT_TRUE((*c)->draw(in, lighting::LightingSnapshot{}));
    // What the window shows (its back buffer, the composite blitted at the same size): the composite,
    // the right way up.
    auto shown = (*window)->readWindow();
    auto composite = (*c)->read();
    ASSERT_TRUE(shown && composite);
    ASSERT_EQ(shown->width(), composite->width());
    ASSERT_EQ(shown->height(), composite->height());
    int differing = 0;
    for (int y = 0; y < composite->height(); ++y) {
        differing += std::memcmp(shown->view().row(y), composite->view().row(y), 3 * static_cast<std::size_t>(composite->width())) != 0;
    }
    EXPECT_EQ(differing, 0) << "rows of the window that differ from the composite";
    (*window)->present();
    (*window)->pollKeys();
    EXPECT_FALSE((*window)->shouldClose());
    auto out = (*c)->read();
    ASSERT_TRUE(out);
    const Eigen::Vector2d centre = *camera.project(lookingDown().rotation * Eigen::Vector3d(0, 0, 0.6) + lookingDown().translation);
    EXPECT_NEAR(out->view().row(static_cast<int>(centre.y()))[3 * static_cast<int>(centre.x())], 0.7 * 255, 2);
    c->reset();
}

}  // namespace
}  // namespace commonlight::render

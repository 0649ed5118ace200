// The compositor on small hand-made scenes, the real side: an unchanged frame comes back byte for
// byte, YUV frames converted as the CPU converts them, the ratio and the differential rule on a
// proxy, revisions uploaded in place, the modulation only where the snapshot changes something,
// 3D points land where CameraModel::project puts them through lens distortion, real proxies hide
// virtual objects. Offscreen (EGL surfaceless); without any GL context the test exits 77 (skip).
// The virtual side: compositor_virtual_test.cpp.
#include "render/compositor.h"

#include <gtest/gtest.h>

#include "capture/convert.h"
#include "core/mesh_io.h"
#include "render/light_samples.h"
#include "tests/render/compositor_fixture.h"
#include "tests/test_support.h"

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <limits>
#include <map>
#include <numbers>
#include <random>

namespace commonlight::render {
namespace {

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
    lighting::FaceModulation f = floorFace(2, 1);
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
    lighting::FaceModulation f = floorFace(8, 8);
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
        lighting::FaceModulation f = floorFace(8, 8);
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
    lighting::FaceModulation f = floorFace(32, 32);  // 0.125 m a texel
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

// Two small shadows on a big face, at opposite corners of the view: the final pass modulates only
// the camera tiles where they project (ModulationRegion::kTiles, the default), far fewer than one
// rectangle around both, and the composite is byte for byte the one of the modulating program over
// the whole frame (kFrame), and of the rectangle (kRectangle): looking down, and from a camera
// low over the floor, which reaches behind it (the near plane clips the face's blocks). The face at
// 64 texels a side (shadows with a penumbra, several blocks of texels each) and at 16 (a shadow is
// one texel of 36 px: the filtering's reach beyond it is more than a tile). Faint texels (ratio
// 1.0015, within 2e-3) over the whole face mark no tile; a virtual ball draws its own rectangle,
// which the tiles' quads leave out; a texel lit from nothing (D only) counts too.
TEST_F(CompositorTest, TheModulatedTilesAreWhereTheShadowsAreAndTheCompositeIsTheFullFramesOne) {
    Scene scene;
    scene.real_objects.push_back(floorPlane(4.0));
    scene.virtual_objects.push_back(sphere("ball", 0.08, Eigen::Vector3d(-0.5, 0.4, 0.08), Eigen::Vector3d(0.5, 0.5, 0.5)));
    CameraModel camera = smallCamera(320, 240);
    camera.distortion.k1 = -0.2;
    camera.distortion.k2 = 0.05;
    const ResponseCurve response = ResponseCurve::srgb();
    // The floor's modulation at `n` texels a side: shadows of 12.5 cm radius and a penumbra to 19 cm
    // around (0.875, 0.625) and (-0.625, -0.375) m, a texel lit from nothing at (0.1, -0.7) m.
    const auto snapshotAt = [](int n) {
        lighting::LightingSnapshot snapshot;
        snapshot.version = 1;
        lighting::FaceModulation f = floorFace(n, n);
        const int lit_i = static_cast<int>((0.1 + 2.0) / 4.0 * n), lit_j = static_cast<int>((-0.7 + 2.0) / 4.0 * n);
        for (int j = 0; j < n; ++j) {
            for (int i = 0; i < n; ++i) {
                const Eigen::Vector2d p(-2.0 + 4.0 * (i + 0.5) / n, -2.0 + 4.0 * (j + 0.5) / n);
                const double r = std::min((p - Eigen::Vector2d(0.875, 0.625)).norm(), (p - Eigen::Vector2d(-0.625, -0.375)).norm());
                const bool lit = i == lit_i && j == lit_j;  // B~ = 0 there: the difference alone
                f.ratio.push_back(lighting::Rgb::Constant(r < 0.125 ? 0.4f : r < 0.19 ? 0.8f : (i + j) % 3 == 0 ? 1.0015f : 1.0f));
                f.original.push_back(lighting::Rgb::Constant(lit ? 0.0f : 1.0f));
                f.difference.push_back(lighting::Rgb::Constant(lit ? 0.2f : r < 0.125 ? -0.6f : r < 0.19 ? -0.2f : 0.0f));
                f.reflectance.push_back(lighting::Rgb::Constant(0.5f));
            }
        }
        f.mean_original = 1.0f;
        snapshot.faces.push_back(std::make_shared<const lighting::FaceModulation>(f));
        return snapshot;
    };
    // Camera centre to target, image x level: cam_from_world.
    const auto lookAt = [](const Eigen::Vector3d& centre, const Eigen::Vector3d& target) {
        const Eigen::Vector3d z = (target - centre).normalized();
        const Eigen::Vector3d x = z.cross(Eigen::Vector3d::UnitZ()).normalized();
        Eigen::Matrix3d r;
        r.row(0) = x;
        r.row(1) = z.cross(x);
        r.row(2) = z;
        return Rigid3d(Eigen::Quaterniond(r), -(r * centre));
    };
    const auto differing = [&](const Image& a, const Image& b) {
        int n = 0;
        for (int y = 0; y < camera.height; ++y) {
            for (int x = 0; x < 3 * camera.width; ++x) n += a.view().row(y)[x] != b.view().row(y)[x] ? 1 : 0;
        }
        return n;
    };
    const Image frame = noiseFrame(camera.width, camera.height, 23);
    const int all_tiles = ((camera.width + 15) / 16) * ((camera.height + 15) / 16);
    for (const int texels : {64, 16}) {
        const lighting::LightingSnapshot snapshot = snapshotAt(texels);
        for (const Rigid3d& pose : {lookingDown(), lookAt(Eigen::Vector3d(0.1, -1.2, 0.5), Eigen::Vector3d(0.0, 0.4, 0.0))}) {
            SCOPED_TRACE(std::to_string(texels) + " texels, camera at " + std::to_string(pose.inverse().translation.z()) + " m");
            std::map<ModulationRegion, Image> out;
            std::map<ModulationRegion, FinalPassArea> area;
            for (const ModulationRegion region : {ModulationRegion::kFrame, ModulationRegion::kRectangle, ModulationRegion::kTiles}) {
                CompositorOptions options;
                options.modulation_region = region;
                auto c = make(scene, camera, response, options);
                ASSERT_TRUE(c);
                out[region] = render(*c, frame.view(), pose, snapshot);
                area[region] = c->finalPassArea();
                const FinalPassArea& a = area[region];
                EXPECT_EQ(a.plain + a.modulated + a.with_virtual, long{camera.width} * camera.height) << "every pixel drawn once";
                EXPECT_GT(a.with_virtual, 0);
                EXPECT_LE(a.draws, 3);
            }
            EXPECT_GT(differing(out[ModulationRegion::kFrame], frame), 1000) << "the shadows darken the frame";
            EXPECT_EQ(differing(out[ModulationRegion::kTiles], out[ModulationRegion::kFrame]), 0) << "tiles";
            EXPECT_EQ(differing(out[ModulationRegion::kRectangle], out[ModulationRegion::kFrame]), 0) << "rectangle";
            const int tiles = area[ModulationRegion::kTiles].modulated_tiles, rectangle = area[ModulationRegion::kRectangle].modulated_tiles;
            EXPECT_EQ(area[ModulationRegion::kFrame].modulated_tiles, all_tiles);
            EXPECT_GT(tiles, 0);
            // (Measured: 67 and 46 tiles at 64 texels, the rectangle 270 and 200, of 300; at 16
            // texels, where a texel's filtering reaches 108 px, 133 and 138.)
            EXPECT_LT((texels == 64 ? 3 : 1) * tiles, rectangle) << tiles << " tiles, the rectangle " << rectangle;
            if (texels == 64) {
                EXPECT_LT(4 * tiles, all_tiles) << tiles << " tiles of " << all_tiles;
            }
        }
    }
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
}  // namespace
}  // namespace commonlight::render

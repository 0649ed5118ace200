// The compositor on small hand-made scenes, the virtual side: textured meshes, antialiased edges,
// the shading's scale, GGX lobes and area-light highlights, shadow maps with real and virtual
// occluders, camera matching (noise, blur), no leaked GL objects, bad input, and the window (it
// needs a display: xvfb-run). Offscreen (EGL surfaceless); without any GL context the test exits 77
// (skip). The real side: compositor_test.cpp.
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
#include <numbers>
#include <random>

namespace commonlight::render {
namespace {

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

// A virtual tile of `size` at the origin (facing +z), Lambertian of albedo 0.8.
VirtualObject whiteTile(const Eigen::Vector2d& size) {
    VirtualObject tile;
    tile.name = "tile";
    tile.shape = PlaneShape{size};
    tile.material.albedo = Eigen::Vector3d::Constant(0.8);
    return tile;
}

// A real box of side `side` centred at `at`.
RealObject realBlock(double side, const Eigen::Vector3d& at) {
    RealObject block;
    block.name = "block";
    block.shape = BoxShape{Eigen::Vector3d::Constant(side)};
    block.world_from_object = Rigid3d(Eigen::Quaterniond::Identity(), at);
    return block;
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
    scene.virtual_objects.push_back(whiteTile(Eigen::Vector2d(1.6, 1.0)));
    VirtualObject cube;
    cube.name = "cube";
    cube.shape = BoxShape{Eigen::Vector3d(0.2, 0.2, 0.2)};
    cube.placement = FixedPlacement{Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(-0.4, 0.0, 0.4))};
    scene.virtual_objects.push_back(cube);
    scene.real_objects.push_back(realBlock(0.2, Eigen::Vector3d(0.4, 0.0, 0.4)));
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
    scene.virtual_objects.push_back(whiteTile(Eigen::Vector2d(0.4, 0.4)));
    scene.real_objects.push_back(realBlock(0.1, Eigen::Vector3d(0.0, 0.0, 0.45)));
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
        lighting::FaceModulation f = floorFace(2, 2);
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
    auto window = testWindow("compositor-test", 160, 120);
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

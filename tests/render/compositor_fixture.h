// The compositor tests' shared fixture (compositor_test.cpp, compositor_virtual_test.cpp): an
// offscreen GL context for the suite (exit 77, skip, without one), small cameras and frames, and
// the proxies and objects the tests place.
#pragma once

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "render/compositor.h"
#include "tests/render/gl_suite.h"

namespace commonlight::render {

inline CameraModel smallCamera(int w = 160, int h = 120) {
    CameraModel c;
    c.width = w;
    c.height = h;
    c.fx = c.fy = 0.9 * w;
    c.cx = 0.5 * w - 0.5 + 0.37;  // off-centre on purpose: the principal point must be honoured
    c.cy = 0.5 * h - 0.5 - 0.21;
    return c;
}

// Camera at (0, 0, 2) looking down -z (world z up), image x along world x.
inline Rigid3d lookingDown() {
    // cam_from_world: x_cam = x, y_cam = -y, z_cam = 2 - z.
    Eigen::Matrix3d r;
    r << 1, 0, 0, 0, -1, 0, 0, 0, -1;
    return Rigid3d(Eigen::Quaterniond(r), Eigen::Vector3d(0, 0, 2));
}

inline Image constantFrame(int w, int h, std::uint8_t value) {
    Image image(PixelFormat::kRgb8, w, h);
    for (int y = 0; y < h; ++y) std::fill_n(image.mutableView().row(y), 3 * w, value);
    return image;
}

inline Image noiseFrame(int w, int h, unsigned seed) {
    Image image(PixelFormat::kRgb8, w, h);
    std::mt19937 rng(seed);
    for (int y = 0; y < h; ++y) {
        for (int x = 0; x < 3 * w; ++x) image.mutableView().row(y)[x] = static_cast<std::uint8_t>(rng() & 0xff);
    }
    return image;
}

class CompositorTest : public GlSuite {
protected:
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

inline RealObject floorPlane(double size = 4.0) {
    RealObject o;
    o.name = "floor";
    o.shape = PlaneShape{Eigen::Vector2d(size, size)};
    return o;
}

// floorPlane(4.0)'s face as a snapshot modulation of width x height texels (values left empty).
inline lighting::FaceModulation floorFace(int width, int height) {
    lighting::FaceModulation f;
    f.object_index = 0;
    f.face = 0;
    f.corners = {{-2, -2, 0}, {2, -2, 0}, {2, 2, 0}, {-2, 2, 0}};
    f.width = width;
    f.height = height;
    return f;
}

inline VirtualObject sphere(const std::string& name, double radius, const Eigen::Vector3d& at,
                            const Eigen::Vector3d& albedo, std::optional<Eigen::Vector3d> emission = std::nullopt) {
    VirtualObject v;
    v.name = name;
    v.shape = SphereShape{radius};
    v.material.albedo = albedo;
    v.emission = emission;
    v.placement = FixedPlacement{Rigid3d(Eigen::Quaterniond::Identity(), at)};
    return v;
}

}  // namespace commonlight::render

// Tags as the tracker will see them: rendered lying exactly on real surfaces (a floor plane and a
// box's top face, no lift), detected by libapriltag's own detector with the right ids and corners.
// This checks the texture's orientation end to end (a mirrored or rotated texture decodes to
// another id or puts libapriltag's first corner elsewhere) and that coplanar tag and surface do
// not fight: every pixel inside a tag sees the tag.
#include <apriltag/apriltag.h>
#include <apriltag/tag36h11.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

#include <gtest/gtest.h>

#include "mocks/sim/render.h"

namespace commonlight::mocks::sim {
namespace {

using Eigen::Vector2d;
using Eigen::Vector3d;

Rigid3d lookAt(const Vector3d& eye, const Vector3d& target) {
    const Vector3d z = (target - eye).normalized();
    const Vector3d x = z.cross(Vector3d::UnitZ()).normalized();
    Eigen::Matrix3d r;
    r.col(0) = x;
    r.col(1) = z.cross(x);
    r.col(2) = z;
    return {Eigen::Quaterniond(r), eye};
}

TEST(RenderTags, CoplanarTagsAreDetectedWithTheirIdsAndCorners) {
    constexpr double kSize = 0.1;
    Scene scene;
    const auto grey = [](double a) { return RgbOrEstimate::constant(Vector3d::Constant(a)); };
    scene.real_objects.push_back({"floor", PlaneShape{{3, 3}}, Rigid3d::identity(), grey(0.3)});
    scene.real_objects.push_back(
        {"table", BoxShape{{0.5, 0.5, 0.4}}, Rigid3d({1, 0, 0, 0}, {0.3, 0.1, 0.2}), grey(0.4)});
    // Tag 7 on the floor, tag 12 on the table top (z = 0.4), both exactly on the surface.
    scene.tags.items.push_back({7, kSize, Rigid3d::fromRpyDeg({-0.25, -0.05, 0.0}, {0, 0, -20}), 0.04, 0.8});
    scene.tags.items.push_back({12, kSize, Rigid3d::fromRpyDeg({0.3, 0.1, 0.4}, {0, 0, 35}), 0.04, 0.8});
    scene.lights.push_back({"sun", DirectionalLightShape{Vector3d(0.1, 0.2, -1).normalized()}, Rigid3d::identity(),
                            RgbOrEstimate::constant(Vector3d::Constant(2.0))});
    scene.lights.push_back(
        {"sky", DistantLightShape{16}, Rigid3d::identity(), RgbOrEstimate::constant(Vector3d::Constant(0.1))});
    auto sim = SimScene::build(scene);
    ASSERT_TRUE(sim) << sim.error().message;

    RenderRequest request;
    request.scene = &*sim;
    request.camera.width = 640;
    request.camera.height = 480;
    request.camera.fx = request.camera.fy = 600;
    request.camera.cx = 319.5;
    request.camera.cy = 239.5;
    request.camera.distortion.k1 = -0.05;
    request.world_from_cam = lookAt({-0.1, -0.9, 0.9}, {0.05, 0.05, 0.15});
    request.spp = 16;
    request.max_depth = 2;
    auto out = render(request);
    ASSERT_TRUE(out) << out.error().message;

    // 8-bit grey for the detector: white paper in direct sun maps to ~200.
    const double white = 0.8 * 2.0 / std::numbers::pi;
    std::vector<std::uint8_t> grey8(640 * 480);
    for (int v = 0; v < 480; ++v) {
        const auto* row = reinterpret_cast<const float*>(out->radiance.data() + v * out->radiance.stride());
        for (int u = 0; u < 640; ++u)
            grey8[v * 640 + u] = static_cast<std::uint8_t>(std::clamp(200.0 * row[3 * u] / white, 0.0, 255.0));
    }
    image_u8_t image = {640, 480, 640, grey8.data()};
    apriltag_family_t* family = tag36h11_create();               // destroyed below
    apriltag_detector_t* detector = apriltag_detector_create();  // destroyed below
    apriltag_detector_add_family(detector, family);
    detector->quad_decimate = 1.0f;
    detector->nthreads = 1;
    zarray_t* detections = apriltag_detector_detect(detector, &image);  // destroyed below

    const Rigid3d cam_from_world = request.world_from_cam.inverse();
    // libapriltag's corners wrap counter-clockwise in the image starting at the tag's bottom left:
    // in our tag frame (top edge +y) that is (-s/2, -s/2), (s/2, -s/2), (s/2, s/2), (-s/2, s/2).
    const std::vector<Vector2d> corner_xy = {{-1, -1}, {1, -1}, {1, 1}, {-1, 1}};
    int found = 0;
    for (int i = 0; i < zarray_size(detections); ++i) {
        apriltag_detection_t* det = nullptr;
        zarray_get(detections, i, &det);
        const TagItem* item = scene.tags.find(det->id);
        ASSERT_NE(item, nullptr) << "detected an id that is not in the scene: " << det->id;
        EXPECT_EQ(det->hamming, 0);
        ++found;
        for (int c = 0; c < 4; ++c) {
            const Vector3d corner =
                item->world_from_tag * Vector3d(0.5 * kSize * corner_xy[c].x(), 0.5 * kSize * corner_xy[c].y(), 0);
            const auto expected = request.camera.project(cam_from_world * corner);
            ASSERT_TRUE(expected);
            // libapriltag puts the centre of the top-left pixel at (0.5, 0.5).
            const Vector2d detected(det->p[c][0] - 0.5, det->p[c][1] - 0.5);
            const double error = (detected - *expected).norm();
            std::printf("  tag %2d corner %d: detected (%.2f, %.2f), projected (%.2f, %.2f), %.3f px\n", det->id, c,
                        detected.x(), detected.y(), expected->x(), expected->y(), error);
            EXPECT_LT(error, 0.5) << "tag " << det->id << " corner " << c;
        }
    }
    apriltag_detections_destroy(detections);
    apriltag_detector_destroy(detector);
    tag36h11_destroy(family);
    EXPECT_EQ(found, 2);

    // No z-fighting: every pixel whose centre ray lands inside a tag's printed square sees that tag.
    for (const TagItem& item : scene.tags.items) {
        int inside = 0;
        for (int v = 0; v < 480; ++v) {
            for (int u = 0; u < 640; ++u) {
                const auto ray = request.camera.unproject(Vector2d(u, v));
                const Vector3d dir = (request.world_from_cam.rotation * ray->normalized()).normalized();
                const Rigid3d tag_from_world = item.world_from_tag.inverse();
                const Vector3d o = tag_from_world * request.world_from_cam.translation;
                const Vector3d d = tag_from_world.rotation * dir;
                const Vector3d p = o + (-o.z() / d.z()) * d;
                if (std::max(std::abs(p.x()), std::abs(p.y())) > 0.6 * kSize) continue;  // inside the white border
                ++inside;
                const std::int32_t id = out->object_id[v * 640 + u];
                ASSERT_GE(id, 0);
                EXPECT_EQ(sim->objects()[id].kind, ObjectKind::kTag) << u << "," << v;
                EXPECT_EQ(sim->objects()[id].name, "tag " + std::to_string(item.id)) << u << "," << v;
            }
        }
        EXPECT_GT(inside, 500) << "tag " << item.id;
    }
}

}  // namespace
}  // namespace commonlight::mocks::sim

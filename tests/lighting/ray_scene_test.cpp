// lighting/ray_scene.h: a virtual sphere's visibility in closed form against Embree's own sphere
// (the same object traced through its instance by intersectVirtual()), with a mesh object beside
// it (still traced by Embree), masks, a disabled object and a moved one; a mesh traced only where a
// segment meets its bounding ball, with Embree's answer; intersectVirtualExcept()'s ball test; a prepared
// segment's answer (prepareSegment()) against the plain one, also with the objects gathered once
// (virtualSet()), for few objects and for more than VirtualSet::kMax; the prepared segment against
// the lifted segment it stands for, bit for bit; the change stamps of the objects (virtualChangedSince()).
#include "lighting/ray_scene.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

namespace commonlight::lighting {
namespace {

// A floor face far below, so the real scene is not empty.
std::vector<Face> floorFace() {
    Face f;
    f.origin = {-5, -5, -3};
    f.edge_s = {10, 0, 0};
    f.edge_t = {0, 10, 0};
    f.normal = {0, 0, 1};
    f.area = 100.0;
    return {f};
}

// A cube of side 0.4 centred on `at` in its object frame, as six faces (outward normals).
VirtualShape cube(const Eigen::Vector3d& at = Eigen::Vector3d::Zero()) {
    VirtualShape s;
    const double h = 0.2;
    const auto face = [&](Eigen::Vector3d o, Eigen::Vector3d es, Eigen::Vector3d et) {
        Face f;
        f.owner = FaceOwner::kVirtual;
        f.origin = o + at;
        f.edge_s = es;
        f.edge_t = et;
        f.normal = es.cross(et).normalized();
        f.area = es.cross(et).norm();
        s.faces.push_back(f);
    };
    const double a = 2 * h;
    face({-h, -h, -h}, {0, a, 0}, {a, 0, 0});  // z-
    face({-h, -h, h}, {a, 0, 0}, {0, a, 0});   // z+
    face({-h, -h, -h}, {a, 0, 0}, {0, 0, a});  // y-
    face({-h, h, -h}, {0, 0, a}, {a, 0, 0});   // y+
    face({-h, -h, -h}, {0, 0, a}, {0, a, 0});  // x-
    face({h, -h, -h}, {0, a, 0}, {0, 0, a});   // x+
    return s;
}

TEST(RayScene, SphereInClosedFormAgreesWithEmbree) {
    VirtualShape sphere;
    sphere.sphere_radius = 0.3;
    auto built = RayScene::build(floorFace(), {}, {sphere, cube()});
    ASSERT_TRUE(built) << built.error().message;
    RayScene& rays = **built;
    const Eigen::Vector3d centre(0.2, -0.1, 0.4), cube_at(2.0, 0.0, 0.0);
    rays.setVirtualPose(0, Rigid3d(Eigen::Quaterniond::Identity(), centre));
    rays.setVirtualPose(1, Rigid3d(Eigen::Quaterniond::Identity(), cube_at));
    ASSERT_TRUE(rays.commitVirtual());
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    const std::uint32_t sphere_bit = RayScene::virtualBit(0), cube_bit = RayScene::virtualBit(1);
    int blocked = 0, open = 0, ambiguous = 0;
    for (int k = 0; k < 20000; ++k) {
        // Segments around the sphere: through it, past it, from inside it, ending inside it.
        const Eigen::Vector3d a = centre + Eigen::Vector3d(u(rng), u(rng), u(rng));
        const Eigen::Vector3d b = centre + Eigen::Vector3d(u(rng), u(rng), u(rng));
        const double length = (b - a).norm();
        if (length < 1e-3) continue;
        const Eigen::Vector3d dir = (b - a) / length;
        // Embree's answer: the first hit on the sphere within the segment (no normals: no lift;
        // the segment stops epsilon() short of b).
        const RayHit hit = rays.intersectVirtual(a, dir, length - rays.epsilon());
        const bool embree = hit.kind == HitKind::kVirtual && hit.index == 0;
        // Segments that graze the sphere or end on its surface are left out (float against double).
        const Eigen::Vector3d closest = a + std::clamp((centre - a).dot(dir), 0.0, length) * dir;
        const double margin = 1e-4;
        if (std::abs((closest - centre).norm() - 0.3) < margin || std::abs((a - centre).norm() - 0.3) < margin ||
            std::abs((b - centre).norm() - 0.3) < margin) {
            ++ambiguous;
            continue;
        }
        const bool closed_form = rays.occludedVirtual(a, Eigen::Vector3d::Zero(), b, Eigen::Vector3d::Zero(), sphere_bit);
        ASSERT_EQ(closed_form, embree) << "segment " << k << " from " << a.transpose() << " to " << b.transpose();
        (closed_form ? blocked : open)++;
        // The cube is far away: with its bit as well, the same answer; with its bit alone, open.
        ASSERT_EQ(rays.occludedVirtual(a, Eigen::Vector3d::Zero(), b, Eigen::Vector3d::Zero(), sphere_bit | cube_bit), closed_form);
        ASSERT_FALSE(rays.occludedVirtual(a, Eigen::Vector3d::Zero(), b, Eigen::Vector3d::Zero(), cube_bit));
    }
    EXPECT_GT(blocked, 2000);
    EXPECT_GT(open, 2000);
    EXPECT_LT(ambiguous, 200);
    // A ray to infinity from inside the sphere meets its far side; from outside, pointing away, nothing.
    EXPECT_TRUE(rays.occludedVirtualRay(centre, Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitX(), sphere_bit));
    EXPECT_FALSE(rays.occludedVirtualRay(centre + Eigen::Vector3d(0, 0, 0.5), Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitZ(), sphere_bit));
    // The mesh is still traced (Embree): a segment through the cube is blocked by it alone.
    const Eigen::Vector3d p = cube_at - Eigen::Vector3d(1, 0, 0), q = cube_at + Eigen::Vector3d(1, 0, 0);
    EXPECT_TRUE(rays.occludedVirtual(p, Eigen::Vector3d::Zero(), q, Eigen::Vector3d::Zero(), cube_bit));
    EXPECT_FALSE(rays.occludedVirtual(p, Eigen::Vector3d::Zero(), q, Eigen::Vector3d::Zero(), sphere_bit));
    // A segment lifted off its surfaces (normals -y: the lift moves it epsilon towards -y) grazes
    // the sphere that the segment itself passes half an epsilon from: blocked.
    const double eps = rays.epsilon();
    const Eigen::Vector3d graze(0, 0.3 + 0.5 * eps, 0), down(0, -1, 0);
    EXPECT_FALSE(rays.occludedVirtual(centre + graze - Eigen::Vector3d(1, 0, 0), Eigen::Vector3d::Zero(), centre + graze + Eigen::Vector3d(1, 0, 0),
                                      Eigen::Vector3d::Zero(), sphere_bit));
    EXPECT_TRUE(rays.occludedVirtual(centre + graze - Eigen::Vector3d(1, 0, 0), down, centre + graze + Eigen::Vector3d(1, 0, 0), down, sphere_bit));
    // Moved: the answer follows the committed pose only.
    const Eigen::Vector3d s = centre - Eigen::Vector3d(1, 0, 0), t = centre + Eigen::Vector3d(1, 0, 0);
    EXPECT_TRUE(rays.occludedVirtual(s, Eigen::Vector3d::Zero(), t, Eigen::Vector3d::Zero(), sphere_bit));
    rays.setVirtualPose(0, Rigid3d(Eigen::Quaterniond::Identity(), centre + Eigen::Vector3d(0, 0, 1)));
    EXPECT_TRUE(rays.occludedVirtual(s, Eigen::Vector3d::Zero(), t, Eigen::Vector3d::Zero(), sphere_bit));  // not committed yet
    ASSERT_TRUE(rays.commitVirtual());
    EXPECT_FALSE(rays.occludedVirtual(s, Eigen::Vector3d::Zero(), t, Eigen::Vector3d::Zero(), sphere_bit));
    // Disabled: it blocks nothing.
    rays.setVirtualPose(0, Rigid3d(Eigen::Quaterniond::Identity(), centre));
    rays.setVirtualEnabled(0, false);
    ASSERT_TRUE(rays.commitVirtual());
    EXPECT_FALSE(rays.occludedVirtual(s, Eigen::Vector3d::Zero(), t, Eigen::Vector3d::Zero(), ~0u));
    rays.setVirtualEnabled(0, true);
    ASSERT_TRUE(rays.commitVirtual());
    EXPECT_TRUE(rays.occludedVirtual(s, Eigen::Vector3d::Zero(), t, Eigen::Vector3d::Zero(), ~0u));
}

// A mesh is traced through Embree only where a segment meets its bounding ball: the answer is
// Embree's own (intersectVirtual() has no such test) for segments through the cube, past its
// corners (which lie on the ball) and from inside it, with the cube off its object origin, rotated
// and moved.
// intersectVirtualExcept() (the probes' rays leaving their object): with the excluded object
// alone, nothing (from inside it, through it); with a second object, that one's hit beyond it.
TEST(RayScene, IntersectVirtualExceptSeesOnlyTheOthers) {
    VirtualShape sphere;
    sphere.sphere_radius = 0.3;
    for (const bool two : {false, true}) {
        std::vector<VirtualShape> shapes{sphere};
        if (two) shapes.push_back(cube());
        auto built = RayScene::build(floorFace(), {}, shapes);
        ASSERT_TRUE(built) << built.error().message;
        RayScene& rays = **built;
        rays.setVirtualPose(0, Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0, 0, 0)));
        if (two) rays.setVirtualPose(1, Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(2, 0, 0)));
        ASSERT_TRUE(rays.commitVirtual());
        for (const Eigen::Vector3d& origin : {Eigen::Vector3d(0.1, 0, 0), Eigen::Vector3d(-1, 0, 0)}) {
            ASSERT_EQ(rays.intersectVirtual(origin, Eigen::Vector3d::UnitX()).index, 0) << two;
            const RayHit hit = rays.intersectVirtualExcept(origin, Eigen::Vector3d::UnitX(), 0);
            if (two) {
                ASSERT_EQ(hit.kind, HitKind::kVirtual);
                EXPECT_EQ(hit.index, 1);
                EXPECT_NEAR(hit.distance, 1.8 - origin.x(), 1e-4);
            } else {
                EXPECT_EQ(hit.kind, HitKind::kNone);
            }
            // Excluding the other one: the sphere.
            if (two) {
                EXPECT_EQ(rays.intersectVirtualExcept(origin, Eigen::Vector3d::UnitX(), 1).index, 0);
            }
        }
    }
}

// A segment prepared once (prepareSegment(): lifted, without the balls' pre-test) gets the answer
// of occludedVirtual() on its two ends, for segments through, past and ending on two spheres and a
// rotated cube, with and without normals, short ones, every mask, an object disabled and moved;
// the same with the mask's objects gathered once (virtualSet()).
TEST(RayScene, PreparedSegmentKeepsTheAnswer) {
    VirtualShape sphere;
    sphere.sphere_radius = 0.3;
    auto built = RayScene::build(floorFace(), {}, {sphere, cube(Eigen::Vector3d(0.05, 0, 0)), sphere});
    ASSERT_TRUE(built) << built.error().message;
    RayScene& rays = **built;
    const Eigen::Vector3d at[3] = {{0, 0, 0}, {0.8, 0.2, 0.1}, {-0.3, 0.7, 0.3}};
    const Eigen::Quaterniond q(Eigen::AngleAxisd(0.6, Eigen::Vector3d(1, 2, 3).normalized()));
    std::mt19937 rng(23);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    int blocked = 0, open = 0;
    for (int round = 0; round < 3; ++round) {
        const Eigen::Vector3d shift = 0.2 * round * Eigen::Vector3d(1, -1, 0.5);
        for (int v = 0; v < 3; ++v) rays.setVirtualPose(v, Rigid3d(v == 1 ? q : Eigen::Quaterniond::Identity(), at[v] + shift));
        rays.setVirtualEnabled(2, round != 1);
        ASSERT_TRUE(rays.commitVirtual());
        for (int k = 0; k < 6000; ++k) {
            // Ends near the objects' surfaces (some on them), some segments shorter than the lifts.
            const int v = k % 3;
            const Eigen::Vector3d n = Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized();
            const Eigen::Vector3d a = at[v] + shift + (k % 4 == 0 ? 0.3 : 0.3 + 0.8 * std::abs(u(rng))) * n;
            const Eigen::Vector3d b = k % 11 == 0 ? Eigen::Vector3d(a + rays.epsilon() * Eigen::Vector3d(u(rng), u(rng), u(rng)))
                                                  : Eigen::Vector3d(at[(k + 1) % 3] + shift + 1.2 * Eigen::Vector3d(u(rng), u(rng), u(rng)));
            const Eigen::Vector3d na = k % 3 == 0 ? Eigen::Vector3d(Eigen::Vector3d::Zero()) : n;
            const Eigen::Vector3d nb = k % 5 == 0 ? Eigen::Vector3d(Eigen::Vector3d::Zero())
                                                  : Eigen::Vector3d(Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized());
            const std::uint32_t mask = static_cast<std::uint32_t>(k % 8);
            const PreparedSegment s = rays.prepareSegment(a, na, b, nb);
            const bool expected = rays.occludedVirtual(a, na, b, nb, mask);
            ASSERT_EQ(rays.occludedVirtual(s, mask), expected) << "round " << round << " segment " << k;
            ASSERT_EQ(rays.occludedVirtual(s, rays.virtualSet(mask)), expected) << "set, round " << round << " segment " << k;
            (expected ? blocked : open)++;
        }
    }
    EXPECT_GT(blocked, 1500);
    EXPECT_GT(open, 3000);
}

// More objects than a VirtualSet holds (spheres and cubes, two sharing a mask bit: objects v and
// v + 32): virtualSet()'s answers are still occludedVirtual()'s for every mask tried.
TEST(RayScene, VirtualSetKeepsTheAnswerWithManyObjects) {
    VirtualShape sphere;
    sphere.sphere_radius = 0.15;
    std::vector<VirtualShape> shapes;
    for (int v = 0; v < 34; ++v) shapes.push_back(v % 2 == 0 ? sphere : cube());
    auto built = RayScene::build(floorFace(), {}, shapes);
    ASSERT_TRUE(built) << built.error().message;
    RayScene& rays = **built;
    std::mt19937 rng(41);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    std::vector<Eigen::Vector3d> at;
    for (int v = 0; v < 34; ++v) {
        at.emplace_back(1.5 * u(rng), 1.5 * u(rng), 0.5 * u(rng));
        rays.setVirtualPose(v, Rigid3d(Eigen::Quaterniond::Identity(), at.back()));
    }
    rays.setVirtualEnabled(5, false);
    ASSERT_TRUE(rays.commitVirtual());
    int blocked = 0, open = 0, general = 0, gathered = 0;
    for (int k = 0; k < 4000; ++k) {
        const Eigen::Vector3d a = at[static_cast<std::size_t>(k % 34)] + 0.4 * Eigen::Vector3d(u(rng), u(rng), u(rng));
        const Eigen::Vector3d b = at[static_cast<std::size_t>((k * 7 + 3) % 34)] + 0.4 * Eigen::Vector3d(u(rng), u(rng), u(rng));
        const Eigen::Vector3d na = k % 2 == 0 ? Eigen::Vector3d(Eigen::Vector3d::Zero()) : Eigen::Vector3d(Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized());
        // Masks of one to many bits (bit 0 and bit 1: two objects each).
        std::uint32_t mask = 0;
        const int bits = 1 + k % 9;
        for (int i = 0; i < bits; ++i) mask |= RayScene::virtualBit(static_cast<int>(rng() % 34));
        const PreparedSegment s = rays.prepareSegment(a, na, b, Eigen::Vector3d::Zero());
        const bool expected = rays.occludedVirtual(a, na, b, Eigen::Vector3d::Zero(), mask);
        const VirtualSet set = rays.virtualSet(mask);
        (set.general ? general : gathered)++;
        ASSERT_EQ(rays.occludedVirtual(s, set), expected) << "segment " << k << " mask " << mask;
        (expected ? blocked : open)++;
    }
    EXPECT_GT(blocked, 400);
    EXPECT_GT(open, 400);
    EXPECT_GT(general, 400);
    EXPECT_GT(gathered, 400);
}

// The spheres of a VirtualSet answered inline (RayScene::occludedVirtual(segment, set)) against
// the plain answer: four spheres and a cube, every mask of the five, segments starting or ending
// inside a sphere, passing at about its radius, or short of it.
TEST(RayScene, InlineSpheresOfAVirtualSetKeepTheAnswer) {
    VirtualShape sphere;
    sphere.sphere_radius = 0.2;
    std::vector<VirtualShape> shapes{sphere, sphere, cube(), sphere, sphere};
    auto built = RayScene::build(floorFace(), {}, shapes);
    ASSERT_TRUE(built) << built.error().message;
    RayScene& rays = **built;
    const Eigen::Vector3d at[5] = {{0, 0, 0}, {0.7, 0, 0}, {0, 0.7, 0}, {0.7, 0.7, 0.2}, {-0.5, 0.3, -0.2}};
    for (int v = 0; v < 5; ++v) rays.setVirtualPose(v, Rigid3d(Eigen::Quaterniond::Identity(), at[v]));
    ASSERT_TRUE(rays.commitVirtual());
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    int blocked = 0, open = 0, inside = 0;
    for (int k = 0; k < 12000; ++k) {
        const int v = k % 5, w = (k / 5) % 5;
        const Eigen::Vector3d n = Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized();
        // From inside a sphere, on it, or about its radius away; to another object or near this one.
        const double r = k % 3 == 0 ? 0.15 * std::abs(u(rng)) : 0.2 + 0.05 * u(rng);
        const Eigen::Vector3d a = at[v] + r * n;
        const Eigen::Vector3d b = k % 4 == 0 ? Eigen::Vector3d(a + 0.1 * Eigen::Vector3d(u(rng), u(rng), u(rng)))
                                             : Eigen::Vector3d(at[w] + 0.25 * Eigen::Vector3d(u(rng), u(rng), u(rng)));
        const Eigen::Vector3d na = k % 2 == 0 ? Eigen::Vector3d(Eigen::Vector3d::Zero()) : n;
        const std::uint32_t mask = 1u + static_cast<std::uint32_t>(k % 31);
        const bool expected = rays.occludedVirtual(a, na, b, Eigen::Vector3d::Zero(), mask);
        const PreparedSegment s = rays.prepareSegment(a, na, b, Eigen::Vector3d::Zero());
        ASSERT_EQ(rays.occludedVirtual(s, rays.virtualSet(mask)), expected) << "segment " << k << " mask " << mask;
        (expected ? blocked : open)++;
        inside += r < 0.2 ? 1 : 0;
    }
    EXPECT_GT(blocked, 3000);
    EXPECT_GT(open, 3000);
    EXPECT_GT(inside, 3000);
}

// Real rays as packets (occludedRealMany()) give occludedReal()'s answers: segments between the
// faces of a closed box room with a lamp in its ceiling and a pillar, grazing ones along the walls,
// ones ending on the lamp, short ones, in batches of 1 to 16.
// A 3 x 2 x 2.5 m room (inward normals), a 0.4 m pillar in it and a ceiling lamp.
void pillarRoom(std::vector<Face>& faces, LightGeometry& lamp) {
    const auto face = [&](Eigen::Vector3d o, Eigen::Vector3d es, Eigen::Vector3d et) {
        Face f;
        f.origin = o;
        f.edge_s = es;
        f.edge_t = et;
        f.normal = es.cross(et).normalized();
        f.area = es.cross(et).norm();
        faces.push_back(f);
    };
    face({0, 0, 0}, {0, 2, 0}, {3, 0, 0});
    face({0, 0, 2.5}, {3, 0, 0}, {0, 2, 0});
    face({0, 0, 0}, {3, 0, 0}, {0, 0, 2.5});
    face({0, 2, 0}, {0, 0, 2.5}, {3, 0, 0});
    face({0, 0, 0}, {0, 0, 2.5}, {0, 2, 0});
    face({3, 0, 0}, {0, 2, 0}, {0, 0, 2.5});
    face({1.3, 0.8, 0}, {0.4, 0, 0}, {0, 0, 1.5});
    face({1.3, 1.2, 0}, {0, 0, 1.5}, {0.4, 0, 0});
    face({1.3, 0.8, 0}, {0, 0, 1.5}, {0, 0.4, 0});
    face({1.7, 0.8, 0}, {0, 0.4, 0}, {0, 0, 1.5});
    lamp.polygon = {{1.2, 0.7, 2.5}, {1.8, 0.7, 2.5}, {1.8, 1.3, 2.5}, {1.2, 1.3, 2.5}};
}

TEST(RayScene, RealPacketsKeepTheAnswer) {
    std::vector<Face> faces;
    LightGeometry lamp;
    pillarRoom(faces, lamp);
    auto built = RayScene::build(faces, {lamp}, {});
    ASSERT_TRUE(built) << built.error().message;
    const RayScene& rays = **built;
    std::mt19937 rng(77);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    const auto onFace = [&](const Face& f) { return Eigen::Vector3d(f.origin + u(rng) * f.edge_s + u(rng) * f.edge_t); };
    int blocked = 0, open = 0;
    for (int batch = 0; batch < 600; ++batch) {
        const int count = 1 + batch % 16;
        std::vector<PreparedSegment> segments;
        std::vector<bool> expected;
        for (int k = 0; k < count; ++k) {
            const Face& fa = faces[rng() % faces.size()];
            const Eigen::Vector3d a = onFace(fa);
            Eigen::Vector3d b, nb = Eigen::Vector3d::Zero();
            switch ((batch + k) % 4) {
                case 0: b = onFace(faces[rng() % faces.size()]); nb = faces[rng() % faces.size()].normal; break;
                case 1: b = lamp.polygon[0] + u(rng) * (lamp.polygon[1] - lamp.polygon[0]) + u(rng) * (lamp.polygon[3] - lamp.polygon[0]); nb = {0, 0, -1}; break;
                case 2: b = a + 2.0 * rays.epsilon() * Eigen::Vector3d(u(rng), u(rng), u(rng)); break;  // short
                default: b = a + Eigen::Vector3d(u(rng) - 0.5, u(rng) - 0.5, 0.0); break;  // along the face's plane
            }
            segments.push_back(rays.prepareSegment(a, fa.normal, b, nb));
            expected.push_back(rays.occludedReal(a, fa.normal, b, nb));
        }
        const std::uint64_t got = rays.occludedRealMany(segments.data(), count);
        for (int k = 0; k < count; ++k) {
            ASSERT_EQ(((got >> k) & 1u) != 0, expected[static_cast<std::size_t>(k)]) << "batch " << batch << " segment " << k;
            (expected[static_cast<std::size_t>(k)] ? blocked : open)++;
        }
        EXPECT_EQ(got >> count, 0u);
    }
    EXPECT_GT(blocked, 300);
    EXPECT_GT(open, 300);
}

// intersectRealMany() and intersectAllMany() (packets of 8: the probes' rays, the observations')
// give each ray the hit intersectReal() and intersectAll() give it: the same face, lamp or virtual
// object and distance, for 1-20 rays from one point (a partial last packet), from points in the
// room and on the pillar's side, some with a finite reach (misses), a sphere and a cube standing in
// the room.
TEST(RayScene, HitsInPacketsEqualOneRayAtATime) {
    std::vector<Face> faces;
    LightGeometry lamp;
    pillarRoom(faces, lamp);
    VirtualShape sphere;
    sphere.sphere_radius = 0.25;
    auto built = RayScene::build(faces, {lamp}, {sphere, cube()});
    ASSERT_TRUE(built) << built.error().message;
    RayScene& rays = **built;
    rays.setVirtualPose(0, Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0.7, 0.6, 0.8)));
    rays.setVirtualPose(1, Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.6, Eigen::Vector3d(1, 2, 3).normalized())), Eigen::Vector3d(2.2, 1.3, 1.0)));
    ASSERT_TRUE(rays.commitVirtual());
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    std::normal_distribution<double> g(0.0, 1.0);
    int faces_hit = 0, lamp_hit = 0, missed = 0, pillar_hit = 0, virtual_hit = 0;
    for (int probe = 0; probe < 400; ++probe) {
        const int count = 1 + probe % 20;
        const Eigen::Vector3d origin = probe % 5 == 0 ? Eigen::Vector3d(1.3 - 0.01 * u(rng), 0.8 + 0.4 * u(rng), 1.5 * u(rng))
                                                      : Eigen::Vector3d(0.1 + 2.8 * u(rng), 0.1 + 1.8 * u(rng), 0.1 + 2.3 * u(rng));
        const double reach = probe % 3 == 0 ? 0.5 + u(rng) : 1e30;
        std::vector<Eigen::Vector3d> dirs;
        for (int k = 0; k < count; ++k) dirs.push_back(Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized());
        std::vector<RayHit> real(static_cast<std::size_t>(count)), all(static_cast<std::size_t>(count));
        rays.intersectRealMany(origin, dirs.data(), count, real.data(), reach);
        rays.intersectAllMany(origin, dirs.data(), count, all.data(), reach);
        for (int k = 0; k < count; ++k) {
            const Eigen::Vector3d& d = dirs[static_cast<std::size_t>(k)];
            for (const auto& [one, many] : {std::pair{rays.intersectReal(origin, d, reach), real[static_cast<std::size_t>(k)]},
                                            std::pair{rays.intersectAll(origin, d, reach), all[static_cast<std::size_t>(k)]}}) {
                ASSERT_EQ(many.kind, one.kind) << "probe " << probe << " ray " << k;
                ASSERT_EQ(many.index, one.index) << "probe " << probe << " ray " << k;
                ASSERT_EQ(many.primitive, one.primitive) << "probe " << probe << " ray " << k;
                ASSERT_NEAR(many.distance, one.distance, 1e-6) << "probe " << probe << " ray " << k;
            }
            const RayHit& one = real[static_cast<std::size_t>(k)];
            if (one.kind == HitKind::kRealFace) ++faces_hit;
            if (one.kind == HitKind::kRealFace && one.index >= 6) ++pillar_hit;
            if (one.kind == HitKind::kLight) ++lamp_hit;
            if (one.kind == HitKind::kNone) ++missed;
            if (all[static_cast<std::size_t>(k)].kind == HitKind::kVirtual) ++virtual_hit;
        }
    }
    EXPECT_GT(faces_hit, 1000);
    EXPECT_GT(pillar_hit, 100);
    EXPECT_GT(lamp_hit, 5);
    EXPECT_GT(missed, 300);
    EXPECT_GT(virtual_hit, 100);
}

// intersectVirtualExcept() skips a ray that misses every other object's ball: its answer is the
// plain one (intersectVirtual(), stepping past the excluded object's hits) for rays grazing a
// sphere and a cube's corners, from inside the excluded sphere too, with an object disabled.
TEST(RayScene, IntersectVirtualExceptBallTestKeepsTheAnswer) {
    VirtualShape sphere;
    sphere.sphere_radius = 0.3;
    auto built = RayScene::build(floorFace(), {}, {sphere, cube(), sphere, sphere});
    ASSERT_TRUE(built) << built.error().message;
    RayScene& rays = **built;
    const Eigen::Vector3d at[4] = {{0, 0, 0}, {1.5, 0.2, 0.1}, {-0.4, 1.4, 0.3}, {0, -2, 0}};
    const Eigen::Quaterniond q(Eigen::AngleAxisd(0.6, Eigen::Vector3d(1, 2, 3).normalized()));
    for (int v = 0; v < 4; ++v) rays.setVirtualPose(v, Rigid3d(v == 1 ? q : Eigen::Quaterniond::Identity(), at[v]));
    rays.setVirtualEnabled(3, false);
    ASSERT_TRUE(rays.commitVirtual());
    const auto plain = [&](Eigen::Vector3d o, const Eigen::Vector3d& d, int excluded, double max_distance) {
        double travelled = 0.0;
        for (int guard = 0; guard < 16; ++guard) {
            RayHit hit = rays.intersectVirtual(o, d, max_distance - travelled);
            if (hit.kind == HitKind::kNone || hit.index != excluded) {
                if (hit.kind != HitKind::kNone) hit.distance += travelled;
                return hit;
            }
            o += (hit.distance + rays.epsilon()) * d;
            travelled += hit.distance + rays.epsilon();
        }
        return RayHit{};
    };
    std::mt19937 rng(17);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    int hits = 0, misses = 0;
    for (int k = 0; k < 6000; ++k) {
        const int excluded = k % 3 == 2 ? 1 : 0;
        // Aim at a point just inside or just outside a sphere's surface or a cube's corner.
        Eigen::Vector3d target;
        if (k % 2 == 0) {
            const Eigen::Vector3d n = Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized();
            target = at[2] + (0.3 + 0.002 * u(rng)) * n;
        } else {
            const Eigen::Vector3d corner(k % 4 == 1 ? 0.2 : -0.2, k % 5 ? 0.2 : -0.2, k % 7 ? 0.2 : -0.2);
            target = at[1] + q * corner + 0.002 * Eigen::Vector3d(u(rng), u(rng), u(rng));
        }
        const Eigen::Vector3d o = k % 4 == 0 ? Eigen::Vector3d(0.1 * u(rng), 0.1 * u(rng), 0.1 * u(rng))
                                             : target + 2.0 * Eigen::Vector3d(u(rng), u(rng), u(rng));
        const Eigen::Vector3d d = (target - o).normalized();
        // Past the target, or stopping short of it.
        const double max_distance = k % 5 == 0 ? (target - o).norm() * 0.5 : 1e30;
        const RayHit want = plain(o, d, excluded, max_distance);
        const RayHit got = rays.intersectVirtualExcept(o, d, excluded, max_distance);
        ASSERT_EQ(got.kind, want.kind) << "ray " << k;
        if (want.kind == HitKind::kNone) {
            ++misses;
            continue;
        }
        ++hits;
        EXPECT_EQ(got.index, want.index) << "ray " << k;
        EXPECT_EQ(got.distance, want.distance) << "ray " << k;
        EXPECT_NE(got.index, 3) << "ray " << k;
    }
    EXPECT_GT(hits, 1000);
    EXPECT_GT(misses, 1000);
}

TEST(RayScene, MeshBoundingBallKeepsEmbreesAnswer) {
    const Eigen::Vector3d offset(0.5, -0.3, 0.2);
    auto built = RayScene::build(floorFace(), {}, {cube(offset)});
    ASSERT_TRUE(built) << built.error().message;
    RayScene& rays = **built;
    const std::uint32_t bit = RayScene::virtualBit(0);
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    for (int pose = 0; pose < 3; ++pose) {
        const Eigen::Quaterniond q = Eigen::Quaterniond(Eigen::AngleAxisd(0.7 * pose + 0.3, Eigen::Vector3d(1, 2, 3).normalized()));
        const Rigid3d world_from_object(q, Eigen::Vector3d(1.0 * pose, 2.0, -0.5 * pose));
        rays.setVirtualPose(0, world_from_object);
        ASSERT_TRUE(rays.commitVirtual());
        const Eigen::Vector3d centre = world_from_object * offset;
        int blocked = 0, open = 0;
        for (int k = 0; k < 6000; ++k) {
            Eigen::Vector3d a, b;
            if (k % 3 == 0) {  // towards a corner: past it or just through it
                const Eigen::Vector3d corner = world_from_object * (offset + 0.2 * Eigen::Vector3d(k % 2 ? 1 : -1, k % 5 ? 1 : -1, k % 7 ? 1 : -1));
                a = centre + 2.0 * Eigen::Vector3d(u(rng), u(rng), u(rng));
                b = corner + 0.02 * Eigen::Vector3d(u(rng), u(rng), u(rng)) + 0.5 * (corner - a);
            } else {  // around the cube, from inside it too
                a = centre + 0.6 * Eigen::Vector3d(u(rng), u(rng), u(rng));
                b = centre + 0.6 * Eigen::Vector3d(u(rng), u(rng), u(rng));
            }
            const double length = (b - a).norm();
            if (length < 1e-3) continue;
            const RayHit hit = rays.intersectVirtual(a, (b - a) / length, length - rays.epsilon());
            const bool embree = hit.kind == HitKind::kVirtual && hit.index == 0;
            ASSERT_EQ(rays.occludedVirtual(a, Eigen::Vector3d::Zero(), b, Eigen::Vector3d::Zero(), bit), embree)
                << "pose " << pose << " segment " << k << " from " << a.transpose() << " to " << b.transpose();
            (embree ? blocked : open)++;
        }
        EXPECT_GT(blocked, 1000);
        EXPECT_GT(open, 1000);
        // A segment through the cube's centre is blocked; one that misses its ball is not.
        const Eigen::Vector3d side = q * Eigen::Vector3d::UnitX();
        EXPECT_TRUE(rays.occludedVirtual(centre - side, Eigen::Vector3d::Zero(), centre + side, Eigen::Vector3d::Zero(), bit));
        const Eigen::Vector3d away = q * Eigen::Vector3d::UnitZ();
        EXPECT_FALSE(rays.occludedVirtual(centre + away - side, Eigen::Vector3d::Zero(), centre + away + side, Eigen::Vector3d::Zero(), bit));
    }
}


// The change stamps (virtualStamp(), virtualChangedSince(), virtualChangedLast()): answers kept
// against an object hold until its pose or presence changes. After build() every object counts
// as changed; a commit marks the moved, removed and brought-back objects alone; a commit with
// nothing pending, or with poses set to those the objects have, keeps the stamp; a second
// scene's stamps are all later.
TEST(RayScene, ChangeStampsMarkTheChangedObjectsAlone) {
    VirtualShape sphere;
    sphere.sphere_radius = 0.3;
    auto built = RayScene::build(floorFace(), {}, {sphere, cube(), cube()});
    ASSERT_TRUE(built) << built.error().message;
    RayScene& rays = **built;
    const std::uint32_t b0 = RayScene::virtualBit(0), b1 = RayScene::virtualBit(1), b2 = RayScene::virtualBit(2);
    EXPECT_EQ(rays.virtualChangedLast(), b0 | b1 | b2);
    EXPECT_EQ(rays.virtualChangedSince(0), b0 | b1 | b2);
    const std::uint64_t s0 = rays.virtualStamp();
    EXPECT_EQ(rays.virtualChangedSince(s0), 0u);
    const auto move = [&](int v, double x) { rays.setVirtualPose(v, Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(x, 0, 0))); };
    // The sphere moves: it alone.
    move(0, 1.0);
    ASSERT_TRUE(rays.commitVirtual());
    const std::uint64_t s1 = rays.virtualStamp();
    EXPECT_GT(s1, s0);
    EXPECT_EQ(rays.virtualChangedLast(), b0);
    EXPECT_EQ(rays.virtualChangedSince(s0), b0);
    EXPECT_EQ(rays.virtualChangedSince(s1), 0u);
    // Nothing pending: the same stamp and the same last change; nor when every object is set
    // where it is (the estimator sets every pose, moved or not).
    ASSERT_TRUE(rays.commitVirtual());
    EXPECT_EQ(rays.virtualStamp(), s1);
    EXPECT_EQ(rays.virtualChangedLast(), b0);
    move(0, 1.0);
    move(1, 0.0);
    rays.setVirtualPose(2, Rigid3d{});
    ASSERT_TRUE(rays.commitVirtual());
    EXPECT_EQ(rays.virtualStamp(), s1);
    EXPECT_EQ(rays.virtualChangedSince(s1), 0u);
    // A cube removed (presence), then brought back, then the other cube moved.
    rays.setVirtualEnabled(1, false);
    ASSERT_TRUE(rays.commitVirtual());
    const std::uint64_t s2 = rays.virtualStamp();
    EXPECT_GT(s2, s1);
    EXPECT_EQ(rays.virtualChangedLast(), b1);
    EXPECT_EQ(rays.virtualChangedSince(s1), b1);
    EXPECT_EQ(rays.virtualChangedSince(s0), b0 | b1);
    rays.setVirtualEnabled(1, true);
    ASSERT_TRUE(rays.commitVirtual());
    EXPECT_EQ(rays.virtualChangedLast(), b1);
    EXPECT_EQ(rays.virtualChangedSince(s2), b1);
    move(2, -1.0);
    ASSERT_TRUE(rays.commitVirtual());
    EXPECT_EQ(rays.virtualChangedLast(), b2);
    EXPECT_EQ(rays.virtualChangedSince(s2), b1 | b2);
    EXPECT_EQ(rays.virtualChangedSince(s1), b1 | b2);
    // Another scene: stamps later than all of this one's.
    auto other = RayScene::build(floorFace(), {}, {sphere});
    ASSERT_TRUE(other) << other.error().message;
    EXPECT_GT((*other)->virtualStamp(), rays.virtualStamp());
    EXPECT_EQ((*other)->virtualChangedSince(rays.virtualStamp()), b0);
}


// prepareSegment() against the segment ray_scene.h describes, written out here: each end lifted by
// epsilon() along its normal (unit, or zero: not lifted) to the side the other end lies on (a
// segment in the normal's plane: to the normal's side), the ray from the lifted start towards the
// lifted end, unit, tfar their distance (epsilon() less when the end has no normal), and no
// segment between ends 2 epsilon() or less apart. Bit for bit, for random segments, segments in
// their ends' plane, and short ones around 2 epsilon().
TEST(RayScene, PreparedSegmentIsTheLiftedSegment) {
    auto built = RayScene::build(floorFace(), {}, {});
    ASSERT_TRUE(built) << built.error().message;
    const RayScene& rays = **built;
    const double eps = rays.epsilon();
    const auto lift = [&](const Eigen::Vector3d& x, const Eigen::Vector3d& n, const Eigen::Vector3d& towards) {
        if (n.squaredNorm() == 0.0) return x;
        const Eigen::Vector3d dir = (towards - x) / (towards - x).norm();
        return Eigen::Vector3d(x + (dir.dot(n) >= 0.0 ? eps : -eps) * n);
    };
    std::mt19937 rng(41);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    int lifted_both = 0, in_plane = 0, too_short = 0, flipped = 0;
    for (int k = 0; k < 20000; ++k) {
        const Eigen::Vector3d a(u(rng), u(rng), u(rng));
        Eigen::Vector3d na = Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized();
        Eigen::Vector3d b(u(rng), u(rng), u(rng)), nb = Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized();
        if (k % 4 == 1) {
            // Both ends on one plane z = a.z with its normal (or its opposite): the lifts' sign test
            // meets a zero product.
            b.z() = a.z();
            na = Eigen::Vector3d(0, 0, k % 8 == 1 ? 1 : -1);
            nb = na;
            ++in_plane;
        }
        if (k % 7 == 2) b = a + (1.0 + 0.2 * u(rng)) * 2.0 * eps * Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized();
        if (k % 3 == 0) na.setZero();
        if (k % 5 == 0) nb.setZero();
        const PreparedSegment s = rays.prepareSegment(a, na, b, nb);
        if ((b - a).norm() <= 2.0 * eps) {
            ASSERT_EQ(s.tfar, 0.0) << k;
            ++too_short;
            continue;
        }
        const Eigen::Vector3d o = lift(a, na, b);
        const Eigen::Vector3d t = lift(b, nb, a);
        const Eigen::Vector3d span = t - o;
        ASSERT_GT(span.norm(), 0.0) << k;
        ASSERT_EQ(s.origin, o) << k;
        ASSERT_EQ(s.direction, Eigen::Vector3d(span / span.norm())) << k;
        ASSERT_EQ(s.tfar, nb.squaredNorm() > 0.0 ? span.norm() : span.norm() - eps) << k;
        if (na.squaredNorm() > 0.0 && nb.squaredNorm() > 0.0) ++lifted_both;
        if (na.squaredNorm() > 0.0 && (b - a).dot(na) < 0.0) ++flipped;  // lifted against its normal
    }
    EXPECT_GT(lifted_both, 5000);
    EXPECT_GT(in_plane, 4000);
    EXPECT_GT(too_short, 1000);
    EXPECT_GT(flipped, 3000);
}

}  // namespace
}  // namespace commonlight::lighting

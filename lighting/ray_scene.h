// Visibility for the lighting module: Embree 3 scenes of the proxies, the area lights and the
// virtual objects (STYLE.md: opaque handles, error callback right after the device; edits and
// commits on one thread, queries from many).
//
// The static real scene (proxy faces and light polygons) is its own Embree scene, instanced into
// the top-level scenes; each virtual object is its own scene too (an exact sphere, or its faces),
// instanced with its pose. Moving a virtual object changes an instance transform and recommits the
// small top-level scenes: the real scene's BVH is never rebuilt.
//
// Three top-level scenes: `real` (the real instance alone: what the real scene's own light
// transport sees), `virtual` (the virtual instances alone) and `all` (both, for camera rays).
// A segment is blocked "with the virtual objects" when either the real or the virtual scene blocks it.
#pragma once

#include <array>
#include <cmath>
#include <cstdint>
#include <memory>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "core/pose.h"
#include "core/result.h"
#include "lighting/proxy_geometry.h"

namespace commonlight::lighting {

// A virtual object's shape for visibility: an exact sphere, or faces in its own frame.
struct VirtualShape {
    double sphere_radius = 0.0;  // > 0: a sphere centred on the object origin
    std::vector<Face> faces;     // otherwise: its faces (object frame)
};

// A segment lifted off its two surfaces once (as occludedVirtual() lifts it), for queries repeated
// while the virtual objects move: its rays skip the lifting and the balls' pre-test.
struct PreparedSegment {
    Eigen::Vector3d origin = Eigen::Vector3d::Zero();
    Eigen::Vector3d direction = Eigen::Vector3d::Zero();  // unit
    double tfar = 0.0;  // <= 0: never blocked (the ends touch)
};

// The virtual objects of a mask as committed, gathered once for many prepared segments
// (RayScene::virtualSet()): the per-segment loop then visits these alone, without the scene's
// per-object lists and bit tests. occludedVirtual(segment, virtualSet(mask)) ==
// occludedVirtual(segment, mask) (the same tests in the same order).
struct VirtualSet {
    static constexpr int kMax = 4;  // more objects in the mask: `general` (the plain path)
    std::uint32_t mask = 0;
    bool general = false;
    int spheres = 0, meshes = 0;
    std::array<Eigen::Vector3d, kMax> sphere_centre{};
    std::array<double, kMax> sphere_radius{};
    std::array<Eigen::Vector3d, kMax> mesh_centre{};  // the meshes' bounding balls (world)
    std::array<double, kMax> mesh_radius{};
    std::array<std::uint32_t, kMax> mesh_bit{};
    std::uint32_t mesh_bits = 0;  // mask & the enabled meshes' bits
};

enum class HitKind : std::uint8_t { kNone, kRealFace, kLight, kVirtual };

struct RayHit {
    HitKind kind = HitKind::kNone;
    int index = -1;        // real face index (kRealFace), LightGeometry index (kLight), virtual object (kVirtual)
    int primitive = -1;    // kVirtual: the face index within the object (-1 for a sphere)
    double distance = 0.0; // along the unit direction, metres
};

class RayScene {
public:
    // `real_faces` in world coordinates; `lights` their polygons (lights absorb and block like any
    // surface); `virtual_shapes` in object frames, placed at the identity until setVirtualPose().
    static Result<std::unique_ptr<RayScene>> build(const std::vector<Face>& real_faces,
                                                   const std::vector<LightGeometry>& lights,
                                                   const std::vector<VirtualShape>& virtual_shapes);
    ~RayScene();
    RayScene(const RayScene&) = delete;
    RayScene& operator=(const RayScene&) = delete;

    // Moves virtual object `index`; takes effect at the next commitVirtual() (the pose it has, with
    // nothing pending: no change, no new stamp). Lighting thread only.
    void setVirtualPose(int index, const Rigid3d& world_from_object);
    // Takes virtual object `index` out of every scene (false) or puts it back (true); takes effect
    // at the next commitVirtual(). Lighting thread only.
    void setVirtualEnabled(int index, bool enabled);
    // Recommits the top-level scenes after pose changes (microseconds: no BVH of the real scene is rebuilt).
    Result<void> commitVirtual();

    // Whether the open segment from `from` to `to` is blocked. Both ends are lifted by epsilon()
    // off their surfaces along their normals, towards the other end (a zero normal: no lift; the
    // segment then stops epsilon() short of that end), so neither end's own surface blocks it even
    // at grazing angles (adjacent faces, a light in a ceiling).
    bool occludedReal(const Eigen::Vector3d& from, const Eigen::Vector3d& from_normal, const Eigen::Vector3d& to,
                      const Eigen::Vector3d& to_normal = Eigen::Vector3d::Zero()) const;
    // Virtual occluders: only the objects whose bits are in `mask` (Embree ray masks: object v
    // has bit virtualBit(v)).
    bool occludedVirtual(const Eigen::Vector3d& from, const Eigen::Vector3d& from_normal, const Eigen::Vector3d& to,
                         const Eigen::Vector3d& to_normal = Eigen::Vector3d::Zero(), std::uint32_t mask = ~0u) const;
    // The segment occludedVirtual(from, from_normal, to, to_normal, mask) traces, and the same
    // answer from it: occludedVirtual(prepareSegment(f, nf, t, nt), mask) == occludedVirtual(f, nf, t, nt, mask).
    PreparedSegment prepareSegment(const Eigen::Vector3d& from, const Eigen::Vector3d& from_normal,
                                   const Eigen::Vector3d& to, const Eigen::Vector3d& to_normal) const;
    bool occludedVirtual(const PreparedSegment& segment, std::uint32_t mask = ~0u) const;
    // occludedReal() of many prepared segments (prepareSegment()) at once, traced as Embree ray
    // packets: bit k of the result is segment k's answer (at most 64 segments).
    std::uint64_t occludedRealMany(const PreparedSegment* segments, int count) const;
    // The objects of `mask` gathered for many segments (VirtualSet), and the answer with them.
    VirtualSet virtualSet(std::uint32_t mask) const;
    // (Inline, below: the spheres' closed form without a call for each of a link's or a texel's
    // rays; the meshes through occludedVirtualMeshes().)
    bool occludedVirtual(const PreparedSegment& segment, const VirtualSet& set) const;
    static std::uint32_t virtualBit(int index) { return std::uint32_t{1} << (static_cast<unsigned>(index) % 32u); }
    // Same for a ray towards infinity along `direction` (unit): distant lights.
    bool occludedRealRay(const Eigen::Vector3d& from, const Eigen::Vector3d& from_normal,
                         const Eigen::Vector3d& direction) const;
    bool occludedVirtualRay(const Eigen::Vector3d& from, const Eigen::Vector3d& from_normal,
                            const Eigen::Vector3d& direction, std::uint32_t mask = ~0u) const;

    // First hit along a ray (unit direction) in the real scene, in the virtual scene, or in both.
    RayHit intersectReal(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
                         double max_distance = 1e30) const;
    RayHit intersectVirtual(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
                            double max_distance = 1e30) const;
    RayHit intersectAll(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
                        double max_distance = 1e30) const;
    // intersectReal(origin, directions[k], max_distance) for k < count, written to out[k], traced
    // as Embree packets of 8 rays (the rays of a probe: one origin, many directions).
    void intersectRealMany(const Eigen::Vector3d& origin, const Eigen::Vector3d* directions, int count, RayHit* out,
                           double max_distance = 1e30) const;
    // The same with intersectAll() (a camera's rays: the observations).
    void intersectAllMany(const Eigen::Vector3d& origin, const Eigen::Vector3d* directions, int count, RayHit* out,
                          double max_distance = 1e30) const;
    // Same as intersectVirtual but ignoring one virtual object (rays leaving it, for its probes).
    RayHit intersectVirtualExcept(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction, int excluded,
                                  double max_distance = 1e30) const;

    // Change stamps, for answers kept while the virtual objects move: virtualStamp() is the stamp
    // of the latest commitVirtual() that changed an object's pose or presence (or of build());
    // stamps only grow (one process-wide counter: no two commits share one). virtualChangedSince(t):
    // the bits of this scene's objects changed at a later commit than stamp t (every object for
    // t = 0 or a t from before this scene's build). virtualChangedLast(): the bits of the objects
    // the latest such commit changed (every object right after build()). An object's answers
    // against a segment kept at this scene's stamp t hold while its bit is not in
    // virtualChangedSince(t).
    std::uint64_t virtualStamp() const noexcept;
    std::uint32_t virtualChangedSince(std::uint64_t stamp) const;
    std::uint32_t virtualChangedLast() const noexcept;

    // Lift of ray origins and shortening of segments, metres: 1e-5 x the real scene's extent, at
    // least 10 um.
    double epsilon() const noexcept { return epsilon_; }
    std::size_t virtualCount() const noexcept;
    // Virtual object `index` as committed: false when disabled; else a ball that holds all of it
    // (a sphere's own; a mesh's bounding ball, with a margin for single precision). A segment
    // that stays `lift` or more outside every such ball is open (occludedVirtual() lifts each end
    // by epsilon() times its normal).
    bool virtualBall(int index, Eigen::Vector3d& centre, double& radius) const;

private:
    // occludedVirtual(segment, set)'s meshes (set.mesh_bits != 0): their balls, then Embree.
    bool occludedVirtualMeshes(const PreparedSegment& segment, const VirtualSet& set) const;
    // Whether the segment origin + t direction (unit), 0 <= t <= tfar, meets the sphere's surface
    // (as Embree's sphere does: from inside, its far side). Inline for occludedVirtual(segment,
    // set); Impl's mask path calls it too.
    static bool segmentMeetsSphere(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction, double tfar,
                                   const Eigen::Vector3d& centre, double radius) {
        const Eigen::Vector3d oc = origin - centre;
        const double b = direction.dot(oc);
        const double c = oc.squaredNorm() - radius * radius;
        const double disc = b * b - c;
        if (!(disc >= 0.0)) return false;
        const double root = std::sqrt(disc);
        const double t0 = -b - root, t1 = -b + root;
        return (t0 >= 0.0 && t0 <= tfar) || (t1 >= 0.0 && t1 <= tfar);
    }
    bool occludedSegment(bool virtual_scene, const Eigen::Vector3d& from, const Eigen::Vector3d& from_normal,
                         const Eigen::Vector3d& to, const Eigen::Vector3d& to_normal, std::uint32_t mask) const;

    struct Impl;
    explicit RayScene(std::unique_ptr<Impl> impl, double epsilon);
    std::unique_ptr<Impl> impl_;
    double epsilon_;
};

inline bool RayScene::occludedVirtual(const PreparedSegment& segment, const VirtualSet& set) const {
    if (set.general) return occludedVirtual(segment, set.mask);
    if (!(segment.tfar > 0.0)) return false;
    for (int i = 0; i < set.spheres; ++i) {
        const auto k = static_cast<std::size_t>(i);
        if (segmentMeetsSphere(segment.origin, segment.direction, segment.tfar, set.sphere_centre[k], set.sphere_radius[k])) {
            return true;
        }
    }
    return set.mesh_bits != 0u && occludedVirtualMeshes(segment, set);
}

}  // namespace commonlight::lighting

#include "lighting/ray_scene.h"

#include <embree3/rtcore.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <mutex>
#include <string>

#include "core/log.h"

namespace commonlight::lighting {

namespace {

// Embree's error callback: runs on the thread that made the failing call; keeps the first message.
struct EmbreeErrors {
    std::mutex mutex;
    std::string first;
    int count = 0;
    static void callback(void* user, RTCError code, const char* message) {
        auto* self = static_cast<EmbreeErrors*>(user);
        const std::lock_guard lock(self->mutex);
        if (self->count++ == 0) self->first = "Embree error " + std::to_string(static_cast<int>(code)) + ": " + message;
        log::error(std::string("lighting: Embree error ") + std::to_string(static_cast<int>(code)) + ": " + message);
    }
    Result<void> check(const char* step) {
        const std::lock_guard lock(mutex);
        if (count == 0) return {};
        return fail(ErrorCode::kInternal, std::string(step) + ": " + first);
    }
};

// Stamps of the virtual objects' changes: one process-wide counter, so that no two commits of any
// two scenes share a stamp (an answer kept against one scene is never taken for another's).
std::atomic<std::uint64_t> g_virtual_stamp{0};

std::uint64_t nextVirtualStamp() { return g_virtual_stamp.fetch_add(1, std::memory_order_relaxed) + 1; }

constexpr unsigned kFacesGeometry = 0;  // geometry ids inside the real scene
constexpr unsigned kLightsGeometry = 1;

// A triangle geometry from a list of triangles (world or object frame). Owned by the caller until attached.
RTCGeometry trianglesGeometry(RTCDevice device, const std::vector<std::array<Eigen::Vector3d, 3>>& triangles) {
    RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
    auto* vertices = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                                 3 * sizeof(float), 3 * triangles.size()));
    auto* indices = static_cast<unsigned*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                                   3 * sizeof(unsigned), triangles.size()));
    if (vertices && indices) {
        for (std::size_t t = 0; t < triangles.size(); ++t) {
            for (int k = 0; k < 3; ++k) {
                for (int c = 0; c < 3; ++c) vertices[9 * t + 3 * k + c] = static_cast<float>(triangles[t][k][c]);
                indices[3 * t + k] = static_cast<unsigned>(3 * t + k);
            }
        }
    }
    rtcCommitGeometry(geom);
    return geom;
}

// Triangles of a face: one for a triangle, two for a parallelogram.
void appendTriangles(const Face& f, int owner, std::vector<std::array<Eigen::Vector3d, 3>>& triangles,
                     std::vector<int>& owners) {
    const Eigen::Vector3d a = f.origin, b = f.origin + f.edge_s, d = f.origin + f.edge_t;
    triangles.push_back({a, b, d});
    owners.push_back(owner);
    if (!f.triangle) {
        triangles.push_back({b, b + f.edge_t, d});
        owners.push_back(owner);
    }
}

RTCScene newScene(RTCDevice device) {
    RTCScene scene = rtcNewScene(device);
    // Robust traversal: no hit lost on a shared edge (a closed room must stay closed).
    rtcSetSceneFlags(scene, RTC_SCENE_FLAG_ROBUST);
    rtcSetSceneBuildQuality(scene, RTC_BUILD_QUALITY_HIGH);
    return scene;
}

RTCGeometry instanceOf(RTCDevice device, RTCScene child, const Eigen::Matrix4f& world_from_object) {
    RTCGeometry inst = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_INSTANCE);
    rtcSetGeometryInstancedScene(inst, child);
    rtcSetGeometryTransform(inst, 0, RTC_FORMAT_FLOAT4X4_COLUMN_MAJOR, world_from_object.data());
    rtcCommitGeometry(inst);
    return inst;
}

// The origin lifted off its surface towards the side the ray leaves to.
Eigen::Vector3d lifted(const Eigen::Vector3d& from, const Eigen::Vector3d& normal, const Eigen::Vector3d& dir,
                       double epsilon) {
    if (normal.squaredNorm() == 0.0) return from;
    return from + (dir.dot(normal) >= 0.0 ? epsilon : -epsilon) * normal;
}

}  // namespace

struct RayScene::Impl {
    EmbreeErrors errors;
    RTCDevice device = nullptr;
    RTCScene real = nullptr;                   // static: faces + lights
    std::vector<RTCScene> virtual_scenes;      // one per virtual object
    RTCScene real_top = nullptr;               // instance of `real`
    RTCScene virtual_top = nullptr;            // instances of the virtual scenes
    RTCScene all_top = nullptr;                // both
    std::vector<RTCGeometry> virtual_instances;      // in virtual_top, by virtual index
    std::vector<RTCGeometry> all_virtual_instances;  // in all_top, by virtual index
    unsigned all_real_instance = 0;                  // geometry id of the real instance in all_top
    std::vector<int> virtual_of_geom_virtual_top;
    std::vector<int> virtual_of_geom_all_top;
    std::vector<int> face_of_prim;                   // real faces geometry: primitive -> face index
    std::vector<int> light_of_prim;                  // lights geometry: primitive -> LightGeometry index
    std::vector<std::vector<int>> virtual_face_of_prim;  // per virtual object: primitive -> face (-1: sphere)
    std::vector<Eigen::Matrix4f> pending_poses;
    std::vector<bool> pose_dirty;
    std::vector<bool> enabled;        // by virtual index: in the scenes
    std::vector<bool> enabled_dirty;
    // Spheres are tested in closed form (a segment against a ball: a few multiplications, where
    // Embree's instanced traversal costs tens of nanoseconds); meshes go through Embree.
    std::vector<double> sphere_radius;             // by virtual index: > 0 a sphere
    std::vector<Eigen::Vector3d> pending_centre;   // by virtual index: the sphere's centre at the next commit
    std::vector<Eigen::Vector3d> sphere_centre;    // committed (world)
    std::vector<std::uint32_t> sphere_bit;         // committed: virtualBit(v) of an enabled sphere, else 0
    std::uint32_t mesh_bits = 0;                   // committed: bits of the enabled non-sphere objects
    // A mesh's bounding ball (object frame centre, radius with a margin for Embree's single
    // precision): a ray that misses it is not traced through Embree.
    std::vector<Eigen::Vector3d> mesh_centre_object;  // by virtual index
    std::vector<double> mesh_radius;                  // by virtual index: > 0 a mesh
    std::vector<Eigen::Vector3d> pending_mesh_centre; // world, at the next commit
    std::vector<Eigen::Vector3d> mesh_centre;         // committed (world)
    std::vector<std::uint32_t> mesh_bit;              // committed: virtualBit(v) of an enabled mesh, else 0
    // Change stamps (virtualStamp()): the latest commit that changed an object, each object's last
    // change (pose or presence; the build counts as one) and the bits of the objects that latest
    // commit changed.
    std::uint64_t stamp = 0;
    std::vector<std::uint64_t> changed_at;  // by virtual index
    std::uint32_t changed_last = 0;

    void updateCommitted() {
        mesh_bits = 0;
        for (std::size_t v = 0; v < sphere_radius.size(); ++v) {
            const std::uint32_t bit = RayScene::virtualBit(static_cast<int>(v));
            sphere_bit[v] = enabled[v] && sphere_radius[v] > 0.0 ? bit : 0u;
            mesh_bit[v] = enabled[v] && !(sphere_radius[v] > 0.0) ? bit : 0u;
            mesh_bits |= mesh_bit[v];
        }
    }

    // Whether the segment a-b may meet a virtual object in `mask`: it passes within `margin` of a
    // sphere's or a mesh's bounding ball. (A cheap test on the segment before it is lifted off its
    // surfaces: the lifted one lies within the lift of it.)
    bool segmentMayMeet(const Eigen::Vector3d& a, const Eigen::Vector3d& b, std::uint32_t mask, double margin) const {
        const Eigen::Vector3d d = b - a;
        const double dd = d.squaredNorm();
        for (std::size_t v = 0; v < sphere_bit.size(); ++v) {
            const bool sphere = (sphere_bit[v] & mask) != 0u;
            if (!sphere && (mesh_bit[v] & mask) == 0u) continue;
            const Eigen::Vector3d oc = (sphere ? sphere_centre[v] : mesh_centre[v]) - a;
            const double r = (sphere ? sphere_radius[v] : mesh_radius[v]) + margin;
            const double t = dd > 0.0 ? std::clamp(oc.dot(d) / dd, 0.0, 1.0) : 0.0;
            if ((oc - t * d).squaredNorm() <= r * r) return true;
        }
        return false;
    }

    // Whether the ray origin + t direction, 0 <= t <= tfar, passes within reach of an enabled
    // virtual object other than `excluded`: its sphere's or its mesh's bounding ball, widened for
    // Embree's single precision. A ray that does not cannot hit them (intersectVirtualExcept()).
    bool othersMayMeet(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction, double tfar, int excluded) const {
        const double dd = direction.squaredNorm();
        const double hi = tfar > 0.0 ? tfar : 0.0;
        for (std::size_t v = 0; v < sphere_bit.size(); ++v) {
            if (static_cast<int>(v) == excluded) continue;
            const bool sphere = sphere_bit[v] != 0u;
            if (!sphere && mesh_bit[v] == 0u) continue;
            const Eigen::Vector3d& c = sphere ? sphere_centre[v] : mesh_centre[v];
            const double r = (sphere ? sphere_radius[v] : mesh_radius[v]) * (1.0 + 1e-4) + 1e-4 * (1.0 + c.norm());
            const Eigen::Vector3d oc = c - origin;
            const double t = dd > 0.0 ? std::clamp(oc.dot(direction) / dd, 0.0, hi) : 0.0;
            if ((oc - t * direction).squaredNorm() <= r * r) return true;
        }
        return false;
    }

    // Whether the segment origin + t direction (unit), 0 <= t <= tfar, meets the solid ball.
    static bool segmentMeetsBall(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction, double tfar,
                                 const Eigen::Vector3d& centre, double radius) {
        const Eigen::Vector3d oc = centre - origin;
        const double t = std::clamp(direction.dot(oc), 0.0, tfar);
        return (oc - t * direction).squaredNorm() <= radius * radius;
    }

    // The virtual objects in `mask`: spheres in closed form, the rest through Embree.
    bool occludedVirtual(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction, double tfar, std::uint32_t mask) const {
        if (!(tfar > 0.0)) return false;
        for (std::size_t v = 0; v < sphere_bit.size(); ++v) {
            if ((sphere_bit[v] & mask) != 0u && RayScene::segmentMeetsSphere(origin, direction, tfar, sphere_centre[v], sphere_radius[v])) return true;
        }
        std::uint32_t rest = mask & mesh_bits;
        if (rest == 0u) return false;
        for (std::size_t v = 0; v < mesh_bit.size(); ++v) {
            if ((mesh_bit[v] & rest) != 0u && !segmentMeetsBall(origin, direction, tfar, mesh_centre[v], mesh_radius[v])) rest &= ~mesh_bit[v];
        }
        return rest != 0u && occluded(virtual_top, origin, direction, tfar, rest);
    }

    ~Impl() {
        for (RTCScene s : {all_top, virtual_top, real_top, real}) {
            if (s) rtcReleaseScene(s);
        }
        for (RTCScene s : virtual_scenes) {
            if (s) rtcReleaseScene(s);
        }
        if (device) rtcReleaseDevice(device);
    }

    RayHit decode(const RTCRayHit& rh, RTCScene top) const {
        RayHit hit;
        if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return hit;
        hit.distance = rh.ray.tfar;
        const unsigned inst = rh.hit.instID[0];
        bool is_real = false;
        int virtual_index = -1;
        if (top == real_top) {
            is_real = true;
        } else if (top == virtual_top) {
            virtual_index = inst < virtual_of_geom_virtual_top.size() ? virtual_of_geom_virtual_top[inst] : -1;
        } else {
            if (inst == all_real_instance) {
                is_real = true;
            } else {
                virtual_index = inst < virtual_of_geom_all_top.size() ? virtual_of_geom_all_top[inst] : -1;
            }
        }
        if (is_real) {
            if (rh.hit.geomID == kFacesGeometry) {
                hit.kind = HitKind::kRealFace;
                hit.index = face_of_prim.at(rh.hit.primID);
            } else {
                hit.kind = HitKind::kLight;
                hit.index = light_of_prim.at(rh.hit.primID);
            }
        } else if (virtual_index >= 0) {
            hit.kind = HitKind::kVirtual;
            hit.index = virtual_index;
            const auto& prims = virtual_face_of_prim[static_cast<std::size_t>(virtual_index)];
            hit.primitive = rh.hit.primID < prims.size() ? prims[rh.hit.primID] : -1;
        }
        return hit;
    }

    RayHit intersect(RTCScene top, const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
                     double max_distance) const {
        RTCIntersectContext context;
        rtcInitIntersectContext(&context);
        RTCRayHit rh{};
        rh.ray.org_x = static_cast<float>(origin.x());
        rh.ray.org_y = static_cast<float>(origin.y());
        rh.ray.org_z = static_cast<float>(origin.z());
        rh.ray.dir_x = static_cast<float>(direction.x());
        rh.ray.dir_y = static_cast<float>(direction.y());
        rh.ray.dir_z = static_cast<float>(direction.z());
        rh.ray.tnear = 0.0f;
        rh.ray.tfar = static_cast<float>(std::min(max_distance, 1e30));
        rh.ray.mask = 0xFFFFFFFFu;
        rh.ray.flags = 0;
        rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
        rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
        rtcIntersect1(top, &context, &rh);
        return decode(rh, top);
    }

    // The rays intersect() makes, eight at a time (Embree's packets: rays from one origin are
    // coherent); each lane's hit decoded as one ray's.
    void intersectMany(RTCScene scene, const Eigen::Vector3d& origin, const Eigen::Vector3d* directions, int count, RayHit* out,
                       double max_distance) const {
        const auto ox = static_cast<float>(origin.x()), oy = static_cast<float>(origin.y()), oz = static_cast<float>(origin.z());
        const auto tfar = static_cast<float>(std::min(max_distance, 1e30));
        for (int first = 0; first < count; first += 8) {
            RTCRayHit8 packet{};
            alignas(32) int valid[8] = {};
            for (int j = 0; j < 8 && first + j < count; ++j) {
                const Eigen::Vector3d& w = directions[first + j];
                packet.ray.org_x[j] = ox;
                packet.ray.org_y[j] = oy;
                packet.ray.org_z[j] = oz;
                packet.ray.dir_x[j] = static_cast<float>(w.x());
                packet.ray.dir_y[j] = static_cast<float>(w.y());
                packet.ray.dir_z[j] = static_cast<float>(w.z());
                packet.ray.tnear[j] = 0.0f;
                packet.ray.tfar[j] = tfar;
                packet.ray.mask[j] = 0xFFFFFFFFu;
                packet.hit.geomID[j] = RTC_INVALID_GEOMETRY_ID;
                packet.hit.instID[0][j] = RTC_INVALID_GEOMETRY_ID;
                valid[j] = -1;
            }
            RTCIntersectContext context;
            rtcInitIntersectContext(&context);
            rtcIntersect8(valid, scene, &context, &packet);
            for (int j = 0; j < 8 && first + j < count; ++j) {
                RTCRayHit one{};
                one.ray.tfar = packet.ray.tfar[j];
                one.hit.geomID = packet.hit.geomID[j];
                one.hit.primID = packet.hit.primID[j];
                one.hit.instID[0] = packet.hit.instID[0][j];
                out[first + j] = decode(one, scene);
            }
        }
    }

    bool occluded(RTCScene top, const Eigen::Vector3d& origin, const Eigen::Vector3d& direction, double tfar,
                  std::uint32_t mask = 0xFFFFFFFFu) const {
        if (!(tfar > 0.0)) return false;
        RTCIntersectContext context;
        rtcInitIntersectContext(&context);
        RTCRay ray{};
        ray.org_x = static_cast<float>(origin.x());
        ray.org_y = static_cast<float>(origin.y());
        ray.org_z = static_cast<float>(origin.z());
        ray.dir_x = static_cast<float>(direction.x());
        ray.dir_y = static_cast<float>(direction.y());
        ray.dir_z = static_cast<float>(direction.z());
        ray.tnear = 0.0f;
        ray.tfar = static_cast<float>(std::min(tfar, 1e30));
        ray.mask = mask;
        rtcOccluded1(top, &context, &ray);
        return ray.tfar < 0.0f;  // Embree sets tfar to -inf on a hit
    }
};

RayScene::RayScene(std::unique_ptr<Impl> impl, double epsilon) : impl_(std::move(impl)), epsilon_(epsilon) {}
RayScene::~RayScene() = default;

Result<std::unique_ptr<RayScene>> RayScene::build(const std::vector<Face>& real_faces,
                                                  const std::vector<LightGeometry>& lights,
                                                  const std::vector<VirtualShape>& virtual_shapes) {
    auto impl = std::make_unique<Impl>();
    // Under ThreadSanitizer, Embree's own BVH builders run on one thread (see kTsanParallelism in
    // estimator.cpp: oneTBB's hand-overs are invisible to TSan).
#if defined(__SANITIZE_THREAD__)
    impl->device = rtcNewDevice("threads=1");  // owned by impl
#else
    impl->device = rtcNewDevice(nullptr);  // owned by impl
#endif
    if (!impl->device) {
        return fail(ErrorCode::kInternal, "lighting: rtcNewDevice failed (Embree error " +
                                              std::to_string(static_cast<int>(rtcGetDeviceError(nullptr))) + ")");
    }
    rtcSetDeviceErrorFunction(impl->device, &EmbreeErrors::callback, &impl->errors);

    // Step 1: the static real scene: every proxy face and every light polygon.
    Eigen::AlignedBox3d bounds;
    std::vector<std::array<Eigen::Vector3d, 3>> triangles;
    for (std::size_t i = 0; i < real_faces.size(); ++i) {
        appendTriangles(real_faces[i], static_cast<int>(i), triangles, impl->face_of_prim);
        for (const Eigen::Vector3d& c : real_faces[i].corners()) bounds.extend(c);
    }
    impl->real = newScene(impl->device);  // owned by impl
    RTCGeometry faces = trianglesGeometry(impl->device, triangles);
    rtcAttachGeometryByID(impl->real, faces, kFacesGeometry);
    rtcReleaseGeometry(faces);  // the scene holds it
    std::vector<std::array<Eigen::Vector3d, 3>> light_triangles;
    for (std::size_t i = 0; i < lights.size(); ++i) {
        const auto& poly = lights[i].polygon;
        for (std::size_t k = 1; k + 1 < poly.size(); ++k) {  // a fan: polygons are convex
            light_triangles.push_back({poly[0], poly[k], poly[k + 1]});
            impl->light_of_prim.push_back(static_cast<int>(i));
        }
        for (const Eigen::Vector3d& c : poly) bounds.extend(c);
    }
    if (!light_triangles.empty()) {
        RTCGeometry lg = trianglesGeometry(impl->device, light_triangles);
        rtcAttachGeometryByID(impl->real, lg, kLightsGeometry);
        rtcReleaseGeometry(lg);
    }
    rtcCommitScene(impl->real);
    CL_TRY_VOID(impl->errors.check("lighting: building the real scene"));

    // Step 2: one scene per virtual object, in its own frame.
    impl->virtual_face_of_prim.resize(virtual_shapes.size());
    for (std::size_t v = 0; v < virtual_shapes.size(); ++v) {
        RTCScene scene = newScene(impl->device);  // owned by impl->virtual_scenes
        impl->virtual_scenes.push_back(scene);
        const VirtualShape& shape = virtual_shapes[v];
        if (shape.sphere_radius > 0.0) {
            RTCGeometry sphere = rtcNewGeometry(impl->device, RTC_GEOMETRY_TYPE_SPHERE_POINT);
            auto* p = static_cast<float*>(
                rtcSetNewGeometryBuffer(sphere, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT4, 4 * sizeof(float), 1));
            if (p) {
                p[0] = p[1] = p[2] = 0.0f;
                p[3] = static_cast<float>(shape.sphere_radius);
            }
            rtcCommitGeometry(sphere);
            rtcAttachGeometry(scene, sphere);
            rtcReleaseGeometry(sphere);
            impl->virtual_face_of_prim[v] = {-1};
        } else {
            std::vector<std::array<Eigen::Vector3d, 3>> vt;
            for (std::size_t i = 0; i < shape.faces.size(); ++i) {
                appendTriangles(shape.faces[i], static_cast<int>(i), vt, impl->virtual_face_of_prim[v]);
            }
            Eigen::AlignedBox3d box;
            for (const auto& t : vt) {
                for (const Eigen::Vector3d& p : t) box.extend(p);
            }
            const Eigen::Vector3d centre = box.isEmpty() ? Eigen::Vector3d(Eigen::Vector3d::Zero()) : Eigen::Vector3d(box.center());
            double radius = 0.0;
            for (const auto& t : vt) {
                for (const Eigen::Vector3d& p : t) radius = std::max(radius, (p - centre).norm());
            }
            // The margin covers the vertices' and the rays' rounding to single precision.
            impl->mesh_centre_object.resize(virtual_shapes.size(), Eigen::Vector3d::Zero());
            impl->mesh_radius.resize(virtual_shapes.size(), 0.0);
            impl->mesh_centre_object[v] = centre;
            impl->mesh_radius[v] = radius * (1.0 + 1e-4) + 1e-4 * (1.0 + centre.norm());
            RTCGeometry g = trianglesGeometry(impl->device, vt);
            rtcAttachGeometry(scene, g);
            rtcReleaseGeometry(g);
        }
        rtcCommitScene(scene);
    }
    CL_TRY_VOID(impl->errors.check("lighting: building the virtual objects"));

    // Step 3: the top-level scenes of instances.
    impl->real_top = newScene(impl->device);
    impl->virtual_top = newScene(impl->device);
    impl->all_top = newScene(impl->device);
    rtcSetSceneBuildQuality(impl->virtual_top, RTC_BUILD_QUALITY_LOW);  // rebuilt when objects move
    rtcSetSceneBuildQuality(impl->all_top, RTC_BUILD_QUALITY_LOW);
    const Eigen::Matrix4f identity = Eigen::Matrix4f::Identity();
    {
        RTCGeometry inst = instanceOf(impl->device, impl->real, identity);
        rtcAttachGeometry(impl->real_top, inst);
        rtcReleaseGeometry(inst);
        RTCGeometry inst_all = instanceOf(impl->device, impl->real, identity);
        impl->all_real_instance = rtcAttachGeometry(impl->all_top, inst_all);
        rtcReleaseGeometry(inst_all);
    }
    for (std::size_t v = 0; v < virtual_shapes.size(); ++v) {
        RTCGeometry a = instanceOf(impl->device, impl->virtual_scenes[v], identity);
        // Each object its bit: a ray may be blocked by some objects only (lighting/influence.h).
        rtcSetGeometryMask(a, virtualBit(static_cast<int>(v)));
        rtcCommitGeometry(a);
        const unsigned id_v = rtcAttachGeometry(impl->virtual_top, a);
        impl->virtual_instances.push_back(a);  // borrowed: the scene holds the reference
        rtcReleaseGeometry(a);
        RTCGeometry b = instanceOf(impl->device, impl->virtual_scenes[v], identity);
        const unsigned id_a = rtcAttachGeometry(impl->all_top, b);
        impl->all_virtual_instances.push_back(b);
        rtcReleaseGeometry(b);
        if (impl->virtual_of_geom_virtual_top.size() <= id_v) impl->virtual_of_geom_virtual_top.resize(id_v + 1, -1);
        if (impl->virtual_of_geom_all_top.size() <= id_a) impl->virtual_of_geom_all_top.resize(id_a + 1, -1);
        impl->virtual_of_geom_virtual_top[id_v] = static_cast<int>(v);
        impl->virtual_of_geom_all_top[id_a] = static_cast<int>(v);
    }
    impl->pending_poses.assign(virtual_shapes.size(), identity);
    impl->pose_dirty.assign(virtual_shapes.size(), false);
    impl->enabled.assign(virtual_shapes.size(), true);
    impl->enabled_dirty.assign(virtual_shapes.size(), false);
    for (const VirtualShape& shape : virtual_shapes) impl->sphere_radius.push_back(shape.sphere_radius > 0.0 ? shape.sphere_radius : 0.0);
    impl->pending_centre.assign(virtual_shapes.size(), Eigen::Vector3d::Zero());
    impl->sphere_centre.assign(virtual_shapes.size(), Eigen::Vector3d::Zero());
    impl->sphere_bit.assign(virtual_shapes.size(), 0u);
    impl->mesh_centre_object.resize(virtual_shapes.size(), Eigen::Vector3d::Zero());
    impl->mesh_radius.resize(virtual_shapes.size(), 0.0);
    impl->pending_mesh_centre = impl->mesh_centre_object;
    impl->stamp = nextVirtualStamp();
    impl->changed_at.assign(virtual_shapes.size(), impl->stamp);
    impl->changed_last = 0;
    for (std::size_t v = 0; v < virtual_shapes.size(); ++v) impl->changed_last |= virtualBit(static_cast<int>(v));
    impl->mesh_centre = impl->mesh_centre_object;
    impl->mesh_bit.assign(virtual_shapes.size(), 0u);
    impl->updateCommitted();
    rtcCommitScene(impl->real_top);
    rtcCommitScene(impl->virtual_top);
    rtcCommitScene(impl->all_top);
    CL_TRY_VOID(impl->errors.check("lighting: building the top-level scenes"));

    const double extent = bounds.isEmpty() ? 1.0 : bounds.diagonal().norm();
    const double epsilon = std::max(1e-5 * extent, 1e-5);
    return std::unique_ptr<RayScene>(new RayScene(std::move(impl), epsilon));
}

std::size_t RayScene::virtualCount() const noexcept { return impl_->virtual_scenes.size(); }

bool RayScene::virtualBall(int index, Eigen::Vector3d& centre, double& radius) const {
    const auto v = static_cast<std::size_t>(index);
    if (index < 0 || v >= impl_->sphere_bit.size()) return false;
    if (impl_->sphere_bit[v] != 0u) {
        centre = impl_->sphere_centre[v];
        radius = impl_->sphere_radius[v];
        return true;
    }
    if (impl_->mesh_bit[v] != 0u) {
        centre = impl_->mesh_centre[v];
        radius = impl_->mesh_radius[v];
        return true;
    }
    return false;
}

void RayScene::setVirtualPose(int index, const Rigid3d& world_from_object) {
    const auto i = static_cast<std::size_t>(index);
    const Eigen::Matrix4f pose = world_from_object.matrix().cast<float>();
    const Eigen::Vector3d mesh_centre = world_from_object * impl_->mesh_centre_object[i];
    // The pose the object has (nothing pending): no change, no new stamp (callers set every
    // object's pose, moved or not).
    if (!impl_->pose_dirty[i] && impl_->pending_poses.at(i) == pose && impl_->pending_centre[i] == world_from_object.translation &&
        impl_->pending_mesh_centre[i] == mesh_centre) {
        return;
    }
    impl_->pending_poses.at(i) = pose;
    impl_->pending_centre[i] = world_from_object.translation;
    impl_->pending_mesh_centre[i] = mesh_centre;
    impl_->pose_dirty[i] = true;
}

void RayScene::setVirtualEnabled(int index, bool enabled) {
    const auto i = static_cast<std::size_t>(index);
    if (impl_->enabled.at(i) == enabled) return;
    impl_->enabled[i] = enabled;
    impl_->enabled_dirty[i] = true;
}

Result<void> RayScene::commitVirtual() {
    bool any = false;
    std::vector<bool> changed(impl_->enabled.size(), false);
    for (std::size_t i = 0; i < impl_->enabled.size(); ++i) {
        if (!impl_->enabled_dirty[i]) continue;
        changed[i] = true;
        for (RTCGeometry inst : {impl_->virtual_instances[i], impl_->all_virtual_instances[i]}) {
            if (impl_->enabled[i]) {
                rtcEnableGeometry(inst);
            } else {
                rtcDisableGeometry(inst);
            }
        }
        impl_->enabled_dirty[i] = false;
        any = true;
    }
    for (std::size_t i = 0; i < impl_->pending_poses.size(); ++i) {
        if (!impl_->pose_dirty[i]) continue;
        changed[i] = true;
        for (RTCGeometry inst : {impl_->virtual_instances[i], impl_->all_virtual_instances[i]}) {
            rtcSetGeometryTransform(inst, 0, RTC_FORMAT_FLOAT4X4_COLUMN_MAJOR, impl_->pending_poses[i].data());
            rtcCommitGeometry(inst);
        }
        impl_->sphere_centre[i] = impl_->pending_centre[i];
        impl_->mesh_centre[i] = impl_->pending_mesh_centre[i];
        impl_->pose_dirty[i] = false;
        any = true;
    }
    impl_->updateCommitted();
    if (any) {
        rtcCommitScene(impl_->virtual_top);
        rtcCommitScene(impl_->all_top);
        impl_->stamp = nextVirtualStamp();
        impl_->changed_last = 0;
        for (std::size_t i = 0; i < changed.size(); ++i) {
            if (!changed[i]) continue;
            impl_->changed_at[i] = impl_->stamp;
            impl_->changed_last |= virtualBit(static_cast<int>(i));
        }
    }
    return impl_->errors.check("lighting: moving the virtual objects");
}

std::uint64_t RayScene::virtualStamp() const noexcept { return impl_->stamp; }

std::uint32_t RayScene::virtualChangedSince(std::uint64_t stamp) const {
    std::uint32_t bits = 0;
    for (std::size_t v = 0; v < impl_->changed_at.size(); ++v) {
        if (impl_->changed_at[v] > stamp) bits |= virtualBit(static_cast<int>(v));
    }
    return bits;
}

std::uint32_t RayScene::virtualChangedLast() const noexcept { return impl_->changed_last; }

PreparedSegment RayScene::prepareSegment(const Eigen::Vector3d& from, const Eigen::Vector3d& from_normal,
                                         const Eigen::Vector3d& to, const Eigen::Vector3d& to_normal) const {
    PreparedSegment s;
    const Eigen::Vector3d d = to - from;
    const double length = d.norm();
    if (length <= 2.0 * epsilon_) return s;  // hard case: touching points see each other
    const Eigen::Vector3d dir = d / length;
    // lifted(from, from_normal, dir) and lifted(to, to_normal, -dir) written out (the same operations).
    const double to_norm2 = to_normal.squaredNorm();
    Eigen::Vector3d o = from, t = to;
    if (from_normal.squaredNorm() != 0.0) o = from + (dir.dot(from_normal) >= 0.0 ? epsilon_ : -epsilon_) * from_normal;
    if (to_norm2 != 0.0) t = to + ((-dir).dot(to_normal) >= 0.0 ? epsilon_ : -epsilon_) * to_normal;
    const Eigen::Vector3d span = t - o;
    const double span_length = span.norm();
    if (!(span_length > 0.0)) return s;
    s.origin = o;
    s.direction = span / span_length;
    s.tfar = to_norm2 > 0.0 ? span_length : span_length - epsilon_;
    return s;
}

bool RayScene::occludedSegment(bool virtual_scene, const Eigen::Vector3d& from, const Eigen::Vector3d& from_normal,
                               const Eigen::Vector3d& to, const Eigen::Vector3d& to_normal, std::uint32_t mask) const {
    if (virtual_scene && impl_->virtual_scenes.empty()) return false;
    const PreparedSegment s = prepareSegment(from, from_normal, to, to_normal);
    if (virtual_scene) return impl_->occludedVirtual(s.origin, s.direction, s.tfar, mask);
    return impl_->occluded(impl_->real_top, s.origin, s.direction, s.tfar, mask);
}

bool RayScene::occludedVirtual(const PreparedSegment& segment, std::uint32_t mask) const {
    // Without the balls' pre-test of the segment (occludedVirtual() below): it only skips rays
    // Impl::occludedVirtual() finds open, spheres and meshes' balls first.
    if (mask == 0u || impl_->virtual_scenes.empty()) return false;
    return impl_->occludedVirtual(segment.origin, segment.direction, segment.tfar, mask);
}

namespace {

// One packet of N rays (RTCRay4/8) from segments[first..first+N) (those past `count` or never
// blocked left out), traced by `trace`; the blocked ones' bits added to `out`.
template <int N, typename Packet, typename Trace>
void occludedPacket(const PreparedSegment* segments, int first, int count, Trace trace, std::uint64_t& out) {
    Packet packet{};
    alignas(32) int valid[N] = {};
    bool any = false;
    for (int j = 0; j < N; ++j) {
        const int k = first + j;
        if (k >= count || !(segments[k].tfar > 0.0)) continue;
        const PreparedSegment& s = segments[k];
        packet.org_x[j] = static_cast<float>(s.origin.x());
        packet.org_y[j] = static_cast<float>(s.origin.y());
        packet.org_z[j] = static_cast<float>(s.origin.z());
        packet.dir_x[j] = static_cast<float>(s.direction.x());
        packet.dir_y[j] = static_cast<float>(s.direction.y());
        packet.dir_z[j] = static_cast<float>(s.direction.z());
        packet.tnear[j] = 0.0f;
        packet.tfar[j] = static_cast<float>(std::min(s.tfar, 1e30));
        packet.mask[j] = 0xFFFFFFFFu;
        valid[j] = -1;
        any = true;
    }
    if (!any) return;
    trace(valid, &packet);
    for (int j = 0; j < N; ++j) {
        if (valid[j] != 0 && packet.tfar[j] < 0.0f) out |= std::uint64_t{1} << (first + j);
    }
}

}  // namespace

std::uint64_t RayScene::occludedRealMany(const PreparedSegment* segments, int count) const {
    // Packets of 8, the last of 4 when 4 or fewer are left (occludedReal(): the same rays, as
    // Impl::occluded() makes them; a segment with tfar <= 0 is never blocked and not traced).
    std::uint64_t out = 0;
    RTCScene scene = impl_->real_top;
    RTCIntersectContext context;
    const int n = std::min(count, 64);
    for (int first = 0; first < n;) {
        if (n - first > 4) {
            occludedPacket<8, RTCRay8>(segments, first, n, [&](int* valid, RTCRay8* p) {
                rtcInitIntersectContext(&context);
                rtcOccluded8(valid, scene, &context, p);
            }, out);
            first += 8;
        } else {
            occludedPacket<4, RTCRay4>(segments, first, n, [&](int* valid, RTCRay4* p) {
                rtcInitIntersectContext(&context);
                rtcOccluded4(valid, scene, &context, p);
            }, out);
            first += 4;
        }
    }
    return out;
}

VirtualSet RayScene::virtualSet(std::uint32_t mask) const {
    // The objects occludedVirtual(segment, mask) visits, in its order (Impl::occludedVirtual()).
    VirtualSet set;
    set.mask = mask;
    if (mask == 0u || impl_->virtual_scenes.empty()) return set;
    const Impl& d = *impl_;
    for (std::size_t v = 0; v < d.sphere_bit.size(); ++v) {
        if ((d.sphere_bit[v] & mask) == 0u) continue;
        if (set.spheres == VirtualSet::kMax) {
            set.general = true;
            return set;
        }
        set.sphere_centre[static_cast<std::size_t>(set.spheres)] = d.sphere_centre[v];
        set.sphere_radius[static_cast<std::size_t>(set.spheres)] = d.sphere_radius[v];
        ++set.spheres;
    }
    set.mesh_bits = mask & d.mesh_bits;
    if (set.mesh_bits == 0u) return set;
    for (std::size_t v = 0; v < d.mesh_bit.size(); ++v) {
        if ((d.mesh_bit[v] & set.mesh_bits) == 0u) continue;
        if (set.meshes == VirtualSet::kMax) {
            set.general = true;
            return set;
        }
        const auto i = static_cast<std::size_t>(set.meshes);
        set.mesh_centre[i] = d.mesh_centre[v];
        set.mesh_radius[i] = d.mesh_radius[v];
        set.mesh_bit[i] = d.mesh_bit[v];
        ++set.meshes;
    }
    return set;
}

bool RayScene::occludedVirtualMeshes(const PreparedSegment& segment, const VirtualSet& set) const {
    std::uint32_t rest = set.mesh_bits;
    for (int i = 0; i < set.meshes; ++i) {
        const auto k = static_cast<std::size_t>(i);
        if ((set.mesh_bit[k] & rest) != 0u &&
            !Impl::segmentMeetsBall(segment.origin, segment.direction, segment.tfar, set.mesh_centre[k], set.mesh_radius[k])) {
            rest &= ~set.mesh_bit[k];
        }
    }
    return rest != 0u && impl_->occluded(impl_->virtual_top, segment.origin, segment.direction, segment.tfar, rest);
}

bool RayScene::occludedReal(const Eigen::Vector3d& from, const Eigen::Vector3d& from_normal, const Eigen::Vector3d& to,
                            const Eigen::Vector3d& to_normal) const {
    return occludedSegment(false, from, from_normal, to, to_normal, 0xFFFFFFFFu);
}

bool RayScene::occludedVirtual(const Eigen::Vector3d& from, const Eigen::Vector3d& from_normal,
                               const Eigen::Vector3d& to, const Eigen::Vector3d& to_normal, std::uint32_t mask) const {
    if (mask == 0u) return false;
    // The lift moves each end by epsilon times its normal (unit, or zero).
    const double lift = epsilon_ * std::sqrt(std::max({1.0, from_normal.squaredNorm(), to_normal.squaredNorm()}));
    if (!impl_->segmentMayMeet(from, to, mask, 2.0 * lift)) return false;
    return occludedSegment(true, from, from_normal, to, to_normal, mask);
}

bool RayScene::occludedRealRay(const Eigen::Vector3d& from, const Eigen::Vector3d& from_normal,
                               const Eigen::Vector3d& direction) const {
    return impl_->occluded(impl_->real_top, lifted(from, from_normal, direction, epsilon_), direction, 1e30);
}

bool RayScene::occludedVirtualRay(const Eigen::Vector3d& from, const Eigen::Vector3d& from_normal,
                                  const Eigen::Vector3d& direction, std::uint32_t mask) const {
    if (impl_->virtual_scenes.empty() || mask == 0u) return false;
    return impl_->occludedVirtual(lifted(from, from_normal, direction, epsilon_), direction, 1e30, mask);
}

RayHit RayScene::intersectReal(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
                               double max_distance) const {
    return impl_->intersect(impl_->real_top, origin, direction, max_distance);
}

void RayScene::intersectRealMany(const Eigen::Vector3d& origin, const Eigen::Vector3d* directions, int count,
                                 RayHit* out, double max_distance) const {
    impl_->intersectMany(impl_->real_top, origin, directions, count, out, max_distance);
}

void RayScene::intersectAllMany(const Eigen::Vector3d& origin, const Eigen::Vector3d* directions, int count,
                                RayHit* out, double max_distance) const {
    impl_->intersectMany(impl_->all_top, origin, directions, count, out, max_distance);
}

RayHit RayScene::intersectVirtual(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
                                  double max_distance) const {
    if (impl_->virtual_scenes.empty()) return {};
    return impl_->intersect(impl_->virtual_top, origin, direction, max_distance);
}

RayHit RayScene::intersectAll(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
                              double max_distance) const {
    return impl_->intersect(impl_->all_top, origin, direction, max_distance);
}

RayHit RayScene::intersectVirtualExcept(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction, int excluded,
                                        double max_distance) const {
    // The excluded object alone: every hit is on it (the steps below end with none).
    if (impl_->virtual_scenes.size() == 1 && excluded == 0) return {};
    // A ray that misses every other object's ball cannot hit them.
    if (!impl_->othersMayMeet(origin, direction, max_distance, excluded)) return {};
    // Few virtual objects: step past hits on the excluded one.
    Eigen::Vector3d o = origin;
    double travelled = 0.0;
    for (int guard = 0; guard < 16; ++guard) {
        RayHit hit = intersectVirtual(o, direction, max_distance - travelled);
        if (hit.kind == HitKind::kNone || hit.index != excluded) {
            if (hit.kind != HitKind::kNone) hit.distance += travelled;
            return hit;
        }
        const double step = hit.distance + epsilon_;
        o += step * direction;
        travelled += step;
    }
    return {};
}

}  // namespace commonlight::lighting

#include "mocks/sim/embree_scene.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <mutex>
#include <variant>

#include "core/log.h"

namespace commonlight::mocks::sim {

// What the tracer needs to know about one Embree geometry, by geometry id.
struct SimScene::Geometry {
    enum class Shape { kTriangles, kSphere, kDisc };
    enum class Role { kSurface, kTag, kLight };

    Shape shape = Shape::kTriangles;
    Role role = Role::kSurface;
    int object = -1;
    bool is_virtual = false;
    int light = -1;  // Role::kLight: index into lights_
    int tag = -1;    // Role::kTag: index into tags_
    Bsdf bsdf;
    Eigen::Vector3d emission = Eigen::Vector3d::Zero();
    // Triangles: per triangle, its unit normal (front side) and one vertex, in double.
    std::vector<Eigen::Vector3d> normals;
    std::vector<Eigen::Vector3d> first_vertex;
    // Sphere and disc.
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    Eigen::Vector3d axis = Eigen::Vector3d::UnitZ();  // disc normal
    double radius = 0.0;
    Eigen::AlignedBox3d box;  // world bounds
    struct Decal {
        int tag = -1;     // index into tags_
        int object = -1;  // the tag's object id
        // The tag's printed normal, and a ball around its printed square (with the plane's
        // tolerance): a hit outside the ball cannot be on the tag, so most hits on a surface
        // carrying many tags are rejected without a transform into each tag's frame.
        Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
        Eigen::Vector3d centre = Eigen::Vector3d::Zero();
        double reach_squared = 0.0;
    };
    std::vector<Decal> decal_tags;  // tags lying on this surface
};

// Errors Embree reports through its callback (on whichever thread called Embree). The first
// message is kept for the Result of build().
struct SimScene::EmbreeErrors {
    std::mutex mutex;
    std::string first;
    int count = 0;

    // Embree's error callback: runs on the thread that made the failing call, takes a lock briefly.
    static void callback(void* user, RTCError code, const char* message) {
        auto* self = static_cast<EmbreeErrors*>(user);
        const std::lock_guard lock(self->mutex);
        if (self->count++ == 0) self->first = "Embree error " + std::to_string(static_cast<int>(code)) + ": " + message;
        log::error("mocks/sim: Embree error " + std::to_string(static_cast<int>(code)) + ": " + message);
    }
    Result<void> check(const char* step) {
        const std::lock_guard lock(mutex);
        if (count == 0) return {};
        return fail(ErrorCode::kInternal, std::string(step) + ": " + first);
    }
};

void SimScene::DeviceRelease::operator()(RTCDevice device) const noexcept { rtcReleaseDevice(device); }
void SimScene::SceneRelease::operator()(RTCScene scene) const noexcept { rtcReleaseScene(scene); }

SimScene::SimScene() = default;
SimScene::SimScene(SimScene&&) noexcept = default;
SimScene& SimScene::operator=(SimScene&&) noexcept = default;
SimScene::~SimScene() = default;

namespace {

struct TriangleSoup {
    std::vector<Eigen::Vector3d> vertices;  // world
    std::vector<std::array<std::uint32_t, 3>> triangles;

    // Adds a quad (counter-clockwise seen from its front), as two triangles.
    void addQuad(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                 const Eigen::Vector3d& d) {
        const auto base = static_cast<std::uint32_t>(vertices.size());
        vertices.insert(vertices.end(), {a, b, c, d});
        triangles.push_back({base, base + 1, base + 2});
        triangles.push_back({base, base + 2, base + 3});
    }
};

// A centred rectangle in the x-y plane of `world_from_object`, front +z.
TriangleSoup rectangle(const Rigid3d& world_from_object, double half_x, double half_y) {
    TriangleSoup soup;
    const auto at = [&](double x, double y) { return world_from_object * Eigen::Vector3d(x, y, 0.0); };
    soup.addQuad(at(-half_x, -half_y), at(half_x, -half_y), at(half_x, half_y), at(-half_x, half_y));
    return soup;
}

// A centred box, six outward-facing quads.
TriangleSoup box(const Rigid3d& world_from_object, const Eigen::Vector3d& size) {
    TriangleSoup soup;
    const Eigen::Vector3d h = 0.5 * size;
    for (int axis = 0; axis < 3; ++axis) {
        // (axis, u, v) is a cyclic permutation of (x, y, z), so e_u x e_v = e_axis.
        const int u = (axis + 1) % 3;
        const int v = (axis + 2) % 3;
        for (const double sign : {1.0, -1.0}) {
            const auto at = [&](double su, double sv) {
                Eigen::Vector3d p;
                p[axis] = sign * h[axis];
                p[u] = su * h[u];
                p[v] = sv * h[v];
                return world_from_object * p;
            };
            if (sign > 0) {
                soup.addQuad(at(-1, -1), at(1, -1), at(1, 1), at(-1, 1));
            } else {
                soup.addQuad(at(-1, -1), at(-1, 1), at(1, 1), at(1, -1));
            }
        }
    }
    return soup;
}

TriangleSoup mesh(const Rigid3d& world_from_object, const Mesh& m) {
    TriangleSoup soup;
    soup.vertices.reserve(m.positions.size());
    for (const Eigen::Vector3f& p : m.positions) soup.vertices.push_back(world_from_object * p.cast<double>());
    for (std::size_t i = 0; i + 2 < m.indices.size(); i += 3) {
        soup.triangles.push_back({m.indices[i], m.indices[i + 1], m.indices[i + 2]});
    }
    return soup;
}

// A shape that is either triangles or an analytic sphere.
struct ShapeGeometry {
    std::optional<TriangleSoup> triangles;
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    double radius = 0.0;
};

Result<ShapeGeometry> shapeGeometry(const Shape& shape, const Rigid3d& world_from_object, const std::string& name) {
    ShapeGeometry out;
    if (const auto* plane = std::get_if<PlaneShape>(&shape)) {
        out.triangles = rectangle(world_from_object, 0.5 * plane->size.x(), 0.5 * plane->size.y());
    } else if (const auto* b = std::get_if<BoxShape>(&shape)) {
        out.triangles = box(world_from_object, b->size);
    } else if (const auto* sphere = std::get_if<SphereShape>(&shape)) {
        out.centre = world_from_object.translation;
        out.radius = sphere->radius;
    } else if (const auto* m = std::get_if<MeshShape>(&shape)) {
        if (!m->mesh) return fail(ErrorCode::kBadInput, "'" + name + "': mesh " + m->path.string() + " is not loaded");
        for (const std::uint32_t index : m->mesh->indices) {
            if (index >= m->mesh->positions.size()) {
                return fail(ErrorCode::kBadInput, "'" + name + "': mesh index out of range");
            }
        }
        out.triangles = mesh(world_from_object, *m->mesh);
    }
    return out;
}

}  // namespace

// Adds geometry to the Embree scene on the building thread and records it in geometries_.
class SimScene::Builder {
public:
    explicit Builder(SimScene& scene) : s_(scene) {}

    void addTriangles(const TriangleSoup& soup, Geometry record) {
        if (soup.triangles.empty()) return;
        // Owned here until attached; the scene keeps its own reference after rtcAttachGeometry.
        RTCGeometry geom = rtcNewGeometry(s_.device_.get(), RTC_GEOMETRY_TYPE_TRIANGLE);
        auto* vertices = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                                     3 * sizeof(float), soup.vertices.size()));
        auto* indices = static_cast<std::uint32_t*>(rtcSetNewGeometryBuffer(
            geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(std::uint32_t), soup.triangles.size()));
        if (vertices == nullptr || indices == nullptr) {
            rtcReleaseGeometry(geom);
            return;  // the error callback has recorded why
        }
        for (std::size_t i = 0; i < soup.vertices.size(); ++i) {
            for (int k = 0; k < 3; ++k) vertices[3 * i + k] = static_cast<float>(soup.vertices[i][k]);
            record.box.extend(soup.vertices[i]);
        }
        for (std::size_t i = 0; i < soup.triangles.size(); ++i) {
            const auto& tri = soup.triangles[i];
            for (int k = 0; k < 3; ++k) indices[3 * i + k] = tri[k];
            const Eigen::Vector3d& a = soup.vertices[tri[0]];
            const Eigen::Vector3d n = (soup.vertices[tri[1]] - a).cross(soup.vertices[tri[2]] - a);
            const double len = n.norm();
            // Hard case: a degenerate triangle has no normal; Embree never reports a hit on it.
            record.normals.push_back(len > 0.0 ? Eigen::Vector3d(n / len) : Eigen::Vector3d::UnitZ());
            record.first_vertex.push_back(a);
        }
        record.shape = Geometry::Shape::kTriangles;
        attach(geom, std::move(record));
    }

    void addSphere(const Eigen::Vector3d& centre, double radius, Geometry record) {
        if (!(radius > 0.0)) return;
        RTCGeometry geom = rtcNewGeometry(s_.device_.get(), RTC_GEOMETRY_TYPE_SPHERE_POINT);  // owned until attached
        auto* v = static_cast<float*>(
            rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT4, 4 * sizeof(float), 1));
        if (v == nullptr) {
            rtcReleaseGeometry(geom);
            return;
        }
        v[0] = static_cast<float>(centre.x());
        v[1] = static_cast<float>(centre.y());
        v[2] = static_cast<float>(centre.z());
        v[3] = static_cast<float>(radius);
        record.shape = Geometry::Shape::kSphere;
        record.centre = centre;
        record.radius = radius;
        record.box.extend(centre - Eigen::Vector3d::Constant(radius));
        record.box.extend(centre + Eigen::Vector3d::Constant(radius));
        attach(geom, std::move(record));
    }

    void addDisc(const Eigen::Vector3d& centre, const Eigen::Vector3d& normal, double radius, Geometry record) {
        if (!(radius > 0.0)) return;
        RTCGeometry geom =
            rtcNewGeometry(s_.device_.get(), RTC_GEOMETRY_TYPE_ORIENTED_DISC_POINT);  // owned until attached
        auto* v = static_cast<float*>(
            rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT4, 4 * sizeof(float), 1));
        auto* n = static_cast<float*>(
            rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_NORMAL, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), 1));
        if (v == nullptr || n == nullptr) {
            rtcReleaseGeometry(geom);
            return;
        }
        for (int k = 0; k < 3; ++k) {
            v[k] = static_cast<float>(centre[k]);
            n[k] = static_cast<float>(normal[k]);
        }
        v[3] = static_cast<float>(radius);
        record.shape = Geometry::Shape::kDisc;
        record.centre = centre;
        record.axis = normal;
        record.radius = radius;
        record.box.extend(centre - Eigen::Vector3d::Constant(radius));
        record.box.extend(centre + Eigen::Vector3d::Constant(radius));
        attach(geom, std::move(record));
    }

private:
    void attach(RTCGeometry geom, Geometry record) {
        rtcCommitGeometry(geom);
        const unsigned id = rtcAttachGeometry(s_.scene_.get(), geom);
        rtcReleaseGeometry(geom);  // the scene holds the geometry now
        if (id >= s_.geometries_.size()) s_.geometries_.resize(id + 1);
        s_.bounds_.extend(record.box);
        s_.geometries_[id] = std::move(record);
    }

    SimScene& s_;
};

Result<SimScene> SimScene::build(const Scene& scene, const SimSceneOptions& options) {
    SimScene out;
    // Step 1: lights, environment and tag textures (pure data, may fail on bad input).
    CL_TRY(out.lights_, makeSimLights(scene));
    CL_TRY(out.environment_, makeEnvironmentRadiance(scene));
    CL_TRY(out.tags_, makePlacedTags(scene.tags, options.tag_ink_spread_cells));

    // Step 2: the Embree device, with its error callback installed before anything else happens.
    out.errors_ = std::make_unique<EmbreeErrors>();
    out.device_.reset(rtcNewDevice(nullptr));  // owned by out.device_
    if (!out.device_) {
        return fail(ErrorCode::kInternal, "Embree: rtcNewDevice failed (error " +
                                              std::to_string(static_cast<int>(rtcGetDeviceError(nullptr))) + ")");
    }
    rtcSetDeviceErrorFunction(out.device_.get(), &EmbreeErrors::callback, out.errors_.get());
    out.scene_.reset(rtcNewScene(out.device_.get()));  // owned by out.scene_
    if (!out.scene_) return fail(out.errors_->check("Embree: rtcNewScene").error());
    // Robust traversal: no shortcuts that lose hits on shared edges (the furnace box must be closed).
    rtcSetSceneFlags(out.scene_.get(), RTC_SCENE_FLAG_ROBUST);
    rtcSetSceneBuildQuality(out.scene_.get(), RTC_BUILD_QUALITY_HIGH);
    Builder builder(out);

    // Step 3: real objects.
    for (std::size_t i = 0; i < scene.real_objects.size(); ++i) {
        const RealObject& object = scene.real_objects[i];
        Geometry record;
        record.object = static_cast<int>(out.objects_.size());
        record.bsdf = Bsdf::lambertian(object.albedo.value.value_or(options.default_albedo));
        out.objects_.push_back({ObjectKind::kReal, static_cast<int>(i), object.name});
        CL_TRY(const ShapeGeometry shape, shapeGeometry(object.shape, object.world_from_object, object.name));
        if (shape.triangles) {
            builder.addTriangles(*shape.triangles, std::move(record));
        } else {
            builder.addSphere(shape.centre, shape.radius, std::move(record));
        }
    }
    // Step 4: tags, each its own quad at exactly its pose.
    for (std::size_t i = 0; i < out.tags_.size(); ++i) {
        const PlacedTag& tag = out.tags_[i];
        Geometry record;
        record.role = Geometry::Role::kTag;
        record.tag = static_cast<int>(i);
        record.object = static_cast<int>(out.objects_.size());
        const auto item = std::find_if(scene.tags.items.begin(), scene.tags.items.end(),
                                       [&](const TagItem& t) { return t.id == tag.texture.id(); });
        out.objects_.push_back({ObjectKind::kTag, static_cast<int>(item - scene.tags.items.begin()),
                                "tag " + std::to_string(tag.texture.id())});
        builder.addTriangles(rectangle(tag.world_from_tag, tag.half_extent, tag.half_extent), std::move(record));
    }
    // Step 5: area lights (black surfaces that emit from their front).
    for (std::size_t i = 0; i < out.lights_.size(); ++i) {
        const SimLight& light = out.lights_[i];
        if (light.isDelta()) continue;
        Geometry record;
        record.role = Geometry::Role::kLight;
        record.light = static_cast<int>(i);
        record.object = static_cast<int>(out.objects_.size());
        record.bsdf = Bsdf::lambertian(Eigen::Vector3d::Zero());
        out.objects_.push_back({ObjectKind::kLight, light.scene_index, light.name});
        if (light.kind == LightKind::kRectangle) {
            const Rigid3d& pose = scene.lights[light.scene_index].world_from_object;
            builder.addTriangles(rectangle(pose, light.half_x.norm(), light.half_y.norm()), std::move(record));
        } else {
            builder.addDisc(light.position, light.normal, light.half_x.norm(), std::move(record));
        }
    }
    // Step 6: virtual objects at their pose at time_s.
    if (options.include_virtual) {
        for (std::size_t i = 0; i < scene.virtual_objects.size(); ++i) {
            const VirtualObject& object = scene.virtual_objects[i];
            const std::optional<Rigid3d> pose = worldFromObject(object, scene.tags, options.time_s);
            if (!pose)
                return fail(ErrorCode::kBadInput, "virtual object '" + object.name + "': its tag is not in the scene");
            Geometry record;
            record.object = static_cast<int>(out.objects_.size());
            record.is_virtual = true;
            const Material& m = object.material;
            record.bsdf = m.type == MaterialType::kGgx ? Bsdf::ggx(m.albedo, m.roughness) : Bsdf::lambertian(m.albedo);
            if (object.emission) {
                if (!object.emission->allFinite() || object.emission->minCoeff() < 0.0) {
                    return fail(ErrorCode::kBadInput, "virtual object '" + object.name + "': emission must be >= 0");
                }
                record.emission = *object.emission;
            }
            out.objects_.push_back({ObjectKind::kVirtual, static_cast<int>(i), object.name});
            CL_TRY(const ShapeGeometry shape, shapeGeometry(object.shape, *pose, object.name));
            if (shape.triangles) {
                builder.addTriangles(*shape.triangles, std::move(record));
            } else {
                builder.addSphere(shape.centre, shape.radius, std::move(record));
            }
        }
    }
    CL_TRY_VOID(out.errors_->check("Embree: adding geometry"));

    // Step 7: scale-dependent tolerances and the tags lying on each real surface.
    const double extent = out.bounds_.isEmpty() ? 1.0 : out.bounds_.diagonal().maxCoeff();
    out.ray_epsilon_ = 1e-5 * std::max(extent, 1.0);
    std::vector<int> tag_objects(out.tags_.size(), -1);
    for (const Geometry& geometry : out.geometries_) {
        if (geometry.role == Geometry::Role::kTag) tag_objects[geometry.tag] = geometry.object;
    }
    for (Geometry& geometry : out.geometries_) {
        if (geometry.role != Geometry::Role::kSurface || geometry.is_virtual) continue;
        for (std::size_t t = 0; t < out.tags_.size(); ++t) {
            const PlacedTag& tag = out.tags_[t];
            Eigen::AlignedBox3d tag_box;
            for (const double sx : {-1.0, 1.0}) {
                for (const double sy : {-1.0, 1.0}) {
                    tag_box.extend(tag.world_from_tag * Eigen::Vector3d(sx * tag.half_extent, sy * tag.half_extent, 0));
                }
            }
            const Eigen::Vector3d margin = Eigen::Vector3d::Constant(2.0 * out.ray_epsilon_);
            const Eigen::AlignedBox3d grown(geometry.box.min() - margin, geometry.box.max() + margin);
            if (!grown.intersects(tag_box)) continue;
            // |q| of a point on the square within the plane's tolerance is at most
            // sqrt(2 h^2 + eps^2); the factor leaves room for rounding in the transform.
            const double reach_squared =
                (2.0 * tag.half_extent * tag.half_extent + out.ray_epsilon_ * out.ray_epsilon_) * (1.0 + 1e-9) + 1e-24;
            geometry.decal_tags.push_back({static_cast<int>(t), tag_objects[t], tag.world_from_tag.rotation * Eigen::Vector3d::UnitZ(),
                                           tag.world_from_tag.translation, reach_squared});
        }
    }

    // Step 8: build the BVH, once, on this thread.
    rtcCommitScene(out.scene_.get());
    CL_TRY_VOID(out.errors_->check("Embree: rtcCommitScene"));
    return out;
}

namespace {

void setRay(RTCRay& ray, const Eigen::Vector3d& origin, const Eigen::Vector3d& dir, double t_max) {
    ray.org_x = static_cast<float>(origin.x());
    ray.org_y = static_cast<float>(origin.y());
    ray.org_z = static_cast<float>(origin.z());
    ray.dir_x = static_cast<float>(dir.x());
    ray.dir_y = static_cast<float>(dir.y());
    ray.dir_z = static_cast<float>(dir.z());
    ray.tnear = 0.0f;
    ray.tfar = std::isfinite(t_max) ? static_cast<float>(t_max) : std::numeric_limits<float>::infinity();
    ray.time = 0.0f;
    ray.mask = 0xffffffffu;
    ray.id = 0;
    ray.flags = 0;
}

// Distance along origin + t dir to the plane through `point` with normal `n`; `fallback` when
// the ray is (nearly) parallel to the plane. Hard case: parallel rays never reach here with a hit
// from Embree except by rounding, and then Embree's distance is as good as any.
double planeDistance(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir, const Eigen::Vector3d& point,
                     const Eigen::Vector3d& n, double fallback) {
    const double denom = dir.dot(n);
    if (std::abs(denom) < 1e-9) return fallback;
    const double t = (point - origin).dot(n) / denom;
    // Keep Embree's distance when the refinement disagrees wildly (it should agree to float precision).
    return std::isfinite(t) && std::abs(t - fallback) <= 1e-3 * std::max(1.0, fallback) ? t : fallback;
}

}  // namespace

std::optional<SurfaceHit> SimScene::intersect(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir,
                                              double t_max) const {
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    RTCRayHit ray_hit;
    setRay(ray_hit.ray, origin, dir, t_max);
    ray_hit.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    ray_hit.hit.primID = RTC_INVALID_GEOMETRY_ID;
    ray_hit.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(scene_.get(), &context, &ray_hit);
    if (ray_hit.hit.geomID == RTC_INVALID_GEOMETRY_ID || ray_hit.hit.geomID >= geometries_.size()) return std::nullopt;
    return makeHit(ray_hit, origin, dir);
}

bool SimScene::occluded(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir, double t_max) const {
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    RTCRay ray;
    setRay(ray, origin, dir, t_max);
    rtcOccluded1(scene_.get(), &context, &ray);
    // Embree sets tfar to -inf when it finds any hit.
    return ray.tfar < 0.0f;
}

bool SimScene::occludedExceptLight(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir, double t_max,
                                   int light) const {
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    RTCRayHit ray_hit;
    setRay(ray_hit.ray, origin, dir, t_max);
    ray_hit.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    ray_hit.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    // The nearest hit decides: if it is the light itself, nothing lies between (a light is planar,
    // a ray meets it once).
    rtcIntersect1(scene_.get(), &context, &ray_hit);
    if (ray_hit.hit.geomID == RTC_INVALID_GEOMETRY_ID || ray_hit.hit.geomID >= geometries_.size()) return false;
    const Geometry& g = geometries_[ray_hit.hit.geomID];
    return !(g.role == Geometry::Role::kLight && g.light == light);
}

SurfaceHit SimScene::makeHit(const RTCRayHit& ray_hit, const Eigen::Vector3d& origin,
                             const Eigen::Vector3d& dir) const {
    const Geometry& g = geometries_[ray_hit.hit.geomID];
    SurfaceHit hit;
    hit.t = ray_hit.ray.tfar;
    // Refine the hit in double precision against the exact surface.
    switch (g.shape) {
        case Geometry::Shape::kTriangles: {
            const std::size_t prim = std::min<std::size_t>(ray_hit.hit.primID, g.normals.size() - 1);
            hit.n = g.normals[prim];
            hit.t = planeDistance(origin, dir, g.first_vertex[prim], hit.n, hit.t);
            break;
        }
        case Geometry::Shape::kSphere: {
            const Eigen::Vector3d oc = origin - g.centre;
            const double b = oc.dot(dir);
            const double disc = b * b - (oc.squaredNorm() - g.radius * g.radius);
            if (disc >= 0.0) {
                const double root = std::sqrt(disc);
                // The root nearer to Embree's distance (the far one for a ray starting inside).
                const double t0 = -b - root;
                const double t1 = -b + root;
                hit.t = std::abs(t0 - hit.t) <= std::abs(t1 - hit.t) ? t0 : t1;
            }
            const Eigen::Vector3d p = origin + hit.t * dir;
            hit.n = (p - g.centre) / g.radius;
            const double len = hit.n.norm();
            hit.n = len > 0.0 ? Eigen::Vector3d(hit.n / len) : Eigen::Vector3d::UnitZ();
            break;
        }
        case Geometry::Shape::kDisc:
            hit.n = g.axis;
            hit.t = planeDistance(origin, dir, g.centre, g.axis, hit.t);
            break;
    }
    hit.p = origin + hit.t * dir;
    hit.front = dir.dot(hit.n) < 0.0;
    hit.object = g.object;
    hit.is_virtual = g.is_virtual;
    hit.bsdf = g.bsdf;
    switch (g.role) {
        case Geometry::Role::kSurface:
            if (hit.front) hit.emission = g.emission;
            if (!g.decal_tags.empty()) applyDecal(g, hit, dir);
            break;
        case Geometry::Role::kTag: {
            const PlacedTag& tag = tags_[g.tag];
            const Eigen::Vector3d q = tag.tag_from_world * hit.p;
            const double albedo = hit.front ? tag.albedoAt(q.x(), q.y()) : tag.albedo_white;
            hit.bsdf = Bsdf::lambertian(Eigen::Vector3d::Constant(albedo));
            break;
        }
        case Geometry::Role::kLight:
            hit.light = g.light;
            if (hit.front) hit.emission = lights_[g.light].emission;
            break;
    }
    return hit;
}

void SimScene::applyDecal(const Geometry& geometry, SurfaceHit& hit, const Eigen::Vector3d& dir) const {
    for (const Geometry::Decal& decal : geometry.decal_tags) {
        if ((hit.p - decal.centre).squaredNorm() > decal.reach_squared) continue;
        const PlacedTag& tag = tags_[decal.tag];
        // Only the printed side, only surfaces parallel to the tag, only points on its plane.
        if (dir.dot(decal.normal) >= 0.0 || std::abs(hit.n.dot(decal.normal)) < 0.999) continue;
        const Eigen::Vector3d q = tag.tag_from_world * hit.p;
        if (std::abs(q.z()) > ray_epsilon_ || !tag.contains(q.x(), q.y())) continue;
        hit.bsdf = Bsdf::lambertian(Eigen::Vector3d::Constant(tag.albedoAt(q.x(), q.y())));
        hit.object = decal.object;
        return;
    }
}

}  // namespace commonlight::mocks::sim

#include "lighting/proxy_geometry.h"

#include <cmath>
#include <map>
#include <numbers>
#include <variant>

namespace commonlight::lighting {

namespace {

bool finite(const Eigen::Vector3d& v) { return v.allFinite(); }

Face makeFace(FaceOwner owner, int object, int index, const Eigen::Vector3d& origin, const Eigen::Vector3d& edge_s,
              const Eigen::Vector3d& edge_t, bool triangle) {
    Face f;
    f.owner = owner;
    f.object_index = object;
    f.face_index = index;
    f.triangle = triangle;
    f.origin = origin;
    f.edge_s = edge_s;
    f.edge_t = edge_t;
    const Eigen::Vector3d cross = edge_s.cross(edge_t);
    const double norm = cross.norm();
    f.area = triangle ? 0.5 * norm : norm;
    f.normal = norm > 0.0 ? Eigen::Vector3d(cross / norm) : Eigen::Vector3d::UnitZ();
    return f;
}

// The six faces of a box centred on the origin, outward, numbered +x, -x, +y, -y, +z, -z.
std::vector<Face> boxFaces(FaceOwner owner, int object, const Eigen::Vector3d& size) {
    const Eigen::Vector3d h = 0.5 * size;
    const Eigen::Vector3d sx(size.x(), 0, 0), sy(0, size.y(), 0), sz(0, 0, size.z());
    return {
        makeFace(owner, object, 0, {h.x(), -h.y(), -h.z()}, sy, sz, false),
        makeFace(owner, object, 1, {-h.x(), h.y(), -h.z()}, -sy, sz, false),
        makeFace(owner, object, 2, {h.x(), h.y(), -h.z()}, -sx, sz, false),
        makeFace(owner, object, 3, {-h.x(), -h.y(), -h.z()}, sx, sz, false),
        makeFace(owner, object, 4, {-h.x(), -h.y(), h.z()}, sx, sy, false),
        makeFace(owner, object, 5, {-h.x(), h.y(), -h.z()}, sx, -sy, false),
    };
}

// Faces of a shape in the object's own frame. `what` names the object in errors.
Result<std::vector<Face>> shapeFaces(FaceOwner owner, int object, const Shape& shape, const std::string& what,
                                    int sphere_levels = 2) {
    std::vector<Face> faces;
    if (const auto* plane = std::get_if<PlaneShape>(&shape)) {
        if (!(plane->size.allFinite() && plane->size.x() > 0.0 && plane->size.y() > 0.0)) {
            return fail(ErrorCode::kBadInput, what + ": plane of zero area or non-finite size");
        }
        faces.push_back(makeFace(owner, object, 0, {-0.5 * plane->size.x(), -0.5 * plane->size.y(), 0.0},
                                 {plane->size.x(), 0.0, 0.0}, {0.0, plane->size.y(), 0.0}, false));
    } else if (const auto* box = std::get_if<BoxShape>(&shape)) {
        if (!box->size.allFinite() || (box->size.array() <= 0.0).any()) {
            return fail(ErrorCode::kBadInput, what + ": box size must be positive along x, y and z (a zero or negative "
                                                     "size makes it flat or inside-out)");
        }
        faces = boxFaces(owner, object, box->size);
    } else if (const auto* sphere = std::get_if<SphereShape>(&shape)) {
        if (!(std::isfinite(sphere->radius) && sphere->radius > 0.0)) {
            return fail(ErrorCode::kBadInput, what + ": sphere radius must be positive");
        }
        int index = 0;
        for (const auto& tri : icosphere(sphere_levels)) {
            const Eigen::Vector3d a = sphere->radius * tri[0], b = sphere->radius * tri[1], c = sphere->radius * tri[2];
            faces.push_back(makeFace(owner, object, index++, a, b - a, c - a, true));
        }
    } else if (const auto* mesh = std::get_if<MeshShape>(&shape)) {
        if (!mesh->mesh) return fail(ErrorCode::kBadInput, what + ": mesh " + mesh->path.string() + " is not loaded");
        const Mesh& m = *mesh->mesh;
        for (std::size_t t = 0; t < m.triangleCount(); ++t) {
            const std::uint32_t i0 = m.indices[3 * t], i1 = m.indices[3 * t + 1], i2 = m.indices[3 * t + 2];
            if (i0 >= m.positions.size() || i1 >= m.positions.size() || i2 >= m.positions.size()) {
                return fail(ErrorCode::kBadInput, what + ": mesh " + mesh->path.string() + ": triangle " +
                                                      std::to_string(t) + " indexes a vertex that does not exist");
            }
            const Eigen::Vector3d a = m.positions[i0].cast<double>(), b = m.positions[i1].cast<double>(),
                                  c = m.positions[i2].cast<double>();
            if (!finite(a) || !finite(b) || !finite(c)) continue;
            Face f = makeFace(owner, object, static_cast<int>(t), a, b - a, c - a, true);
            // Hard case: a sliver or a repeated vertex carries no light; skip it, keep its index free.
            if (!(f.area > 1e-12)) continue;
            faces.push_back(f);
        }
        if (faces.empty()) {
            return fail(ErrorCode::kBadInput,
                        what + ": mesh " + mesh->path.string() + " is degenerate (no triangle of positive area)");
        }
    }
    return faces;
}

Result<void> checkPose(const Rigid3d& pose, const std::string& what) {
    if (!pose.isValid()) return fail(ErrorCode::kBadInput, what + ": world_from_object is not a finite rigid transform");
    return {};
}

}  // namespace

std::vector<Eigen::Vector3d> Face::corners() const {
    if (triangle) return {origin, origin + edge_s, origin + edge_t};
    return {origin, origin + edge_s, origin + edge_s + edge_t, origin + edge_t};
}

Face transformed(const Face& face, const Rigid3d& world_from_object) {
    Face f = face;
    const Eigen::Matrix3d r = world_from_object.rotationMatrix();
    f.origin = world_from_object * face.origin;
    f.edge_s = r * face.edge_s;
    f.edge_t = r * face.edge_t;
    f.normal = r * face.normal;
    return f;
}

Result<std::vector<Face>> realFaces(const Scene& scene) {
    std::vector<Face> all;
    for (std::size_t i = 0; i < scene.real_objects.size(); ++i) {
        const RealObject& object = scene.real_objects[i];
        const std::string what = "real object '" + object.name + "'";
        CL_TRY_VOID(checkPose(object.world_from_object, what));
        CL_TRY(std::vector<Face> faces, shapeFaces(FaceOwner::kReal, static_cast<int>(i), object.shape, what));
        for (Face& f : faces) {
            f = transformed(f, object.world_from_object);
            if (object.albedo.value) {
                f.albedo = object.albedo.value->cwiseMax(0.0).cwiseMin(1.0);
                f.albedo_known = true;
            }
            all.push_back(f);
        }
    }
    return all;
}

Result<std::vector<Face>> virtualFaces(const Scene& scene, int virtual_index, int sphere_levels) {
    const VirtualObject& object = scene.virtual_objects.at(static_cast<std::size_t>(virtual_index));
    const std::string what = "virtual object '" + object.name + "'";
    CL_TRY(std::vector<Face> faces, shapeFaces(FaceOwner::kVirtual, virtual_index, object.shape, what, sphere_levels));
    for (Face& f : faces) {
        // GGX objects take part in the radiosity solution as Lambertian reflectors of the same
        // albedo (their bounce onto real surfaces; the renderer shades their own look).
        f.albedo = object.material.albedo.cwiseMax(0.0).cwiseMin(1.0);
        f.albedo_known = true;
        if (object.emission) f.emission = object.emission->cwiseMax(0.0);
    }
    return faces;
}

Result<std::vector<LightGeometry>> lightGeometry(const Scene& scene) {
    std::vector<LightGeometry> lights;
    for (std::size_t i = 0; i < scene.lights.size(); ++i) {
        const Light& light = scene.lights[i];
        const std::string what = "light '" + light.name + "'";
        LightGeometry g;
        g.light_index = static_cast<int>(i);
        g.world_from_object = light.world_from_object;
        if (const auto* area = std::get_if<AreaLightShape>(&light.shape)) {
            if (!(area->size.allFinite() && area->size.x() > 0.0 && area->size.y() > 0.0)) {
                return fail(ErrorCode::kBadInput, what + ": area light of zero or negative size");
            }
            CL_TRY_VOID(checkPose(light.world_from_object, what));
            g.size = area->size;
            const double hx = 0.5 * area->size.x(), hy = 0.5 * area->size.y();
            for (const Eigen::Vector3d& c : {Eigen::Vector3d(-hx, -hy, 0), Eigen::Vector3d(hx, -hy, 0),
                                             Eigen::Vector3d(hx, hy, 0), Eigen::Vector3d(-hx, hy, 0)}) {
                g.polygon.push_back(light.world_from_object * c);
            }
            g.area = area->size.x() * area->size.y();
        } else if (const auto* disc = std::get_if<DiscLightShape>(&light.shape)) {
            if (!(std::isfinite(disc->radius) && disc->radius > 0.0)) {
                return fail(ErrorCode::kBadInput, what + ": disc light of zero or negative radius");
            }
            CL_TRY_VOID(checkPose(light.world_from_object, what));
            g.disc = true;
            g.radius = disc->radius;
            // A regular 32-gon of the disc's area (form factors); sampling uses the true disc.
            constexpr int kSides = 32;
            const double r = disc->radius * std::sqrt(2.0 * std::numbers::pi / (kSides * std::sin(2.0 * std::numbers::pi / kSides)));
            for (int k = 0; k < kSides; ++k) {
                const double a = 2.0 * std::numbers::pi * k / kSides;
                g.polygon.push_back(light.world_from_object * Eigen::Vector3d(r * std::cos(a), r * std::sin(a), 0.0));
            }
            g.area = std::numbers::pi * disc->radius * disc->radius;
        } else {
            continue;
        }
        g.normal = light.world_from_object.rotationMatrix().col(2);
        g.centre = light.world_from_object.translation;
        lights.push_back(std::move(g));
    }
    return lights;
}

std::vector<std::array<Eigen::Vector3d, 3>> icosphere(int levels) {
    const double t = (1.0 + std::sqrt(5.0)) / 2.0;
    std::vector<Eigen::Vector3d> v{{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0}, {0, -1, t}, {0, 1, t},
                                   {0, -1, -t}, {0, 1, -t}, {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
    for (auto& p : v) p.normalize();
    std::vector<std::array<int, 3>> f{{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                                      {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                                      {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                                      {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
    for (int level = 0; level < levels; ++level) {
        std::map<std::pair<int, int>, int> mid;
        const auto midpoint = [&](int a, int b) {
            const auto key = std::minmax(a, b);
            const auto it = mid.find(key);
            if (it != mid.end()) return it->second;
            v.push_back((v[a] + v[b]).normalized());
            const int index = static_cast<int>(v.size()) - 1;
            mid.emplace(key, index);
            return index;
        };
        std::vector<std::array<int, 3>> next;
        for (const auto& tri : f) {
            const int a = midpoint(tri[0], tri[1]), b = midpoint(tri[1], tri[2]), c = midpoint(tri[2], tri[0]);
            next.push_back({tri[0], a, c});
            next.push_back({tri[1], b, a});
            next.push_back({tri[2], c, b});
            next.push_back({a, b, c});
        }
        f = std::move(next);
    }
    std::vector<std::array<Eigen::Vector3d, 3>> out;
    out.reserve(f.size());
    for (const auto& tri : f) out.push_back({v[tri[0]], v[tri[1]], v[tri[2]]});
    return out;
}

}  // namespace commonlight::lighting

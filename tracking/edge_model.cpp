#include "tracking/edge_model.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>
#include <numbers>
#include <sstream>
#include <tuple>
#include <utility>
#include <variant>

namespace commonlight::tracking {
namespace {

using Eigen::Vector2d;
using Eigen::Vector3d;

constexpr double kInfinity = std::numeric_limits<double>::infinity();

// Entry and exit of a ray through an axis-aligned box, in ray parameters; nullopt when it misses.
// Hard case: a direction component of zero (the ray is parallel to a pair of faces): it is inside
// that slab for every t, or for none.
std::optional<std::pair<double, double>> slabs(const Vector3d& origin, const Vector3d& dir, const Vector3d& lower,
                                               const Vector3d& upper) {
    double t_near = -kInfinity;
    double t_far = kInfinity;
    for (int i = 0; i < 3; ++i) {
        if (dir[i] == 0.0) {
            if (origin[i] < lower[i] || origin[i] > upper[i]) return std::nullopt;
            continue;
        }
        double t1 = (lower[i] - origin[i]) / dir[i];
        double t2 = (upper[i] - origin[i]) / dir[i];
        if (t1 > t2) std::swap(t1, t2);
        t_near = std::max(t_near, t1);
        t_far = std::min(t_far, t2);
        if (t_near > t_far) return std::nullopt;
    }
    return std::make_pair(t_near, t_far);
}

// The first surface crossing of a box's boundary in (t_min, t_max]: the entry, or the exit for
// a ray that starts inside (a camera inside a room modelled as a box).
std::optional<double> boxCrossing(const std::pair<double, double>& span, double t_min, double t_max) {
    const auto [t_near, t_far] = span;
    if (t_near > t_min && t_near <= t_max) return t_near;
    if (t_near <= t_min && t_far > t_min && t_far <= t_max) return t_far;
    return std::nullopt;
}

// Moller-Trumbore, both sides.
std::optional<double> triangleHit(const Vector3d& origin, const Vector3d& dir, const Vector3d& p0, const Vector3d& p1,
                                  const Vector3d& p2) {
    const Vector3d e1 = p1 - p0;
    const Vector3d e2 = p2 - p0;
    const Vector3d p = dir.cross(e2);
    const double det = e1.dot(p);
    // Hard case: a ray in the triangle's plane; it cannot hide anything behind the triangle.
    if (std::abs(det) < 1e-300) return std::nullopt;
    const double inv = 1.0 / det;
    const Vector3d s = origin - p0;
    const double u = s.dot(p) * inv;
    if (u < 0.0 || u > 1.0) return std::nullopt;
    const Vector3d q = s.cross(e1);
    const double v = dir.dot(q) * inv;
    if (v < 0.0 || u + v > 1.0) return std::nullopt;
    return e2.dot(q) * inv;
}

Result<void> checkPose(const RealObject& object) {
    if (object.world_from_object.isValid()) return {};
    return fail(ErrorCode::kBadInput, "real object '" + object.name + "': world_from_object is not a valid pose");
}

void addEdge(std::vector<ModelEdge>& edges, const Vector3d& a, const Vector3d& b, const Vector3d& n0,
             const Vector3d& n1, int object, double min_length) {
    if ((b - a).norm() < min_length) return;
    edges.push_back({a, b, n0, n1, object});
}

}  // namespace

Result<void> EdgeModelOptions::validate() const {
    if (!(crease_angle_deg > 0.0 && crease_angle_deg < 180.0)) {
        return fail(ErrorCode::kUsage,
                    "EdgeModelOptions.crease_angle_deg must be in (0, 180), got " + std::to_string(crease_angle_deg));
    }
    if (!(min_edge_length >= 0.0) || !std::isfinite(min_edge_length)) {
        return fail(ErrorCode::kUsage, "EdgeModelOptions.min_edge_length must be >= 0");
    }
    if (!(weld_tolerance > 0.0 && weld_tolerance < 0.1)) {
        return fail(ErrorCode::kUsage, "EdgeModelOptions.weld_tolerance must be in (0, 0.1)");
    }
    return {};
}

Result<EdgeModel> EdgeModel::fromScene(const Scene& scene, const EdgeModelOptions& options) {
    CL_TRY_VOID(options.validate());
    EdgeModel model;
    const double cos_crease = std::cos(options.crease_angle_deg * std::numbers::pi / 180.0);
    for (std::size_t index = 0; index < scene.real_objects.size(); ++index) {
        const RealObject& object = scene.real_objects[index];
        const int id = static_cast<int>(index);
        model.names_.push_back(object.name);
        CL_TRY_VOID(checkPose(object));
        const Rigid3d& pose = object.world_from_object;
        const Eigen::Matrix3d r = pose.rotationMatrix();

        if (const auto* box = std::get_if<BoxShape>(&object.shape)) {
            if (!box->size.allFinite() || !(box->size.minCoeff() > 0.0)) {
                return fail(ErrorCode::kBadInput, "real object '" + object.name + "': box size must be positive");
            }
            const Vector3d h = 0.5 * box->size;
            // The edges along axis k at the corners (s1, s2) of the two other axes i, j; its faces
            // are those with normals s1 e_i and s2 e_j.
            for (int k = 0; k < 3; ++k) {
                const int i = (k + 1) % 3;
                const int j = (k + 2) % 3;
                for (const double s1 : {-1.0, 1.0}) {
                    for (const double s2 : {-1.0, 1.0}) {
                        Vector3d a = Vector3d::Zero();
                        a[i] = s1 * h[i];
                        a[j] = s2 * h[j];
                        Vector3d b = a;
                        a[k] = -h[k];
                        b[k] = h[k];
                        addEdge(model.edges_, pose * a, pose * b, r * (s1 * Vector3d::Unit(i)),
                                r * (s2 * Vector3d::Unit(j)), id, options.min_edge_length);
                    }
                }
            }
            model.boxes_.push_back({pose.inverse(), h});
        } else if (const auto* plane = std::get_if<PlaneShape>(&object.shape)) {
            if (!plane->size.allFinite() || !(plane->size.minCoeff() > 0.0)) {
                return fail(ErrorCode::kBadInput, "real object '" + object.name + "': plane size must be positive");
            }
            const Vector2d h = 0.5 * plane->size;
            const std::array<Vector3d, 4> corners = {Vector3d(-h.x(), -h.y(), 0), Vector3d(h.x(), -h.y(), 0),
                                                     Vector3d(h.x(), h.y(), 0), Vector3d(-h.x(), h.y(), 0)};
            const Vector3d n = r.col(2);
            for (int c = 0; c < 4; ++c) {
                addEdge(model.edges_, pose * corners[c], pose * corners[(c + 1) % 4], n, Vector3d::Zero(), id,
                        options.min_edge_length);
            }
            model.planes_.push_back({pose.inverse(), h});
        } else if (const auto* sphere = std::get_if<SphereShape>(&object.shape)) {
            if (!std::isfinite(sphere->radius) || !(sphere->radius > 0.0)) {
                return fail(ErrorCode::kBadInput, "real object '" + object.name + "': sphere radius must be positive");
            }
            model.spheres_.push_back({pose.translation, sphere->radius});
        } else if (const auto* mesh_shape = std::get_if<MeshShape>(&object.shape)) {
            if (!mesh_shape->mesh) {
                return fail(ErrorCode::kBadInput, "real object '" + object.name + "': mesh '" +
                                                      mesh_shape->path.string() + "' was not loaded");
            }
            const Mesh& mesh = *mesh_shape->mesh;
            if (mesh.positions.empty() || mesh.indices.size() % 3 != 0) {
                return fail(ErrorCode::kBadInput, "real object '" + object.name + "': mesh has no triangles");
            }
            // Step 1: vertices in the world, welded by position on a grid of the tolerance.
            MeshOccluder occluder;
            occluder.lower = Vector3d::Constant(kInfinity);
            occluder.upper = Vector3d::Constant(-kInfinity);
            std::vector<Vector3d> world(mesh.positions.size());
            for (std::size_t v = 0; v < mesh.positions.size(); ++v) {
                world[v] = pose * mesh.positions[v].cast<double>();
                if (!world[v].allFinite()) {
                    return fail(ErrorCode::kBadInput,
                                "real object '" + object.name + "': mesh has non-finite vertices");
                }
                occluder.lower = occluder.lower.cwiseMin(world[v]);
                occluder.upper = occluder.upper.cwiseMax(world[v]);
            }
            const double cell = std::max(options.weld_tolerance * (occluder.upper - occluder.lower).norm(), 1e-12);
            std::map<std::tuple<long long, long long, long long>, int> cells;
            std::vector<int> welded(world.size());
            for (std::size_t v = 0; v < world.size(); ++v) {
                const auto key = std::make_tuple(std::llround(world[v].x() / cell), std::llround(world[v].y() / cell),
                                                 std::llround(world[v].z() / cell));
                welded[v] = cells.emplace(key, static_cast<int>(v)).first->second;
            }
            // Step 2: faces and the faces of every (welded) edge.
            std::vector<Vector3d> face_normals;
            std::map<std::pair<int, int>, std::vector<int>> edge_faces;
            for (std::size_t t = 0; t + 2 < mesh.indices.size(); t += 3) {
                std::array<int, 3> v{};
                for (int c = 0; c < 3; ++c) {
                    const std::uint32_t i = mesh.indices[t + c];
                    if (i >= world.size()) {
                        return fail(ErrorCode::kBadInput, "real object '" + object.name + "': mesh index out of range");
                    }
                    v[c] = welded[i];
                }
                const Vector3d cross = (world[v[1]] - world[v[0]]).cross(world[v[2]] - world[v[0]]);
                // Hard case: degenerate triangles (collapsed by welding, or slivers) have no normal.
                if (v[0] == v[1] || v[1] == v[2] || v[0] == v[2] || cross.norm() < 1e-20) continue;
                for (int c = 0; c < 3; ++c) occluder.vertices.push_back(world[v[c]]);
                const int face = static_cast<int>(face_normals.size());
                face_normals.push_back(cross.normalized());
                for (int c = 0; c < 3; ++c) {
                    const int a = v[c];
                    const int b = v[(c + 1) % 3];
                    edge_faces[{std::min(a, b), std::max(a, b)}].push_back(face);
                }
            }
            // Step 3: boundary edges (one face), creases (two faces at a sharp angle), and
            // non-manifold edges (three or more faces meet: always an edge).
            for (const auto& [key, faces] : edge_faces) {
                const Vector3d& a = world[key.first];
                const Vector3d& b = world[key.second];
                if (faces.size() == 1) {
                    addEdge(model.edges_, a, b, face_normals[faces[0]], Vector3d::Zero(), id, options.min_edge_length);
                } else if (faces.size() > 2 || face_normals[faces[0]].dot(face_normals[faces[1]]) < cos_crease) {
                    addEdge(model.edges_, a, b, face_normals[faces[0]], face_normals[faces[1]], id,
                            options.min_edge_length);
                }
            }
            if (!occluder.vertices.empty()) model.meshes_.push_back(std::move(occluder));
        }
    }
    return model;
}

std::optional<double> EdgeModel::firstHit(const Vector3d& origin, const Vector3d& dir, double t_min, double t_max,
                                          bool any) const {
    double best = kInfinity;
    const auto consider = [&](std::optional<double> t) {
        if (t && *t > t_min && *t <= t_max && *t < best) best = *t;
    };
    for (const BoxOccluder& box : boxes_) {
        const Vector3d o = box.object_from_world * origin;
        const Vector3d d = box.object_from_world.rotation * dir;
        if (const auto span = slabs(o, d, -box.half_size, box.half_size)) consider(boxCrossing(*span, t_min, t_max));
        if (any && best < kInfinity) return best;
    }
    for (const PlaneOccluder& plane : planes_) {
        const Vector3d o = plane.object_from_world * origin;
        const Vector3d d = plane.object_from_world.rotation * dir;
        if (d.z() == 0.0) continue;  // parallel to the plane
        const double t = -o.z() / d.z();
        const Vector3d p = o + t * d;
        if (std::abs(p.x()) <= plane.half_size.x() && std::abs(p.y()) <= plane.half_size.y()) consider(t);
        if (any && best < kInfinity) return best;
    }
    for (const SphereOccluder& sphere : spheres_) {
        // |o + t d - c|^2 = r^2
        const Vector3d oc = origin - sphere.centre;
        const double a = dir.squaredNorm();
        const double b = oc.dot(dir);
        const double c = oc.squaredNorm() - sphere.radius * sphere.radius;
        const double disc = b * b - a * c;
        if (disc < 0.0 || a == 0.0) continue;
        const double root = std::sqrt(disc);
        const double t0 = (-b - root) / a;
        const double t1 = (-b + root) / a;
        consider(t0 > t_min ? t0 : t1);
        if (any && best < kInfinity) return best;
    }
    for (const MeshOccluder& mesh : meshes_) {
        const auto span = slabs(origin, dir, mesh.lower, mesh.upper);
        if (!span || span->second < t_min || span->first > std::min(t_max, best)) continue;
        for (std::size_t v = 0; v + 2 < mesh.vertices.size(); v += 3) {
            consider(triangleHit(origin, dir, mesh.vertices[v], mesh.vertices[v + 1], mesh.vertices[v + 2]));
            if (any && best < kInfinity) return best;
        }
    }
    if (best == kInfinity) return std::nullopt;
    return best;
}

bool EdgeModel::occluded(const Vector3d& from, const Vector3d& to, double epsilon) const {
    const Vector3d dir = to - from;
    const double length = dir.norm();
    if (!(length > epsilon)) return false;
    // firstHit's tests, ending at the first hit in range: any hit occludes, the nearest is not needed.
    return firstHit(from, dir / length, 0.0, length - epsilon, true).has_value();
}

}  // namespace commonlight::tracking

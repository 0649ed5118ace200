// The straight edges of the real proxy geometry (boxes, planes, meshes) and the proxies as
// occluders, for model-edge refinement (tracking/edge_refine.h). docs/edge-refine.md
// describes the model.
//
// Edges:
// - a box gives its 12 edges, each with the outward normals of its two faces;
// - a plane gives its 4 boundary edges with its one face normal (+z of the plane);
// - a mesh gives its boundary edges (one face) and its creases: edges shared by two triangles
//   whose normals differ by more than `crease_angle_deg`. Vertices are welded by position first,
//   so split vertices (a glTF cube has 24) do not make every triangle edge a boundary, and the
//   diagonals of coplanar triangles are never edges;
// - spheres give no straight edges; they only occlude.
// Tags are not edges (they lie on surfaces and have edges of their own that this model ignores).
//
// Immutable once built: any number of threads may query one model.
#pragma once

#include <optional>
#include <span>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/pose.h"
#include "core/result.h"
#include "core/scene.h"

namespace commonlight::tracking {

struct ModelEdge {
    Eigen::Vector3d a_in_world = Eigen::Vector3d::Zero();  // end points, metres
    Eigen::Vector3d b_in_world = Eigen::Vector3d::Zero();
    // Unit outward normals of the adjacent faces (world). A boundary edge (plane, open mesh) has
    // one face: normal1 is zero.
    Eigen::Vector3d normal0 = Eigen::Vector3d::Zero();
    Eigen::Vector3d normal1 = Eigen::Vector3d::Zero();
    int object = -1;  // index into Scene::real_objects

    bool hasTwoFaces() const { return !normal1.isZero(); }
};

struct EdgeModelOptions {
    double crease_angle_deg = 30.0;  // mesh edges whose faces' normals differ by more are edges; in (0, 180)
    double min_edge_length = 1e-4;   // metres; shorter edges are dropped
    // Relative tolerance of the vertex welding of meshes (fraction of the mesh's bounding-box diagonal).
    double weld_tolerance = 1e-6;

    // Names the bad field.
    Result<void> validate() const;
};

class EdgeModel {
public:
    // Edges and occluders of every real object. Fails (kBadInput, naming the object) for a mesh
    // that was not loaded, a box or plane with a non-positive or non-finite size, or an invalid pose.
    static Result<EdgeModel> fromScene(const Scene& scene, const EdgeModelOptions& options = {});

    std::span<const ModelEdge> edges() const { return edges_; }
    // The scene's real objects' names, by index (ModelEdge::object).
    std::span<const std::string> objectNames() const { return names_; }
    int objectCount() const { return static_cast<int>(names_.size()); }

    // Distance along the ray origin + t * dir (dir need not be unit; t in units of |dir|) to the
    // first proxy surface with t in (t_min, t_max]; nullopt when there is none. Brute force over
    // the objects (boxes and planes analytically, spheres exactly, meshes triangle by triangle
    // behind a bounding box): fine for tens of objects and meshes of a few thousand triangles.
    // `any`: return the first hit found in range instead of the nearest (an occlusion test).
    std::optional<double> firstHit(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir, double t_min,
                                   double t_max, bool any = false) const;
    // Whether a proxy lies between `from` and `to`, ignoring the last `epsilon` metres before `to`
    // (so that a point on a surface is not hidden by that surface).
    bool occluded(const Eigen::Vector3d& from, const Eigen::Vector3d& to, double epsilon) const;

private:
    struct BoxOccluder {
        Rigid3d object_from_world;
        Eigen::Vector3d half_size;
    };
    struct PlaneOccluder {
        Rigid3d object_from_world;
        Eigen::Vector2d half_size;
    };
    struct SphereOccluder {
        Eigen::Vector3d centre;
        double radius = 0.0;
    };
    struct MeshOccluder {
        std::vector<Eigen::Vector3d> vertices;  // three per triangle, world
        Eigen::Vector3d lower, upper;           // bounding box
    };

    std::vector<ModelEdge> edges_;
    std::vector<std::string> names_;
    std::vector<BoxOccluder> boxes_;
    std::vector<PlaneOccluder> planes_;
    std::vector<SphereOccluder> spheres_;
    std::vector<MeshOccluder> meshes_;
};

}  // namespace commonlight::tracking

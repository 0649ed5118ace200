// The scene as planar faces: real proxies, virtual objects and area lights as the polygons the
// radiosity solution is built on (lighting/hierarchy.h subdivides them into elements).
//
// A face is a parallelogram or a triangle with the parametrisation of lighting/snapshot.h:
// p(s, t) = origin + s * edge_s + t * edge_t, (s, t) in [0, 1]^2 (parallelogram) or s + t <= 1
// (triangle). Its front side looks along `normal` = normalize(edge_s x edge_t).
//
// Face numbering (FaceModulation::face): box 0..5 = +x, -x, +y, -y, +z, -z (outward normals);
// plane 0 (front, +z); mesh: triangle index; sphere: triangle index of its icosphere (real
// spheres: 320 triangles).
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/result.h"
#include "core/scene.h"

namespace commonlight::lighting {

enum class FaceOwner : std::uint8_t { kReal, kVirtual };

struct Face {
    FaceOwner owner = FaceOwner::kReal;
    int object_index = 0;  // Scene::real_objects or Scene::virtual_objects index
    int face_index = 0;    // numbering above
    bool triangle = false;
    // Real faces: world coordinates. Virtual faces: the object's own frame (posed at solve time).
    Eigen::Vector3d origin = Eigen::Vector3d::Zero();
    Eigen::Vector3d edge_s = Eigen::Vector3d::UnitX();
    Eigen::Vector3d edge_t = Eigen::Vector3d::UnitY();
    Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
    double area = 1.0;  // m^2
    // Reflectance: given (albedo_known) or to be estimated; virtual faces always know theirs.
    Eigen::Vector3d albedo = Eigen::Vector3d::Constant(0.5);
    bool albedo_known = false;
    Eigen::Vector3d emission = Eigen::Vector3d::Zero();  // virtual emitters: radiance, scene units

    Eigen::Vector3d point(double s, double t) const { return origin + s * edge_s + t * edge_t; }
    // Corners in order (3 or 4), counter-clockwise seen from the front.
    std::vector<Eigen::Vector3d> corners() const;
    // Length of the edges, metres.
    double lengthS() const { return edge_s.norm(); }
    double lengthT() const { return edge_t.norm(); }
};

// Area lights as polygons (a disc as a regular 32-gon of the same area, for form factors; sampled
// exactly as a disc for visibility). Point, directional and distant lights have no polygon.
struct LightGeometry {
    int light_index = 0;  // Scene::lights index
    std::vector<Eigen::Vector3d> polygon;  // world, counter-clockwise seen from the emitting (+z) side
    Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  // world, the emitting side
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    double area = 0.0;  // m^2
    // The light's own frame and shape, for sampling points on it.
    Rigid3d world_from_object;
    bool disc = false;
    Eigen::Vector2d size = Eigen::Vector2d::Zero();  // rectangle: full extent along x, y
    double radius = 0.0;                              // disc
};

// Faces of the real proxies, in world coordinates. Errors (kBadInput, naming the object): a box
// with a non-positive or non-finite size (an inside-out box), a plane of zero area, a mesh that
// is not loaded or has no triangle of positive area, a sphere of non-positive radius, a
// non-finite pose. Degenerate triangles of an otherwise valid mesh are skipped.
Result<std::vector<Face>> realFaces(const Scene& scene);

// Faces of one virtual object in its own frame (spheres as an icosphere of 20 x 4^sphere_levels
// triangles: 80 by default, enough for the light it bounces; its shadow comes from the exact sphere).
Result<std::vector<Face>> virtualFaces(const Scene& scene, int virtual_index, int sphere_levels = 1);

// Area and disc lights (polygons); other kinds are skipped. Errors: a light of zero or negative
// size (kBadInput naming it).
Result<std::vector<LightGeometry>> lightGeometry(const Scene& scene);

// A face moved by a rigid transform (virtual objects at their pose).
Face transformed(const Face& face, const Rigid3d& world_from_object);

// Triangles of a unit icosphere subdivided `levels` times (20 * 4^levels triangles), as vertex
// triples, counter-clockwise seen from outside.
std::vector<std::array<Eigen::Vector3d, 3>> icosphere(int levels);

}  // namespace commonlight::lighting

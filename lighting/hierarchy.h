// Elements: the faces of lighting/proxy_geometry.h subdivided into a hierarchy (a quadtree per
// parallelogram, halving along one side when it is much longer than the other; four children per
// triangle), the finite elements of the radiosity solution.
//
// An element is a parallelogram or triangle in its face's (s, t) coordinates: corner + a * ds +
// b * dt, (a, b) in [0, 1]^2 (or a + b <= 1). Elements are created on demand (subdivide()) and
// never destroyed, so indices stay valid; a leaf is an element without children. Each face's
// root is element `roots[face]`.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "lighting/proxy_geometry.h"

namespace commonlight::lighting {

struct Element {
    int face = 0;
    int parent = -1;
    int first_child = -1;  // children are contiguous
    int child_count = 0;
    int level = 0;
    bool triangle = false;
    Eigen::Vector2d st = Eigen::Vector2d::Zero();  // corner in face (s, t)
    Eigen::Vector2d ds = Eigen::Vector2d::UnitX(); // edge vectors in face (s, t)
    Eigen::Vector2d dt = Eigen::Vector2d::UnitY();
    double area = 0.0;        // m^2
    double size_s = 0.0;      // metres along ds
    double size_t_ = 0.0;     // metres along dt
    bool buried = false;      // inside another proxy (a box's bottom on a table): takes no part in transport
    // Fraction of the area outside other proxies (a floor element under a cabinet's edge: the part
    // under the cabinet is no surface). Negative until Radiosity::markBuried() has measured it.
    float exposed = -1.0f;
    bool retired = false;     // under a collapsed element (see the file comment)
    int retired_first = -1;   // a collapsed element: its children, kept for the next subdivide()
    int retired_count = 0;

    bool leaf() const { return child_count == 0 && !retired; }
};

// The element's polygon in world coordinates: corner, edge vectors.
struct ElementGeometry {
    Eigen::Vector3d corner;
    Eigen::Vector3d edge_s;
    Eigen::Vector3d edge_t;
    Eigen::Vector3d normal;
    Eigen::Vector3d centroid;
    bool triangle = false;
    std::vector<Eigen::Vector3d> polygon() const;
    // Distance from a point to the polygon (its nearest point within the clamped edge coordinates).
    double distanceTo(const Eigen::Vector3d& x) const;
};

class Hierarchy {
public:
    // One root element per face.
    explicit Hierarchy(const std::vector<Face>& faces);

    const std::vector<Element>& elements() const noexcept { return elements_; }
    const Element& operator[](int i) const { return elements_[static_cast<std::size_t>(i)]; }
    int root(int face) const { return roots_[static_cast<std::size_t>(face)]; }
    std::size_t faceCount() const noexcept { return roots_.size(); }
    int leafCount() const noexcept { return leaf_count_; }

    // Splits a leaf into 2 or 4 children; returns false (and does nothing) when the element is not
    // a leaf or its children would be smaller than `min_size` metres along a split side. A
    // collapsed element gets its retired children back when they are the split asked for (else
    // new ones; the old stay retired).
    bool subdivide(int element, double min_size);
    bool canSubdivide(int element, double min_size) const;
    // Makes an element a leaf again: everything under it is retired (kept for subdivide()).
    // Nothing happens to a leaf. Returns the number of leaves removed (leaves before - 1).
    int collapse(int element);
    // A key of an element's place (its face and (s, t) parallelogram), the same however the
    // hierarchy was built: what random sample streams of an element are seeded with, so that an
    // element made again in another order (the influence's refinement) samples the same.
    std::uint64_t key(int element) const;
    // Elements ever made (active and retired), for bounds on memory.
    std::size_t storedCount() const noexcept { return elements_.size(); }

    // World geometry of an element with its face placed by `face` (for virtual faces: the posed face).
    static ElementGeometry geometry(const Element& e, const Face& face);
    // The leaf containing face point (s, t) (clamped into the face), starting from the face's root.
    int leafAt(int face, Eigen::Vector2d st) const;
    // leafAt(face, st) again, `last` being what leafAt(face, st) gave for the same (s, t) at an
    // earlier state of this hierarchy (splits and collapses since): the same leaf, descending from
    // `last` instead of the root while `last` is not retired. (A non-retired element's ancestors
    // are not retired either and hold the same children as when it was found: collapse() retires
    // everything under an element, subdivide() brings back the same children or makes new ones, the
    // old staying retired; and the descent's choice at an element reads its children alone.)
    // `last` retired, of another face or -1: from the root.
    int leafAtAgain(int face, Eigen::Vector2d st, int last) const;
    // Leaves under an element (itself when it is a leaf).
    void leavesUnder(int element, std::vector<int>& out) const;
    // Marks an element and everything under it buried (or not).
    void setBuried(int element, bool buried);
    // Sets an element's exposed fraction (Radiosity::markBuried()).
    void setExposed(int element, float exposed) { elements_[static_cast<std::size_t>(element)].exposed = exposed; }

private:
    // Appends an element and its ab_from_st_.
    void add(const Element& e);
    // leafAt()'s descent from element `current` (its face's clamped (s, t)).
    int descend(int current, const Eigen::Vector2d& st) const;

    std::vector<Element> elements_;
    // By element: the inverse of [ds dt], (a, b) = ab_from_st_ * ((s, t) - st). leafAt() descends
    // through it for every probe ray and texel; computed once when the element is made (the same
    // Eigen inverse leafAt() took per visit, so the same bits).
    std::vector<Eigen::Matrix2d> ab_from_st_;
    std::vector<int> roots_;
    std::vector<Face> faces_;  // metric sizes of the (s, t) edges
    int leaf_count_ = 0;
};

// Whether (a, b) lies in the unit parallelogram / triangle, with a tolerance.
inline bool insideUnit(double a, double b, bool triangle, double tolerance = 1e-12) {
    if (a < -tolerance || b < -tolerance) return false;
    if (triangle) return a + b <= 1.0 + tolerance;
    return a <= 1.0 + tolerance && b <= 1.0 + tolerance;
}

}  // namespace commonlight::lighting

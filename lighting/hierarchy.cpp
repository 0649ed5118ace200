#include "lighting/hierarchy.h"

#include <algorithm>
#include <cmath>

#include "lighting/sampling.h"

namespace commonlight::lighting {

std::vector<Eigen::Vector3d> ElementGeometry::polygon() const {
    if (triangle) return {corner, corner + edge_s, corner + edge_t};
    return {corner, corner + edge_s, corner + edge_s + edge_t, corner + edge_t};
}

double ElementGeometry::distanceTo(const Eigen::Vector3d& x) const {
    Eigen::Matrix<double, 3, 2> b;
    b.col(0) = edge_s;
    b.col(1) = edge_t;
    Eigen::Vector2d ab = (b.transpose() * b).inverse() * (b.transpose() * (x - corner));
    ab = ab.cwiseMax(0.0).cwiseMin(1.0);
    if (triangle && ab.sum() > 1.0) ab /= ab.sum();
    return (corner + ab.x() * edge_s + ab.y() * edge_t - x).norm();
}

namespace {

Element makeElement(const Face& face, int face_index, const Eigen::Vector2d& st, const Eigen::Vector2d& ds,
                    const Eigen::Vector2d& dt, bool triangle) {
    Element e;
    e.face = face_index;
    e.triangle = triangle;
    e.st = st;
    e.ds = ds;
    e.dt = dt;
    const Eigen::Vector3d es = ds.x() * face.edge_s + ds.y() * face.edge_t;
    const Eigen::Vector3d et = dt.x() * face.edge_s + dt.y() * face.edge_t;
    e.size_s = es.norm();
    e.size_t_ = et.norm();
    const double cross = es.cross(et).norm();
    e.area = triangle ? 0.5 * cross : cross;
    return e;
}

}  // namespace

void Hierarchy::add(const Element& e) {
    elements_.push_back(e);
    Eigen::Matrix2d m;
    m.col(0) = e.ds;
    m.col(1) = e.dt;
    ab_from_st_.push_back(m.inverse());
}

Hierarchy::Hierarchy(const std::vector<Face>& faces) : faces_(faces) {
    elements_.reserve(faces.size() * 8);
    ab_from_st_.reserve(faces.size() * 8);
    for (std::size_t f = 0; f < faces.size(); ++f) {
        roots_.push_back(static_cast<int>(elements_.size()));
        add(makeElement(faces[f], static_cast<int>(f), Eigen::Vector2d::Zero(), Eigen::Vector2d::UnitX(),
                                        Eigen::Vector2d::UnitY(), faces[f].triangle));
    }
    leaf_count_ = static_cast<int>(faces.size());
}

bool Hierarchy::canSubdivide(int element, double min_size) const {
    const Element& e = elements_[static_cast<std::size_t>(element)];
    if (!e.leaf()) return false;
    if (e.triangle) return 0.5 * std::min(e.size_s, e.size_t_) >= min_size;
    return 0.5 * std::max(e.size_s, e.size_t_) >= min_size;
}

bool Hierarchy::subdivide(int element, double min_size) {
    if (!canSubdivide(element, min_size)) return false;
    const Element e = elements_[static_cast<std::size_t>(element)];
    const Face& face = faces_[static_cast<std::size_t>(e.face)];
    std::vector<Element> children;
    if (e.triangle) {
        // Four similar triangles: three at the corners and the inverted middle one.
        const Eigen::Vector2d hs = 0.5 * e.ds, ht = 0.5 * e.dt;
        children.push_back(makeElement(face, e.face, e.st, hs, ht, true));
        children.push_back(makeElement(face, e.face, e.st + hs, hs, ht, true));
        children.push_back(makeElement(face, e.face, e.st + ht, hs, ht, true));
        children.push_back(makeElement(face, e.face, e.st + hs + ht, -hs, -ht, true));
    } else {
        // Keep elements near square: halve only the long side of an elongated one.
        const int ns = 0.5 * e.size_s >= min_size && !(e.size_t_ > 1.6 * e.size_s) ? 2 : 1;
        const int nt = 0.5 * e.size_t_ >= min_size && !(e.size_s > 1.6 * e.size_t_) ? 2 : 1;
        if (ns * nt == 1) return false;
        const Eigen::Vector2d cs = e.ds / ns, ct = e.dt / nt;
        for (int j = 0; j < nt; ++j) {
            for (int i = 0; i < ns; ++i) children.push_back(makeElement(face, e.face, e.st + i * cs + j * ct, cs, ct, false));
        }
    }
    // A collapsed element whose retired children are this very split: bring them back.
    if (e.retired_count == static_cast<int>(children.size())) {
        bool same = true;
        for (std::size_t c = 0; c < children.size() && same; ++c) {
            const Element& old = elements_[static_cast<std::size_t>(e.retired_first) + c];
            same = (old.st - children[c].st).norm() < 1e-12 && (old.ds - children[c].ds).norm() < 1e-12 &&
                   (old.dt - children[c].dt).norm() < 1e-12;
        }
        if (same) {
            Element& parent = elements_[static_cast<std::size_t>(element)];
            parent.first_child = e.retired_first;
            parent.child_count = e.retired_count;
            parent.retired_first = -1;
            parent.retired_count = 0;
            for (int c = 0; c < parent.child_count; ++c) {
                Element& child = elements_[static_cast<std::size_t>(parent.first_child + c)];
                child.retired = false;
                child.buried = child.buried || e.buried;
            }
            leaf_count_ += parent.child_count - 1;
            return true;
        }
    }
    Element& parent = elements_[static_cast<std::size_t>(element)];
    parent.retired_first = -1;  // a different split: the old children stay retired for good
    parent.retired_count = 0;
    parent.first_child = static_cast<int>(elements_.size());
    parent.child_count = static_cast<int>(children.size());
    for (Element& c : children) {
        c.parent = element;
        c.level = e.level + 1;
        c.buried = e.buried;
        add(c);
    }
    leaf_count_ += static_cast<int>(children.size()) - 1;
    return true;
}

std::uint64_t Hierarchy::key(int element) const {
    const Element& e = elements_[static_cast<std::size_t>(element)];
    const auto q = [](double v) { return static_cast<std::uint64_t>(std::llround(v * 1073741824.0)); };  // 2^30
    std::uint64_t h = hash64(static_cast<std::uint64_t>(e.face) + 0x9e3779b97f4a7c15ull);
    for (double v : {e.st.x(), e.st.y(), e.ds.x(), e.ds.y(), e.dt.x(), e.dt.y()}) h = hashCombine(h, q(v));
    return h;
}

int Hierarchy::collapse(int element) {
    Element& e = elements_[static_cast<std::size_t>(element)];
    if (e.child_count == 0) return 0;
    int removed = 0;
    const int first = e.first_child, count = e.child_count;
    for (int c = 0; c < count; ++c) {
        removed += collapse(first + c);  // each child a leaf first: one level kept per element
        elements_[static_cast<std::size_t>(first + c)].retired = true;
    }
    Element& parent = elements_[static_cast<std::size_t>(element)];
    parent.retired_first = first;
    parent.retired_count = count;
    parent.first_child = -1;
    parent.child_count = 0;
    removed += count - 1;
    leaf_count_ -= count - 1;
    return removed;
}

ElementGeometry Hierarchy::geometry(const Element& e, const Face& face) {
    ElementGeometry g;
    g.triangle = e.triangle;
    g.corner = face.origin + e.st.x() * face.edge_s + e.st.y() * face.edge_t;
    g.edge_s = e.ds.x() * face.edge_s + e.ds.y() * face.edge_t;
    g.edge_t = e.dt.x() * face.edge_s + e.dt.y() * face.edge_t;
    g.normal = face.normal;
    g.centroid = g.corner + (e.triangle ? 1.0 / 3.0 : 0.5) * (g.edge_s + g.edge_t);
    return g;
}

int Hierarchy::leafAt(int face, Eigen::Vector2d st) const {
    const bool tri = faces_[static_cast<std::size_t>(face)].triangle;
    st = st.cwiseMax(0.0).cwiseMin(1.0);
    if (tri && st.sum() > 1.0) st /= st.sum();
    return descend(roots_[static_cast<std::size_t>(face)], st);
}

int Hierarchy::leafAtAgain(int face, Eigen::Vector2d st, int last) const {
    if (last < 0 || elements_[static_cast<std::size_t>(last)].retired || elements_[static_cast<std::size_t>(last)].face != face) {
        return leafAt(face, st);
    }
    const bool tri = faces_[static_cast<std::size_t>(face)].triangle;
    st = st.cwiseMax(0.0).cwiseMin(1.0);
    if (tri && st.sum() > 1.0) st /= st.sum();
    return descend(last, st);
}

int Hierarchy::descend(int current, const Eigen::Vector2d& st) const {
    while (!elements_[static_cast<std::size_t>(current)].leaf()) {
        const Element& e = elements_[static_cast<std::size_t>(current)];
        int next = -1;
        double best_outside = 1e300;
        for (int c = 0; c < e.child_count; ++c) {
            const Element& child = elements_[static_cast<std::size_t>(e.first_child + c)];
            const Eigen::Vector2d ab = ab_from_st_[static_cast<std::size_t>(e.first_child + c)] * (st - child.st);
            if (insideUnit(ab.x(), ab.y(), child.triangle, 1e-9)) {
                next = e.first_child + c;
                break;
            }
            // Rounding at shared borders: fall back to the nearest child.
            const double outside = std::max({-ab.x(), -ab.y(), child.triangle ? ab.sum() - 1.0 : std::max(ab.x(), ab.y()) - 1.0});
            if (outside < best_outside) {
                best_outside = outside;
                next = e.first_child + c;
            }
        }
        current = next;
    }
    return current;
}

void Hierarchy::leavesUnder(int element, std::vector<int>& out) const {
    const Element& e = elements_[static_cast<std::size_t>(element)];
    if (e.leaf()) {
        out.push_back(element);
        return;
    }
    for (int c = 0; c < e.child_count; ++c) leavesUnder(e.first_child + c, out);
}

void Hierarchy::setBuried(int element, bool buried) {
    Element& e = elements_[static_cast<std::size_t>(element)];
    e.buried = buried;
    for (int c = 0; c < e.child_count; ++c) setBuried(e.first_child + c, buried);
}

}  // namespace commonlight::lighting

// Clustering of small real proxies in the hierarchical radiosity (Smits, Arvo and Greenberg 1994;
// Sillion 1995): a real object of many faces (a mesh, a real sphere's icosphere) is one node for
// the exchanges the oracle allows to be coarse, so inserting it adds a few links per receiver
// instead of one per face and receiver.
//
// As a source, a cluster's light towards a receiver point x is, per face f (area A_f, normal n_f,
// centroid c_f, exposed fraction e_f), A_f e_f cos_f cos_x / d_f^2 times the face's radiance;
// a link keeps that kernel's mean over the receiver (the exact sum over faces, at setup) and, in
// the solve, multiplies it by the cluster's mean radiance towards the link's direction: the
// projected-area-weighted mean of its faces' radiances over a cube map of 96 direction bins
// (exact when every face has the same radiance, so a cluster neither makes nor loses light). As
// a receiver, the light of a source element arrives at the cluster's centre from one direction
// with a vector irradiance (the source's mean of A_s cos_s / d^2 along the direction); the links'
// vectors are summed per direction bin and each face takes max(0, n_f . sum) from each bin:
// each face receives by its own orientation. Visibility: pairs from the element to points on the
// faces that face it (chosen by projected area), through the real scene, the cluster's own faces
// included (a concave proxy shadows itself).
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <numbers>

#include "lighting/form_factor.h"
#include "lighting/radiosity.h"
#include "lighting/sampling.h"

namespace commonlight::lighting {

namespace {

constexpr int kCells = 6;                       // per cube face side
constexpr int kBins = 6 * kCells * kCells;      // direction bins
constexpr int kVisibilityPairs = 16;
constexpr double kMaxAngle = 0.3;               // a cluster's source is at most this wide over its distance

int directionBin(const Eigen::Vector3d& u) {
    int axis = 0;
    u.cwiseAbs().maxCoeff(&axis);
    const double major = u[axis];
    if (!(std::abs(major) > 0.0)) return 0;
    const int face = 2 * axis + (major < 0.0 ? 1 : 0);
    const double a = u[(axis + 1) % 3] / std::abs(major), b = u[(axis + 2) % 3] / std::abs(major);
    const int i = std::clamp(static_cast<int>((a + 1.0) * 0.5 * kCells), 0, kCells - 1);
    const int j = std::clamp(static_cast<int>((b + 1.0) * 0.5 * kCells), 0, kCells - 1);
    return (face * kCells + j) * kCells + i;
}

Eigen::Vector3d binCentre(int bin) {
    const int i = bin % kCells, j = (bin / kCells) % kCells, face = bin / (kCells * kCells);
    const int axis = face / 2;
    Eigen::Vector3d u;
    u[axis] = face % 2 == 0 ? 1.0 : -1.0;
    u[(axis + 1) % 3] = (i + 0.5) / kCells * 2.0 - 1.0;
    u[(axis + 2) % 3] = (j + 0.5) / kCells * 2.0 - 1.0;
    return u.normalized();
}

const std::vector<Eigen::Vector3d>& binDirections() {
    static const std::vector<Eigen::Vector3d> table = [] {
        std::vector<Eigen::Vector3d> t;
        for (int b = 0; b < kBins; ++b) t.push_back(binCentre(b));
        return t;
    }();
    return table;
}

Eigen::Vector3d binDirection(int bin) { return binDirections()[static_cast<std::size_t>(bin)]; }

Eigen::Vector3d faceCentroid(const Face& f) {
    return f.origin + (f.triangle ? (f.edge_s + f.edge_t) / 3.0 : (f.edge_s + f.edge_t) / 2.0);
}

}  // namespace

std::vector<int> Radiosity::clusterObjects() const {
    std::vector<int> out;
    for (const Cluster& c : clusters_) out.push_back(c.object);
    return out;
}

int Radiosity::clusterOfFace(int face) const {
    return static_cast<std::size_t>(face) < face_cluster_.size() ? face_cluster_[static_cast<std::size_t>(face)] : -1;
}

void Radiosity::makeClusters() {
    clusters_.clear();
    face_cluster_.assign(faces_.size(), -1);
    if (!options_.hierarchical || (options_.cluster_min_faces <= 0 && !(options_.cluster_small_radius > 0.0))) return;
    markBuried();
    Eigen::AlignedBox3d scene_box;
    std::map<int, std::vector<int>> by_object;
    for (std::size_t f = 0; f < real_count_; ++f) {
        for (const Eigen::Vector3d& c : faces_[f].corners()) scene_box.extend(c);
        by_object[faces_[f].object_index].push_back(static_cast<int>(f));
    }
    const double scene_radius = 0.5 * scene_box.diagonal().norm();
    for (const auto& [object, faces] : by_object) {
        if (faces.size() < 2) continue;
        Eigen::AlignedBox3d box;
        for (int f : faces) {
            for (const Eigen::Vector3d& c : faces_[static_cast<std::size_t>(f)].corners()) box.extend(c);
        }
        Cluster c;
        c.object = object;
        c.faces = faces;
        c.centre = box.center();
        for (int f : faces) {
            for (const Eigen::Vector3d& x : faces_[static_cast<std::size_t>(f)].corners()) c.radius = std::max(c.radius, (x - c.centre).norm());
        }
        const bool many = options_.cluster_min_faces > 0 && static_cast<int>(faces.size()) >= options_.cluster_min_faces;
        const bool small = options_.cluster_small_radius > 0.0 && c.radius <= options_.cluster_small_radius;
        if (!(many || small) || c.radius > options_.cluster_max_fraction * scene_radius || !(c.radius > 0.0)) continue;
        c.projected.assign(kBins, 0.0);
        c.face_bins.resize(faces.size());
        for (std::size_t i = 0; i < faces.size(); ++i) {
            const int root = hierarchy_.root(faces[i]);
            if (hierarchy_[root].buried) continue;
            const Face& face = faces_[static_cast<std::size_t>(faces[i])];
            for (int b = 0; b < kBins; ++b) {
                const double w = face.area * exposure(root) * face.normal.dot(binDirection(b));
                if (!(w > 0.0)) continue;
                c.projected[static_cast<std::size_t>(b)] += w;
                c.face_bins[i].emplace_back(b, static_cast<float>(w));
            }
        }
        c.peak = 0.0;
        for (int f : faces) c.peak = std::max(c.peak, sourceStat(source_peak_, hierarchy_.root(f)));
        for (int f : faces) face_cluster_[static_cast<std::size_t>(f)] = static_cast<int>(clusters_.size());
        clusters_.push_back(std::move(c));
    }
}

double Radiosity::clusterKernel(int cluster, const Eigen::Vector3d& x, const Eigen::Vector3d& normal) const {
    const Cluster& c = clusters_[static_cast<std::size_t>(cluster)];
    double sum = 0.0;
    for (int f : c.faces) {
        const int root = hierarchy_.root(f);
        if (hierarchy_[root].buried) continue;
        const Face& face = faces_[static_cast<std::size_t>(f)];
        const Eigen::Vector3d d = faceCentroid(face) - x;
        const double d2 = d.squaredNorm();
        if (!(d2 > 0.0)) continue;
        sum += face.area * exposure(root) * std::max(0.0, -face.normal.dot(d)) * std::max(0.0, normal.dot(d)) / (d2 * d2);
    }
    return sum;
}

double Radiosity::clusterVisibility(int cluster, int element, const Eigen::Vector3d& towards, std::uint64_t seed) const {
    const Cluster& c = clusters_[static_cast<std::size_t>(cluster)];
    // The faces that face the element, by projected area (a cumulative table).
    std::vector<double> cdf;
    cdf.reserve(c.faces.size());
    double total = 0.0;
    for (int f : c.faces) {
        const int root = hierarchy_.root(f);
        const Face& face = faces_[static_cast<std::size_t>(f)];
        if (!hierarchy_[root].buried) total += face.area * exposure(root) * std::max(0.0, face.normal.dot(towards));
        cdf.push_back(total);
    }
    if (!(total > 0.0)) return 0.0;
    const ElementGeometry ge = geometry(element);
    const bool partial = exposure(element) < 1.0;
    int valid = 0, open = 0;
    for (int k = 0; k < kVisibilityPairs; ++k) {
        const SamplePair pair = stratifiedPair(seed, k, kVisibilityPairs);
        const Eigen::Vector3d xe = surfacePoint(element, ge, pair.first.x(), pair.first.y());
        if (partial && hidden(element, xe)) continue;
        // The face: stratified over the table; the point on it from a second stream.
        const double u = (k + unitFromHash(hashCombine(seed, static_cast<std::uint64_t>(k) + 77))) / kVisibilityPairs * total;
        const auto it = std::upper_bound(cdf.begin(), cdf.end(), u);
        const std::size_t i = std::min(static_cast<std::size_t>(it - cdf.begin()), c.faces.size() - 1);
        const int root = hierarchy_.root(c.faces[i]);
        const Eigen::Vector3d xf = surfacePoint(root, pair.second.x(), pair.second.y());
        ++valid;
        if (!rays_->occludedReal(xe, ge.normal, xf, faces_[static_cast<std::size_t>(c.faces[i])].normal)) ++open;
    }
    return valid > 0 ? static_cast<double>(open) / valid : 0.0;
}

void Radiosity::computeClusterLink(ClusterLink& link) const {
    const Cluster& c = clusters_[static_cast<std::size_t>(link.cluster)];
    const ElementGeometry g = geometry(link.element);
    const double size = std::sqrt(hierarchy_[link.element].area);
    const int order = formFactorRule((g.centroid - c.centre).norm(), size, 2.0 * c.radius);
    const std::uint64_t seed = hashCombine(options_.seed ^ 0xc1057e5ull,
                                           hashCombine(hierarchy_.key(link.element), static_cast<std::uint64_t>(link.cluster) * 2 +
                                                                                       (link.kind == ClusterLink::Kind::kSource ? 0 : 1)));
    if (link.kind == ClusterLink::Kind::kSource) {
        double w = 0.0;
        for (const QuadraturePoint& q : exposedRule(link.element, order)) w += q.weight * clusterKernel(link.cluster, q.x, g.normal);
        link.weight = static_cast<float>(w);
        link.bin = directionBin(g.centroid - c.centre);
        link.vis_real = static_cast<float>(clusterVisibility(link.cluster, link.element, (g.centroid - c.centre).normalized(), seed));
        return;
    }
    // Receiver: the vector irradiance per unit radiance of the source element at the centre, and
    // its derivative (central differences over half the radius): a face 0.15 m nearer a ceiling
    // 1.3 m away receives 28% more of a piece of it than the centre does.
    const double area = hierarchy_[link.element].area * exposure(link.element);
    const std::vector<QuadraturePoint> rule = exposedRule(link.element, order);
    const auto vector_irradiance = [&](const Eigen::Vector3d& x) {
        Eigen::Vector3d v = Eigen::Vector3d::Zero();
        for (const QuadraturePoint& q : rule) {
            const Eigen::Vector3d d = x - q.x;  // from the source point to x
            const double d2 = d.squaredNorm();
            if (!(d2 > 0.0)) continue;
            const double dist = std::sqrt(d2);
            const double cos_s = std::max(0.0, g.normal.dot(d) / dist);
            v += q.weight * area * cos_s / d2 * (-d / dist);
        }
        return v;
    };
    const Eigen::Vector3d v = vector_irradiance(c.centre);
    const double h = 0.5 * c.radius;
    for (int k = 0; k < 3; ++k) {
        const Eigen::Vector3d step = h * Eigen::Vector3d::Unit(k);
        link.grad.col(k) = ((vector_irradiance(c.centre + step) - vector_irradiance(c.centre - step)) / (2.0 * h)).cast<float>();
    }
    link.dir = v.cast<float>();
    link.weight = static_cast<float>(v.norm());
    link.bin = directionBin(v);
    link.vis_real = v.norm() > 0.0 ? static_cast<float>(clusterVisibility(link.cluster, link.element, v.normalized(), seed)) : 0.0f;
}

void Radiosity::openCluster(int receiver, int cluster, int depth) {
    for (int f : clusters_[static_cast<std::size_t>(cluster)].faces) refine(receiver, hierarchy_.root(f), depth + 1);
}

void Radiosity::refineFromCluster(int r, int cluster, int depth) {
    const Cluster& c = clusters_[static_cast<std::size_t>(cluster)];
    if (hierarchy_[r].buried) return;
    const ElementGeometry gr = geometry(r);
    if ((c.centre - gr.corner).dot(gr.normal) <= -c.radius) return;  // wholly behind the receiver
    const double min_size = std::max(options_.min_element_size, options_.min_link_size);
    const bool budget = hierarchy_.leafCount() + 3 < options_.max_elements;
    const bool can_descend = !hierarchy_[r].leaf() || (budget && hierarchy_.canSubdivide(r, min_size));
    const auto split = [&] {
        if (hierarchy_[r].leaf()) hierarchy_.subdivide(r, min_size);
        const int first = hierarchy_[r].first_child, count = hierarchy_[r].child_count;
        for (int k = 0; k < count; ++k) refineFromCluster(first + k, cluster, depth + 1);
    };
    const double receiver_size = std::sqrt(hierarchy_[r].area);
    const double nearest = gr.distanceTo(c.centre);
    // Close to the cluster: its faces one by one (after the receiver is split to the cluster's scale).
    if (nearest < options_.cluster_distance * c.radius || depth >= 40) {
        if (depth < 40 && can_descend && receiver_size > 2.0 * c.radius) return split();
        return openCluster(r, cluster, depth);
    }
    // The kernel (pi F per unit radiance) at the receiver's corners, centre and nearest point.
    std::vector<Eigen::Vector3d> probes = gr.polygon();
    probes.push_back(gr.centroid);
    double f_min = 1e300, f_max = 0.0;
    for (const Eigen::Vector3d& p : probes) {
        const double f = clusterKernel(cluster, p + 0.01 * (gr.centroid - p), gr.normal) / std::numbers::pi;
        f_min = std::min(f_min, f);
        f_max = std::max(f_max, f);
    }
    // Near field (as refine()'s): the receiver larger than its distance to the cluster, where the
    // cluster is bright enough to matter.
    const bool close = nearest < receiver_size && f_max * c.peak > options_.link_epsilon;
    if ((((f_max - f_min) * c.peak > options_.link_epsilon) || close) && can_descend) return split();
    // The cluster as one source is wrong by about its form factor's variation over its own extent.
    if (f_max * c.peak * c.radius / nearest > options_.link_epsilon) return openCluster(r, cluster, depth);
    ClusterLink l;
    l.kind = ClusterLink::Kind::kSource;
    l.cluster = cluster;
    l.element = r;
    pending_cluster_links_.push_back(l);
}

void Radiosity::refineToCluster(int cluster, int s, int depth) {
    const Cluster& c = clusters_[static_cast<std::size_t>(cluster)];
    if (hierarchy_[s].buried) return;
    const ElementGeometry gs = geometry(s);
    if ((c.centre - gs.corner).dot(gs.normal) <= -c.radius) return;  // the cluster is behind the source
    const double min_size = std::max(options_.min_element_size, options_.min_link_size);
    const bool budget = hierarchy_.leafCount() + 3 < options_.max_elements;
    const bool can_descend = !hierarchy_[s].leaf() || (budget && hierarchy_.canSubdivide(s, min_size));
    const auto split = [&] {
        if (hierarchy_[s].leaf()) hierarchy_.subdivide(s, min_size);
        const int first = hierarchy_[s].first_child, count = hierarchy_[s].child_count;
        for (int k = 0; k < count; ++k) refineToCluster(cluster, first + k, depth + 1);
    };
    const auto open = [&] {
        for (int f : c.faces) refine(hierarchy_.root(f), s, depth + 1);
    };
    const double source_size = std::sqrt(hierarchy_[s].area);
    const double nearest = gs.distanceTo(c.centre);
    if (nearest < options_.cluster_distance * c.radius || depth >= 40) {
        if (depth < 40 && can_descend && source_size > 2.0 * c.radius) return split();
        return open();
    }
    // The source's form factor seen from the cluster's centre (A_s cos_s / (pi d^2), at most 1).
    const Eigen::Vector3d d = c.centre - gs.centroid;
    const double dist = d.norm();
    const double f = std::min(1.0, hierarchy_[s].area * std::max(0.0, gs.normal.dot(d) / dist) / (std::numbers::pi * dist * dist));
    // A source seen under a wide angle: one direction would light a face across its horizon like
    // one facing it (the light of a wall beside the cluster reaches faces turned 80 degrees away).
    if (source_size > kMaxAngle * nearest && can_descend) return split();
    if (source_size > kMaxAngle * nearest) return open();
    // The irradiance varies over the cluster's extent by about f x (radius / distance).
    if (f * sourceStat(source_peak_, s) * c.radius / nearest > options_.link_epsilon) return open();
    if (f * sourceStat(source_range_, s) > options_.source_epsilon && can_descend) return split();
    ClusterLink l;
    l.kind = ClusterLink::Kind::kReceiver;
    l.cluster = cluster;
    l.element = s;
    pending_cluster_links_.push_back(l);
}

void Radiosity::finishClusterLinks() {
    markBuried();
    std::vector<ClusterLink> out = std::move(pending_cluster_links_);
    pending_cluster_links_.clear();
    std::erase_if(out, [&](const ClusterLink& l) { return hierarchy_[l.element].buried; });
    tbb::parallel_for(std::size_t{0}, out.size(), [&](std::size_t i) { computeClusterLink(out[i]); });
    std::erase_if(out, [](const ClusterLink& l) { return !(l.weight > 0.0f) || !(l.vis_real > 0.0f); });
    cluster_links_.insert(cluster_links_.end(), out.begin(), out.end());
}

void Radiosity::gatherClusters(const std::vector<Eigen::Vector3d>& radiance, std::vector<Eigen::Vector3d>& gathered) const {
    if (clusters_.empty()) return;
    // Each cluster's exitance by direction bin (projected-area-weighted sums) and its mean.
    std::vector<std::vector<Eigen::Vector3d>> exitance(clusters_.size());
    std::vector<Eigen::Vector3d> mean(clusters_.size(), Eigen::Vector3d::Zero());
    std::vector<std::vector<Eigen::Matrix3d>> incident(clusters_.size());
    std::vector<std::vector<std::array<Eigen::Matrix3d, 3>>> incident_grad(clusters_.size());  // per channel
    std::vector<std::vector<char>> used(clusters_.size());
    for (std::size_t ci = 0; ci < clusters_.size(); ++ci) {
        const Cluster& c = clusters_[ci];
        exitance[ci].assign(kBins, Eigen::Vector3d::Zero());
        double area = 0.0;
        for (std::size_t i = 0; i < c.faces.size(); ++i) {
            const int root = hierarchy_.root(c.faces[i]);
            if (hierarchy_[root].buried) continue;
            const double a = faces_[static_cast<std::size_t>(c.faces[i])].area * exposure(root);
            const Eigen::Vector3d& l = radiance[static_cast<std::size_t>(root)];
            mean[ci] += a * l;
            area += a;
            for (const auto& [b, w] : c.face_bins[i]) exitance[ci][static_cast<std::size_t>(b)] += static_cast<double>(w) * l;
        }
        if (area > 0.0) mean[ci] /= area;
        incident[ci].assign(kBins, Eigen::Matrix3d::Zero());
        incident_grad[ci].assign(kBins, {Eigen::Matrix3d::Zero(), Eigen::Matrix3d::Zero(), Eigen::Matrix3d::Zero()});
        used[ci].assign(kBins, 0);
    }
    for (const ClusterLink& l : cluster_links_) {
        const auto ci = static_cast<std::size_t>(l.cluster);
        const auto b = static_cast<std::size_t>(l.bin);
        if (l.kind == ClusterLink::Kind::kSource) {
            const double p = clusters_[ci].projected[b];
            const Eigen::Vector3d lbar = p > 0.0 ? Eigen::Vector3d(exitance[ci][b] / p) : mean[ci];
            gathered[static_cast<std::size_t>(l.element)] += static_cast<double>(l.weight * l.vis_real) * lbar;
        } else {
            const Eigen::Vector3d& ls = radiance[static_cast<std::size_t>(l.element)];
            incident[ci][b] += ls * (static_cast<double>(l.vis_real) * l.dir.cast<double>()).transpose();
            const Eigen::Matrix3d grad = static_cast<double>(l.vis_real) * l.grad.cast<double>();
            for (int ch = 0; ch < 3; ++ch) incident_grad[ci][b][static_cast<std::size_t>(ch)] += ls[ch] * grad;
            used[ci][b] = 1;
        }
    }
    for (std::size_t ci = 0; ci < clusters_.size(); ++ci) {
        std::vector<int> bins;
        for (int b = 0; b < kBins; ++b) {
            if (used[ci][static_cast<std::size_t>(b)]) bins.push_back(b);
        }
        if (bins.empty()) continue;
        // In parallel over faces (each writes its own root): every face reads every used bin.
        const std::vector<int>& faces = clusters_[ci].faces;
        tbb::parallel_for(std::size_t{0}, faces.size(), [&](std::size_t i) {
            const int f = faces[i];
            const Face& face = faces_[static_cast<std::size_t>(f)];
            const Eigen::Vector3d& n = face.normal;
            const Eigen::Vector3d offset = faceCentroid(face) - clusters_[ci].centre;
            Eigen::Vector3d e = Eigen::Vector3d::Zero();
            for (int b : bins) {
                const auto bi = static_cast<std::size_t>(b);
                for (int ch = 0; ch < 3; ++ch) {
                    const Eigen::Vector3d v = incident[ci][bi].row(ch).transpose() + incident_grad[ci][bi][static_cast<std::size_t>(ch)] * offset;
                    e[ch] += std::max(0.0, n.dot(v));
                }
            }
            gathered[static_cast<std::size_t>(hierarchy_.root(f))] += e;
        });
    }
}

std::pair<Eigen::Vector3d, double> Radiosity::clusterBall(int cluster) const {
    const Cluster& c = clusters_[static_cast<std::size_t>(cluster)];
    return {c.centre, c.radius};
}

std::vector<Link> Radiosity::clusterTransfers(std::vector<int>* origin) const {
    std::vector<Link> out;
    if (origin) origin->clear();
    int current = 0;  // the cluster link being expanded
    const auto push = [&](int receiver, int source, double transfer, float vis) {
        if (!(transfer > 0.0) || !(vis > 0.0f)) return;
        if (origin) origin->push_back(current);
        Link l;
        l.receiver = receiver;
        l.source = source;
        l.form_factor = static_cast<float>(transfer / std::numbers::pi);
        l.vis_real = vis;
        out.push_back(l);
    };
    for (const ClusterLink& l : cluster_links_) {
        current = static_cast<int>(&l - cluster_links_.data());
        const Cluster& c = clusters_[static_cast<std::size_t>(l.cluster)];
        if (l.kind == ClusterLink::Kind::kSource) {
            // The bin's mean radiance: sum_f w_fb L_f / p_b (or the area-weighted mean where no face
            // sees the bin, as gatherClusters() does).
            const auto b = static_cast<std::size_t>(l.bin);
            const double p = c.projected[b];
            double area = 0.0;
            if (!(p > 0.0)) {
                for (int f : c.faces) {
                    const int root = hierarchy_.root(f);
                    if (!hierarchy_[root].buried) area += faces_[static_cast<std::size_t>(f)].area * exposure(root);
                }
            }
            for (std::size_t i = 0; i < c.faces.size(); ++i) {
                const int root = hierarchy_.root(c.faces[i]);
                if (hierarchy_[root].buried) continue;
                double share = 0.0;
                if (p > 0.0) {
                    for (const auto& [bin, w] : c.face_bins[i]) {
                        if (bin == l.bin) share = static_cast<double>(w) / p;
                    }
                } else if (area > 0.0) {
                    share = faces_[static_cast<std::size_t>(c.faces[i])].area * exposure(root) / area;
                }
                push(l.element, root, static_cast<double>(l.weight) * share, l.vis_real);
            }
            continue;
        }
        for (int f : c.faces) {
            const int root = hierarchy_.root(f);
            if (hierarchy_[root].buried) continue;
            const Face& face = faces_[static_cast<std::size_t>(f)];
            const Eigen::Vector3d v = l.dir.cast<double>() + l.grad.cast<double>() * (faceCentroid(face) - c.centre);
            push(root, l.element, std::max(0.0, face.normal.dot(v)), l.vis_real);
        }
    }
    return out;
}

void Radiosity::clusterFormFactors(std::vector<double>& own) const {
    for (const ClusterLink& l : cluster_links_) {
        if (l.kind == ClusterLink::Kind::kSource) {
            own[static_cast<std::size_t>(l.element)] += l.weight * l.vis_real / std::numbers::pi;
            continue;
        }
        for (int f : clusters_[static_cast<std::size_t>(l.cluster)].faces) {
            const Eigen::Vector3d& n = faces_[static_cast<std::size_t>(f)].normal;
            own[static_cast<std::size_t>(hierarchy_.root(f))] += std::max(0.0, n.dot(l.dir.cast<double>())) * l.vis_real / std::numbers::pi;
        }
    }
}

}  // namespace commonlight::lighting

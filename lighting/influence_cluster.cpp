// A clustered real proxy's cluster links in the virtual objects' influence (lighting/influence.h):
// a cluster link whose cluster receives (a source element lighting a real mesh proxy's faces) is
// made of one transfer per face (Radiosity::clusterTransfers()). A virtual object in its shaft
// blocks it for the faces whose own shaft it meets; their transmission is estimated once per
// cluster link and class of faces (ClusterNode::blocked_faces), over pairs from those faces
// (chosen by their transfers' weights) to the source, and shared by them, instead of once per
// face (InfluenceOptions::share_cluster_links). Each face's correction stays w_f (t - 1) (B~_s + D_s).
#include <tbb/parallel_for.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <array>
#include <cmath>
#include <ranges>
#include <span>
#include <tuple>

#include "lighting/influence_impl.h"
#include "lighting/sampling.h"

namespace commonlight::lighting {

void VirtualInfluence::Impl::buildNodes(const std::vector<int>& origin, std::size_t first_transfer) {
    const Radiosity& rad = self.radiosity_;
    const Hierarchy& h = rad.hierarchy();
    const std::vector<ClusterLink>& cluster_links = rad.clusterLinks();
    nodes.clear();
    node_face.assign(h.faceCount(), 0);
    link_node.assign(links.size(), -1);
    link_position.assign(links.size(), -1);
    std::vector<int> node_of(cluster_links.size(), -1);
    std::vector<int> under;
    for (std::size_t i = 0; i < origin.size(); ++i) {
        const auto ci = static_cast<std::size_t>(origin[i]);
        const ClusterLink& cl = cluster_links[ci];
        if (cl.kind != ClusterLink::Kind::kReceiver) continue;
        if (node_of[ci] < 0) {
            node_of[ci] = static_cast<int>(nodes.size());
            ClusterNode n;
            n.source = cl.element;
            std::tie(n.centre, n.radius) = rad.clusterBall(cl.cluster);
            nodes.push_back(std::move(n));
        }
        const std::size_t li = first_transfer + i;
        ClusterNode& n = nodes[static_cast<std::size_t>(node_of[ci])];
        link_position[li] = static_cast<int>(n.transfers.size());
        n.transfers.push_back(static_cast<int>(li));
        link_node[li] = node_of[ci];
        const int root = links[li].receiver;
        node_face[static_cast<std::size_t>(h[root].face)] = 1;
        under.clear();
        h.leavesUnder(root, under);
        for (int e : under) {
            if (base_leaf[static_cast<std::size_t>(e)]) n.face_leaves.emplace_back(h[root].face, e);
        }
    }
    for (ClusterNode& n : nodes) {
        std::sort(n.face_leaves.begin(), n.face_leaves.end());
        n.face_leaves.erase(std::unique(n.face_leaves.begin(), n.face_leaves.end()), n.face_leaves.end());
        buildGroups(n);
    }
}

// A node's faces in groups of at most kGroup neighbours (halving at the median centroid along the
// widest extent), each group under a ball that holds its faces' balls (centroid, largest distance
// to a corner: ElementShape). A face's shaft (its ball to the source's) then lies in its group's
// shaft (a cone of balls between balls that hold the ends holds the cone between the ends:
// lighting/shaft_index.h). The node's own shaft (the cluster's bounding ball, which holds its faces
// but not every face's ball) is tested first: an object outside it is left out of the answer, as
// before the groups.
void VirtualInfluence::Impl::buildGroups(ClusterNode& node) const {
    constexpr int kGroup = 8;
    const auto n = static_cast<int>(node.transfers.size());
    node.members.resize(static_cast<std::size_t>(n));
    for (int t = 0; t < n; ++t) node.members[static_cast<std::size_t>(t)] = t;
    node.groups.clear();
    const auto face = [&](int t) -> const ElementShape& {
        return shape[static_cast<std::size_t>(links[static_cast<std::size_t>(node.transfers[static_cast<std::size_t>(t)])].receiver)];
    };
    std::vector<std::pair<int, int>> stack;
    if (n > 0) stack.emplace_back(0, n);
    while (!stack.empty()) {
        const auto [b, e] = stack.back();
        stack.pop_back();
        const auto first = node.members.begin() + b, last = node.members.begin() + e;
        if (e - b <= kGroup) {
            ClusterNode::Group g;
            g.begin = b;
            g.end = e;
            for (auto it = first; it != last; ++it) g.centre += face(*it).centroid;
            g.centre /= static_cast<double>(e - b);
            for (auto it = first; it != last; ++it) g.radius = std::max(g.radius, (face(*it).centroid - g.centre).norm() + face(*it).radius);
            g.radius = g.radius * (1.0 + 1e-9) + 1e-12;  // (round-off: the group's ball must hold its faces')
            node.groups.push_back(g);
            continue;
        }
        Eigen::AlignedBox3d box;
        for (auto it = first; it != last; ++it) box.extend(face(*it).centroid);
        int axis = 0;
        box.sizes().maxCoeff(&axis);
        const int mid = (b + e) / 2;
        std::nth_element(first, node.members.begin() + mid, last, [&](int x, int y) { return face(x).centroid[axis] < face(y).centroid[axis]; });
        stack.emplace_back(mid, e);
        stack.emplace_back(b, mid);
    }
    node.member_balls.clear();
    for (int t : node.members) node.member_balls.push_back(Ball{face(t).centroid, face(t).radius});
}

Shaft VirtualInfluence::Impl::nodeShaft(const ClusterNode& node) const {
    const ElementShape& s = shape[static_cast<std::size_t>(node.source)];
    return Shaft{node.centre, s.centroid, node.radius, s.radius};
}

Shaft VirtualInfluence::Impl::groupShaft(const ClusterNode& node, const ClusterNode::Group& group) const {
    const ElementShape& s = shape[static_cast<std::size_t>(node.source)];
    return Shaft{group.centre, s.centroid, group.radius, s.radius};
}

bool VirtualInfluence::Impl::nodeReached(const ClusterNode& node, const Ball& ball) const {
    if (!shaftMeetsBall(nodeShaft(node), ball)) return false;
    if (!self.options_.group_cluster_faces) return true;
    return std::ranges::any_of(node.groups, [&](const ClusterNode::Group& g) { return shaftMeetsBall(groupShaft(node, g), ball); });
}

// A node's visibility pairs (ClusterNode::Pair): 16 x link_pairs over all its faces, each face
// chosen by its transfer's weight (stratified over their cumulative weights), so that a subset's
// pairs estimate the transfer-weighted mean of its faces' transmissions.
void VirtualInfluence::Impl::nodePairs(int k, ClusterNode& node) const {
    const Radiosity& rad = self.radiosity_;
    const Hierarchy& h = rad.hierarchy();
    node.pairs.clear();
    node.pairs_made = true;
    std::vector<double> cdf;
    double total = 0.0;
    for (int li : node.transfers) {
        const Link& l = links[static_cast<std::size_t>(li)];
        total += static_cast<double>(l.form_factor) * static_cast<double>(l.vis_real);
        cdf.push_back(total);
    }
    node.pair_offsets.assign(node.transfers.size() + 1, 0);
    if (cdf.empty() || !(total > 0.0)) return;
    const int n = std::clamp(16 * self.options_.link_pairs, 1, 1024);
    const std::uint64_t seed = hashCombine(hashCombine(self.options_.seed ^ 0xc1a5ull, h.key(node.source)), static_cast<std::uint64_t>(k));
    const ElementGeometry gs = rad.geometry(node.source);
    for (int p = 0; p < n; ++p) {
        const SamplePair pair = stratifiedPair(seed, p, n);
        const double u = (p + unitFromHash(hashCombine(seed, static_cast<std::uint64_t>(p) + 77))) / n * total;
        const auto t = std::min(static_cast<std::size_t>(std::upper_bound(cdf.begin(), cdf.end(), u) - cdf.begin()), cdf.size() - 1);
        const int root = links[static_cast<std::size_t>(node.transfers[t])].receiver;
        const ElementGeometry gr = rad.geometry(root);
        const Eigen::Vector3d xr = rad.surfacePoint(root, gr, pair.first.x(), pair.first.y());
        if (rad.exposure(root) < 1.0 && rad.hidden(root, xr)) continue;  // on the face's hidden part: none of its light
        const Eigen::Vector3d xs = rad.surfacePoint(node.source, gs, pair.second.x(), pair.second.y());
        const Eigen::Vector3d dv = xs - xr;
        if (!(gr.normal.dot(dv) > 0.0) || !(-gs.normal.dot(dv) > 0.0)) continue;  // the pair exchanges no light
        if (self.rays_.occludedReal(xr, gr.normal, xs, gs.normal)) continue;
        node.pairs.push_back(ClusterNode::Pair{static_cast<int>(t), xr, xs});
    }
    // (The faces were drawn in order of their cumulative weights: the pairs are sorted by transfer.)
    node.pair_offsets.assign(node.transfers.size() + 1, 0);
    for (const ClusterNode::Pair& p : node.pairs) ++node.pair_offsets[static_cast<std::size_t>(p.transfer) + 1];
    for (std::size_t t = 1; t < node.pair_offsets.size(); ++t) node.pair_offsets[t] += node.pair_offsets[t - 1];
}

// Each face's hull with the source (its face planes), in group order: made at the node's first answer.
void VirtualInfluence::Impl::nodeHulls(ClusterNode& node) const {
    if (node.hulls.size() == node.members.size()) return;
    node.hulls.resize(node.members.size());
    const std::span<const Eigen::Vector3d> source = shape[static_cast<std::size_t>(node.source)].polygon();
    for (std::size_t m = 0; m < node.members.size(); ++m) {
        const auto t = static_cast<std::size_t>(node.members[m]);
        node.hulls[m] = HullPlanes::of(shape[static_cast<std::size_t>(links[static_cast<std::size_t>(node.transfers[t])].receiver)].polygon(), source);
    }
}

// The objects whose bounds meet the node's shaft and the faces whose own shaft meets one of them,
// by class (ClusterNode::blocked_faces, blocked_classes). No ray: the transmissions are
// nodeTransmissions()'.
void VirtualInfluence::Impl::nodeFaces(ClusterNode& node) const {
    const Hierarchy& h = self.radiosity_.hierarchy();
    ClusterNode& out = node;
    out.mask = 0;
    out.blocked_faces.clear();
    out.blocked_classes.clear();
    out.transfer_objects.assign(node.transfers.size(), 0u);
    const Shaft shaft = nodeShaft(node);
    std::vector<const Ball*> balls;
    std::vector<int> ball_object;
    for (std::size_t o = 0; o < objects.size(); ++o) {
        if (!objects[o].present || !shaftMeetsBall(shaft, objects[o].ball)) continue;
        balls.push_back(&objects[o].ball);
        ball_object.push_back(static_cast<int>(o));
    }
    if (balls.empty()) return;
    const Eigen::Vector3d& to = shape[static_cast<std::size_t>(node.source)].centroid;
    const double to_radius = shape[static_cast<std::size_t>(node.source)].radius;
    // The blocked faces' transfers and classes, found as the faces of the groups whose shaft meets
    // an object's bounds are tested one by one (a face blocked by two objects: the lower class).
    for (std::size_t j = 0; j < balls.size(); ++j) {
        const Ball* ball = balls[j];
        const std::uint32_t bit = RayScene::virtualBit(ball_object[j]);
        for (const ClusterNode::Group& g : node.groups) {
            if (self.options_.group_cluster_faces && !shaftMeetsBall(groupShaft(node, g), *ball)) continue;
            out.mask |= bit;
            for (int m = g.begin; m < g.end; ++m) {
                const Ball& fb = node.member_balls[static_cast<std::size_t>(m)];
                if (!shaftMeetsBall(Shaft{fb.centre, to, fb.radius, to_radius}, *ball)) continue;
                const auto t = static_cast<std::size_t>(node.members[static_cast<std::size_t>(m)]);
                if (!node.hulls[static_cast<std::size_t>(m)].meets(*ball)) continue;
                // How near the centroids' segment passes to the ball's centre, over its radius.
                const Eigen::Vector3d d = to - fb.centre;
                const double u = std::clamp((ball->centre - fb.centre).dot(d) / std::max(d.squaredNorm(), 1e-300), 0.0, 1.0);
                const double near = (fb.centre + u * d - ball->centre).norm() / std::max(ball->radius, 1e-12);
                const int cls = near <= 0.5 ? 0 : (near <= 1.0 ? 1 : 2);
                if (out.transfer_objects[t] == 0u) {
                    out.blocked_classes.emplace_back(static_cast<int>(t), cls);
                } else {
                    for (auto& [bt, bc] : out.blocked_classes) {
                        if (bt == static_cast<int>(t)) bc = std::min(bc, cls);
                    }
                }
                out.transfer_objects[t] |= bit;
            }
        }
    }
    if (out.mask == 0) return;
    std::sort(out.blocked_classes.begin(), out.blocked_classes.end());
    out.blocked_faces.reserve(out.blocked_classes.size());
    for (const auto& [t, cls] : out.blocked_classes) {
        out.blocked_faces.emplace_back(h[links[static_cast<std::size_t>(node.transfers[static_cast<std::size_t>(t)])].receiver].face, cls);
    }
    std::sort(out.blocked_faces.begin(), out.blocked_faces.end());
}

// Each class's transmission over the node's blocked faces (its blocked_classes and mask): the
// fraction of its faces' pairs (nodePairs()) that the objects leave open (the transfer-weighted
// mean of the faces' transmissions).
void VirtualInfluence::Impl::nodeTransmissions(int k, ClusterNode& node) const {
    const Radiosity& rad = self.radiosity_;
    const Hierarchy& h = rad.hierarchy();
    const RayScene& rays = self.rays_;
    constexpr int kClasses = ClusterNode::kClasses;
    node.mixed.fill(false);
    node.transmission.fill(1.0);
    if (node.blocked_classes.empty()) return;
    if (!node.pairs_made) nodePairs(k, node);
    const Eigen::Vector3d ns = rad.geometry(node.source).normal;
    std::array<double, kClasses + 1> open_real{}, open_all{};  // by class, then pooled
    std::array<bool, kClasses + 1> any_blocked{}, any_open{};
    for (const auto& [t, c] : node.blocked_classes) {
        const auto cls = static_cast<std::size_t>(c);
        const Eigen::Vector3d& nr = rad.face(h[links[static_cast<std::size_t>(node.transfers[static_cast<std::size_t>(t)])].receiver].face).normal;
        for (int i = node.pair_offsets[static_cast<std::size_t>(t)]; i < node.pair_offsets[static_cast<std::size_t>(t) + 1]; ++i) {
            const ClusterNode::Pair& p = node.pairs[static_cast<std::size_t>(i)];
            const bool blocked = rays.occludedVirtual(p.from, nr, p.to, ns, node.mask);
            for (const std::size_t j : {cls, static_cast<std::size_t>(kClasses)}) {
                open_real[j] += 1.0;
                if (blocked) {
                    any_blocked[j] = true;
                } else {
                    any_open[j] = true;
                    open_all[j] += 1.0;
                }
            }
        }
    }
    for (std::size_t i = 0; i < static_cast<std::size_t>(kClasses); ++i) {
        const std::size_t from = open_real[i] > 0.0 ? i : static_cast<std::size_t>(kClasses);  // no pair of its own: the pooled one
        node.mixed[i] = any_blocked[from] && any_open[from];
        node.transmission[i] = open_real[from] > 0.0 ? open_all[from] / open_real[from] : 1.0;
    }
}

void VirtualInfluence::Impl::refreshNodes(bool all) {
    if (nodes.empty() || !self.options_.share_cluster_links) return;
    tbb::parallel_for(std::size_t{0}, nodes.size(), [&](std::size_t k) {
        ClusterNode& node = nodes[k];
        node.pending = false;
        if (!all && node.valid && !reachedByMove([&](const Ball& ball) { return nodeReached(node, ball); })) return;
        nodeHulls(node);
        node.pending = true;
        node.was_known = node.valid && node.known;
        node.before_mask = node.mask;
        node.before_faces.swap(node.blocked_faces);
        node.before_transmission = node.transmission;
        node.before_mixed = node.mixed;
        node.valid = true;
        node.known = false;
        nodeFaces(node);
    });
}

void VirtualInfluence::Impl::answerNodes(std::vector<int>& touched) {
    if (nodes.empty() || !self.options_.share_cluster_links) return;
    // The nodes a base leaf's entries select a transfer of: the only ones an element may read (a
    // base leaf's selection is taken from its entries, and its entries change only where the
    // candidates touched it, which is walked). Every entry is at a base leaf its object touched,
    // and only a changed object's entries change: the others keep their list.
    const Hierarchy& h = self.radiosity_.hierarchy();
    std::vector<char> read(nodes.size(), self.options_.lazy_cluster_answers ? 0 : 1);
    if (self.options_.lazy_cluster_answers) {
        for (std::size_t o = 0; o < objects.size(); ++o) {
            ObjectState& obj = objects[o];
            if (o >= object_changed.size() || object_changed[o]) {
                obj.node_reads.clear();
                for (int b : obj.touched) {
                    if (!node_face[static_cast<std::size_t>(h[b].face)]) continue;
                    for (const auto& [object, li] : entries[static_cast<std::size_t>(b)]) {
                        if (object != static_cast<int>(o) || li < 0 || static_cast<std::size_t>(li) >= link_node.size()) continue;
                        if (const int k = link_node[static_cast<std::size_t>(li)]; k >= 0) obj.node_reads.push_back(k);
                    }
                }
                std::sort(obj.node_reads.begin(), obj.node_reads.end());
                obj.node_reads.erase(std::unique(obj.node_reads.begin(), obj.node_reads.end()), obj.node_reads.end());
            }
            for (int k : obj.node_reads) read[static_cast<std::size_t>(k)] = 1;
        }
    }
    std::vector<char> walk(nodes.size(), 0);
    tbb::parallel_for(std::size_t{0}, nodes.size(), [&](std::size_t k) {
        ClusterNode& node = nodes[k];
        node.changed = false;
        const bool was_known = node.pending ? node.was_known : node.known;
        if (!node.pending && (node.known || !read[k] || !node.valid)) return;
        // (Faces blocked by no object: every transmission 1, no ray.)
        if (node.blocked_classes.empty() || read[k]) {
            nodeTransmissions(static_cast<int>(k), node);
            node.known = true;
        }
        if (node.pending && was_known && node.known && node.mask == node.before_mask && node.blocked_faces == node.before_faces &&
            node.transmission == node.before_transmission && node.mixed == node.before_mixed) {
            return;  // the same answer
        }
        node.changed = true;
        ++node.version;
        // An answer that was made may be held by the elements of the faces it blocked, if a base
        // leaf still selects one of its transfers (where none does, the base leaves whose entries
        // selected one before are walked: their entries changed). One never made is held by none,
        // and the base leaves that read it now are walked for their new entries.
        walk[k] = node.pending && was_known && read[k] ? 1 : 0;
    });
    // The faces it blocked and blocks now are walked again (the others keep no answer of it): an
    // element holds a node's answer only where its base leaf's entries select the node's transfer,
    // and the base leaves of a changed object's entries, before and now, are walked already. So
    // only an object that did not change and has entries makes the walk needed.
    const bool held = std::ranges::any_of(std::views::iota(std::size_t{0}, objects.size()), [&](std::size_t o) {
        return (o < object_changed.size() && !object_changed[o]) && !objects[o].touched.empty();
    });
    for (std::size_t k = 0; k < nodes.size(); ++k) {
        nodes[k].pending = false;
        if (!walk[k] || !held) continue;
        const ClusterNode& node = nodes[k];
        for (const auto* faces : {static_cast<const std::vector<std::pair<int, int>>*>(&node.before_faces), &node.blocked_faces}) {
            for (const auto& [f, cls] : *faces) {
                auto it = std::lower_bound(node.face_leaves.begin(), node.face_leaves.end(), std::make_pair(f, -1));
                for (; it != node.face_leaves.end() && it->first == f; ++it) touched.push_back(it->second);
            }
        }
    }
}

std::vector<VirtualInfluence::ClusterLinkInfo> VirtualInfluence::clusterLinkInfo() const {
    std::vector<ClusterLinkInfo> out;
    for (const ClusterNode& node : impl_->nodes) {
        ClusterLinkInfo info;
        info.blocked_faces = node.blocked_faces;
        info.known = node.known;
        for (std::size_t i = 0; i < info.transmission.size(); ++i) info.transmission[i] = node.transmission[i];
        out.push_back(std::move(info));
    }
    return out;
}

}  // namespace commonlight::lighting

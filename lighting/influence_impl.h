// Internal state of lighting/influence.h, shared by influence.cpp (structure: shafts, selection,
// the update), influence_candidates.cpp (the candidates), influence_refine.cpp (refinement,
// transmissions), influence_objects.cpp (the virtual objects as clusters) and
// influence_solve.cpp (propagation and the dense reference). Not part of the module's interface.
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <limits>
#include <span>
#include <memory>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "lighting/influence.h"
#include "lighting/ray_scene.h"

namespace commonlight::lighting {

inline double lumaOf(const Eigen::Vector3d& v) { return 0.2126 * v.x() + 0.7152 * v.y() + 0.0722 * v.z(); }

// A base link's change at one leaf: w (t - 1), w = pi F V of the link, t the virtual transmission
// of the shaft from the leaf to the link's source.
struct Correction {
    int source = -1;
    double coef = 0.0;
};

// What the virtual objects do to one element (lighting/influence.h): at a leaf dDirect and the
// objects' light; at the "link level" (an element about link_size across, or a larger leaf) the
// corrections of the base links they block, with their current sum C, for everything under it
// (indirect shadows are smooth: a leaf per pixel would multiply the work, not the accuracy).
struct LeafTerms {
    Eigen::Vector3d direct = Eigen::Vector3d::Zero();
    Eigen::Vector3d cluster = Eigen::Vector3d::Zero();
    Eigen::Vector3d cl = Eigen::Vector3d::Zero();  // sum coef (B~_s + D_s - U_s): what was shot so far
    std::vector<Correction> corrections;
    void clear() {
        direct.setZero();
        cluster.setZero();
        cl.setZero();
        corrections.clear();
    }
};

// An element's answers of its last evaluation, item by item: what the virtual objects do to its
// light from each selected light, each selected base link and each object's own light. An answer
// depends on the objects only through the rays in its shaft (the segments between the element and
// the light, the link's source or the object), so it stands while no object that moved had its old
// or new bounds in that shaft: a move recomputes what it reaches, not every element it touches.
struct LightAnswer {
    int light = 0;
    bool blocked = false;  // a significant object's bounds meet the shaft (the rays were traced)
    bool mixed = false;    // the pilot found a penumbra
    double pilot = 1.0;    // transmission, pilot estimate
    double full = -1.0;    // the full estimate of a penumbra (once the element stays a leaf); < 0: not made
};
struct LinkAnswer {
    int link = 0;
    bool blocked = false;
    bool mixed = false;
    double transmission = 1.0;
    std::uint32_t version = 0;  // a cluster node's transfer: the node's answer it was read from (ClusterNode)
};
struct ClusterAnswer {
    int object = 0;
    Eigen::Vector3d irradiance = Eigen::Vector3d::Zero();
    double variation = 0.0;
};
// Sorted by their key (light, link, object): the selection's order.
struct Answers {
    bool valid = false;        // lights and clusters answered
    bool links_valid = false;  // links answered (only elements that carry corrections)
    std::vector<LightAnswer> lights;
    std::vector<LinkAnswer> links;
    std::vector<ClusterAnswer> clusters;
};
// The selected items (sorted) whose shaft at an element met a moved object's old or new bounds:
// the only ones its children test again (a child's shaft lies in its parent's).
struct Reach {
    std::vector<int> lights, links, objects;
};

// Which visibility pairs the real scene blocks, kept per leaf and light (key -1 - k) or per leaf
// and link source (key s): the real scene never changes, so a move costs virtual rays only.
// A blocked base link's pairs the real scene leaves open, as transmissionToSource() traces them
// (both ends' points lifted as the rays take them, the kernel weight), in the pairs' order: a
// re-answer traces their virtual rays only.
// Each pair is kept as its ray (RayScene::prepareSegment: lifted once), with a ball holding all the
// rays: an object whose ball misses it blocks none of them (the answer's mask drops it).
struct LinkPoints {
    struct Pair {
        PreparedSegment ray;
        double w = 0.0;
    };
    std::vector<Pair> pairs;
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();  // the rays' ball
    double radius = 0.0;
    double open_real = 0.0;  // the pairs' weights summed in their order (an answer's denominator)
    // The pairs the objects `kept_objects` (virtual bits: objects near the rays that did not move
    // at the latest commit) block, bit i for pairs[i], kept at RayScene::virtualStamp() `kept_at`:
    // while none of those objects changes, a re-answer traces the other objects' rays alone
    // (transmissionToSource(); this element's thread only, as its RealMask).
    mutable std::uint64_t kept_blocked = 0;
    mutable std::uint64_t kept_at = 0;
    mutable std::uint32_t kept_objects = 0;
    // Whether the kept answers hold for the near objects `still`: kept for those very objects, and
    // none of them changed since (a change the link was not re-answered at counts too).
    bool keptHold(std::uint32_t still, const RayScene& rays) const {
        return kept_objects == still && (still == 0u || (rays.virtualChangedSince(kept_at) & still) == 0u);
    }
};

struct RealMask {
    int key = 0;
    std::uint64_t pilot = 0;
    std::uint64_t full = 0;
    std::uint64_t pilot_hidden = 0;  // and which pairs start on the leaf's hidden part (under a box)
    std::uint64_t full_hidden = 0;
    std::uint8_t have = 0;  // bit 0: pilot known, bit 1: full known, bit 2: `points` known
    std::shared_ptr<const LinkPoints> points;  // a base link's (key >= 0) open pairs, once traced
};

// A base leaf's blockers worth computing (lighting/influence.h `link_epsilon`): lights and base
// links, and the objects whose light reaches it at leaf level.
struct Selection {
    std::vector<int> lights;
    std::vector<int> links;
    std::vector<int> objects;
};

// A real element's (or a posed virtual face's) geometry, cached (the shaft tests run thousands
// of times per move).
struct ElementShape {
    Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
    double radius = 0.0;  // largest distance from the centroid to a corner
    std::array<Eigen::Vector3d, 4> corners{Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()};
    int count = 0;
    std::span<const Eigen::Vector3d> polygon() const { return {corners.data(), static_cast<std::size_t>(count)}; }
};

// A base cluster link whose cluster receives (ClusterLink::Kind::kReceiver: a clustered real
// proxy's faces lit by one source element) as one node for the per-face transfers it is made of
// (Radiosity::clusterTransfers()): one shaft test (the cluster's bounding ball to the source) and
// one transmission per configuration, shared by every face, instead of one per face. The faces
// whose own shaft meets an object's bounds are the ones it blocks (`blocked_faces`); the
// transmission is the transfer-weighted mean over their pairs (InfluenceOptions::share_cluster_links).
struct ClusterNode {
    int source = -1;                                   // the element the cluster's faces receive from
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();  // the cluster's bounding ball
    double radius = 0.0;
    std::vector<int> transfers;                        // its base links (one per face)
    std::vector<std::pair<int, int>> face_leaves;      // (face, base leaf under the face's root), sorted
    // Its faces in groups of neighbours, each under a ball holding the faces' own balls, so that
    // a shaft from a group's ball to the source holds its faces' shafts: an object's bounds that
    // miss it miss all of them (one test instead of one per face). `members`: positions in
    // `transfers`, a group's contiguous.
    struct Group {
        Eigen::Vector3d centre = Eigen::Vector3d::Zero();
        double radius = 0.0;
        int begin = 0, end = 0;  // members[begin, end)
    };
    std::vector<Group> groups;
    std::vector<int> members;
    std::vector<Ball> member_balls;  // by position in `members`: its face's ball (centroid, radius), read in order
    // The answer for the configuration now.
    bool valid = false;
    bool changed = false;        // in this update (its faces are walked again)
    std::uint32_t version = 0;   // counts the answers that changed
    std::uint32_t mask = 0;      // objects whose bounds meet a group's shaft (ray mask bits)
    // The faces it blocks, by how deep in an object's bounds their shaft runs: class 0 when the
    // segment between the face's and the source's centroids passes within half the ball's radius
    // of its centre, 1 within the radius, 2 beside it (the hull alone meets it). Each class has
    // its own transmission, over its own faces' pairs (the pooled one where a class has none):
    // a shadow's core and its edge are not averaged together. (face, class), sorted.
    static constexpr int kClasses = 3;
    std::vector<std::pair<int, int>> blocked_faces;
    std::vector<std::uint32_t> transfer_objects;  // per transfer: the objects whose bounds meet its face's shaft
    std::array<bool, kClasses> mixed{};
    std::array<double, kClasses> transmission{1.0, 1.0, 1.0};
    // Lazy answers (InfluenceOptions::lazy_cluster_answers): the faces (above) are found at every
    // move that reaches the node (the candidates read them), the transmissions only while a base
    // leaf's entries select one of its transfers (answerNodes()). `known`: `transmission` and
    // `mixed` hold for the faces now; `blocked_classes`: (position in `transfers`, class) of the
    // blocked faces, what the transmissions are made from.
    bool known = false;
    std::vector<std::pair<int, int>> blocked_classes;
    // Reached in this update (refreshNodes()): the faces found again, the transmissions not yet;
    // the answer before, for answerNodes() to compare with and to walk its faces if it changed.
    bool pending = false;
    bool was_known = false;
    std::uint32_t before_mask = 0;
    std::vector<std::pair<int, int>> before_faces;
    std::array<bool, kClasses> before_mixed{};
    std::array<double, kClasses> before_transmission{1.0, 1.0, 1.0};
    // Its visibility pairs, made at the first answer that needs them: faces chosen by their
    // transfers' weights (`transfer`: the position in `transfers`), points stratified; only the
    // pairs that exchange light and that the real scene leaves open are kept (the real scene
    // never changes: an answer traces virtual rays only).
    struct Pair {
        int transfer = 0;
        Eigen::Vector3d from = Eigen::Vector3d::Zero();  // on the face
        Eigen::Vector3d to = Eigen::Vector3d::Zero();    // on the source
    };
    bool pairs_made = false;
    std::vector<Pair> pairs;          // by transfer (their faces were drawn in order)
    std::vector<int> pair_offsets;    // per transfer: its pairs are pairs[pair_offsets[t], pair_offsets[t + 1])
    std::vector<HullPlanes> hulls;  // by position in `members`: the hull of its face and the source (made at the first answer)
};

// A virtual object: where it is, what it is made of, what it touched.
struct ObjectState {
    bool present = false;
    bool known = false;  // has been placed at least once since the base
    Rigid3d pose;
    Eigen::Vector3d emission = Eigen::Vector3d::Zero();  // relative radiance of its faces (uniform)
    bool emission_given = false;
    Ball ball;                      // world
    Eigen::Vector3d centre_local = Eigen::Vector3d::Zero();
    double radius = 0.0;            // of the bounding ball
    bool sphere = false;            // an exact sphere (its form factor in closed form: pointToSphere())
    double sphere_radius = 0.0;
    std::vector<int> faces;         // global face indices
    std::vector<int> touched;       // base leaves it affected last time (sorted)
    std::vector<int> node_reads;    // the cluster nodes its entries select a transfer of (sorted; answerNodes())
    std::vector<int> cluster_leaves;  // base leaves whose own leaves link to it (sorted)
    std::vector<std::pair<int, Eigen::Vector3d>> cluster_links;  // above base leaves: element, irradiance
    std::vector<Eigen::Vector3d> face_radiance;  // per face in `faces`
    std::vector<ElementShape> face_shape;         // per face, posed (world)
    std::vector<Eigen::Vector3d> face_normal;
    std::vector<double> face_area;
    std::vector<Eigen::Vector3d> exitance;       // per table direction: radiance towards it
    std::vector<double> projected;               // per table direction: projected area, m^2
    double projected_max = 0.0;
    double luma_max = 0.0;                        // largest face radiance (luminance)
    // The shafts near the object: (base leaf, base link; or -1 - light) pairs whose shaft meets
    // `cache_ball`, a ball `margin` larger than the object's. A move that stays inside it filters
    // these instead of querying the index again.
    bool cache_valid = false;
    Ball cache_ball;
    std::vector<std::pair<int, int>> cache_pairs;
    // Per cache pair, its hull's face planes once found (at the first move that needs them; null
    // until then). Held apart: a pair in six or fewer ever needs them (a HullPlanes is 388 bytes,
    // the room's ball caches 29 000 pairs).
    std::vector<std::unique_ptr<HullPlanes>> cache_hulls;
    // The hulls the object's cache held under the last base whose element and source kept their
    // shapes (setBase()), by (element, source element; -1 - light for a light), sorted: taken by
    // the first cache made under the new base, then dropped. A hull is the two polygons' alone.
    struct CarriedHull {
        int element = 0;
        int source = 0;
        std::unique_ptr<HullPlanes> hull;
    };
    std::vector<CarriedHull> carried_hulls;
    // Per cache pair, the parts of its significance that do not depend on where the object is
    // (share, solid angle; < 0: not found yet).
    std::vector<std::array<double, 2>> cache_sig;
    // Per cache pair, its shaft (the base leaf's end first; found with cache_sig), laid out for the
    // loop over the pairs at every move; `far`: a directional light or a distant cell (only the
    // shaft's first end, the base leaf's centroid, is set).
    struct PairShaft {
        Shaft shaft;
        bool far = false;
    };
    std::vector<PairShaft> cache_shafts;
    // Cached pairs left alone while the object moves (its candidates at every move): `travel`,
    // the distance its ball's centre has covered since it was placed (summed move by move, at
    // least how far it now is from where it was at any earlier move), and per pair the travel up
    // to which its answer is known: `cache_idle`, it is not kept (its significance stays below
    // the item threshold, or its shaft stays clear of the ball) while travel < cache_idle;
    // `cache_meets`, the ball still meets its shaft while travel < cache_meets. Both bounds come
    // from distances that are 1-Lipschitz in the ball's centre, less a margin for round-off, so
    // the pairs kept are those the tests would keep. 0: test again.
    double travel = 0.0;
    bool travel_known = false;
    Ball travel_ball;  // the ball at the last move (its radius: a change starts again)
    std::vector<double> cache_idle, cache_meets;
    // Which cached pairs the next move looks at, so that a move costs the pairs it may change, not
    // the whole cache: `cache_awake`, positions in cache_pairs; `cache_asleep`, the positions (keyed
    // by their cache_idle) of the pairs left alone until `travel` reaches their cache_idle. A pair
    // in neither is never significant (its share below the item threshold: it does not depend on
    // where the object is). Made again from cache_idle when the cache is made or `travel` restarts.
    std::vector<int> cache_awake;
    SleepQueue cache_asleep;
    // Per cache pair, whether the ball the pairs were collected with (`cache_query`: cache_ball,
    // or the object's ball for a scan) meets the hull of its two ends: 0 not tested yet, 1 yes, 2
    // no (then the pair is not one of the cache's: never kept). Tested at the first move that asks
    // whether the object meets the pair's shaft, not for every pair collected.
    Ball cache_query;
    std::vector<std::uint8_t> cache_hull_in;
};

struct VirtualInfluence::Impl {
    VirtualInfluence& self;
    explicit Impl(VirtualInfluence& s) : self(s) {}

    InfluenceBase base;
    double scale = 1.0;        // largest B~ leaf radiance (max over channels)
    double luma_scale = 1.0;   // largest B~ leaf luminance
    double mean_luma = 0.0;    // area-weighted mean B~ of the real leaves (luminance)

    // By element (grown with the hierarchy by grow()).
    std::vector<char> sub;        // made here
    std::vector<char> base_leaf;  // a leaf of the base
    std::vector<double> up;       // pull weight towards the parent
    std::vector<Eigen::Vector3d> G, V, U, pending;
    std::vector<char> queued, pending_flag, column_known;
    std::vector<LeafTerms> terms;
    std::vector<Answers> answers;
    std::vector<char> has_terms;  // any element (active): direct or cluster (leaves), corrections (link level)
    std::vector<std::vector<RealMask>> masks;
    // By element: the hulls linkMeetsBall() tests, per source (sorted), found once (both ends are static
    // real elements). Only the thread walking the element reads or grows its list.
    mutable std::vector<std::vector<std::pair<int, CachedHull>>> link_hulls;
    std::vector<Selection> selection;                      // base leaves
    std::vector<std::vector<std::pair<int, int>>> entries;  // base leaves: (object, base link)
    std::vector<int> bound_level;                           // base leaves: the footprint level used
    std::vector<ElementShape> shape;                        // real elements
    std::vector<std::vector<Eigen::Vector3d>> light_polygons;  // by light, at the last setBase() (its hulls kept while the same)
    mutable std::atomic<long> hulls_made{0};                // hull planes found since the update began (InfluenceStats::hulls_made)
    std::vector<double> rho_max, rho_mean, den_min;         // base elements: over the leaves under them (luminance)
    // B~ as the objects' irradiance reads it: an element made here reads as its base leaf (so an
    // object's light does not depend on the refinement that others left), virtual faces as black.
    std::vector<Eigen::Vector3d> probe_radiance;

    // The base links: the radiosity's element links, then its cluster links as element links
    // (Radiosity::clusterTransfers()). Every "base link" index below is into this.
    std::vector<Link> links;
    // The base cluster links whose clusters receive, as nodes (ClusterNode), and by base link its
    // node (-1: none).
    std::vector<ClusterNode> nodes;
    std::vector<int> link_node;
    std::vector<char> node_face;     // by face: a face some node's transfers light (its base leaves may read a node)
    std::vector<int> link_position;  // by base link of a node: its place in the node's transfers
    // Base links by source (CSR), corrections by source (rebuilt after each refinement).
    std::vector<int> link_offsets, link_by_source;
    std::vector<int> corr_offsets;
    std::vector<std::pair<int, int>> corr_by_source;  // (leaf, index in its corrections)
    std::vector<char> corr_source;                    // by element: has corrections leaving it

    // Shafts: ids [0, link_shafts) are base links, then (base leaf, light) pairs.
    std::unique_ptr<ShaftIndex> index;
    int link_shafts = 0;
    std::vector<std::pair<int, int>> light_shafts;
    std::vector<int> shaft_link;  // link shafts: the base link (only links strong enough to matter are indexed)
    std::vector<int> far_lights;  // directional lights and distant cells (not in the index)

    std::vector<ObjectState> objects;
    // This update's moves: the old and new bounds of the objects whose pose or presence changed,
    // and by object whether it changed at all (pose, presence or emission: its own light again).
    std::vector<Ball> moved_balls;
    std::vector<char> object_changed;
    template <typename F>
    bool reachedByMove(F meets) const {
        for (const Ball& ball : moved_balls) {
            if (meets(ball)) return true;
        }
        return false;
    }
    std::vector<Eigen::Vector3d> table;  // directions of the objects' exitance tables
    // The table direction nearest to each cell of a cube map (kLookup x kLookup per face): the
    // exitance of a direction in O(1) instead of a scan of the table.
    static constexpr int kLookup = 24;
    std::vector<std::uint8_t> table_lookup;
    int tableIndex(const Eigen::Vector3d& direction) const;
    std::optional<InfluenceViewer> viewer;

    std::vector<int> worklist, pending_list;
    std::vector<char> face_dirty;
    int shots = 0;

    // --- influence.cpp ---
    void grow();
    int baseLeafOf(int element) const;
    // The B~ (luminance) a change at an element is measured against: its own, floored at a
    // twentieth of its face's mean (below a fiftieth the renderer adds the difference B - B~
    // instead of multiplying by the ratio: Debevec's rule, lighting/snapshot.h), and at 1e-3 of
    // the scene's largest.
    double floorLuma(int element) const;
    std::vector<double> face_floor;  // by face
    int boundLevel(int element) const;  // footprint bound as min_size * 2^level; large: out of view
    double boundSize(int level) const;
    Shaft elementShaft(int element, int other) const;
    Shaft lightShaft(int element, int light) const;
    std::span<const Eigen::Vector3d> lightPolygon(int light) const;
    void cacheShape(int element);
    // The tight tests (cone of balls first, then the hull's planes).
    bool linkMeetsBall(int element, int source, const Ball& ball) const;
    const CachedHull& linkHull(int element, int source) const;
    bool lightMeetsBall(int element, int light, const Ball& ball) const;
    bool farLightMeetsBall(int element, int light, const Ball& ball) const;
    // lightMeetsBall() / linkMeetsBall() for pair i of an object's cache, the hull's planes found once.
    bool cachedPairMeets(ObjectState& obj, std::size_t i, const Ball& ball, double* clearance = nullptr) const;
    ObjectState::PairShaft pairShaft(int element, int what) const;
    double radiusOf(int element) const { return shape[static_cast<std::size_t>(element)].radius; }
    // (influence_candidates.cpp)
    void candidates(int object, const Ball& ball, bool scan, std::vector<int>& touched, bool record_links);
    void collectPairs(int object, const Ball& query, bool scan, std::vector<std::pair<int, int>>& pairs);
    double denominator(int element) const;  // B~ (luminance) a change is relative to: floored
    double objectBlocks(int object, int element, double omega) const;  // fraction of a solid angle it can cover
    double objectBlocksFrom(int object, const Eigen::Vector3d& centroid, double omega) const;  // the same, element given by its centroid
    double lightSignificance(int b, int light, int object) const;
    double linkSignificance(int b, int link, int object) const;
    // Their parts that do not depend on the object: significance = share x objectBlocks(omega).
    void lightSignificanceParts(int b, int light, double& share, double& omega) const;
    void linkSignificanceParts(int b, int link, double& share, double& omega) const;
    std::uint32_t objectMask(int b) const;  // objects significant at base leaf b (ray mask bits)
    void select(int b);
    struct LeafResult {
        double variation = 0.0;       // direct light and the objects' own light
        double link_variation = 0.0;  // blocked base links
        bool links = false;           // corrections computed
        // Lights whose pilot found a penumbra: their full estimate waits until the element is
        // known to stay a leaf (a split element's own terms are dropped). (light, pilot transmission)
        std::vector<std::pair<int, double>> deferred;
        long computed = 0, reused = 0;  // answers
    };
    int evaluated = 0, link_evaluated = 0;  // in the last refine()
    long items_computed = 0, items_reused = 0;
    // Direct light and the objects' light (clears every term); `reach` in, `met` out (Reach).
    // `links_open`: c may carry corrections (no element above it does).
    LeafResult computeTerms(int c, int b, bool links_open, const Reach& reach, Reach& met);
    // Corrections; returns their variation.
    double computeLinks(int c, int b, const Reach& met, LeafResult& out);
    double linkSize(int b) const;  // elements of about this size carry the corrections
    // `full`: the full estimate where the pilot finds a penumbra; else the pilot's answer alone.
    double transmissionToLight(int c, int light, bool& mixed, std::uint32_t mask, bool full = true);
    // The deferred full estimates of an element that stays a leaf (LeafResult::deferred).
    void finishDeferred(int c, int b, const LeafResult& r);
    double transmissionToSource(int c, int s, bool& mixed, std::uint32_t mask);
    RealMask& mask(int element, int key);
    void refine(const std::vector<int>& touched);
    void rebuildCorrectionIndex();

    // --- influence_cluster.cpp ---
    void buildNodes(const std::vector<int>& origin, std::size_t first_transfer);
    Shaft nodeShaft(const ClusterNode& node) const;
    Shaft groupShaft(const ClusterNode& node, const ClusterNode::Group& group) const;
    void buildGroups(ClusterNode& node) const;
    bool nodeReached(const ClusterNode& node, const Ball& ball) const;  // a group's shaft meets the ball
    // The node answers the move reached (or never made): their faces found again (before the
    // candidates, which read them). `all`: every node again (a rebuild).
    void refreshNodes(bool all);
    // After the candidates: the transmissions of the nodes a base leaf's entries select (lazily:
    // InfluenceOptions::lazy_cluster_answers), and the base leaves of the faces whose read answer
    // changed added to `touched`.
    void answerNodes(std::vector<int>& touched);
    void nodeFaces(ClusterNode& node) const;  // its mask, transfer_objects, blocked faces and classes now
    void nodeTransmissions(int k, ClusterNode& node) const;  // from its blocked_classes (its pairs made first)
    void nodeHulls(ClusterNode& node) const;
    void nodePairs(int k, ClusterNode& node) const;
    // The node a base link reads its answer from when they are shared (nullptr: its own). (Here:
    // the candidates and the corrections ask it for every link.)
    const ClusterNode* sharedNode(int link) const {
        if (static_cast<std::size_t>(link) >= link_node.size() || !self.options_.share_cluster_links) return nullptr;
        const int k = link_node[static_cast<std::size_t>(link)];
        return k >= 0 ? &nodes[static_cast<std::size_t>(k)] : nullptr;
    }

    // --- influence_objects.cpp ---
    void placeObject(int o, const InfluenceObject& in);
    void objectRadiance(int o);
    void clusterLinks(int o, std::vector<int>& leaf_level);
    void removeClusterLinks(int o);
    Eigen::Vector3d clusterAt(int o, int element, double* variation, std::uint32_t mask);  // irradiance; variation of rho F L / B~
    double pointFormFactor(int o, const Eigen::Vector3d& x, const Eigen::Vector3d& n, Eigen::Vector3d* radiance) const;
    // Fraction of pairs left open; the element's hidden pairs kept in `hidden` (may be null; its
    // RealMask for object o, clusterMaskKey(o): pilot_hidden for 4 pairs, full_hidden for 16).
    double clusterVisibility(int o, int element, int pairs, bool& mixed, std::uint32_t mask, RealMask* hidden) const;
    static int clusterMaskKey(int o) { return std::numeric_limits<int>::min() + o; }

    // --- influence_solve.cpp ---
    Eigen::Vector3d value(int leaf) const;
    void addUnshot(int element, const Eigen::Vector3d& delta);
    Eigen::Vector3d pushDown(int element, const Eigen::Vector3d& irradiance);
    Eigen::Vector3d pushDownIn(const Element* els, int element, const Eigen::Vector3d& irradiance, double tau, double dirty);
    void propagateUp(int element, Eigen::Vector3d delta);
    void pullSubtree(int element);
    void propagate(InfluenceStats& stats);
    void resync();
    void finish();
};

}  // namespace commonlight::lighting

// What the virtual objects change in the real scene's radiosity, kept up to date incrementally as
// they move, appear, disappear or change emission (Lighting II; seed 000 sec. 4.2-4.4 and 6.2).
//
// The real scene's solution B~ (lighting/radiosity.h: links, direct light, push-pull) is the
// *base*; it does not depend on the virtual objects. With them, every real leaf c has
//     B_c = B~_c + D_c,   D_c = rho_c / pi * ( dDirect_c + sum_{a above c} (G_a + V_a) + C_c )
// where, in irradiance units (W/m^2, relative):
//   dDirect_c  the direct light the objects take away: sum_k E_k col_k(c) (t_k(c) - 1), t_k the
//              virtual transmission of the shaft between c and light k (lighting/direct.h columns)
//   G_a        what element a gathers through its base links from the sources' differences:
//              sum_links w D_s, w = pi F V (the base link's transfer)
//   C_c        the change a virtual object makes to a base link that reaches c through a shaft it
//              blocks: sum w (t(c, s) - 1) (B~_s + D_s), t the transmission from c to the link's
//              source (a *correction*: the base link stays, so D = 0 wherever nothing blocks)
//   V_a        light the virtual objects send (reflected or emitted), as *cluster* links: each
//              object is one source whose radiance towards a receiver is its faces' radiance
//              averaged over their projected area in that direction (faces lit by order-2 SH
//              irradiance at the object's centre, from B~ and the lights), so a detailed mesh
//              does not multiply links. Close receivers see its faces one by one.
// Internal elements hold the area-weighted mean of their children's D (push-pull on differences).
// The base links are the element links and, where real proxies are clustered, the cluster links
// taken as the element links they are linear in (Radiosity::clusterTransfers()). A cluster link
// that lights a proxy's faces is one node for its faces' transfers: one shaft test and one
// transmission per class of the faces it blocks, shared by them (lighting/influence_cluster.cpp).
//
// Incremental update (seed 000 sec. 4.4): a moved object's old and new bounding balls are looked
// up in a shaft index (lighting/shaft_index.h) over the base links and the light shafts of the base
// leaves; only the base leaves whose shafts meet them are walked again, and in them only the answers
// (a light's transmission, a blocked link's, an object's own light, at an element) whose shaft met
// the moved objects' old or new bounds are computed again (the others give what they gave); the
// refinement follows from the answers, the object's cluster links are rebuilt, and the change is
// propagated from there by shooting (Southwell): unshot differences above the residual bound go
// through the links that leave their element, to the receivers and down to their leaves, until
// none is left. A fresh solve is the same computation with every object new and D = 0, and
// denseDifference() solves the same system by plain Jacobi sweeps: the tests compare the three.
//
// Refinement follows the influence (seed 000 sec. 4.4, 6.2: a partially visible link too high in
// the hierarchy gives a "spread shadow"): a leaf whose light is blocked in part (a penumbra, a
// shadow's edge across it; not when the direct light is drawn per texel), or whose form factor to a virtual emitter varies across it, is split
// while the ratio B/B~ may vary across it by more than `refine_epsilon`, down to the size of
// `footprint_pixels` pixels of the camera (and never below `min_size`): an element never needs to
// be much smaller than the pixels it covers. These elements lie under the base leaves; when the
// influence goes away they are collapsed (lighting/hierarchy.h keeps them for the next time), so
// the element count follows the objects.
//
// Threads: every call on the lighting thread (the Embree scene edits included); internally
// parallel (TBB).
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "core/camera_model.h"
#include "core/pose.h"
#include "core/result.h"
#include "lighting/direct.h"
#include "lighting/radiosity.h"
#include "lighting/shaft_index.h"
#include "lighting/snapshot_builder.h"

namespace commonlight::lighting {

struct InfluenceOptions {
    double refine_epsilon = 0.02;   // a leaf is split while B/B~ may vary across it by more than this
    double link_epsilon = 5e-3;     // per base leaf, the largest total change of B/B~ left out (the weakest
                                    // blocked links and lights, the faintest virtual light)
    double min_size = 0.01;         // metres: the smallest element (and the split pattern's minimum)
    double footprint_pixels = 2.0;  // an element need not be smaller than this many of the camera's pixels
    double shaft_margin = 0.12;     // metres: the shafts near a moving object are kept for moves within this (the
                                    // cache refreshed every 24 moves of 5 mm; 0.03 refreshed it every 6 moves, the
                                    // room p95 then 42 ms CPU instead of 19)
    double link_size = 0.08;        // metres: blocked base links are corrected on elements about this size (or
                                    // twice the camera's resolution), and everything under them
    int max_leaves = 8000;          // leaf budget, real and virtual, base included
    int pilot_pairs = 16;           // visibility pairs per leaf and light (a pilot) ...
    int partial_pairs = 64;         // ... and when the pilot finds a penumbra
    int link_pairs = 16;            // per leaf and blocked link
    // A clustered real proxy's faces receiving through one cluster link (Radiosity::clusterTransfers()):
    // one shaft test per link and one transmission per class of the faces it blocks, shared, from
    // the pairs among 16 x link_pairs over its faces that fall on them (false: one transmission per
    // face and link).
    bool share_cluster_links = true;
    // Such a link's faces tested in groups of neighbours (a group's shaft first: one test for the
    // group where an object's bounds miss it, and a move that meets no group's shaft keeps the
    // link's answer); false: every face's shaft tested, and any move that meets the link's shaft
    // answers it again. The same answers either way (test SharedClusterAnswersGroupedEqualPerFace).
    bool group_cluster_faces = true;
    // Such a link's transmissions (its virtual rays) made only while a base leaf's entries select
    // one of its transfers (nothing else reads them; its blocked faces, which the candidates read,
    // at every move that reaches it); false: at every move that reaches it. The same answers where
    // read either way (test LazyClusterAnswersEqualEager). Off: in the `cluster` case nearly every
    // link a move reaches is read, and finding which costs more than the rays it saves.
    bool lazy_cluster_answers = false;
    // An object's cached (base leaf, link or light) pairs left alone at a move while it cannot
    // have come close enough to change their answer: a pair not kept stays out while the ball's
    // centre has travelled less than the distance by which its significance or its shaft missed,
    // a shaft the ball met stays met while it has travelled less than how deep it met (test
    // CachedPairsLeftAloneKeepTheCandidates). False: every pair tested at every move.
    bool idle_cached_pairs = true;
    // A blocked base link's open pairs (points, normals, kernel weights) kept per element and
    // source from its first answer, so a re-answer traces the virtual rays alone (the same sums;
    // test CachedLinkPointsEqualFresh). False: the points made again at every answer.
    bool cache_link_points = true;
    // The area lights' direct light is drawn per texel where the objects change it
    // (lighting/texel_direct.h): the elements' own direct transmission only feeds D's share that
    // others receive, so a penumbra splits no element and takes the pilot's estimate.
    bool direct_per_texel = false;
    int texel_link_pairs = 8;       // link_pairs then (ratio RMS within 0.001 of 16's on the desk and the room)
    int object_directions = 128;    // rays for a virtual object's irradiance
    double residual = 1e-4;         // propagation stops when no unshot difference exceeds this x the largest radiance
    std::uint64_t seed = 11;
};

// A light as the influence sees it: the estimator's source and its real column (by element: the
// influence computes the column of the elements it makes), and its emission.
struct InfluenceLight {
    const DirectSource* source = nullptr;
    DirectColumn* column = nullptr;
    Eigen::Vector3d emission = Eigen::Vector3d::Zero();  // relative units, per unit of the column
};

// The base solution (B~) and what it was made of, by element index.
struct InfluenceBase {
    std::vector<InfluenceLight> lights;
    std::vector<Eigen::Vector3d> rho;        // reflectance (real leaves read; new elements inherit their base leaf's)
    std::vector<Eigen::Vector3d> emission;   // Le of real leaves (relative)
    std::vector<Eigen::Vector3d> radiance;   // B~ (every element; pulled above leaves)
    std::vector<Eigen::Vector3d> indirect;   // B~'s gathered irradiance at leaves
    double radiance_scale = 1.0;             // relative radiance per W/(m^2 sr) (virtual emission is in scene units)
    DirectOptions direct;                    // how the columns were computed (for the elements made here)
};

// A virtual object as the influence sees it (by Scene::virtual_objects index).
struct InfluenceObject {
    Rigid3d world_from_object;
    bool present = true;
    std::optional<Eigen::Vector3d> emission;  // scene units (W/(m^2 sr)); nullopt: the scene's
};

// The camera the refinement works for (the resolution it needs).
struct InfluenceViewer {
    CameraModel camera;
    Rigid3d cam_from_world;
};

struct InfluenceStats {
    double ms_total = 0.0;
    double ms_candidates = 0.0;  // Embree poses, shaft queries, cluster links
    double ms_refine = 0.0;      // the recomputed base leaves: transmissions, corrections, splits
    double ms_solve = 0.0;       // propagation (or the dense solve)
    int moved = 0;               // objects that changed
    int touched = 0;             // base leaves recomputed
    int evaluated = 0;           // elements whose terms were computed (every level of the recomputed base leaves)
    int link_evaluated = 0;      // of them, with the corrections of blocked links
    long answers_computed = 0;   // items (a light, a blocked link, an object's light at an element) answered again
    long answers_kept = 0;       // items whose last answer stood (no moved object's old or new bounds in the shaft)
    long pairs_tested = 0;       // the moved objects' cached (base leaf, link or light) pairs tested (significance, shaft)
    long hulls_made = 0;         // hulls of (element, source) pairs found (the others kept, also through a new base)
    int leaves = 0;              // real leaves in use (base and refined)
    int refined = 0;             // of them, under the base leaves
    int corrections = 0;         // blocked base links corrected at leaves
    int cluster_links = 0;       // links from the virtual objects to real elements
    int shafts = 0;              // in the index
    int rounds = 0;              // propagation rounds
    int shots = 0;               // elements shot
    std::size_t stored = 0;      // elements stored (active and retired)
    double residual = 0.0;       // largest unshot difference left, over the largest radiance
};

class VirtualInfluence {
public:
    VirtualInfluence(Radiosity& radiosity, RayScene& rays, const InfluenceOptions& options);
    ~VirtualInfluence();
    VirtualInfluence(const VirtualInfluence&) = delete;
    VirtualInfluence& operator=(const VirtualInfluence&) = delete;

    InfluenceOptions& options() noexcept { return options_; }

    // Makes the hierarchy the base's again: every element made here is collapsed. Call before
    // changing the base (refinement by light or observations, links) and before setBase().
    void collapseAll();
    // A new base (after a full update of B~): indexes its links and light shafts, forgets every
    // influence. The next update() computes everything.
    Result<void> setBase(InfluenceBase base);
    bool hasBase() const noexcept { return has_base_; }

    // The objects now (by virtual object index) and the camera: recomputes what changed and
    // propagates. `viewer` nullopt: no camera, elements down to min_size. `committed`, if given, is
    // called once the objects are committed at their new poses in the RayScene and movedBalls() is
    // this update's (before the candidates): from then on until update() returns, the RayScene is
    // only read, so work that needs the new poses (the textures' direct light) may run beside it.
    Result<InfluenceStats> update(const std::vector<InfluenceObject>& objects, const std::optional<InfluenceViewer>& viewer,
                                  const std::function<void()>& committed = {});
    // The same from nothing: every object new, candidates by a scan of every shaft (no index),
    // and B solved by dense Jacobi sweeps. What a full re-solve would do; the same answer.
    Result<InfluenceStats> rebuild(const std::vector<InfluenceObject>& objects, const std::optional<InfluenceViewer>& viewer);

    // By element: B (real leaves B~ + D, pulled above; virtual faces' radiance), B~ (elements made
    // here: their own direct light, their base leaf's indirect), D = B - B~.
    const std::vector<Eigen::Vector3d>& radiance() const noexcept { return radiance_; }
    const std::vector<Eigen::Vector3d>& original() const noexcept { return tilde_; }
    const std::vector<Eigen::Vector3d>& difference() const noexcept { return d_; }
    // Reflectance by element (base leaves' and their refinements').
    const std::vector<Eigen::Vector3d>& reflectance() const noexcept { return rho_; }
    // The same system solved by Jacobi sweeps from D = 0, to `tolerance` x the largest radiance:
    // the reference the propagation is tested against. Does not change the state.
    std::vector<Eigen::Vector3d> denseDifference(double tolerance = 1e-9) const;
    // Real faces whose leaves changed (values or elements) in the last update.
    const std::vector<int>& changedFaces() const noexcept { return changed_faces_; }
    const InfluenceStats& stats() const noexcept { return stats_; }
    // Whether an element was made by the influence's refinement (under a base leaf).
    bool refinedElement(int element) const;
    // What the objects do to one leaf (irradiance, relative units): the direct light they take
    // away, their own light at leaf level, the corrections of blocked base links (count and the
    // sum of w (t - 1)). For tests and the benchmark's breakdown.
    struct LeafInfo {
        Eigen::Vector3d direct = Eigen::Vector3d::Zero();
        Eigen::Vector3d cluster = Eigen::Vector3d::Zero();
        int corrections = 0;
        double correction_sum = 0.0;
    };
    LeafInfo leafInfo(int leaf) const;
    // leafInfo(leaf).direct alone (the textures ask it of every element at every update).
    Eigen::Vector3d leafDirect(int leaf) const;
    // Each present virtual object's bounding ball, world.
    std::vector<Ball> objectBalls() const;
    // The last update's moves: the old and new bounds of the objects whose pose or presence changed.
    const std::vector<Ball>& movedBalls() const;
    // Per cluster link that lights a clustered proxy's faces (share_cluster_links), its current
    // answer: the faces it blocks with their class, and each class's transmission. For tests.
    struct ClusterLinkInfo {
        std::vector<std::pair<int, int>> blocked_faces;  // (face, class), sorted
        std::array<double, 3> transmission{1.0, 1.0, 1.0};
        bool known = true;  // the transmissions made for the faces now (lazy_cluster_answers: only where read)
    };
    std::vector<ClusterLinkInfo> clusterLinkInfo() const;

    struct Impl;

private:
    Radiosity& radiosity_;
    RayScene& rays_;
    InfluenceOptions options_;
    bool has_base_ = false;
    std::vector<Eigen::Vector3d> radiance_;
    std::vector<Eigen::Vector3d> tilde_;
    std::vector<Eigen::Vector3d> d_;
    std::vector<Eigen::Vector3d> rho_;
    std::vector<int> changed_faces_;
    InfluenceStats stats_;
    std::unique_ptr<Impl> impl_;
};

}  // namespace commonlight::lighting

// Hierarchical radiosity over the proxies and the virtual objects (Hanrahan, Salzman and Aupperle
// 1991; seed 000 sec. 4), with Embree visibility.
//
// Quantities (lighting/snapshot.h: relative units): L radiance of a Lambertian element
// (W/(m^2 sr)), H irradiance (W/m^2), rho reflectance in [0, 1). Per element i:
//     L_i = Le_i + rho_i / pi * (D_i + H_i),   H_i = pi * sum_j F_ij V_ij L_j
// D_i the direct irradiance from the lights (lighting/direct.h), F_ij the element-to-element form
// factor from i to j (area average over i of the point-to-polygon form factor: lighting/form_factor.h)
// and V_ij the fraction of jittered rays between them that are not blocked. Links connect
// elements at the level the refinement oracle allows; a link's gather goes to its receiver's
// level and push-pull carries it to the leaves (push: irradiance down, pull: area-weighted
// radiance up).
//
// The links are the real scene's (visibility through the real proxies only): their solve is B~.
// What the virtual objects change (they block, reflect and emit) is lighting/influence.h's: it
// keeps B - B~ on these links and elements, and updates it incrementally as objects move.
// `Mode::kAll` adds the virtual objects' leaves to the leaves a solve covers (they have no links:
// their radiance is their emission plus reflected direct light).
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "core/pose.h"
#include "core/result.h"
#include "lighting/form_factor.h"
#include "lighting/hierarchy.h"
#include "lighting/proxy_geometry.h"
#include "lighting/ray_scene.h"
#include "lighting/snapshot.h"

namespace commonlight::lighting {

struct RadiosityOptions {
    // Link refinement (directed: a receiver gathers from a source). A receiver is split while the
    // point form factor to the source varies over it by more than this, times the source's largest
    // radiance relative to the scene's largest (setSourceRadiance(); the gathered irradiance is
    // pushed down as if uniform). Smaller: more links, more accuracy.
    double link_epsilon = 0.01;
    // A source is split while (its form factor from the receiver) x (the spread of its radiance,
    // relative to the scene's largest) exceeds this: the BF oracle of Hanrahan et al. 1991 on the
    // source side (setSourceRadiance() gives the radiance; without it every source counts as varying fully).
    double source_epsilon = 0.002;
    // A source seen in part (a shadow boundary across the link) is split while the form factor to
    // it exceeds link_epsilon x this factor.
    double partial_visibility_factor = 1.0;
    double min_element_size = 0.01;  // metres: elements are not split below this (shadows, observations)
    double min_link_size = 0.15;     // metres: link refinement creates no element smaller than this
                                     // (it descends into existing smaller ones) ...
    double gap_resolution = 2.0;     // ... except between facing parallel elements closer than that
                                     // (narrow gaps): down to this times their separation
    // Shelter: the fraction of a point's (cosine-weighted) hemisphere that meets a real surface within
    // shelter_distance metres (the wall behind a cabinet: nearly 1; an open floor: 0). A receiver
    // whose points' shelter varies by more than shelter_epsilon takes no link (it is split): a link
    // pushes its irradiance down as uniform, and would light the sheltered part like the open one.
    double shelter_distance = 0.25;
    double shelter_epsilon = 0.5;
    double shelter_resolution = 0.1;  // metres: such receivers may be split below min_link_size, down to this
    // Consistency of the links: a leaf gathers through its own links and its ancestors'; the sum
    // of their F x V is the fraction of its hemisphere that meets real faces, which shelter rays
    // measure. Where the two differ by more than this (a link at a coarse level pushes down a
    // visibility its leaf does not have), the ancestors' links are moved one level down, up to
    // consistency_rounds times.
    double consistency_tolerance = 0.1;
    int consistency_rounds = 8;
    int max_elements = 8000;         // leaf budget
    int visibility_rays = 4;         // jittered rays per link (16 where its pilot finds it partly blocked or the receiver partly hidden)
    bool hierarchical = true;        // false: every pair of leaves linked (the uniform-grid gather baseline)
    // Clustering of small real proxies (Smits et al. 1994; lighting/radiosity_cluster.cpp): a real
    // object with at least cluster_min_faces faces (a mesh, a real sphere's 320 triangles), or
    // with a bounding radius of at most cluster_small_radius metres, whose bounding radius is at
    // most cluster_max_fraction of the scene's, exchanges light with everything else through one
    // cluster: as a source, its faces' exitance by direction; as a receiver, the incident light by
    // direction pushed to each face by its own cosine. A link opens the cluster into its faces
    // when its receiver (or source) is closer than cluster_distance radii, or when the form
    // factor's variation over the cluster's extent, times the radiance, exceeds link_epsilon.
    // cluster_min_faces = 0: no clustering (every face linked on its own). On by default (24, the
    // setting the tests and `bench lighting --cases cluster` use): a detailed real mesh must not
    // multiply the links (a 320-face proxy: 27x fewer, the setup halved), though a move of a
    // virtual object beside a clustered proxy costs more than beside the same proxy unclustered
    // (docs/lighting.md, `cluster` case); a box (6 faces) is not clustered by its faces.
    int cluster_min_faces = 24;
    double cluster_small_radius = 0.0;
    double cluster_max_fraction = 0.25;
    double cluster_distance = 2.0;
    double residual = 1e-4;          // stop when the largest radiance change of an iteration is below this fraction of the largest radiance
    int max_iterations = 2000;
    std::uint64_t seed = 1;          // of every jittered sample
};

enum class Mode : std::uint8_t { kReal, kAll };

// A link through a cluster (RadiosityOptions::cluster_min_faces). `kind` kSource: element
// `element` gathers from cluster `cluster`: its irradiance is weight x vis x the cluster's mean
// radiance towards direction bin `bin` (weight: the receiver's mean of sum over the cluster's faces
// of A_f cos_f cos_r / d^2). kReceiver: cluster `cluster` gathers from element `element`: each face
// f of it receives vis x L_element x max(0, n_f . dir), dir the unit direction from the cluster's
// centre to the source times its solid angle's cosine-weighted measure (the source's mean of
// A_s cos_s / d^2), taken at the face's centroid to first order (`grad`).
struct ClusterLink {
    enum class Kind : std::uint8_t { kSource, kReceiver };
    Kind kind = Kind::kSource;
    int cluster = 0;
    int element = 0;
    int bin = 0;
    float weight = 0.0f;
    float vis_real = 1.0f;
    Eigen::Vector3f dir = Eigen::Vector3f::Zero();
    Eigen::Matrix3f grad = Eigen::Matrix3f::Zero();  // kReceiver: d dir / d x at the centre (faces off the centre)
};

struct Link {
    int receiver = 0;
    int source = 0;
    float form_factor = 0.0f;  // F(receiver -> source), area average over the receiver
    float vis_real = 1.0f;     // unblocked fraction (kernel-weighted), real occluders
    std::uint16_t real_blocked = 0;  // which of the jittered samples the real scene blocks
    std::uint8_t samples = 0;
};

// A solution: radiance per element (every level), irradiance per leaf.
struct Solution {
    std::vector<Eigen::Vector3d> radiance;    // L, by element index
    std::vector<Eigen::Vector3d> irradiance;  // D + H at leaves (zero elsewhere)
    std::vector<Eigen::Vector3d> indirect;    // H at leaves: the part gathered through links
    SolveSummary summary;
};

class Radiosity {
public:
    // Faces: the real ones (world) and the virtual ones (object frames) with their object index.
    // `rays` must outlive this object; its virtual poses are the caller's (setVirtualPoses here
    // poses the faces, the caller poses the Embree instances).
    Radiosity(std::vector<Face> real_faces, std::vector<Face> virtual_faces, std::vector<double> sphere_radius,
              const RayScene& rays, RadiosityOptions options);

    const RadiosityOptions& options() const noexcept { return options_; }
    void setOptions(const RadiosityOptions& options) { options_ = options; }

    // Poses the virtual faces (by virtual object index).
    void setVirtualPoses(const std::vector<Rigid3d>& world_from_object);
    const std::vector<Rigid3d>& virtualPoses() const noexcept { return poses_; }
    // A virtual object's exact sphere radius (0: not a sphere).
    double sphereRadius(int object) const { return sphere_radius_[static_cast<std::size_t>(object)]; }

    Hierarchy& hierarchy() noexcept { return hierarchy_; }
    const Hierarchy& hierarchy() const noexcept { return hierarchy_; }
    std::size_t realFaceCount() const noexcept { return real_count_; }
    bool isVirtualFace(int face) const noexcept { return static_cast<std::size_t>(face) >= real_count_; }
    bool isVirtualElement(int element) const { return isVirtualFace(hierarchy_[element].face); }
    int virtualObjectOfFace(int face) const { return faces_[static_cast<std::size_t>(face)].object_index; }
    // The face as placed now (virtual faces at their pose).
    const Face& face(int f) const { return posed_[static_cast<std::size_t>(f)]; }
    ElementGeometry geometry(int element) const { return Hierarchy::geometry(hierarchy_[element], face(hierarchy_[element].face)); }
    // A point of an element at (a, b) of its own parametrisation, on the surface that blocks rays
    // (virtual spheres: pushed out onto the exact sphere).
    Eigen::Vector3d surfacePoint(int element, double a, double b) const;
    // The same with the element's geometry() given (a loop over many samples of one element).
    Eigen::Vector3d surfacePoint(int element, const ElementGeometry& g, double a, double b) const;
    // A point of an element's flat polygon moved onto the surface that blocks rays (identity except
    // for virtual spheres, whose facets lie inside the exact sphere).
    Eigen::Vector3d onSurface(int element, const Eigen::Vector3d& x) const;
    const RayScene& rays() const noexcept { return *rays_; }
    // Whether a point of an element lies inside another real box or is pressed against another
    // real face (under a cabinet standing on the floor, under the books lying on the desk, the
    // bottom of a leg standing on the floor plane): no surface there. Always false for elements
    // markBuried() found wholly exposed, and for virtual elements.
    bool hidden(int element, const Eigen::Vector3d& x) const;
    // The fraction of an element's area outside other boxes (1 until markBuried() measured it).
    double exposure(int element) const;
    // An element's shelter (RadiosityOptions::shelter_distance): its mean, and the lowest and
    // highest over its points (over its leaves' points for a parent). Measured on first use (16
    // points x 8 rays per leaf) and kept: geometry does not change.
    struct Shelter {
        float mean = -1.0f;
        float lo = -1.0f;
        float hi = -1.0f;
        float hit = -1.0f;  // the fraction of the hemisphere that meets a real face at any distance
        bool known() const { return mean >= 0.0f; }
    };
    Shelter shelter(int element);
    // Measures the shelter of every real leaf not yet measured (in parallel).
    void measureShelters();
    // A Gauss rule over the element's exposed part: of the given order for an element wholly
    // exposed; for one partly inside a box the order-8 rule with its hidden points dropped and the
    // weights renormalised (hard case: if every point is hidden, the plain order-8 rule).
    std::vector<QuadraturePoint> exposedRule(int element, int order) const;

    // Step 1: the initial mesh: real faces split until no element is larger than `size` metres
    // (within the budget); virtual faces once to `virtual_size`.
    void subdivideTo(double size, double virtual_size);
    // Measures how much of each new leaf lies inside another real box (a box resting on a table:
    // its bottom and the table under it). A leaf wholly inside is buried: it neither receives nor
    // sends light; one partly inside keeps its exposed fraction, and its light is that of its
    // exposed part (form factors, visibility and direct light are integrated over the exposed part
    // alone, and its radiance counts by its exposed area when pulled up the hierarchy). Call after
    // subdividing; buried leaves stay buried.
    void markBuried();
    // The same for one leaf alone (its parents are left as they are): for elements made later
    // (lighting/influence.h's refinement under the real scene's leaves).
    void measureExposure(int leaf);

    // An estimate of each leaf's radiance (direct light x a nominal reflectance is enough) for the
    // oracles: each node's largest radiance and spread of radiance, relative to the scene's
    // largest (virtual elements count as the brightest). Call before buildRealLinks(); elements
    // created later take their parent's values.
    void setSourceRadiance(const std::vector<double>& radiance);

    // Step 2: links among real elements (F, V_real) by the refinement oracle. Clears every link.
    void buildRealLinks();

    // The solve: Jacobi gathering over links with push-pull, to options().residual.
    // rho, emission and direct are indexed by element (only leaves are read); emission is Le.
    Solution solve(Mode mode, const std::vector<Eigen::Vector3d>& rho, const std::vector<Eigen::Vector3d>& emission,
                   const std::vector<Eigen::Vector3d>& direct) const;
    // Irradiance gathered through links by one leaf from given element radiances (one gather,
    // no iteration): inverse radiosity (seed 003 sec. 5.2) uses it with observed radiances.
    std::vector<Eigen::Vector3d> gatherIndirect(Mode mode, const std::vector<Eigen::Vector3d>& radiance) const;

    // Links: element links plus cluster links.
    int linkCount(Mode mode) const;
    const std::vector<Link>& links() const noexcept { return links_; }
    const std::vector<ClusterLink>& clusterLinks() const noexcept { return cluster_links_; }
    // The cluster links as the element links they are linear in, so that what works on links (the
    // virtual objects' influence: shooting differences, correcting blocked links) works on them.
    // A kSource link is one link per face that sees its bin, from the face's root to the element,
    // weighted by the face's share of the bin's projected area; a kReceiver link is one link per
    // face that faces it, from the element to the face's root, weighted by max(0, n_f . (dir +
    // grad offset_f)) (the solve clamps the sum of a bin's links instead: the same unless links of
    // one bin light a face from both sides). form_factor x pi x vis_real is the transfer; the
    // links' real_blocked and samples are not set. `origin`: for each transfer, the index of the
    // cluster link (clusterLinks()) it comes from.
    std::vector<Link> clusterTransfers(std::vector<int>* origin = nullptr) const;
    // A cluster's bounding ball (centre, radius), world.
    std::pair<Eigen::Vector3d, double> clusterBall(int cluster) const;
    // Clusters made by buildRealLinks() (RadiosityOptions::cluster_min_faces): the real object of each.
    std::vector<int> clusterObjects() const;
    // Leaves in use for a mode (not buried; virtual leaves only in kAll).
    std::vector<int> leaves(Mode mode) const;
    // Pull: fills non-leaf radiances as area-weighted means of their children.
    void pull(std::vector<Eigen::Vector3d>& radiance) const;

private:
    // A small real proxy as one node (lighting/radiosity_cluster.cpp).
    struct Cluster {
        int object = -1;
        std::vector<int> faces;  // face indices
        Eigen::Vector3d centre = Eigen::Vector3d::Zero();
        double radius = 0.0;
        double peak = 1.0;                 // largest radiance of its faces / the scene's
        std::vector<double> projected;     // per direction bin: sum of A_f exposure max(0, n_f . w_b)
        // The same by face: (bin, A_f exposure cos) for every bin a face sees (its exitance's share).
        std::vector<std::vector<std::pair<int, float>>> face_bins;
    };
    void makeClusters();
    int clusterOfFace(int face) const;
    void refineFromCluster(int receiver, int cluster, int depth);
    void refineToCluster(int cluster, int source, int depth);
    void openCluster(int receiver, int cluster, int depth);
    void computeClusterLink(ClusterLink& link) const;
    double clusterKernel(int cluster, const Eigen::Vector3d& x, const Eigen::Vector3d& normal) const;
    double clusterVisibility(int cluster, int element, const Eigen::Vector3d& towards, std::uint64_t seed) const;
    void finishClusterLinks();
    // Adds what the cluster links gather (irradiance at face roots and elements) to `gathered`.
    void gatherClusters(const std::vector<Eigen::Vector3d>& radiance, std::vector<Eigen::Vector3d>& gathered) const;
    // Adds each element's F x V through cluster links to `own` (enforceConsistency()).
    void clusterFormFactors(std::vector<double>& own) const;

    void refine(int receiver, int source, int depth);
    double sourceStat(const std::vector<double>& stat, int element) const;
    void addLink(int receiver, int source);
    std::vector<Link> takePendingLinks();  // computes F and V of the pending pairs
    void computeLink(Link& link) const;
    bool facing(int a, int b) const;
    void sortLinks();

    // Real boxes (six parallelogram faces) as inward half-spaces, for hidden().
    struct BoxPlanes {
        int object = -1;
        std::array<Eigen::Vector3d, 6> origin;
        std::array<Eigen::Vector3d, 6> normal;
    };
    // Real faces for contact tests (a box standing on a plane).
    struct ContactFace {
        int object = -1;
        Eigen::Vector3d origin;
        Eigen::Vector3d normal;
        Eigen::Matrix<double, 2, 3> dual;  // world offset -> face (s, t)
        bool triangle = false;
    };
    // Inside another real box, or pressed against another real face (normal opposite, no distance).
    bool insideOtherBox(const Eigen::Vector3d& x, const Eigen::Vector3d& normal, int own_object) const;

    Shelter measureShelter(int element) const;
    void enforceConsistency();

    std::vector<BoxPlanes> boxes_;
    std::vector<ContactFace> contact_faces_;
    std::vector<Shelter> shelter_;  // by element
    std::vector<Face> faces_;  // real (world) then virtual (object frame)
    std::vector<Face> posed_;  // real then virtual (world)
    std::vector<double> sphere_radius_;  // per virtual object; 0: not a sphere
    std::size_t real_count_ = 0;
    const RayScene* rays_;
    RadiosityOptions options_;
    Hierarchy hierarchy_;
    std::vector<Rigid3d> poses_;
    std::vector<Link> links_;            // sorted by receiver
    std::vector<int> link_offsets_;      // CSR over elements: links_[offsets[e], offsets[e+1]) have receiver e
    std::vector<std::pair<int, int>> pending_pairs_;  // during refinement
    std::vector<double> source_range_;                // per element: radiance spread / scene maximum
    std::vector<double> source_peak_;                 // per element: largest radiance under it / scene maximum
    std::vector<Cluster> clusters_;
    std::vector<int> face_cluster_;                   // per face: its cluster, or -1
    std::vector<ClusterLink> cluster_links_;
    std::vector<ClusterLink> pending_cluster_links_;
};

}  // namespace commonlight::lighting

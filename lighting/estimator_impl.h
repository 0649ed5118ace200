// Internal state of lighting/estimator.h, shared by estimator.cpp (creation, observation, the
// known-everything solve), estimator_update.cpp (the full update) and estimator_snapshot.cpp (the
// influence brought up to date, the snapshot, the analyses). Not part of the module's interface.
#pragma once

#include <chrono>
#include <map>
#include <memory>
#include <numbers>
#include <optional>
#include <string>
#include <vector>

#include "lighting/estimator.h"
#include "lighting/influence.h"
#include "lighting/snapshot_builder.h"
#include "lighting/texel_direct.h"

namespace commonlight::lighting {

namespace estimator_detail {

inline constexpr double kPi = std::numbers::pi;

// Milliseconds since `start` added to `total` when the scope ends.
class ScopedMs {
public:
    explicit ScopedMs(double& total) : total_(total), start_(std::chrono::steady_clock::now()) {}
    ~ScopedMs() {
        total_ += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start_).count();
    }
    ScopedMs(const ScopedMs&) = delete;
    ScopedMs& operator=(const ScopedMs&) = delete;

private:
    double& total_;
    std::chrono::steady_clock::time_point start_;
};

inline double luma(const Eigen::Vector3d& v) { return 0.2126 * v.x() + 0.7152 * v.y() + 0.0722 * v.z(); }

// Whether a surface's mean is a measurement: saturated and near-black pixels are never averaged in,
// and the mean of the others is censored (the brightest of a lamp's pool, the darkest of a shadow,
// missing from it: measured, the lamp came out 5% low). Up to 2% of clipped pixels is sensor
// noise at a bright surface's top (3% noise, clipping 2 sigma above the mean: the mean of the rest
// is 0.2% low); more, and the surface is left out of the fit.
inline bool uncensored(const RadianceStats& s) { return 50u * s.clipped <= s.pixels + s.clipped; }

}  // namespace estimator_detail

// A column of the light model: a light, or one cell of a distant one.
struct Source {
    int light = -1;
    DirectSource direct;
    bool estimate = false;
    Eigen::Vector3d known = Eigen::Vector3d::Zero();  // relative units, when !estimate
    DirectColumn column;
    bool dominant = false;  // the refined direction of a distant light
};

struct Estimator::Impl {
    Scene scene;
    CameraModel camera;
    SceneLightingOptions options;
    std::vector<Face> real_faces;
    std::vector<Face> virtual_faces;
    std::vector<double> sphere_radius;
    std::vector<LightGeometry> light_geometry;  // stable: sources point into it
    std::vector<Source> sources;
    std::vector<char> column_valid;  // per element: every source's column is current
    std::vector<Rigid3d> poses;
    bool poses_changed = true;
    bool mesh_built = false;
    std::uint64_t frames_at_refinement = 0;
    std::vector<int> group_of_object;  // real object -> reflectance group (-1: albedo given)
    int groups = 0;
    std::vector<Eigen::Vector3d> group_albedo;  // last fit, per group
    // Tags: per tag, per source, the unit-emission irradiance at its white ring (real occluders).
    std::vector<std::vector<double>> tag_columns;
    std::vector<int> tag_columns_face;
    // Distant lights: the refined dominant direction (towards the light) and when it was found.
    std::map<int, Eigen::Vector3d> dominant;
    std::map<int, std::uint64_t> dominant_frames;
    Eigen::Vector3d illuminant = Eigen::Vector3d::Ones();
    bool links_from_fit = false;                 // the links were rebuilt with the first fit's lights
    int update_depth = 0;                        // update() calls itself once after rebuilding the links
    std::vector<Eigen::Vector3d> last_emission;  // per source, the last update's (relative units)
    std::vector<std::string> setup_warnings;
    // Lighting II: the virtual objects' influence (B - B~), incremental between full updates.
    std::unique_ptr<VirtualInfluence> influence;
    std::vector<bool> present;                             // by virtual object
    std::vector<std::optional<Eigen::Vector3d>> emission;  // by virtual object: scene units; nullopt: the scene's
    std::optional<Rigid3d> viewer;                         // the camera the refinement works for
    std::uint64_t frames_at_fit = 0;                       // observations when B~ was last solved
    bool force_full = false;
    bool direction_fitted = false;  // a distant light's direction was (re)fitted this full update
    LightingSnapshot last;          // the last full update's snapshot (lights, warnings)
    std::vector<FaceBuild> face_builds;  // by real face: the textures and what their next build keeps
    // The next textures visit every face (a full update: new B~ everywhere). Each face's build is
    // kept through it: its layout, leaves and box filters stand where the leaves did, and only the
    // texels whose leaves' values moved are made again (new emissions move most of them).
    bool textures_all = false;
    std::unique_ptr<TexelDirectCache> texels;               // the area lights' direct light per texel (null: off; renewed at a full update)
    // Per element, the area lights' direct light without the objects (finishUpdate(); made with
    // `texels`: the columns and the lights' emissions stand until the next full update), and the
    // largest channel of any of them.
    std::vector<Eigen::Vector3d> texel_area_without;
    double texel_area_largest = 0.0;
    std::vector<ProbeLight> probe_lights;
    ProbeMemories probe_memories;  // the probes' real hits, kept between full updates (buildProbes())
    std::vector<Eigen::Vector3d> solve_emission;  // Le per element of the last full update
};

}  // namespace commonlight::lighting

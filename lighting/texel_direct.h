// The direct light of the area lights per texel of the modulation textures, where the virtual
// objects change it (issue 12; lighting/snapshot_builder.h TexelDirect). `commonlight bench
// lighting --incremental --direct-analysis` measured per-texel shadow rays better than the
// elements' transmissions for the direct term at the same number of rays (docs/lighting.md): the
// elements keep the indirect light and decide where the objects change the direct light; the
// texels compute it where they do.
//
// A texel's answer is kept while no object that moved had its old or new bounds in the shaft
// between the texel's point and a light (the influence's rule, lighting/influence.h), so a move
// traces the texels it reaches; and of those, only the virtual rays: the form factor and which
// pairs the real scene blocks are kept (the real scene does not change), across full updates too:
// their new emissions are applied to each texel's kept fractions (renew()). Lighting thread only; at() is called in parallel for distinct texels.
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <deque>
#include <mutex>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "lighting/direct.h"
#include "lighting/ray_scene.h"
#include "lighting/shaft_index.h"

namespace commonlight::lighting {

class TexelDirectCache {
public:
    struct Light {
        const LightGeometry* polygon = nullptr;
        Eigen::Vector3d emission = Eigen::Vector3d::Zero();  // relative radiance
    };
    // `pairs`: visibility pairs per texel and light (stratified on the light, kernel-weighted).
    TexelDirectCache(const RayScene& rays, int pairs) : rays_(rays), pairs_(pairs) {}

    // A new set of lights (a full update): every answer goes. `faces`: the real faces (world), which
    // at() takes its texels' points on (texel (i, j) of a w x h layout at s = (i + 0.5) / w,
    // t = (j + 0.5) / h: forget() bounds tiles of texels by them).
    void reset(std::vector<Light> lights, std::vector<Face> faces);
    // Whether `lights` are the cache's polygons in its order and `faces` its faces: then a full
    // update keeps the visibility (renew()) instead of tracing every texel again (reset()).
    bool sameGeometry(const std::vector<Light>& lights, const std::vector<Face>& faces) const;
    // A full update with sameGeometry() lights and new emissions: every answer is made again from
    // its kept visibility, as at() would make it with these emissions (the same sums in the same
    // order); the answers forget() took stay to be traced and on the forgotten lists (the
    // textures that follow keep their layouts and rebuild those texels). The moves since the last
    // textures must have been forgotten first (movedSinceSeen(): a full update's influence starts
    // afresh).
    void renew(std::vector<Light> lights);
    // After an update's textures: the virtual objects as committed now are those the answers stand
    // for. movedSinceSeen(): the balls then and now of every object committed since with another
    // pose or presence (every object before the first seen()).
    void seen();
    std::vector<Ball> movedSinceSeen() const;
    // Before the textures of an update: the answers whose shafts meet any of `moved` go (tested
    // by tiles of texels first: most of a face is far from a move).
    void forget(const std::vector<Ball>& moved);
    // Ahead of the textures, on another thread while the influence is updated (the virtual objects
    // already committed at their new poses): the answers forget() took that the last update's
    // textures asked for (a good guess of what this update's ask for), made again at their kept
    // points. Each stays unread (kept() false) until at() asks for it, which then counts it as
    // traced: the textures, their answers and traced() are what they would be without it.
    void prefetch();
    // The texels of face `face` whose answers went since the last call, appended to `texels`
    // (TexelDirect::forgotten); false when any may have (none taken since the last reset()).
    bool takeForgotten(int face, std::vector<std::uint32_t>& texels);
    // The direct light at point x of texel `texel` of face `face` (layout width x height), facing
    // `normal`: without the virtual objects and with them. Thread-safe for distinct texels.
    void at(int face, std::size_t texel, int width, int height, const Eigen::Vector3d& x, const Eigen::Vector3d& normal,
            Eigen::Vector3d& without, Eigen::Vector3d& with);

    // The answer of texel `texel` of face `face` stands (made, and no move reached it since).
    bool kept(int face, std::size_t texel) const {
        const FaceState& f = faces_[static_cast<std::size_t>(face)];
        return texel < f.entries.size() && f.entries[texel].valid && f.entries[texel].real && !f.entries[texel].prefetched;
    }
    long traced() const noexcept { return traced_; }  // texels traced since the last reset() (statistics)
    // Statistics of prefetch() since the last reset(): answers made ahead, and of them those at() asked for.
    long prefetched() const noexcept { return prefetched_; }
    long prefetchUsed() const noexcept { return prefetch_used_; }

private:
    struct Entry {
        bool valid = false;  // `with` stands (no move reached the texel's shafts)
        bool real = false;   // `without` and the parts below stand (the texel's point is x)
        bool prefetched = false;  // `with` made by prefetch(), not yet asked for
        std::uint32_t asked = 0;  // round_ when at() last asked for it
        Eigen::Vector3d x = Eigen::Vector3d::Zero();
        Eigen::Vector3d without = Eigen::Vector3d::Zero(), with = Eigen::Vector3d::Zero();
    };
    // Per texel and light: what does not depend on the virtual objects.
    struct RealPart {
        double form = 0.0;           // point-to-polygon form factor
        double all = 0.0;            // kernel weight of the pairs
        std::uint64_t blocked = 0;   // pairs the real scene blocks (bit j), or with no weight
        double open = 0.0;           // kernel weight of the pairs it leaves open (summed in order)
        double both = 0.0;           // ... and of those the virtual objects leave open too (while the entry is valid)
    };
    struct FaceState {
        lighting::Face geometry;
        int width = 0, height = 0;
        std::vector<Entry> entries;
        std::vector<RealPart> parts;  // entries x lights
        std::vector<std::uint32_t> gone;  // texels forgotten since the last takeForgotten()
        bool all_gone = true;             // ... or any (a reset() since)
    };
    // The virtual objects' balls as at() widens them (RayScene::virtualBall()), made once per
    // commit of the scene (its virtualStamp()), not at every call.
    struct Balls {
        std::array<Ball, 32> balls;
        std::size_t count = 0;
        bool all = true;  // every object's ball is in `balls`
    };
    const Balls& virtualBalls();

    const RayScene& rays_;
    int pairs_;
    Balls balls_;
    std::atomic<std::uint64_t> balls_stamp_{0};  // the scene's stamp `balls_` was made at (0: none; stamps start at 1)
    std::mutex balls_lock_;
    std::vector<Light> lights_;
    std::vector<double> light_radius_;  // a ball about each light polygon's centre holding it
    std::vector<FaceState> faces_;
    // By face: a change of layout, under `lock`; `layout` (width << 32 | height, 0: none) the
    // layout `entries` has, read first without the lock (calls at the same time ask one layout).
    struct FaceLock {
        std::mutex lock;
        std::atomic<std::uint64_t> layout{0};
    };
    std::deque<FaceLock> locks_;
    std::atomic<long> traced_{0};
    std::uint32_t round_ = 1;  // forget() calls since the last reset(), plus one
    std::atomic<long> prefetched_{0}, prefetch_used_{0};
    std::uint64_t seen_stamp_ = 0;                 // the scene's stamp at the last seen() (0: never)
    std::vector<std::optional<Ball>> seen_balls_;  // by virtual object, then (none: disabled)
};

}  // namespace commonlight::lighting

// What the frames show of the real proxies: per face, a fine grid of cells accumulating the mean
// linear relative radiance of the pixels that see it, over every frame with a pose.
//
// Per frame (add()):
//   Step 1: a ray through every `stride`-th pixel (the camera model's exact lens) finds the first
//           surface among all proxies and virtual objects (so a pixel counts only for the element
//           it really shows: the depth test against all proxies).
//   Step 2: pixels are excluded, never averaged in, when: saturated (a channel >= 250) or near black
//           (every channel <= 4); on a virtual object; on a tag (tags are printed, not the
//           surface's albedo; the white border of each tag is kept apart as a radiometric reference
//           of known albedo); on a face border (a neighbour sample sees another surface: mixed
//           pixels); a specular highlight (seed 002 sec. 4: a local intensity peak, more than 1.5x
//           the median of its neighbourhood on the same face, whose chromaticity moves towards the
//           illuminant's).
//   Step 3: each kept pixel adds its radiance (code -> inverse response -> / (exposure x gain))
//           to its cell with weight cos(viewing angle): a frame that sees a surface face-on counts
//           more than one that grazes it, and cells never seen again keep their value.
//
// Interleaving (`interleave` k > 1, the real-time lighting thread's default): each frame samples
// one of k x k offsets of the lattice of every (k stride)-th pixel, the offsets taken in turn, so
// k x k consecutive frames sample exactly the pixels one frame samples at `stride` alone, for
// 1 / k^2 of the rays and work per frame. The neighbour tests of step 2 are then between samples
// k stride pixels apart (the highlight test's block is 8 x 8 samples either way).
//
// Elements aggregate the cells whose centres they contain (aggregate()).
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "core/camera_model.h"
#include "core/image.h"
#include "core/pose.h"
#include "core/response.h"
#include "core/result.h"
#include "core/scene.h"
#include "lighting/hierarchy.h"
#include "lighting/proxy_geometry.h"
#include "lighting/ray_scene.h"

namespace commonlight::lighting {

// Weighted radiance statistics (relative radiance per channel).
struct RadianceStats {
    double weight = 0.0;                                 // sum of weights
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();       // sum of w L
    Eigen::Vector3d sum_sq = Eigen::Vector3d::Zero();    // sum of w L^2
    std::uint32_t pixels = 0;
    // Pixels left out as saturated or near black. Their neighbours' mean is censored (the brightest
    // of a lamp's pool, the darkest of a shadow, are missing from it): a surface with any is not
    // measured by its mean.
    std::uint32_t clipped = 0;

    void add(const Eigen::Vector3d& radiance, double w) {
        weight += w;
        sum += w * radiance;
        sum_sq += w * radiance.cwiseProduct(radiance);
        ++pixels;
    }
    void merge(const RadianceStats& o) {
        weight += o.weight;
        sum += o.sum;
        sum_sq += o.sum_sq;
        pixels += o.pixels;
        clipped += o.clipped;
    }
    Eigen::Vector3d mean() const { return weight > 0.0 ? Eigen::Vector3d(sum / weight) : Eigen::Vector3d::Zero(); }
    // Weighted variance of the pixels (not of the mean), per channel; zero with one pixel.
    Eigen::Vector3d variance() const {
        if (!(weight > 0.0)) return Eigen::Vector3d::Zero();
        const Eigen::Vector3d m = mean();
        return (sum_sq / weight - m.cwiseProduct(m)).cwiseMax(0.0);
    }
};

// A tag's white border seen in the frames: radiance of a surface of known albedo.
struct TagReference {
    int tag = 0;                   // index in Scene::tags.items
    int face = -1;                 // the real face it lies on (-1: not seen yet)
    double albedo_white = 0.8;
    RadianceStats white;           // pixels of its white border
    std::vector<Eigen::Vector3d> ring_points;  // world points spread over the white border
    Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
};

// What one frame contributed and why pixels were left out.
struct FrameObservation {
    std::uint64_t samples = 0;    // rays cast
    std::uint64_t used = 0;       // pixels accumulated on proxy faces
    std::uint64_t saturated = 0;
    std::uint64_t dark = 0;
    std::uint64_t on_virtual = 0;
    std::uint64_t on_tag = 0;
    std::uint64_t tag_reference = 0;  // of on_tag: white border pixels kept as references
    std::uint64_t border = 0;
    std::uint64_t highlight = 0;
    std::uint64_t nothing = 0;    // rays that hit no proxy (or a light)
};

class Observations {
public:
    // `cell_size`: target cell edge, metres (grids are powers of two per axis, at most 256).
    // `interleave`: k (see above; 1: every frame samples every `stride`-th pixel).
    Observations(const std::vector<Face>& real_faces, const Scene& scene, const CameraModel& camera,
                 const ResponseCurve& response, int stride, double cell_size = 0.01, int interleave = 1);

    // Adds one frame (RGB8, distorted, the camera's size). `illuminant` is the chromaticity-bearing
    // colour of the light (e.g. the estimated lights' mean emission; white when unknown).
    Result<FrameObservation> add(const ImageView& rgb8, const Rigid3d& cam_from_world, double exposure_s, double gain,
                                 const RayScene& rays, const Eigen::Vector3d& illuminant = Eigen::Vector3d::Ones());

    std::uint64_t frames() const noexcept { return frames_; }
    const FrameObservation& totals() const noexcept { return totals_; }

    int gridS(int face) const { return grids_[static_cast<std::size_t>(face)].ns; }
    int gridT(int face) const { return grids_[static_cast<std::size_t>(face)].nt; }
    const RadianceStats& cell(int face, int i, int j) const;
    // Cells whose centres lie in the element (or, for an element smaller than a cell, the cell at
    // its centre with its weight scaled by the area ratio).
    RadianceStats aggregate(const Element& element) const;

    // Spread of the observed radiance inside an element: (p90 - p10) / mean of the luminance of its
    // cells with at least `min_pixels` pixels; 0 with fewer than 4 such cells.
    double spread(const Element& element, int min_pixels) const;

    const std::vector<TagReference>& tags() const noexcept { return tags_; }
    void setResponse(const ResponseCurve& response) { response_ = response; }

private:
    struct Grid {
        int ns = 1, nt = 1;
        bool triangle = false;
        std::vector<RadianceStats> cells;
        // Dual basis of the face: s = (p - origin) . ds_star, t = (p - origin) . dt_star.
        Eigen::Vector3d ds_star = Eigen::Vector3d::Zero();
        Eigen::Vector3d dt_star = Eigen::Vector3d::Zero();
        double cell_area = 0.0;  // m^2
    };
    struct TagFrame {
        Rigid3d tag_from_world;
        double half_black = 0.0;  // half the black square's edge, metres
        double half_total = 0.0;  // half the printed tag's edge, metres
        double cell = 0.0;        // one tag cell, metres
        bool white_ring = false;  // the ring outside the black square is plain white
    };

    // Whether a pixel's whole footprint lies on one side of a tag's white ring (`centre_in_tag`:
    // where its centre's ray meets the tag, tag frame).
    bool pixelOnRing(const TagFrame& tf, const Eigen::Vector2d& pixel, const Eigen::Matrix3d& world_from_cam_rotation,
                     const Eigen::Vector3d& camera_origin, const Eigen::Vector3d& centre_in_tag) const;

    std::vector<Face> faces_;
    std::vector<Grid> grids_;
    std::vector<TagReference> tags_;
    std::vector<TagFrame> tag_frames_;
    CameraModel camera_;
    ResponseCurve response_;
    int stride_ = 2;
    int interleave_ = 1;
    // Unit, per sample of each of the interleave^2 offsets in turn (NaN where the lens has no ray).
    std::vector<Eigen::Vector3f> rays_in_cam_;
    int samples_x_ = 0, samples_y_ = 0;  // per frame

    // The pixel of sample (i, j) at the offset of `phase` (0 .. interleave^2 - 1).
    Eigen::Vector2i samplePixel(int phase, int i, int j) const;
    std::uint64_t frames_ = 0;
    FrameObservation totals_;
};

// An apriltag family's layout (libapriltag's width_at_border and total_width, in cells):
// tag36h11 8 and 10. For the classic families (total = border + 2) the one-cell ring outside the
// black square is plain white; for the others (tagStandard, tagCircle) it carries data bits.
struct TagLayout {
    int width_at_border = 8;
    int total_width = 10;
    bool known = false;
};
TagLayout tagLayout(std::string_view family);

}  // namespace commonlight::lighting

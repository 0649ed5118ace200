// Tag pose from every edge of the tag's pattern, not only its four corners.
//
// A tag36h11 tag has about seventy boundaries between black and white cells whose positions on
// the tag are known exactly from its code. Aligning the projected pattern with the image uses all
// of them: for each sample point on a cell boundary, Step 1 projects it with the current pose
// (lens included), Step 2 finds the boundary in the image along the projected normal (the
// halfway crossing in linear light, edge_profile.h), Step 3 takes one robust Gauss-Newton step
// on the signed distances over the pose's 6 degrees of freedom and the tag's dilation; repeated a
// few times. Tags whose cells are under `min_cell_px` pixels keep their corner pose (there is
// nothing to resolve).
//
// Dilation: every black/white boundary of the image may lie a little into the white (black
// regions grown) or into the black (shrunk), by the same distance: ink spread on the print, and a
// camera response other than the one assumed (the halfway crossing of a blurred edge in wrongly
// linearized values moves towards one side by a fraction of the blur). Fitted by the pose alone,
// this shifts the black square's outline outward or inward: a scale error, so a range error of
// a few percent. The pattern has boundaries facing both ways (the outline faces out, inner cells'
// boundaries face in and out), so one parameter per tag, the distance `dilation` (in cells of the
// tag, along each boundary's normal towards its white side), is observable beside the pose and
// solved jointly with it: the model's boundary is the pattern's moved by `dilation` cells.
#pragma once
#include "tracking/edge_profile.h"

#include <map>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/camera_model.h"
#include "core/image.h"
#include "core/result.h"
#include "tracking/pose_types.h"

namespace commonlight::tracking {

// The black/white cell boundaries of one tag, in units of the black square's edge (so a tag of
// edge `size` has them at size times these coordinates), in the tag frame of tag_detector.h.
class TagPattern {
public:
    struct Edge {
        Eigen::Vector2d a, b;       // end points, tag frame / size
        Eigen::Vector2d to_bright;  // unit normal in the tag plane, from the black cell to the white one
        // The boundary turns a corner at its end a (b): the two cells beyond that end have one
        // colour (an L junction: a black or a white region's convex corner), not a straight
        // continuation or a crossing of four cells.
        bool corner_a = false, corner_b = false;
    };
    // Draws the tag with libapriltag (apriltag_to_image); kUsage for an unknown family or id.
    static Result<TagPattern> make(const std::string& family, int id);
    const std::vector<Edge>& edges() const noexcept { return edges_; }
    double cell() const noexcept { return cell_; }  // one cell, in units of the black square's edge
    // The drawn tag's cells, `total()` by `total()` (the white border included), row 0 at the
    // tag's top (+y): true for white. The cell (col, row) spans x in [-h + col c, -h + (col+1) c],
    // y in [h - (row+1) c, h - row c], with c = cell() and h = total() c / 2.
    int total() const noexcept { return total_; }
    bool white(int col, int row) const noexcept { return white_[static_cast<std::size_t>(row * total_ + col)]; }

private:
    std::vector<Edge> edges_;
    double cell_ = 0.0;
    int total_ = 0;
    std::vector<bool> white_;
};

// Patterns by id for one family, made on first use.
class TagPatternCache {
public:
    explicit TagPatternCache(std::string family) : family_(std::move(family)) {}
    const TagPattern* get(int id);

private:
    std::string family_;
    std::map<int, std::unique_ptr<TagPattern>> patterns_;
};

struct TagAlignOptions {
    double min_cell_px = 2.0;   // cells smaller than this in the image: no alignment
    int iterations = 4;         // at most
    // Converged: a step that moves no corner of the black square by more than this many pixels
    // ends the iterations (measured on the bundled sample: the second step moves the corners by
    // 0.008 px at the median, the third by 0.001 px).
    double converged_px = 0.01;
    double search_px = 1.5;     // +- along the normal (at least; 35% of a cell when cells are larger)
    double huber_px = 0.5;
    double max_rms_px = 0.6;    // a final RMS above this: the alignment is refused
    bool srgb = true;           // pixels are sRGB-encoded: find edges in linear light
    // Solve the tag's dilation (black grown or shrunk, in cells) with its pose; false: 0.
    bool estimate_dilation = true;
    double dilation_sigma_cells = 0.2;  // a weak prior on the dilation: zero, this standard deviation
    double max_dilation_cells = 0.3;    // a larger fitted dilation: the alignment is refused
    // A boundary point nearer an L junction than this (pixels, along the boundary) is not
    // sampled: the blur rounds a region's convex corner, so the edge found there lies inside the
    // region by a fraction of the blur, in pixels: a scale error that differs along and across a
    // foreshortened tag (a tilt error) and that the dilation, in cells, does not absorb. 0: every
    // point (before issue 13's fix).
    double corner_clearance_px = 2.0;
    // On cells under this many pixels every point is sampled (measured: dropping them on cells
    // of 2.4 px made the pattern choose the wrong candidate of a 19 px tag, tracking/ambiguity).
    double corner_clearance_min_cell_px = 3.0;
    // ... and on tags whose shorter projected side is under this fraction of the longer (tilted
    // more than about 60 degrees): the clearance left their short boundaries a point each.
    // Measured by `bench tracking`: without this limit `oblique75` (75-80 degrees) had camera
    // rotation p50 0.052 degrees and `tiny75` 0.044; with it 0.037 and 0.035, as before the
    // clearance, and every other case the same as without the limit.
    double corner_clearance_min_aspect = 0.5;
    // The camera\'s response when it is neither sRGB nor linear (--response): replaces `srgb`.
    std::shared_ptr<const Linearizer> linearizer;
    // A response other than the assumed one (a linear camera read as sRGB, an ISP's own curve):
    // the halfway crossing of a blurred edge is then not the middle of its linear step (about
    // 73 % of it for a linear camera read as sRGB), off the steepest point, where the sensor's
    // noise and the pixel grid's phase move it more. The mismatch is measured on the tag itself,
    // from the start pose: the ratio of its black cells' level to its white cells' (the pixels at
    // their centres: the darker quarter of the black cells, the brighter quarter of the white)
    // against the ratio of its albedos (known from the scene, as the lighting uses them). Through
    // the assumed linearization the measured ratio, raised to an exponent e, gives the albedos'
    // ratio; a gross mismatch (e beyond response_min_change either way) replaces the
    // linearization, for this tag, by the pure gamma curve that maps the two levels' codes onto
    // the albedos' ratio (exact for a linear or a gamma camera; sRGB reads as gamma 1.9-2.4). A
    // moderate mismatch is kept: the print's real contrast differs from the scene's albedos by
    // some, and gamma 1.8 or 2.6 read as sRGB costs little (1.0-1.1x the matched rotation error).
    bool estimate_response = true;
    double albedo_ratio = 0.05;         // the tag's black albedo over its white one (scene defaults 0.04 / 0.8)
    double response_min_change = 1.3;   // e within [1 / this, this]: the assumed response stays
    double response_min_cell_px = 3.0;  // smaller cells: no pixel at a cell's centre is clear of the blur
    int response_min_cells = 12;        // black and white cells each, in the image
    double min_response_gamma = 0.3, max_response_gamma = 4.0;
};

struct TagAlignResult {
    bool ok = false;
    std::string reason;         // when not ok
    // The fit ran: false when refused before it (bad input, the tag outside the lens model, cells
    // under min_cell_px), where the pattern says nothing for or against the pose.
    bool measured = false;
    Rigid3d cam_from_tag;       // aligned when ok, the input otherwise
    Matrix6d covariance = Matrix6d::Identity();  // of cam_from_tag, pose_types.h convention
    int points = 0;             // edge points used in the last step
    double rms_px = 0.0;
    double dilation_cells = 0.0;  // fitted dilation: > 0 the black regions look grown, in cells
    double dilation_px = 0.0;     // the same in image pixels (times the tag's mean cell size)
    double cell_px = 0.0;         // the tag's cell size in the image (the shorter side's), pixels
    // The response mismatch measured (TagAlignOptions::estimate_response; 0: not measured) and
    // the gamma of the linearization that replaced the assumed one (0: none).
    double response_exponent_measured = 0.0;
    double response_gamma = 0.0;
};

TagAlignResult alignTagPose(const ImageView& gray8, const CameraModel& camera, const TagPattern& pattern, double size,
                            const Rigid3d& cam_from_tag, const TagAlignOptions& options = {});

}  // namespace commonlight::tracking

// Verifying a predicted tag that the detector did not find (tiny tags: a tag36h11 black square of
// 7-10 px has cells of 0.9-1.25 px, too small to decode, but not too small to recognise when the
// id and the place are known).
//
// When the frame's other tags (or the motion model) give the camera pose, every scene tag is
// predicted at known corners with a known id, so its pattern is known. Step 1 projects the tag's
// whole drawn square (black square and white border) with the predicted pose; a homography from
// its four outer corners maps each pixel back to the tag plane (the lens is locally a homography
// over a tag this small). Step 2 renders the expected image of the pattern pixel by pixel (each
// pixel the white fraction of 3 x 3 sub-samples), blurs it by each of `blur_sigma_px` in turn and
// takes the best normalized cross-correlation (NCC) with the image in linear light, over shifts
// of the whole prediction within +- `search_px` (`search_step_px` steps, climbed from the
// prediction, then half a step around the best). Step 3
// does the same with the plain black square (no inner cells) on a 3 x 3 grid of steps around the
// pattern's best shift, and with `other ids` of the family at that shift (skipped when the
// pattern already fails). The tag is accepted when its
// pattern's NCC reaches `min_ncc` and beats each alternative by its margin:
// a place where the tag is not (background, an occluder, a wrong prediction) matches neither
// clearly, or a plain square as well as the pattern. The accepted corners are the predicted ones
// moved by the best shift.
#pragma once

#include <Eigen/Core>
#include <array>
#include <string>
#include <vector>

#include "core/camera_model.h"
#include "core/image.h"
#include "tracking/edge_profile.h"
#include "tracking/pose_types.h"
#include "tracking/tag_align.h"

namespace commonlight::tracking {

struct TagVerifyOptions {
    // Predicted black squares whose shorter span (between the midpoints of opposite sides) is
    // under min_side_px, or over max_side_px (the detector finds those), are not tried.
    double min_side_px = 5.0;
    double max_side_px = 20.0;
    // ... and one whose mean side is over max_side_px (foreshortened) only when its shorter span is
    // at most this (cells of 1.5 px across); the tracker detects the wider ones at full resolution
    // first (TrackerOptions::verify_redetect_full_res) and verifies only those it misses there.
    double max_foreshortened_span_px = 12.0;
    double edge_margin_px = 3.0;  // the drawn square (white border included) this far inside the image
    double search_px = 1.0;       // the prediction's error this verification absorbs, +- pixels
    // The grid of shifts (step 2; step 3's plain square on 3 x 3 of them), then half of it around
    // its best.
    double search_step_px = 0.25;
    // The grid of step 2 climbed from the prediction (to the best of the 3 x 3 shifts around the
    // current one, until none is better) instead of tried whole: about 12 of its 81 shifts where
    // the prediction is within 0.2 px, the same shift wherever the correlation has one peak over
    // the grid (docs/tracking.md, "Speed (issue 13)", seventh round). A tag predicted up to
    // search_px off is still found: the climb walks there.
    bool search_ascent = true;
    // The pattern's normalized cross-correlation with the image: measured on synthetic 7-20 px
    // tags (blur 0.8 px, noise 1.5 grey levels) 0.95-0.99 at the truth; another id printed in
    // the tag's place, 0.8-0.87 (the black square and the border dominate both).
    double min_ncc = 0.9;
    double min_margin_square = 0.12;  // over the plain black square's
    double min_margin_other = 0.05;   // over every other id's
    int other_ids = 8;                // other ids of the family compared (the ids after the tag's)
    double min_contrast = 0.03;       // the image's standard deviation over the tag, linear [0, 1]
    // The optics' blur is not known: the expected image is blurred by each of these Gaussians
    // (sigma, pixels, on top of the pixel's own area; 0: none) and each template's NCC is its
    // best over them. At 1 px cells the blur decides the correlation: a path-traced frame (a box
    // pixel, no optics) correlates 0.44-0.83 at the truth under a fixed 0.7 px blur, 0.90-0.98
    // with none.
    std::vector<double> blur_sigma_px = {0.0, 0.5, 0.75, 1.0};
    // The tracker (step 3b) tries a tag again, once the tags it accepted have joined the bundle,
    // when its pattern correlated at least this much (but under min_ncc) the first time.
    double retry_min_ncc = 0.7;
    bool srgb = true;  // pixels are sRGB-encoded (as TagAlignOptions::srgb)
    // Tests: the NCC the plain way: each blur level through scalar loops, one tap and one pixel
    // at a time, the five products left to right; each level scored with its mean subtracted,
    // then summed; every pixel rendered at every shift. The fast paths (symmetric taps, two
    // pixels a vector, one-pass sums, pixels of one colour under a search's shifts rendered once)
    // must give the same decisions and shifts and NCCs within 1e-12 (docs/tracking.md, "Speed
    // (issue 13)").
    bool reference_ncc = false;
};

struct TagVerifyResult {
    bool ok = false;
    std::string reason;                                  // when not ok
    std::array<Eigen::Vector2d, 4> corners{};            // the black square's, distorted pixels (tag_detector.h order)
    Eigen::Vector2d shift_px = Eigen::Vector2d::Zero();  // from the predicted corners
    double ncc = 0.0;                                    // the tag's pattern at the best shift
    int grid_shifts_tried = 0;                           // of step 2's 0.5 px grid (search_ascent)
    double ncc_square = 0.0;                             // the plain black square at its best shift
    double ncc_other = -1.0;                             // the best of the other ids
    // Step 3 skipped: the tag was reported at this place in the last frame (`known_at_px`), so
    // ncc_square and ncc_other were not measured.
    bool alternatives_skipped = false;
    double side_px = 0.0;                                // the predicted black square's mean side
    double span_px = 0.0;                                // its shorter span (the range's measure)
    // Not tried: a foreshortened tag whose shorter span is over max_foreshortened_span_px (but in
    // the range), wide enough for the detector at full resolution (the tracker detects it there).
    bool wide_enough_to_detect = false;
};

// `pattern`: the predicted tag's; `others`: patterns of other ids of the family (may be empty).
// `known_at_px`: where the tag's black square was centred when it was last reported (detected or
// verified in the previous frame of a sequence), or null. When the predicted square's centre is
// within half its shorter span of it, the alternatives (step 3: the plain square, the other ids)
// are not compared: what they guard against, a place where another id or no tag is, is excluded
// by the tag having been there a frame ago; the pattern's own correlation (min_ncc) still
// decides, so a tag covered or gone since is refused as before.
TagVerifyResult verifyPredictedTag(const ImageView& gray8, const CameraModel& camera, const TagPattern& pattern,
                                   const std::vector<const TagPattern*>& others, double size,
                                   const Rigid3d& cam_from_tag, const TagVerifyOptions& options = {},
                                   const Eigen::Vector2d* known_at_px = nullptr);

}  // namespace commonlight::tracking

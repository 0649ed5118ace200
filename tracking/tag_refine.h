// Sub-pixel refinement of a tag's corners from its black square's four edges.
//
// libapriltag fits its quad to a thresholded contour (and refines edges only when it decimates),
// so its corners carry a few tenths of a pixel of noise and bias. Here, for each side:
//   Step 1  sample the image every pixel along the side (away from the corners), and at each
//           sample search along the outward normal for the strongest dark-to-bright step
//           (bilinear samples every 0.25 px, the peak of the derivative to sub-pixel by a parabola);
//   Step 2  undistort those edge points with the calibration (a straight edge is straight only in
//           the ideal pinhole image) and fit a line by total least squares, twice, dropping points
//           more than 0.75 px from the first fit (a partly occluded side);
//   Step 3  intersect adjacent lines for the corners and distort them back to image pixels.
// A side with too few edge points, or a result that moves a corner by more than `max_shift_px`,
// leaves the tag's corners unchanged (reported, not an error).
#pragma once
#include "tracking/edge_profile.h"

#include <memory>

#include <array>

#include <Eigen/Core>

#include "core/camera_model.h"
#include "core/image.h"

namespace commonlight::tracking {

struct TagRefineOptions {
    double search_px = 2.5;     // +- along the normal, pixels (at least; grows with the tag, 8% of a side)
    double max_shift_px = 2.0;  // a refined corner further than this from the detected one: refinement refused
    int min_points = 6;         // per side
    bool srgb = true;           // pixels are sRGB-encoded (webcams, our sequences): find edges in linear light
    // The black square's edges are this far into the white in the image (black regions grown by
    // the print or a response other than the one assumed; < 0: shrunk), pixels: each measured
    // edge point is moved back by it. The tag alignment measures it (TagAlignResult::dilation_px);
    // the tracker passes the frame's aligned tags' median to the tags it could not align.
    double dilation_px = 0.0;
    // The camera\'s response when it is neither sRGB nor linear (--response): replaces `srgb`.
    std::shared_ptr<const Linearizer> linearizer;
};

// Refines `corners` (distorted pixels, OpenCV convention, libapriltag's order) in place from the
// 8-bit grey image. Returns false (corners untouched) when a side cannot be refined.
bool refineTagCorners(const ImageView& gray8, const CameraModel& camera, std::array<Eigen::Vector2d, 4>& corners,
                      const TagRefineOptions& options = {});

}  // namespace commonlight::tracking

// Synthetic images of AprilTags for tracking tests: the tags' albedo (mocks/sim's tag texture)
// through a pinhole, supersampled per pixel, optionally averaged over several poses (motion blur
// over an exposure), blurred in linear light (the optics), with Gaussian sensor noise, encoded
// as 8-bit sRGB grey. The ground truth is exact: the poses the caller gives.
#pragma once

#include <cstdint>
#include <functional>
#include <vector>

#include "core/camera_model.h"
#include "core/image.h"
#include "core/pose.h"
#include "core/scene.h"

namespace commonlight::tracking::testing {

struct SyntheticTag {
    int id = 0;
    double size = 0.1;  // edge of the black square, metres
    Rigid3d cam_from_tag;
};

struct SyntheticImageOptions {
    int supersample = 4;         // per pixel and axis
    double blur_sigma_px = 0.8;  // Gaussian optics blur in linear light (0: none)
    double noise_sigma = 0.0;    // sensor noise, in 8-bit grey levels (1 sigma)
    std::uint64_t seed = 1;
    double background = 0.3;  // albedo around the tags
};

// A 640 x 480 pinhole camera, f = 500 px, principal point at the centre, no distortion.
CameraModel syntheticCamera();

// Eight foreshortened tags, ids 30-37, in a 4 x 2 grid about the origin of the tag plane (x at
// -0.18 + 0.12 i, y at -+0.12), each turned about its y axis by turn0 + turn_step (k mod 3)
// degrees, sized size0 + size_step k metres, appended to `tags`.
void addForeshortenedGrid(TagSet& tags, double turn0_deg, double turn_step_deg, double size0, double size_step);

// The tags at one instant.
Image renderSyntheticTags(const CameraModel& camera, const std::vector<SyntheticTag>& tags,
                          const SyntheticImageOptions& options = {});

// Motion blur: the mean of the linear images at `time_samples` instants spread evenly over the
// exposure (sample k at (k + 0.5) / time_samples of it); `tags_at(s)` gives the tags at the
// fraction s in [0, 1] of the exposure.
Image renderSyntheticTagsBlurred(const CameraModel& camera,
                                 const std::function<std::vector<SyntheticTag>(double)>& tags_at, int time_samples,
                                 const SyntheticImageOptions& options = {});

}  // namespace commonlight::tracking::testing

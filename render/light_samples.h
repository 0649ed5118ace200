// The estimated lights as the point samples the virtual objects are shaded with, and the views of
// their shadow maps. Internal to render/.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "core/pose.h"
#include "lighting/snapshot.h"

namespace commonlight::render {

constexpr int kMaxLightSamples = 16;

struct LightSample {
    int kind = 0;  // 0 a point of an area or disc light, 1 point light, 2 directional
    Eigen::Vector3d position = Eigen::Vector3d::Zero();  // world (kinds 0, 1)
    Eigen::Vector3d axis = Eigen::Vector3d::UnitZ();     // 0: the emitting normal; 2: the direction light travels
    Eigen::Vector3d power = Eigen::Vector3d::Zero();     // relative: L A / n (area), I (point), E (directional)
    double radius = 0.0;  // m: the radius of a disc of the area this sample stands for (kind 0); 0: a point
    int layer = -1;                                      // shadow map layer, -1: none
    Eigen::Matrix4f view_proj = Eigen::Matrix4f::Identity();  // world -> the shadow map's clip space (virtual objects)
    Eigen::Matrix4f static_view_proj = Eigen::Matrix4f::Identity();  // world -> the real proxies' shadow map's clip space
};

// The snapshot's lights with a positive finite emission, scaled by its radiance_scale to relative
// units: area and disc lights as `per_area` points (a grid on a rectangle, a golden-angle spiral
// on a disc), each with its share of the power. At most kMaxLightSamples.
std::vector<LightSample> lightSamples(const lighting::LightingSnapshot& snapshot, int per_area);

// Gives each sample a shadow map layer and the view that covers the virtual objects' bounds
// [vmin, vmax] (world): a perspective frustum around their bounding sphere, an orthographic box for
// directional light, or, for a light among the objects, a 150-degree frustum along its axis.
void fitShadowViews(std::vector<LightSample>& samples, const Eigen::Vector3d& vmin, const Eigen::Vector3d& vmax);

// The view of one sample's shadow map that covers the sphere (centre, radius): up to its far side
// (what lies beyond cannot shadow anything in it).
Eigen::Matrix4f shadowView(const LightSample& sample, const Eigen::Vector3d& centre, double radius);

// The virtual objects' shadow maps only shade the objects themselves (their shadows on real
// surfaces come from the snapshot), so a map needs no finer texels than the objects' pixels: their
// bounding sphere's width in pixels at its near side, as a power of two in [64, `max_size`]
// (filtered by the comparison sampler and, for area lights, averaged over samples). The size in use
// is kept while it is enough and at most 2.5x what is needed (no reallocation back and forth as
// the objects move towards or away from the camera).
// `footprint_px`: that width (infinite when the camera is inside or near the sphere); `current`: the
// size in use (0: none).
int virtualShadowMapSize(double footprint_px, int current, int max_size);

// A pose as a GL model matrix (column vectors).
Eigen::Matrix4f toGl(const Rigid3d& pose);

}  // namespace commonlight::render

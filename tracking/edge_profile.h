// Locating a dark-to-bright edge along an image profile, in linear light (shared by the tag
// corner refinement and the tag alignment).
#pragma once

#include <array>
#include <memory>
#include <optional>

#include <Eigen/Core>

#include "core/image.h"

namespace commonlight::tracking {

// Pixel value to linear intensity (0..255 scale): the sRGB curve inverted, or the identity.
// Edges are found in linear intensity: the optics blur light, not encoded pixel values, and the
// steepest point of a blurred step moves towards the dark side once the sRGB curve is applied
// (measured on the desk sample: about 0.15 px per edge, a scale bias of the whole tag).
struct Linearizer {
    double lut[256];
    explicit Linearizer(bool srgb);
    // Any response: the linear value (in [0, 1]) of each code, scaled to 0..255.
    explicit Linearizer(const std::array<float, 256>& linear_of_code);
    // The two tables, built once (256 pow() calls each) instead of per tag and frame.
    static const Linearizer& get(bool srgb);
    // A pure gamma curve: the linear value of code v is (v / 255)^g.
    static Linearizer gamma(double g);
};

// Along the line p + s * n (n unit), s in [-range, range] pixels: where the intensity crosses
// halfway between its dark and bright levels on a dark-to-bright step (exact for any symmetric
// blur in linear light, and steadier under noise than the peak of the derivative). Three
// profiles 0.5 px apart along `along` are averaged. nullopt when the profile leaves the image or
// shows no step of a few grey levels.
std::optional<double> edgeOffset(const ImageView& gray8, const Linearizer& lin, const Eigen::Vector2d& p,
                                 const Eigen::Vector2d& n, const Eigen::Vector2d& along, double range);

}  // namespace commonlight::tracking

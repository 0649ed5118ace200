// AprilTag detection with libapriltag.
//
// The detector runs on the distorted 8-bit image. Corners are reported in OpenCV's pixel
// convention (centre of the top-left pixel at (0, 0)): libapriltag's corners minus 0.5.
// Corner order is libapriltag's: counter-clockwise in the image starting at the tag's bottom
// left, which in the tag frame of docs/formats-scene.md (x right, y towards the tag image's top,
// z out of the printed side) is (-s/2, -s/2), (s/2, -s/2), (s/2, s/2), (-s/2, s/2); see
// tagCornerInTag().
#pragma once

#include <array>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Core>

#include "core/image.h"
#include "core/pose.h"
#include "core/result.h"

struct apriltag_family;  // libapriltag's (global namespace)

namespace commonlight::tracking {

struct TagDetectorOptions {
    std::string family = "tag36h11";  // any libapriltag family by name (tagFamilyNames())
    double decimate = 1.0;            // quad_decimate: detect quads on an image this many times smaller (>= 1);
                                      // 2 (libapriltag's default) is faster but misses tags under ~40 px
    double sigma = 0.0;               // quad_sigma: Gaussian blur in pixels before quad detection (>= 0)
    int threads = 1;                  // libapriltag's worker threads (>= 1)
    bool refine_edges = true;         // snap quad edges to the full-resolution gradient
    int max_hamming = 1;              // reject decodings with more corrected bits than this (0..2)
    double min_decision_margin = 20;  // reject weaker decodings (libapriltag's decision_margin)

    // For comparisons (bench tracking): when set, each detection also carries libapriltag's own
    // estimate_tag_pose, computed from libapriltag's corners and homography with these pinhole
    // intrinsics (OpenCV convention; the detector adds libapriltag's half-pixel offset). It
    // knows no lens distortion.
    struct ReferencePose {
        double tag_size = 0.0;  // metres, edge of the black square
        double fx = 0.0, fy = 0.0, cx = 0.0, cy = 0.0;
    };
    std::optional<ReferencePose> reference_pose;

    // Names the offending field.
    Result<void> validate() const;
};

// The families libapriltag 3.3 ships: tag36h11, tag25h9, tag16h5, tagCircle21h7, ...
std::span<const char* const> tagFamilyNames();

// libapriltag's family by name (nullptr for an unknown one); the caller frees it with
// destroyApriltagFamily under the same name.
::apriltag_family* makeApriltagFamily(std::string_view name);
void destroyApriltagFamily(std::string_view name, ::apriltag_family* family);

struct TagDetection {
    int id = -1;
    std::array<Eigen::Vector2d, 4> corners;  // distorted pixels, OpenCV convention, libapriltag's order
    Eigen::Vector2d center = Eigen::Vector2d::Zero();  // distorted pixels, OpenCV convention
    int hamming = 0;                                   // bits corrected
    double decision_margin = 0.0;                      // libapriltag's decoding confidence
    // libapriltag's estimate_tag_pose as cam_from_tag in our tag frame, when the options ask for it.
    std::optional<Rigid3d> reference_cam_from_tag;
};

// A rectangle of the image, pixels; clipped to the image by the detector.
struct PixelWindow {
    int x = 0, y = 0, width = 0, height = 0;
};

// Where the tag corner `index` (0..3, libapriltag's order) lies in the tag frame, metres, for a tag
// whose black square has edge `size`.
Eigen::Vector3d tagCornerInTag(int index, double size);

class TagDetector {
public:
    // Fails (kUsage) for an unknown family or an invalid option, naming it.
    static Result<TagDetector> create(const TagDetectorOptions& options);
    TagDetector(TagDetector&&) noexcept;
    TagDetector& operator=(TagDetector&&) noexcept;
    ~TagDetector();

    // Detects every tag in an 8-bit grey image (kGray8; other formats fail with kBadInput).
    // An image without tags gives an empty vector; a failure of the detector itself (libapriltag's
    // worker pool, an allocation) is an error, not an empty result.
    Result<std::vector<TagDetection>> detect(const ImageView& gray8);
    // Detects only inside the windows (clipped to the image; empty windows are skipped), without
    // copying pixels; corners are in full-image pixels. When decimated, each window is first grown
    // to the decimation's sampling and threshold grid (up to 4 x decimate - 1 px a side), so that a
    // tag well inside it is found as the whole frame's detection finds it. A tag seen by two
    // overlapping windows is reported once (the detection with the larger decision margin).
    Result<std::vector<TagDetection>> detectInWindows(const ImageView& gray8, std::span<const PixelWindow> windows);

    const TagDetectorOptions& options() const noexcept { return options_; }

private:
    struct Impl;
    TagDetector(std::unique_ptr<Impl> impl, TagDetectorOptions options);
    std::unique_ptr<Impl> impl_;
    TagDetectorOptions options_;
};

}  // namespace commonlight::tracking

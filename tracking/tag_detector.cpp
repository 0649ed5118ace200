#include "tracking/tag_detector.h"

#include <apriltag/apriltag.h>
#include <apriltag/apriltag_pose.h>
#include <apriltag/tag16h5.h>
#include <apriltag/tag25h9.h>
#include <apriltag/tag36h11.h>
#include <apriltag/tagCircle21h7.h>
#include <apriltag/tagCircle49h12.h>
#include <apriltag/tagCustom48h12.h>
#include <apriltag/tagStandard41h12.h>
#include <apriltag/tagStandard52h13.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>

#include <Eigen/SVD>
#include <string_view>

namespace commonlight::tracking {
namespace {

struct FamilyEntry {
    const char* name;
    apriltag_family_t* (*create)();
    void (*destroy)(apriltag_family_t*);
};

constexpr FamilyEntry kFamilies[] = {
    {"tag36h11", tag36h11_create, tag36h11_destroy},
    {"tag25h9", tag25h9_create, tag25h9_destroy},
    {"tag16h5", tag16h5_create, tag16h5_destroy},
    {"tagCircle21h7", tagCircle21h7_create, tagCircle21h7_destroy},
    {"tagCircle49h12", tagCircle49h12_create, tagCircle49h12_destroy},
    {"tagCustom48h12", tagCustom48h12_create, tagCustom48h12_destroy},
    {"tagStandard41h12", tagStandard41h12_create, tagStandard41h12_destroy},
    {"tagStandard52h13", tagStandard52h13_create, tagStandard52h13_destroy},
};
constexpr const char* kFamilyNames[] = {"tag36h11",       "tag25h9",        "tag16h5",          "tagCircle21h7",
                                        "tagCircle49h12", "tagCustom48h12", "tagStandard41h12", "tagStandard52h13"};

const FamilyEntry* findFamily(std::string_view name) {
    for (const FamilyEntry& entry : kFamilies) {
        if (name == entry.name) return &entry;
    }
    return nullptr;
}

std::string familyList() {
    std::string list;
    for (const char* name : kFamilyNames) {
        if (!list.empty()) list += ", ";
        list += name;
    }
    return list;
}

}  // namespace

std::span<const char* const> tagFamilyNames() { return kFamilyNames; }

apriltag_family_t* makeApriltagFamily(std::string_view name) {
    const FamilyEntry* entry = findFamily(name);
    return entry ? entry->create() : nullptr;
}

void destroyApriltagFamily(std::string_view name, apriltag_family_t* family) {
    if (const FamilyEntry* entry = findFamily(name); entry && family) entry->destroy(family);
}

Result<void> TagDetectorOptions::validate() const {
    if (!findFamily(family)) {
        return fail(ErrorCode::kUsage, "unknown tag family '" + family + "' (known: " + familyList() + ")");
    }
    if (!(decimate >= 1.0) || !std::isfinite(decimate)) {
        return fail(ErrorCode::kUsage, "decimate must be a number >= 1, got " + std::to_string(decimate));
    }
    if (!(sigma >= 0.0) || !std::isfinite(sigma)) {
        return fail(ErrorCode::kUsage, "sigma must be a number >= 0, got " + std::to_string(sigma));
    }
    if (threads < 1 || threads > 64) {
        return fail(ErrorCode::kUsage, "threads must be in 1..64, got " + std::to_string(threads));
    }
    if (max_hamming < 0 || max_hamming > 2) {
        return fail(ErrorCode::kUsage, "max_hamming must be 0, 1 or 2, got " + std::to_string(max_hamming));
    }
    if (!std::isfinite(min_decision_margin) || min_decision_margin < 0) {
        return fail(ErrorCode::kUsage, "min_decision_margin must be >= 0");
    }
    return {};
}

Eigen::Vector3d tagCornerInTag(int index, double size) {
    // libapriltag's order, counter-clockwise in the image from the bottom left of the tag image.
    static constexpr double kSigns[4][2] = {{-1, -1}, {1, -1}, {1, 1}, {-1, 1}};
    const int i = index & 3;
    return {0.5 * size * kSigns[i][0], 0.5 * size * kSigns[i][1], 0.0};
}

// libapriltag's estimate_tag_pose for one of its detections. Its tag frame has y down and z into
// the tag (our frame rotated by pi about x); its pixels put the top-left centre at (0.5, 0.5).
// It allocates R and t with malloc; they are freed here with free (matd_destroy is not exported
// by Debian's library).
std::optional<Rigid3d> referencePose(apriltag_detection_t* det, const TagDetectorOptions::ReferencePose& ref, int x0,
                                     int y0) {
    // The detection is in window pixels: shift the principal point instead of the corners.
    apriltag_detection_info_t info{det, ref.tag_size, ref.fx, ref.fy, ref.cx + 0.5 - x0, ref.cy + 0.5 - y0};
    apriltag_pose_t pose{nullptr, nullptr};
    estimate_tag_pose(&info, &pose);
    std::optional<Rigid3d> result;
    if (pose.R && pose.t) {
        Eigen::Matrix3d r;
        for (int i = 0; i < 3; ++i) {
            for (int j = 0; j < 3; ++j) r(i, j) = pose.R->data[3 * i + j];
        }
        const Eigen::Vector3d t(pose.t->data[0], pose.t->data[1], pose.t->data[2]);
        const Eigen::Matrix3d ours_to_theirs = Eigen::Vector3d(1, -1, -1).asDiagonal();
        const Eigen::Matrix3d rotation = r * ours_to_theirs;
        if (rotation.allFinite() && t.allFinite()) {
            // Orthonormalise what the library returns before making a quaternion of it.
            Eigen::JacobiSVD<Eigen::Matrix3d> svd(rotation, Eigen::ComputeFullU | Eigen::ComputeFullV);
            Eigen::Matrix3d u = svd.matrixU();
            if ((u * svd.matrixV().transpose()).determinant() < 0) u.col(2) *= -1;
            result = Rigid3d(Eigen::Quaterniond(u * svd.matrixV().transpose()), t);
        }
    }
    std::free(pose.R);
    std::free(pose.t);
    return result;
}

struct TagDetector::Impl {
    const FamilyEntry* entry = nullptr;
    apriltag_family_t* family = nullptr;      // owned: entry->destroy
    apriltag_detector_t* detector = nullptr;  // owned: apriltag_detector_destroy

    ~Impl() {
        if (detector) apriltag_detector_destroy(detector);
        if (family) entry->destroy(family);
    }

    // Step 1: detect on a (sub-)image; Step 2: convert, filter and offset the detections.
    Result<void> run(const ImageView& view, int x0, int y0, int width, int height, const TagDetectorOptions& options,
                     std::vector<TagDetection>& out) {
        image_u8_t image{width, height, static_cast<std::int32_t>(view.stride),
                         const_cast<std::uint8_t*>(view.data + static_cast<std::size_t>(y0) * view.stride + x0)};
        errno = 0;
        zarray_t* detections = apriltag_detector_detect(detector, &image);  // destroyed below
        if (!detections) return fail(ErrorCode::kInternal, "libapriltag's detector returned nothing (out of memory?)");
        const int count = zarray_size(detections);
        // libapriltag returns an empty list when it cannot start its worker threads; tell that
        // apart from "no tag in view" by the errno pthread_create/malloc leave behind.
        if (count == 0 && (errno == EAGAIN || errno == ENOMEM)) {
            apriltag_detections_destroy(detections);
            return fail(ErrorCode::kInternal, "libapriltag's detector failed to start its " +
                                                  std::to_string(options.threads) + " worker thread(s)");
        }
        for (int i = 0; i < count; ++i) {
            apriltag_detection_t* det = nullptr;
            zarray_get(detections, i, &det);
            if (det->hamming > options.max_hamming || det->decision_margin < options.min_decision_margin) continue;
            TagDetection d;
            d.id = det->id;
            d.hamming = det->hamming;
            d.decision_margin = det->decision_margin;
            bool finite = true;
            for (int c = 0; c < 4; ++c) {
                d.corners[c] = Eigen::Vector2d(det->p[c][0] - 0.5 + x0, det->p[c][1] - 0.5 + y0);
                finite = finite && d.corners[c].allFinite();
            }
            d.center = Eigen::Vector2d(det->c[0] - 0.5 + x0, det->c[1] - 0.5 + y0);
            if (!finite || !d.center.allFinite()) continue;
            if (options.reference_pose) d.reference_cam_from_tag = referencePose(det, *options.reference_pose, x0, y0);
            out.push_back(d);
        }
        apriltag_detections_destroy(detections);
        return {};
    }
};

Result<TagDetector> TagDetector::create(const TagDetectorOptions& options) {
    CL_TRY_VOID(options.validate());
    auto impl = std::make_unique<Impl>();
    impl->entry = findFamily(options.family);
    impl->family = impl->entry->create();
    impl->detector = apriltag_detector_create();
    if (!impl->family || !impl->detector) return fail(ErrorCode::kInternal, "libapriltag could not create a detector");
    apriltag_detector_add_family_bits(impl->detector, impl->family, options.max_hamming);
    impl->detector->quad_decimate = static_cast<float>(options.decimate);
    impl->detector->quad_sigma = static_cast<float>(options.sigma);
    impl->detector->nthreads = options.threads;
    impl->detector->refine_edges = options.refine_edges;
    return TagDetector(std::move(impl), options);
}

TagDetector::TagDetector(std::unique_ptr<Impl> impl, TagDetectorOptions options)
    : impl_(std::move(impl)), options_(std::move(options)) {}
TagDetector::TagDetector(TagDetector&&) noexcept = default;
TagDetector& TagDetector::operator=(TagDetector&&) noexcept = default;
TagDetector::~TagDetector() = default;

namespace {
// The grid a window's edges are put on, full-image pixels. libapriltag 3.3 decimates by keeping
// every `factor`-th pixel counted from the image's origin (1.5: 3 x 3 blocks into 2 x 2) and
// thresholds in tiles of 4 decimated pixels counted from it, each pixel against the extremes of
// the 3 x 3 tiles around its own. A window whose edges are on this grid sees, 12 px or more
// inside them (tracking mode's margin), the pixels, tiles and thresholds the full frame sees
// there. One off it sees other ones: at decimate 2 a window starting at an odd pixel keeps the
// pixels the full frame drops. On `bench tracking --cases wide` (tags of 30 px: cells of 2 px
// decimated) such windows missed tags the full frame found in 9 of 31 frames and found some it
// missed in 4 (docs/tracking.md, "Windows"; on the grid: the same tags in every frame).
// Undecimated (the factor 1), a window has no sampling phase and is left as it is: put on the
// tiles' 4 px grid, step 3b's full-resolution windows (TrackerOptions::verify_redetect_full_res,
// which no full-frame detection has to match) turned a tag of `tiny75` from verified (corners 0.08
// px from the truth) to detected late (0.9 px), and the full frame's output would change.
int windowGrid(double decimate) {
    constexpr int kTile = 4;  // libapriltag 3.3's threshold tile, decimated pixels
    if (decimate == 1.5) return 3 * kTile / 2;
    const int factor = static_cast<int>(decimate);
    return factor > 1 ? kTile * factor : 1;
}

int floorToMultiple(int v, int m) { return (v >= 0 ? v / m : -((-v + m - 1) / m)) * m; }

Result<void> checkGray(const ImageView& image) {
    if (image.format != PixelFormat::kGray8) {
        return fail(ErrorCode::kBadInput, "the tag detector needs an 8-bit grey image, got " +
                                              std::string(pixelFormatName(image.format)));
    }
    if (image.width <= 0 || image.height <= 0 || image.data == nullptr ||
        image.stride < static_cast<std::size_t>(image.width)) {
        return fail(ErrorCode::kBadInput, "the tag detector got an empty or malformed image");
    }
    return {};
}
}  // namespace

Result<std::vector<TagDetection>> TagDetector::detect(const ImageView& gray8) {
    CL_TRY_VOID(checkGray(gray8));
    std::vector<TagDetection> out;
    CL_TRY_VOID(impl_->run(gray8, 0, 0, gray8.width, gray8.height, options_, out));
    return out;
}

Result<std::vector<TagDetection>> TagDetector::detectInWindows(const ImageView& gray8,
                                                               std::span<const PixelWindow> windows) {
    CL_TRY_VOID(checkGray(gray8));
    std::vector<TagDetection> all;
    const int grid = windowGrid(options_.decimate);
    for (const PixelWindow& w : windows) {
        // Grown out to the grid, then clipped to the image (whose origin is on it).
        const int x0 = std::clamp(floorToMultiple(w.x, grid), 0, gray8.width);
        const int y0 = std::clamp(floorToMultiple(w.y, grid), 0, gray8.height);
        const int x1 = std::clamp(-floorToMultiple(-(w.x + std::max(w.width, 0)), grid), 0, gray8.width);
        const int y1 = std::clamp(-floorToMultiple(-(w.y + std::max(w.height, 0)), grid), 0, gray8.height);
        // Too small for a quad of a few pixels after decimation: skip.
        if (x1 - x0 < 8 || y1 - y0 < 8) continue;
        CL_TRY_VOID(impl_->run(gray8, x0, y0, x1 - x0, y1 - y0, options_, all));
    }
    // A tag inside two overlapping windows: keep the stronger decoding.
    std::vector<TagDetection> out;
    for (const TagDetection& d : all) {
        auto same = std::find_if(out.begin(), out.end(), [&](const TagDetection& o) {
            return o.id == d.id && (o.center - d.center).norm() < 2.0;
        });
        if (same == out.end()) {
            out.push_back(d);
        } else if (d.decision_margin > same->decision_margin) {
            *same = d;
        }
    }
    return out;
}

}  // namespace commonlight::tracking

#include "tracking/tracker_support.h"

#include <algorithm>
#include <cmath>
#include <cstddef>

namespace commonlight::tracking::tracker_support {
namespace {

bool overlap(const PixelWindow& a, const PixelWindow& b) {
    return a.x < b.x + b.width && b.x < a.x + a.width && a.y < b.y + b.height && b.y < a.y + a.height;
}

}  // namespace

PixelWindow grownBox(const std::array<Eigen::Vector2d, 4>& pts, double margin, int min_px) {
    Eigen::Vector2d lo = pts[0], hi = pts[0];
    for (const auto& p : pts) {
        lo = lo.cwiseMin(p);
        hi = hi.cwiseMax(p);
    }
    const double grow = std::max(margin * (hi - lo).maxCoeff(), static_cast<double>(min_px));
    const int x0 = static_cast<int>(std::floor(lo.x() - grow));
    const int y0 = static_cast<int>(std::floor(lo.y() - grow));
    const int x1 = static_cast<int>(std::ceil(hi.x() + grow));
    const int y1 = static_cast<int>(std::ceil(hi.y() + grow));
    return {x0, y0, x1 - x0, y1 - y0};
}

std::vector<PixelWindow> mergeOverlapping(std::vector<PixelWindow> windows) {
    bool merged = true;
    while (merged) {
        merged = false;
        for (std::size_t i = 0; i < windows.size() && !merged; ++i) {
            for (std::size_t j = i + 1; j < windows.size() && !merged; ++j) {
                if (!overlap(windows[i], windows[j])) continue;
                const int x0 = std::min(windows[i].x, windows[j].x), y0 = std::min(windows[i].y, windows[j].y);
                const int x1 = std::max(windows[i].x + windows[i].width, windows[j].x + windows[j].width);
                const int y1 = std::max(windows[i].y + windows[i].height, windows[j].y + windows[j].height);
                windows[i] = {x0, y0, x1 - x0, y1 - y0};
                windows.erase(windows.begin() + static_cast<std::ptrdiff_t>(j));
                merged = true;
            }
        }
    }
    return windows;
}

std::vector<PixelWindow> trackingWindows(const CameraModel& camera, const TagSet& tags,
                                         const std::optional<Rigid3d>& predicted,
                                         const std::vector<TagDetection>& last_detections,
                                         const TrackerOptions& options, const EdgeModel* occluders) {
    std::vector<PixelWindow> out;
    std::vector<int> covered;
    if (predicted) {
        const Eigen::Vector3d eye = predicted->inverse().translation;
        for (const TagItem& item : tags.items) {
            // Its back to the camera, or behind a proxy: not in view (the verification skips the
            // hidden ones too), unless the last frame detected it (below).
            if (facesAway(*predicted * item.world_from_tag)) continue;
            if (occluders && hiddenByProxies(*occluders, eye, item, 9)) continue;
            std::array<Eigen::Vector2d, 4> corners;
            bool ok = true;
            for (int c = 0; c < 4 && ok; ++c) {
                const auto px = camera.project(*predicted * (item.world_from_tag * tagCornerInTag(c, item.size)));
                ok = px.has_value();
                if (ok) corners[c] = *px;
            }
            if (!ok) continue;
            // Too small for the decimated detector: left to the verification (or to the window of
            // the last frame's detection below).
            if (shorterSpan(corners) < options.window_min_span_px * options.detector.decimate) continue;
            // The detector finds a tag only whole in the image: one predicted further out than the
            // window's growth (its size at most the image's) gets no window. On `bench tracking
            // --cases oblique75` the table's tags, beside the camera, had corners 10^5-10^6 px out and
            // their boxes made the merged window the whole frame: the windows cost more than a
            // full-frame detection.
            Eigen::Vector2d lo = corners[0], hi = corners[0];
            for (const auto& p : corners) {
                lo = lo.cwiseMin(p);
                hi = hi.cwiseMax(p);
            }
            const double extent = std::min((hi - lo).maxCoeff(), static_cast<double>(std::max(camera.width, camera.height)));
            const double grow = std::max(options.window_margin * extent, static_cast<double>(options.window_min_margin_px));
            if (lo.x() < -grow || lo.y() < -grow || hi.x() > camera.width + grow || hi.y() > camera.height + grow) {
                continue;
            }
            const PixelWindow w = grownBox(corners, options.window_margin, options.window_min_margin_px);
            out.push_back(w);
            covered.push_back(item.id);
        }
    }
    // Tags the scene does not place (or no prediction): where they were last frame.
    for (const TagDetection& d : last_detections) {
        if (std::find(covered.begin(), covered.end(), d.id) != covered.end()) continue;
        out.push_back(grownBox(d.corners, options.window_margin, options.window_min_margin_px));
    }
    return mergeOverlapping(std::move(out));
}

bool facesAway(const Rigid3d& cam_from_tag) {
    // The camera centre in the tag's frame: in front of the printed side when its z is positive.
    return !(cam_from_tag.inverse().translation.z() > 0.0);
}

bool hiddenByProxies(const EdgeModel& occluders, const Eigen::Vector3d& eye, const TagItem& item, int min_hidden) {
    // Stops as soon as the answer is known: a window (9 of 9) at the first point in view, which
    // for a tag in view is the first one.
    int hidden = 0, tested = 0;
    for (int j = -1; j <= 1; ++j) {
        for (int i = -1; i <= 1; ++i) {
            const Eigen::Vector3d p = item.world_from_tag * Eigen::Vector3d(0.4 * i * item.size, 0.4 * j * item.size, 0.0);
            hidden += occluders.occluded(eye, p, 1e-3) ? 1 : 0;
            ++tested;
            if (hidden >= min_hidden) return true;
            if (hidden + (9 - tested) < min_hidden) return false;
        }
    }
    return hidden >= min_hidden;
}

double shorterSpan(const std::array<Eigen::Vector2d, 4>& c) {
    return std::min((0.5 * (c[0] + c[1]) - 0.5 * (c[2] + c[3])).norm(), (0.5 * (c[1] + c[2]) - 0.5 * (c[3] + c[0])).norm());
}

double squareAspect(const std::array<Eigen::Vector2d, 4>& c) {
    const double side_a = 0.5 * ((c[1] - c[0]).norm() + (c[2] - c[3]).norm());
    const double side_b = 0.5 * ((c[3] - c[0]).norm() + (c[2] - c[1]).norm());
    const double longer = std::max(side_a, side_b);
    return longer > 0 ? std::min(side_a, side_b) / longer : 0.0;
}

std::optional<TrackedTag> alignedKnownTag(const TagAlignResult& aligned, int id, double size, const CameraModel& camera) {
    if (!aligned.ok) return std::nullopt;
    TrackedTag tag;
    for (int c = 0; c < 4; ++c) {
        const auto px = camera.project(aligned.cam_from_tag * tagCornerInTag(c, size));
        if (!px) return std::nullopt;
        tag.detection.corners[static_cast<std::size_t>(c)] = *px;
    }
    const auto& corners = tag.detection.corners;
    tag.detection.id = id;
    tag.detection.center = 0.25 * (corners[0] + corners[1] + corners[2] + corners[3]);
    tag.aligned = true;
    tag.detected_late = true;
    tag.aligned_known = true;
    TagPose pose;
    pose.id = id;
    pose.cam_from_tag = aligned.cam_from_tag;
    pose.rms_px = aligned.rms_px;
    pose.choice = PoseChoice::kPrediction;
    pose.candidates = {{aligned.cam_from_tag, aligned.rms_px}};
    pose.covariance = aligned.covariance;
    tag.pose = std::move(pose);
    return tag;
}

}  // namespace commonlight::tracking::tracker_support

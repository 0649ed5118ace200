#include "apps/bench_tracking_tiny.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <string>

#include "core/percentiles.h"
#include "tracking/edge_model.h"
#include "tracking/tag_detector.h"

namespace commonlight::apps {
namespace {

using nlohmann::json;

// Bins of the black square's shorter span (the distance between the midpoints of opposite
// sides), pixels; the first is below the 7 px and not part of its target.
constexpr std::array<double, 6> kBinEdges = {5.0, 7.0, 10.0, 14.0, 20.0, 1e9};
constexpr std::array<const char*, 5> kBinNames = {"5-7", "7-10", "10-14", "14-20", "20+"};
constexpr int kBins = 5;
// A verified tag (or one detected late, at full resolution in a window) whose corners are further
// than this from the truth is counted as a wrong accept.
constexpr double kWrongPx = 1.5;

struct TagInView {
    int bin = -1;
    double span_px = 0, tilt_deg = 0;
    std::array<Eigen::Vector2d, 4> corners{};
};

// A scene tag's black square under the true pose: in view when its corners are inside the image,
// its printed side faces the camera and the proxies hide fewer than 3 of 9 points on it (the
// tracker's rule for not trying a tag, TrackerOptions::verify_skip_occluded).
std::optional<TagInView> tagInView(const CameraModel& camera, const TagItem& item, const Rigid3d& cam_from_world,
                                   const tracking::EdgeModel* occluders) {
    const Rigid3d cam_from_tag = cam_from_world * item.world_from_tag;
    if (occluders) {
        const Eigen::Vector3d eye = cam_from_world.inverse().translation;
        int hidden = 0;
        for (int j = -1; j <= 1; ++j) {
            for (int i = -1; i <= 1; ++i) {
                const Eigen::Vector3d p =
                    item.world_from_tag * Eigen::Vector3d(0.4 * i * item.size, 0.4 * j * item.size, 0);
                hidden += occluders->occluded(eye, p, 1e-3) ? 1 : 0;
            }
        }
        if (hidden >= 3) return std::nullopt;
    }
    const Eigen::Vector3d normal = cam_from_tag.rotation * Eigen::Vector3d::UnitZ();
    if (normal.dot(cam_from_tag.translation) >= 0) return std::nullopt;
    TagInView t;
    for (int k = 0; k < 4; ++k) {
        const Eigen::Vector3d p = cam_from_tag * tracking::tagCornerInTag(k, item.size);
        const auto px = p.z() > 0 ? camera.project(p) : std::nullopt;
        if (!px || px->x() < 0 || px->y() < 0 || px->x() > camera.width - 1 || px->y() > camera.height - 1) {
            return std::nullopt;
        }
        t.corners[static_cast<std::size_t>(k)] = *px;
    }
    const auto mid = [&](int a, int b) {
        return 0.5 * (t.corners[static_cast<std::size_t>(a)] + t.corners[static_cast<std::size_t>(b)]);
    };
    t.span_px = std::min((mid(0, 1) - mid(2, 3)).norm(), (mid(1, 2) - mid(3, 0)).norm());
    t.tilt_deg = std::acos(std::clamp(-normal.dot(cam_from_tag.translation.normalized()), -1.0, 1.0)) * 180.0 / M_PI;
    for (int b = 0; b < kBins; ++b) {
        if (t.span_px >= kBinEdges[static_cast<std::size_t>(b)] &&
            t.span_px < kBinEdges[static_cast<std::size_t>(b) + 1])
            t.bin = b;
    }
    return t;
}

double pct(std::vector<double> v, double p) {
    if (v.empty()) return NAN;
    std::sort(v.begin(), v.end());
    return nearestRank(v, p);
}

double mean(const std::vector<double>& v) {
    if (v.empty()) return NAN;
    double s = 0;
    for (const double x : v) s += x;
    return s / static_cast<double>(v.size());
}

struct RunCounts {
    std::array<int, kBins> in_view{}, detected{}, verified{}, late{}, wrong{};
    std::array<double, kBins> tilt_max{};
    std::vector<double> corner_err_px;                // verified tags, worst corner, against the truth
    std::vector<double> late_err_px;                  // tags detected late (full resolution, a window): the same
    int verified_elsewhere = 0, wrong_elsewhere = 0;  // verified tags outside the bins (span under 5 px)
    std::vector<double> rot_deg, trans_mm, verify_cpu_ms, total_cpu_ms;
    std::vector<std::vector<int>> verified_ids;  // per frame
};

Result<RunCounts> run(const DetectionBySizeInput& in, const tracking::TrackerOptions& options) {
    CL_TRY(auto tracker, tracking::Tracker::create(*in.camera, in.scene->tags, in.scene, options));
    CL_TRY(const tracking::EdgeModel occluders, tracking::EdgeModel::fromScene(*in.scene));
    RunCounts out;
    for (std::size_t i = 0; i < in.frames->size(); ++i) {
        CL_TRY(auto track, tracker.process((*in.frames)[i].view(), (*in.meta)[i]));
        const Rigid3d& truth = (*in.cam_from_world_true)[i];
        out.verify_cpu_ms.push_back(track.times.verify_cpu_ms);
        out.verified_ids.emplace_back();
        for (const auto& t : track.tags) {
            if (t.verified) out.verified_ids.back().push_back(t.detection.id);
        }
        out.total_cpu_ms.push_back(track.times.total_cpu_ms);
        if (track.cam_from_world) {
            out.rot_deg.push_back(rotationErrorDeg(*track.cam_from_world, truth));
            out.trans_mm.push_back(1000.0 *
                                   (track.cam_from_world->inverse().translation - truth.inverse().translation).norm());
        }
        for (const TagItem& item : in.scene->tags.items) {
            const auto view = tagInView(*in.camera, item, truth, &occluders);
            if (!view || view->bin < 0) {
                // Verified though not in view or too small for the bins: right or wrong?
                for (const tracking::TrackedTag& t : track.tags) {
                    if (t.detection.id != item.id || !t.verified) continue;
                    ++out.verified_elsewhere;
                    const Rigid3d cam_from_tag = truth * item.world_from_tag;
                    double err = 1e9;
                    if (view) {
                        err = 0;
                        for (std::size_t k = 0; k < 4; ++k)
                            err = std::max(err, (t.detection.corners[k] - view->corners[k]).norm());
                    } else if (cam_from_tag.translation.z() > 0) {
                        err = 0;
                        for (int k = 0; k < 4; ++k) {
                            const auto px = in.camera->project(cam_from_tag * tracking::tagCornerInTag(k, item.size));
                            err = px ? std::max(err, (t.detection.corners[static_cast<std::size_t>(k)] - *px).norm())
                                     : 1e9;
                        }
                    }
                    out.corner_err_px.push_back(err);
                    if (err > kWrongPx) ++out.wrong_elsewhere;
                }
                continue;
            }
            const auto b = static_cast<std::size_t>(view->bin);
            ++out.in_view[b];
            out.tilt_max[b] = std::max(out.tilt_max[b], view->tilt_deg);
            const auto found = std::find_if(track.tags.begin(), track.tags.end(),
                                            [&](const tracking::TrackedTag& t) { return t.detection.id == item.id; });
            if (found == track.tags.end()) continue;
            if (found->verified || found->detected_late) {
                double err = 0;
                for (std::size_t k = 0; k < 4; ++k)
                    err = std::max(err, (found->detection.corners[k] - view->corners[k]).norm());
                (found->verified ? out.corner_err_px : out.late_err_px).push_back(err);
                if (err > kWrongPx) {
                    ++out.wrong[b];
                    continue;
                }
                ++(found->verified ? out.verified : out.late)[b];
            }
            ++out.detected[b];
        }
    }
    return out;
}

std::string rate(int n, int d) {
    if (d == 0) return "-";
    char buf[48];
    std::snprintf(buf, sizeof buf, "%d/%d (%.1f%%)", n, d, 100.0 * n / d);
    return buf;
}

}  // namespace

Result<json> benchDetectionBySize(const DetectionBySizeInput& input, const tracking::TrackerOptions& base) {
    tracking::TrackerOptions off = base, on = base;
    off.verify_predicted = false;
    on.verify_predicted = true;
    CL_TRY(RunCounts without, run(input, off));
    CL_TRY(RunCounts with, run(input, on));
    tracking::TrackerOptions no_skip = on;
    no_skip.verify_skip_occluded = false;
    CL_TRY(RunCounts all_tried, run(input, no_skip));
    std::printf(
        "\ndetection by the black square's shorter span (tags in view by the true pose; bundle + filter, "
        "decimate 2):\n\n");
    std::printf("| %-8s | %11s | %18s | %18s | %8s | %6s | %6s |\n", "span px", "max tilt", "without verify",
                "with verify", "verified", "late", "wrong");
    std::printf("|%s|\n", std::string(95, '-').c_str());
    json bins = json::object();
    int total7 = 0, without7 = 0, with7 = 0;
    for (int b = 0; b < kBins; ++b) {
        const auto k = static_cast<std::size_t>(b);
        std::printf("| %-8s | %9.1f d | %18s | %18s | %8d | %6d | %6d |\n", kBinNames[k], with.tilt_max[k],
                    rate(without.detected[k], without.in_view[k]).c_str(),
                    rate(with.detected[k], with.in_view[k]).c_str(), with.verified[k], with.late[k], with.wrong[k]);
        bins[kBinNames[k]] = {{"in_view", with.in_view[k]},
                              {"detected_without_verify", without.detected[k]},
                              {"detected_with_verify", with.detected[k]},
                              {"verified", with.verified[k]},
                              {"detected_late", with.late[k]},
                              {"wrong_accepts", with.wrong[k]},
                              {"max_tilt_deg", with.tilt_max[k]}};
        if (b >= 1) {
            total7 += with.in_view[k];
            without7 += without.detected[k];
            with7 += with.detected[k];
        }
    }
    const double rate7 = total7 > 0 ? static_cast<double>(with7) / total7 : NAN;
    std::printf("\nblack squares of 7 px or more: detected %s without verify, %s with [target at least 95%%: %s]\n",
                rate(without7, total7).c_str(), rate(with7, total7).c_str(),
                total7 == 0 ? "no tags" : (rate7 >= 0.95 ? "met" : "MISSED"));
    std::printf("verified outside the bins (span under 5 px or partly out of the image): %d, %d of them wrong\n",
                with.verified_elsewhere, with.wrong_elsewhere);
    std::printf("verified corners against the truth: p50 %.3f, max %.3f px (over %.1f px counted wrong)\n",
                pct(with.corner_err_px, 50), pct(with.corner_err_px, 100), kWrongPx);
    std::printf("tags detected late (full resolution, in a window around the prediction): %zu, corners against the "
                "truth p50 %.3f, max %.3f px\n",
                with.late_err_px.size(), pct(with.late_err_px, 50), pct(with.late_err_px, 100));
    std::printf(
        "camera pose without verify: rotation p50 %.3f p95 %.3f deg, position p50 %.2f p95 %.2f mm (%zu "
        "poses); with: %.3f %.3f deg, %.2f %.2f mm (%zu poses)\n",
        pct(without.rot_deg, 50), pct(without.rot_deg, 95), pct(without.trans_mm, 50), pct(without.trans_mm, 95),
        without.rot_deg.size(), pct(with.rot_deg, 50), pct(with.rot_deg, 95), pct(with.trans_mm, 50),
        pct(with.trans_mm, 95), with.rot_deg.size());
    std::printf(
        "verify step CPU per frame: mean %.2f ms, p50 %.2f, max %.2f; tracking stage CPU p50 %.2f ms without, "
        "%.2f ms with\n",
        mean(with.verify_cpu_ms), pct(with.verify_cpu_ms, 50), pct(with.verify_cpu_ms, 100),
        pct(without.total_cpu_ms, 50), pct(with.total_cpu_ms, 50));
    const bool same_accepts = all_tried.verified_ids == with.verified_ids;
    std::printf(
        "verify step without skipping the tags the proxies hide: CPU per frame mean %.2f ms (with the skip "
        "%.2f); the same tags verified in every frame: %s\n",
        mean(all_tried.verify_cpu_ms), mean(with.verify_cpu_ms), same_accepts ? "yes" : "NO");
    json j;
    j["verify_cpu_ms_per_frame_without_occlusion_skip"] = mean(all_tried.verify_cpu_ms);
    j["occlusion_skip_same_accepts"] = same_accepts;
    j["bins"] = bins;
    j["verified_outside_bins"] = with.verified_elsewhere;
    j["wrong_outside_bins"] = with.wrong_elsewhere;
    j["span7_in_view"] = total7;
    j["span7_detected_without_verify"] = without7;
    j["span7_detected_with_verify"] = with7;
    j["span7_rate_with_verify"] = rate7;
    j["verified_corner_err_px"] = {{"p50", pct(with.corner_err_px, 50)}, {"max", pct(with.corner_err_px, 100)}};
    j["detected_late_corner_err_px"] = {{"count", with.late_err_px.size()},
                                        {"p50", pct(with.late_err_px, 50)},
                                        {"max", pct(with.late_err_px, 100)}};
    const auto pose = [](const RunCounts& r) {
        return json{{"poses", r.rot_deg.size()},
                    {"rot_deg", {{"p50", pct(r.rot_deg, 50)}, {"p95", pct(r.rot_deg, 95)}}},
                    {"trans_mm", {{"p50", pct(r.trans_mm, 50)}, {"p95", pct(r.trans_mm, 95)}}}};
    };
    j["camera_without_verify"] = pose(without);
    j["camera_with_verify"] = pose(with);
    j["verify_cpu_ms_per_frame"] = {{"mean", mean(with.verify_cpu_ms)},
                                    {"p50", pct(with.verify_cpu_ms, 50)},
                                    {"max", pct(with.verify_cpu_ms, 100)}};
    j["total_cpu_ms_p50"] = {{"without_verify", pct(without.total_cpu_ms, 50)},
                             {"with_verify", pct(with.total_cpu_ms, 50)}};
    return j;
}

}  // namespace commonlight::apps

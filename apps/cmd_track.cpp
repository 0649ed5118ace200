// commonlight track INPUT (--scene S | --calib C --tag-size M) [--out poses.csv]: tracking only,
// tag corners and poses per frame (docs/tracking.md).
//
// INPUT is a sequence, a folder of images or one image. With --scene, the scene's tags (and
// their placement) give a bundle pose cam_from_world per frame; with --tag-size, every tag gets
// its single-tag pose cam_from_tag and there is no world. Photos (folder, image) are treated as
// independent views: no temporal filter and no tracking mode.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <memory>

#include "apps/app.h"
#include "apps/quiet.h"
#include "core/response.h"
#include "tracking/edge_profile.h"
#include "apps/progress.h"
#include "apps/report.h"
#include "apps/track_input.h"
#include "core/percentiles.h"
#include "core/calibration_io.h"
#include "core/log.h"
#include "core/scene_io.h"
#include "tracking/tracker.h"

namespace commonlight::apps {
namespace {

namespace fs = std::filesystem;

struct TrackCommandOptions {
    std::string input;
    std::string scene;
    std::string calib;
    double tag_size = 0.0;
    std::string out;
    std::string family;
    bool tracking_mode = false;
    bool no_filter = false;
    bool edges = false;
    std::string response;  // --response: overrides sensor.yaml's
    tracking::TrackerOptions tracker;
};

// A CSV field with nothing in it needs no quoting; names with commas or quotes do.
std::string csvField(const std::string& text) {
    if (text.find_first_of(",\"\n") == std::string::npos) return text;
    std::string quoted = "\"";
    for (char c : text) {
        if (c == '"') quoted += '"';
        quoted += c;
    }
    return quoted + "\"";
}

int runTrack(TrackCommandOptions& options) {
    // Step 1: input, camera, scene.
    auto input = openTrackInput(options.input);
    if (!input) return reportError(input.error());
    std::optional<Scene> scene;
    std::optional<fs::path> scene_path;
    if (!options.scene.empty()) {
        scene_path = fs::path(options.scene);
    } else if (input->scene_path) {
        scene_path = input->scene_path;  // the sequence's own scene.yaml
    }
    if (scene_path) {
        auto s = readScene(*scene_path);
        if (!s) return reportError(s.error());
        scene = std::move(*s);
    }
    std::optional<CameraModel> camera;
    if (!options.calib.empty()) {
        auto c = readCalibration(options.calib);
        if (!c) return reportError(c.error());
        camera = *c;
    } else if (input->sensor_camera) {
        camera = input->sensor_camera;
    } else if (scene && scene->camera) {
        camera = scene->camera;
    }
    if (!camera) {
        return reportError(Error{ErrorCode::kUsage, "no camera calibration: give --calib (or a sequence with intrinsics "
                                                    "in cam0/sensor.yaml, or a scene with camera:)"});
    }
    if (options.tag_size <= 0 && (!scene || scene->tags.items.empty())) {
        return reportError(Error{ErrorCode::kUsage, "give --tag-size, or a --scene that places tags"});
    }
    // The family: --family, else the scene's, else tag36h11.
    if (!options.family.empty()) {
        options.tracker.detector.family = options.family;
    } else if (scene) {
        options.tracker.detector.family = scene->tags.family;
    }
    // The response the edges are linearised with: --response, else the sequence's sensor.yaml,
    // else sRGB (webcams).
    {
        Result<ResponseCurve> response = ResponseCurve::srgb();
        if (!options.response.empty()) {
            response = ResponseCurve::parse(options.response, fs::current_path());
            if (!response) return reportError(Error{response.error().code, "--response: " + response.error().message});
        } else if (input->sequence) {
            response = ResponseCurve::parse(input->sequence->sensor.response, input->sequence->cam_dir);
            if (!response) {
                return reportError(Error{response.error().code, (input->sequence->cam_dir / "sensor.yaml").string() +
                                                                     ": key 'response': " + response.error().message});
            }
        }
        const bool srgb = response->kind() == ResponseCurve::Kind::kSrgb;
        options.tracker.refine.srgb = options.tracker.align.srgb = srgb;
        if (response->kind() != ResponseCurve::Kind::kSrgb && response->kind() != ResponseCurve::Kind::kLinear) {
            // Tracking works on grey values: the green channel's curve stands for all three.
            auto lin = std::make_shared<const tracking::Linearizer>(response->table()[1]);
            options.tracker.refine.linearizer = options.tracker.align.linearizer = lin;
        }
    }
    options.tracker.default_tag_size = options.tag_size;
    options.tracker.tracking_mode = options.tracking_mode && !input->independentFrames();
    options.tracker.filter = !options.no_filter && !input->independentFrames();
    options.tracker.independent_frames = input->independentFrames();
    options.tracker.edges = options.edges;
    if (options.edges && !scene) return reportError(Error{ErrorCode::kUsage, "--edges needs --scene"});
    const TagSet no_tags;
    auto tracker = tracking::Tracker::create(*camera, scene ? scene->tags : no_tags, scene ? &*scene : nullptr,
                                             options.tracker);
    if (!tracker) return reportError(tracker.error());

    // Step 2: the CSV, written as frames are tracked (a stop keeps what was done).
    std::FILE* csv = stdout;
    std::unique_ptr<std::FILE, int (*)(std::FILE*)> file(nullptr, &std::fclose);
    if (!options.out.empty()) {
        file.reset(std::fopen(options.out.c_str(), "w"));
        if (!file) return reportError(Error{ErrorCode::kIo, options.out + ": cannot create the file"});
        csv = file.get();
    }
    std::fprintf(csv, "image,timestamp_ns,tag_id,c0x,c0y,c1x,c1y,c2x,c2y,c3x,c3y,tx,ty,tz,qw,qx,qy,qz,status,"
                      "pose_timestamp_ns,ambiguity_ratio,alt_tx,alt_ty,alt_tz,alt_qw,alt_qx,alt_qy,alt_qz,verified\n");
    // ambiguity_ratio, the alternative pose and `verified` (tag rows only), empty
    constexpr const char* kNoAlternative = ",,,,,,,,";

    // Step 3: track every frame.
    GreyFrameLoader loader;
    Image grey;
    Progress progress("track", input->frames.size());
    std::size_t unreadable = 0, with_pose = 0, tag_rows = 0, ambiguous_tags = 0, ambiguous_frames = 0, verified_tags = 0;
    std::string first_unreadable;
    std::vector<double> rot_err, trans_err, total_ms;
    for (std::size_t i = 0; i < input->frames.size(); ++i) {
        if (stopToken().stop_requested()) break;
        const TrackInputFrame& frame = input->frames[i];
        const std::string image = csvField(frame.name);
        if (auto ok = loader.load(*input, i, grey); !ok) {
            log::warning(ok.error().message);
            if (unreadable++ == 0) first_unreadable = ok.error().message;
            std::fprintf(csv, "%s,%lld,-1,,,,,,,,,,,,,,,,unreadable,,%s\n", image.c_str(),
                         static_cast<long long>(frame.timestamp_ns), kNoAlternative);
            continue;
        }
        auto track = tracker->process(grey.view(), frame.meta());
        if (!track) {
            // The wrong size for the calibration is the input's fault; report it and stop.
            if (track.error().code == ErrorCode::kBadInput) {
                log::warning(frame.path.string() + ": " + track.error().message);
                if (unreadable++ == 0) first_unreadable = frame.path.string() + ": " + track.error().message;
                std::fprintf(csv, "%s,%lld,-1,,,,,,,,,,,,,,,,bad_frame,,%s\n", image.c_str(),
                             static_cast<long long>(frame.timestamp_ns), kNoAlternative);
                continue;
            }
            return reportError(track.error());
        }
        // The ambiguity ratio and the other candidate (when there is one), after the status.
        const auto alternativeColumns = [&](double ratio, const std::optional<Rigid3d>& alt) {
            char r[32];
            std::snprintf(r, sizeof r, "%.6g", ratio);
            return std::string(r) + "," + (alt ? poseColumns(*alt) : std::string(",,,,,,"));
        };
        for (const auto& tag : track->tags) {
            // libapriltag's pixel convention in the file (top-left pixel centre at (0.5, 0.5)).
            std::array<Eigen::Vector2d, 4> c = tag.detection.corners;
            for (auto& corner : c) corner += Eigen::Vector2d(0.5, 0.5);
            const char* status = tag.pose ? (tag.pose->ambiguous ? "ambiguous" : "ok")
                                          : (scene && !scene->tags.find(tag.detection.id) && options.tag_size <= 0
                                                 ? "unknown_tag"
                                                 : "pose_failed");
            std::string extra = ",,,,,,,";
            if (tag.pose) {
                std::optional<Rigid3d> alt;
                if (tag.pose->candidates.size() > 1) alt = tag.pose->candidates[1].cam_from_tag;
                extra = alternativeColumns(tag.pose->ambiguity_ratio, alt);
            }
            // verified: 1 when the tag was not decoded but verified at its predicted place against
            // its known pattern (too small for the detector; docs/tracking.md "Small and tiny tags").
            extra += tag.verified ? ",1" : ",0";
            std::fprintf(csv, "%s,%lld,%d,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%s,%s,%lld,%s\n", image.c_str(),
                         static_cast<long long>(frame.timestamp_ns), tag.detection.id, c[0].x(), c[0].y(), c[1].x(),
                         c[1].y(), c[2].x(), c[2].y(), c[3].x(), c[3].y(),
                         tag.pose ? poseColumns(tag.pose->cam_from_tag).c_str() : ",,,,,,", status,
                         static_cast<long long>(track->pose_timestamp_ns), extra.c_str());
            ++tag_rows;
            if (tag.pose && tag.pose->ambiguous) ++ambiguous_tags;
            if (tag.verified) ++verified_tags;
        }
        const std::string frame_extra =
            track->status == tracking::TrackStatus::kAmbiguous
                ? alternativeColumns(track->ambiguity_ratio, track->alternative_cam_from_world) + ","
                : std::string(kNoAlternative);
        std::fprintf(csv, "%s,%lld,-1,,,,,,,,,%s,%s,%lld,%s\n", image.c_str(), static_cast<long long>(frame.timestamp_ns),
                     track->cam_from_world ? poseColumns(*track->cam_from_world).c_str() : ",,,,,,",
                     tracking::trackStatusName(track->status), static_cast<long long>(track->pose_timestamp_ns),
                     frame_extra.c_str());
        if (track->status == tracking::TrackStatus::kAmbiguous) ++ambiguous_frames;
        total_ms.push_back(track->times.total_ms);
        if (track->cam_from_world) {
            ++with_pose;
            // Ground truth of a sequence (the simulated camera's, or a motion-capture system's).
            // At the instant the pose is for, the middle of the exposure (groundTruthOfFrame).
            if (input->sequence && !input->sequence->groundtruth_poses.empty()) {
                if (const auto world_from_cam = groundTruthOfFrame(*input->sequence, i)) {
                    rot_err.push_back(rotationErrorDeg(*track->cam_from_world, world_from_cam->inverse()));
                    trans_err.push_back(1000.0 * translationError(track->cam_from_world->inverse(), *world_from_cam));
                }
            }
        }
        std::fflush(csv);
        progress.update(i + 1);
    }
    progress.finish();

    // Step 4: summary (stderr, so the CSV can go to stdout).
    const auto pct = [](std::vector<double> v, double q) {
        std::sort(v.begin(), v.end());
        return nearestRank(v, 100.0 * q);
    };
    sayErr("tracked %zu frames: %zu with a camera pose (%zu ambiguous), %zu tag rows (%zu ambiguous, %zu verified); %.2f "
           "ms per frame (p50)\n",
           input->frames.size() - unreadable, with_pose, ambiguous_frames, tag_rows, ambiguous_tags, verified_tags,
           total_ms.empty() ? 0.0 : pct(total_ms, 0.5));
    if (!rot_err.empty()) {
        sayErr("pose error against groundtruth/cam_poses.csv (%zu frames): rotation p50 %.3f p95 %.3f max %.3f "
               "deg; camera position p50 %.2f p95 %.2f max %.2f mm\n",
               rot_err.size(), pct(rot_err, 0.5), pct(rot_err, 0.95), pct(rot_err, 1.0), pct(trans_err, 0.5),
               pct(trans_err, 0.95), pct(trans_err, 1.0));
    }
    if (unreadable > 0) {
        return reportError(Error{ErrorCode::kBadInput, std::to_string(unreadable) +
                                                           " frame(s) could not be tracked (their rows say so); first: " +
                                                           first_unreadable});
    }
    return stopToken().stop_requested() ? 130 : kExitOk;
}

}  // namespace

void addTrackCommand(CLI::App& app, Runner& runner) {
    auto options = std::make_shared<TrackCommandOptions>();
    CLI::App* sub = app.add_subcommand("track", "Tag corners and camera poses of a sequence, an image folder or an image");
    sub->add_option("input", options->input, "Sequence folder, folder of .png/.jpg images, or one image")->required();
    sub->add_option("--scene", options->scene,
                    "Scene file: the tags' sizes and placement (and the camera); default: the sequence's scene.yaml");
    sub->add_option("--calib", options->calib, "Camera calibration (OpenCV or ROS YAML); default: the sequence's or scene's");
    sub->add_option("--tag-size", options->tag_size, "Edge of every tag's black square, metres (without --scene)")
        ->check(CLI::PositiveNumber);
    sub->add_option("--out", options->out, "CSV file to write (default: standard output)");
    auto& det = options->tracker.detector;
    sub->add_option("--family", options->family, "AprilTag family (default: the scene's, else tag36h11)");
    sub->add_option("--decimate", det.decimate, "Detect quads on an image this many times smaller")
        ->check(CLI::Range(1.0, 8.0))
        ->capture_default_str();
    sub->add_option("--sigma", det.sigma, "Gaussian blur before quad detection, pixels")->check(CLI::NonNegativeNumber);
    sub->add_option("--threads", det.threads, "Detector threads")->check(CLI::Range(1, 64))->capture_default_str();
    sub->add_flag("--no-refine-edges{false}", det.refine_edges, "Do not snap quad edges to the image gradient");
    sub->add_flag("--tracking-mode", options->tracking_mode, "Detect only around the predicted tags (sequences)");
    sub->add_option("--redetect-every", options->tracker.redetect_every, "Full-frame detection every N frames in tracking mode")
        ->check(CLI::PositiveNumber)
        ->capture_default_str();
    sub->add_flag("--no-filter", options->no_filter, "No temporal filter (the bundle's pose per frame)");
    sub->add_flag("--edges", options->edges, "Refine with the edges of the scene's proxy geometry");
    sub->add_option("--response", options->response,
                    "The camera's response: srgb, linear, gamma:G or a response file (default: the sequence's sensor.yaml, else srgb)");
    sub->footer(
        "CSV columns: image,timestamp_ns,tag_id,c0x..c3y (pixels, libapriltag's corner order and pixel convention),"
        "tx,ty,tz,qw,qx,qy,qz,status,pose_timestamp_ns,ambiguity_ratio,alt_tx..alt_qz,verified. Tag rows hold cam_from_tag; the "
        "frame row (tag_id -1) holds cam_from_world; both for pose_timestamp_ns, the middle of the exposure "
        "(timestamp_ns is its start). Status ambiguous: the image cannot tell the pose from the alt_ one. verified 1: a "
        "scene tag too small to decode, verified at its predicted place against its pattern (0: decoded). "
        "See docs/tracking.md. Exit codes: 0 ok, 2 usage, 3 bad input.");
    sub->callback([options, &runner] { runner = [options] { return runTrack(*options); }; });
}

}  // namespace commonlight::apps

#include "apps/bench_tracking.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <fstream>
#include <map>
#include <optional>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "apps/app.h"
#include "apps/bench_tracking_tiny.h"
#include "apps/progress.h"
#include "apps/report.h"
#include "apps/track_input.h"
#include "core/percentiles.h"
#include "core/calibration_io.h"
#include "core/file_util.h"
#include "core/log.h"
#include "core/scene_io.h"
#include "mocks/sim/simulation.h"
#include "mocks/sim/trajectory.h"
#include "tracking/tag_align.h"
#include "tracking/tracker.h"

namespace commonlight::apps {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using nlohmann::json;

// The calling thread's CPU time: on a shared, loaded machine the wall time also counts the waits
// for a core (libapriltag runs with one thread here, so the thread's time is all of it).
double threadCpuMs() {
    timespec t{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return static_cast<double>(t.tv_sec) * 1e3 + static_cast<double>(t.tv_nsec) * 1e-6;
}

// Step 0: the sequences. "desk" is the bundled sample; the others are rendered once into the
// data folder (with the sim's ground truth) and reused while their parameters match.
struct CaseSpec {
    const char* name;
    const char* what;
    const char* scene;       // relative to the repository; null: the bundled sample
    const char* trajectory;
    const char* calib;       // null: the scene's camera
    bool motion_blur = false;
    double exposure_us = 0;  // 0: the sensor's default
    bool noise_free = false;
    int width = 0, height = 0;  // > 0: the desk camera at this size (same field of view)
    int frames = 0;             // 0: the whole trajectory
    bool sweep = false;         // run the decimate x tracking-mode sweep on it
    // Conditions that break the response and print assumptions: what the camera does, what the
    // tracker is told, how the tags were printed, the lens.
    mocks::sim::SensorResponse response = mocks::sim::SensorResponse::kSrgb;  // the camera's
    double gamma = 2.2;              // of SensorResponse::kGamma
    bool tracker_srgb = true;        // the tracker assumes sRGB (else linear)
    double ink_spread_cells = 0.0;   // black grown (> 0) or shrunk (< 0) on the print
    double defocus_radius_px = 0.0;  // circle of confusion
    const char* matched = nullptr;   // the case with the matched response to compare with
    int min_spp = 0;                 // rendered with at least this many samples per pixel
    // Detection by the black square's size, without and with the verification of predicted tags
    // (bench_tracking_tiny.h).
    bool by_size = false;
};

constexpr const char* kHard = "data/scenes/hard/scene.yaml";
constexpr const char* kResponsePath = "data/scenes/hard/response.yaml";
constexpr const char* kTiny = "data/scenes/tiny/scene.yaml";

const std::vector<CaseSpec>& cases() {
    static const std::vector<CaseSpec> list = {
        {"desk", "bundled sample: desk scene, 640x480, slow pan", nullptr, nullptr, nullptr, false, 0, false, 0, 0, 0,
         true},
        {"desk720", "desk scene at 1280x720 (tracking-mode speed)", "data/scenes/desk/scene.yaml",
         "data/scenes/desk/trajectory.yaml", nullptr, false, 0, false, 1280, 720, 31, true},
        {.name = "small", .what = "tags of 14-26 px", .scene = kHard, .trajectory = "data/scenes/hard/small.yaml",
         .calib = nullptr, .by_size = true},
        {"fronto", "exactly fronto-parallel tag, noise-free sensor", "data/scenes/hard/scene.yaml",
         "data/scenes/hard/fronto.yaml", nullptr, false, 0, true},
        {"oblique75", "tag at 72-78 degrees", "data/scenes/hard/scene.yaml", "data/scenes/hard/oblique75.yaml", nullptr},
        {"blur", "fast pan, motion blur over 20 ms", "data/scenes/hard/scene.yaml", "data/scenes/hard/blur.yaml", nullptr,
         true, 20000},
        {"wide", "strong distortion, k1 = -0.4", "data/scenes/hard/scene.yaml", "data/scenes/hard/wide.yaml",
         "data/scenes/hard/calib_wide.yaml"},
        {"occluded", "tag 5 half under a bar", "data/scenes/hard/scene.yaml", "data/scenes/hard/occluded.yaml", nullptr},
        // Tags too small to decode (issue 13): black squares of 6-10 px from 1.3-1.5 m, 0-38 degrees
        // off their normal; and 7-10 px across when seen 75-80 degrees off it.
        // At least 16 samples per pixel: a pixel integrates its whole area, and 4 random samples of
        // cells of 1 px leave a coverage noise no camera has.
        {.name = "tiny", .what = "tiny tags: black squares of 6-10 px, 0-38 degrees", .scene = kTiny,
         .trajectory = "data/scenes/tiny/tiny.yaml", .calib = nullptr, .min_spp = 16, .by_size = true},
        {.name = "tiny75", .what = "tags 7-10 px across at 75-80 degrees", .scene = kTiny,
         .trajectory = "data/scenes/tiny/tiny75.yaml", .calib = nullptr, .min_spp = 16, .by_size = true},
        // The response, print and defocus cases: the left board from about 1 m, one path; each
        // compares with `matched` (an sRGB camera read as sRGB, an exact print, in focus).
        {.name = "matched", .what = "response cases' reference: sRGB camera read as sRGB, exact print",
         .scene = kHard, .trajectory = kResponsePath, .calib = nullptr, .frames = 20},
        {.name = "linear_as_srgb", .what = "linear-response camera read as sRGB", .scene = kHard,
         .trajectory = kResponsePath, .calib = nullptr, .frames = 20, .response = mocks::sim::SensorResponse::kLinear,
         .matched = "matched"},
        {.name = "srgb_as_linear", .what = "sRGB camera read as linear", .scene = kHard, .trajectory = kResponsePath,
         .calib = nullptr, .frames = 20, .tracker_srgb = false, .matched = "matched"},
        {.name = "gamma18", .what = "gamma 1.8 camera read as sRGB", .scene = kHard, .trajectory = kResponsePath,
         .calib = nullptr, .frames = 20, .response = mocks::sim::SensorResponse::kGamma, .gamma = 1.8,
         .matched = "matched"},
        {.name = "gamma26", .what = "gamma 2.6 camera read as sRGB", .scene = kHard, .trajectory = kResponsePath,
         .calib = nullptr, .frames = 20, .response = mocks::sim::SensorResponse::kGamma, .gamma = 2.6,
         .matched = "matched"},
        {.name = "ink_grown", .what = "tags printed with the black grown by 10% of a cell", .scene = kHard,
         .trajectory = kResponsePath, .calib = nullptr, .frames = 20, .ink_spread_cells = 0.10, .matched = "matched"},
        {.name = "ink_shrunk", .what = "tags printed with the black shrunk by 5% of a cell", .scene = kHard,
         .trajectory = kResponsePath, .calib = nullptr, .frames = 20, .ink_spread_cells = -0.05, .matched = "matched"},
        {.name = "ink_grown2", .what = "tags printed with the black grown by 2% of a cell", .scene = kHard,
         .trajectory = kResponsePath, .calib = nullptr, .frames = 20, .ink_spread_cells = 0.02, .matched = "matched"},
        {.name = "defocus", .what = "slight defocus: a disc of 1.5 px radius", .scene = kHard,
         .trajectory = kResponsePath, .calib = nullptr, .frames = 20, .defocus_radius_px = 1.5, .matched = "matched"},
    };
    return list;
}

std::string renderKey(const CaseSpec& c, int spp, std::uint64_t seed) {
    std::string key = std::string("case=") + c.name + " spp=" + std::to_string(spp) + " version=2";
    if (seed != 1) key += " seed=" + std::to_string(seed);  // (older renders, seed 1, stay valid)
    // Motion blur: rendered since the ground truth has the mid-exposure pose (the blurred image's
    // instant); older renders of it are compared with the start of the exposure and are redone.
    if (c.motion_blur) key += " truth=mid-exposure";
    // The rendering conditions, when not the defaults (so older renders stay valid).
    if (c.response != mocks::sim::SensorResponse::kSrgb || c.ink_spread_cells != 0 || c.defocus_radius_px != 0) {
        char conditions[160];
        std::snprintf(conditions, sizeof conditions, " response=%s gamma=%g ink=%g defocus=%g",
                      std::string(mocks::sim::sensorResponseName(c.response)).c_str(), c.gamma, c.ink_spread_cells,
                      c.defocus_radius_px);
        key += conditions;
    }
    return key;
}

Result<fs::path> ensureSequence(const CaseSpec& c, const BenchTrackingOptions& options) {
    if (!c.scene) return options.source_dir / "data/sample";
    const fs::path out = options.data_dir / c.name;
    const fs::path marker = out / "bench-render.txt";
    const int spp = std::max(c.noise_free ? std::max(options.spp, 64) : options.spp, c.min_spp);
    {
        std::ifstream in(marker);
        std::string key;
        if (in && std::getline(in, key) && key == renderKey(c, spp, options.seed)) return out;
    }
    std::error_code ec;
    fs::remove_all(out, ec);
    CL_TRY(Scene scene, readScene(options.source_dir / c.scene));
    CL_TRY(auto trajectory, mocks::sim::Trajectory::read(options.source_dir / c.trajectory));
    mocks::sim::SimulationOptions sim;
    sim.out = out;
    sim.spp = spp;
    sim.seed = options.seed;
    sim.max_depth = 2;  // direct light and one bounce: enough for tracking, a third of the time
    sim.frames = c.frames;
    sim.write_composite = false;
    sim.write_masks = false;
    sim.write_radiance = false;
    sim.motion_blur = c.motion_blur;
    if (c.exposure_us > 0) sim.sensor.exposure_us = c.exposure_us;
    sim.sensor.response = c.response;
    sim.sensor.gamma = c.gamma;
    sim.tag_ink_spread_cells = c.ink_spread_cells;
    sim.defocus_radius_px = c.defocus_radius_px;
    if (c.noise_free) {
        sim.sensor.dark_noise_e = 0;
        sim.sensor.dsnu_e = 0;
        sim.sensor.prnu = 0;
    }
    if (c.calib) {
        CL_TRY(sim.camera, readCalibration(options.source_dir / c.calib));
    }
    if (c.width > 0 && scene.camera) {
        // The same field of view (horizontal) and lens at another size.
        CameraModel cam = *scene.camera;
        const double f = cam.fx * (static_cast<double>(c.width) / cam.width);
        cam.width = c.width;
        cam.height = c.height;
        cam.fx = cam.fy = f;
        cam.cx = (c.width - 1) / 2.0;
        cam.cy = (c.height - 1) / 2.0;
        sim.camera = cam;
    }
    const int total = c.frames > 0 ? c.frames : trajectory.frameCount();
    std::fprintf(stderr, "rendering the '%s' sequence (%d frames, %d spp) into %s\n", c.name, total, spp, out.c_str());
    Progress progress(std::string("render ") + c.name, static_cast<std::uint64_t>(total));
    CL_TRY(auto summary, mocks::sim::simulate(scene, trajectory, sim,
                                             [&](int done, int) { progress.update(static_cast<std::uint64_t>(done)); },
                                             stopToken()));
    progress.finish();
    if (summary.stopped) return fail(ErrorCode::kCancelled, "stopped while rendering " + out.string());
    std::ofstream(marker) << renderKey(c, spp, options.seed) << "\n";
    return out;
}

// Step 1: a case in memory: grey frames, the camera, the scene's tags and proxies, the truth.
struct LoadedCase {
    const CaseSpec* spec = nullptr;
    fs::path path;
    std::vector<Image> frames;
    std::vector<FrameMetadata> meta;          // timestamp (start of exposure) and exposure
    std::vector<Rigid3d> cam_from_world_true;  // at the middle of each frame's exposure
    CameraModel camera;
    Scene scene;
};

Result<LoadedCase> loadCase(const CaseSpec& spec, const fs::path& path, int max_frames) {
    LoadedCase out;
    out.spec = &spec;
    out.path = path;
    CL_TRY(TrackInput input, openTrackInput(path));
    if (!input.sensor_camera) return fail(ErrorCode::kBadInput, path.string() + ": cam0/sensor.yaml has no intrinsics");
    out.camera = *input.sensor_camera;
    if (!input.scene_path) return fail(ErrorCode::kBadInput, path.string() + ": no scene.yaml");
    CL_TRY(out.scene, readScene(*input.scene_path));
    GreyFrameLoader loader;
    const std::size_t n = max_frames > 0 ? std::min<std::size_t>(input.frames.size(), max_frames) : input.frames.size();
    for (std::size_t i = 0; i < n; ++i) {
        // The truth at the instant the poses are for: the middle of the exposure.
        const auto truth = groundTruthOfFrame(*input.sequence, i);
        if (!truth) {
            return fail(ErrorCode::kBadInput, path.string() + ": frame " + input.frames[i].name +
                                                  " has no ground truth at the middle of its exposure (groundtruth/)");
        }
        Image grey;
        CL_TRY_VOID(loader.load(input, i, grey));
        out.frames.push_back(std::move(grey));
        out.meta.push_back(input.frames[i].meta());
        out.cam_from_world_true.push_back(truth->inverse());
    }
    return out;
}

// Error statistics of a set of poses against the truth.
struct ErrorStats {
    std::vector<double> rot_deg, trans_mm, ms;
    std::vector<double> cpu_ms;     // the thread's CPU time per frame (beside the wall time `ms`)
    std::vector<double> range_rel;  // single tags: |t_estimate| / |t_true| - 1 (signed: < 0 too close)
    int attempts = 0;  // frames (or tag detections) that should have had a pose

    // cam_from_tag: the tag's position in the camera; cam_from_world: the camera centre in the world.
    void add(const Rigid3d& estimate, const Rigid3d& truth) {
        rot_deg.push_back(rotationErrorDeg(estimate, truth));
        trans_mm.push_back(1000.0 * (estimate.translation - truth.translation).norm());
        range_rel.push_back(estimate.translation.norm() / truth.translation.norm() - 1.0);
    }
    // The mean signed relative range error (the scale bias), in percent.
    double rangeBiasPct() const {
        if (range_rel.empty()) return NAN;
        double sum = 0;
        for (const double r : range_rel) sum += r;
        return 100.0 * sum / static_cast<double>(range_rel.size());
    }
    void addCamera(const Rigid3d& cam_from_world, const Rigid3d& truth) {
        rot_deg.push_back(rotationErrorDeg(cam_from_world, truth));
        trans_mm.push_back(1000.0 * (cam_from_world.inverse().translation - truth.inverse().translation).norm());
    }
    static double pct(std::vector<double> v, double p) {
        if (v.empty()) return NAN;
        std::sort(v.begin(), v.end());
        return nearestRank(v, p);
    }
    double gross() const {
        if (rot_deg.empty()) return NAN;
        return static_cast<double>(std::count_if(rot_deg.begin(), rot_deg.end(), [](double r) { return r > 5.0; })) /
               static_cast<double>(rot_deg.size());
    }
    json toJson() const {
        json j;
        j["count"] = rot_deg.size();
        j["attempts"] = attempts;
        j["rot_deg"] = {{"p50", pct(rot_deg, 50)}, {"p95", pct(rot_deg, 95)}, {"max", pct(rot_deg, 100)}};
        j["trans_mm"] = {{"p50", pct(trans_mm, 50)}, {"p95", pct(trans_mm, 95)}, {"max", pct(trans_mm, 100)}};
        j["gross_rate"] = gross();
        if (!range_rel.empty()) j["range_bias_pct"] = rangeBiasPct();
        if (!ms.empty()) j["ms_per_frame"] = {{"p50", pct(ms, 50)}, {"p95", pct(ms, 95)}, {"max", pct(ms, 100)}};
        if (!cpu_ms.empty()) {
            j["cpu_ms_per_frame"] = {{"p50", pct(cpu_ms, 50)}, {"p95", pct(cpu_ms, 95)}, {"max", pct(cpu_ms, 100)}};
        }
        return j;
    }
};

std::string fmt(double v, const char* f = "%.3f") {
    if (!std::isfinite(v)) return "-";
    char buf[32];
    std::snprintf(buf, sizeof buf, f, v);
    return buf;
}

void printRow(const std::string& name, const ErrorStats& s) {
    std::printf("| %-26s | %4zu/%-4d | %7s | %7s | %7s | %8s | %8s | %8s | %6s | %7s | %7s |\n", name.c_str(),
                s.rot_deg.size(),
                s.attempts, fmt(ErrorStats::pct(s.rot_deg, 50)).c_str(), fmt(ErrorStats::pct(s.rot_deg, 95)).c_str(),
                fmt(ErrorStats::pct(s.rot_deg, 100)).c_str(), fmt(ErrorStats::pct(s.trans_mm, 50), "%.2f").c_str(),
                fmt(ErrorStats::pct(s.trans_mm, 95), "%.2f").c_str(), fmt(ErrorStats::pct(s.trans_mm, 100), "%.2f").c_str(),
                fmt(100.0 * s.gross(), "%.1f%%").c_str(),
                s.ms.empty() ? "-" : fmt(ErrorStats::pct(s.ms, 50), "%.2f").c_str(),
                s.cpu_ms.empty() ? "-" : fmt(ErrorStats::pct(s.cpu_ms, 50), "%.2f").c_str());
}

void printHeader(const char* first) {
    std::printf("| %-26s | %9s | %7s | %7s | %7s | %8s | %8s | %8s | %6s | %7s | %7s |\n", first, "poses", "rot p50",
                "rot p95", "rot max", "mm p50", "mm p95", "mm max", "gross", "ms/frm", "cpu ms");
    std::printf("|%s|\n", std::string(141, '-').c_str());
}

// Step 2: libapriltag's own pose against ours on the same detections; the detector alone timed.
struct SingleTagComparison {
    ErrorStats reference, ours, ours_refined, ours_aligned_fixed, ours_aligned;
    // The detector alone (what the tracking stage's time is compared with), and with libapriltag's
    // estimate_tag_pose for every tag (what a user of libapriltag runs for poses).
    ErrorStats detector_only, detector_with_pose;
    // The response exponent each aligned tag measured (TagAlignResult::response_exponent_measured;
    // 0: not measured), and how many of them had the assumed response replaced (response_gamma > 0).
    std::vector<double> response_exponent;
    int response_replaced = 0;
};

SingleTagComparison compareSingleTag(const LoadedCase& lc, double decimate) {
    SingleTagComparison out;
    tracking::TagRefineOptions refine_options;
    refine_options.srgb = lc.spec->tracker_srgb;
    tracking::TagAlignOptions align_options;
    align_options.srgb = lc.spec->tracker_srgb;
    tracking::TagDetectorOptions det;
    det.family = lc.scene.tags.family;
    det.decimate = decimate;
    // estimate_tag_pose is linear in the tag size: run it for size 1 and scale per tag.
    det.reference_pose = tracking::TagDetectorOptions::ReferencePose{1.0, lc.camera.fx, lc.camera.fy, lc.camera.cx,
                                                                     lc.camera.cy};
    auto detector = tracking::TagDetector::create(det);
    tracking::TagDetectorOptions det_alone = det;
    det_alone.reference_pose.reset();
    auto detector_alone = tracking::TagDetector::create(det_alone);
    if (!detector || !detector_alone) return out;
    tracking::TagPatternCache patterns(det.family);
    const auto timed = [&](tracking::TagDetector& d, ErrorStats& stats, const ImageView& image) {
        const auto start = Clock::now();
        const double start_cpu = threadCpuMs();
        auto detections = d.detect(image);
        stats.cpu_ms.push_back(threadCpuMs() - start_cpu);
        stats.ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - start).count());
        return detections;
    };
    for (std::size_t i = 0; i < lc.frames.size(); ++i) {
        (void)timed(*detector_alone, out.detector_only, lc.frames[i].view());
        auto detections = timed(*detector, out.detector_with_pose, lc.frames[i].view());
        if (!detections) continue;
        for (const auto& d : *detections) {
            const TagItem* item = lc.scene.tags.find(d.id);
            if (!item) continue;
            const Rigid3d truth = lc.cam_from_world_true[i] * item->world_from_tag;
            ++out.reference.attempts;
            ++out.ours.attempts;
            if (d.reference_cam_from_tag) {
                Rigid3d ref = *d.reference_cam_from_tag;
                ref.translation *= item->size;
                out.reference.add(ref, truth);
            }
            auto ours = tracking::solveTagPose(d.id, d.corners, item->size, lc.camera);
            if (ours) out.ours.add(ours->cam_from_tag, truth);
            ++out.ours_refined.attempts;
            auto corners = d.corners;
            tracking::refineTagCorners(lc.frames[i].view(), lc.camera, corners, refine_options);
            auto refined = tracking::solveTagPose(d.id, corners, item->size, lc.camera);
            if (refined) out.ours_refined.add(refined->cam_from_tag, truth);
            ++out.ours_aligned.attempts;
            ++out.ours_aligned_fixed.attempts;
            if (refined) {
                const tracking::TagPattern* pattern = patterns.get(d.id);
                Rigid3d aligned = refined->cam_from_tag, fixed = refined->cam_from_tag;
                if (pattern) {
                    align_options.albedo_ratio = item->albedo_black / item->albedo_white;
                    tracking::TagAlignOptions no_dilation = align_options;
                    no_dilation.estimate_dilation = false;
                    auto f = tracking::alignTagPose(lc.frames[i].view(), lc.camera, *pattern, item->size, fixed, no_dilation);
                    if (f.ok) fixed = f.cam_from_tag;
                    auto a = tracking::alignTagPose(lc.frames[i].view(), lc.camera, *pattern, item->size, aligned,
                                                    align_options);
                    if (a.ok) aligned = a.cam_from_tag;
                    if (a.ok && a.response_exponent_measured > 0) {
                        out.response_exponent.push_back(a.response_exponent_measured);
                        if (a.response_gamma > 0) ++out.response_replaced;
                    }
                }
                out.ours_aligned.add(aligned, truth);
                out.ours_aligned_fixed.add(fixed, truth);
            }
        }
    }
    return out;
}

// Step 3: the tracker, in a given configuration, over the whole sequence.
// The CPU time of each step of one frame, in the tracker's order.
std::vector<std::pair<std::string, double>> stageCpuMs(const tracking::StageTimes& t) {
    return {{"detect", t.detect_cpu_ms},
            {"refine", t.refine_cpu_ms},
            {"align", t.align_cpu_ms},
            {"solve", std::max(0.0, t.tag_pose_cpu_ms - t.refine_cpu_ms - t.align_cpu_ms)},
            {"bundle", t.bundle_cpu_ms},
            {"verify", t.verify_cpu_ms},
            {"edges", t.edges_cpu_ms},
            {"filter", t.filter_cpu_ms}};
}

struct TrackerRun {
    ErrorStats camera;       // cam_from_world per frame
    ErrorStats single_tags;  // the tracker's chosen single-tag poses
    // CPU time per frame of each step (StageTimes): detect, refine, align, the rest of the
    // single-tag step (pose solving), bundle, verify (predicted tags not detected), edges, filter.
    std::map<std::string, std::vector<double>> stage_cpu_ms;
    double detect_ms_p50 = 0;
    int full_frame_detections = 0;
};

Result<TrackerRun> runTracker(const LoadedCase& lc, const tracking::TrackerOptions& options) {
    CL_TRY(auto tracker, tracking::Tracker::create(lc.camera, lc.scene.tags, &lc.scene, options));
    TrackerRun run;
    std::vector<double> detect_ms;
    for (std::size_t i = 0; i < lc.frames.size(); ++i) {
        CL_TRY(auto track, tracker.process(lc.frames[i].view(), lc.meta[i]));
        ++run.camera.attempts;
        run.camera.ms.push_back(track.times.total_ms);
        run.camera.cpu_ms.push_back(track.times.total_cpu_ms);
        for (const auto& [name, value] : stageCpuMs(track.times)) run.stage_cpu_ms[name].push_back(value);
        detect_ms.push_back(track.times.detect_ms);
        if (track.full_frame_detection) ++run.full_frame_detections;
        if (track.cam_from_world) run.camera.addCamera(*track.cam_from_world, lc.cam_from_world_true[i]);
        for (const auto& t : track.tags) {
            const TagItem* item = lc.scene.tags.find(t.detection.id);
            if (!item) continue;
            ++run.single_tags.attempts;
            if (t.pose) run.single_tags.add(t.pose->cam_from_tag, lc.cam_from_world_true[i] * item->world_from_tag);
        }
    }
    run.detect_ms_p50 = ErrorStats::pct(detect_ms, 50);
    return run;
}

tracking::TrackerOptions baseOptions(const LoadedCase& lc, double decimate) {
    tracking::TrackerOptions o;
    o.detector.family = lc.scene.tags.family;
    o.detector.decimate = decimate;
    o.refine.srgb = lc.spec->tracker_srgb;
    o.align.srgb = lc.spec->tracker_srgb;
    return o;
}

struct SweepPoint {
    std::string case_name;
    double decimate;
    bool tracking_mode;
    TrackerRun run;
};

void drawPlot(const std::vector<SweepPoint>& points, const fs::path& file) {
    const int w = 900, h = 560, left = 80, right = 30, top = 40, bottom = 60;
    cv::Mat img(h, w, CV_8UC3, cv::Scalar(255, 255, 255));
    double max_ms = 0, max_err = 0;
    for (const auto& p : points) {
        max_ms = std::max(max_ms, ErrorStats::pct(p.run.camera.ms, 50));
        max_err = std::max(max_err, ErrorStats::pct(p.run.camera.rot_deg, 50));
    }
    max_ms = max_ms > 0 ? max_ms * 1.15 : 1;
    max_err = max_err > 0 ? max_err * 1.25 : 1;
    const auto X = [&](double ms) { return left + static_cast<int>((w - left - right) * ms / max_ms); };
    const auto Y = [&](double e) { return h - bottom - static_cast<int>((h - top - bottom) * e / max_err); };
    const cv::Scalar black(0, 0, 0), grey(200, 200, 200);
    for (int k = 0; k <= 5; ++k) {
        const double ms = max_ms * k / 5, e = max_err * k / 5;
        cv::line(img, {X(ms), top}, {X(ms), h - bottom}, grey);
        cv::line(img, {left, Y(e)}, {w - right, Y(e)}, grey);
        cv::putText(img, fmt(ms, "%.1f"), {X(ms) - 12, h - bottom + 20}, cv::FONT_HERSHEY_SIMPLEX, 0.45, black);
        cv::putText(img, fmt(e, "%.3f"), {10, Y(e) + 5}, cv::FONT_HERSHEY_SIMPLEX, 0.45, black);
    }
    cv::rectangle(img, {left, top}, {w - right, h - bottom}, black);
    cv::putText(img, "tracking time per frame, ms (p50)", {left + 220, h - 15}, cv::FONT_HERSHEY_SIMPLEX, 0.55, black);
    cv::putText(img, "camera rotation error p50, deg: decimate x tracking mode", {left, 25}, cv::FONT_HERSHEY_SIMPLEX, 0.55,
                black);
    cv::putText(img, "circle: full frame, square: tracking mode", {w - right - 320, top + 20}, cv::FONT_HERSHEY_SIMPLEX, 0.45,
                black);
    const cv::Scalar colours[] = {{200, 60, 20}, {20, 120, 220}, {40, 160, 40}, {160, 40, 160}};
    std::map<std::string, int> case_colour;
    for (const auto& p : points) {
        const int ci = case_colour.emplace(p.case_name, static_cast<int>(case_colour.size())).first->second % 4;
        const double ms = ErrorStats::pct(p.run.camera.ms, 50), e = ErrorStats::pct(p.run.camera.rot_deg, 50);
        if (!std::isfinite(e)) continue;
        const cv::Point at(X(ms), Y(e));
        if (p.tracking_mode) {
            cv::rectangle(img, at - cv::Point(5, 5), at + cv::Point(5, 5), colours[ci], cv::FILLED);
        } else {
            cv::circle(img, at, 6, colours[ci], cv::FILLED);
        }
        cv::putText(img, p.case_name + " d" + fmt(p.decimate, "%.0f") + (p.tracking_mode ? " trk" : ""),
                    at + cv::Point(8, -6), cv::FONT_HERSHEY_SIMPLEX, 0.4, colours[ci]);
    }
    cv::imwrite(file.string(), img);
}

}  // namespace

std::vector<std::string> benchTrackingCaseNames() {
    std::vector<std::string> names;
    for (const auto& c : cases()) names.push_back(c.name);
    return names;
}

int runBenchTracking(const BenchTrackingOptions& options) {
    std::vector<const CaseSpec*> selected;
    for (const auto& c : cases()) {
        if (options.cases.empty() || std::find(options.cases.begin(), options.cases.end(), c.name) != options.cases.end()) {
            selected.push_back(&c);
        }
    }
    for (const auto& name : options.cases) {
        if (std::none_of(cases().begin(), cases().end(), [&](const CaseSpec& c) { return name == c.name; })) {
            return reportError(Error{ErrorCode::kUsage, "unknown case '" + name + "'"});
        }
    }
    json report;
    report["cases"] = json::object();
    std::vector<SweepPoint> sweep;
    struct Reference {
        double range_bias_pct, rot_p50, tracker_range_bias_pct, tracker_rot_p50;
    };
    std::map<std::string, Reference> references;  // per case: what the cases that match it compare with
    for (const CaseSpec* spec : selected) {
        // Step 0 and 1.
        auto path = ensureSequence(*spec, options);
        if (!path) return reportError(path.error());
        auto lc = loadCase(*spec, *path, options.max_frames);
        if (!lc) return reportError(lc.error());
        std::printf("\n## %s: %s (%zu frames, %dx%d)\n\n", spec->name, spec->what, lc->frames.size(), lc->camera.width,
                    lc->camera.height);

        // Step 2: single tags, same detections (decimate 2, libapriltag's default here).
        const SingleTagComparison single = compareSingleTag(*lc, 2.0);
        // Step 3: the stages, decimate 2, full-frame detection.
        tracking::TrackerOptions bundle_only = baseOptions(*lc, 2.0);
        bundle_only.filter = false;
        tracking::TrackerOptions filtered = baseOptions(*lc, 2.0);
        tracking::TrackerOptions with_edges = filtered;
        with_edges.edges = true;
        // As play and live run it: detection only around the predicted tags between full-frame ones.
        tracking::TrackerOptions in_tracking_mode = filtered;
        in_tracking_mode.tracking_mode = true;
        auto run_bundle = runTracker(*lc, bundle_only);
        auto run_filter = runTracker(*lc, filtered);
        auto run_edges = runTracker(*lc, with_edges);
        auto run_mode = runTracker(*lc, in_tracking_mode);
        if (!run_bundle) return reportError(run_bundle.error());
        if (!run_filter) return reportError(run_filter.error());
        if (!run_edges) return reportError(run_edges.error());
        if (!run_mode) return reportError(run_mode.error());

        printHeader("method (decimate 2)");
        printRow("libapriltag estimate_tag_pose", single.reference);
        printRow("our single tag", single.ours);
        printRow("our single tag, refined", single.ours_refined);
        printRow("single tag, aligned, no dil.", single.ours_aligned_fixed);
        printRow("our single tag, aligned", single.ours_aligned);
        printRow("our single tag, in tracker", run_filter->single_tags);
        printRow("bundle", run_bundle->camera);
        printRow("bundle + filter", run_filter->camera);
        printRow("bundle + filter + edges", run_edges->camera);
        printRow("bundle + filter, tracking mode", run_mode->camera);
        const double det_ms = ErrorStats::pct(single.detector_only.ms, 50);
        const double track_ms = ErrorStats::pct(run_filter->camera.ms, 50);
        std::printf("\nlibapriltag detector alone: %.2f ms/frame (p50); tracking stage (bundle + filter): %.2f ms = %.2fx\n",
                    det_ms, track_ms, track_ms / det_ms);
        const double det_cpu = ErrorStats::pct(single.detector_only.cpu_ms, 50);
        const double track_cpu = ErrorStats::pct(run_filter->camera.cpu_ms, 50);
        const double det_pose_cpu = ErrorStats::pct(single.detector_with_pose.cpu_ms, 50);
        std::printf("CPU time: libapriltag detector alone %.2f ms/frame (p50); tracking stage (bundle + filter) "
                    "%.2f ms = %.2fx [target at most 1.2x: %s]; with edges %.2f ms; libapriltag detector + "
                    "estimate_tag_pose %.2f ms\n",
                    det_cpu, track_cpu, track_cpu / det_cpu, track_cpu / det_cpu <= 1.2 ? "met" : "MISSED",
                    ErrorStats::pct(run_edges->camera.cpu_ms, 50), det_pose_cpu);
        const double mode_cpu = ErrorStats::pct(run_mode->camera.cpu_ms, 50);
        std::printf("CPU time in tracking mode (play, live): tracking stage (bundle + filter) %.2f ms = %.2fx the "
                    "detector alone [target at most 1.2x: %s]; full-frame detection in %d of %zu frames\n",
                    mode_cpu, mode_cpu / det_cpu, mode_cpu / det_cpu <= 1.2 ? "met" : "MISSED",
                    run_mode->full_frame_detections, lc->frames.size());
        const auto printSplit = [](const char* label, const TrackerRun& run) {
            std::printf("CPU time per frame, mean, %s:", label);
            double sum = 0;
            for (const char* name : {"detect", "refine", "align", "solve", "bundle", "verify", "edges", "filter"}) {
                const auto it = run.stage_cpu_ms.find(name);
                if (it == run.stage_cpu_ms.end() || it->second.empty()) continue;
                double mean = 0;
                for (const double v : it->second) mean += v;
                mean /= static_cast<double>(it->second.size());
                sum += mean;
                std::printf(" %s %.2f", name, mean);
            }
            std::printf(" (sum %.2f ms)\n", sum);
        };
        printSplit("bundle + filter", *run_filter);
        printSplit("with edges", *run_edges);
        printSplit("tracking mode", *run_mode);
        const double ref_p50 = ErrorStats::pct(single.reference.rot_deg, 50);
        const double ours_p50 = ErrorStats::pct(single.ours_aligned.rot_deg, 50);
        std::printf("single-tag rotation p50: ours %.3f deg vs libapriltag %.3f deg = %.2fx\n", ours_p50, ref_p50,
                    ours_p50 / ref_p50);
        // Range (scale) bias and translation against libapriltag, and against the matched case.
        const double ours_mm = ErrorStats::pct(single.ours_aligned.trans_mm, 50);
        const double ref_mm = ErrorStats::pct(single.reference.trans_mm, 50);
        const double tracker_mm = ErrorStats::pct(run_filter->single_tags.trans_mm, 50);
        std::printf("single-tag range bias: libapriltag %+.3f%%, ours refined %+.3f%%, aligned without dilation "
                    "%+.3f%%, aligned %+.3f%%, in tracker %+.3f%%\n",
                    single.reference.rangeBiasPct(), single.ours_refined.rangeBiasPct(),
                    single.ours_aligned_fixed.rangeBiasPct(), single.ours_aligned.rangeBiasPct(),
                    run_filter->single_tags.rangeBiasPct());
        if (!single.response_exponent.empty()) {
            std::printf("response exponent measured by the aligned tags: min %.3f, p5 %.3f, p50 %.3f, p95 %.3f, max "
                        "%.3f; response replaced on %d of %zu tags\n",
                        ErrorStats::pct(single.response_exponent, 0), ErrorStats::pct(single.response_exponent, 5),
                        ErrorStats::pct(single.response_exponent, 50), ErrorStats::pct(single.response_exponent, 95),
                        ErrorStats::pct(single.response_exponent, 100), single.response_replaced,
                        single.response_exponent.size());
        }
        std::printf("single-tag translation p50: ours aligned %.2f mm, in tracker %.2f mm vs libapriltag %.2f mm: %s\n",
                    ours_mm, tracker_mm, ref_mm, std::max(ours_mm, tracker_mm) <= ref_mm ? "at most (met)" : "MORE (missed)");
        const Reference mine{single.ours_aligned.rangeBiasPct(), ours_p50, run_filter->single_tags.rangeBiasPct(),
                             ErrorStats::pct(run_filter->single_tags.rot_deg, 50)};
        references[spec->name] = mine;
        json jm;
        if (spec->matched) {
            const auto it = references.find(spec->matched);
            if (it == references.end()) {
                std::printf("(run the case '%s' too to compare with the matched response)\n", spec->matched);
            } else {
                const Reference& m = it->second;
                const double d_range = mine.range_bias_pct - m.range_bias_pct;
                const double d_range_tr = mine.tracker_range_bias_pct - m.tracker_range_bias_pct;
                const double rot_ratio = mine.rot_p50 / m.rot_p50, rot_ratio_tr = mine.tracker_rot_p50 / m.tracker_rot_p50;
                std::printf("against '%s': range bias %+.3f%% (aligned), %+.3f%% (in tracker) [target within 0.2%%: %s]; "
                            "rotation p50 %.2fx (aligned), %.2fx (in tracker) [target at most 1.2x: %s]\n",
                            spec->matched, d_range, d_range_tr,
                            std::max(std::abs(d_range), std::abs(d_range_tr)) <= 0.2 ? "met" : "MISSED", rot_ratio,
                            rot_ratio_tr, std::max(rot_ratio, rot_ratio_tr) <= 1.2 ? "met" : "MISSED");
                jm = {{"case", spec->matched}, {"range_bias_diff_pct", d_range}, {"range_bias_diff_pct_tracker", d_range_tr},
                      {"rot_p50_ratio", rot_ratio}, {"rot_p50_ratio_tracker", rot_ratio_tr}};
            }
        }

        json j;
        j["what"] = spec->what;
        j["frames"] = lc->frames.size();
        j["size"] = {lc->camera.width, lc->camera.height};
        j["apriltag_estimate_tag_pose"] = single.reference.toJson();
        j["single_tag_apriltag_corners"] = single.ours.toJson();
        j["single_tag_refined_corners"] = single.ours_refined.toJson();
        j["single_tag_aligned_without_dilation"] = single.ours_aligned_fixed.toJson();
        j["single_tag"] = single.ours_aligned.toJson();
        j["single_tag_in_tracker"] = run_filter->single_tags.toJson();
        if (!single.response_exponent.empty()) {
            j["single_tag_response_exponent"] = {{"p5", ErrorStats::pct(single.response_exponent, 5)},
                                                 {"p50", ErrorStats::pct(single.response_exponent, 50)},
                                                 {"p95", ErrorStats::pct(single.response_exponent, 95)},
                                                 {"min", ErrorStats::pct(single.response_exponent, 0)},
                                                 {"max", ErrorStats::pct(single.response_exponent, 100)},
                                                 {"measured", single.response_exponent.size()},
                                                 {"replaced", single.response_replaced}};
        }
        j["bundle"] = run_bundle->camera.toJson();
        j["bundle_filter"] = run_filter->camera.toJson();
        j["bundle_filter_edges"] = run_edges->camera.toJson();
        j["detector_only_ms_p50"] = det_ms;
        j["tracking_over_detector"] = track_ms / det_ms;
        j["detector_only_cpu_ms_p50"] = det_cpu;
        j["detector_estimate_tag_pose_cpu_ms_p50"] = det_pose_cpu;
        j["tracking_over_detector_cpu"] = track_cpu / det_cpu;
        j["bundle_filter_tracking_mode"] = run_mode->camera.toJson();
        j["tracking_mode_over_detector_cpu"] = mode_cpu / det_cpu;
        j["tracking_mode_full_frame_detections"] = run_mode->full_frame_detections;
        for (const auto* run : {&*run_filter, &*run_edges, &*run_mode}) {
            json split;
            for (const auto& [name, v] : run->stage_cpu_ms) {
                double mean = 0;
                for (const double x : v) mean += x;
                split[name] = v.empty() ? 0.0 : mean / static_cast<double>(v.size());
            }
            j[run == &*run_filter  ? "stage_cpu_ms_mean"
              : run == &*run_edges ? "stage_cpu_ms_mean_edges"
                                   : "stage_cpu_ms_mean_tracking_mode"] = split;
        }
        j["single_over_apriltag_rot_p50"] = ours_p50 / ref_p50;
        j["single_over_apriltag_trans_p50"] = ours_mm / ref_mm;
        j["single_in_tracker_over_apriltag_trans_p50"] = tracker_mm / ref_mm;
        if (!jm.is_null()) j["against_matched"] = jm;
        if (spec->by_size) {
            auto by_size = benchDetectionBySize(
                {&lc->frames, &lc->meta, &lc->cam_from_world_true, &lc->camera, &lc->scene}, filtered);
            if (!by_size) return reportError(by_size.error());
            j["detection_by_size"] = std::move(*by_size);
        }

        // Step 4: decimate x tracking mode.
        if (spec->sweep) {
            std::printf("\n");
            printHeader("decimate, mode (bundle+filter)");
            json js = json::array();
            for (const double decimate : {1.0, 2.0, 3.0}) {
                for (const bool tracking_mode : {false, true}) {
                    tracking::TrackerOptions o = baseOptions(*lc, decimate);
                    o.tracking_mode = tracking_mode;
                    auto run = runTracker(*lc, o);
                    if (!run) return reportError(run.error());
                    const std::string label =
                        "d" + fmt(decimate, "%.0f") + (tracking_mode ? " tracking mode" : " full frame");
                    printRow(label, run->camera);
                    json e = run->camera.toJson();
                    e["decimate"] = decimate;
                    e["tracking_mode"] = tracking_mode;
                    e["detect_ms_p50"] = run->detect_ms_p50;
                    e["full_frame_detections"] = run->full_frame_detections;
                    js.push_back(e);
                    sweep.push_back({spec->name, decimate, tracking_mode, std::move(*run)});
                }
            }
            j["sweep"] = js;
            // Tracking mode against full frame at each decimation.
            for (std::size_t k = 0; k + 1 < sweep.size(); ++k) {
                const SweepPoint& a = sweep[k];
                const SweepPoint& b = sweep[k + 1];
                if (a.case_name != spec->name || a.tracking_mode || !b.tracking_mode || a.decimate != b.decimate) continue;
                std::printf("decimate %.0f: tracking mode %.2fx faster per frame; rotation p50 %.3f -> %.3f deg\n",
                            a.decimate, ErrorStats::pct(a.run.camera.ms, 50) / ErrorStats::pct(b.run.camera.ms, 50),
                            ErrorStats::pct(a.run.camera.rot_deg, 50), ErrorStats::pct(b.run.camera.rot_deg, 50));
            }
        }
        report["cases"][spec->name] = j;
    }
    if (!options.plot.empty()) {
        if (sweep.empty()) {
            log::warning("--plot: no case with a sweep ran (desk, desk720); no plot written");
        } else {
            drawPlot(sweep, options.plot);
            std::printf("\nplot: %s\n", options.plot.c_str());
        }
    }
    if (!options.json.empty()) {
        if (auto ok = writeJson(options.json, report); !ok) return reportError(ok.error());
        std::printf("json: %s\n", options.json.c_str());
    }
    return kExitOk;
}

}  // namespace commonlight::apps

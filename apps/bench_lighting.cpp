#include "apps/bench_lighting.h"
#include "apps/bench_lighting_common.h"

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <numbers>
#include <random>

#include "apps/app.h"
#include "apps/report.h"
#include "bench/lighting_eval.h"
#include "core/log.h"
#include "core/scene_io.h"
#include "core/sequence_io.h"
#include "lighting/estimator.h"
#include "lighting/shading_direction.h"
#include "mocks/sim/render.h"
#include "mocks/sim/simulation.h"
#include "mocks/sim/trajectory.h"

namespace commonlight::apps {

namespace fs = std::filesystem;

namespace bench_common {

double luma(const Eigen::Vector3d& v) { return 0.2126 * v.x() + 0.7152 * v.y() + 0.0722 * v.z(); }

double percentile(std::vector<double> v, double p) {
    if (v.empty()) return 0.0;
    std::sort(v.begin(), v.end());
    const auto k = static_cast<std::size_t>(std::clamp(std::ceil(p / 100.0 * v.size()), 1.0, static_cast<double>(v.size())));
    return v[k - 1];
}

std::string fmt(double v, const char* f) {
    char b[64];
    std::snprintf(b, sizeof b, f, v);
    return b;
}

Result<cv::Mat> readExrRgb(const fs::path& file) {
    cv::Mat bgr = cv::imread(file.string(), cv::IMREAD_UNCHANGED);
    if (bgr.empty() || bgr.type() != CV_32FC3) return fail(ErrorCode::kBadInput, file.string() + ": not a float RGB EXR");
    cv::Mat rgb;
    cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
    return rgb;
}

// Renders the scene along the trajectory once into data_dir (kept for later runs), then reads it.
Result<SimSequence> renderOrLoad(const fs::path& scene_file, const fs::path& trajectory_file, const BenchLightingOptions& o,
                                 const std::string& name, int frames) {
    CL_TRY(Scene truth, readScene(scene_file));
    if (!truth.camera) return fail(ErrorCode::kBadInput, scene_file.string() + ": the scene names no camera");
    const int height = o.width * truth.camera->height / truth.camera->width;
    const CameraModel camera = truth.camera->scaledTo(o.width, height);
    CL_TRY(mocks::sim::Trajectory trajectory, mocks::sim::Trajectory::read(trajectory_file));
    const fs::path dir = o.data_dir / (name + "-" + std::to_string(o.width) + "-" + std::to_string(o.spp) + "spp-" +
                                       std::to_string(frames));
    return renderOrLoadScene(truth, trajectory, camera, o.spp, dir, name, frames);
}

Result<SimSequence> renderOrLoadScene(const Scene& truth, const mocks::sim::Trajectory& trajectory, const CameraModel& camera, int spp,
                                      const fs::path& dir, const std::string& name, int frames) {
    const auto complete = [&]() {
        auto seq = readSequence(dir);
        return seq && static_cast<int>(seq->frames.size()) == frames && static_cast<int>(seq->groundtruth_poses.size()) == frames;
    };
    if (!complete()) {
        std::error_code ec;
        fs::remove_all(dir, ec);
        fs::create_directories(dir.parent_path(), ec);
        mocks::sim::SimulationOptions sim;
        sim.out = dir;
        sim.frames = frames;
        sim.spp = spp;
        sim.max_depth = 8;
        sim.camera = camera;
        std::printf("  rendering %s: %d frames %dx%d at %d spp (kept in %s)\n", name.c_str(), frames, camera.width,
                    camera.height, spp, dir.c_str());
        std::fflush(stdout);
        CL_TRY(mocks::sim::SimulationSummary summary, mocks::sim::simulate(truth, trajectory, sim));
        if (summary.frames_written != frames) return fail(ErrorCode::kInternal, "bench: the render of " + name + " stopped early");
    }
    CL_TRY(Sequence seq, readSequence(dir));
    SimSequence out;
    out.camera = camera;
    for (std::size_t i = 0; i < seq.frames.size(); ++i) {
        const std::string stem = fs::path(seq.frames[i].filename).stem().string();
        // The pose the frame was rendered at (the middle of its exposure).
        const std::optional<Rigid3d> world_from_cam = groundTruthOfFrame(seq, i);
        if (!world_from_cam) return fail(ErrorCode::kBadInput, dir.string() + ": frame " + stem + " has no ground-truth pose");
        out.world_from_cam.push_back(*world_from_cam);
        CL_TRY(cv::Mat r, readExrRgb(dir / "groundtruth/radiance" / (stem + ".exr")));
        CL_TRY(cv::Mat c, readExrRgb(dir / "groundtruth/radiance_composite" / (stem + ".exr")));
        out.radiance.push_back(r);
        out.composite.push_back(c);
        out.changed.push_back(cv::imread((dir / "groundtruth/masks/changed" / (stem + ".png")).string(), cv::IMREAD_GRAYSCALE));
        out.virtual_coverage.push_back(cv::imread((dir / "groundtruth/masks/virtual" / (stem + ".png")).string(), cv::IMREAD_GRAYSCALE));
    }
    return out;
}

// The camera the estimator sees: linear radiance x scale, multiplicative Gaussian noise of
// `noise` (relative, per pixel and channel), clipped, sRGB-encoded to 8 bits. Relative radiance
// is then exactly scale x radiance (exposure 1 s, gain 1).
Image encodeFrame(const cv::Mat& radiance, double scale, double noise, std::uint64_t seed) {
    Image out(PixelFormat::kRgb8, radiance.cols, radiance.rows);
    std::mt19937_64 rng(seed);
    std::normal_distribution<double> n01(0.0, 1.0);
    for (int y = 0; y < radiance.rows; ++y) {
        const auto* in = radiance.ptr<float>(y);
        std::uint8_t* px = out.mutableView().row(y);
        for (int x = 0; x < 3 * radiance.cols; ++x) {
            double v = scale * in[x];
            if (noise > 0.0) v *= 1.0 + noise * n01(rng);
            px[x] = static_cast<std::uint8_t>(std::lround(255.0 * linearToSrgb(static_cast<float>(std::clamp(v, 0.0, 1.0)))));
        }
    }
    return out;
}

// A scale that puts the 99.9th percentile of the first frame's luminance at 0.85 of full scale: a careful
// exposure, which keeps the small bright things (a tag's white ring in the sun) below saturation.
double exposureFor(const cv::Mat& radiance) {
    std::vector<double> l;
    for (int y = 0; y < radiance.rows; y += 2) {
        const auto* in = radiance.ptr<float>(y);
        for (int x = 0; x < radiance.cols; x += 2) l.push_back(0.2126 * in[3 * x] + 0.7152 * in[3 * x + 1] + 0.0722 * in[3 * x + 2]);
    }
    const double p = percentile(l, 99.9);
    return p > 0.0 ? 0.85 / p : 1.0;
}

}  // namespace bench_common

namespace bench_common {

// The truth's ratio composite / plain (luminance) over the bounding box of masks/changed,
// path-traced again at `spp` with another seed: per pixel, the sequence's own ratio carries the
// Monte Carlo noise of its spp where paths meet a virtual object (NaN outside the box).
Result<cv::Mat> referenceRatio(const mocks::sim::SimScene& plain, const mocks::sim::SimScene& composite, const SimSequence& seq,
                               std::size_t frame, int spp) {
    cv::Mat out(seq.camera.height, seq.camera.width, CV_64F, cv::Scalar(std::nan("")));
    if (seq.changed[frame].empty() || cv::countNonZero(seq.changed[frame]) == 0) return out;
    const cv::Rect box = cv::boundingRect(seq.changed[frame] >= 128);
    mocks::sim::RenderRequest request;
    request.camera = seq.camera;
    request.world_from_cam = seq.world_from_cam[frame];
    request.spp = spp;
    request.seed = 0x5eed2;
    request.frame_index = frame;
    request.max_depth = 8;
    request.region = mocks::sim::PixelRect{box.x, box.y, box.width, box.height};
    request.scene = &plain;
    CL_TRY(mocks::sim::RenderOutput a, mocks::sim::render(request));
    request.scene = &composite;
    CL_TRY(mocks::sim::RenderOutput b, mocks::sim::render(request));
    for (int y = box.y; y < box.y + box.height; ++y) {
        const auto* pa = reinterpret_cast<const float*>(a.radiance.view().row(y));
        const auto* pb = reinterpret_cast<const float*>(b.radiance.view().row(y));
        for (int x = box.x; x < box.x + box.width; ++x) {
            const double la = luma(Eigen::Vector3d(pa[3 * x], pa[3 * x + 1], pa[3 * x + 2]));
            const double lb = luma(Eigen::Vector3d(pb[3 * x], pb[3 * x + 1], pb[3 * x + 2]));
            if (la > 1e-6) out.at<double>(y, x) = lb / la;
        }
    }
    return out;
}

void RatioError::add(const Image& predicted, const cv::Mat& plain, const cv::Mat& composite, const cv::Mat& changed,
                     const cv::Mat& coverage) {
    for (int y = 0; y < plain.rows; ++y) {
        const auto* p = reinterpret_cast<const float*>(predicted.view().row(y));
        const auto* a = plain.ptr<float>(y);
        const auto* b = composite.ptr<float>(y);
        for (int x = 0; x < plain.cols; ++x) {
            if (changed.empty() || changed.at<std::uint8_t>(y, x) < 128) continue;
            if (!coverage.empty() && coverage.at<std::uint8_t>(y, x) > 0) continue;
            if (!std::isfinite(p[3 * x + 1])) continue;
            const double la = 0.2126 * a[3 * x] + 0.7152 * a[3 * x + 1] + 0.0722 * a[3 * x + 2];
            const double lb = 0.2126 * b[3 * x] + 0.7152 * b[3 * x + 1] + 0.0722 * b[3 * x + 2];
            if (!(la > 1e-6)) continue;
            const double lp = 0.2126 * p[3 * x] + 0.7152 * p[3 * x + 1] + 0.0722 * p[3 * x + 2];
            errors.push_back(lp - lb / la);
        }
    }
}

double RatioError::rms() const {
    double sum = 0.0;
    for (double e : errors) sum += e * e;
    return errors.empty() ? 0.0 : std::sqrt(sum / static_cast<double>(errors.size()));
}

double RatioError::mean() const {
    double sum = 0.0;
    for (double e : errors) sum += e;
    return errors.empty() ? 0.0 : sum / static_cast<double>(errors.size());
}

}  // namespace bench_common

namespace {

using namespace bench_common;
using lighting::Estimator;
using lighting::EstimatorOptions;
using lighting::LightingSnapshot;
using lighting::Mode;

struct EstimateRun {
    std::unique_ptr<Estimator> estimator;
    LightingSnapshot snapshot;
    std::vector<lighting::LightEstimate> lights;  // the estimator's, relative units
    double radiance_scale = 1.0;
    double update_ms = 0.0;
};

// Feeds frames [0, count) of the sequence at one noise level and updates after each checkpoint.
Result<std::vector<EstimateRun>> estimateAlong(const Scene& estimated, const SimSequence& seq, double noise,
                                               const std::vector<int>& checkpoints) {
    const double scale = exposureFor(seq.radiance.front());
    std::vector<EstimateRun> runs;
    lighting::SceneLightingOptions options;
    options.radiance_scale = scale;
    CL_TRY(std::unique_ptr<Estimator> estimator, Estimator::create(estimated, seq.camera, options));
    const auto poses = lighting::SceneLighting::scenePoses(estimated, 0.0);
    estimator->setVirtualPoses(poses);
    int fed = 0;
    for (int checkpoint : checkpoints) {
        for (; fed < checkpoint && fed < static_cast<int>(seq.radiance.size()); ++fed) {
            const Image frame = encodeFrame(seq.radiance[static_cast<std::size_t>(fed)], scale, noise, 1000 + fed);
            CL_TRY_VOID(estimator->observe(frame.view(), seq.world_from_cam[static_cast<std::size_t>(fed)].inverse(), 1.0, 1.0, fed));
        }
        const auto t0 = std::chrono::steady_clock::now();
        CL_TRY(LightingSnapshot snapshot, estimator->update(poses));
        EstimateRun run;
        run.update_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
        run.snapshot = std::move(snapshot);
        run.lights = estimator->lights();
        run.radiance_scale = estimator->radianceScale();
        runs.push_back(std::move(run));
    }
    runs.back().estimator = std::move(estimator);
    return runs;
}

// Reflectance errors (relative, max over channels) of the observed elements against their object's truth.
std::pair<double, double> reflectanceError(const Estimator& est, const Scene& truth) {
    std::vector<double> errors;
    const auto& rad = est.radiosity();
    for (int e : rad.leaves(Mode::kReal)) {
        const lighting::Face& f = rad.face(rad.hierarchy()[e].face);
        if (est.observations().aggregate(rad.hierarchy()[e]).pixels < 10) continue;
        const auto& albedo = truth.real_objects[static_cast<std::size_t>(f.object_index)].albedo.value;
        if (!albedo) continue;
        errors.push_back(((est.reflectance()[static_cast<std::size_t>(e)] - *albedo).cwiseQuotient(*albedo)).cwiseAbs().maxCoeff());
    }
    return {100.0 * percentile(errors, 50), 100.0 * percentile(errors, 95)};
}

const std::vector<double> kNoise{0.0, 0.01, 0.03};

// Case `known`: the desk with both lights' emission unknown.
Result<nlohmann::json> caseKnown(const BenchLightingOptions& o) {
    const fs::path scenes = o.source_dir / "data/scenes";
    CL_TRY(Scene truth, readScene(scenes / "desk/scene.yaml"));
    CL_TRY(SimSequence seq, renderOrLoad(scenes / "desk/scene.yaml", scenes / "desk/trajectory.yaml", o, "desk", o.frames));
    const Scene estimated = bench::asEstimated(truth, true, true);
    nlohmann::json rows = nlohmann::json::array();
    std::printf("\nknown light geometry, unknown emission (desk, %dx%d): emission error per light, reflectance error\n",
                seq.camera.width, seq.camera.height);
    std::printf("  %-6s %-7s %-34s %-22s %s\n", "noise", "frames", "emission error % (max over RGB)", "reflectance % p50/p95", "update ms");
    const std::vector<int> checkpoints{1, 10, o.frames};
    for (double noise : kNoise) {
        CL_TRY(std::vector<EstimateRun> runs, estimateAlong(estimated, seq, noise, checkpoints));
        for (std::size_t c = 0; c < runs.size(); ++c) {
            nlohmann::json lights = nlohmann::json::object(), signed_rgb = nlohmann::json::object();
            std::string text;
            for (const auto& light : runs[c].snapshot.lights) {
                const Light* t = nullptr;
                for (const Light& l : truth.lights) {
                    if (l.name == light.name) t = &l;
                }
                if (!t) continue;
                const Eigen::Vector3d relative = (light.emission - *t->emission.value).cwiseQuotient(*t->emission.value);
                const double err = 100.0 * relative.cwiseAbs().maxCoeff();
                lights[light.name] = err;
                signed_rgb[light.name] = {100.0 * relative.x(), 100.0 * relative.y(), 100.0 * relative.z()};
                text += light.name + " " + fmt(err) + "  ";
            }
            std::pair<double, double> refl{0, 0};
            if (c + 1 == runs.size()) refl = reflectanceError(*runs.back().estimator, truth);
            std::printf("  %-6s %-7d %-34s %-22s %.0f\n", (fmt(100 * noise, "%.0f") + "%").c_str(), checkpoints[c], text.c_str(),
                        c + 1 == runs.size() ? (fmt(refl.first) + " / " + fmt(refl.second)).c_str() : "",
                        runs[c].update_ms);
            nlohmann::json row{{"noise", noise}, {"frames", checkpoints[c]}, {"emission_error_pct", lights},
                               {"emission_signed_error_pct_rgb", signed_rgb}, {"update_ms", runs[c].update_ms}};
            if (c + 1 == runs.size()) row["reflectance_error_pct"] = {{"p50", refl.first}, {"p95", refl.second}};
            rows.push_back(row);
        }
    }
    return nlohmann::json{{"scene", "desk"}, {"rows", rows}};
}

// Case `distant`: the sunlit scene, one unknown distant light (128 directions).
Result<nlohmann::json> caseDistant(const BenchLightingOptions& o) {
    const fs::path scenes = o.source_dir / "data/scenes";
    CL_TRY(Scene truth, readScene(scenes / "sunlit/scene.yaml"));
    CL_TRY(Scene estimated, readScene(scenes / "sunlit/scene_estimated.yaml"));
    CL_TRY(SimSequence seq, renderOrLoad(scenes / "sunlit/scene.yaml", scenes / "sunlit/trajectory.yaml", o, "sunlit", o.frames));
    const Eigen::Vector3d sun_travel = std::get<DirectionalLightShape>(truth.lights[0].shape).direction.normalized();
    const Eigen::Vector3d sun_irradiance = *truth.lights[0].emission.value;
    // The truth's horizontal irradiance: the sun's at its elevation plus a uniform sky's pi L.
    const Eigen::Vector3d horizontal_truth = sun_irradiance * std::max(0.0, -sun_travel.z()) + std::numbers::pi * *truth.lights[1].emission.value;
    nlohmann::json rows = nlohmann::json::array();
    std::printf("\nunknown distant light (sunlit, %d directions): dominant direction and the sun's irradiance\n",
                std::get<DistantLightShape>(estimated.lights[0].shape).directions);
    std::printf("  %-6s %-7s %-12s %-18s %-18s %-10s %-13s %s\n", "noise", "frames", "direction", "sun irradiance %",
                "sun+sky horiz. %", "condition", "plain-LS < 0", "update ms");
    const std::vector<int> checkpoints{1, 10, o.frames};
    for (double noise : kNoise) {
        CL_TRY(std::vector<EstimateRun> runs, estimateAlong(estimated, seq, noise, checkpoints));
        for (std::size_t c = 0; c < runs.size(); ++c) {
            double direction_err = -1.0, irradiance_err = -1.0, irradiance_signed = 0.0;
            for (const auto& light : runs[c].snapshot.lights) {
                if (light.kind != lighting::LightKind::kDirectional) continue;
                direction_err = std::acos(std::clamp(light.direction.dot(sun_travel), -1.0, 1.0)) * 180.0 / M_PI;
                const Eigen::Vector3d relative = (light.emission - sun_irradiance).cwiseQuotient(sun_irradiance);
                irradiance_err = 100.0 * relative.cwiseAbs().maxCoeff();
                irradiance_signed = 100.0 * luma(relative);
            }
            // What is determined best: sun and sky together on an open horizontal surface (the
            // split between the sun and the sky cells around it is not: both light the same
            // elements the same way but for the shadows' edges).
            double total_err = 0.0;
            if (!runs[c].lights.empty()) {
                const Eigen::Vector3d total = runs[c].lights[0].emission / runs[c].radiance_scale;
                total_err = 100.0 * luma((total - horizontal_truth).cwiseQuotient(horizontal_truth));
            }
            double condition = 0.0;
            int negative = 0;
            if (c + 1 == runs.size() && !runs.back().estimator->lights().empty()) {
                condition = runs.back().estimator->lights()[0].condition_number;
                negative = runs.back().estimator->lights()[0].negative_in_plain_least_squares;
            }
            std::printf("  %-6s %-7d %-12s %-18s %-18s %-10s %-13s %.0f\n", (fmt(100 * noise, "%.0f") + "%").c_str(), checkpoints[c],
                        (fmt(direction_err, "%.2f") + " deg").c_str(),
                        (fmt(irradiance_err, "%.1f") + " (" + fmt(irradiance_signed, "%+.1f") + ")").c_str(),
                        fmt(total_err, "%+.1f").c_str(), c + 1 == runs.size() ? fmt(condition, "%.0f").c_str() : "",
                        c + 1 == runs.size() ? std::to_string(negative).c_str() : "", runs[c].update_ms);
            nlohmann::json row{{"noise", noise},
                               {"frames", checkpoints[c]},
                               {"direction_error_deg", direction_err},
                               {"irradiance_error_pct", irradiance_err},
                               {"irradiance_signed_error_pct", irradiance_signed},
                               {"horizontal_irradiance_signed_error_pct", total_err},
                               {"update_ms", runs[c].update_ms}};
            if (c + 1 == runs.size()) {
                row["condition_number"] = condition;
                row["negative_in_plain_least_squares"] = negative;
            }
            rows.push_back(row);
        }
    }
    return nlohmann::json{{"scene", "sunlit"}, {"rows", rows}};
}

struct RatioErrors {
    RatioError sequence;   // against the sequence's own frames (its spp)
    RatioError reference;  // against the reference renders (8x the spp)
    RatioError truth_noise;  // the sequence's ratio against the reference: its own noise
};

// The ratio against the truth on every 5th frame of a sequence.
Result<RatioErrors> ratioErrorOf(const Scene& truth, const Estimator& est, const LightingSnapshot& snapshot, const SimSequence& seq,
                                 int reference_spp) {
    RatioErrors err;
    mocks::sim::SimSceneOptions plain_options, composite_options;
    composite_options.include_virtual = true;
    CL_TRY(const mocks::sim::SimScene plain, mocks::sim::SimScene::build(truth, plain_options));
    CL_TRY(const mocks::sim::SimScene composite, mocks::sim::SimScene::build(truth, composite_options));
    for (std::size_t i = 0; i < seq.radiance.size(); i += 5) {
        auto predicted = est.ratioImage(snapshot, seq.world_from_cam[i].inverse());
        if (!predicted) continue;
        err.sequence.add(*predicted, seq.radiance[i], seq.composite[i], seq.changed[i], seq.virtual_coverage[i]);
        CL_TRY(const cv::Mat reference, referenceRatio(plain, composite, seq, i, reference_spp));
        for (int y = 0; y < reference.rows; ++y) {
            const auto* p = reinterpret_cast<const float*>(predicted->view().row(y));
            const auto* a = seq.radiance[i].ptr<float>(y);
            const auto* b = seq.composite[i].ptr<float>(y);
            for (int x = 0; x < reference.cols; ++x) {
                if (seq.changed[i].at<std::uint8_t>(y, x) < 128) continue;
                if (!seq.virtual_coverage[i].empty() && seq.virtual_coverage[i].at<std::uint8_t>(y, x) > 0) continue;
                const double r = reference.at<double>(y, x);
                if (!std::isfinite(r) || !std::isfinite(p[3 * x + 1])) continue;
                const double la = luma(Eigen::Vector3d(a[3 * x], a[3 * x + 1], a[3 * x + 2]));
                if (!(la > 1e-6)) continue;
                const double lb = luma(Eigen::Vector3d(b[3 * x], b[3 * x + 1], b[3 * x + 2]));
                err.reference.errors.push_back(luma(Eigen::Vector3d(p[3 * x], p[3 * x + 1], p[3 * x + 2])) - r);
                err.truth_noise.errors.push_back(lb / la - r);
            }
        }
    }
    return err;
}

// Case `ratio` (and `nothing`): the predicted ratio against the simulator's with/without frames.
Result<nlohmann::json> caseRatio(const BenchLightingOptions& o, bool nothing_known) {
    const fs::path scenes = o.source_dir / "data/scenes";
    nlohmann::json out = nlohmann::json::array();
    std::printf(nothing_known ? "\nno light in the scene (every surface emits): ratio B/B~ over masks/changed\n"
                              : "\nratio B/B~ against the simulator's frames with and without the virtual objects, over masks/changed\n");
    std::printf("  (against a reference rendered at 8x the sequence's spp over the changed region; beside it, against the\n"
                "   sequence's own frames, and the RMS noise of those frames' ratio against the reference)\n");
    std::printf("  %-6s %-16s %-16s %-14s %-8s %-8s %s\n", "scene", "RMS  mean", "frames: RMS mean", "frames noise", "pixels",
                "leaves", "update ms");
    for (const std::string name : {"desk", "room"}) {
        if (nothing_known && name == "room") continue;
        CL_TRY(Scene truth, readScene(scenes / name / "scene.yaml"));
        CL_TRY(SimSequence seq, renderOrLoad(scenes / name / "scene.yaml", scenes / name / "trajectory.yaml", o, name, o.frames));
        Scene estimated = bench::asEstimated(truth, true, true);
        if (nothing_known) estimated.lights.clear();
        CL_TRY(std::vector<EstimateRun> runs, estimateAlong(estimated, seq, 0.01, {o.frames}));
        const int reference_spp = 8 * o.spp;
        CL_TRY(const RatioErrors err, ratioErrorOf(truth, *runs.back().estimator, runs.back().snapshot, seq, reference_spp));
        std::printf("  %-6s %-16s %-16s %-14s %-8zu %-8d %.0f\n", name.c_str(),
                    (fmt(err.reference.rms(), "%.4f") + " " + fmt(err.reference.mean(), "%+.4f")).c_str(),
                    (fmt(err.sequence.rms(), "%.4f") + " " + fmt(err.sequence.mean(), "%+.4f")).c_str(), fmt(err.truth_noise.rms(), "%.4f").c_str(),
                    err.reference.errors.size(), runs.back().snapshot.solve.elements, runs.back().update_ms);
        out.push_back({{"scene", name},
                       {"rms", err.reference.rms()},
                       {"mean_signed", err.reference.mean()},
                       {"reference_spp", reference_spp},
                       {"rms_against_sequence_frames", err.sequence.rms()},
                       {"mean_signed_against_sequence_frames", err.sequence.mean()},
                       {"sequence_truth_noise_rms", err.truth_noise.rms()},
                       {"pixels", err.reference.errors.size()},
                       {"elements", runs.back().snapshot.solve.elements},
                       {"update_ms", runs.back().update_ms}});
    }
    return out;
}

// Seed 002's Tables 1-3 (Fournier et al., "Illumination problems in computer augmented reality",
// sec. 5): estimated tilt/slant of synthetic spheres by Pentland's method, Lee and Rosenfeld's and
// their own. Rows: the true slant; columns: the true tilt 0, 20, ..., 180; at slant 0 only the
// slant is given. As printed.
struct SeedTable {
    const char* method;
    std::vector<int> slants;
    std::vector<std::vector<std::pair<double, double>>> cells;  // [row][column] = (tilt, slant)
};

std::vector<SeedTable> seedTables() {
    using C = std::vector<std::pair<double, double>>;
    return {
        {"Pentland (seed 002 table 1)",
         {0, 10, 20, 30, 40, 50, 60, 80, 90},
         {C{{0, 28}},
          C{{10, 29}, {25, 29}, {46, 28}, {66, 27}, {78, 28}, {94, 27}, {112, 26}, {134, 26}, {156, 27}, {170, 27}},
          C{{25, 27}, {55, 28}, {66, 28}, {78, 27}, {81, 27}, {96, 27}, {107, 25}, {125, 27}, {154, 28}, {172, 26}},
          C{{7, 30}, {32, 30}, {54, 30}, {67, 28}, {81, 26}, {97, 25}, {115, 25}, {133, 27}, {151, 25}, {174, 23}},
          C{{4, 26}, {28, 30}, {48, 30}, {60, 29}, {78, 30}, {98, 27}, {117, 28}, {135, 29}, {154, 24}, {176, 24}},
          C{{3, 26}, {26, 30}, {47, 30}, {63, 29}, {77, 30}, {99, 27}, {114, 28}, {130, 26}, {155, 27}, {173, 29}},
          C{{2, 26}, {22, 30}, {45, 30}, {59, 29}, {78, 30}, {98, 27}, {111, 26}, {132, 29}, {156, 27}, {174, 27}},
          C{{1.3, 26}, {22, 30}, {45, 30}, {63, 24}, {78, 27}, {100, 25}, {111, 24}, {130, 25}, {151, 27}, {174, 23}},
          C{{1.6, 26}, {22, 30}, {45, 30}, {63, 24}, {76, 27}, {101, 25}, {117, 24}, {133, 27}, {151, 27}, {174, 23}}}},
        {"Lee-Rosenfeld (seed 002 table 2)",
         {0, 10, 20, 30, 40, 50, 60, 70, 80, 90},
         {C{{0, 26}},
          C{{17, 26}, {29, 28}, {42, 29}, {56, 30}, {67, 28}, {79, 27}, {91, 28}, {105, 26}, {120, 25}, {139, 26}},
          C{{28, 39}, {50, 44}, {60, 44}, {69, 44}, {73, 41}, {86, 38}, {101, 40}, {114, 30}, {140, 30}, {163, 24}},
          C{{8, 47}, {25, 49}, {49, 52}, {60, 50}, {75, 49}, {89, 48}, {106, 45}, {126, 40}, {147, 35}, {170, 33}},
          C{{6, 58}, {41, 58}, {41, 57}, {59, 58}, {76, 60}, {90, 59}, {108, 55}, {128, 49}, {150, 46}, {171, 44}},
          C{{6, 64}, {35, 68}, {47, 64}, {61, 64}, {76, 65}, {90, 64}, {107, 61}, {118, 63}, {150, 58}, {151, 59}},
          C{{6, 71}, {21, 70}, {41, 67}, {61, 67}, {78, 71}, {89, 78}, {106, 66}, {130, 64}, {154, 66}, {172, 69}},
          C{{6, 78}, {19, 76}, {42, 75}, {62, 74}, {82, 79}, {85, 80}, {105, 72}, {129, 72}, {158, 74}, {173, 78}},
          C{{4, 84}, {21, 81}, {40, 81}, {61, 80}, {84, 82}, {85, 83}, {108, 79}, {128, 80}, {152, 80}, {174, 84}},
          C{{4, 88}, {20, 86}, {41, 87}, {61, 87}, {78, 86}, {92, 86}, {109, 86}, {129, 86}, {145, 86}, {176, 88}}}},
        {"improved (seed 002 table 3)",
         {0, 10, 20, 30, 40, 50, 60, 80, 90},
         {C{{0, 52}},
          C{{-1, 51}, {18, 51}, {38, 50}, {60, 51}, {78, 51}, {98, 51}, {118, 52}, {140, 52}, {161, 52}, {181, 52}},
          C{{21, 45}, {49, 47}, {62, 46}, {73, 47}, {80, 51}, {98, 51}, {113, 45}, {129, 52}, {160, 52}, {181, 50}},
          C{{0, 50}, {20, 51}, {49, 48}, {63, 49}, {81, 49}, {95, 49}, {117, 50}, {140, 49}, {160, 51}, {181, 49}},
          C{{0, 47}, {40, 45}, {40, 45}, {61, 45}, {82, 43}, {97, 45}, {118, 47}, {139, 47}, {161, 52}, {181, 48}},
          C{{0, 49}, {30, 37}, {45, 40}, {63, 44}, {81, 45}, {98, 45}, {116, 45}, {128, 43}, {160, 47}, {166, 44}},
          C{{0, 47}, {17, 43}, {40, 43}, {63, 44}, {82, 47}, {95, 42}, {116, 48}, {139, 47}, {162, 47}, {181, 49}},
          C{{0, 58}, {20, 43}, {40, 43}, {61, 43}, {83, 59}, {97, 56}, {119, 53}, {139, 52}, {160, 50}, {180, 55}},
          C{{0, 73}, {19, 47}, {42, 36}, {60, 45}, {81, 57}, {99, 60}, {120, 62}, {139, 58}, {157, 50}, {179, 64}}}},
    };
}

double tiltError(double a, double b) {
    const double d = std::fmod(std::abs(a - b), 360.0);
    return std::min(d, 360.0 - d);
}

// Case `shading`: light direction from a known sphere's shading (seed 002 sec. 5), on the seed's
// spheres rendered by the path tracer for every cell of Tables 1-3, against the tables.
Result<nlohmann::json> caseShading(const BenchLightingOptions& o) {
    const int size = 96;
    const std::vector<SeedTable> tables = seedTables();
    std::printf("\nlight direction from the shading of a known sphere (seed 002 sec. 5): mean |error| per true tilt,\n"
                "  degrees tilt / slant, over the true slants of each table; %dx%d spheres, %d spp, 1%% noise\n", size, size, o.spp);
    // Step 1: our errors (and our Pentland and Lee-Rosenfeld) on every cell of the union of rows.
    std::map<std::pair<int, int>, std::array<std::pair<double, double>, 3>> ours;  // (slant, tilt) -> ours, pentland, lee
    for (int slant : {0, 10, 20, 30, 40, 50, 60, 70, 80, 90}) {
        for (int tilt = 0; tilt <= 180; tilt += 20) {
            if (slant == 0 && tilt > 0) continue;
            const Eigen::Vector3d l = lighting::directionOf({static_cast<double>(tilt), static_cast<double>(slant)});
            Scene scene;
            RealObject sphere;
            sphere.name = "ball";
            sphere.shape = SphereShape{0.5};
            sphere.albedo = RgbOrEstimate::constant(Eigen::Vector3d::Constant(0.7));
            scene.real_objects.push_back(sphere);
            Light sun;
            sun.name = "sun";
            sun.shape = DirectionalLightShape{-l};
            sun.emission = RgbOrEstimate::constant(Eigen::Vector3d::Constant(3.0));
            scene.lights.push_back(sun);
            CL_TRY(mocks::sim::SimScene sim, mocks::sim::SimScene::build(scene, {}));
            CameraModel camera;
            camera.width = camera.height = size;
            camera.fx = camera.fy = size * 0.42 / 0.05;
            camera.cx = camera.cy = (size - 1) / 2.0;
            CL_TRY(const Rigid3d world_from_cam, worldFromCamLookingAt(Eigen::Vector3d(0, 0, 10), Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitY()));
            mocks::sim::RenderRequest request;
            request.scene = &sim;
            request.camera = camera;
            request.world_from_cam = world_from_cam;
            request.spp = o.spp;
            request.max_depth = 1;
            CL_TRY(mocks::sim::RenderOutput out, mocks::sim::render(request));
            // 1% sensor noise per pixel and channel (the direct-only render of a sphere under a
            // directional light is exact otherwise).
            std::mt19937_64 rng(static_cast<std::uint64_t>(slant * 1000 + tilt));
            std::normal_distribution<float> n01(0.0f, 1.0f);
            auto* px = reinterpret_cast<float*>(out.radiance.data());
            for (int i = 0; i < 3 * size * size; ++i) px[i] *= 1.0f + 0.01f * n01(rng);
            std::vector<float> lum;
            std::vector<std::uint8_t> mask;
            for (int i = 0; i < size * size; ++i) {
                const auto* p = reinterpret_cast<const float*>(out.radiance.data()) + 3 * i;
                lum.push_back(0.2126f * p[0] + 0.7152f * p[1] + 0.0722f * p[2]);
                mask.push_back(out.object_id[static_cast<std::size_t>(i)] == 0 ? 1 : 0);
            }
            std::array<std::pair<double, double>, 3> e{};
            auto fit = lighting::fitSphereLight(out.radiance.view(), camera, world_from_cam.inverse(), Eigen::Vector3d::Zero(), 0.5);
            if (fit) e[0] = {tiltError(fit->view.tilt_deg, tilt), std::abs(fit->view.slant_deg - slant)};
            auto p = lighting::estimatePentland(lum, mask, size, size);
            if (p) e[1] = {tiltError(p->tilt_deg, tilt), std::abs(p->slant_deg - slant)};
            auto lr = lighting::estimateLeeRosenfeld(lum, mask, size, size);
            if (lr) e[2] = {tiltError(lr->tilt_deg, tilt), std::abs(lr->slant_deg - slant)};
            ours[{slant, tilt}] = e;
        }
    }
    // Step 2: per table and column, mean |error| of the seed's method and of ours on the same cells.
    nlohmann::json out = nlohmann::json::array();
    bool beats_all = true;
    for (const SeedTable& t : tables) {
        std::printf("  %-34s", t.method);
        for (int tilt = 0; tilt <= 180; tilt += 20) std::printf(" %9d", tilt);
        std::printf("\n");
        nlohmann::json columns = nlohmann::json::array();
        std::string seed_row = "    seed (as printed)                ", ours_row = "    ours (known sphere)              ",
                    mine_row = std::string("    this method as implemented here  ");
        for (int c = 0; c < 10; ++c) {
            const int tilt = 20 * c;
            double st = 0, ss = 0, ot = 0, os = 0, mt = 0, ms = 0;
            int nt = 0, ns = 0;
            for (std::size_t r = 0; r < t.slants.size(); ++r) {
                const int slant = t.slants[r];
                if (slant == 0 && c > 0) continue;
                const auto& cell = t.cells[r][static_cast<std::size_t>(c)];
                const auto& e = ours[{slant, slant == 0 ? 0 : tilt}];
                ss += std::abs(cell.second - slant);
                os += e[0].second;
                ms += t.method[0] == 'P' ? e[1].second : e[2].second;
                ++ns;
                if (slant > 0) {
                    st += tiltError(cell.first, tilt);
                    ot += e[0].first;
                    mt += t.method[0] == 'P' ? e[1].first : e[2].first;
                    ++nt;
                }
            }
            const double seed_t = nt ? st / nt : 0, seed_s = ss / ns, our_t = nt ? ot / nt : 0, our_s = os / ns;
            const bool beats = our_t <= seed_t && our_s <= seed_s;
            beats_all = beats_all && beats;
            seed_row += " " + fmt(seed_t, "%4.1f") + "/" + fmt(seed_s, "%-4.1f");
            ours_row += " " + fmt(our_t, "%4.2f") + "/" + fmt(our_s, "%-4.2f");
            mine_row += " " + fmt(nt ? mt / nt : 0, "%4.1f") + "/" + fmt(ms / ns, "%-4.1f");
            columns.push_back({{"tilt", tilt}, {"seed_tilt_error", seed_t}, {"seed_slant_error", seed_s},
                               {"ours_tilt_error", our_t}, {"ours_slant_error", our_s}, {"ours_better", beats}});
        }
        std::printf("%s\n%s\n", seed_row.c_str(), ours_row.c_str());
        if (t.method[0] != 'i') std::printf("%s\n", mine_row.c_str());
        out.push_back({{"method", t.method}, {"columns", columns}});
    }
    std::printf("  ours beats every column of the three tables: %s\n", beats_all ? "yes" : "NO");
    return nlohmann::json{{"tables", out}, {"ours_beats_every_column", beats_all}};
}

}  // namespace

std::vector<std::string> benchLightingCaseNames() { return {"solver", "known", "distant", "nothing", "ratio", "shading", "cluster", "incremental"}; }

int runBenchLighting(const BenchLightingOptions& options) {
    // Every case but `incremental` (its own run: --incremental) by default.
    std::vector<std::string> cases = options.cases;
    if (cases.empty()) {
        cases = benchLightingCaseNames();
        std::erase(cases, "incremental");
    }
    const bool solver_plot = std::find(cases.begin(), cases.end(), "solver") != cases.end();
    nlohmann::json report;
    report["frames"] = options.frames;
    report["width"] = options.width;
    report["spp"] = options.spp;
    for (const std::string& name : cases) {
        Result<nlohmann::json> result = fail(ErrorCode::kUsage, "unknown case " + name);
        if (name == "solver") result = runSolverCase(options, options.plot);
        if (name == "known") result = caseKnown(options);
        if (name == "distant") result = caseDistant(options);
        if (name == "nothing") result = caseRatio(options, true);
        if (name == "ratio") result = caseRatio(options, false);
        if (name == "shading") result = caseShading(options);
        if (name == "cluster") result = runClusterCase(options);
        if (name == "incremental") {
            // Its plot beside the solver's when both run.
            std::string plot = options.plot;
            if (!plot.empty() && solver_plot) plot = (fs::path(plot).parent_path() / (fs::path(plot).stem().string() + "-incremental.png")).string();
            result = runIncrementalCase(options, plot);
        }
        if (!result) return reportError(result.error());
        report[name] = *result;
        std::fflush(stdout);
    }
    if (!options.json.empty()) {
        if (auto ok = writeJson(options.json, report); !ok) return reportError(ok.error());
        std::printf("json: %s\n", options.json.c_str());
    }
    return kExitOk;
}

}  // namespace commonlight::apps

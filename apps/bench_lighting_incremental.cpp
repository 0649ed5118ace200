// `commonlight bench lighting --incremental`: a virtual object moving along a path, its influence on
// the real surfaces updated incrementally (lighting/influence.h), against full re-solves and the
// path tracer (mocks/sim). See apps/bench_lighting.h and docs/lighting.md ("Incremental update").
//
// The estimator is given the scene's true lights and albedos (Estimator::solveWith): what is
// measured is the incremental machinery, not the light estimation (the other cases measure that).
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <array>
#include <map>
#include <numbers>
#include <random>
#include <cstdlib>
#include <tuple>
#if __has_include(<valgrind/callgrind.h>)
#include <valgrind/callgrind.h>
#define CL_HAVE_CALLGRIND 1
#endif

#include "apps/bench_lighting.h"
#include "apps/bench_lighting_common.h"
#include "core/scene_io.h"
#include "lighting/estimator.h"
#include "lighting/snapshot_builder.h"
#include "mocks/sim/render.h"

namespace commonlight::apps {

namespace fs = std::filesystem;
using namespace bench_common;
using lighting::Estimator;
using lighting::EstimatorOptions;
using lighting::LightingSnapshot;
using lighting::Mode;

namespace {

constexpr double kPi = std::numbers::pi;

// CL_CG_MOVES=N: under `valgrind --tool=callgrind --instr-atstart=no --collect-atstart=no`, collect
// the first N incremental moves' updates only (not the setup, the truth or the full re-solves).
int callgrindMoves() {
    const char* v = std::getenv("CL_CG_MOVES");
    return v ? std::atoi(v) : 0;
}

void callgrindCollect(bool on) {
#ifdef CL_HAVE_CALLGRIND
    if (on) {
        CALLGRIND_START_INSTRUMENTATION;
        CALLGRIND_TOGGLE_COLLECT;
    } else {
        CALLGRIND_TOGGLE_COLLECT;
        CALLGRIND_STOP_INSTRUMENTATION;
    }
#else
    (void)on;
#endif
}

double msSince(std::chrono::steady_clock::time_point t0) {
    return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

// CPU time of the process (every thread), milliseconds: steadier than the wall clock on a machine
// other work shares.
double cpuMs() {
    timespec t{};
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
    return static_cast<double>(t.tv_sec) * 1e3 + static_cast<double>(t.tv_nsec) * 1e-6;
}

// A scene of the case: its files, the base mesh, the path of its first virtual object.
struct PathScene {
    std::string name;
    double element_size;        // EstimatorOptions::initial_element_size
    Eigen::Vector2d centre;     // the path: a circle in the object's horizontal plane
    double radius;
};

struct Setup {
    Scene truth;
    CameraModel camera;
    Rigid3d world_from_cam;
    std::vector<Rigid3d> start;
};

Result<Setup> loadSetup(const BenchLightingOptions& o, const PathScene& ps) {
    const fs::path scenes = o.source_dir / "data/scenes";
    Setup s;
    CL_TRY(s.truth, readScene(scenes / ps.name / "scene.yaml"));
    if (!s.truth.camera) return fail(ErrorCode::kBadInput, ps.name + ": the scene names no camera");
    s.camera = s.truth.camera->scaledTo(o.width, o.width * s.truth.camera->height / s.truth.camera->width);
    CL_TRY(mocks::sim::Trajectory trajectory, mocks::sim::Trajectory::read(scenes / ps.name / "trajectory.yaml"));
    s.world_from_cam = trajectory.worldFromCam(trajectory.startTime());
    s.start = lighting::SceneLighting::scenePoses(s.truth, 0.0);
    if (s.start.empty()) return fail(ErrorCode::kBadInput, ps.name + ": the scene has no virtual object");
    return s;
}

// The moving object's pose at step k of n: once around the circle, at its resting height.
std::vector<Rigid3d> posesAt(const Setup& s, const PathScene& ps, int k, int n) {
    std::vector<Rigid3d> poses = s.start;
    const double a = 2.0 * kPi * k / n;
    poses[0].translation = Eigen::Vector3d(ps.centre.x() + ps.radius * std::cos(a), ps.centre.y() + ps.radius * std::sin(a),
                                           s.start[0].translation.z());
    return poses;
}

Result<std::unique_ptr<Estimator>> makeEstimator(const Setup& s, const PathScene& ps, const lighting::InfluenceOptions* influence,
                                                 const std::vector<Rigid3d>& poses) {
    EstimatorOptions eo;
    eo.refine_unobserved = true;
    eo.initial_element_size = ps.element_size;
    eo.light_refinement_size = 0.08;
    if (influence) {
        // (The scenes' lights are area lights: the direct light per texel, and these the elements'.)
        eo.influence = *influence;
        eo.texel_refine_epsilon = influence->refine_epsilon;
        eo.texel_footprint_pixels = influence->footprint_pixels;
    }
    CL_TRY(std::unique_ptr<Estimator> est, Estimator::create(s.truth, s.camera, {}, eo));
    est->setViewer(s.world_from_cam.inverse());
    std::vector<Eigen::Vector3d> emission, albedo;
    for (const Light& l : s.truth.lights) emission.push_back(*l.emission.value);
    for (const RealObject& r : s.truth.real_objects) albedo.push_back(*r.albedo.value);
    CL_TRY_VOID(est->solveWith(emission, albedo, poses));
    return est;
}

// The truth at one step: the scene with the object there, rendered once (kept), and the reference
// ratio at 8x its spp over the changed region.
struct Truth {
    SimSequence seq;
    cv::Mat reference;
};

Result<Truth> truthAt(const BenchLightingOptions& o, const Setup& s, const PathScene& ps, int step, const std::vector<Rigid3d>& poses) {
    Scene truth = s.truth;
    for (std::size_t v = 0; v < truth.virtual_objects.size() && v < poses.size(); ++v) truth.virtual_objects[v].placement = FixedPlacement{poses[v]};
    CL_TRY(mocks::sim::Trajectory still, mocks::sim::Trajectory::fromKeyframes({mocks::sim::CameraKeyframe{0.0, s.world_from_cam}}));
    const fs::path dir = o.data_dir / ("incremental-" + ps.name + "-" + std::to_string(o.width) + "-" + std::to_string(o.spp) + "spp-" +
                                       std::to_string(o.steps) + "steps-" + std::to_string(step));
    Truth t;
    CL_TRY(t.seq, renderOrLoadScene(truth, still, s.camera, o.spp, dir, ps.name + " step " + std::to_string(step), 1));
    mocks::sim::SimSceneOptions plain_options, composite_options;
    composite_options.include_virtual = true;
    // The reference is kept beside the frames too (raw floats: rows, cols, type, then the pixels):
    // it costs more than the frames.
    const fs::path kept = dir / ("reference-ratio-" + std::to_string(8 * o.spp) + "spp.bin");
    if (std::FILE* f = std::fopen(kept.c_str(), "rb")) {
        int header[3] = {0, 0, 0};
        bool ok = std::fread(header, sizeof(int), 3, f) == 3 && header[0] > 0 && header[1] > 0 && header[0] < 100000 && header[1] < 100000;
        if (ok) {
            t.reference.create(header[0], header[1], header[2]);
            const std::size_t bytes = t.reference.total() * t.reference.elemSize();
            ok = t.reference.isContinuous() && std::fread(t.reference.data, 1, bytes, f) == bytes;
        }
        std::fclose(f);
        if (ok) return t;
    }
    CL_TRY(const mocks::sim::SimScene plain, mocks::sim::SimScene::build(truth, plain_options));
    CL_TRY(const mocks::sim::SimScene composite, mocks::sim::SimScene::build(truth, composite_options));
    CL_TRY(t.reference, referenceRatio(plain, composite, t.seq, 0, 8 * o.spp));
    if (t.reference.isContinuous()) {
        if (std::FILE* f = std::fopen(kept.c_str(), "wb")) {
            const int header[3] = {t.reference.rows, t.reference.cols, t.reference.type()};
            const std::size_t bytes = t.reference.total() * t.reference.elemSize();
            const bool ok = std::fwrite(header, sizeof(int), 3, f) == 3 && std::fwrite(t.reference.data, 1, bytes, f) == bytes;
            if (std::fclose(f) != 0 || !ok) {
                std::error_code ec;
                fs::remove(kept, ec);
            }
        }
    }
    return t;
}

// The predicted ratio against the reference (and the sequence's own frame) over masks/changed.
struct RatioFigures {
    double rms = 0.0, mean = 0.0, frame_rms = 0.0;
    std::size_t pixels = 0;
};

RatioFigures ratioAgainst(const Estimator& est, const LightingSnapshot& snapshot, const Truth& t, const Rigid3d& world_from_cam) {
    RatioFigures out;
    auto predicted = est.ratioImage(snapshot, world_from_cam.inverse());
    if (!predicted) return out;
    RatioError frame;
    frame.add(*predicted, t.seq.radiance[0], t.seq.composite[0], t.seq.changed[0], t.seq.virtual_coverage[0]);
    RatioError reference;
    for (int y = 0; y < t.reference.rows; ++y) {
        const auto* p = reinterpret_cast<const float*>(predicted->view().row(y));
        for (int x = 0; x < t.reference.cols; ++x) {
            if (t.seq.changed[0].at<std::uint8_t>(y, x) < 128) continue;
            if (!t.seq.virtual_coverage[0].empty() && t.seq.virtual_coverage[0].at<std::uint8_t>(y, x) > 0) continue;
            const double r = t.reference.at<double>(y, x);
            if (!std::isfinite(r) || !std::isfinite(p[3 * x + 1])) continue;
            reference.errors.push_back(luma(Eigen::Vector3d(p[3 * x], p[3 * x + 1], p[3 * x + 2])) - r);
        }
    }
    out.rms = reference.rms();
    out.mean = reference.mean();
    out.frame_rms = frame.rms();
    out.pixels = reference.errors.size();
    return out;
}

// Where the ratio's error is (by face, by depth of shadow) and what per-texel shadow rays for the
// direct light of the area lights would give instead of the elements' (Estimator::texelDirectRatio()),
// accumulated over the truth's steps.
struct DirectAnalysis {
    struct Sum {
        double sq = 0.0, sum = 0.0;
        std::size_t n = 0;
        void add(double e) {
            sq += e * e;
            sum += e;
            ++n;
        }
        double rms() const { return n ? std::sqrt(sq / static_cast<double>(n)) : 0.0; }
        double mean() const { return n ? sum / static_cast<double>(n) : 0.0; }
    };
    static constexpr int kPairs[] = {4, 16, 64, 256};
    Sum element, leaf, texel[4];
    double ms[4] = {0, 0, 0, 0};
    long rays[4] = {0, 0, 0, 0};
    std::map<std::string, std::array<Sum, 3>> by_face;  // element, leaf, texel at 256
    std::array<std::array<Sum, 3>, 3> by_depth;          // reference ratio < 0.6, 0.6-0.95, >= 0.95; element, leaf, texel 256
};

Result<void> analyseDirect(const Estimator& est, const LightingSnapshot& snapshot, const Truth& t, const Setup& s, DirectAnalysis& a) {
    CL_TRY(Image predicted, est.ratioImage(snapshot, s.world_from_cam.inverse()));
    const int w = t.reference.cols, h = t.reference.rows;
    std::vector<std::uint8_t> mask(static_cast<std::size_t>(w) * static_cast<std::size_t>(h), 0);
    for (int y = 0; y < h; ++y) {
        for (int x = 0; x < w; ++x) {
            if (t.seq.changed[0].at<std::uint8_t>(y, x) < 128) continue;
            if (!t.seq.virtual_coverage[0].empty() && t.seq.virtual_coverage[0].at<std::uint8_t>(y, x) > 0) continue;
            if (!std::isfinite(t.reference.at<double>(y, x))) continue;
            mask[static_cast<std::size_t>(y) * static_cast<std::size_t>(w) + static_cast<std::size_t>(x)] = 1;
        }
    }
    std::vector<Estimator::TexelRatio> texel;
    for (int k = 0; k < 4; ++k) {
        CL_TRY(Estimator::TexelRatio r, est.texelDirectRatio(s.world_from_cam.inverse(), DirectAnalysis::kPairs[k], mask));
        a.ms[k] += r.ms;
        a.rays[k] += r.rays;
        texel.push_back(std::move(r));
    }
    for (int y = 0; y < h; ++y) {
        const auto* p = reinterpret_cast<const float*>(predicted.view().row(y));
        for (int x = 0; x < w; ++x) {
            const std::size_t i = static_cast<std::size_t>(y) * static_cast<std::size_t>(w) + static_cast<std::size_t>(x);
            if (!mask[i] || !std::isfinite(p[3 * x + 1])) continue;
            const float leaf = texel[0].leaf[i];
            bool all = std::isfinite(leaf);
            for (const auto& r : texel) all = all && std::isfinite(r.texel[i]);
            if (!all) continue;
            const double ref = t.reference.at<double>(y, x);
            const double e_el = luma(Eigen::Vector3d(p[3 * x], p[3 * x + 1], p[3 * x + 2])) - ref, e_leaf = leaf - ref;
            const double e_tex = texel[3].texel[i] - ref;
            a.element.add(e_el);
            a.leaf.add(e_leaf);
            for (int k = 0; k < 4; ++k) a.texel[k].add(texel[static_cast<std::size_t>(k)].texel[i] - ref);
            const int fi = texel[0].face[i];
            std::string name = "?";
            if (fi >= 0) {
                const lighting::Face& f = est.radiosity().face(fi);
                name = (f.object_index >= 0 && static_cast<std::size_t>(f.object_index) < s.truth.real_objects.size()
                            ? s.truth.real_objects[static_cast<std::size_t>(f.object_index)].name
                            : std::string("object ") + std::to_string(f.object_index)) +
                       " face " + std::to_string(f.face_index);
            }
            auto& face = a.by_face[name];
            face[0].add(e_el);
            face[1].add(e_leaf);
            face[2].add(e_tex);
            const int depth = ref < 0.6 ? 0 : ref < 0.95 ? 1 : 2;
            a.by_depth[static_cast<std::size_t>(depth)][0].add(e_el);
            a.by_depth[static_cast<std::size_t>(depth)][1].add(e_leaf);
            a.by_depth[static_cast<std::size_t>(depth)][2].add(e_tex);
        }
    }
    return {};
}

nlohmann::json reportDirect(const DirectAnalysis& a) {
    std::printf("        where the ratio's error is (the same pixels for every column: RMS / mean signed, pixels):\n");
    std::printf("          element textures %.4f / %+.4f; the leaves' values unfiltered %.4f / %+.4f (%zu pixels)\n", a.element.rms(), a.element.mean(),
                a.leaf.rms(), a.leaf.mean(), a.element.n);
    nlohmann::json texel = nlohmann::json::array();
    for (int k = 0; k < 4; ++k) {
        std::printf("          direct light by per-texel shadow rays, %3d pairs per light: %.4f / %+.4f (%.1f ms, %.2f M rays over the steps)\n",
                    DirectAnalysis::kPairs[k], a.texel[k].rms(), a.texel[k].mean(), a.ms[k], static_cast<double>(a.rays[k]) * 1e-6);
        texel.push_back({{"pairs", DirectAnalysis::kPairs[k]}, {"rms", a.texel[k].rms()}, {"mean", a.texel[k].mean()}, {"ms", a.ms[k]}, {"rays", a.rays[k]}});
    }
    const char* depth[] = {"reference ratio < 0.6", "0.6 - 0.95", ">= 0.95"};
    nlohmann::json depths = nlohmann::json::array();
    for (int d = 0; d < 3; ++d) {
        const auto& x = a.by_depth[static_cast<std::size_t>(d)];
        std::printf("          %-22s %6zu px: element %.4f / %+.4f, leaves %.4f, texel (256) %.4f / %+.4f\n", depth[d], x[0].n, x[0].rms(), x[0].mean(),
                    x[1].rms(), x[2].rms(), x[2].mean());
        depths.push_back({{"range", depth[d]}, {"pixels", x[0].n}, {"element_rms", x[0].rms()}, {"element_mean", x[0].mean()}, {"leaf_rms", x[1].rms()},
                          {"texel256_rms", x[2].rms()}, {"texel256_mean", x[2].mean()}});
    }
    // Faces by their share of the squared error.
    std::vector<std::pair<double, std::string>> faces;
    for (const auto& [name, x] : a.by_face) faces.emplace_back(x[0].sq, name);
    std::sort(faces.rbegin(), faces.rend());
    nlohmann::json by_face = nlohmann::json::array();
    for (std::size_t k = 0; k < faces.size() && k < 8; ++k) {
        const auto& x = a.by_face.at(faces[k].second);
        std::printf("          %-24s %6zu px, %4.1f%% of the squared error: element %.4f / %+.4f, leaves %.4f, texel (256) %.4f / %+.4f\n",
                    faces[k].second.c_str(), x[0].n, 100.0 * x[0].sq / std::max(1e-300, a.element.sq), x[0].rms(), x[0].mean(), x[1].rms(), x[2].rms(),
                    x[2].mean());
        by_face.push_back({{"face", faces[k].second}, {"pixels", x[0].n}, {"element_rms", x[0].rms()}, {"element_mean", x[0].mean()},
                           {"leaf_rms", x[1].rms()}, {"texel256_rms", x[2].rms()}});
    }
    return {{"element_rms", a.element.rms()}, {"leaf_rms", a.leaf.rms()}, {"texel", texel}, {"by_depth", depths}, {"by_face", by_face}};
}

// Largest |D_a - D_b| between two estimators' leaves at the same places (their elements may have
// been made in different orders), over the largest B~.
double differenceBetween(const Estimator& a, const Estimator& b) {
    using Place = std::tuple<int, long, long, long, long>;
    const auto place = [](const lighting::Element& e) {
        const auto q = [](double v) { return std::lround(v * 1e7); };
        return Place{e.face, q(e.st.x()), q(e.st.y()), q(e.ds.x() + e.dt.x()), q(e.ds.y() + e.dt.y())};
    };
    std::map<Place, Eigen::Vector3d> db;
    for (int e : b.radiosity().leaves(Mode::kReal)) db[place(b.radiosity().hierarchy()[e])] = b.influence().difference()[static_cast<std::size_t>(e)];
    double worst = 0.0, scale = 0.0;
    for (int e : a.radiosity().leaves(Mode::kReal)) {
        scale = std::max(scale, a.influence().original()[static_cast<std::size_t>(e)].maxCoeff());
        const auto it = db.find(place(a.radiosity().hierarchy()[e]));
        if (it == db.end()) return 1e300;  // not the same elements
        worst = std::max(worst, (a.influence().difference()[static_cast<std::size_t>(e)] - it->second).cwiseAbs().maxCoeff());
    }
    return scale > 0.0 ? worst / scale : worst;
}

struct SweepPoint {
    std::string scene;
    double refine_epsilon = 0.0;
    double footprint = 0.0;
    double link_size = 0.0;
    double p50 = 0.0, p95 = 0.0;
    double rms = 0.0;
    int leaves_max = 0;
    bool full = false;  // a full re-solve point
};

struct Series {
    std::string scene;
    std::vector<int> leaves, links;
};

nlohmann::json stats(const std::vector<double>& v) {
    return {{"p50", percentile(v, 50)}, {"p95", percentile(v, 95)}, {"max", v.empty() ? 0.0 : *std::max_element(v.begin(), v.end())}};
}

// One scene: the path with the default thresholds (incremental, full re-solves beside it, truth),
// then the thresholds swept.
Result<nlohmann::json> runScene(const BenchLightingOptions& o, const PathScene& ps, std::vector<SweepPoint>& sweep, std::vector<Series>& series) {
    CL_TRY(const Setup s, loadSetup(o, ps));
    const int n = o.steps;
    std::vector<int> truth_steps;
    for (int k = 0; k < n; k += std::max(1, o.truth_every)) truth_steps.push_back(k);
    if (truth_steps.back() != n - 1) truth_steps.push_back(n - 1);
    // Step 1: the truth at the checkpoints (rendered once, kept in data_dir).
    std::map<int, Truth> truth;
    for (int k : truth_steps) {
        CL_TRY(truth[k], truthAt(o, s, ps, k, posesAt(s, ps, k, n)));
    }
    // Step 2: the path, incremental, with a full re-solve beside it every full_every steps.
    CL_TRY(std::unique_ptr<Estimator> inc, makeEstimator(s, ps, nullptr, posesAt(s, ps, 0, n)));
    CL_TRY(std::unique_ptr<Estimator> full, makeEstimator(s, ps, nullptr, posesAt(s, ps, 0, n)));
    const int base_leaves = static_cast<int>(inc->radiosity().leaves(Mode::kReal).size());
    const int base_links = inc->radiosity().linkCount(Mode::kReal);
    std::vector<double> cpu_ms;
    std::vector<double> update_ms, influence_ms, snapshot_ms, full_ms, rebuild_ms, agreement, candidates_ms, refine_ms, solve_ms, touched, evaluated,
        answers_computed, answers_kept, texels_built, texels, texels_traced;
    Series ser;
    ser.scene = ps.name;
    std::vector<RatioFigures> inc_ratio, full_ratio;
    DirectAnalysis direct;
    int most_leaves = 0;
    const int cg_moves = callgrindMoves();
    for (int k = 1; k <= n; ++k) {
        const int step = k % n;  // back to the start: the loop closes
        const std::vector<Rigid3d> poses = posesAt(s, ps, step, n);
        const auto t0 = std::chrono::steady_clock::now();
        const double c0 = cpuMs();
        const bool collect = k <= cg_moves;
        if (collect) callgrindCollect(true);
        CL_TRY(LightingSnapshot snapshot, inc->update(poses));
        if (collect) callgrindCollect(false);
        update_ms.push_back(msSince(t0));
        cpu_ms.push_back(cpuMs() - c0);
        if (inc->stats().full) return fail(ErrorCode::kInternal, "bench: a move made a full update");
        influence_ms.push_back(inc->stats().ms_influence);
        snapshot_ms.push_back(inc->stats().ms_snapshot);
        texels_built.push_back(static_cast<double>(inc->stats().texels_built));
        texels.push_back(static_cast<double>(inc->stats().texels));
        texels_traced.push_back(static_cast<double>(inc->stats().texels_traced));
        const auto& is = inc->stats().influence;
        candidates_ms.push_back(is.ms_candidates);
        refine_ms.push_back(is.ms_refine);
        solve_ms.push_back(is.ms_solve);
        touched.push_back(is.touched);
        evaluated.push_back(is.evaluated);
        answers_computed.push_back(static_cast<double>(is.answers_computed));
        answers_kept.push_back(static_cast<double>(is.answers_kept));
        ser.leaves.push_back(is.leaves);
        ser.links.push_back(base_links + is.corrections + is.cluster_links);
        most_leaves = std::max(most_leaves, is.leaves);
        const bool checkpoint = std::find(truth_steps.begin(), truth_steps.end(), step) != truth_steps.end();
        if (checkpoint) inc_ratio.push_back(ratioAgainst(*inc, snapshot, truth.at(step), s.world_from_cam));
        if (checkpoint && o.direct_analysis) CL_TRY_VOID(analyseDirect(*inc, snapshot, truth.at(step), s, direct));
        if (o.full_every > 0 && (checkpoint || k % o.full_every == 0)) {
            // The full re-solve: B~, the index and the influence from nothing, every texture.
            full->requestFullUpdate();
            const auto t1 = std::chrono::steady_clock::now();
            CL_TRY(LightingSnapshot full_snapshot, full->update(poses));
            full_ms.push_back(msSince(t1));
            agreement.push_back(differenceBetween(*inc, *full));
            // The influence alone from nothing (every shaft scanned, dense sweeps).
            std::vector<lighting::InfluenceObject> objects(poses.size());
            for (std::size_t v = 0; v < poses.size(); ++v) objects[v].world_from_object = poses[v];
            const auto t2 = std::chrono::steady_clock::now();
            CL_TRY(lighting::InfluenceStats rs, full->influence().rebuild(objects, lighting::InfluenceViewer{s.camera, s.world_from_cam.inverse()}));
            (void)rs;
            rebuild_ms.push_back(msSince(t2));
            if (checkpoint) full_ratio.push_back(ratioAgainst(*full, full_snapshot, truth.at(step), s.world_from_cam));
        }
    }
    series.push_back(ser);
    const auto mean_of = [](const std::vector<RatioFigures>& r, double RatioFigures::*f) {
        double sum = 0.0;
        std::size_t pixels = 0;
        for (const RatioFigures& x : r) {
            sum += (x.*f) * (x.*f) * static_cast<double>(x.pixels);
            pixels += x.pixels;
        }
        return pixels > 0 ? std::sqrt(sum / static_cast<double>(pixels)) : 0.0;
    };
    const auto mean_signed = [](const std::vector<RatioFigures>& r) {
        double sum = 0.0;
        std::size_t pixels = 0;
        for (const RatioFigures& x : r) {
            sum += x.mean * static_cast<double>(x.pixels);
            pixels += x.pixels;
        }
        return pixels > 0 ? sum / static_cast<double>(pixels) : 0.0;
    };
    const double inc_rms = mean_of(inc_ratio, &RatioFigures::rms), full_rms = mean_of(full_ratio, &RatioFigures::rms);
    const double inc_frame_rms = mean_of(inc_ratio, &RatioFigures::frame_rms);
    std::printf("  %-5s base %d leaves %d links; moving object: leaves %d..%d, links %d..%d\n", ps.name.c_str(), base_leaves, base_links,
                *std::min_element(ser.leaves.begin(), ser.leaves.end()), most_leaves, *std::min_element(ser.links.begin(), ser.links.end()),
                *std::max_element(ser.links.begin(), ser.links.end()));
    std::printf("        incremental update ms p50 %.1f p95 %.1f max %.1f (influence p50 %.1f, textures and probes p50 %.1f)\n",
                percentile(update_ms, 50), percentile(update_ms, 95), *std::max_element(update_ms.begin(), update_ms.end()),
                percentile(influence_ms, 50), percentile(snapshot_ms, 50));
    std::printf("        CPU time per update (all threads) p50 %.1f ms p95 %.1f ms\n", percentile(cpu_ms, 50), percentile(cpu_ms, 95));
    std::printf("        influence p50: candidates %.1f ms, refinement %.1f ms (%.0f base leaves recomputed, %.0f elements evaluated), "
                "propagation %.1f ms\n",
                percentile(candidates_ms, 50), percentile(refine_ms, 50), percentile(touched, 50), percentile(evaluated, 50), percentile(solve_ms, 50));
    std::printf("        answers per move p50 (a light, a blocked link or an object's light at an element): %.0f computed, %.0f kept\n",
                percentile(answers_computed, 50), percentile(answers_kept, 50));
    std::printf("        texels per move p50: %.0f computed of %.0f on the faces whose leaves changed (%.0f of them traced: a move reached their direct light)\n",
                percentile(texels_built, 50), percentile(texels, 50), percentile(texels_traced, 50));
    std::printf("        full re-solve ms p50 %.0f (influence from scratch alone p50 %.0f): %.0fx (%.0fx) the incremental p50\n",
                percentile(full_ms, 50), percentile(rebuild_ms, 50), percentile(full_ms, 50) / percentile(update_ms, 50),
                percentile(rebuild_ms, 50) / percentile(update_ms, 50));
    std::printf("        incremental against the full re-solve: largest |B - B'| / max B~ %.1e\n",
                agreement.empty() ? 0.0 : *std::max_element(agreement.begin(), agreement.end()));
    std::printf("        ratio B/B~ over masks/changed, %zu steps: incremental RMS %.4f mean %+.4f (against the frames %.4f); full re-solve RMS %.4f\n",
                inc_ratio.size(), inc_rms, mean_signed(inc_ratio), inc_frame_rms, full_rms);
    nlohmann::json direct_json;
    if (o.direct_analysis) direct_json = reportDirect(direct);
    sweep.push_back({ps.name, inc->influence().options().refine_epsilon, inc->influence().options().footprint_pixels,
                     inc->influence().options().link_size, percentile(update_ms, 50), percentile(update_ms, 95), inc_rms, most_leaves, false});
    sweep.push_back({ps.name, 0.0, 0.0, 0.0, percentile(full_ms, 50), percentile(full_ms, 95), full_rms, most_leaves, true});
    nlohmann::json out{{"scene", ps.name},
                       {"base_leaves", base_leaves},
                       {"base_links", base_links},
                       {"steps", n},
                       {"update_ms", stats(update_ms)},
                       {"update_cpu_ms", stats(cpu_ms)},
                       {"influence_ms", stats(influence_ms)},
                       {"snapshot_ms", stats(snapshot_ms)},
                       {"candidates_ms", stats(candidates_ms)},
                       {"refine_ms", stats(refine_ms)},
                       {"propagation_ms", stats(solve_ms)},
                       {"touched_base_leaves", stats(touched)},
                       {"evaluated_elements", stats(evaluated)},
                       {"answers_computed", stats(answers_computed)},
                       {"answers_kept", stats(answers_kept)},
                       {"texels_computed", stats(texels_built)},
                       {"texels_of_changed_faces", stats(texels)},
                       {"texels_traced", stats(texels_traced)},
                       {"full_resolve_ms", stats(full_ms)},
                       {"influence_rebuild_ms", stats(rebuild_ms)},
                       {"speedup_full_over_incremental_p50", percentile(full_ms, 50) / percentile(update_ms, 50)},
                       {"largest_difference_to_full", agreement.empty() ? 0.0 : *std::max_element(agreement.begin(), agreement.end())},
                       {"leaves", ser.leaves},
                       {"links", ser.links},
                       {"ratio_rms", inc_rms},
                       {"ratio_mean_signed", mean_signed(inc_ratio)},
                       {"ratio_rms_against_frames", inc_frame_rms},
                       {"full_ratio_rms", full_rms},
                       {"truth_steps", truth_steps}};
    if (o.direct_analysis) out["direct_analysis"] = direct_json;
    // Step 3: the thresholds swept (a fifth of the path's steps, the checkpoints among them).
    if (o.sweep) {
        nlohmann::json rows = nlohmann::json::array();
        std::printf("        refine_epsilon footprint_px link_size  update ms p50/p95   ratio RMS  leaves max\n");
        // refine_epsilon x link_size at the default footprint, then the footprint at the defaults.
        lighting::InfluenceOptions defaults;
        defaults.refine_epsilon = EstimatorOptions{}.texel_refine_epsilon;
        defaults.footprint_pixels = EstimatorOptions{}.texel_footprint_pixels;
        std::vector<std::tuple<double, double, double>> configs;
        for (double eps : {0.005, 0.01, 0.02, 0.05, 0.1}) {
            for (double link : {0.04, 0.08, 0.16}) configs.emplace_back(eps, defaults.footprint_pixels, link);
        }
        for (double fp : {1.0, 2.0, 8.0}) configs.emplace_back(defaults.refine_epsilon, fp, defaults.link_size);
        for (const auto& [eps, fp, link] : configs) {
            {
                lighting::InfluenceOptions io;
                io.refine_epsilon = eps;
                io.footprint_pixels = fp;
                io.link_size = link;
                io.max_leaves = s.truth.lighting.max_elements;
                CL_TRY(std::unique_ptr<Estimator> est, makeEstimator(s, ps, &io, posesAt(s, ps, 0, n)));
                std::vector<double> ms;
                std::vector<RatioFigures> rf;
                int leaves = 0;
                for (int k = 1; k <= n; ++k) {
                    const int step = k % n;
                    const bool checkpoint = std::find(truth_steps.begin(), truth_steps.end(), step) != truth_steps.end();
                    if (!checkpoint && k % 5 != 0) continue;
                    const auto t0 = std::chrono::steady_clock::now();
                    CL_TRY(LightingSnapshot snapshot, est->update(posesAt(s, ps, step, n)));
                    ms.push_back(msSince(t0));
                    leaves = std::max(leaves, est->stats().influence.leaves);
                    if (checkpoint) rf.push_back(ratioAgainst(*est, snapshot, truth.at(step), s.world_from_cam));
                }
                const double rms = mean_of(rf, &RatioFigures::rms);
                std::printf("        %-14.3f %-12.0f %-9.2f  %6.1f / %-8.1f  %.4f     %d\n", eps, fp, link, percentile(ms, 50), percentile(ms, 95), rms,
                            leaves);
                sweep.push_back({ps.name, eps, fp, link, percentile(ms, 50), percentile(ms, 95), rms, leaves, false});
                rows.push_back({{"refine_epsilon", eps}, {"footprint_pixels", fp}, {"link_size", link}, {"update_ms_p50", percentile(ms, 50)},
                                {"update_ms_p95", percentile(ms, 95)}, {"ratio_rms", rms}, {"leaves_max", leaves}});
            }
        }
        out["sweep"] = rows;
    }
    return out;
}

// The long check: random moves of the desk's first object over the table, then the state against
// a fresh solve of the last configuration.
Result<nlohmann::json> stressCheck(const BenchLightingOptions& o, const PathScene& ps) {
    CL_TRY(const Setup s, loadSetup(o, ps));
    CL_TRY(std::unique_ptr<Estimator> est, makeEstimator(s, ps, nullptr, s.start));
    std::mt19937 rng(2026);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    std::vector<Rigid3d> poses = s.start;
    int most = 0;
    std::size_t stored_first = 0;
    std::vector<double> ms;
    std::printf("  long check: %d random moves of the %s's %s over its table\n", o.stress_moves, ps.name.c_str(),
                s.truth.virtual_objects[0].name.c_str());
    for (int k = 0; k < o.stress_moves; ++k) {
        poses[0].translation = Eigen::Vector3d(ps.centre.x() + 0.5 * u(rng), ps.centre.y() + 0.3 * u(rng), s.start[0].translation.z());
        poses[0].rotation = Eigen::Quaterniond(Eigen::AngleAxisd(kPi * u(rng), Eigen::Vector3d::UnitZ()));
        const auto t0 = std::chrono::steady_clock::now();
        CL_TRY(LightingSnapshot snapshot, est->update(poses));
        (void)snapshot;
        ms.push_back(msSince(t0));
        most = std::max(most, est->stats().influence.leaves);
        if (k == std::min(99, o.stress_moves - 1)) stored_first = est->stats().influence.stored;
    }
    CL_TRY(std::unique_ptr<Estimator> fresh, makeEstimator(s, ps, nullptr, poses));
    const double difference = differenceBetween(*est, *fresh);
    const int fresh_leaves = static_cast<int>(fresh->radiosity().leaves(Mode::kReal).size());
    const std::size_t stored = est->stats().influence.stored;
    std::printf("        leaves at most %d (a fresh solve of the last configuration: %d); elements stored %zu after 100 moves, %zu after %d\n",
                most, fresh_leaves, stored_first, stored, o.stress_moves);
    std::printf("        the last state against a fresh solve: largest |B - B'| / max B~ %.1e (%s elements); update ms p50 %.1f p95 %.1f\n",
                difference, difference < 1e299 ? "the same" : "NOT the same", percentile(ms, 50), percentile(ms, 95));
    return nlohmann::json{{"moves", o.stress_moves},           {"leaves_max", most},        {"fresh_leaves", fresh_leaves},
                          {"stored_after_100", stored_first}, {"stored_at_end", stored},   {"difference_to_fresh", difference},
                          {"update_ms", stats(ms)}};
}

void drawPlot(const std::vector<SweepPoint>& sweep, const std::vector<Series>& series, const fs::path& file) {
    const int w = 1360, h = 600;
    cv::Mat img(h, w, CV_8UC3, cv::Scalar(255, 255, 255));
    const cv::Scalar black(0, 0, 0), grey(215, 215, 215), red(40, 40, 200);
    const cv::Scalar colours[] = {{200, 60, 20}, {20, 120, 220}};
    std::map<std::string, int> colour;
    for (const Series& s : series) colour.emplace(s.scene, static_cast<int>(colour.size()) % 2);
    // Left: update time (log) against ratio RMS.
    {
        const int left = 70, right = 640, top = 40, bottom = h - 60;
        double max_ms = 20.0, max_err = 0.04;
        for (const SweepPoint& p : sweep) {
            max_ms = std::max(max_ms, p.p50 * 1.5);
            max_err = std::max(max_err, p.rms * 1.15);
        }
        const double lmin = std::log10(0.5), lmax = std::log10(max_ms);
        const auto X = [&](double ms) { return left + static_cast<int>((right - left) * (std::log10(std::max(ms, 0.5)) - lmin) / (lmax - lmin)); };
        const auto Y = [&](double e) { return bottom - static_cast<int>((bottom - top) * e / max_err); };
        for (double ms = 1.0; ms <= max_ms; ms *= 10.0) {
            cv::line(img, {X(ms), top}, {X(ms), bottom}, grey);
            cv::putText(img, fmt(ms, "%.0f"), {X(ms) - 10, bottom + 18}, cv::FONT_HERSHEY_SIMPLEX, 0.45, black);
        }
        for (int k = 0; k <= 4; ++k) {
            const double e = max_err * k / 4;
            cv::line(img, {left, Y(e)}, {right, Y(e)}, grey);
            cv::putText(img, fmt(e, "%.3f"), {5, Y(e) + 5}, cv::FONT_HERSHEY_SIMPLEX, 0.45, black);
        }
        cv::line(img, {left, Y(0.03)}, {right, Y(0.03)}, red);  // the 0.03
        cv::line(img, {X(5.0), top}, {X(5.0), bottom}, red);    // and 5 ms p50
        cv::rectangle(img, {left, top}, {right, bottom}, black);
        cv::putText(img, "update ms p50 (log)   red: 5 ms, ratio RMS 0.03", {left + 100, h - 20}, cv::FONT_HERSHEY_SIMPLEX, 0.5, black);
        cv::putText(img, "ratio B/B~ RMS vs path tracer (dot: thresholds swept, ring: default, square: full re-solve)", {left - 40, 25},
                    cv::FONT_HERSHEY_SIMPLEX, 0.45, black);
        for (const SweepPoint& p : sweep) {
            const cv::Scalar c = colours[colour.count(p.scene) ? colour[p.scene] : 0];
            const cv::Point at(X(p.p50), Y(p.rms));
            if (p.full) {
                cv::rectangle(img, at - cv::Point(5, 5), at + cv::Point(5, 5), c, cv::FILLED);
            } else if (p.refine_epsilon == EstimatorOptions{}.texel_refine_epsilon && p.footprint == EstimatorOptions{}.texel_footprint_pixels &&
                       p.link_size == lighting::InfluenceOptions{}.link_size) {
                cv::circle(img, at, 7, c, 2);
            } else {
                cv::circle(img, at, 4, c, cv::FILLED);
            }
        }
        int y = top + 20;
        for (const auto& [scene, ci] : colour) {
            cv::putText(img, scene, {right - 70, y}, cv::FONT_HERSHEY_SIMPLEX, 0.5, colours[ci], 2);
            y += 20;
        }
    }
    // Right: leaves (top) and links (bottom) over the path's steps.
    {
        const int left = 760, right = w - 30;
        std::size_t steps = 1;
        for (const Series& s : series) steps = std::max(steps, s.leaves.size());
        const auto X = [&](std::size_t k) { return left + static_cast<int>((right - left) * static_cast<double>(k) / static_cast<double>(steps)); };
        const auto panel = [&](int top, int bottom, const char* what, auto values) {
            double lo = 1e300, hi = 0.0;
            for (const Series& s : series) {
                for (int v : values(s)) {
                    lo = std::min(lo, static_cast<double>(v));
                    hi = std::max(hi, static_cast<double>(v));
                }
            }
            lo = std::max(0.0, lo - 0.05 * (hi - lo + 1.0));
            hi = hi + 0.05 * (hi - lo + 1.0);
            const auto Y = [&](double v) { return bottom - static_cast<int>((bottom - top) * (v - lo) / (hi - lo)); };
            cv::rectangle(img, {left, top}, {right, bottom}, black);
            for (int k = 0; k <= 4; ++k) {
                const double v = lo + (hi - lo) * k / 4;
                cv::line(img, {left, Y(v)}, {right, Y(v)}, grey);
                cv::putText(img, fmt(v, "%.0f"), {left - 70, Y(v) + 5}, cv::FONT_HERSHEY_SIMPLEX, 0.4, black);
            }
            for (const Series& s : series) {
                const auto& vs = values(s);
                for (std::size_t k = 1; k < vs.size(); ++k) cv::line(img, {X(k - 1), Y(vs[k - 1])}, {X(k), Y(vs[k])}, colours[colour[s.scene]], 2);
            }
            cv::putText(img, what, {left + 10, top + 18}, cv::FONT_HERSHEY_SIMPLEX, 0.5, black);
        };
        panel(40, 270, "leaves along the path", [](const Series& s) -> const std::vector<int>& { return s.leaves; });
        panel(300, h - 60, "links (base + corrections + cluster) along the path", [](const Series& s) -> const std::vector<int>& { return s.links; });
        cv::putText(img, "step", {(left + right) / 2, h - 25}, cv::FONT_HERSHEY_SIMPLEX, 0.5, black);
    }
    cv::imwrite(file.string(), img);
}

}  // namespace

Result<nlohmann::json> runIncrementalCase(const BenchLightingOptions& o, const std::string& plot) {
    // The desk's ball once around the table; the room's ball around its desk (the room's base mesh
    // has over 1000 leaves, as the issue asks).
    const std::vector<PathScene> scenes{{"desk", 0.3, {0.0, 0.25}, 0.2}, {"room", 0.45, {0.0, 0.85}, 0.25}};
    std::printf("\nincremental update (lighting/influence.h): a virtual object moving along a path, %d steps, camera %dx%d\n", o.steps,
                o.width, o.width * 3 / 4);
    nlohmann::json out = nlohmann::json::array();
    std::vector<SweepPoint> sweep;
    std::vector<Series> series;
    for (const PathScene& ps : scenes) {
        if (!o.incremental_scenes.empty() && std::find(o.incremental_scenes.begin(), o.incremental_scenes.end(), ps.name) == o.incremental_scenes.end()) {
            continue;
        }
        CL_TRY(nlohmann::json j, runScene(o, ps, sweep, series));
        out.push_back(j);
        std::fflush(stdout);
    }
    nlohmann::json result{{"scenes", out}};
    if (o.stress_moves > 0) {
        CL_TRY(result["long_check"], stressCheck(o, scenes[0]));
    }
    if (!plot.empty()) {
        drawPlot(sweep, series, plot);
        std::printf("\nplot: %s\n", plot.c_str());
    }
    return result;
}

}  // namespace commonlight::apps

// Case `cluster` of `commonlight bench lighting`: a detailed real mesh proxy in a room (real
// spheres: icospheres of 320 triangles), solved with and without clustering of small proxies
// (lighting/radiosity_cluster.cpp): links, elements, setup and solve time, and the face radiances'
// error against the unclustered solve at fine settings (links refined 4x further).
#include <chrono>
#include <ctime>
#include <cmath>
#include <cstdio>
#include <memory>

#include "apps/bench_lighting.h"
#include "apps/bench_lighting_common.h"
#include "core/scene_io.h"
#include "lighting/estimator.h"
#include "lighting/radiosity.h"

namespace commonlight::apps {

namespace {

using bench_common::percentile;
using lighting::Face;
using lighting::Mode;
using lighting::Radiosity;
using lighting::RadiosityOptions;

// A 3 x 2.4 x 2.2 m room with a table; the ceiling emits; every surface has reflectance 0.5.
constexpr const char* kRoom = R"(
real:
  - {name: floor, plane: {size: [3.0, 2.4]}, world_from_object: {t: [0, 0, 0]}}
  - {name: ceiling, plane: {size: [3.0, 2.4]}, world_from_object: {t: [0, 0, 2.2], rpy_deg: [180, 0, 0]}}
  - {name: north, plane: {size: [3.0, 2.2]}, world_from_object: {t: [0, 1.2, 1.1], rpy_deg: [90, 0, 0]}}
  - {name: south, plane: {size: [3.0, 2.2]}, world_from_object: {t: [0, -1.2, 1.1], rpy_deg: [-90, 0, 0]}}
  - {name: west, plane: {size: [2.2, 2.4]}, world_from_object: {t: [-1.5, 0, 1.1], rpy_deg: [0, 90, 0]}}
  - {name: east, plane: {size: [2.2, 2.4]}, world_from_object: {t: [1.5, 0, 1.1], rpy_deg: [0, -90, 0]}}
  - {name: table, box: {size: [0.9, 0.6, 0.7]}, world_from_object: {t: [-0.6, 0.3, 0.35]}}
)";
// Real spheres (320 triangles each): one floating, one on the table, one on the floor.
constexpr const char* kBalls[] = {
    "  - {name: ball, sphere: {radius: 0.15}, world_from_object: {t: [0.5, -0.3, 0.9]}}\n",
    "  - {name: ball_on_table, sphere: {radius: 0.1}, world_from_object: {t: [-0.4, 0.3, 0.8]}}\n",
    "  - {name: ball_on_floor, sphere: {radius: 0.12}, world_from_object: {t: [0.9, 0.6, 0.12]}}\n",
};
constexpr int kCeiling = 1;

struct Run {
    int links = 0, cluster_links = 0, leaves = 0, iterations = 0;
    double setup_ms = 0.0, solve_ms = 0.0;
    std::vector<double> face_radiance, face_area;
    std::vector<int> face_object;
};

Result<Run> solveRoom(const std::string& yaml, const RadiosityOptions& options) {
    auto scene = parseScene(yaml, "bench-cluster.yaml");
    if (!scene) return std::unexpected(scene.error());
    auto faces = lighting::realFaces(*scene);
    if (!faces) return std::unexpected(faces.error());
    auto rays = lighting::RayScene::build(*faces, {}, {});
    if (!rays) return std::unexpected(rays.error());
    const auto t0 = std::chrono::steady_clock::now();
    Radiosity radiosity(*faces, {}, {}, **rays, options);
    radiosity.subdivideTo(0.3, 1.0);
    radiosity.markBuried();
    const std::size_t n0 = radiosity.hierarchy().elements().size();
    std::vector<double> estimate(n0, 0.3);
    for (std::size_t e = 0; e < n0; ++e) {
        if (radiosity.face(radiosity.hierarchy()[static_cast<int>(e)].face).object_index == kCeiling) estimate[e] = 1.0;
    }
    radiosity.setSourceRadiance(estimate);
    radiosity.buildRealLinks();
    const auto t1 = std::chrono::steady_clock::now();
    const std::size_t n = radiosity.hierarchy().elements().size();
    std::vector<Eigen::Vector3d> rho(n, Eigen::Vector3d::Constant(0.5)), emission(n, Eigen::Vector3d::Zero()), direct(n, Eigen::Vector3d::Zero());
    for (std::size_t e = 0; e < n; ++e) {
        if (radiosity.face(radiosity.hierarchy()[static_cast<int>(e)].face).object_index == kCeiling) emission[e].setOnes();
    }
    Run run;
    run.solve_ms = 1e300;
    lighting::Solution solution;
    for (int k = 0; k < 3; ++k) {  // best of 3
        const auto s0 = std::chrono::steady_clock::now();
        solution = radiosity.solve(Mode::kReal, rho, emission, direct);
        run.solve_ms = std::min(run.solve_ms, std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - s0).count());
    }
    run.setup_ms = std::chrono::duration<double, std::milli>(t1 - t0).count();
    run.links = radiosity.linkCount(Mode::kReal);
    run.cluster_links = static_cast<int>(radiosity.clusterLinks().size());
    run.leaves = static_cast<int>(radiosity.leaves(Mode::kReal).size());
    run.iterations = solution.summary.iterations;
    for (std::size_t f = 0; f < radiosity.realFaceCount(); ++f) {
        const int root = radiosity.hierarchy().root(static_cast<int>(f));
        run.face_radiance.push_back(solution.radiance[static_cast<std::size_t>(root)].x());
        run.face_area.push_back(radiosity.face(static_cast<int>(f)).area * radiosity.exposure(root));
        run.face_object.push_back(radiosity.face(static_cast<int>(f)).object_index);
    }
    return run;
}

// Area-weighted RMS and largest relative error of face radiances: the room's (objects < first_ball)
// or the balls' faces.
// `object` >= 0: that object's faces alone.
std::pair<double, double> faceError(const Run& run, const Run& reference, bool balls, int first_ball, int object = -1) {
    double area = 0.0, sq = 0.0, worst = 0.0;
    for (std::size_t f = 0; f < run.face_radiance.size() && f < reference.face_radiance.size(); ++f) {
        if ((run.face_object[f] >= first_ball) != balls || !(run.face_area[f] > 0.0) || !(reference.face_radiance[f] > 0.0)) continue;
        if (object >= 0 && run.face_object[f] != object) continue;
        const double rel = run.face_radiance[f] / reference.face_radiance[f] - 1.0;
        area += run.face_area[f];
        sq += run.face_area[f] * rel * rel;
        worst = std::max(worst, std::abs(rel));
    }
    return {area > 0.0 ? std::sqrt(sq / area) : 0.0, worst};
}

// The largest absolute error of the balls' faces over the largest radiance of the reference (the
// oracle's tolerance is relative to the scene's largest radiance: dark faces have large relative errors).
double ballErrorOfPeak(const Run& run, const Run& reference, int first_ball) {
    double peak = 0.0, worst = 0.0;
    for (std::size_t f = 0; f < reference.face_radiance.size(); ++f) peak = std::max(peak, reference.face_radiance[f]);
    for (std::size_t f = 0; f < run.face_radiance.size() && f < reference.face_radiance.size(); ++f) {
        if (run.face_object[f] < first_ball || !(run.face_area[f] > 0.0)) continue;
        worst = std::max(worst, std::abs(run.face_radiance[f] - reference.face_radiance[f]));
    }
    return peak > 0.0 ? worst / peak : 0.0;
}

// The virtual objects' influence (lighting/influence.h) sees a cluster's links as the element
// links they are linear in (Radiosity::clusterTransfers()): a virtual ball beside a clustered real
// sphere must change the ratio B/B~ as it does with the sphere unclustered. Measured against the
// unclustered solve, the ball at three places, beside the difference between two unclustered
// solves (links refined 2x further): what two valid discretisations of the same scene differ by.
// The scene: data/scenes/statue.

// The statue scene's estimator, solved without the ball's influence yet.
Result<std::unique_ptr<lighting::Estimator>> statueEstimator(const Scene& scene, int cluster_min_faces, double link_epsilon) {
    CameraModel camera;
    camera.width = 160;
    camera.height = 120;
    camera.fx = camera.fy = 140.0;
    camera.cx = 79.5;
    camera.cy = 59.5;
    lighting::EstimatorOptions o;
    o.refine_unobserved = true;
    o.radiosity.cluster_min_faces = cluster_min_faces;
    o.radiosity.link_epsilon = link_epsilon;
    auto est = lighting::Estimator::create(scene, camera, {}, o);
    if (!est) return std::unexpected(est.error());
    (*est)->setViewer(Rigid3d::fromRpyDeg(Eigen::Vector3d(0.0, -1.5, 1.2), Eigen::Vector3d(-130, 0, 0)).inverse());
    const std::vector<Eigen::Vector3d> albedo{Eigen::Vector3d::Constant(0.5), Eigen::Vector3d::Constant(0.7), Eigen::Vector3d::Constant(0.9)};
    if (auto solved = (*est)->solveWith({*scene.lights[0].emission.value}, albedo, lighting::SceneLighting::scenePoses(scene, 0.0)); !solved) {
        return std::unexpected(solved.error());
    }
    return std::move(*est);
}

Result<lighting::LightingSnapshot> influenceSnapshot(const Scene& scene, int cluster_min_faces, double link_epsilon, const Eigen::Vector3d& ball) {
    auto est = statueEstimator(scene, cluster_min_faces, link_epsilon);
    if (!est) return std::unexpected(est.error());
    std::vector<Rigid3d> poses = lighting::SceneLighting::scenePoses(scene, 0.0);
    poses[0] = Rigid3d::fromRpyDeg(ball, Eigen::Vector3d::Zero());
    return (*est)->update(poses);
}

// CPU time of the process (every thread), milliseconds: steadier than the wall clock on a machine
// other work shares.
double cpuMs() {
    timespec t{};
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
    return static_cast<double>(t.tv_sec) * 1e3 + static_cast<double>(t.tv_nsec) * 1e-6;
}

// The ball moving towards the statue in 5 mm steps (40 moves from 0.2 m away to touching it)
// and back, three times (240 moves): the update's wall and CPU time and the influence's share,
// per move, and the links the influence carries (element links and cluster transfers).
struct MoveTiming {
    double update_ms_p50 = 0.0, influence_ms_p50 = 0.0, update_cpu_ms_p50 = 0.0, update_cpu_ms_p95 = 0.0;
    double candidates_ms_p50 = 0.0, refine_ms_p50 = 0.0, solve_ms_p50 = 0.0;  // the influence's phases (wall)
    std::size_t moves = 0, links = 0, transfers = 0;
};
Result<MoveTiming> influenceTiming(const Scene& scene, int cluster_min_faces, int repeats) {
    auto est = statueEstimator(scene, cluster_min_faces, RadiosityOptions{}.link_epsilon);
    if (!est) return std::unexpected(est.error());
    std::vector<Rigid3d> poses = lighting::SceneLighting::scenePoses(scene, 0.0);
    std::vector<double> update, influence, cpu, candidates, refine, solve;
    constexpr int kLeg = 40;
    const int kMoves = 2 * repeats * kLeg;
    for (int move = 0; move <= kMoves; ++move) {
        const int step = (move / kLeg) % 2 == 0 ? move % kLeg : kLeg - move % kLeg;
        poses[0] = Rigid3d::fromRpyDeg(Eigen::Vector3d(-0.45 + 0.005 * step, 0.3, 0.1), Eigen::Vector3d::Zero());
        const auto start = std::chrono::steady_clock::now();
        const double c0 = cpuMs();
        if (auto s = (*est)->update(poses); !s) return std::unexpected(s.error());
        const double c1 = cpuMs();
        const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
        if (move == 0) continue;  // the ball's first placement
        update.push_back(ms);
        cpu.push_back(c1 - c0);
        influence.push_back((*est)->stats().ms_influence);
        candidates.push_back((*est)->stats().influence.ms_candidates);
        refine.push_back((*est)->stats().influence.ms_refine);
        solve.push_back((*est)->stats().influence.ms_solve);
    }
    MoveTiming t;
    t.moves = update.size();
    t.update_ms_p50 = percentile(update, 50);
    t.influence_ms_p50 = percentile(influence, 50);
    t.update_cpu_ms_p50 = percentile(cpu, 50);
    t.update_cpu_ms_p95 = percentile(cpu, 95);
    t.candidates_ms_p50 = percentile(candidates, 50);
    t.refine_ms_p50 = percentile(refine, 50);
    t.solve_ms_p50 = percentile(solve, 50);
    t.links = (*est)->radiosity().links().size();
    t.transfers = (*est)->radiosity().clusterTransfers().size();
    return t;
}

}  // namespace

Result<nlohmann::json> runClusterCase(const BenchLightingOptions& bench) {
    nlohmann::json rows = nlohmann::json::array();
    nlohmann::json gap = nlohmann::json::array();
    auto statue = readScene(bench.source_dir / "data/scenes/statue/scene.yaml");
    if (!statue) return std::unexpected(statue.error());
    if (!bench.cluster_moves_only) {
        std::printf("\n== cluster: real mesh proxies (real spheres, 320 triangles each) in a room, with and without clustering\n");
        std::printf("%-6s %-12s %8s %8s %8s %9s %9s %10s %10s %10s %10s\n", "balls", "method", "leaves", "links", "cluster", "setup_ms",
                    "solve_ms", "room_rms%", "room_max%", "ball_rms%", "ball_max%");
        RadiosityOptions clustered;
        clustered.cluster_min_faces = 24;
        RadiosityOptions plain = clustered;
        plain.cluster_min_faces = 0;
        RadiosityOptions fine = plain;
        fine.link_epsilon = 0.0025;
        fine.source_epsilon = 0.0005;
        auto empty = solveRoom(kRoom, clustered);
        if (!empty) return std::unexpected(empty.error());
        rows.push_back({{"balls", 0}, {"method", "room"}, {"leaves", empty->leaves}, {"links", empty->links}, {"setup_ms", empty->setup_ms},
                        {"solve_ms", empty->solve_ms}});
        std::printf("%-6d %-12s %8d %8d %8d %9.1f %9.2f\n", 0, "room", empty->leaves, empty->links, 0, empty->setup_ms, empty->solve_ms);
        constexpr int kFirstBall = 7;
        for (int balls = 1; balls <= 3; balls += 2) {
            std::string yaml = kRoom;
            for (int b = 0; b < balls; ++b) yaml += kBalls[b];
            auto reference = solveRoom(yaml, fine);
            if (!reference) return std::unexpected(reference.error());
            for (const auto& [name, options] : {std::pair{"clustered", clustered}, std::pair{"unclustered", plain}, std::pair{"fine", fine}}) {
                Result<Run> run = std::string(name) == "fine" ? Result<Run>(*reference) : solveRoom(yaml, options);
                if (!run) return std::unexpected(run.error());
                const auto [room_rms, room_max] = faceError(*run, *reference, false, kFirstBall);
                const auto [ball_rms, ball_max] = faceError(*run, *reference, true, kFirstBall);
                std::printf("%-6d %-12s %8d %8d %8d %9.1f %9.2f %10.3f %10.3f %10.3f %10.3f\n", balls, name, run->leaves, run->links,
                            run->cluster_links, run->setup_ms, run->solve_ms, 100 * room_rms, 100 * room_max, 100 * ball_rms, 100 * ball_max);
                nlohmann::json per_ball = nlohmann::json::array();
                for (int b = 0; b < balls; ++b) {
                    const auto [rms, worst] = faceError(*run, *reference, true, kFirstBall, kFirstBall + b);
                    per_ball.push_back({{"rms_pct", 100 * rms}, {"max_pct", 100 * worst}});
                    if (balls > 1) std::printf("         ball %d: rms %.3f%%, max %.3f%%\n", b, 100 * rms, 100 * worst);
                }
                const double of_peak = ballErrorOfPeak(*run, *reference, kFirstBall);
                std::printf("         balls' largest error over the largest radiance: %.3f%%\n", 100 * of_peak);
                rows.push_back({{"per_ball", per_ball},
                                {"balls", balls},
                                {"faces_added", 320 * balls},
                                {"method", name},
                                {"leaves", run->leaves},
                                {"links", run->links},
                                {"links_added", run->links - empty->links},
                                {"cluster_links", run->cluster_links},
                                {"setup_ms", run->setup_ms},
                                {"solve_ms", run->solve_ms},
                                {"iterations", run->iterations},
                                {"room_rms_pct", 100 * room_rms},
                                {"room_max_pct", 100 * room_max},
                                {"ball_rms_pct", 100 * ball_rms},
                                {"ball_max_pct", 100 * ball_max},
                                {"ball_max_of_peak_pct", 100 * of_peak}});
            }
        }
        std::printf("(errors: face radiances against the unclustered solve with links refined 4x further, `fine`)\n");

        // The influence through cluster links: the ratio with the statue clustered against unclustered,
        // on the statue's faces and on the floor; and unclustered refined further against unclustered.
        std::printf("virtual ball beside a clustered real sphere (statue, r 0.2 m): ratio B/B~ against the unclustered solve's\n");
        std::printf("%-22s %-7s %8s %13s %13s %13s %13s\n", "ball at", "object", "texels", "clustered_rms", "clustered_max", "finer_rms",
                    "finer_max");
        const double epsilon = RadiosityOptions{}.link_epsilon;
        const auto compare = [](const lighting::LightingSnapshot& a, const lighting::LightingSnapshot& b, int object) {
            double sq = 0.0, worst = 0.0;
            long texels = 0;
            for (const auto& fa : a.faces) {
                const lighting::FaceModulation* fb = b.findFace(fa->object_index, fa->face);
                if (fa->object_index != object || !fb || fb->width != fa->width || fb->height != fa->height) continue;
                for (std::size_t k = 0; k < fa->ratio.size(); ++k) {
                    const double d = std::abs(static_cast<double>(fa->ratio[k].y() - fb->ratio[k].y()));
                    sq += d * d;
                    worst = std::max(worst, d);
                    ++texels;
                }
            }
            return std::tuple{texels, texels > 0 ? std::sqrt(sq / static_cast<double>(texels)) : 0.0, worst};
        };
        for (const Eigen::Vector3d& at : {Eigen::Vector3d(0.0, 0.0, 0.1), Eigen::Vector3d(0.2, 0.05, 0.15), Eigen::Vector3d(-0.25, 0.3, 0.1)}) {
            auto clustered_run = influenceSnapshot(*statue, 24, epsilon, at);
            if (!clustered_run) return std::unexpected(clustered_run.error());
            auto unclustered = influenceSnapshot(*statue, 0, epsilon, at);
            if (!unclustered) return std::unexpected(unclustered.error());
            auto finer = influenceSnapshot(*statue, 0, 0.5 * epsilon, at);
            if (!finer) return std::unexpected(finer.error());
            for (const auto& [object, name] : {std::pair{0, "floor"}, std::pair{2, "statue"}}) {
                const auto [texels, rms, worst] = compare(*clustered_run, *unclustered, object);
                const auto [finer_texels, finer_rms, finer_worst] = compare(*finer, *unclustered, object);
                std::printf("(%5.2f, %5.2f, %5.2f)    %-7s %8ld %13.4f %13.4f %13.4f %13.4f\n", at.x(), at.y(), at.z(), name, texels, rms, worst,
                            finer_rms, finer_worst);
                gap.push_back({{"ball", {at.x(), at.y(), at.z()}},
                               {"object", name},
                               {"texels", texels},
                               {"ratio_rms", rms},
                               {"ratio_max", worst},
                               {"finer_texels", finer_texels},
                               {"finer_ratio_rms", finer_rms},
                               {"finer_ratio_max", finer_worst}});
            }
        }
    }
    std::printf("the ball moving towards the statue and back, 40 moves of 5 mm each way, %d times: per move, p50 (CPU: all threads; "
                "the influence's phases: wall)\n",
                bench.cluster_repeats);
    std::printf("%-12s %10s %13s %14s %14s %14s %10s %10s %12s %10s\n", "method", "update_ms", "influence_ms", "update_cpu_ms", "cpu_ms_p95",
                "candidates_ms", "refine_ms", "solve_ms", "links", "transfers");
    nlohmann::json moves = nlohmann::json::array();
    for (const auto& [faces, name] : {std::pair{24, "clustered"}, std::pair{0, "unclustered"}}) {
        if (!bench.cluster_method.empty() && bench.cluster_method != name) continue;
        auto t = influenceTiming(*statue, faces, bench.cluster_repeats);
        if (!t) return std::unexpected(t.error());
        std::printf("%-12s %10.2f %13.2f %14.2f %14.2f %14.2f %10.2f %10.2f %12zu %10zu\n", name, t->update_ms_p50, t->influence_ms_p50,
                    t->update_cpu_ms_p50, t->update_cpu_ms_p95, t->candidates_ms_p50, t->refine_ms_p50, t->solve_ms_p50, t->links,
                    t->transfers);
        moves.push_back({{"method", name},
                         {"moves", t->moves},
                         {"update_ms_p50", t->update_ms_p50},
                         {"influence_ms_p50", t->influence_ms_p50},
                         {"update_cpu_ms_p50", t->update_cpu_ms_p50},
                         {"update_cpu_ms_p95", t->update_cpu_ms_p95},
                         {"candidates_ms_p50", t->candidates_ms_p50},
                         {"refine_ms_p50", t->refine_ms_p50},
                         {"solve_ms_p50", t->solve_ms_p50},
                         {"links", t->links},
                         {"cluster_transfers", t->transfers}});
    }
    return nlohmann::json{{"rows", rows}, {"influence_through_clusters", gap}, {"moves", moves}};
}

}  // namespace commonlight::apps

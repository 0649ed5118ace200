// The simulated camera's speed against its error, on the desk scene (data/scenes/desk):
//
//   BM_RenderDesk/<spp>: a whole 640x480 frame (frame 0 of the desk trajectory, real scene) on all
//     cores; counters: samples per second per core, seconds per frame.
//   BM_WallNoise/<spp>: a 48x48 patch of the flat back wall on one core; counters: the Monte
//     Carlo noise as the relative standard deviation of a pixel (from two renders with different
//     seeds: std(a - b) / sqrt(2) / mean, so neither the lighting gradient nor a reference
//     image enters it), and samples per second per core. Noise should fall as 1/sqrt(spp).
//   BM_SensorExpose: the EMVA 1288 sensor on a 640x480 RGB radiance image (noise, fixed pattern,
//     quantisation) plus the 8-bit response, with the default parameters; time per frame.
//
// Run from the repository root or set COMMONLIGHT_SOURCE_DIR.
#include <benchmark/benchmark.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <thread>

#include <tbb/global_control.h>

#include "core/scene_io.h"
#include "mocks/sim/embree_scene.h"
#include "mocks/sim/render.h"
#include "mocks/sim/sensor.h"
#include "mocks/sim/trajectory.h"

namespace commonlight::bench {
namespace {

namespace fs = std::filesystem;
using mocks::sim::RenderRequest;

struct Desk {
    Scene scene;
    std::optional<mocks::sim::SimScene> sim;
    Rigid3d world_from_cam;
    std::string error;
};

const Desk& desk() {
    static Desk d = [] {
        Desk out;
        const char* source = std::getenv("COMMONLIGHT_SOURCE_DIR");
        const fs::path root = source ? fs::path(source) : fs::current_path();
        auto scene = readScene(root / "data/scenes/desk/scene.yaml");
        auto trajectory = mocks::sim::Trajectory::read(root / "data/scenes/desk/trajectory.yaml");
        if (!scene || !trajectory) {
            out.error = "cannot read data/scenes/desk (run from the repository root)";
            return out;
        }
        out.scene = *scene;
        auto sim = mocks::sim::SimScene::build(out.scene, {});
        if (!sim) {
            out.error = sim.error().message;
            return out;
        }
        out.sim.emplace(std::move(*sim));
        out.world_from_cam = trajectory->worldFromCam(0.0);
        return out;
    }();
    return d;
}

RenderRequest request(int spp, std::uint64_t seed) {
    RenderRequest r;
    r.scene = &*desk().sim;
    r.camera = *desk().scene.camera;
    r.world_from_cam = desk().world_from_cam;
    r.spp = spp;
    r.seed = seed;
    r.max_depth = 8;
    return r;
}

void BM_RenderDesk(benchmark::State& state) {
    if (!desk().error.empty()) return state.SkipWithError(desk().error.c_str());
    const int spp = static_cast<int>(state.range(0));
    std::int64_t samples = 0;
    double seconds = 0.0;
    for (auto _ : state) {
        auto out = mocks::sim::render(request(spp, 1));
        if (!out) return state.SkipWithError(out.error().message.c_str());
        samples += out->samples;
        seconds += out->seconds;
    }
    const double cores = std::max(1u, std::thread::hardware_concurrency());
    state.counters["samples_per_s_per_core"] = static_cast<double>(samples) / seconds / cores;
    state.counters["s_per_frame"] = seconds / static_cast<double>(state.iterations());
}
BENCHMARK(BM_RenderDesk)->Arg(1)->Arg(4)->Arg(16)->Unit(benchmark::kSecond)->UseRealTime()->Iterations(1);

// A patch of the back wall in frame 0 (checked: every pixel's primary hit is the wall).
constexpr mocks::sim::PixelRect kWall{120, 30, 48, 48};

void BM_WallNoise(benchmark::State& state) {
    if (!desk().error.empty()) return state.SkipWithError(desk().error.c_str());
    tbb::global_control one_core(tbb::global_control::max_allowed_parallelism, 1);
    const int spp = static_cast<int>(state.range(0));
    double rel_std = 0.0;
    std::int64_t samples = 0;
    double seconds = 0.0;
    for (auto _ : state) {
        RenderRequest a = request(spp, 1);
        RenderRequest b = request(spp, 2);
        a.region = b.region = kWall;
        auto ra = mocks::sim::render(a);
        auto rb = mocks::sim::render(b);
        if (!ra || !rb) return state.SkipWithError("render failed");
        const int wall_id = ra->object_id[kWall.y * ra->width + kWall.x];
        double sum = 0.0, sum_diff2 = 0.0;
        int n = 0;
        for (int y = kWall.y; y < kWall.y + kWall.height; ++y) {
            for (int x = kWall.x; x < kWall.x + kWall.width; ++x) {
                const std::size_t i = static_cast<std::size_t>(y * ra->width + x);
                if (ra->object_id[i] != wall_id) return state.SkipWithError("the patch is not all wall");
                const auto* pa = reinterpret_cast<const float*>(ra->radiance.data()) + 3 * i;
                const auto* pb = reinterpret_cast<const float*>(rb->radiance.data()) + 3 * i;
                const double ya = 0.2126 * pa[0] + 0.7152 * pa[1] + 0.0722 * pa[2];
                const double yb = 0.2126 * pb[0] + 0.7152 * pb[1] + 0.0722 * pb[2];
                sum += ya + yb;
                sum_diff2 += (ya - yb) * (ya - yb);
                ++n;
            }
        }
        const double mean = sum / (2.0 * n);
        rel_std = std::sqrt(sum_diff2 / n / 2.0) / mean;
        samples += ra->samples + rb->samples;
        seconds += ra->seconds + rb->seconds;
    }
    state.counters["rel_std"] = rel_std;
    state.counters["samples_per_s_per_core"] = static_cast<double>(samples) / seconds;
}
BENCHMARK(BM_WallNoise)->RangeMultiplier(4)->Range(4, 1024)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(1);

void BM_SensorExpose(benchmark::State& state) {
    constexpr int kWidth = 640, kHeight = 480;
    const mocks::sim::SensorParams params;
    auto sensor = mocks::sim::SensorModel::create(params, kWidth, kHeight);
    if (!sensor) return state.SkipWithError(sensor.error().message.c_str());
    Image radiance(PixelFormat::kRgbF32, kWidth, kHeight);
    for (int y = 0; y < kHeight; ++y) {
        auto* row = reinterpret_cast<float*>(radiance.mutableView().row(y));
        for (int x = 0; x < kWidth; ++x) {  // a gradient, so both dark and bright pixels are exposed
            const float v = 0.2f + 4.0f * static_cast<float>(x) / kWidth;
            row[3 * x] = v;
            row[3 * x + 1] = 0.8f * v;
            row[3 * x + 2] = 0.5f * v;
        }
    }
    mocks::sim::RawFrame raw;
    Image pixels;
    std::uint64_t frame = 0;
    for (auto _ : state) {
        auto ok = sensor->expose(radiance.view(), ++frame, raw);
        if (!ok) return state.SkipWithError(ok.error().message.c_str());
        sensor->encode8(raw, pixels);
        benchmark::DoNotOptimize(pixels.data());
    }
}
BENCHMARK(BM_SensorExpose)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
}  // namespace commonlight::bench

BENCHMARK_MAIN();

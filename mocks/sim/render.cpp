#include "mocks/sim/render.h"

#include <tbb/blocked_range.h>
#include <tbb/combinable.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <sstream>

namespace commonlight::mocks::sim {

namespace {

constexpr int kTileSize = 16;

}  // namespace

Result<void> RenderRequest::validate() const {
    std::ostringstream msg;
    if (scene == nullptr) return fail(ErrorCode::kUsage, "render: no scene");
    if (auto valid = camera.validate(); !valid) return fail(std::move(valid).error().prepend("render: camera"));
    if (spp < 1) {
        msg << "render: spp must be >= 1, got " << spp;
    } else if (max_depth < 0) {
        msg << "render: max_depth must be >= 0, got " << max_depth;
    } else if (!(std::isfinite(exposure_s) && exposure_s >= 0.0)) {
        msg << "render: exposure_s must be finite and >= 0, got " << exposure_s;
    } else if (!(std::isfinite(rolling_shutter_row_time_s) && rolling_shutter_row_time_s >= 0.0)) {
        msg << "render: rolling_shutter_row_time_s must be finite and >= 0, got " << rolling_shutter_row_time_s;
    } else if (!world_from_cam_at && !world_from_cam.isValid()) {
        msg << "render: world_from_cam is not a valid pose";
    } else if (region && (region->x < 0 || region->y < 0 || region->width < 0 || region->height < 0 ||
                          region->x + region->width > camera.width || region->y + region->height > camera.height)) {
        msg << "render: region " << region->x << "," << region->y << " " << region->width << "x" << region->height
            << " is not inside the " << camera.width << "x" << camera.height << " image";
    } else {
        return {};
    }
    return fail(ErrorCode::kUsage, msg.str());
}

Result<RenderOutput> render(const RenderRequest& request) {
    CL_TRY_VOID(request.validate());
    const auto start = std::chrono::steady_clock::now();
    const CameraModel& camera = request.camera;
    const int width = camera.width;
    const int height = camera.height;
    const PixelRect rect = request.region.value_or(PixelRect{0, 0, width, height});

    RenderOutput out;
    out.width = width;
    out.height = height;
    out.radiance = Image(PixelFormat::kRgbF32, width, height);
    std::fill_n(out.radiance.data(), out.radiance.sizeBytes(), std::uint8_t{0});
    out.object_id.assign(static_cast<std::size_t>(width) * height, -1);
    out.virtual_coverage.assign(static_cast<std::size_t>(width) * height, 0.0f);

    // Step 1: camera rays (row poses are evaluated here, on this thread) and the integrator.
    const CameraRays rays(camera, request.world_from_cam, request.world_from_cam_at, request.exposure_s,
                          request.rolling_shutter_row_time_s);
    IntegratorOptions options;
    options.max_depth = request.max_depth;
    const PathTracer tracer(*request.scene, options);

    // Step 2: tiles in parallel. Each pixel is written by exactly one task.
    const int tiles_x = (rect.width + kTileSize - 1) / kTileSize;
    const int tiles_y = (rect.height + kTileSize - 1) / kTileSize;
    tbb::combinable<std::int64_t> nonfinite([] { return std::int64_t{0}; });
    const int spp = request.spp;
    tbb::parallel_for(tbb::blocked_range<int>(0, tiles_x * tiles_y), [&](const tbb::blocked_range<int>& range) {
        std::int64_t& dropped = nonfinite.local();
        for (int tile = range.begin(); tile != range.end(); ++tile) {
            const int x0 = rect.x + (tile % tiles_x) * kTileSize;
            const int y0 = rect.y + (tile / tiles_x) * kTileSize;
            const int x1 = std::min(x0 + kTileSize, rect.x + rect.width);
            const int y1 = std::min(y0 + kTileSize, rect.y + rect.height);
            for (int v = y0; v < y1; ++v) {
                auto* row =
                    reinterpret_cast<float*>(out.radiance.data() + static_cast<std::size_t>(v) * out.radiance.stride());
                for (int u = x0; u < x1; ++u) {
                    const std::size_t index = static_cast<std::size_t>(v) * width + u;
                    const PixelSampler sampler(PixelSampler::pixelSeed(request.seed, request.frame_index, index), spp);
                    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
                    int virtual_hits = 0;
                    for (int i = 0; i < spp; ++i) {
                        const Eigen::Vector2d jitter = sampler.get2D(i, kDimensionPixel);
                        const Eigen::Vector2d pixel(u - 0.5 + jitter.x(), v - 0.5 + jitter.y());
                        const double t = rays.sampleTime(v, sampler.get1D(i, kDimensionTime));
                        const std::optional<Ray> ray = rays.ray(pixel, v, t);
                        if (!ray) continue;  // beyond the lens model: this sample sees nothing
                        PrimaryHit primary;
                        const Eigen::Vector3d value = tracer.radiance(*ray, sampler, i, &primary);
                        // Guard: a non-finite sample (never expected: every division by a pdf is
                        // guarded) must not poison the pixel; it counts as black and is reported.
                        if (value.allFinite()) {
                            sum += value;
                        } else {
                            ++dropped;
                        }
                        if (primary.is_virtual) ++virtual_hits;
                    }
                    const Eigen::Vector3d mean = sum / spp;
                    // Hard case: a finite double beyond float's range would become infinity.
                    constexpr double kMaxFloat = std::numeric_limits<float>::max();
                    for (int c = 0; c < 3; ++c) row[3 * u + c] = static_cast<float>(std::min(mean[c], kMaxFloat));
                    out.virtual_coverage[index] = static_cast<float>(virtual_hits) / static_cast<float>(spp);
                    if (const std::optional<Ray> centre = rays.centreRay(u, v)) {
                        if (const auto hit = request.scene->intersect(centre->origin, centre->dir)) {
                            out.object_id[index] = hit->object;
                        }
                    }
                }
            }
        }
    });

    out.samples = static_cast<std::int64_t>(rect.width) * rect.height * spp;
    out.nonfinite_samples = nonfinite.combine(std::plus<>());
    out.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    return out;
}

}  // namespace commonlight::mocks::sim

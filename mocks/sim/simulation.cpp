#include "mocks/sim/simulation.h"

#include <cmath>
#include <cstring>
#include <variant>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/file_util.h"
#include "core/scene_io.h"
#include "core/sequence_io.h"
#include "core/sequence_writer.h"
#include "mocks/sim/embree_scene.h"
#include "mocks/sim/render.h"
#include "mocks/sim/sensor.h"

namespace commonlight::mocks::sim {

namespace fs = std::filesystem;

Result<void> SimulationOptions::validate() const {
    auto usage = [](const std::string& msg) { return fail(ErrorCode::kUsage, msg); };
    if (out.empty()) return usage("--out: give the sequence folder to create");
    if (frames < 0) return usage("--frames must not be negative");
    if (spp < 1) return usage("--spp must be at least 1");
    if (max_depth < 1) return usage("--max-depth must be at least 1");
    if (jpeg_quality < 1 || jpeg_quality > 100) return usage("--jpeg-quality must be in 1..100");
    if (!(rolling_shutter_row_time_s >= 0.0) || !std::isfinite(rolling_shutter_row_time_s)) {
        return usage("--rolling-shutter must be a non-negative row time");
    }
    if (!(changed_threshold > 0.0)) return usage("the changed-region threshold must be positive");
    if (!(defocus_radius_px >= 0.0 && defocus_radius_px <= 20.0)) return usage("the defocus radius must be in [0, 20] px");
    if (!(std::abs(tag_ink_spread_cells) <= 0.25)) return usage("the tag ink spread must be in [-0.25, 0.25] cells");
    CL_TRY_VOID(sensor.validate());
    if (camera) CL_TRY_VOID(camera->validate());
    return {};
}

Scene estimatorScene(const Scene& truth) {
    Scene scene = truth;
    for (auto& object : scene.real_objects) object.albedo = RgbOrEstimate::estimate();
    for (auto& light : scene.lights) light.emission = RgbOrEstimate::estimate();
    scene.camera_path.reset();  // the sequence's sensor.yaml holds the intrinsics
    scene.camera.reset();
    return scene;
}

namespace {

// Frame i's seed for the sensor's temporal noise, mixed from the run's seed (SplitMix64).
std::uint64_t frameSeed(std::uint64_t seed, std::uint64_t frame) {
    std::uint64_t z = seed * 0x9E3779B97F4A7C15ull + frame + 0x632BE59BD9B4E019ull;
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

Result<void> writeMat(const fs::path& file, const cv::Mat& mat, const std::vector<int>& params = {}) {
    std::vector<std::uint8_t> bytes;
    try {
        if (!cv::imencode(file.extension().string(), mat, bytes, params)) {
            return fail(ErrorCode::kInternal, file.string() + ": encoding failed");
        }
    } catch (const cv::Exception& e) {
        return fail(ErrorCode::kInternal, file.string() + ": encoding failed: " + e.what());
    }
    return writeFileAtomic(file, bytes, /*sync=*/false);
}

// The defocus kernel: a uniform disc of `radius` pixels, its pixel weights the disc's area in
// each pixel (16 x 16 sub-samples per pixel), normalised to sum 1.
cv::Mat discKernel(double radius) {
    const int half = static_cast<int>(std::ceil(radius));
    cv::Mat k(2 * half + 1, 2 * half + 1, CV_32F, cv::Scalar(0));
    constexpr int kSub = 16;
    for (int y = -half; y <= half; ++y) {
        for (int x = -half; x <= half; ++x) {
            int inside = 0;
            for (int sy = 0; sy < kSub; ++sy) {
                for (int sx = 0; sx < kSub; ++sx) {
                    const double px = x - 0.5 + (sx + 0.5) / kSub, py = y - 0.5 + (sy + 0.5) / kSub;
                    if (px * px + py * py <= radius * radius) ++inside;
                }
            }
            k.at<float>(y + half, x + half) = static_cast<float>(inside);
        }
    }
    return k / cv::sum(k)[0];
}

// Convolves the linear radiance with the defocus disc (borders replicated).
void defocus(Image& radiance, double radius) {
    cv::Mat rgb(radiance.height(), radiance.width(), CV_32FC3, radiance.data(), radiance.stride());
    cv::filter2D(rgb, rgb, -1, discKernel(radius), cv::Point(-1, -1), 0.0, cv::BORDER_REPLICATE);
}

cv::Mat radianceMat(const Image& radiance) {
    const cv::Mat rgb(radiance.height(), radiance.width(), CV_32FC3, const_cast<std::uint8_t*>(radiance.data()),
                      radiance.stride());
    cv::Mat bgr;
    cv::cvtColor(rgb, bgr, cv::COLOR_RGB2BGR);
    return bgr;
}

// Luminance (Rec. 709 weights) of a radiance image.
cv::Mat luminance(const Image& radiance) {
    cv::Mat y(radiance.height(), radiance.width(), CV_32F);
    const auto* px = reinterpret_cast<const float*>(radiance.data());
    for (int i = 0; i < radiance.width() * radiance.height(); ++i) {
        y.at<float>(i) = 0.2126f * px[3 * i] + 0.7152f * px[3 * i + 1] + 0.0722f * px[3 * i + 2];
    }
    return y;
}

// masks/changed: where the virtual objects change the radiance of real surfaces by more than
// `threshold`. Both renders share their sample seeds, so pixels whose paths never meet a virtual
// object are identical; where paths do, the Monte Carlo noise of the difference is large per
// pixel, so the relative change is measured on 9x9 box-filtered luminance (shadows and
// reflections are spatially coherent, noise is not). The filter averages real-surface pixels
// only (a normalised, masked blur), so a virtual object's own radiance never leaks into its
// neighbours; pixels a virtual object covers are left out: they belong to masks/virtual.
cv::Mat changedMask(const Image& real, const Image& composite, const std::vector<float>& coverage, double threshold) {
    const int w = real.width();
    const int h = real.height();
    cv::Mat weight(h, w, CV_32F);
    for (int i = 0; i < w * h; ++i) weight.at<float>(i) = coverage[static_cast<std::size_t>(i)] > 0.0f ? 0.0f : 1.0f;
    const cv::Size window(9, 9);
    cv::Mat weight_sum;
    cv::blur(weight, weight_sum, window);
    auto maskedBlur = [&](const Image& radiance) {
        cv::Mat y = luminance(radiance).mul(weight);
        cv::blur(y, y, window);
        return y;
    };
    const cv::Mat y_real = maskedBlur(real);
    const cv::Mat y_comp = maskedBlur(composite);
    cv::Mat mask(h, w, CV_8U, cv::Scalar(0));
    for (int i = 0; i < w * h; ++i) {
        if (weight.at<float>(i) == 0.0f) continue;
        // Both sums share the same weights, so their ratio is the ratio of the masked means.
        const float base = y_real.at<float>(i);
        const float diff = std::abs(y_comp.at<float>(i) - base);
        // Hard case: black real surfaces (base 0) change "infinitely" when lit at all; compare
        // against a floor of 1e-6 W/(m^2 sr), far below any visible radiance.
        if (diff > threshold * std::max(base, 1e-6f * weight_sum.at<float>(i))) mask.at<std::uint8_t>(i) = 255;
    }
    return mask;
}

cv::Mat coverageMask(const std::vector<float>& coverage, int width, int height) {
    cv::Mat mask(height, width, CV_8U);
    for (int i = 0; i < width * height; ++i) {
        mask.at<std::uint8_t>(i) = static_cast<std::uint8_t>(std::lround(255.0f * coverage[static_cast<std::size_t>(i)]));
    }
    return mask;
}

bool virtualObjectsMove(const Scene& scene) {
    for (const auto& object : scene.virtual_objects) {
        if (std::holds_alternative<KeyframePlacement>(object.placement)) return true;
    }
    return false;
}

// One 8-bit camera image as stored in the sequence: RGB8 (PNG) or the JPEG bytes (MJPEG).
Result<void> toFrameImage(const Image& rgb, const SimulationOptions& options, Image& frame) {
    if (options.frame_format == FrameFileFormat::kPng) {
        frame.assign(rgb);
        return {};
    }
    const cv::Mat view(rgb.height(), rgb.width(), CV_8UC3, const_cast<std::uint8_t*>(rgb.data()), rgb.stride());
    cv::Mat bgr;
    cv::cvtColor(view, bgr, cv::COLOR_RGB2BGR);
    std::vector<std::uint8_t> jpeg;
    if (!cv::imencode(".jpg", bgr, jpeg, {cv::IMWRITE_JPEG_QUALITY, options.jpeg_quality})) {
        return fail(ErrorCode::kInternal, "JPEG encoding failed");
    }
    frame.reshapeCompressed(rgb.width(), rgb.height(), jpeg.size());
    std::memcpy(frame.data(), jpeg.data(), jpeg.size());
    return {};
}

cv::Mat bgrOf(const Image& rgb) {
    const cv::Mat view(rgb.height(), rgb.width(), CV_8UC3, const_cast<std::uint8_t*>(rgb.data()), rgb.stride());
    cv::Mat bgr;
    cv::cvtColor(view, bgr, cv::COLOR_RGB2BGR);
    return bgr;
}

Result<void> createFolders(const fs::path& root, const SimulationOptions& options) {
    std::vector<fs::path> folders = {root / "groundtruth"};
    if (options.write_composite) folders.push_back(root / "groundtruth" / "composite");
    if (options.write_masks) {
        folders.push_back(root / "groundtruth" / "masks" / "virtual");
        folders.push_back(root / "groundtruth" / "masks" / "changed");
    }
    if (options.write_radiance) {
        folders.push_back(root / "groundtruth" / "radiance");
        if (options.write_composite) folders.push_back(root / "groundtruth" / "radiance_composite");
    }
    for (const auto& folder : folders) {
        std::error_code ec;
        fs::create_directories(folder, ec);
        if (ec) return fail(fileError(folder, "cannot create folder", ec.value()));
    }
    return {};
}

Result<void> writeSceneFiles(const Scene& scene, const SimulationOptions& options) {
    const fs::path gt = options.out / "groundtruth";
    CL_TRY_VOID(writeScene(options.out / "scene.yaml", estimatorScene(scene)));
    Scene truth = scene;
    truth.camera_path.reset();
    truth.camera.reset();
    CL_TRY_VOID(writeScene(gt / "scene.yaml", truth));
    Scene lights_only;
    lights_only.lights = scene.lights;
    CL_TRY_VOID(writeScene(gt / "lights.yaml", lights_only));
    return writeTextFileAtomic(gt / "sensor.yaml", "# the simulated sensor (docs/sim-sensor.md)\nsensor: " +
                                                        formatSensorParams(options.sensor) + "\n");
}

}  // namespace

Result<SimulationSummary> simulate(const Scene& scene, const Trajectory& trajectory, const SimulationOptions& options,
                                   const SimulationProgress& progress, std::stop_token stop) {
    // Step 1: what to render with.
    CL_TRY_VOID(options.validate());
    std::optional<CameraModel> camera = options.camera ? options.camera : scene.camera;
    if (!camera) return fail(ErrorCode::kUsage, "the scene has no camera: give one in the scene or with --calib");
    CL_TRY(const SensorModel sensor, SensorModel::create(options.sensor, camera->width, camera->height));
    CL_TRY(const SimScene real_scene,
           SimScene::build(scene, {.include_virtual = false, .time_s = 0.0,
                                   .tag_ink_spread_cells = options.tag_ink_spread_cells}));
    const bool moving = virtualObjectsMove(scene);
    std::optional<SimScene> composite_scene;
    if (options.write_composite && !moving) {
        CL_TRY(composite_scene, SimScene::build(scene, {.include_virtual = true, .time_s = 0.0,
                                                        .tag_ink_spread_cells = options.tag_ink_spread_cells}));
    }

    // Step 2: the sequence and the files that do not change per frame.
    SensorInfo sensor_info;
    sensor_info.rate_hz = trajectory.rateHz();
    sensor_info.camera = camera;
    sensor_info.response = sensorResponseSpec(options.sensor);
    // The camera's radiometric calibration: relative radiance (linear value of full scale per
    // second per unit gain) per W/(m^2 sr), from the sensor's own parameters (dark current aside).
    sensor_info.radiance_scale = options.sensor.electrons_per_radiance_second * options.sensor.systemGainDnPerE() /
                                 (options.sensor.maxDn() - options.sensor.blackLevelDn());
    sensor_info.comment = "simulated by commonlight sim (mocks/sim): " + std::to_string(options.spp) + " spp, seed " +
                          std::to_string(options.seed);
    CL_TRY(SequenceWriter writer, SequenceWriter::create(options.out, sensor_info, {.sync = false}));
    CL_TRY_VOID(createFolders(options.out, options));
    CL_TRY_VOID(writeSceneFiles(scene, options));
    CL_TRY(LineAppender poses, LineAppender::open(options.out / "groundtruth" / "cam_poses.csv", kPosesCsvHeader));
    CL_TRY(LineAppender mid_poses,
           LineAppender::open(options.out / "groundtruth" / kMidExposurePosesFile, kPosesCsvHeader));

    // Step 3: the frames.
    const int total = options.frames > 0 ? options.frames : trajectory.frameCount();
    const fs::path gt = options.out / "groundtruth";
    const char* frame_ext = options.frame_format == FrameFileFormat::kJpeg ? ".jpg" : ".png";
    const std::vector<int> image_params = options.frame_format == FrameFileFormat::kJpeg
                                              ? std::vector<int>{cv::IMWRITE_JPEG_QUALITY, options.jpeg_quality}
                                              : std::vector<int>{cv::IMWRITE_PNG_COMPRESSION, 3};
    const std::vector<int> exr_params = {cv::IMWRITE_EXR_TYPE, cv::IMWRITE_EXR_TYPE_FLOAT};
    SimulationSummary summary;
    RawFrame raw;
    Image rgb;
    Image composite_rgb;
    Image frame_image;
    for (int i = 0; i < total; ++i) {
        if (stop.stop_requested()) {
            summary.stopped = true;
            break;
        }
        const double t = trajectory.startTime() + i / trajectory.rateHz();
        const std::int64_t timestamp_ns = std::llround(t * 1e9);
        const std::string stem = std::to_string(timestamp_ns);

        // The timestamp is the start of the exposure; the image is the light gathered over it
        // (docs/tracking.md, "Timestamps"). With motion blur, each sample's time is spread over
        // the exposure; without, the whole frame is rendered at the middle of the exposure, the
        // instant a blurred image stands for (so both give the same ground truth,
        // cam_poses_mid_exposure.csv).
        const std::int64_t mid_ns = midExposureNs(timestamp_ns, options.sensor.exposure_us);
        const double t_mid = t + 0.5e-6 * options.sensor.exposure_us;
        const double t_render = options.motion_blur ? t : t_mid;
        RenderRequest request;
        request.scene = &real_scene;
        request.camera = *camera;
        request.world_from_cam = trajectory.worldFromCam(t_render);
        if (options.motion_blur || options.rolling_shutter_row_time_s > 0) {
            request.world_from_cam_at = [&trajectory, t_render](double dt) { return trajectory.worldFromCam(t_render + dt); };
        }
        request.spp = options.spp;
        request.seed = options.seed;
        request.frame_index = static_cast<std::uint64_t>(i);
        request.max_depth = options.max_depth;
        request.exposure_s = options.motion_blur ? options.sensor.exposureS() : 0.0;
        request.rolling_shutter_row_time_s = options.rolling_shutter_row_time_s;
        CL_TRY(RenderOutput real, render(request));
        if (options.defocus_radius_px > 0.0) defocus(real.radiance, options.defocus_radius_px);
        summary.render_seconds += real.seconds;
        summary.samples += real.samples;
        summary.nonfinite_samples += real.nonfinite_samples;

        const std::uint64_t noise_seed = frameSeed(options.seed, static_cast<std::uint64_t>(i));
        CL_TRY_VOID(sensor.expose(real.radiance, noise_seed, raw));
        sensor.encode8(raw, rgb);

        // Ground truth first: the data.csv row comes last.
        if (options.write_composite) {
            std::optional<SimScene> moving_scene;
            if (moving) {
                CL_TRY(moving_scene, SimScene::build(scene, {.include_virtual = true, .time_s = t,
                                                             .tag_ink_spread_cells = options.tag_ink_spread_cells}));
            }
            request.scene = moving ? &*moving_scene : &*composite_scene;
            CL_TRY(RenderOutput composite, render(request));
            if (options.defocus_radius_px > 0.0) defocus(composite.radiance, options.defocus_radius_px);
            summary.render_seconds += composite.seconds;
            summary.samples += composite.samples;
            summary.nonfinite_samples += composite.nonfinite_samples;
            CL_TRY_VOID(sensor.expose(composite.radiance, noise_seed, raw));  // same noise seed
            sensor.encode8(raw, composite_rgb);
            CL_TRY_VOID(writeMat(gt / "composite" / (stem + frame_ext), bgrOf(composite_rgb), image_params));
            if (options.write_masks) {
                CL_TRY_VOID(writeMat(gt / "masks" / "virtual" / (stem + ".png"),
                                     coverageMask(composite.virtual_coverage, composite.width, composite.height)));
                CL_TRY_VOID(writeMat(gt / "masks" / "changed" / (stem + ".png"),
                                     changedMask(real.radiance, composite.radiance, composite.virtual_coverage,
                                                 options.changed_threshold)));
            }
            if (options.write_radiance) {
                CL_TRY_VOID(writeMat(gt / "radiance_composite" / (stem + ".exr"), radianceMat(composite.radiance),
                                     exr_params));
            }
        }
        if (options.write_radiance) {
            CL_TRY_VOID(writeMat(gt / "radiance" / (stem + ".exr"), radianceMat(real.radiance), exr_params));
        }
        CL_TRY_VOID(toFrameImage(rgb, options, frame_image));
        FrameMetadata meta;
        meta.timestamp_ns = timestamp_ns;
        meta.timestamp_source = TimestampSource::kSimulated;
        meta.sequence = static_cast<std::uint64_t>(i);
        meta.exposure_us = options.sensor.exposure_us;
        meta.analog_gain = options.sensor.analog_gain;
        CL_TRY_VOID(writer.write(frame_image, meta));
        CL_TRY_VOID(poses.append(poseCsvRow({timestamp_ns, trajectory.worldFromCam(t)})));
        CL_TRY_VOID(mid_poses.append(poseCsvRow({mid_ns, trajectory.worldFromCam(t_mid)})));
        ++summary.frames_written;
        if (progress) progress(i + 1, total);
    }
    return summary;
}

}  // namespace commonlight::mocks::sim

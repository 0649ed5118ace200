// commonlight sim --scene S --trajectory T --out SEQ [--frames N] [--spp N] [--seed N]:
// renders a simulated sequence with its ground truth (docs/sim.md).
#include <cstdio>
#include <memory>

#include "apps/app.h"
#include "apps/quiet.h"
#include "apps/progress.h"
#include "core/calibration_io.h"
#include "core/file_util.h"
#include "core/log.h"
#include "core/scene_io.h"
#include "core/yaml_util.h"
#include "mocks/sim/simulation.h"

namespace commonlight::apps {

namespace {

struct SimCommandOptions {
    std::string scene;
    std::string trajectory;
    std::string calib;
    std::string format = "png";
    std::string sensor_file;
    std::vector<std::string> sensor_settings;  // KEY=VALUE
    std::optional<double> exposure_us;
    std::optional<double> gain;
    bool no_composite = false;
    bool no_masks = false;
    bool no_radiance = false;
    mocks::sim::SimulationOptions sim;
};

// Sensor parameters, later sources overriding earlier ones: the scene file's `sensor:` map, the
// --sensor-file, the --sensor KEY=VALUE settings, --exposure-us and --gain.
Result<mocks::sim::SensorParams> sensorParams(const SimCommandOptions& options) {
    mocks::sim::SensorParams params;
    {
        CL_TRY(const YAML::Node scene_root, yaml::loadFile(options.scene));
        if (yaml::has(scene_root, "sensor")) {
            CL_TRY(params, mocks::sim::parseSensorParams(options.scene, scene_root["sensor"]));
        }
    }
    if (!options.sensor_file.empty()) {
        CL_TRY(const YAML::Node root, yaml::loadFile(options.sensor_file));
        CL_TRY_VOID(yaml::checkKeys(options.sensor_file, root, "", {"sensor"}));
        CL_TRY(params, mocks::sim::parseSensorParams(options.sensor_file, root["sensor"]));
    }
    for (const auto& setting : options.sensor_settings) {
        const auto eq = setting.find('=');
        if (eq == std::string::npos) {
            return fail(ErrorCode::kUsage, "--sensor '" + setting + "': expected KEY=VALUE (e.g. bits=12)");
        }
        CL_TRY_VOID(mocks::sim::setSensorParam(params, setting.substr(0, eq), setting.substr(eq + 1)));
    }
    if (options.exposure_us) params.exposure_us = *options.exposure_us;
    if (options.gain) params.analog_gain = *options.gain;
    CL_TRY_VOID(params.validate());
    return params;
}

int runSim(SimCommandOptions options) {
    // Step 1: inputs.
    auto scene = readScene(options.scene);
    if (!scene) return reportError(scene.error());
    auto trajectory = mocks::sim::Trajectory::read(options.trajectory);
    if (!trajectory) return reportError(trajectory.error());
    auto sensor = sensorParams(options);
    if (!sensor) return reportError(sensor.error());
    options.sim.sensor = *sensor;
    if (!options.calib.empty()) {
        auto calib = readCalibration(options.calib);
        if (!calib) return reportError(calib.error());
        options.sim.camera = *calib;
    }
    options.sim.frame_format = options.format == "jpeg" ? mocks::sim::FrameFileFormat::kJpeg
                                                        : mocks::sim::FrameFileFormat::kPng;
    options.sim.write_composite = !options.no_composite;
    options.sim.write_masks = !options.no_masks;
    options.sim.write_radiance = !options.no_radiance;
    const int total = options.sim.frames > 0 ? options.sim.frames : trajectory->frameCount();
    say("simulating %s along %s: %d frames at %.4g fps, %d spp, seed %llu -> %s\n", options.scene.c_str(),
                options.trajectory.c_str(), total, trajectory->rateHz(), options.sim.spp,
                static_cast<unsigned long long>(options.sim.seed), options.sim.out.c_str());

    // Step 2: render.
    Progress progress("sim", static_cast<std::uint64_t>(total));
    auto summary = mocks::sim::simulate(
        *scene, *trajectory, options.sim, [&](int done, int) { progress.update(static_cast<std::uint64_t>(done)); },
        stopToken());
    progress.finish();
    if (!summary) return reportError(summary.error());

    // Step 3: report.
    const double per_frame = summary->frames_written > 0 ? summary->render_seconds / summary->frames_written : 0.0;
    say("wrote %d frames to %s (render %.1f s, %.2f s per frame incl. the composite, %.3g samples/s)\n",
                summary->frames_written, options.sim.out.c_str(), summary->render_seconds, per_frame,
                summary->render_seconds > 0 ? static_cast<double>(summary->samples) / summary->render_seconds : 0.0);
    if (summary->nonfinite_samples > 0) {
        log::warning(std::to_string(summary->nonfinite_samples) + " samples were not finite and were dropped");
    }
    if (summary->stopped) {
        log::warning("stopped: the sequence holds the " + std::to_string(summary->frames_written) + " frames done");
        return 130;
    }
    return kExitOk;
}

}  // namespace

void addSimCommand(CLI::App& app, Runner& runner) {
    auto options = std::make_shared<SimCommandOptions>();
    CLI::App* sub = app.add_subcommand("sim", "Render a simulated sequence with its ground truth (docs/sim.md)");
    sub->add_option("--scene", options->scene, "Scene file with the true albedos and lights")->required();
    sub->add_option("--trajectory", options->trajectory, "Camera trajectory file (keyframes, orbit or pan)")->required();
    sub->add_option("--out", options->sim.out, "Sequence folder to create")->required();
    sub->add_option("--frames", options->sim.frames, "Frames to render (default: the whole trajectory)")
        ->check(CLI::NonNegativeNumber);
    sub->add_option("--spp", options->sim.spp, "Samples per pixel")->check(CLI::Range(1, 1 << 20))->capture_default_str();
    sub->add_option("--seed", options->sim.seed, "Seed of the samples and the sensor noise")->capture_default_str();
    sub->add_option("--max-depth", options->sim.max_depth, "Scattering events per light path")
        ->check(CLI::Range(1, 1000))->capture_default_str();
    sub->add_option("--calib", options->calib, "Camera calibration (default: the scene's camera)");
    sub->add_option("--format", options->format, "Frame files: png (lossless) or jpeg (as an MJPEG webcam sends)")
        ->check(CLI::IsMember({"png", "jpeg"}))
        ->capture_default_str();
    sub->add_option("--jpeg-quality", options->sim.jpeg_quality, "JPEG quality")->check(CLI::Range(1, 100))->capture_default_str();
    sub->add_option("--exposure-us", options->exposure_us, "Exposure time, microseconds")->check(CLI::PositiveNumber);
    sub->add_option("--gain", options->gain, "Analog gain (linear)")->check(CLI::PositiveNumber);
    sub->add_option("--sensor", options->sensor_settings,
                    "Sensor parameter KEY=VALUE (repeatable; keys in docs/sim-sensor.md, e.g. bits=12)");
    sub->add_option("--sensor-file", options->sensor_file, "YAML file with a 'sensor:' map (docs/sim-sensor.md)");
    sub->add_flag("--motion-blur", options->sim.motion_blur, "Average the camera's motion over the exposure");
    sub->add_option("--rolling-shutter", options->sim.rolling_shutter_row_time_s,
                    "Rolling shutter: seconds between the exposure starts of consecutive rows (0: global shutter)")
        ->check(CLI::NonNegativeNumber);
    sub->add_flag("--no-composite", options->no_composite, "Do not render the composite ground truth (nor its masks)");
    sub->add_flag("--no-masks", options->no_masks, "Do not write the masks");
    sub->add_flag("--no-radiance", options->no_radiance, "Do not write the linear radiance images");
    sub->footer("Exit codes: 0 ok, 2 usage, 3 bad input, 130 stopped (the sequence keeps the frames done)");
    sub->callback([options, &runner] { runner = [options] { return runSim(*options); }; });
}

}  // namespace commonlight::apps

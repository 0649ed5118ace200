#include "mocks/sim/sim_camera.h"

#include <cmath>
#include <iterator>

#include "core/log.h"
#include "core/scene_io.h"
#include "mocks/sim/render.h"

namespace commonlight::mocks::sim {

Result<std::unique_ptr<SimCamera>> SimCamera::open(std::string id, const Scene& scene, Trajectory trajectory,
                                                   const SimCameraOptions& options, Clock& clock) {
    if (!scene.camera) return fail(ErrorCode::kBadInput, id + ": the scene has no camera (key 'camera')");
    if (options.spp < 1 || options.max_depth < 1) return fail(ErrorCode::kUsage, id + ": spp and max_depth must be >= 1");
    CL_TRY_VOID(options.playback.validate());
    CL_TRY(SimScene sim_scene, SimScene::build(scene, {.include_virtual = false, .time_s = 0.0}));
    CL_TRY(SensorModel sensor, SensorModel::create(options.sensor, scene.camera->width, scene.camera->height));
    return std::unique_ptr<SimCamera>(new SimCamera(std::move(id), std::move(sim_scene), *scene.camera,
                                                    std::move(trajectory), std::move(sensor), options, clock));
}

Result<std::unique_ptr<SimCamera>> SimCamera::open(const hal::CameraUri& uri, Clock& clock) {
    const auto trajectory_file = uri.option("trajectory");
    if (!trajectory_file) {
        return fail(ErrorCode::kUsage, "camera URI '" + uri.text + "': sim: needs trajectory=<file>");
    }
    CL_TRY(const Scene scene, readScene(uri.path));
    CL_TRY(Trajectory trajectory, Trajectory::read(std::string(*trajectory_file)));
    SimCameraOptions options;
    CL_TRY(options.playback, PlaybackOptions::fromUri(uri));
    CL_TRY(const auto spp, uri.integer("spp"));
    CL_TRY(const auto seed, uri.integer("seed"));
    CL_TRY(const auto depth, uri.integer("max_depth"));
    if (spp) options.spp = static_cast<int>(*spp);
    if (seed) options.seed = static_cast<std::uint64_t>(*seed);
    if (depth) options.max_depth = static_cast<int>(*depth);
    CL_TRY(const auto exposure, uri.number("exposure_us"));
    CL_TRY(const auto gain, uri.number("gain"));
    if (exposure) options.sensor.exposure_us = *exposure;
    if (gain) options.sensor.analog_gain = *gain;
    return open(uri.text, scene, std::move(trajectory), options, clock);
}

SimCamera::SimCamera(std::string id, SimScene scene, CameraModel camera, Trajectory trajectory, SensorModel sensor,
                     const SimCameraOptions& options, Clock& clock)
    : PacedCamera(std::move(id), clock, options.playback),
      scene_(std::move(scene)),
      camera_(camera),
      trajectory_(std::move(trajectory)),
      sensor_(std::make_shared<const SensorModel>(std::move(sensor))),
      options_(options) {}

SimCamera::~SimCamera() { stop(); }

std::vector<hal::StreamFormat> SimCamera::doFormats() const {
    return {{PixelFormat::kRgb8, camera_.width, camera_.height, {trajectory_.rateHz()}, 0.0}};
}

Result<hal::StreamFormat> SimCamera::doConfigure(const hal::StreamConfig& config) {
    return hal::negotiate(doFormats(), config, id());
}

std::vector<hal::ControlInfo> SimCamera::doControls() const {
    std::lock_guard lock(sensor_mutex_);
    return {{hal::Control::kExposureUs, 1.0, 1e8, 0.0, options_.sensor.exposure_us},
            {hal::Control::kAnalogGain, 1e-3, 1000.0, 0.0, options_.sensor.analog_gain}};
}

Result<void> SimCamera::doSetControl(hal::Control control, double value) {
    if (control == hal::Control::kAutoExposure) {
        // The simulated sensor has no auto exposure: turning it off is a no-op, on is unsupported.
        if (value == 0.0) return {};
        return fail(ErrorCode::kUnsupported, id() + ": the simulated camera has no auto exposure");
    }
    if (control != hal::Control::kExposureUs && control != hal::Control::kAnalogGain) {
        return fail(ErrorCode::kUnsupported,
                    id() + ": control " + std::string(hal::controlName(control)) + " is not supported");
    }
    std::lock_guard lock(sensor_mutex_);
    SensorParams params = options_.sensor;
    (control == hal::Control::kExposureUs ? params.exposure_us : params.analog_gain) = value;
    CL_TRY(SensorModel sensor, SensorModel::create(params, camera_.width, camera_.height));  // validates
    options_.sensor = params;
    sensor_ = std::make_shared<const SensorModel>(std::move(sensor));
    return {};
}

Result<double> SimCamera::doGetControl(hal::Control control) const {
    std::lock_guard lock(sensor_mutex_);
    if (control == hal::Control::kExposureUs) return options_.sensor.exposure_us;
    if (control == hal::Control::kAnalogGain) return options_.sensor.analog_gain;
    return fail(ErrorCode::kUnsupported, id() + ": control " + std::string(hal::controlName(control)) + " is not supported");
}

std::shared_ptr<const SensorModel> SimCamera::currentSensor() const {
    std::lock_guard lock(sensor_mutex_);
    return sensor_;
}

void SimCamera::run(std::stop_token stop) {
    const int frames = trajectory_.frameCount();
    const double period_s = frames / trajectory_.rateHz();
    RawFrame raw;
    for (std::uint64_t n = 0; !stop.stop_requested(); ++n) {
        const auto index = static_cast<int>(n % static_cast<std::uint64_t>(frames));
        if (n > 0 && index == 0 && !options_.playback.loop) {
            emitEvent({hal::CameraEvent::Type::kEndOfStream, {}});
            return;
        }
        const double pass = std::floor(static_cast<double>(n) / frames);
        const double t = trajectory_.startTime() + index / trajectory_.rateHz();
        const auto timestamp_ns = std::llround((t - trajectory_.startTime() + pass * period_s) * 1e9);
        if (!pacer().waitUntilDue(timestamp_ns, stop)) return;

        RenderRequest request;
        request.scene = &scene_;
        request.camera = camera_;
        // At the middle of the exposure (the timestamp is its start): what a real camera's image
        // of a moving scene stands for (docs/tracking.md, "Timestamps").
        request.world_from_cam = trajectory_.worldFromCam(t + 0.5e-6 * currentSensor()->params().exposure_us);
        request.spp = options_.spp;
        request.seed = options_.seed;
        request.frame_index = n;
        request.max_depth = options_.max_depth;
        auto rendered = render(request);
        FrameHandle slot = acquireFrame();
        if (!slot) continue;  // counted by the base class
        slot->meta = {};
        slot->meta.sequence = n;
        slot->meta.timestamp_ns = timestamp_ns;
        slot->meta.timestamp_source = TimestampSource::kSimulated;
        const std::shared_ptr<const SensorModel> sensor = currentSensor();
        slot->meta.exposure_us = sensor->params().exposure_us;
        slot->meta.analog_gain = sensor->params().analog_gain;
        if (!rendered || !sensor->expose(rendered->radiance, n, raw)) {
            // Never expected (the scene was validated when opened); deliver the frame as corrupt.
            log::warning(id() + ": frame " + std::to_string(n) + " could not be rendered");
            slot->image.clear();
            slot->meta.status = FrameStatus::kCorrupt;
        } else {
            sensor->encode8(raw, slot->image);
        }
        slot->meta.arrival_ns = clock().nowNs();
        emitFrame(std::move(slot));
    }
}

void registerSimBackend(hal::CameraRegistry& registry, Clock& clock) {
    registry.add(hal::Backend{
        "sim",
        "the simulated camera (path traced): sim:<scene.yaml>?trajectory=<file>&spp=16&seed=1&rate=realtime|max|step",
        std::vector<std::string>(std::begin(kSimOptionNames), std::end(kSimOptionNames)),
        [&clock](const hal::CameraUri& uri) -> Result<std::unique_ptr<hal::Camera>> {
            CL_TRY(auto camera, SimCamera::open(uri, clock));
            return std::unique_ptr<hal::Camera>(std::move(camera));
        },
        {},
    });
}

std::string SimCamera::doResponseSpec() const {
    const std::lock_guard lock(sensor_mutex_);
    return sensorResponseSpec(options_.sensor);
}

}  // namespace commonlight::mocks::sim

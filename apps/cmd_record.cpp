// commonlight record --camera URI --out SEQ [--frames N]: records a sequence
// (docs/formats-sequence.md) that stays readable whatever happens: Ctrl-C, a disconnected camera,
// a full disk or kill -9 leave every completed frame listed and valid.
#include <chrono>
#include <cstdio>
#include <memory>

#include "apps/app.h"
#include "apps/quiet.h"
#include "apps/progress.h"
#include "apps/report.h"
#include "capture/capture_session.h"
#include "capture/recorder.h"
#include "core/calibration_io.h"
#include "core/log.h"

namespace commonlight::apps {

namespace {

struct RecordOptions {
    std::string camera;
    std::string out;
    std::uint64_t frames = 0;  // 0: until the stream ends or Ctrl-C
    std::string calib;
    bool sync = false;
    bool no_fsync = false;
    std::size_t queue = 16;
    double timeout_s = 5.0;
};

int runRecord(const RecordOptions& options) {
    // Step 1: open and configure the camera from its URI.
    const hal::CameraRegistry registry = makeCameraRegistry();
    auto camera = registry.openConfigured(options.camera);
    if (!camera) return reportError(camera.error());
    const hal::StreamFormat format = (*camera)->activeFormat();

    SensorInfo sensor;
    sensor.rate_hz = format.fps;
    sensor.comment = "recorded by commonlight from " + options.camera;
    if (!options.calib.empty()) {
        auto calib = readCalibration(options.calib);
        if (!calib) return reportError(calib.error());
        if (auto size = calib->checkImageSize(format.width, format.height); !size) {
            return reportError(Error{ErrorCode::kBadInput, options.calib + ": " + size.error().message});
        }
        sensor.camera = *calib;
    }

    // Step 2: the recorder (fails early on an unwritable or existing folder) and the session.
    capture::RecorderOptions recorder_options;
    recorder_options.queue_frames = options.queue;
    recorder_options.sync = !options.no_fsync;
    auto recorder = capture::Recorder::start(options.out, sensor, recorder_options);
    if (!recorder) return reportError(recorder.error());
    capture::CaptureOptions capture_options;
    capture_options.sync = options.sync;
    auto session = capture::CaptureSession::create(std::move(*camera), capture_options);
    if (!session) return reportError(session.error());
    say("recording %s (%s) to %s\n", options.camera.c_str(), hal::describe(format).c_str(), options.out.c_str());
    if (auto started = (*session)->start(); !started) {
        (*recorder)->finish();
        return reportError(started.error());
    }

    // Step 3: hand every frame to the recorder until done.
    std::optional<Error> failure;
    std::uint64_t taken = 0;
    const auto timeout = std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::duration<double>(options.timeout_s));
    Progress progress("record", options.frames);
    while (options.frames == 0 || taken < options.frames) {
        capture::NextFrame next = (*session)->next(stopToken(), timeout);
        if (!next) {
            if (next.error().code != ErrorCode::kCancelled) failure = next.error();
            break;
        }
        if (!next->has_value()) break;  // end of stream
        if (options.sync) {
            // Lossless: keep the recorder's queue from overflowing by waiting for the disk.
            const auto s = (*recorder)->summary();
            if (s.frames_queued - s.frames_written - s.rejected >= options.queue) (*recorder)->flush();
        }
        (*recorder)->push(***next);
        ++taken;
        progress.update(taken);
        if ((*recorder)->summary().write_error) break;
    }
    progress.finish();
    (*session)->stop();
    const capture::RecorderSummary summary = (*recorder)->finish();
    const capture::CaptureStats stats = (*session)->stats();

    // Step 4: report.
    say("recorded %zu frames to %s (dropped by the recorder %llu, rejected %llu, corrupt kept %llu)\n",
                summary.frames_written, options.out.c_str(), static_cast<unsigned long long>(summary.dropped),
                static_cast<unsigned long long>(summary.rejected),
                static_cast<unsigned long long>(summary.corrupt_written));
    if (!quiet()) printCaptureStats(stats);
    if (summary.first_rejection) log::warning(summary.first_rejection->message);
    if (summary.write_error) return reportError(*summary.write_error);
    if (failure) {
        if (failure->code == ErrorCode::kTimeout) {
            failure->message = options.camera + ": no frame for " + std::to_string(options.timeout_s) + " s";
            failure->code = ErrorCode::kDevice;
        }
        log::info("the sequence holds every frame received before the error");
        return reportError(*failure);
    }
    return stopToken().stop_requested() ? 130 : kExitOk;
}

}  // namespace

void addRecordCommand(CLI::App& app, Runner& runner) {
    auto options = std::make_shared<RecordOptions>();
    CLI::App* sub = app.add_subcommand("record", "Record a camera to a sequence (docs/formats-sequence.md)");
    sub->add_option("--camera", options->camera, "Camera URI, e.g. v4l2:/dev/video0 or replay:SEQ (docs/cli.md)")->required();
    sub->add_option("--out", options->out, "Sequence folder to create (must not hold a sequence yet)")->required();
    sub->add_option("--frames", options->frames, "Stop after N frames (default: until the stream ends or Ctrl-C)");
    sub->add_option("--calib", options->calib, "Calibration file whose intrinsics go into sensor.yaml");
    sub->add_flag("--sync", options->sync, "Lossless: never drop a frame (for replay:/video: sources, not live cameras)");
    sub->add_flag("--no-fsync", options->no_fsync, "Do not flush each frame to disk before listing it (faster; a power loss may lose the last frames)");
    sub->add_option("--queue", options->queue, "Frames buffered between camera and disk")->check(CLI::Range(1, 1024))->capture_default_str();
    sub->add_option("--timeout", options->timeout_s, "Seconds without a frame before the camera counts as lost")
        ->check(CLI::PositiveNumber)->capture_default_str();
    sub->footer("Exit codes: 0 ok, 2 usage, 3 bad input or unwritable output, 4 device error (the sequence keeps every frame received)");
    sub->callback([options, &runner] { runner = [options] { return runRecord(*options); }; });
}

}  // namespace commonlight::apps

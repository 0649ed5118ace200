// live's camera as the pipeline's frame source: a capture session (newest wins: a live camera
// never waits for us) that is reopened with back-off when the camera is lost, the photometry
// locked after a settle period, the frames recorded while recording is on, and the camera's state
// for the window's overlay.
//
// Threads: next() on the pipeline thread (the reconnection, the photometry lock and the
// recorder's push() happen there); startRecording(), stopRecording(), recording() and state()
// from any thread (the main thread's keys and overlay); finish() once the run is over.
#pragma once

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include "capture/capture_session.h"
#include "capture/photometry_lock.h"
#include "capture/recorder.h"
#include "core/sequence_io.h"
#include "hal/registry.h"
#include "pipeline/frame_loop.h"

namespace commonlight::pipeline {

struct CameraSourceOptions {
    std::string uri;
    std::uint64_t frames = 0;       // the stream ends after this many frames taken (0: never)
    double timeout_s = 5.0;         // no frame for this long: the camera is lost
    bool reconnect = true;          // false: a lost camera ends the run (its device error)
    double reconnect_max_s = 60.0;  // give up after this long; back-off 0.25 s doubling to 8 s
    bool lock_photometry = true;
    double settle_s = 2.0;          // auto exposure's time before the photometry is locked
};

// What the window says about the camera.
struct CameraState {
    enum class Kind { kStreaming, kReconnecting, kGone };
    Kind kind = Kind::kStreaming;
    std::string lost_reason;        // the device error that lost it (kReconnecting, kGone)
    int attempts = 0;               // reconnection attempts since it was lost
    double next_attempt_s = 0.0;    // back-off before the next attempt
    std::uint64_t reconnects = 0;   // successful reconnections so far
    std::uint64_t taken = 0;        // frames taken so far
};

struct RecordingState {
    bool on = false;
    std::filesystem::path folder;   // the current (or last) recording
    std::uint64_t frames = 0;       // frames queued to it
};

// The sums over the connections (one capture session each).
struct CameraTotals {
    std::uint64_t received = 0, delivered = 0, device = 0, no_slot = 0, mailbox = 0, corrupt = 0;
    std::uint64_t taken = 0, reconnects = 0;
    capture::CaptureStats last;     // the last connection's
};

class CameraSource final : public FrameSource {
public:
    // Opens and starts the camera. Errors: the registry's (kUsage for a bad URI, kDevice, ...).
    static Result<std::unique_ptr<CameraSource>> open(const hal::CameraRegistry& registry, const CameraSourceOptions& options);
    ~CameraSource() override;
    CameraSource(const CameraSource&) = delete;
    CameraSource& operator=(const CameraSource&) = delete;

    // Pipeline thread. The next frame (recorded first when recording); a lost camera is reopened
    // here with back-off (kDevice when it does not come back, or at once without reconnection;
    // kCancelled when `stop` is requested meanwhile).
    Result<std::optional<FrameHandle>> next(std::stop_token stop) override;
    // Called on the pipeline thread after each reconnection (a new connection's timestamps may
    // start over: the tracking restarts). An error ends the run.
    void setOnReconnect(std::function<Result<void>()> on_reconnect) { on_reconnect_ = std::move(on_reconnect); }

    // The first connection's format and response (for the calibration check and the lighting).
    const hal::StreamFormat& format() const noexcept { return format_; }
    const std::string& responseSpec() const noexcept { return response_spec_; }
    // The first connection's intrinsics, when the camera knows them (hal::Camera::calibration).
    const std::optional<CameraModel>& calibration() const noexcept { return calibration_; }

    // Any thread. Starts recording every frame taken into a new sequence `folder` (its
    // sensor.yaml from `sensor`); errors name the folder (it exists, cannot be written). kUsage
    // when already recording.
    Result<void> startRecording(const std::filesystem::path& folder, const SensorInfo& sensor);
    // Any thread. Stops recording: the queued frames are written, the summary returned (nullopt
    // when not recording).
    std::optional<capture::RecorderSummary> stopRecording();
    RecordingState recording() const;
    CameraState state() const;

    // Once the run is over: stops the session, and the sums over every connection.
    CameraTotals finish();

private:
    CameraSource(const hal::CameraRegistry& registry, const CameraSourceOptions& options);
    Result<void> reconnect(const Error& lost, std::stop_token stop);

    const hal::CameraRegistry* registry_;
    CameraSourceOptions options_;
    std::chrono::nanoseconds timeout_;
    std::unique_ptr<capture::CaptureSession> session_;  // pipeline thread (and open/finish)
    capture::PhotometryLock photometry_;
    hal::StreamFormat format_;
    std::string response_spec_;
    std::optional<CameraModel> calibration_;
    std::function<Result<void>()> on_reconnect_;
    CameraTotals totals_;  // the pipeline thread's (and finish's)

    mutable std::mutex mutex_;  // guards the members below
    CameraState state_;
    std::unique_ptr<capture::Recorder> recorder_;
    RecordingState recording_;
};

// A folder for a new recording: `wanted` when it is free, else `wanted-2`, `wanted-3`, ...
std::filesystem::path freeRecordingFolder(const std::filesystem::path& wanted);

}  // namespace commonlight::pipeline

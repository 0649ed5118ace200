#include "pipeline/camera_source.h"

#include <algorithm>
#include <condition_variable>
#include <cstdio>

#include "core/clock.h"
#include "core/log.h"

namespace commonlight::pipeline {

namespace fs = std::filesystem;

namespace {

Result<std::unique_ptr<capture::CaptureSession>> connect(const hal::CameraRegistry& registry, const std::string& uri) {
    CL_TRY(std::unique_ptr<hal::Camera> camera, registry.openConfigured(uri));
    capture::CaptureOptions capture_options;  // newest wins: a live camera never waits for us
    CL_TRY(std::unique_ptr<capture::CaptureSession> session, capture::CaptureSession::create(std::move(camera), capture_options));
    CL_TRY_VOID(session->start());
    return session;
}

// Sleeps up to `seconds`, waking early when `stop` is requested. False when stopped.
bool sleepUnlessStopped(double seconds, std::stop_token stop) {
    std::mutex mutex;
    std::condition_variable_any cv;
    std::unique_lock lock(mutex);
    return !cv.wait_for(lock, stop, std::chrono::duration<double>(seconds), [] { return false; });
}

void addStats(CameraTotals& totals, const capture::CaptureStats& s) {
    totals.received += s.frames_received;
    totals.delivered += s.frames_delivered;
    totals.device += s.drops.device;
    totals.no_slot += s.drops.no_slot;
    totals.mailbox += s.drops.mailbox;
    totals.corrupt += s.drops.corrupt;
    totals.last = s;
}

}  // namespace

fs::path freeRecordingFolder(const fs::path& wanted) {
    std::error_code ec;
    if (!fs::exists(wanted, ec)) return wanted;
    for (int k = 2;; ++k) {
        char suffix[24];
        std::snprintf(suffix, sizeof suffix, "-%d", k);
        fs::path candidate = wanted;
        candidate += suffix;
        if (!fs::exists(candidate, ec)) return candidate;
    }
}

CameraSource::CameraSource(const hal::CameraRegistry& registry, const CameraSourceOptions& options)
    : registry_(&registry),
      options_(options),
      timeout_(std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::duration<double>(options.timeout_s))),
      photometry_(static_cast<std::int64_t>(options.settle_s * 1e9)) {}

CameraSource::~CameraSource() {
    stopRecording();
    if (session_) session_->stop();
}

Result<std::unique_ptr<CameraSource>> CameraSource::open(const hal::CameraRegistry& registry, const CameraSourceOptions& options) {
    auto source = std::unique_ptr<CameraSource>(new CameraSource(registry, options));
    CL_TRY(source->session_, connect(registry, options.uri));
    source->format_ = source->session_->camera().activeFormat();
    source->response_spec_ = source->session_->camera().responseSpec();
    source->calibration_ = source->session_->camera().calibration();
    return source;
}

Result<std::optional<FrameHandle>> CameraSource::next(std::stop_token stop) {
    while (true) {
        if (options_.frames > 0 && totals_.taken >= options_.frames) return std::optional<FrameHandle>();
        // Step 1: the newest frame of the current connection.
        capture::NextFrame next = session_->next(stop, timeout_);
        if (next && !next->has_value()) return std::optional<FrameHandle>();  // the stream ended (a recording's end)
        if (!next) {
            if (next.error().code == ErrorCode::kCancelled) return fail(next.error());
            // Step 2: the camera is lost; reopen it (or end the run with its error).
            Error lost = next.error();
            if (lost.code == ErrorCode::kTimeout) {
                char text[64];
                std::snprintf(text, sizeof text, ": no frame for %g s", options_.timeout_s);
                lost = Error{ErrorCode::kDevice, options_.uri + text};
            }
            log::error("camera lost: " + lost.message);
            CL_TRY_VOID(reconnect(lost, stop));
            continue;
        }
        FrameHandle frame = std::move(**next);
        ++totals_.taken;
        // Step 3: record it, then lock the photometry once the camera has settled.
        {
            std::lock_guard lock(mutex_);
            state_.taken = totals_.taken;
            if (recorder_ && recorder_->push(*frame)) ++recording_.frames;
        }
        if (options_.lock_photometry) {
            auto locked = photometry_.onFrame(session_->camera(), frame->meta.arrival_ns);
            if (!locked) {
                log::warning("cannot lock the photometry: " + locked.error().message);
            } else if (*locked) {
                char settled[32];
                std::snprintf(settled, sizeof settled, "%.1f s", options_.settle_s);
                log::info(std::string("photometry locked after ") + settled + ": " + (*locked)->describe());
            }
        }
        return std::optional<FrameHandle>(std::move(frame));
    }
}

Result<void> CameraSource::reconnect(const Error& lost, std::stop_token stop) {
    session_->stop();
    addStats(totals_, session_->stats());
    session_.reset();
    {
        std::lock_guard lock(mutex_);
        state_.kind = options_.reconnect ? CameraState::Kind::kReconnecting : CameraState::Kind::kGone;
        state_.lost_reason = lost.message;
        state_.attempts = 0;
        state_.next_attempt_s = 0.25;
    }
    if (!options_.reconnect) return fail(lost);
    // Back-off: 0.25 s doubling to 8 s, until the camera is back or reconnect_max_s passed.
    double backoff = 0.25;
    const std::int64_t lost_ns = monotonicNowNs();
    while (true) {
        if (!sleepUnlessStopped(backoff, stop)) return fail(ErrorCode::kCancelled, "stopped while reconnecting");
        auto again = connect(*registry_, options_.uri);
        if (again) {
            session_ = std::move(*again);
            break;
        }
        const double waited = static_cast<double>(monotonicNowNs() - lost_ns) / 1e9;
        char when[32];
        std::snprintf(when, sizeof when, "%.2f s", waited);
        log::warning("reconnecting to " + options_.uri + " failed after " + when + ": " + again.error().message);
        {
            std::lock_guard lock(mutex_);
            ++state_.attempts;
            state_.next_attempt_s = std::min(backoff * 2.0, 8.0);
        }
        if (waited >= options_.reconnect_max_s) {
            std::lock_guard lock(mutex_);
            state_.kind = CameraState::Kind::kGone;
            char limit[32];
            std::snprintf(limit, sizeof limit, "%g s", options_.reconnect_max_s);
            return fail(ErrorCode::kDevice, options_.uri + ": lost and not back within " + limit + " (" + lost.message + ")");
        }
        backoff = std::min(backoff * 2.0, 8.0);
    }
    ++totals_.reconnects;
    {
        std::lock_guard lock(mutex_);
        state_.kind = CameraState::Kind::kStreaming;
        state_.reconnects = totals_.reconnects;
        ++state_.attempts;
    }
    photometry_.reset();
    if (on_reconnect_) CL_TRY_VOID(on_reconnect_());
    log::info("reconnected to " + options_.uri);
    return {};
}

Result<void> CameraSource::startRecording(const fs::path& folder, const SensorInfo& sensor) {
    std::lock_guard lock(mutex_);
    if (recorder_) return fail(ErrorCode::kUsage, "already recording to " + recording_.folder.string());
    CL_TRY(recorder_, capture::Recorder::start(folder, sensor));
    recording_ = RecordingState{true, folder, 0};
    return {};
}

std::optional<capture::RecorderSummary> CameraSource::stopRecording() {
    std::unique_ptr<capture::Recorder> recorder;
    {
        std::lock_guard lock(mutex_);
        recorder = std::move(recorder_);
        recording_.on = false;
    }
    // The queued frames are written outside the lock: the pipeline thread goes on meanwhile.
    if (!recorder) return std::nullopt;
    return recorder->finish();
}

RecordingState CameraSource::recording() const {
    std::lock_guard lock(mutex_);
    return recording_;
}

CameraState CameraSource::state() const {
    std::lock_guard lock(mutex_);
    return state_;
}

CameraTotals CameraSource::finish() {
    if (session_) {
        session_->stop();
        addStats(totals_, session_->stats());
        session_.reset();
    }
    return totals_;
}

}  // namespace commonlight::pipeline

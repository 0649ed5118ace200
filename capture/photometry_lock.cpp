#include "capture/photometry_lock.h"

#include <cstdio>

namespace commonlight::capture {

namespace {

// The control's value, nullopt when the camera does not have it; other errors pass through.
Result<std::optional<double>> readIfPresent(hal::Camera& camera, hal::Control control) {
    auto value = camera.getControl(control);
    if (value) return std::optional<double>(*value);
    if (value.error().code == ErrorCode::kUnsupported) return std::optional<double>();
    return fail(value.error());
}

// Sets the control; false when the camera does not have it.
Result<bool> setIfPresent(hal::Camera& camera, hal::Control control, double value) {
    auto set = camera.setControl(control, value);
    if (set) return true;
    if (set.error().code == ErrorCode::kUnsupported) return false;
    return fail(set.error());
}

}  // namespace

std::string PhotometryLockReport::describe() const {
    std::string out;
    char buffer[96];
    if (exposure_us) {
        std::snprintf(buffer, sizeof buffer, "exposure %.0f us", *exposure_us);
        out += buffer;
    } else {
        out += "no exposure control";
    }
    if (analog_gain) {
        std::snprintf(buffer, sizeof buffer, ", gain %.3f", *analog_gain);
        out += buffer;
    } else {
        out += ", no gain control";
    }
    out += auto_exposure_off ? ", auto exposure off" : ", no auto exposure to turn off";
    out += auto_white_balance_off ? ", auto white balance off" : ", no auto white balance to turn off";
    return out;
}

Result<PhotometryLockReport> PhotometryLock::lock(hal::Camera& camera) {
    PhotometryLockReport report;
    // Read what auto exposure chose before turning it off: some cameras reset the values then.
    CL_TRY(report.exposure_us, readIfPresent(camera, hal::Control::kExposureUs));
    CL_TRY(report.analog_gain, readIfPresent(camera, hal::Control::kAnalogGain));
    CL_TRY(report.auto_exposure_off, setIfPresent(camera, hal::Control::kAutoExposure, 0.0));
    CL_TRY(report.auto_white_balance_off, setIfPresent(camera, hal::Control::kAutoWhiteBalance, 0.0));
    if (report.exposure_us) {
        CL_TRY_VOID(camera.setControl(hal::Control::kExposureUs, *report.exposure_us));
    }
    if (report.analog_gain) {
        CL_TRY_VOID(camera.setControl(hal::Control::kAnalogGain, *report.analog_gain));
    }
    return report;
}

Result<std::optional<PhotometryLockReport>> PhotometryLock::onFrame(hal::Camera& camera, std::int64_t now_ns) {
    if (locked_) return std::optional<PhotometryLockReport>();
    if (!first_ns_) first_ns_ = now_ns;
    if (now_ns - *first_ns_ < settle_ns_) return std::optional<PhotometryLockReport>();
    locked_ = true;  // once, even when it fails: the caller reports the error
    CL_TRY(PhotometryLockReport report, lock(camera));
    return std::optional<PhotometryLockReport>(report);
}

}  // namespace commonlight::capture

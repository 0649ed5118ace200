// Locks a camera's photometry after a settle period, for common illumination: the lighting
// estimate assumes that a pixel value means the same radiance from frame to frame, so auto
// exposure, auto gain and auto white balance must stop once they have found their levels.
//
// Used by `live` on its control thread: call onFrame() for every frame; once `settle_ns` has
// passed since the first frame, it reads the exposure and gain the camera chose, turns auto
// exposure and auto white balance off, and writes the chosen values back (a camera that only
// holds them while auto exposure is on would otherwise fall back to its defaults). Controls the
// camera does not have are skipped and reported; any other control error is returned.
#pragma once

#include <cstdint>
#include <optional>
#include <string>

#include "core/result.h"
#include "hal/camera.h"

namespace commonlight::capture {

struct PhotometryLockReport {
    std::optional<double> exposure_us;  // the value locked; nullopt: the camera has no exposure control
    std::optional<double> analog_gain;
    bool auto_exposure_off = false;       // false: no auto-exposure control (nothing to turn off)
    bool auto_white_balance_off = false;  // false: no auto-white-balance control
    std::string describe() const;
};

class PhotometryLock {
public:
    explicit PhotometryLock(std::int64_t settle_ns) noexcept : settle_ns_(settle_ns) {}

    // Control thread, once per frame with the frame's arrival time. Returns the report the one
    // time it locks; nullopt before and after.
    Result<std::optional<PhotometryLockReport>> onFrame(hal::Camera& camera, std::int64_t now_ns);

    // Starts over (after a reconnect: the new session settles and locks again).
    void reset() noexcept {
        first_ns_.reset();
        locked_ = false;
    }
    bool locked() const noexcept { return locked_; }

    // Locks now, whatever the time.
    static Result<PhotometryLockReport> lock(hal::Camera& camera);

private:
    std::int64_t settle_ns_;
    std::optional<std::int64_t> first_ns_;
    bool locked_ = false;
};

}  // namespace commonlight::capture

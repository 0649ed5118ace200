// A camera whose frames come from memory: it emits copies of one prepared image, stamped at a
// nominal rate, paced like a recording (rate=max: as fast as the consumer takes them). Its thread
// copies the image into a pool slot, as a hardware backend copies out of a driver buffer, so it
// measures and tests the pipeline around the pixels without any decoding or I/O.
//
// Not registered as a URI scheme: tests and benchmarks construct it.
#pragma once

#include <cstdint>
#include <vector>

#include "core/clock.h"
#include "core/image.h"
#include "hal/camera.h"
#include "mocks/pacer.h"
#include "mocks/paced_camera.h"

namespace commonlight::mocks {

class MemoryCamera final : public PacedCamera {
public:
    // `frame` is the image every frame carries (owned); `fps` its nominal rate (timestamps are
    // n / fps); `clock` paces and stamps arrival_ns (borrowed, must outlive the camera).
    MemoryCamera(Image frame, double fps, PlaybackOptions options, Clock& clock = SteadyClock::instance());
    ~MemoryCamera() override;

private:
    std::vector<hal::StreamFormat> doFormats() const override;
    Result<hal::StreamFormat> doConfigure(const hal::StreamConfig& config) override;
    void run(std::stop_token stop) override;  // the camera thread

    Image frame_;
    double fps_;
};

}  // namespace commonlight::mocks

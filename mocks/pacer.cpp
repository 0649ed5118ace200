#include "mocks/pacer.h"

#include <algorithm>
#include <cmath>
#include <string>

namespace commonlight::mocks {

Result<void> PlaybackOptions::validate() const {
    if (!(speed > 0.0) || !std::isfinite(speed)) return fail(ErrorCode::kUsage, "speed must be a positive number");
    if (speed != 1.0 && rate != PlaybackRate::kRealtime) {
        return fail(ErrorCode::kUsage, "speed applies to rate=realtime only");
    }
    return {};
}

Result<PlaybackOptions> PlaybackOptions::fromUri(const hal::CameraUri& uri) {
    PlaybackOptions options;
    if (const auto rate = uri.option("rate")) {
        if (*rate == "realtime") {
            options.rate = PlaybackRate::kRealtime;
        } else if (*rate == "max") {
            options.rate = PlaybackRate::kMax;
        } else if (*rate == "step") {
            options.rate = PlaybackRate::kStep;
        } else {
            return fail(ErrorCode::kUsage, "camera URI '" + uri.text +
                                               "': option 'rate' must be realtime, max or step, got '" +
                                               std::string(*rate) + "'");
        }
    }
    CL_TRY(const auto loop, uri.flag("loop"));
    CL_TRY(const auto speed, uri.number("speed"));
    options.loop = loop.value_or(false);
    options.speed = speed.value_or(1.0);
    if (auto valid = options.validate(); !valid) {
        return fail(std::move(valid.error()).prepend("camera URI '" + uri.text + "'"));
    }
    return options;
}

std::int64_t nominalIntervalNs(double rate_hz, std::int64_t first_ns, std::int64_t last_ns,
                               std::size_t count) noexcept {
    if (rate_hz > 0.0) return std::max<std::int64_t>(1, std::llround(1e9 / rate_hz));
    if (count >= 2 && last_ns > first_ns) {
        return std::max<std::int64_t>(1, (last_ns - first_ns) / static_cast<std::int64_t>(count - 1));
    }
    return 33'333'333;  // a single frame of unknown rate: loop it at 30 fps
}

void Pacer::reset() {
    first_timestamp_ns_.reset();
    std::lock_guard lock(mutex_);
    pending_triggers_ = 0;
}

bool Pacer::waitUntilDue(std::int64_t timestamp_ns, std::stop_token stop) {
    switch (options_.rate) {
        case PlaybackRate::kMax:
            return !stop.stop_requested();
        case PlaybackRate::kStep: {
            std::unique_lock lock(mutex_);
            if (!triggered_.wait(lock, stop, [&] { return pending_triggers_ > 0; })) return false;
            --pending_triggers_;
            return true;
        }
        case PlaybackRate::kRealtime:
            break;
    }
    if (!first_timestamp_ns_) {
        first_timestamp_ns_ = timestamp_ns;
        anchor_ns_ = clock_.nowNs();
    }
    const std::int64_t since_first = timestamp_ns - *first_timestamp_ns_;
    // speed 1 stays in integers, so a clock advanced by exactly one recorded interval releases
    // exactly one frame.
    const std::int64_t offset =
        options_.speed == 1.0
            ? since_first
            : static_cast<std::int64_t>(std::llround(static_cast<double>(since_first) / options_.speed));
    return clock_.sleepUntil(anchor_ns_ + offset, stop);
}

Result<void> Pacer::trigger(const std::string& camera) {
    if (options_.rate != PlaybackRate::kStep) {
        return fail(ErrorCode::kUnsupported, camera + ": software trigger needs rate=step");
    }
    {
        std::lock_guard lock(mutex_);
        ++pending_triggers_;
    }
    triggered_.notify_one();
    return {};
}

}  // namespace commonlight::mocks

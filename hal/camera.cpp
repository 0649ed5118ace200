#include "hal/camera.h"

#include <algorithm>
#include <cmath>
#include <sstream>

namespace commonlight::hal {

std::string_view controlName(Control control) noexcept {
    switch (control) {
        case Control::kExposureUs: return "exposure_us";
        case Control::kAnalogGain: return "gain";
        case Control::kAutoExposure: return "auto_exposure";
        case Control::kAutoWhiteBalance: return "auto_white_balance";
        case Control::kFrameRate: return "fps";
    }
    return "unknown";
}

std::string describe(const StreamFormat& format) {
    std::ostringstream out;
    out << pixelFormatName(format.format) << " " << format.width << "x" << format.height;
    if (format.fps > 0) {
        out << " @" << format.fps << " fps";
    } else if (!format.frame_rates.empty()) {
        out << " @";
        for (std::size_t i = 0; i < format.frame_rates.size(); ++i) out << (i ? "/" : "") << format.frame_rates[i];
        out << " fps";
    }
    return out.str();
}

Result<StreamFormat> negotiate(const std::vector<StreamFormat>& offered, const StreamConfig& wanted,
                               const std::string& device) {
    const StreamFormat* best = nullptr;
    for (const auto& f : offered) {
        if (wanted.format != PixelFormat::kInvalid && f.format != wanted.format) continue;
        if (wanted.width > 0 && f.width != wanted.width) continue;
        if (wanted.height > 0 && f.height != wanted.height) continue;
        if (wanted.fps > 0 && !f.frame_rates.empty() &&
            std::none_of(f.frame_rates.begin(), f.frame_rates.end(),
                         [&](double r) { return std::abs(r - wanted.fps) <= 0.01 * wanted.fps; })) {
            continue;
        }
        const bool size_free = wanted.width <= 0 && wanted.height <= 0;
        if (best == nullptr || (size_free && f.width * f.height > best->width * best->height)) best = &f;
    }
    if (best == nullptr) {
        std::ostringstream msg;
        msg << device << ": cannot stream";
        if (wanted.format != PixelFormat::kInvalid) msg << " " << pixelFormatName(wanted.format);
        if (wanted.width > 0 || wanted.height > 0) msg << " " << wanted.width << "x" << wanted.height;
        if (wanted.fps > 0) msg << " @" << wanted.fps << " fps";
        msg << "; the device offers:";
        if (offered.empty()) msg << " nothing";
        for (const auto& f : offered) msg << "\n  " << describe(f);
        return fail(ErrorCode::kUnsupported, msg.str());
    }
    StreamFormat chosen = *best;
    if (wanted.fps > 0 && !chosen.frame_rates.empty()) {
        // The device runs at the rate it offers (30, not the 29.97 that matched it within 1%).
        chosen.fps = *std::min_element(chosen.frame_rates.begin(), chosen.frame_rates.end(), [&](double a, double b) {
            return std::abs(a - wanted.fps) < std::abs(b - wanted.fps);
        });
    } else if (wanted.fps > 0) {
        chosen.fps = wanted.fps;
    } else if (!chosen.frame_rates.empty()) {
        chosen.fps = *std::max_element(chosen.frame_rates.begin(), chosen.frame_rates.end());
    }
    return chosen;
}

Result<StreamFormat> Camera::configure(const StreamConfig& config) {
    if (state_ == State::kStreaming) return fail(ErrorCode::kUsage, id_ + ": cannot configure while streaming");
    CL_TRY(active_, doConfigure(config));
    state_ = State::kConfigured;
    return active_;
}

Result<void> Camera::start() {
    if (state_ == State::kStreaming) return fail(ErrorCode::kUsage, id_ + ": already streaming");
    if (state_ != State::kConfigured) return fail(ErrorCode::kUsage, id_ + ": configure() before start()");
    if (allocator_ == nullptr || !on_frame_) {
        return fail(ErrorCode::kUsage, id_ + ": set a frame allocator and a frame callback before start()");
    }
    CL_TRY_VOID(doStart());
    state_ = State::kStreaming;
    return {};
}

void Camera::stop() noexcept {
    if (state_ != State::kStreaming) return;
    doStop();
    state_ = State::kConfigured;
}

Result<void> Camera::setControl(Control control, double value) {
    if (!std::isfinite(value)) {
        return fail(ErrorCode::kUsage, id_ + ": " + std::string(controlName(control)) + " must be a finite number");
    }
    return doSetControl(control, value);
}

Result<double> Camera::getControl(Control control) const { return doGetControl(control); }

Result<void> Camera::trigger() {
    if (state_ != State::kStreaming) return fail(ErrorCode::kUsage, id_ + ": trigger() needs a streaming camera");
    return doTrigger();
}

FrameHandle Camera::acquireFrame() noexcept {
    FrameHandle frame = allocator_ != nullptr ? allocator_->acquire() : FrameHandle();
    if (!frame) frames_without_slot_.fetch_add(1, std::memory_order_relaxed);
    return frame;
}

void Camera::emitFrame(FrameHandle frame) {
    if (on_frame_) on_frame_(std::move(frame));
}

void Camera::emitEvent(const CameraEvent& event) {
    if (on_event_) on_event_(event);
}

Result<void> Camera::doSetControl(Control control, double) {
    return fail(ErrorCode::kUnsupported, id_ + ": control " + std::string(controlName(control)) + " is not supported");
}

Result<double> Camera::doGetControl(Control control) const {
    return fail(ErrorCode::kUnsupported, id_ + ": control " + std::string(controlName(control)) + " is not supported");
}

Result<void> Camera::doTrigger() {
    return fail(ErrorCode::kUnsupported, id_ + ": software trigger is not supported");
}

}  // namespace commonlight::hal

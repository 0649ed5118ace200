#include "hal/libcamera/mapping.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <sstream>

namespace commonlight::hal::libcamera_backend {

void RequestControls::merge(const RequestControls& later) noexcept {
    if (later.exposure_time_us) exposure_time_us = later.exposure_time_us;
    if (later.analogue_gain) analogue_gain = later.analogue_gain;
    if (later.ae_enable) ae_enable = later.ae_enable;
    if (later.awb_enable) awb_enable = later.awb_enable;
    if (later.frame_duration_us) frame_duration_us = later.frame_duration_us;
}

namespace {

struct FormatPair {
    std::uint32_t fourcc;
    PixelFormat format;
};
constexpr FormatPair kFormats[] = {
    {kFourccR8, PixelFormat::kGray8},       {kFourccYuyv, PixelFormat::kYuyv},
    {kFourccNv12, PixelFormat::kNv12},      {kFourccMjpeg, PixelFormat::kMjpeg},
    {kFourccRgb888, PixelFormat::kBgr8},    {kFourccBgr888, PixelFormat::kRgb8},
    {kFourccAbgr8888, PixelFormat::kRgba8},
};

std::string formatList(const std::vector<StreamFormat>& offered) {
    std::string out;
    if (offered.empty()) out += " nothing we can use";
    for (const auto& f : offered) out += "\n  " + describe(f);
    return out;
}

}  // namespace

std::optional<PixelFormat> pixelFormatFromDevice(DeviceFormatId format) noexcept {
    if (format.modifier != 0) return std::nullopt;
    for (const auto& pair : kFormats) {
        if (pair.fourcc == format.fourcc) return pair.format;
    }
    return std::nullopt;
}

std::optional<DeviceFormatId> deviceFormatFor(PixelFormat format) noexcept {
    for (const auto& pair : kFormats) {
        if (pair.format == format) return DeviceFormatId{pair.fourcc, 0};
    }
    return std::nullopt;
}

std::string deviceFormatName(DeviceFormatId format) {
    std::string name;
    for (int i = 0; i < 4; ++i) {
        const char c = static_cast<char>((format.fourcc >> (8 * i)) & 0xff);
        name += (c >= 0x20 && c < 0x7f) ? c : '?';
    }
    while (!name.empty() && name.back() == ' ') name.pop_back();
    if (format.modifier != 0) {
        std::ostringstream mod;
        mod << "-0x" << std::hex << format.modifier;
        name += mod.str();
    }
    return name;
}

Result<StreamRole> parseStreamRole(std::string_view text, std::string_view uri) {
    if (text == "viewfinder") return StreamRole::kViewfinder;
    if (text == "video") return StreamRole::kVideoRecording;
    if (text == "still") return StreamRole::kStillCapture;
    if (text == "raw") return StreamRole::kRaw;
    return fail(ErrorCode::kUsage, std::string(uri) + ": role must be viewfinder, video, still or raw, not '" +
                                       std::string(text) + "'");
}

std::string_view streamRoleName(StreamRole role) noexcept {
    switch (role) {
        case StreamRole::kViewfinder: return "viewfinder";
        case StreamRole::kVideoRecording: return "video";
        case StreamRole::kStillCapture: return "still";
        case StreamRole::kRaw: return "raw";
    }
    return "unknown";
}

std::vector<StreamFormat> offeredFormats(const std::vector<DeviceFormat>& formats) {
    std::vector<StreamFormat> out;
    for (const auto& f : formats) {
        const auto format = pixelFormatFromDevice(f.format);
        if (!format || f.width <= 0 || f.height <= 0) continue;
        StreamFormat ours{*format, f.width, f.height, {}, 0.0};
        if (std::find(out.begin(), out.end(), ours) == out.end()) out.push_back(std::move(ours));
    }
    return out;
}

std::optional<std::pair<double, double>> fpsRange(const DeviceControls& controls) noexcept {
    if (!controls.frame_duration_us || controls.frame_duration_us->min <= 0 ||
        controls.frame_duration_us->max < controls.frame_duration_us->min) {
        return std::nullopt;
    }
    return std::pair{1e6 / controls.frame_duration_us->max, 1e6 / controls.frame_duration_us->min};
}

DeviceStreamConfig deviceConfigFor(const StreamFormat& format, unsigned buffer_count) {
    DeviceStreamConfig config;
    config.format = deviceFormatFor(format.format).value_or(DeviceFormatId{});
    config.width = format.width;
    config.height = format.height;
    config.buffer_count = buffer_count;
    return config;
}

Result<Acceptance> acceptConfiguration(const ConfigureResult& result, const StreamFormat& wanted,
                                       const std::vector<StreamFormat>& offered, const std::string& camera) {
    const std::string asked = describe(wanted);
    if (result.status == ValidationStatus::kInvalid) {
        return fail(ErrorCode::kUsage,
                    camera + ": libcamera rejected the configuration " + asked + "; the camera offers:" + formatList(offered));
    }
    const auto format = pixelFormatFromDevice(result.config.format);
    if (!format) {
        return fail(ErrorCode::kUsage, camera + ": libcamera adjusted " + asked + " to the pixel format " +
                                           deviceFormatName(result.config.format) +
                                           ", which commonlight cannot read; the camera offers:" + formatList(offered));
    }
    Acceptance out;
    out.format = wanted;
    out.format.format = *format;
    out.format.width = result.config.width;
    out.format.height = result.config.height;
    if (result.status == ValidationStatus::kAdjusted) {
        std::string changes;
        if (out.format.format != wanted.format) {
            changes += std::string(" format ") + std::string(pixelFormatName(wanted.format)) + " -> " +
                       std::string(pixelFormatName(out.format.format)) + ";";
        }
        if (out.format.width != wanted.width || out.format.height != wanted.height) {
            changes += " size " + std::to_string(wanted.width) + "x" + std::to_string(wanted.height) + " -> " +
                       std::to_string(out.format.width) + "x" + std::to_string(out.format.height) + ";";
        }
        if (changes.empty()) changes = " stride, buffer count or colour space only;";
        changes.pop_back();
        out.warning = camera + ": libcamera adjusted the configuration " + asked + ":" + changes;
    }
    return out;
}

std::int64_t frameDurationUs(double fps) noexcept {
    if (!(fps > 0)) return 0;
    return static_cast<std::int64_t>(std::llround(1e6 / fps));
}

double fpsForFrameDurationUs(std::int64_t duration_us) noexcept {
    return duration_us > 0 ? 1e6 / static_cast<double>(duration_us) : 0.0;
}

std::vector<ControlInfo> controlInfos(const DeviceControls& controls) {
    std::vector<ControlInfo> out;
    if (controls.exposure_time_us) {
        const auto& r = *controls.exposure_time_us;
        out.push_back({Control::kExposureUs, r.min, r.max, 1.0, r.default_value});
    }
    if (controls.analogue_gain) {
        const auto& r = *controls.analogue_gain;
        out.push_back({Control::kAnalogGain, r.min, r.max, 0.0, r.default_value});
    }
    if (controls.ae_enable) out.push_back({Control::kAutoExposure, 0, 1, 1, controls.ae_enable->default_value});
    if (controls.awb_enable) out.push_back({Control::kAutoWhiteBalance, 0, 1, 1, controls.awb_enable->default_value});
    if (const auto range = fpsRange(controls)) {
        const double default_fps = fpsForFrameDurationUs(static_cast<std::int64_t>(controls.frame_duration_us->default_value));
        out.push_back({Control::kFrameRate, range->first, range->second, 0.0, default_fps > 0 ? default_fps : range->second});
    }
    return out;
}

Result<void> setRequestControl(Control control, double value, const DeviceControls& controls, RequestControls& out,
                               const std::string& camera) {
    const std::string name(controlName(control));
    auto unsupported = [&] {
        return fail(ErrorCode::kUnsupported, camera + ": control " + name + " is not supported by this camera");
    };
    auto check = [&](double min, double max) -> Result<void> {
        if (value < min || value > max) {
            std::ostringstream msg;
            msg << camera << ": " << name << " " << value << " is outside the camera's range [" << min << ", " << max << "]";
            return fail(ErrorCode::kUsage, msg.str());
        }
        return {};
    };
    auto flag = [&]() -> Result<bool> {
        if (value != 0.0 && value != 1.0) {
            return fail(ErrorCode::kUsage, camera + ": " + name + " must be 0 (off) or 1 (on)");
        }
        return value != 0.0;
    };
    switch (control) {
        case Control::kExposureUs: {
            if (!controls.exposure_time_us) return unsupported();
            CL_TRY_VOID(check(controls.exposure_time_us->min, controls.exposure_time_us->max));
            out.exposure_time_us = static_cast<std::int32_t>(std::lround(value));
            return {};
        }
        case Control::kAnalogGain: {
            if (!controls.analogue_gain) return unsupported();
            CL_TRY_VOID(check(controls.analogue_gain->min, controls.analogue_gain->max));
            out.analogue_gain = static_cast<float>(value);
            return {};
        }
        case Control::kAutoExposure: {
            if (!controls.ae_enable) return unsupported();
            CL_TRY(out.ae_enable, flag());
            return {};
        }
        case Control::kAutoWhiteBalance: {
            if (!controls.awb_enable) return unsupported();
            CL_TRY(out.awb_enable, flag());
            return {};
        }
        case Control::kFrameRate: {
            const auto range = fpsRange(controls);
            if (!range) return unsupported();
            // 1% slack: 30 fps stays legal when the shortest duration is 33334 us.
            CL_TRY_VOID(check(range->first * 0.99, range->second * 1.01));
            const auto duration = std::clamp(frameDurationUs(value), static_cast<std::int64_t>(controls.frame_duration_us->min),
                                             static_cast<std::int64_t>(controls.frame_duration_us->max));
            out.frame_duration_us = duration;
            return {};
        }
    }
    return unsupported();
}

std::int64_t sensorTimestampToMonotonic(std::int64_t timestamp_ns, std::int64_t mono_now, std::int64_t boot_now) noexcept {
    const std::int64_t offset = boot_now - mono_now;  // time spent suspended since boot (>= 0)
    if (offset <= 0) return timestamp_ns;
    // Which clock's "now" is the timestamp nearer to? A frame is at most a few seconds old.
    const std::int64_t to_mono = mono_now - timestamp_ns;
    const std::int64_t to_boot = boot_now - timestamp_ns;
    if (std::llabs(to_boot) < std::llabs(to_mono)) return timestamp_ns - offset;
    return timestamp_ns;
}

FrameTiming frameTiming(const CompletedRequest& request, std::int64_t mono_now, std::int64_t boot_now) noexcept {
    if (request.sensor_timestamp_ns && *request.sensor_timestamp_ns > 0) {
        return {sensorTimestampToMonotonic(*request.sensor_timestamp_ns, mono_now, boot_now), TimestampSource::kSensor};
    }
    if (request.buffer_timestamp_ns > 0 &&
        request.buffer_timestamp_ns <= static_cast<std::uint64_t>(std::numeric_limits<std::int64_t>::max())) {
        return {static_cast<std::int64_t>(request.buffer_timestamp_ns), TimestampSource::kDriver};
    }
    return {mono_now, TimestampSource::kHost};
}

std::uint64_t SequenceUnwrapper::next(std::uint32_t sequence) noexcept {
    if (!started_) {
        started_ = true;
        last_ = sequence;
        return last_;
    }
    const auto low = static_cast<std::uint32_t>(last_);
    const auto delta = static_cast<std::uint32_t>(sequence - low);  // modulo 2^32
    if (delta < 0x80000000u) {
        last_ += delta;
        return last_;
    }
    // Older than the last one (reordered): place it before, without moving forward.
    return last_ - static_cast<std::uint32_t>(low - sequence);
}

namespace {

// Copies `rows` rows of `row_bytes` from a plane with `src_stride` into dst (packed). Returns
// false when the plane is too short.
bool copyRows(const PlaneData& plane, std::size_t offset, std::size_t src_stride, std::size_t row_bytes, int rows,
              std::uint8_t* dst) noexcept {
    if (rows <= 0) return true;
    const std::size_t available = std::min(plane.bytes_used, plane.length);
    const std::size_t needed = offset + src_stride * static_cast<std::size_t>(rows - 1) + row_bytes;
    if (plane.data == nullptr || needed > available) return false;
    for (int y = 0; y < rows; ++y) {
        std::memcpy(dst + row_bytes * static_cast<std::size_t>(y), plane.data + offset + src_stride * static_cast<std::size_t>(y),
                    row_bytes);
    }
    return true;
}

}  // namespace

FrameStatus copyFrame(const CompletedRequest& request, const StreamFormat& format, const DeviceStreamConfig& config,
                      Image& image) {
    if (request.plane_count == 0) return FrameStatus::kIncomplete;
    const PlaneData& first = request.planes[0];
    if (format.format == PixelFormat::kMjpeg) {
        const std::size_t bytes = std::min(first.bytes_used, first.length);
        const std::size_t capacity = image.capacity();
        const std::size_t copied = capacity > 0 ? std::min(bytes, capacity) : bytes;
        image.reshapeCompressed(format.width, format.height, copied);
        if (copied > 0 && first.data != nullptr) std::memcpy(image.data(), first.data, copied);
        if (request.status == CompletedRequest::Status::kError) return FrameStatus::kCorrupt;
        return copied < bytes || bytes == 0 ? FrameStatus::kIncomplete : FrameStatus::kOk;
    }
    image.reshape(format.format, format.width, format.height);
    const std::size_t row_bytes = image.stride();
    const std::size_t src_stride = std::max<std::size_t>(config.stride, row_bytes);
    bool complete = true;
    if (format.format == PixelFormat::kNv12) {
        const int uv_rows = format.height / 2;
        std::uint8_t* uv_dst = image.data() + row_bytes * static_cast<std::size_t>(format.height);
        complete = copyRows(first, 0, src_stride, row_bytes, format.height, image.data());
        if (request.plane_count >= 2) {
            complete = copyRows(request.planes[1], 0, src_stride, row_bytes, uv_rows, uv_dst) && complete;
        } else {
            // One plane holding both: UV follows the Y rows.
            complete = copyRows(first, src_stride * static_cast<std::size_t>(format.height), src_stride, row_bytes, uv_rows,
                                uv_dst) && complete;
        }
    } else {
        complete = copyRows(first, 0, src_stride, row_bytes, format.height, image.data());
    }
    if (request.status == CompletedRequest::Status::kError) return FrameStatus::kCorrupt;
    return complete ? FrameStatus::kOk : FrameStatus::kIncomplete;
}

}  // namespace commonlight::hal::libcamera_backend

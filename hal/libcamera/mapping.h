// Pure translation between commonlight's camera types and libcamera's (as the plain data of
// hal/libcamera/device.h): pixel formats, stream roles, configuration validation, controls,
// timestamps, sequence numbers and the pixel copy out of a completed buffer. No libcamera
// header is needed: everything here is unit-tested (tests/hal/libcamera_mapping_test.cpp).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "core/frame.h"
#include "core/image.h"
#include "core/result.h"
#include "hal/camera.h"
#include "hal/libcamera/device.h"

namespace commonlight::hal::libcamera_backend {

// DRM fourcc codes (libcamera/formats.h spells its PixelFormats with them).
constexpr std::uint32_t fourcc(char a, char b, char c, char d) noexcept {
    return static_cast<std::uint32_t>(static_cast<unsigned char>(a)) |
           static_cast<std::uint32_t>(static_cast<unsigned char>(b)) << 8 |
           static_cast<std::uint32_t>(static_cast<unsigned char>(c)) << 16 |
           static_cast<std::uint32_t>(static_cast<unsigned char>(d)) << 24;
}
inline constexpr std::uint32_t kFourccR8 = fourcc('R', '8', ' ', ' ');        // formats::R8
inline constexpr std::uint32_t kFourccYuyv = fourcc('Y', 'U', 'Y', 'V');      // formats::YUYV
inline constexpr std::uint32_t kFourccNv12 = fourcc('N', 'V', '1', '2');      // formats::NV12
inline constexpr std::uint32_t kFourccMjpeg = fourcc('M', 'J', 'P', 'G');     // formats::MJPEG
// DRM_FORMAT_RGB888 is "[23:0] R:G:B little endian": B, G, R bytes in memory.
inline constexpr std::uint32_t kFourccRgb888 = fourcc('R', 'G', '2', '4');    // formats::RGB888
// DRM_FORMAT_BGR888 is "[23:0] B:G:R little endian": R, G, B bytes in memory.
inline constexpr std::uint32_t kFourccBgr888 = fourcc('B', 'G', '2', '4');    // formats::BGR888
// DRM_FORMAT_ABGR8888 is "[31:0] A:B:G:R little endian": R, G, B, A bytes in memory.
inline constexpr std::uint32_t kFourccAbgr8888 = fourcc('A', 'B', '2', '4');  // formats::ABGR8888

std::optional<PixelFormat> pixelFormatFromDevice(DeviceFormatId format) noexcept;
std::optional<DeviceFormatId> deviceFormatFor(PixelFormat format) noexcept;
// "YUYV", "RG24", "MJPG" (the fourcc's characters, as libcamera prints them).
std::string deviceFormatName(DeviceFormatId format);

// URI option `role`: viewfinder (default), video, still, raw.
Result<StreamRole> parseStreamRole(std::string_view text, std::string_view uri);
std::string_view streamRoleName(StreamRole role) noexcept;

// What the camera offers for a role, in our terms: formats we cannot represent are left out,
// duplicates removed. Frame rates are not per format in libcamera (FrameDurationLimits is one
// range for the camera), so frame_rates stays empty ("any") and fpsRange() bounds the rate.
std::vector<StreamFormat> offeredFormats(const std::vector<DeviceFormat>& formats);
// Frames per second the FrameDurationLimits range allows, as {min, max}; nullopt without it.
std::optional<std::pair<double, double>> fpsRange(const DeviceControls& controls) noexcept;

// The request for Device::configure() from a negotiated format.
DeviceStreamConfig deviceConfigFor(const StreamFormat& format, unsigned buffer_count);

// CameraConfiguration::validate()'s verdict on `wanted`: kValid -> the format; kAdjusted -> the
// adjusted format (in `warning`, what libcamera changed); kInvalid, or an adjustment to a format
// we cannot represent -> kUsage listing what the camera offers.
struct Acceptance {
    StreamFormat format;
    std::string warning;  // empty unless adjusted
};
Result<Acceptance> acceptConfiguration(const ConfigureResult& result, const StreamFormat& wanted,
                                       const std::vector<StreamFormat>& offered, const std::string& camera);

// Frame rate <-> frame duration (microseconds, as FrameDurationLimits counts).
std::int64_t frameDurationUs(double fps) noexcept;
double fpsForFrameDurationUs(std::int64_t duration_us) noexcept;

// Our controls the camera has, with their ranges (frame rate from FrameDurationLimits).
std::vector<ControlInfo> controlInfos(const DeviceControls& controls);
// Puts `value` of `control` into `out`. kUnsupported naming the control and camera when the
// camera lacks it; kUsage naming the range when the value is outside it.
Result<void> setRequestControl(Control control, double value, const DeviceControls& controls,
                               RequestControls& out, const std::string& camera);

// SensorTimestamp is documented as CLOCK_BOOTTIME ("since the system boot time"), but pipeline
// handlers fill it from V4L2 buffer times, which are CLOCK_MONOTONIC. The two clocks differ by
// the time the machine spent suspended; when that difference is large enough to tell them
// apart, a timestamp nearer the BOOTTIME clock is shifted onto CLOCK_MONOTONIC. `mono_now` and
// `boot_now` are the two clocks read together, when the frame arrived.
std::int64_t sensorTimestampToMonotonic(std::int64_t timestamp_ns, std::int64_t mono_now,
                                        std::int64_t boot_now) noexcept;

struct FrameTiming {
    std::int64_t timestamp_ns = 0;
    TimestampSource source = TimestampSource::kUnknown;
};
// SensorTimestamp (start of exposure) when the request carries it -> kSensor; otherwise the
// buffer's timestamp (the V4L2 buffer time, CLOCK_MONOTONIC) -> kDriver; otherwise the arrival
// time -> kHost.
FrameTiming frameTiming(const CompletedRequest& request, std::int64_t mono_now, std::int64_t boot_now) noexcept;

// Extends libcamera's 32-bit frame sequence to 64 bits across wrap-around.
class SequenceUnwrapper {
public:
    std::uint64_t next(std::uint32_t sequence) noexcept;
    void reset() noexcept { started_ = false; }

private:
    bool started_ = false;
    std::uint64_t last_ = 0;
};

// Copies the pixels of a completed buffer into `image` (which keeps its capacity: a pool slot
// sized for the format does not allocate). `config` gives the device's stride. Returns kOk,
// kIncomplete when the buffer holds fewer bytes than the format needs (or, for MJPEG, more
// than the slot holds), kCorrupt for a buffer libcamera marked as failed.
FrameStatus copyFrame(const CompletedRequest& request, const StreamFormat& format,
                      const DeviceStreamConfig& config, Image& image);

}  // namespace commonlight::hal::libcamera_backend

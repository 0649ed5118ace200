// The seam between the libcamera backend and libcamera itself.
//
// LibcameraCamera (libcamera_camera.h) holds the state machine, the format/control mapping and
// the frame hand-over; it talks to one libcamera camera only through the abstract Device below,
// whose types are plain data (no libcamera header is needed to include this file). The real
// implementation (libcamera_device.cpp) is a thin layer over libcamera::Camera; tests/hal
// drives LibcameraCamera against a fake Device, since no machine we test on has a camera.
//
// Threads: every Device function is called from the control thread, except queue(), which the
// completion handler also calls from libcamera's thread to requeue a request. The completion
// and disconnect handlers run on libcamera's thread (or, for requests cancelled by stop(),
// inside stop() on the caller's thread).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "core/result.h"

namespace commonlight::hal::libcamera_backend {

// libcamera::StreamRole, which decides what generateConfiguration() proposes.
enum class StreamRole { kViewfinder, kVideoRecording, kStillCapture, kRaw };

// A libcamera pixel format: a DRM fourcc and its modifier (0 for every format we use).
struct DeviceFormatId {
    std::uint32_t fourcc = 0;
    std::uint64_t modifier = 0;
    bool operator==(const DeviceFormatId&) const = default;
};

// One pixel format at one size as the camera offers it for a role (StreamFormats).
struct DeviceFormat {
    DeviceFormatId format;
    int width = 0;
    int height = 0;
};

// A numeric libcamera control as ControlInfo describes it (bools: 0/1).
struct DeviceRange {
    double min = 0.0;
    double max = 0.0;
    double default_value = 0.0;
};

// The controls of Camera::controls() that we use; absent = the camera lacks it.
struct DeviceControls {
    std::optional<DeviceRange> exposure_time_us;     // controls::ExposureTime (int32, us)
    std::optional<DeviceRange> analogue_gain;        // controls::AnalogueGain (float)
    std::optional<DeviceRange> ae_enable;            // controls::AeEnable (or the exposure/gain modes)
    std::optional<DeviceRange> awb_enable;           // controls::AwbEnable
    std::optional<DeviceRange> frame_duration_us;    // controls::FrameDurationLimits (int64[2], us)
};

// One StreamConfiguration: what we ask for, and what validate() made of it.
struct DeviceStreamConfig {
    DeviceFormatId format;
    int width = 0;
    int height = 0;
    unsigned stride = 0;        // bytes per row (0 for compressed formats), set by validate()
    unsigned frame_size = 0;    // bytes per frame, set by validate()
    unsigned buffer_count = 0;  // 0: the camera's proposal
};

// CameraConfiguration::Status.
enum class ValidationStatus { kValid, kAdjusted, kInvalid };

struct ConfigureResult {
    ValidationStatus status = ValidationStatus::kInvalid;
    DeviceStreamConfig config;  // after validation (what is configured, unless kInvalid)
};

// Controls to put on a request (unset ones are left alone).
struct RequestControls {
    std::optional<std::int32_t> exposure_time_us;
    std::optional<float> analogue_gain;
    std::optional<bool> ae_enable;
    std::optional<bool> awb_enable;
    std::optional<std::int64_t> frame_duration_us;  // FrameDurationLimits {d, d}

    bool empty() const noexcept {
        return !exposure_time_us && !analogue_gain && !ae_enable && !awb_enable && !frame_duration_us;
    }
    // Later values win.
    void merge(const RequestControls& later) noexcept;
};

// One plane of a completed buffer, mapped once at start.
struct PlaneData {
    const std::uint8_t* data = nullptr;
    std::size_t bytes_used = 0;  // FrameMetadata::Plane::bytesused
    std::size_t length = 0;      // mapped length of the plane
};

// A completed request as plain data. Only valid during the completion handler.
struct CompletedRequest {
    enum class Status { kOk, kError, kCancelled };
    unsigned index = 0;            // which request (0..buffers-1)
    Status status = Status::kOk;   // Request cancelled, or FrameMetadata FrameError
    std::uint32_t sequence = 0;    // FrameMetadata::sequence (the device's frame counter)
    std::uint64_t buffer_timestamp_ns = 0;  // FrameMetadata::timestamp
    std::optional<std::int64_t> sensor_timestamp_ns;  // metadata SensorTimestamp
    std::optional<std::int32_t> exposure_time_us;     // metadata ExposureTime
    std::optional<float> analogue_gain;               // metadata AnalogueGain
    std::optional<std::int64_t> frame_duration_us;    // metadata FrameDuration
    std::array<PlaneData, 3> planes{};
    unsigned plane_count = 0;
};

class Device {
public:
    using CompletionHandler = std::function<void(const CompletedRequest&)>;
    using DisconnectHandler = std::function<void()>;

    virtual ~Device() = default;

    // Camera::id(), and a human-readable name (the Model property when there is one).
    virtual const std::string& cameraId() const = 0;
    virtual const std::string& model() const = 0;

    // What generateConfiguration({role}) offers (discrete sizes, or the ends of a size range).
    virtual std::vector<DeviceFormat> formats(StreamRole role) const = 0;
    virtual DeviceControls controls() const = 0;

    // generateConfiguration({role}), the wanted fields set, validate(); when not kInvalid,
    // Camera::configure() with the validated configuration. kDevice when libcamera fails.
    virtual Result<ConfigureResult> configure(StreamRole role, const DeviceStreamConfig& wanted) = 0;

    // Allocates the buffers of the configured stream (FrameBufferAllocator), maps them and
    // creates one request per buffer. Returns the number of requests. Configured only.
    virtual Result<unsigned> allocate() = 0;
    // Frees what allocate() made (not streaming).
    virtual void release() noexcept = 0;

    virtual void setHandlers(CompletionHandler on_complete, DisconnectHandler on_disconnect) = 0;

    // Camera::start() with `initial` controls; queues no request.
    virtual Result<void> start(const RequestControls& initial) = 0;
    // Reuses request `index` with its buffer, sets `controls` on it and queues it.
    virtual Result<void> queue(unsigned index, const RequestControls& controls) = 0;
    // Camera::stop(): pending requests complete as kCancelled before it returns.
    virtual void stop() noexcept = 0;
};

}  // namespace commonlight::hal::libcamera_backend

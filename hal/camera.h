// The camera interface every backend implements (V4L2, libcamera, Aravis, and the mocks).
//
// Public methods are non-virtual: they check the state machine and call the private do*()
// functions a backend implements, so no backend can skip the checks (Magnum's pattern).
//
//   open (registry) --> Opened --configure()--> Configured --start()--> Streaming
//                                                    ^                      |
//                                                    +-------stop()---------+
//
// Threads: configure/start/stop/controls are called from one control thread. Frames and events
// are delivered on the camera's own thread through the callbacks, which must not block.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "core/camera_model.h"
#include "core/frame.h"
#include "core/image.h"
#include "core/result.h"

namespace commonlight::hal {

enum class Control {
    kExposureUs,        // exposure time, microseconds
    kAnalogGain,        // linear gain (1 = unity)
    kAutoExposure,      // 1 on, 0 off
    kAutoWhiteBalance,  // 1 on, 0 off
    kFrameRate,         // frames per second
};
std::string_view controlName(Control control) noexcept;

struct ControlInfo {
    Control id = Control::kExposureUs;
    double min = 0.0;
    double max = 0.0;
    double step = 0.0;  // 0: continuous
    double default_value = 0.0;
};

// One pixel format at one size, with the frame rates the device offers for it (empty: any).
struct StreamFormat {
    PixelFormat format = PixelFormat::kInvalid;
    int width = 0;
    int height = 0;
    std::vector<double> frame_rates;
    double fps = 0.0;  // in a negotiated format: the rate chosen; 0 when the device sets none

    bool operator==(const StreamFormat&) const = default;
};
std::string describe(const StreamFormat& format);

// What a user asked for; 0 / kInvalid fields mean "whatever the device prefers".
struct StreamConfig {
    PixelFormat format = PixelFormat::kInvalid;
    int width = 0;
    int height = 0;
    double fps = 0.0;
};

// Picks the offered format that satisfies every set field of `wanted` (the largest when size is
// free, the first offered format otherwise). Fails with kUnsupported listing what the device
// offers, naming `device`.
Result<StreamFormat> negotiate(const std::vector<StreamFormat>& offered, const StreamConfig& wanted,
                               const std::string& device);

struct CameraInfo {
    std::string uri;      // what to pass to --camera
    std::string name;     // human-readable model name
    std::string backend;  // URI scheme
    std::vector<StreamFormat> formats;
};

struct CameraEvent {
    enum class Type {
        kEndOfStream,  // a recording or file ended
        kDeviceError,  // the device failed or disconnected; `error` names it
    };
    Type type = Type::kEndOfStream;
    Error error;
};

class Camera {
public:
    enum class State { kOpened, kConfigured, kStreaming };

    using FrameCallback = std::function<void(FrameHandle)>;
    using EventCallback = std::function<void(const CameraEvent&)>;

    explicit Camera(std::string id) : id_(std::move(id)) {}
    virtual ~Camera() = default;
    Camera(const Camera&) = delete;
    Camera& operator=(const Camera&) = delete;

    // The URI or device path that names this camera in messages.
    const std::string& id() const noexcept { return id_; }
    State state() const noexcept { return state_; }

    std::vector<StreamFormat> formats() const { return doFormats(); }
    // Opened or Configured -> Configured. Returns the negotiated format.
    Result<StreamFormat> configure(const StreamConfig& config);
    const StreamFormat& activeFormat() const noexcept { return active_; }

    // Where frame slots come from (borrowed; must outlive streaming). Set before start().
    void setFrameAllocator(FrameAllocator* allocator) noexcept { allocator_ = allocator; }
    // Called on the camera's own thread for every frame. Must not block: hand the frame on.
    void setFrameCallback(FrameCallback on_frame) { on_frame_ = std::move(on_frame); }
    // Called on the camera's own thread when the stream ends or fails; no frame follows it.
    // Must not block. Not called for a stop() the user asked for.
    void setEventCallback(EventCallback on_event) { on_event_ = std::move(on_event); }

    // Configured -> Streaming. Needs a configured format, an allocator and a frame callback.
    Result<void> start();
    // Streaming -> Configured. Joins the camera thread: no callback runs after it returns.
    // Never fails; does nothing when not streaming.
    void stop() noexcept;

    std::vector<ControlInfo> controls() const { return doControls(); }
    Result<void> setControl(Control control, double value);
    Result<double> getControl(Control control) const;

    // Emits one frame in software-trigger mode (replay:?rate=step). kUnsupported otherwise.
    Result<void> trigger();

    // The response the camera applies to its values, as core/response.h parses it ("srgb",
    // "linear", "gamma:G", or a response file): what lighting and tracking linearise with unless
    // the user says otherwise (--response). Backends report what the device tells (Aravis: the
    // GenICam GammaEnable/Gamma features; replay: sensor.yaml); the default is "srgb", what a
    // webcam's ISP applies.
    std::string responseSpec() const { return doResponseSpec(); }

    // The camera's intrinsics and lens distortion when the source knows them (replay: the
    // recording's sensor.yaml; sim: the simulated lens), so `live` needs no --calib for them.
    // Hardware backends do not know their lens: nullopt.
    std::optional<CameraModel> calibration() const { return doCalibration(); }

    // Frames the backend had to discard because no pool slot was free (lost in our pipeline,
    // not at the device).
    std::uint64_t framesWithoutSlot() const noexcept { return frames_without_slot_.load(std::memory_order_relaxed); }

protected:
    // For backends, on the camera thread. Returns an empty handle (and counts it) when the pool
    // is exhausted.
    FrameHandle acquireFrame() noexcept;
    void emitFrame(FrameHandle frame);
    void emitEvent(const CameraEvent& event);

private:
    virtual std::vector<StreamFormat> doFormats() const = 0;
    virtual Result<StreamFormat> doConfigure(const StreamConfig& config) = 0;
    virtual Result<void> doStart() = 0;
    virtual void doStop() noexcept = 0;
    virtual std::vector<ControlInfo> doControls() const { return {}; }
    virtual Result<void> doSetControl(Control control, double value);
    virtual Result<double> doGetControl(Control control) const;
    virtual Result<void> doTrigger();
    virtual std::string doResponseSpec() const { return "srgb"; }
    virtual std::optional<CameraModel> doCalibration() const { return std::nullopt; }

    std::string id_;
    State state_ = State::kOpened;
    StreamFormat active_;
    FrameAllocator* allocator_ = nullptr;
    FrameCallback on_frame_;
    EventCallback on_event_;
    std::atomic<std::uint64_t> frames_without_slot_{0};
};

}  // namespace commonlight::hal

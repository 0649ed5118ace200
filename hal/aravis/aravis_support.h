// The parts of the Aravis backend that need no camera and no network, so they are unit-tested
// (tests/hal/aravis_support_test.cpp): pixel-format mapping, the Mono12 copy, the URI options,
// the device frame-id unwrapping and the device-to-host clock mapping.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "core/image.h"
#include "core/result.h"
#include "hal/camera_uri.h"

namespace commonlight::hal::aravis {

// GenICam PFNC codes (ArvPixelFormat values) of the formats this backend streams.
inline constexpr std::uint32_t kPfncMono8 = 0x01080001;
inline constexpr std::uint32_t kPfncMono12 = 0x01100005;  // 12 bits in a 16-bit little-endian container
inline constexpr std::uint32_t kPfncMono16 = 0x01100007;
inline constexpr std::uint32_t kPfncRgb8 = 0x02180014;    // "RGB8" / "RGB8Packed"
inline constexpr std::uint32_t kPfncBayerGr8 = 0x01080008;
inline constexpr std::uint32_t kPfncBayerRg8 = 0x01080009;
inline constexpr std::uint32_t kPfncBayerGb8 = 0x0108000A;
inline constexpr std::uint32_t kPfncBayerBg8 = 0x0108000B;

// Our pixel format for a device format; nullopt for one we do not stream.
std::optional<PixelFormat> fromPfnc(std::uint32_t pfnc) noexcept;
// The device formats that deliver `format`, preferred first (gray16: Mono16 then Mono12).
std::vector<std::uint32_t> toPfnc(PixelFormat format);

// Copies one device image (rows packed) into `out` (already shaped as kGray16 width x height):
// Mono12 values are shifted to the high bits (core/image.h: kGray16 uses the high bits of the
// range), Mono16 is copied as is. Both little-endian on the wire (GigE Vision pixel data).
void copyGray16(const std::uint8_t* src, std::size_t src_bytes, std::uint32_t pfnc, int width, int height,
                std::uint8_t* out, std::size_t out_stride) noexcept;

// URI options of aravis: (docs/cameras-aravis.md).
struct AravisOptions {
    int x = 0;                               // region of interest offset
    int y = 0;
    bool packet_resend = true;
    std::optional<int> packet_timeout_ms;    // unset: Aravis's default (20 ms)
    std::optional<int> frame_retention_ms;   // unset: Aravis's default (100 ms)
    int packet_size = 0;                     // bytes; 0: negotiated with the device
    int buffers = 8;                         // stream buffers allocated at start
    int timeout_ms = 2000;                   // no frame for this long: device error

    static Result<AravisOptions> fromUri(const CameraUri& uri);
};
// The option names above, for hal::Backend::options.
std::vector<std::string> aravisOptionNames();

// GigE Vision block ids are 16 bits and skip 0 (65535 is followed by 1); USB3 Vision and the
// GVSP extended ids are 64 bits. Turns the device's ids into a counter that keeps increasing
// across wraps, so a gap means frames lost at the device.
class FrameIdUnwrapper {
public:
    std::uint64_t unwrap(std::uint64_t frame_id) noexcept;
    void reset() noexcept { started_ = false; }

private:
    bool started_ = false;
    std::uint64_t last_raw_ = 0;
    std::uint64_t base_ = 0;
};

// Maps device timestamps (ns in the device's own epoch) to CLOCK_MONOTONIC.
//
// The offset host - device is estimated from arrivals: every frame gives a sample
// arrival_ns - device_ns, which is the true offset plus that frame's transport delay (>= 0).
// The minimum over the last `window` samples is the offset with the least delay; a sliding
// window follows a slow drift between the clocks. A device clock that jumps backwards (reset,
// resynchronised) makes samples grow by far more than any delay: after `confirm` consecutive
// samples more than `jump_ns` above the estimate, the window restarts from them. A forward jump
// lowers the samples and is taken by the minimum at once.
class DeviceClockMapper {
public:
    explicit DeviceClockMapper(std::size_t window = 64, std::int64_t jump_ns = 50'000'000, int confirm = 3);

    struct Mapped {
        std::int64_t host_ns = 0;
        bool rebased = false;  // this frame confirmed a jump: the window restarted
    };
    // The host time of a frame whose device timestamp is `device_ns` and which arrived at
    // `arrival_ns` (CLOCK_MONOTONIC). Never later than the arrival. A frame far later than the
    // estimate is mapped with the current offset until the jump is confirmed (a late frame is
    // far more common than a clock jump). No allocation.
    Mapped toHost(std::int64_t device_ns, std::int64_t arrival_ns) noexcept;
    void reset() noexcept;
    std::int64_t offsetNs() const noexcept { return offset_; }
    std::uint64_t rebases() const noexcept { return rebases_; }

private:
    std::vector<std::int64_t> samples_;  // ring buffer, allocated once
    std::size_t next_ = 0;
    std::size_t count_ = 0;
    std::int64_t jump_ns_;
    int confirm_;
    int above_ = 0;  // consecutive samples beyond jump_ns_ above the estimate
    std::int64_t above_min_ = 0;  // their minimum
    std::int64_t offset_ = 0;
    std::uint64_t rebases_ = 0;
};

// The response spec (core/response.h) of a camera whose GenICam Gamma feature is `gamma`: SFNC's
// Gamma encodes out = in^Gamma (values in [0, 1]), so decoding is in = out^(1/Gamma): "gamma:<1/Gamma>"
// (clamped to [0.2, 5]); 1 (or within 1e-3 of it) is "linear".
std::string gammaResponseSpec(double gamma);

}  // namespace commonlight::hal::aravis

#include "hal/aravis/aravis_support.h"

#include <cstdio>
#include <cmath>
#include <algorithm>
#include <cstring>
#include <limits>

namespace commonlight::hal::aravis {

std::optional<PixelFormat> fromPfnc(std::uint32_t pfnc) noexcept {
    switch (pfnc) {
        case kPfncMono8: return PixelFormat::kGray8;
        case kPfncMono12:
        case kPfncMono16: return PixelFormat::kGray16;
        case kPfncRgb8: return PixelFormat::kRgb8;
        case kPfncBayerRg8: return PixelFormat::kBayerRggb8;
        case kPfncBayerGr8: return PixelFormat::kBayerGrbg8;
        case kPfncBayerGb8: return PixelFormat::kBayerGbrg8;
        case kPfncBayerBg8: return PixelFormat::kBayerBggr8;
        default: return std::nullopt;
    }
}

std::vector<std::uint32_t> toPfnc(PixelFormat format) {
    switch (format) {
        case PixelFormat::kGray8: return {kPfncMono8};
        case PixelFormat::kGray16: return {kPfncMono16, kPfncMono12};
        case PixelFormat::kRgb8: return {kPfncRgb8};
        case PixelFormat::kBayerRggb8: return {kPfncBayerRg8};
        case PixelFormat::kBayerGrbg8: return {kPfncBayerGr8};
        case PixelFormat::kBayerGbrg8: return {kPfncBayerGb8};
        case PixelFormat::kBayerBggr8: return {kPfncBayerBg8};
        default: return {};
    }
}

void copyGray16(const std::uint8_t* src, std::size_t src_bytes, std::uint32_t pfnc, int width, int height,
                std::uint8_t* out, std::size_t out_stride) noexcept {
    const std::size_t row_bytes = static_cast<std::size_t>(width) * 2;
    const int shift = pfnc == kPfncMono12 ? 4 : 0;
    for (int y = 0; y < height; ++y) {
        auto* dst = reinterpret_cast<std::uint16_t*>(out + static_cast<std::size_t>(y) * out_stride);
        const std::size_t row_start = static_cast<std::size_t>(y) * row_bytes;
        for (int x = 0; x < width; ++x) {
            const std::size_t at = row_start + static_cast<std::size_t>(x) * 2;
            if (at + 1 >= src_bytes) {
                dst[x] = 0;  // a short (incomplete) buffer: the missing pixels are black
                continue;
            }
            const auto value = static_cast<std::uint16_t>(src[at] | (src[at + 1] << 8));
            // Mono12 has 12 significant bits; mask stray high bits before moving them up.
            dst[x] = shift != 0 ? static_cast<std::uint16_t>((value & 0x0FFF) << shift) : value;
        }
    }
}

namespace {

Result<std::optional<int>> boundedInt(const CameraUri& uri, std::string_view key, long long min, long long max) {
    CL_TRY(const auto value, uri.integer(key));
    if (!value) return std::optional<int>();
    if (*value < min || *value > max) {
        return fail(ErrorCode::kUsage, "camera URI '" + uri.text + "': " + std::string(key) + " must be in " +
                                           std::to_string(min) + ".." + std::to_string(max) + ", got " +
                                           std::to_string(*value));
    }
    return std::optional<int>(static_cast<int>(*value));
}

}  // namespace

std::vector<std::string> aravisOptionNames() {
    return {"x", "y", "packet_resend", "packet_timeout_ms", "frame_retention_ms", "packet_size", "buffers", "timeout_ms"};
}

Result<AravisOptions> AravisOptions::fromUri(const CameraUri& uri) {
    AravisOptions o;
    CL_TRY(const auto x, boundedInt(uri, "x", 0, 1 << 20));
    CL_TRY(const auto y, boundedInt(uri, "y", 0, 1 << 20));
    CL_TRY(const auto resend, uri.flag("packet_resend"));
    CL_TRY(o.packet_timeout_ms, boundedInt(uri, "packet_timeout_ms", 1, 10'000));
    CL_TRY(o.frame_retention_ms, boundedInt(uri, "frame_retention_ms", 1, 60'000));
    CL_TRY(const auto packet_size, boundedInt(uri, "packet_size", 0, 65'535));
    CL_TRY(const auto buffers, boundedInt(uri, "buffers", 2, 256));
    CL_TRY(const auto timeout, boundedInt(uri, "timeout_ms", 10, 600'000));
    if (x) o.x = *x;
    if (y) o.y = *y;
    if (resend) o.packet_resend = *resend;
    if (packet_size) {
        if (*packet_size != 0 && *packet_size < 576) {
            return fail(ErrorCode::kUsage, "camera URI '" + uri.text +
                                               "': packet_size must be 0 (negotiate) or at least 576 bytes, got " +
                                               std::to_string(*packet_size));
        }
        o.packet_size = *packet_size;
    }
    if (buffers) o.buffers = *buffers;
    if (timeout) o.timeout_ms = *timeout;
    return o;
}

std::uint64_t FrameIdUnwrapper::unwrap(std::uint64_t frame_id) noexcept {
    constexpr std::uint64_t kGvspMax = 0xFFFF;
    constexpr std::uint64_t kWrapMargin = 0x1000;  // a wrap is a jump from near the top to near the bottom
    if (started_ && frame_id < last_raw_ && last_raw_ <= kGvspMax && last_raw_ > kGvspMax - kWrapMargin &&
        frame_id < kWrapMargin) {
        base_ += kGvspMax;  // 65535 -> 1: id 0 is skipped, so one period is 65535 ids
    } else if (started_ && frame_id < last_raw_) {
        // The device restarted its counter (a new acquisition, a reset): continue after the last.
        base_ = base_ + last_raw_ + 1 - frame_id;
    }
    started_ = true;
    last_raw_ = frame_id;
    return base_ + frame_id;
}

DeviceClockMapper::DeviceClockMapper(std::size_t window, std::int64_t jump_ns, int confirm)
    : samples_(std::max<std::size_t>(window, 1)), jump_ns_(jump_ns), confirm_(std::max(confirm, 1)) {}

void DeviceClockMapper::reset() noexcept {
    next_ = 0;
    count_ = 0;
    above_ = 0;
    offset_ = 0;
}

DeviceClockMapper::Mapped DeviceClockMapper::toHost(std::int64_t device_ns, std::int64_t arrival_ns) noexcept {
    const std::int64_t sample = arrival_ns - device_ns;
    if (count_ > 0 && sample > offset_ + jump_ns_) {
        // Far later than any delay seen: the device clock went back, or a stall. Wait for
        // `confirm_` such samples in a row before believing it.
        above_min_ = above_ == 0 ? sample : std::min(above_min_, sample);
        // Until confirmed it is taken for a delay: the current offset still maps it (exact for
        // a late frame; for the first frames after a backward jump, early by the jump).
        if (++above_ < confirm_) return {std::min(device_ns + offset_, arrival_ns), false};
        count_ = 0;
        next_ = 0;
        ++rebases_;
        samples_[next_] = above_min_;
        next_ = 1 % samples_.size();
        count_ = 1;
        above_ = 0;
        offset_ = samples_[0];
        return {std::min(device_ns + offset_, arrival_ns), true};  // rebased
    }
    above_ = 0;
    if (count_ > 0 && sample < offset_ - jump_ns_) ++rebases_;  // forward jump: the minimum takes it
    samples_[next_] = sample;
    next_ = (next_ + 1) % samples_.size();
    count_ = std::min(count_ + 1, samples_.size());
    std::int64_t best = std::numeric_limits<std::int64_t>::max();
    for (std::size_t i = 0; i < count_; ++i) best = std::min(best, samples_[i]);
    offset_ = best;
    return {std::min(device_ns + offset_, arrival_ns), false};
}

std::string gammaResponseSpec(double gamma) {
    if (!(gamma > 0.0) || !std::isfinite(gamma) || std::abs(gamma - 1.0) < 1e-3) return "linear";
    char spec[32];
    std::snprintf(spec, sizeof spec, "gamma:%.4g", std::clamp(1.0 / gamma, 0.2, 5.0));
    return spec;
}

}  // namespace commonlight::hal::aravis

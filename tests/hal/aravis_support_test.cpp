// The Aravis backend's logic that needs no network: formats, the Mono12 copy, URI options, frame
// ids and the device-to-host clock mapping (with synthetic clocks).
#include "hal/aravis/aravis_support.h"

#include <gtest/gtest.h>

#include <cstring>
#include <cmath>
#include <random>

#include "hal/registry.h"
#include "hal/aravis/aravis_backend.h"

namespace commonlight::hal::aravis {
namespace {

TEST(AravisFormats, DeviceFormatsMapToOurs) {
    EXPECT_EQ(fromPfnc(kPfncMono8), PixelFormat::kGray8);
    EXPECT_EQ(fromPfnc(kPfncMono12), PixelFormat::kGray16);
    EXPECT_EQ(fromPfnc(kPfncMono16), PixelFormat::kGray16);
    EXPECT_EQ(fromPfnc(kPfncRgb8), PixelFormat::kRgb8);
    EXPECT_EQ(fromPfnc(kPfncBayerRg8), PixelFormat::kBayerRggb8);
    EXPECT_EQ(fromPfnc(kPfncBayerGr8), PixelFormat::kBayerGrbg8);
    EXPECT_EQ(fromPfnc(kPfncBayerGb8), PixelFormat::kBayerGbrg8);
    EXPECT_EQ(fromPfnc(kPfncBayerBg8), PixelFormat::kBayerBggr8);
    EXPECT_FALSE(fromPfnc(0x010C0006));  // Mono12Packed: not streamed
    EXPECT_FALSE(fromPfnc(0));
}

TEST(AravisFormats, OurFormatsMapBackPreferringFullDepth) {
    EXPECT_EQ(toPfnc(PixelFormat::kGray8), std::vector<std::uint32_t>{kPfncMono8});
    EXPECT_EQ(toPfnc(PixelFormat::kGray16), (std::vector<std::uint32_t>{kPfncMono16, kPfncMono12}));
    EXPECT_EQ(toPfnc(PixelFormat::kRgb8), std::vector<std::uint32_t>{kPfncRgb8});
    EXPECT_TRUE(toPfnc(PixelFormat::kMjpeg).empty());
    EXPECT_EQ(toPfnc(PixelFormat::kBayerGbrg8), std::vector<std::uint32_t>{kPfncBayerGb8});
    for (const auto f : {PixelFormat::kGray8, PixelFormat::kGray16, PixelFormat::kRgb8, PixelFormat::kBayerRggb8,
                         PixelFormat::kBayerGrbg8, PixelFormat::kBayerGbrg8, PixelFormat::kBayerBggr8}) {
        for (const auto pfnc : toPfnc(f)) EXPECT_EQ(fromPfnc(pfnc), f);
    }
}

TEST(AravisFormats, Mono12IsShiftedToTheHighBits) {
    // Little-endian 12-bit values 0x000, 0x001, 0xABC, 0xFFF (and a stray high nibble).
    const std::uint8_t wire[] = {0x00, 0x00, 0x01, 0x00, 0xBC, 0x0A, 0xFF, 0xFF};
    std::uint16_t out[4] = {};
    copyGray16(wire, sizeof(wire), kPfncMono12, 4, 1, reinterpret_cast<std::uint8_t*>(out), sizeof(out));
    EXPECT_EQ(out[0], 0x0000);
    EXPECT_EQ(out[1], 0x0010);
    EXPECT_EQ(out[2], 0xABC0);
    EXPECT_EQ(out[3], 0xFFF0);
}

TEST(AravisFormats, Mono16IsCopiedAsIsAndShortBuffersAreBlack) {
    const std::uint8_t wire[] = {0x34, 0x12, 0xFF, 0xFF, 0x01};  // the last pixel is cut short
    std::uint16_t out[6] = {7, 7, 7, 7, 7, 7};                    // 3x1 image, stride of 6 bytes, 2 rows
    copyGray16(wire, sizeof(wire), kPfncMono16, 3, 1, reinterpret_cast<std::uint8_t*>(out), 6);
    EXPECT_EQ(out[0], 0x1234);
    EXPECT_EQ(out[1], 0xFFFF);
    EXPECT_EQ(out[2], 0);
    EXPECT_EQ(out[3], 7) << "nothing written past the image";
}

CameraUri uri(std::string text) {
    auto parsed = parseCameraUri(text);
    EXPECT_TRUE(parsed) << text;
    return parsed ? *parsed : CameraUri{};
}

TEST(AravisOptions, DefaultsAndValues) {
    const auto defaults = AravisOptions::fromUri(uri("aravis:127.0.0.1"));
    ASSERT_TRUE(defaults) << defaults.error().message;
    EXPECT_TRUE(defaults->packet_resend);
    EXPECT_EQ(defaults->packet_size, 0);
    EXPECT_FALSE(defaults->packet_timeout_ms);
    EXPECT_EQ(defaults->x, 0);

    const auto set = AravisOptions::fromUri(
        uri("aravis:127.0.0.1?x=16&y=8&packet_resend=0&packet_timeout_ms=40&frame_retention_ms=300&packet_size=1500"
            "&buffers=12&timeout_ms=750"));
    ASSERT_TRUE(set) << set.error().message;
    EXPECT_EQ(set->x, 16);
    EXPECT_EQ(set->y, 8);
    EXPECT_FALSE(set->packet_resend);
    EXPECT_EQ(set->packet_timeout_ms, 40);
    EXPECT_EQ(set->frame_retention_ms, 300);
    EXPECT_EQ(set->packet_size, 1500);
    EXPECT_EQ(set->buffers, 12);
    EXPECT_EQ(set->timeout_ms, 750);
}

TEST(AravisOptions, BadValuesNameTheUriAndKey) {
    for (const char* text : {"aravis:cam?buffers=1", "aravis:cam?timeout_ms=abc", "aravis:cam?packet_size=100",
                             "aravis:cam?packet_resend=maybe", "aravis:cam?x=-4"}) {
        const auto o = AravisOptions::fromUri(uri(text));
        ASSERT_FALSE(o) << text;
        EXPECT_EQ(o.error().code, ErrorCode::kUsage);
        EXPECT_NE(o.error().message.find(text), std::string::npos) << o.error().message;
    }
}

TEST(AravisOptions, TheRegistryAcceptsThemAndRejectsOthers) {
    CameraRegistry registry;
    registerBackend(registry);
    EXPECT_TRUE(registry.parse("aravis:127.0.0.1?packet_resend=1&timeout_ms=500&width=320&exposure_us=100"));
    const auto bad = registry.parse("aravis:127.0.0.1?packet_rsend=1");
    ASSERT_FALSE(bad);
    EXPECT_NE(bad.error().message.find("packet_resend"), std::string::npos) << "lists what is accepted";
}

TEST(FrameIdUnwrapper, GvspIdsWrapFrom65535To1) {
    FrameIdUnwrapper u;
    EXPECT_EQ(u.unwrap(65533), 65533u);
    EXPECT_EQ(u.unwrap(65534), 65534u);
    EXPECT_EQ(u.unwrap(65535), 65535u);
    EXPECT_EQ(u.unwrap(1), 65536u) << "0 is skipped: no gap across the wrap";
    EXPECT_EQ(u.unwrap(2), 65537u);
    EXPECT_EQ(u.unwrap(5), 65540u) << "a real gap stays a gap";
}

TEST(FrameIdUnwrapper, WideIdsPassAndARestartContinues) {
    FrameIdUnwrapper u;
    EXPECT_EQ(u.unwrap(1'000'000), 1'000'000u);
    EXPECT_EQ(u.unwrap(1'000'001), 1'000'001u);
    EXPECT_EQ(u.unwrap(3), 1'000'002u) << "a counter reset does not go backwards";
    EXPECT_EQ(u.unwrap(4), 1'000'003u);
}

// A device clock at an offset from the host's, frames with a random transport delay.
TEST(DeviceClockMapper, FindsTheOffsetWithinTheSmallestDelay) {
    constexpr std::int64_t kOffset = -1'700'000'000'000'000'000;  // device epoch far from the host's
    std::mt19937 rng(4);
    std::uniform_int_distribution<std::int64_t> delay(200'000, 3'000'000);  // 0.2 .. 3 ms
    DeviceClockMapper mapper;
    std::int64_t worst_late = 0;
    for (int i = 0; i < 300; ++i) {
        const std::int64_t host_exposure = 5'000'000'000 + i * 33'333'333LL;
        const std::int64_t device = host_exposure - kOffset;
        const std::int64_t arrival = host_exposure + delay(rng);
        const auto m = mapper.toHost(device, arrival);
        EXPECT_FALSE(m.rebased);
        EXPECT_LE(m.host_ns, arrival);
        if (i >= 64) worst_late = std::max(worst_late, m.host_ns - host_exposure);
    }
    // Once the window is full, the estimate is the true time plus the least delay seen.
    EXPECT_GE(worst_late, 200'000);
    EXPECT_LT(worst_late, 400'000);
}

TEST(DeviceClockMapper, ABackwardJumpIsRebasedAfterConfirmation) {
    DeviceClockMapper mapper(64, 50'000'000, 3);
    const std::int64_t delay = 1'000'000;
    std::int64_t device_offset = 1'000'000'000'000;  // device = host + this
    for (int i = 0; i < 100; ++i) {
        const std::int64_t host = 1'000'000'000 + i * 10'000'000LL;
        const auto m = mapper.toHost(host + device_offset, host + delay);
        EXPECT_EQ(m.host_ns, host + delay) << i << ": the true time plus the least delay";
    }
    device_offset -= 5'000'000'000;  // the device clock is reset 5 s back
    for (int i = 100; i < 110; ++i) {
        const std::int64_t host = 1'000'000'000 + i * 10'000'000LL;
        const auto m = mapper.toHost(host + device_offset, host + delay);
        if (i < 102) {
            EXPECT_FALSE(m.rebased);
            EXPECT_EQ(m.host_ns, host + delay - 5'000'000'000) << "not yet confirmed: still the old offset";
        } else {
            EXPECT_EQ(m.rebased, i == 102);
            EXPECT_EQ(m.host_ns, host + delay) << i;
        }
    }
    EXPECT_EQ(mapper.rebases(), 1u);
}

TEST(DeviceClockMapper, AForwardJumpIsTakenAtOnceAndASingleLateFrameIsNot) {
    DeviceClockMapper mapper(64, 50'000'000, 3);
    std::int64_t device_offset = 0;
    for (int i = 0; i < 20; ++i) mapper.toHost(i * 10'000'000LL + device_offset, i * 10'000'000LL + 500'000);
    // One frame delayed by 200 ms (a stall in the network): not a clock jump.
    auto late = mapper.toHost(20 * 10'000'000LL, 20 * 10'000'000LL + 200'000'000);
    EXPECT_EQ(late.host_ns, 20 * 10'000'000LL + 500'000) << "a late frame keeps its device time";
    auto next = mapper.toHost(21 * 10'000'000LL, 21 * 10'000'000LL + 500'000);
    EXPECT_EQ(next.host_ns, 21 * 10'000'000LL + 500'000);
    device_offset = 7'000'000'000;  // the device clock steps 7 s forward
    for (int i = 22; i < 30; ++i) {
        const auto m = mapper.toHost(i * 10'000'000LL + device_offset, i * 10'000'000LL + 500'000);
        EXPECT_EQ(m.host_ns, i * 10'000'000LL + 500'000) << i;
    }
    EXPECT_EQ(mapper.rebases(), 1u);
}

}  // namespace
}  // namespace commonlight::hal::aravis

namespace commonlight::hal::aravis {
namespace {

// SFNC's Gamma encodes out = in^Gamma: a camera at Gamma 0.45 (a typical encoding) decodes with
// 1/0.45; Gamma 1 is linear; nonsense values fall back to linear (machine-vision default).
TEST(AravisSupport, GammaFeatureMapsToAResponseSpec) {
    EXPECT_EQ(gammaResponseSpec(1.0), "linear");
    EXPECT_EQ(gammaResponseSpec(1.0004), "linear");
    EXPECT_EQ(gammaResponseSpec(0.5), "gamma:2");
    EXPECT_EQ(gammaResponseSpec(0.45), "gamma:2.222");
    EXPECT_EQ(gammaResponseSpec(0.0), "linear");
    EXPECT_EQ(gammaResponseSpec(std::nan("")), "linear");
    EXPECT_EQ(gammaResponseSpec(0.1), "gamma:5");  // clamped to the range core/response.h accepts
}

}  // namespace
}  // namespace commonlight::hal::aravis

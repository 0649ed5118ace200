// The libcamera backend's translation layer: formats, roles, validation, controls, timestamps,
// sequences and the pixel copy (hal/libcamera/mapping.h). No libcamera needed.
#include "hal/libcamera/mapping.h"

#include <gtest/gtest.h>

namespace commonlight::hal::libcamera_backend {
namespace {

// ---- pixel formats ----------------------------------------------------------------------------

TEST(LibcameraFormats, FourccsMatchLibcamerasSpelling) {
    // libcamera/formats.h: YUYV{__fourcc('Y','U','Y','V')}, the DRM little-endian packing.
    EXPECT_EQ(kFourccYuyv, 0x56595559u);
    EXPECT_EQ(kFourccMjpeg, 0x47504a4du);
    EXPECT_EQ(deviceFormatName({kFourccRgb888, 0}), "RG24");
    EXPECT_EQ(deviceFormatName({kFourccR8, 0}), "R8");
    EXPECT_EQ(deviceFormatName({kFourccNv12, 0x100000000000001ull}), "NV12-0x100000000000001");
}

TEST(LibcameraFormats, RoundTripsEveryFormatWeMap) {
    const std::pair<std::uint32_t, PixelFormat> expected[] = {
        {kFourccR8, PixelFormat::kGray8},    {kFourccYuyv, PixelFormat::kYuyv},  {kFourccNv12, PixelFormat::kNv12},
        {kFourccMjpeg, PixelFormat::kMjpeg}, {kFourccRgb888, PixelFormat::kBgr8}, {kFourccBgr888, PixelFormat::kRgb8},
        {kFourccAbgr8888, PixelFormat::kRgba8},
    };
    for (const auto& [code, format] : expected) {
        SCOPED_TRACE(deviceFormatName({code, 0}));
        EXPECT_EQ(pixelFormatFromDevice({code, 0}), format);
        ASSERT_TRUE(deviceFormatFor(format));
        EXPECT_EQ(deviceFormatFor(format)->fourcc, code);
        EXPECT_EQ(deviceFormatFor(format)->modifier, 0u);
    }
}

TEST(LibcameraFormats, RgbByteOrderFollowsDrmNotTheName) {
    // DRM_FORMAT_RGB888 stores B, G, R in memory: that is our kBgr8, and BGR888 is our kRgb8.
    EXPECT_EQ(pixelFormatFromDevice({kFourccRgb888, 0}), PixelFormat::kBgr8);
    EXPECT_EQ(pixelFormatFromDevice({kFourccBgr888, 0}), PixelFormat::kRgb8);
}

TEST(LibcameraFormats, UnknownFormatsAndModifiersAreLeftOut) {
    EXPECT_FALSE(pixelFormatFromDevice({fourcc('p', 'R', 'A', 'A'), 0}));  // Raspberry Pi packed Bayer
    EXPECT_FALSE(pixelFormatFromDevice({kFourccNv12, 1}));                  // tiled
    EXPECT_FALSE(deviceFormatFor(PixelFormat::kRgbF32));
    EXPECT_FALSE(deviceFormatFor(PixelFormat::kGray16));
}

TEST(LibcameraFormats, OfferedFormatsKeepWhatWeCanReadOnceEach) {
    const std::vector<DeviceFormat> device = {
        {{kFourccYuyv, 0}, 640, 480}, {{kFourccYuyv, 0}, 640, 480}, {{fourcc('p', 'R', 'A', 'A'), 0}, 1920, 1080},
        {{kFourccMjpeg, 0}, 1280, 720}, {{kFourccNv12, 0}, 0, 0}};
    const auto offered = offeredFormats(device);
    ASSERT_EQ(offered.size(), 2u);
    EXPECT_EQ(offered[0], (StreamFormat{PixelFormat::kYuyv, 640, 480, {}, 0}));
    EXPECT_EQ(offered[1], (StreamFormat{PixelFormat::kMjpeg, 1280, 720, {}, 0}));
}

// ---- roles ------------------------------------------------------------------------------------

TEST(LibcameraRoles, ParsesTheUriNames) {
    EXPECT_EQ(parseStreamRole("viewfinder", "u").value(), StreamRole::kViewfinder);
    EXPECT_EQ(parseStreamRole("video", "u").value(), StreamRole::kVideoRecording);
    EXPECT_EQ(parseStreamRole("still", "u").value(), StreamRole::kStillCapture);
    EXPECT_EQ(parseStreamRole("raw", "u").value(), StreamRole::kRaw);
    for (auto role : {StreamRole::kViewfinder, StreamRole::kVideoRecording, StreamRole::kStillCapture, StreamRole::kRaw}) {
        EXPECT_EQ(parseStreamRole(streamRoleName(role), "u").value(), role);
    }
    const auto bad = parseStreamRole("preview", "libcamera:0?role=preview");
    ASSERT_FALSE(bad);
    EXPECT_EQ(bad.error().code, ErrorCode::kUsage);
    EXPECT_EQ(bad.error().message, "libcamera:0?role=preview: role must be viewfinder, video, still or raw, not 'preview'");
}

// ---- validation -------------------------------------------------------------------------------

const std::vector<StreamFormat> kOffered = {{PixelFormat::kYuyv, 640, 480, {}, 0}, {PixelFormat::kNv12, 1296, 972, {}, 0}};

TEST(LibcameraValidation, ValidIsAcceptedSilently) {
    const StreamFormat wanted{PixelFormat::kYuyv, 640, 480, {}, 30};
    ConfigureResult result{ValidationStatus::kValid, deviceConfigFor(wanted, 4)};
    EXPECT_EQ(result.config.format.fourcc, kFourccYuyv);
    EXPECT_EQ(result.config.buffer_count, 4u);
    const auto accepted = acceptConfiguration(result, wanted, kOffered, "libcamera:0");
    ASSERT_TRUE(accepted);
    EXPECT_EQ(accepted->format, wanted);
    EXPECT_TRUE(accepted->warning.empty());
}

TEST(LibcameraValidation, AdjustedIsAcceptedWithAWarningNamingTheChange) {
    const StreamFormat wanted{PixelFormat::kNv12, 1280, 960, {}, 0};
    ConfigureResult result{ValidationStatus::kAdjusted, deviceConfigFor(wanted, 4)};
    result.config.width = 1296;
    result.config.height = 972;
    const auto accepted = acceptConfiguration(result, wanted, kOffered, "libcamera:0");
    ASSERT_TRUE(accepted);
    EXPECT_EQ(accepted->format.width, 1296);
    EXPECT_EQ(accepted->format.height, 972);
    EXPECT_EQ(accepted->warning, "libcamera:0: libcamera adjusted the configuration nv12 1280x960: size 1280x960 -> 1296x972");

    ConfigureResult format_changed{ValidationStatus::kAdjusted, deviceConfigFor(wanted, 4)};
    format_changed.config.format = {kFourccYuyv, 0};
    const auto yuyv = acceptConfiguration(format_changed, wanted, kOffered, "libcamera:0");
    ASSERT_TRUE(yuyv);
    EXPECT_EQ(yuyv->format.format, PixelFormat::kYuyv);
    EXPECT_NE(yuyv->warning.find("format nv12 -> yuyv"), std::string::npos) << yuyv->warning;

    ConfigureResult stride_only{ValidationStatus::kAdjusted, deviceConfigFor(wanted, 4)};
    stride_only.config.stride = 1344;
    const auto same = acceptConfiguration(stride_only, wanted, kOffered, "libcamera:0");
    ASSERT_TRUE(same);
    EXPECT_NE(same->warning.find("stride, buffer count or colour space only"), std::string::npos) << same->warning;
}

TEST(LibcameraValidation, InvalidIsAUsageErrorListingTheOffer) {
    const StreamFormat wanted{PixelFormat::kYuyv, 640, 480, {}, 0};
    const auto rejected = acceptConfiguration({ValidationStatus::kInvalid, deviceConfigFor(wanted, 4)}, wanted, kOffered,
                                              "libcamera:0");
    ASSERT_FALSE(rejected);
    EXPECT_EQ(rejected.error().code, ErrorCode::kUsage);
    EXPECT_EQ(rejected.error().message,
              "libcamera:0: libcamera rejected the configuration yuyv 640x480; the camera offers:\n  yuyv 640x480\n"
              "  nv12 1296x972");
}

TEST(LibcameraValidation, AdjustmentToAFormatWeCannotReadIsAnError) {
    const StreamFormat wanted{PixelFormat::kYuyv, 640, 480, {}, 0};
    ConfigureResult result{ValidationStatus::kAdjusted, deviceConfigFor(wanted, 4)};
    result.config.format = {fourcc('p', 'R', 'A', 'A'), 0};
    const auto rejected = acceptConfiguration(result, wanted, kOffered, "libcamera:0");
    ASSERT_FALSE(rejected);
    EXPECT_EQ(rejected.error().code, ErrorCode::kUsage);
    EXPECT_NE(rejected.error().message.find("pRAA, which commonlight cannot read"), std::string::npos)
        << rejected.error().message;
}

// ---- controls ---------------------------------------------------------------------------------

DeviceControls fullControls() {
    DeviceControls c;
    c.exposure_time_us = DeviceRange{14, 66666, 10000};
    c.analogue_gain = DeviceRange{1.0, 16.0, 1.0};
    c.ae_enable = DeviceRange{0, 1, 1};
    c.awb_enable = DeviceRange{0, 1, 0};
    c.frame_duration_us = DeviceRange{16667, 200000, 33333};
    return c;
}

TEST(LibcameraControls, FrameRateComesFromFrameDurationLimits) {
    EXPECT_EQ(frameDurationUs(30.0), 33333);
    EXPECT_EQ(frameDurationUs(0.0), 0);
    EXPECT_NEAR(fpsForFrameDurationUs(33333), 30.0, 1e-3);
    const auto range = fpsRange(fullControls());
    ASSERT_TRUE(range);
    EXPECT_NEAR(range->first, 5.0, 1e-9);
    EXPECT_NEAR(range->second, 60.0, 0.01);
    EXPECT_FALSE(fpsRange(DeviceControls{}));
}

TEST(LibcameraControls, InfosListWhatTheCameraHas) {
    const auto infos = controlInfos(fullControls());
    ASSERT_EQ(infos.size(), 5u);
    EXPECT_EQ(infos[0].id, Control::kExposureUs);
    EXPECT_EQ(infos[0].min, 14);
    EXPECT_EQ(infos[0].max, 66666);
    EXPECT_EQ(infos[0].default_value, 10000);
    EXPECT_EQ(infos[1].id, Control::kAnalogGain);
    EXPECT_EQ(infos[2].id, Control::kAutoExposure);
    EXPECT_EQ(infos[2].default_value, 1);
    EXPECT_EQ(infos[3].id, Control::kAutoWhiteBalance);
    EXPECT_EQ(infos[3].default_value, 0);
    EXPECT_EQ(infos[4].id, Control::kFrameRate);
    EXPECT_NEAR(infos[4].default_value, 30.0, 1e-3);
    DeviceControls only_gain;
    only_gain.analogue_gain = DeviceRange{1, 8, 1};
    ASSERT_EQ(controlInfos(only_gain).size(), 1u);
    EXPECT_EQ(controlInfos(only_gain)[0].id, Control::kAnalogGain);
}

TEST(LibcameraControls, SetValuesLandInTheRequestControls) {
    const auto controls = fullControls();
    RequestControls out;
    ASSERT_TRUE(setRequestControl(Control::kExposureUs, 5000.4, controls, out, "cam"));
    ASSERT_TRUE(setRequestControl(Control::kAnalogGain, 2.5, controls, out, "cam"));
    ASSERT_TRUE(setRequestControl(Control::kAutoExposure, 0, controls, out, "cam"));
    ASSERT_TRUE(setRequestControl(Control::kAutoWhiteBalance, 1, controls, out, "cam"));
    ASSERT_TRUE(setRequestControl(Control::kFrameRate, 30, controls, out, "cam"));
    EXPECT_EQ(out.exposure_time_us, 5000);
    EXPECT_EQ(out.analogue_gain, 2.5f);
    EXPECT_EQ(out.ae_enable, false);
    EXPECT_EQ(out.awb_enable, true);
    EXPECT_EQ(out.frame_duration_us, 33333);
    RequestControls later;
    later.analogue_gain = 4.0f;
    out.merge(later);
    EXPECT_EQ(out.analogue_gain, 4.0f);
    EXPECT_EQ(out.exposure_time_us, 5000);
}

TEST(LibcameraControls, OutOfRangeAndMissingControlsAreErrorsNamingTheCamera) {
    const auto controls = fullControls();
    RequestControls out;
    const auto too_long = setRequestControl(Control::kExposureUs, 1e6, controls, out, "libcamera:0");
    ASSERT_FALSE(too_long);
    EXPECT_EQ(too_long.error().code, ErrorCode::kUsage);
    EXPECT_EQ(too_long.error().message, "libcamera:0: exposure_us 1e+06 is outside the camera's range [14, 66666]");
    EXPECT_FALSE(setRequestControl(Control::kAnalogGain, 0.5, controls, out, "c"));
    EXPECT_FALSE(setRequestControl(Control::kAutoExposure, 0.5, controls, out, "c"));
    EXPECT_FALSE(setRequestControl(Control::kFrameRate, 120, controls, out, "c"));
    EXPECT_TRUE(out.empty());
    // 60.0 fps is 16666.7 us, just below the 16667 us limit: within the 1% slack, clamped.
    ASSERT_TRUE(setRequestControl(Control::kFrameRate, 60, controls, out, "c"));
    EXPECT_EQ(out.frame_duration_us, 16667);

    const auto missing = setRequestControl(Control::kExposureUs, 100, DeviceControls{}, out, "libcamera:usb");
    ASSERT_FALSE(missing);
    EXPECT_EQ(missing.error().code, ErrorCode::kUnsupported);
    EXPECT_EQ(missing.error().message, "libcamera:usb: control exposure_us is not supported by this camera");
}

// ---- timestamps and sequences -----------------------------------------------------------------

TEST(LibcameraTimestamps, SensorTimestampOnEitherClockEndsOnMonotonic) {
    const std::int64_t mono_now = 1'000'000'000'000;
    const std::int64_t boot_now = mono_now + 3'600'000'000'000;  // suspended for an hour
    const std::int64_t age = 40'000'000;
    // Documented: CLOCK_BOOTTIME -> shifted onto CLOCK_MONOTONIC.
    EXPECT_EQ(sensorTimestampToMonotonic(boot_now - age, mono_now, boot_now), mono_now - age);
    // What V4L2-based pipelines deliver: already CLOCK_MONOTONIC -> unchanged.
    EXPECT_EQ(sensorTimestampToMonotonic(mono_now - age, mono_now, boot_now), mono_now - age);
    // Never suspended: the clocks agree, nothing to do.
    EXPECT_EQ(sensorTimestampToMonotonic(mono_now - age, mono_now, mono_now), mono_now - age);
}

TEST(LibcameraTimestamps, SourceFollowsWhatTheRequestCarries) {
    CompletedRequest request;
    request.buffer_timestamp_ns = 900;
    request.sensor_timestamp_ns = 800;
    auto timing = frameTiming(request, 1000, 1000);
    EXPECT_EQ(timing.timestamp_ns, 800);
    EXPECT_EQ(timing.source, TimestampSource::kSensor);
    request.sensor_timestamp_ns.reset();
    timing = frameTiming(request, 1000, 1000);
    EXPECT_EQ(timing.timestamp_ns, 900);
    EXPECT_EQ(timing.source, TimestampSource::kDriver);
    request.buffer_timestamp_ns = 0;
    timing = frameTiming(request, 1000, 1000);
    EXPECT_EQ(timing.timestamp_ns, 1000);
    EXPECT_EQ(timing.source, TimestampSource::kHost);
}

TEST(LibcameraSequence, GapsSurviveAndWrapAroundExtends) {
    SequenceUnwrapper unwrap;
    EXPECT_EQ(unwrap.next(5), 5u);
    EXPECT_EQ(unwrap.next(6), 6u);
    EXPECT_EQ(unwrap.next(9), 9u);  // 7 and 8 lost at the device
    unwrap.reset();
    EXPECT_EQ(unwrap.next(0xfffffffeu), 0xfffffffeull);
    EXPECT_EQ(unwrap.next(0xffffffffu), 0xffffffffull);
    EXPECT_EQ(unwrap.next(1), 0x100000001ull);
    EXPECT_EQ(unwrap.next(0xffffffffu), 0xffffffffull) << "a late frame does not move the counter forward";
    EXPECT_EQ(unwrap.next(2), 0x100000002ull);
}

// ---- pixel copy -------------------------------------------------------------------------------

TEST(LibcameraCopy, PackedRowsDropTheDevicePadding) {
    const StreamFormat format{PixelFormat::kYuyv, 4, 3, {}, 0};
    DeviceStreamConfig config;
    config.stride = 12;  // 8 bytes of pixels + 4 of padding
    std::vector<std::uint8_t> buffer(36);
    for (std::size_t i = 0; i < buffer.size(); ++i) buffer[i] = static_cast<std::uint8_t>(i);
    CompletedRequest request;
    request.planes[0] = {buffer.data(), buffer.size(), buffer.size()};
    request.plane_count = 1;
    Image image(PixelFormat::kYuyv, 4, 3);
    const auto* before = image.data();
    EXPECT_EQ(copyFrame(request, format, config, image), FrameStatus::kOk);
    EXPECT_EQ(image.data(), before) << "the slot's memory is reused";
    EXPECT_EQ(image.stride(), 8u);
    for (int y = 0; y < 3; ++y) {
        for (int x = 0; x < 8; ++x) EXPECT_EQ(image.view().row(y)[x], y * 12 + x);
    }
    request.planes[0].bytes_used = 30;  // last row short
    EXPECT_EQ(copyFrame(request, format, config, image), FrameStatus::kIncomplete);
    request.planes[0].bytes_used = 36;
    request.status = CompletedRequest::Status::kError;
    EXPECT_EQ(copyFrame(request, format, config, image), FrameStatus::kCorrupt);
}

TEST(LibcameraCopy, Nv12FromTwoPlanesOrOne) {
    const StreamFormat format{PixelFormat::kNv12, 4, 2, {}, 0};
    DeviceStreamConfig config;
    config.stride = 6;
    std::vector<std::uint8_t> y(12), uv(6);
    for (std::size_t i = 0; i < y.size(); ++i) y[i] = static_cast<std::uint8_t>(i);
    for (std::size_t i = 0; i < uv.size(); ++i) uv[i] = static_cast<std::uint8_t>(100 + i);
    CompletedRequest request;
    request.planes[0] = {y.data(), y.size(), y.size()};
    request.planes[1] = {uv.data(), uv.size(), uv.size()};
    request.plane_count = 2;
    Image image;
    ASSERT_EQ(copyFrame(request, format, config, image), FrameStatus::kOk);
    const std::uint8_t expected[] = {0, 1, 2, 3, 6, 7, 8, 9, 100, 101, 102, 103};
    ASSERT_EQ(image.sizeBytes(), sizeof expected);
    EXPECT_TRUE(std::equal(std::begin(expected), std::end(expected), image.data()));

    std::vector<std::uint8_t> single(y);
    single.insert(single.end(), uv.begin(), uv.end());
    request.planes[0] = {single.data(), single.size(), single.size()};
    request.plane_count = 1;
    Image one;
    ASSERT_EQ(copyFrame(request, format, config, one), FrameStatus::kOk);
    EXPECT_TRUE(std::equal(std::begin(expected), std::end(expected), one.data()));
}

TEST(LibcameraCopy, MjpegUsesBytesUsedAndNeverGrowsTheSlot) {
    const StreamFormat format{PixelFormat::kMjpeg, 64, 48, {}, 0};
    std::vector<std::uint8_t> buffer(1000, 0xab);
    CompletedRequest request;
    request.planes[0] = {buffer.data(), 300, buffer.size()};
    request.plane_count = 1;
    Image slot;
    slot.reserve(500);
    EXPECT_EQ(copyFrame(request, format, {}, slot), FrameStatus::kOk);
    EXPECT_EQ(slot.sizeBytes(), 300u);
    EXPECT_EQ(slot.width(), 64);
    request.planes[0].bytes_used = 800;  // larger than the slot
    EXPECT_EQ(copyFrame(request, format, {}, slot), FrameStatus::kIncomplete);
    EXPECT_EQ(slot.sizeBytes(), 500u);
    EXPECT_EQ(slot.capacity(), 500u);
    request.plane_count = 0;
    EXPECT_EQ(copyFrame(request, format, {}, slot), FrameStatus::kIncomplete);
}

}  // namespace
}  // namespace commonlight::hal::libcamera_backend

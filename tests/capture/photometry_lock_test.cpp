#include "capture/photometry_lock.h"

#include <map>
#include <vector>

#include <gtest/gtest.h>

namespace commonlight::capture {
namespace {

// A camera whose auto exposure "chooses" values while it is on and which, like many UVC
// cameras, falls back to its default exposure when auto exposure is turned off.
class AutoCamera final : public hal::Camera {
public:
    explicit AutoCamera(bool has_awb = true, bool has_gain = true)
        : Camera("auto:0"), has_awb_(has_awb), has_gain_(has_gain) {}

    std::map<hal::Control, double> values{{hal::Control::kExposureUs, 12345.0},
                                          {hal::Control::kAnalogGain, 2.5},
                                          {hal::Control::kAutoExposure, 1.0},
                                          {hal::Control::kAutoWhiteBalance, 1.0}};
    std::vector<std::pair<hal::Control, double>> writes;
    bool fail_gain_write = false;

private:
    bool has(hal::Control c) const {
        if (c == hal::Control::kAutoWhiteBalance) return has_awb_;
        if (c == hal::Control::kAnalogGain) return has_gain_;
        return c != hal::Control::kFrameRate;
    }
    std::vector<hal::StreamFormat> doFormats() const override { return {{PixelFormat::kGray8, 8, 8, {30}, 0}}; }
    Result<hal::StreamFormat> doConfigure(const hal::StreamConfig& config) override {
        return hal::negotiate(doFormats(), config, id());
    }
    Result<void> doStart() override { return {}; }
    void doStop() noexcept override {}
    Result<void> doSetControl(hal::Control control, double value) override {
        if (!has(control)) return fail(ErrorCode::kUnsupported, id() + ": no " + std::string(hal::controlName(control)));
        if (control == hal::Control::kAnalogGain && fail_gain_write) return fail(ErrorCode::kDevice, id() + ": gain write failed");
        writes.emplace_back(control, value);
        if (control == hal::Control::kAutoExposure && value == 0.0) values[hal::Control::kExposureUs] = 10000.0;  // the default
        values[control] = value;
        return {};
    }
    Result<double> doGetControl(hal::Control control) const override {
        if (!has(control)) return fail(ErrorCode::kUnsupported, id() + ": no " + std::string(hal::controlName(control)));
        return values.at(control);
    }

    bool has_awb_;
    bool has_gain_;
};

constexpr std::int64_t kSecond = 1'000'000'000;

TEST(PhotometryLock, LocksOnceAfterTheSettlePeriodKeepingTheChosenValues) {
    AutoCamera camera;
    PhotometryLock lock(2 * kSecond);
    for (std::int64_t t : {100 * kSecond, 100 * kSecond + kSecond / 2, 101 * kSecond + kSecond * 9 / 10}) {
        auto r = lock.onFrame(camera, t);
        ASSERT_TRUE(r) << r.error().message;
        EXPECT_FALSE(*r) << "locked before the settle period at " << t;
    }
    EXPECT_TRUE(camera.writes.empty());
    auto r = lock.onFrame(camera, 102 * kSecond);
    ASSERT_TRUE(r) << r.error().message;
    ASSERT_TRUE(*r);
    EXPECT_TRUE(lock.locked());
    EXPECT_EQ((*r)->exposure_us, 12345.0);
    EXPECT_EQ((*r)->analog_gain, 2.5);
    EXPECT_TRUE((*r)->auto_exposure_off);
    EXPECT_TRUE((*r)->auto_white_balance_off);
    // The chosen exposure survives turning auto exposure off (the camera reset it to 10000).
    EXPECT_EQ(camera.values[hal::Control::kExposureUs], 12345.0);
    EXPECT_EQ(camera.values[hal::Control::kAnalogGain], 2.5);
    EXPECT_EQ(camera.values[hal::Control::kAutoExposure], 0.0);
    EXPECT_EQ(camera.values[hal::Control::kAutoWhiteBalance], 0.0);
    const auto writes = camera.writes.size();
    auto again = lock.onFrame(camera, 200 * kSecond);
    ASSERT_TRUE(again);
    EXPECT_FALSE(*again);
    EXPECT_EQ(camera.writes.size(), writes) << "locks only once";
}

TEST(PhotometryLock, ResetSettlesAgainFromTheNextFrame) {
    AutoCamera camera;
    PhotometryLock lock(kSecond);
    ASSERT_TRUE(lock.onFrame(camera, 0));
    ASSERT_TRUE(*lock.onFrame(camera, kSecond));
    lock.reset();
    EXPECT_FALSE(lock.locked());
    EXPECT_FALSE(*lock.onFrame(camera, 50 * kSecond));
    EXPECT_FALSE(*lock.onFrame(camera, 50 * kSecond + kSecond / 2));
    EXPECT_TRUE(*lock.onFrame(camera, 51 * kSecond));
}

TEST(PhotometryLock, ControlsTheCameraLacksAreReportedNotErrors) {
    AutoCamera camera(/*has_awb=*/false, /*has_gain=*/false);
    auto r = PhotometryLock::lock(camera);
    ASSERT_TRUE(r) << r.error().message;
    EXPECT_EQ(r->exposure_us, 12345.0);
    EXPECT_FALSE(r->analog_gain);
    EXPECT_FALSE(r->auto_white_balance_off);
    EXPECT_TRUE(r->auto_exposure_off);
    EXPECT_NE(r->describe().find("no gain control"), std::string::npos);
    EXPECT_NE(r->describe().find("no auto white balance"), std::string::npos);
}

TEST(PhotometryLock, ADeviceErrorIsReturnedNamingTheCamera) {
    AutoCamera camera;
    camera.fail_gain_write = true;
    auto r = PhotometryLock::lock(camera);
    ASSERT_FALSE(r);
    EXPECT_EQ(r.error().code, ErrorCode::kDevice);
    EXPECT_NE(r.error().message.find("auto:0"), std::string::npos);
}

}  // namespace
}  // namespace commonlight::capture

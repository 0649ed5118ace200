// The sensor's parameters: defaults, the scene's `sensor:` map, command-line options, and their errors.
#include "mocks/sim/sensor_params.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <string>

#include "core/yaml_util.h"

namespace commonlight::mocks::sim {
namespace {

using ::testing::HasSubstr;

// Parses `text` as a scene file named scene.yaml and reads its `sensor:` map.
Result<SensorParams> parseScene(const std::string& text) {
    auto root = yaml::loadString(text, "scene.yaml");
    if (!root) return fail(root.error());
    return parseSensorParams("scene.yaml", (*root)["sensor"]);
}

// The error message of parsing `text`, which must fail with kBadInput.
std::string parseError(const std::string& text) {
    const auto params = parseScene(text);
    if (params) return "(parsed without error)";
    EXPECT_EQ(params.error().code, ErrorCode::kBadInput) << params.error().message;
    return params.error().message;
}

TEST(SensorParams, DefaultsAreValidAndMatchTheirDocumentation) {
    const SensorParams params;
    ASSERT_TRUE(params.validate()) << params.validate().error().message;
    EXPECT_EQ(params.bits, 10);
    EXPECT_EQ(params.maxDn(), 1023);
    EXPECT_EQ(params.blackLevelDn(), 64.0);                        // 2^(10 - 4)
    EXPECT_DOUBLE_EQ(params.systemGainDnPerE(), 959.0 / 10000.0);  // full well reaches the top code
    EXPECT_DOUBLE_EQ(params.totalGainDnPerE(), params.systemGainDnPerE());
    EXPECT_EQ(params.channels(), 3);
    // A white Lambertian surface (albedo 0.8) under 10 W/m^2 at 10 ms fills about half the full well.
    const double radiance = 0.8 * 10.0 / std::numbers::pi;
    const double fill = radiance * params.exposureS() * params.electrons_per_radiance_second / params.full_well_e;
    EXPECT_NEAR(fill, 0.5, 0.02);
}

TEST(SensorParams, DerivedBlackLevelAndGainFollowTheBitDepth) {
    SensorParams params;
    params.bits = 8;
    EXPECT_EQ(params.blackLevelDn(), 16.0);
    EXPECT_DOUBLE_EQ(params.systemGainDnPerE(), (255.0 - 16.0) / 10000.0);
    params.bits = 16;
    params.black_level_dn = 0.0;
    params.system_gain_dn_per_e = 2.5;
    params.analog_gain = 4.0;
    EXPECT_EQ(params.blackLevelDn(), 0.0);
    EXPECT_EQ(params.totalGainDnPerE(), 10.0);
}

TEST(SensorParams, AbsentOrEmptySectionKeepsDefaults) {
    const auto absent = parseScene("camera: calib.yaml\n");
    ASSERT_TRUE(absent) << absent.error().message;
    EXPECT_EQ(formatSensorParams(*absent), formatSensorParams(SensorParams{}));
    const auto empty = parseScene("sensor:\n");
    ASSERT_TRUE(empty) << empty.error().message;
    EXPECT_EQ(formatSensorParams(*empty), formatSensorParams(SensorParams{}));
}

TEST(SensorParams, ParsesEveryKey) {
    const auto params = parseScene(
        "sensor:\n"
        "  exposure_us: 8000\n"
        "  analog_gain: 2.5\n"
        "  electrons_per_radiance_second: 1.5e5\n"
        "  full_well_e: 12000\n"
        "  dark_noise_e: 2.2\n"
        "  dark_current_e_per_s: 0\n"
        "  dsnu_e: 0.5\n"
        "  prnu: 0.02\n"
        "  system_gain_dn_per_e: 0.3\n"
        "  bits: 12\n"
        "  black_level_dn: 240\n"
        "  response: linear\n"
        "  color: mono\n"
        "  seed: 18446744073709551615\n");
    ASSERT_TRUE(params) << params.error().message;
    EXPECT_EQ(params->exposure_us, 8000.0);
    EXPECT_EQ(params->analog_gain, 2.5);
    EXPECT_EQ(params->electrons_per_radiance_second, 1.5e5);
    EXPECT_EQ(params->full_well_e, 12000.0);
    EXPECT_EQ(params->dark_noise_e, 2.2);
    EXPECT_EQ(params->dark_current_e_per_s, 0.0);
    EXPECT_EQ(params->dsnu_e, 0.5);
    EXPECT_EQ(params->prnu, 0.02);
    EXPECT_EQ(params->system_gain_dn_per_e, 0.3);
    EXPECT_EQ(params->bits, 12);
    EXPECT_EQ(params->black_level_dn, 240.0);
    EXPECT_EQ(params->response, SensorResponse::kLinear);
    EXPECT_EQ(params->color, SensorColor::kMono);
    EXPECT_EQ(params->seed, 18446744073709551615ULL);
}

TEST(SensorParams, AutoUnsetsTheDerivedFields) {
    const auto params = parseScene("sensor: {system_gain_dn_per_e: auto, black_level_dn: auto, bits: 12}\n");
    ASSERT_TRUE(params) << params.error().message;
    EXPECT_FALSE(params->system_gain_dn_per_e);
    EXPECT_FALSE(params->black_level_dn);
    EXPECT_EQ(params->blackLevelDn(), 256.0);
}

TEST(SensorParams, UnknownKeyNamesFileLineAndKey) {
    const std::string message = parseError("camera: c.yaml\nsensor:\n  exposure_us: 100\n  exposure: 5\n");
    EXPECT_THAT(message, HasSubstr("scene.yaml:4: key 'sensor.exposure': unknown key (expected exposure_us"));
}

TEST(SensorParams, WrongTypesNameFileLineAndKey) {
    EXPECT_THAT(parseError("sensor:\n  exposure_us: fast\n"),
                HasSubstr("scene.yaml:2: key 'sensor.exposure_us': expected a number, found 'fast'"));
    EXPECT_THAT(parseError("sensor:\n  dsnu_e: 1.5e\n"), HasSubstr("key 'sensor.dsnu_e': expected a number"));
    EXPECT_THAT(parseError("sensor:\n  prnu: [0.01]\n"),
                HasSubstr("scene.yaml:2: key 'sensor.prnu': expected a number, found a list"));
    EXPECT_THAT(parseError("sensor:\n  analog_gain: {x: 1}\n"),
                HasSubstr("key 'sensor.analog_gain': expected a number"));
    EXPECT_THAT(parseError("sensor:\n  analog_gain: .inf\n"), HasSubstr("key 'sensor.analog_gain': must be finite"));
    EXPECT_THAT(parseError("sensor:\n  analog_gain: .nan\n"), HasSubstr("key 'sensor.analog_gain': must be finite"));
    EXPECT_THAT(parseError("sensor:\n\n  bits: 11\n"),
                HasSubstr("scene.yaml:3: key 'sensor.bits': expected an integer (8, 10, 12, 14 or 16), found '11'"));
    EXPECT_THAT(parseError("sensor:\n  bits: 10.0\n"), HasSubstr("key 'sensor.bits': expected an integer"));
    EXPECT_THAT(parseError("sensor:\n  response: gamma\n"),
                HasSubstr("key 'sensor.response': expected linear, srgb or gamma:G (G in [1, 4]), found 'gamma'"));
    EXPECT_THAT(parseError("sensor:\n  response: gamma:0.5\n"), HasSubstr("found 'gamma:0.5'"));
    EXPECT_THAT(parseError("sensor:\n  response: gamma:2x\n"), HasSubstr("found 'gamma:2x'"));
    EXPECT_THAT(parseError("sensor:\n  color: bgr\n"), HasSubstr("key 'sensor.color': expected rgb or mono"));
    EXPECT_THAT(parseError("sensor:\n  seed: -3\n"),
                HasSubstr("key 'sensor.seed': expected an integer in [0, 2^64 - 1], found '-3'"));
    EXPECT_THAT(parseError("sensor:\n  seed: 18446744073709551616\n"), HasSubstr("key 'sensor.seed'"));
    EXPECT_THAT(parseError("sensor:\n  black_level_dn: dark\n"),
                HasSubstr("key 'sensor.black_level_dn': expected a number or auto, found 'dark'"));
    EXPECT_THAT(parseError("sensor:\n  exposure_us:\n"),
                HasSubstr("scene.yaml:2: key 'sensor.exposure_us': missing value"));
    EXPECT_THAT(parseError("sensor: [1, 2]\n"), HasSubstr("key 'sensor': expected a map"));
    EXPECT_THAT(parseError("sensor:\n  bits: 10\n  bits: 12\n"), HasSubstr("appears twice"));
}

TEST(SensorParams, OutOfRangeValuesNameFileLineAndKey) {
    EXPECT_THAT(parseError("sensor:\n  exposure_us: 0\n"),
                HasSubstr("scene.yaml:2: key 'sensor.exposure_us': 0 is out of range (0, 1e+08]"));
    EXPECT_THAT(parseError("sensor:\n  prnu: 0.5\n"), HasSubstr("key 'sensor.prnu': 0.5 is out of range [0, 0.2]"));
    EXPECT_THAT(parseError("sensor:\n  dark_noise_e: -1\n"),
                HasSubstr("key 'sensor.dark_noise_e': -1 is out of range"));
    EXPECT_THAT(parseError("sensor:\n  full_well_e: 50\n"), HasSubstr("key 'sensor.full_well_e': 50 is out of range"));
    EXPECT_THAT(parseError("sensor:\n  analog_gain: -2\n"), HasSubstr("key 'sensor.analog_gain'"));
    EXPECT_THAT(parseError("sensor:\n  system_gain_dn_per_e: 0\n"), HasSubstr("key 'sensor.system_gain_dn_per_e'"));
    // Checked against another key: at the line of the value at fault.
    EXPECT_THAT(parseError("sensor:\n  black_level_dn: 300\n  bits: 8\n"),
                HasSubstr("scene.yaml:2: key 'sensor.black_level_dn': 300 is out of range [0, 254] for 8 bits"));
}

TEST(SensorParams, ValidateNamesTheField) {
    SensorParams params;
    params.prnu = 0.3;
    const auto result = params.validate();
    ASSERT_FALSE(result);
    EXPECT_EQ(result.error().code, ErrorCode::kBadInput);
    EXPECT_THAT(result.error().message, HasSubstr("sensor key 'prnu': 0.3 is out of range [0, 0.2]"));
    params = {};
    params.exposure_us = std::nan("");
    EXPECT_THAT(params.validate().error().message, HasSubstr("'exposure_us': must be finite"));
    params = {};
    params.bits = 9;
    EXPECT_THAT(params.validate().error().message, HasSubstr("'bits'"));
    params = {};
    params.system_gain_dn_per_e = -1.0;
    EXPECT_THAT(params.validate().error().message, HasSubstr("'system_gain_dn_per_e'"));
}

TEST(SensorParams, CommandLineOptions) {
    SensorParams params;
    ASSERT_TRUE(setSensorParam(params, "exposure-us", "5000"));
    ASSERT_TRUE(setSensorParam(params, "analog_gain", "2"));
    ASSERT_TRUE(setSensorParam(params, "response", "linear"));
    ASSERT_TRUE(setSensorParam(params, "black-level-dn", "32"));
    EXPECT_EQ(params.exposure_us, 5000.0);
    EXPECT_EQ(params.analog_gain, 2.0);
    EXPECT_EQ(params.response, SensorResponse::kLinear);
    EXPECT_EQ(params.black_level_dn, 32.0);

    const auto unknown = setSensorParam(params, "shutter", "1");
    ASSERT_FALSE(unknown);
    EXPECT_EQ(unknown.error().code, ErrorCode::kUsage);
    EXPECT_THAT(unknown.error().message, HasSubstr("--sensor-shutter: unknown sensor parameter (expected exposure-us"));
    const auto bad = setSensorParam(params, "dark_noise_e", "-3");
    ASSERT_FALSE(bad);
    EXPECT_EQ(bad.error().code, ErrorCode::kUsage);
    EXPECT_THAT(bad.error().message, HasSubstr("--sensor-dark-noise-e: -3 is out of range [0, 1000]"));
    EXPECT_EQ(params.dark_noise_e, 3.0);  // unchanged by a failed option
}

TEST(SensorParams, FormatReadsBackTheSameValues) {
    SensorParams params;
    params.exposure_us = 1234.5;
    params.analog_gain = 1.0 / 3.0;
    params.system_gain_dn_per_e = 0.123456789;
    params.bits = 14;
    params.black_level_dn = 512;
    params.response = SensorResponse::kLinear;
    params.color = SensorColor::kMono;
    params.seed = 42;
    const std::string text = formatSensorParams(params);
    const auto back = parseScene("sensor: " + text + "\n");
    ASSERT_TRUE(back) << back.error().message << "\n" << text;
    EXPECT_EQ(formatSensorParams(*back), text);
    EXPECT_EQ(back->analog_gain, params.analog_gain);
    EXPECT_EQ(back->system_gain_dn_per_e, params.system_gain_dn_per_e);
    EXPECT_EQ(back->seed, 42u);
}

}  // namespace
}  // namespace commonlight::mocks::sim

// Parameters of the simulated camera's sensor (an EMVA 1288 linear sensor, see mocks/sim/sensor.h and
// docs/sim-sensor.md), their defaults for a typical USB camera, and their readers: the scene's `sensor:` map
// and `--sensor-<key> value` options.
//
//     sensor: {exposure_us: 8000, analog_gain: 2, bits: 10, response: srgb, color: rgb, seed: 7}
//
// Every key is optional; a missing key keeps its default. Errors of the YAML reader give
// "<file>:<line>: key 'sensor.<key>': <problem>" (kBadInput); errors of setSensorParam name the option
// (kUsage).
#pragma once

#include <yaml-cpp/yaml.h>

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "core/result.h"

namespace commonlight::mocks::sim {

// How raw digital numbers become the 8-bit values a camera delivers (see SensorModel::encode8).
enum class SensorResponse : std::uint8_t {
    kLinear,  // value8 = 255 * v
    kSrgb,    // value8 = 255 * OETF_sRGB(v), what a webcam's ISP delivers
    kGamma,   // value8 = 255 * v^(1 / gamma), a pure power (SensorParams::gamma)
};

// Colour: one pixel measures all three channels of the radiance (a 3-chip model, no Bayer mosaic);
// mono: one channel measuring the mean of the three.
enum class SensorColor : std::uint8_t { kRgb, kMono };

std::string_view sensorResponseName(SensorResponse response) noexcept;  // "linear", "srgb", "gamma"
std::string_view sensorColorName(SensorColor color) noexcept;
struct SensorParams;
// The response as sequences and core/response.h spell it: "linear", "srgb" or "gamma:G".
std::string sensorResponseSpec(const SensorParams& params);           // "rgb", "mono"

// Defaults: a 1/2.9" 2 Mpx CMOS with 2.9 um pixels (Sony IMX291/IMX290 class, as in many USB
// webcams) behind a small f/2 lens, 10-bit ADC; docs/sim-sensor.md justifies each number.
struct SensorParams {
    double exposure_us = 10000.0;  // exposure time t_exp, microseconds, in (0, 1e8]
    double analog_gain = 1.0;      // linear gain g applied before the ADC, in (0, 1000]
    // Photo-electrons per pixel per second per unit of radiance [e- / (s W/(m^2 sr))], per channel: lumps
    // the lens (f-number, transmission), the pixel area, the quantum efficiency and the photon energy.
    // Default: radiance 0.8 * 10 / pi W/(m^2 sr) (albedo 0.8 under 10 W/m^2) fills 51% of the full well in 10 ms.
    double electrons_per_radiance_second = 2.0e5;
    double full_well_e = 10000.0;       // saturation capacity, electrons, in [100, 1e7]
    double dark_noise_e = 3.0;          // temporal read noise sigma_d0, electrons rms, in [0, 1000]
    double dark_current_e_per_s = 5.0;  // mean dark current, electrons per second, in [0, 1e6]
    double dsnu_e = 1.0;                // spatial std of the dark signal, electrons, in [0, 1000]
    double prnu = 0.01;                 // spatial std of the pixel gain, fraction of 1, in [0, 0.2]
    // System gain K at unity analog gain, DN per electron (the ADC's step); the effective gain is K * g.
    // Unset: (2^bits - 1 - black level) / full well, so that a saturated pixel reaches the top code.
    std::optional<double> system_gain_dn_per_e;
    int bits = 10;  // ADC resolution: 8, 10, 12, 14 or 16
    // Offset added before quantisation, DN (keeps the dark noise from being clipped at 0).
    // Unset: 2^(bits - 4), i.e. 64 DN at 10 bits (the usual raw black level). In [0, 2^bits - 1).
    std::optional<double> black_level_dn;
    SensorResponse response = SensorResponse::kSrgb;
    // The exponent of kGamma, in [1, 4] (written `response: gamma:1.8`, as core/response.h
    // spells it); ignored by the other responses.
    double gamma = 2.2;
    SensorColor color = SensorColor::kRgb;
    // Seed of the fixed-pattern noise (DSNU and PRNU maps): fixed per sensor, shared by all its frames.
    std::uint64_t seed = 1;

    // Fails (kBadInput) when a field is out of range: "sensor key 'prnu': 0.5 is out of range [0, 0.2]".
    Result<void> validate() const;

    // Derived values.
    double exposureS() const noexcept { return exposure_us * 1e-6; }
    int maxDn() const noexcept { return (1 << bits) - 1; }  // top code of the ADC
    double blackLevelDn() const noexcept;
    double systemGainDnPerE() const noexcept;                                             // K at unity gain
    double totalGainDnPerE() const noexcept { return systemGainDnPerE() * analog_gain; }  // K * g
    int channels() const noexcept { return color == SensorColor::kRgb ? 3 : 1; }
};

// Reads the `sensor:` map over the defaults. `path` is the map's key path in messages. Unknown keys,
// values of the wrong type and out-of-range values fail with "<file>:<line>: key 'sensor.<key>': ..."
// (kBadInput).
Result<SensorParams> parseSensorParams(const std::string& file, const YAML::Node& node,
                                       std::string_view path = "sensor");

// Sets one parameter from text, as given on a command line (`--sensor-exposure-us 5000` ->
// key "exposure-us" or "exposure_us", value "5000"). Errors (kUsage) name the option
// "--sensor-<key>". Does not check fields against each other (black level against bits): call
// validate() once every option is set.
Result<void> setSensorParam(SensorParams& params, std::string_view key, std::string_view value);

// The parameters as a YAML flow map that parseSensorParams reads back to the same values (unset
// optional fields are left out).
std::string formatSensorParams(const SensorParams& params);

}  // namespace commonlight::mocks::sim

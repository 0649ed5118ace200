// The simulated camera's sensor: an EMVA 1288 (release 4) linear camera model that turns the renderer's
// linear radiance into the digital numbers of an ADC, then into the 8-bit pixels a USB camera delivers.
// docs/sim-sensor.md has the equations, the parameters and their defaults.
//
// Per pixel and channel, for a radiance L [W/(m^2 sr)] and an exposure t [s]:
//     mu_e  = L * t * electrons_per_radiance_second * (1 + PRNU map)     mean photo-electrons
//     mu_d  = dark_current_e_per_s * t                                   mean thermal electrons
//     e     = Poisson(mu_e + mu_d) + DSNU map + Normal(0, dark_noise_e)  electrons read out
//     e     = min(e, full_well_e)                                        saturation
//     DN    = clip(round(K * g * e + black_level_dn), 0, 2^bits - 1)     quantisation
// so that mean DN = black + K g (mu_e + mu_d) and temporal variance = K^2 sigma_d^2 + 1/12 + K (mu_y - mu_y.dark)
// (EMVA 1288's photon transfer), with sigma_d^2 = dark_noise_e^2 + mu_d.
//
// Deterministic: the fixed pattern comes from SensorParams::seed, the temporal noise of a frame from
// (seed, frame_seed, row); the same inputs give the same bytes on any number of threads.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "core/image.h"
#include "core/result.h"
#include "mocks/sim/sensor_params.h"

namespace commonlight::mocks::sim {

// The raw digital numbers of one exposure, as the ADC delivers them (before any response curve).
struct RawFrame {
    int width = 0;
    int height = 0;
    int channels = 0;               // 3 (R, G, B interleaved) or 1 (mono)
    int bits = 0;                   // values are in [0, 2^bits - 1]
    std::vector<std::uint16_t> dn;  // row-major, channels interleaved, no padding

    std::uint16_t at(int x, int y, int channel = 0) const noexcept {
        return dn[(static_cast<std::size_t>(y) * static_cast<std::size_t>(width) + static_cast<std::size_t>(x)) *
                      static_cast<std::size_t>(channels) +
                  static_cast<std::size_t>(channel)];
    }
};

class SensorModel {
public:
    // Validates the parameters and makes the fixed-pattern maps (DSNU, PRNU; one per channel) of a
    // width x height sensor from params.seed. kBadInput for invalid parameters or sizes.
    static Result<SensorModel> create(const SensorParams& params, int width, int height);

    // One exposure of `radiance` (kRgbF32, width x height, W/(m^2 sr) per channel; a mono sensor takes the mean
    // of the three) into `raw` (reshaped; allocates only on first use). Temporal noise is drawn from
    // (params.seed, frame_seed). When `electrons_out` is given it receives the electrons read out per pixel
    // (after saturation, before quantisation) as kRgbF32, the mono value repeated in the three channels.
    // Hard cases: +inf radiance saturates; a negative or NaN radiance is an error (kBadInput) naming the pixel,
    // and so is a wrong format or size. Safe to call from several threads at once (it is const); runs
    // parallel over rows with TBB.
    Result<void> expose(const ImageView& radiance, std::uint64_t frame_seed, RawFrame& raw,
                        Image* electrons_out = nullptr) const;

    // The 8-bit image a camera delivers for `raw` (from this sensor): RGB8, or GRAY8 for mono, through the
    // response curve: value8 = round(255 * f(v)), v = clamp((DN - black) / (2^bits - 1 - black), 0, 1),
    // f = identity (linear) or the sRGB OETF. Reuses `out`'s capacity.
    void encode8(const RawFrame& raw, Image& out) const;

    const SensorParams& params() const noexcept { return params_; }
    int width() const noexcept { return width_; }
    int height() const noexcept { return height_; }
    // The fixed pattern, laid out like RawFrame::dn: DSNU offsets in electrons (spatial mean 0, std dsnu_e per
    // channel) and PRNU gains (mean 1, std prnu per channel, never negative).
    std::span<const float> dsnuMapE() const noexcept { return dsnu_e_; }
    std::span<const float> prnuMap() const noexcept { return prnu_gain_; }

private:
    SensorModel(const SensorParams& params, int width, int height);

    SensorParams params_;
    int width_ = 0;
    int height_ = 0;
    std::vector<float> dsnu_e_;
    std::vector<float> prnu_gain_;
    std::vector<std::uint8_t> encode_lut_;  // value8 of every DN
};

// Radiometry without noise or fixed pattern: what the model gives on average, and its inverse.
// Mean electrons read out for radiance L: L * t * electrons_per_radiance_second + dark_current * t.
double meanElectrons(const SensorParams& params, double radiance);
// Mean DN before saturation and quantisation: black + K * g * meanElectrons.
double meanDn(const SensorParams& params, double radiance);
// Inverse of meanDn: the radiance [W/(m^2 sr)] whose mean is `dn` (negative below the dark level).
double radianceFromDn(const SensorParams& params, double dn);

// The response curve on normalised values in [0, 1] (inputs outside are clamped) and its inverse.
// `gamma` is the exponent of SensorResponse::kGamma (unused by the others).
double applyResponse(SensorResponse response, double linear, double gamma = 2.2);
double invertResponse(SensorResponse response, double encoded, double gamma = 2.2);

// Inverse of encode8 for one 8-bit value: the normalised linear signal v in [0, 1] (0 = black level,
// 1 = top code). 0 and 255 are clipped values: the true signal may lie below or above them.
double linearFromPixel(std::uint8_t value, SensorResponse response, double gamma = 2.2);
// What lighting calls relative radiance (DESIGN 3): inverse response, divided by exposure [s] x analog gain.
double relativeRadianceFromPixel(std::uint8_t value, const SensorParams& params);
// The absolute radiance [W/(m^2 sr)] of an 8-bit value, with the sensor's true conversion (ground truth).
double radianceFromPixel(std::uint8_t value, const SensorParams& params);

}  // namespace commonlight::mocks::sim

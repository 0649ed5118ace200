#include "mocks/sim/sensor.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <numbers>
#include <sstream>
#include <string>

namespace commonlight::mocks::sim {

namespace {

// ---- Random numbers: our own, so that the same seed gives the same frames with any standard library.

std::uint64_t splitMix64(std::uint64_t x) noexcept {
    x += 0x9e3779b97f4a7c15ULL;
    x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
    x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
    return x ^ (x >> 31);
}

std::uint64_t mixSeed(std::uint64_t a, std::uint64_t b) noexcept { return splitMix64(splitMix64(a) ^ b); }

// Streams of the generator, so that the maps and the temporal noise never share numbers.
constexpr std::uint64_t kDsnuStream = 0x6473'6e75ULL;
constexpr std::uint64_t kPrnuStream = 0x7072'6e75ULL;
constexpr std::uint64_t kFrameStream = 0x6672'616dULL;

// xoshiro256++ (Blackman and Vigna), seeded through SplitMix64; normals by Marsaglia's polar method.
class Rng {
public:
    explicit Rng(std::uint64_t seed) noexcept {
        for (std::uint64_t& word : s_) {
            seed = splitMix64(seed);
            word = seed;
        }
    }

    std::uint64_t next() noexcept {
        const std::uint64_t result = rotl(s_[0] + s_[3], 23) + s_[0];
        const std::uint64_t t = s_[1] << 17;
        s_[2] ^= s_[0];
        s_[3] ^= s_[1];
        s_[1] ^= s_[2];
        s_[0] ^= s_[3];
        s_[2] ^= t;
        s_[3] = rotl(s_[3], 45);
        return result;
    }

    // Uniform in the open interval (0, 1): never 0, so log() and divisions by it are safe.
    double uniform() noexcept { return (static_cast<double>(next() >> 11) + 0.5) * 0x1.0p-53; }

    double normal() noexcept {
        if (has_spare_) {
            has_spare_ = false;
            return spare_;
        }
        double u = 0.0;
        double v = 0.0;
        double s = 0.0;
        do {
            u = 2.0 * uniform() - 1.0;
            v = 2.0 * uniform() - 1.0;
            s = u * u + v * v;
        } while (s >= 1.0 || s == 0.0);
        const double f = std::sqrt(-2.0 * std::log(s) / s);
        spare_ = v * f;
        has_spare_ = true;
        return u * f;
    }

private:
    static std::uint64_t rotl(std::uint64_t x, int k) noexcept { return (x << k) | (x >> (64 - k)); }

    std::array<std::uint64_t, 4> s_{};
    double spare_ = 0.0;
    bool has_spare_ = false;
};

// log(k!) for an integer k >= 0. A table below 32, Stirling's series above (error < 1e-14). Not std::lgamma:
// glibc's lgamma writes the global `signgam`, a data race when rows run on several threads.
double logFactorial(double k) noexcept {
    static const std::array<double, 32> table = [] {
        std::array<double, 32> t{};
        for (std::size_t i = 1; i < t.size(); ++i) t[i] = t[i - 1] + std::log(static_cast<double>(i));
        return t;
    }();
    if (k < 32.0) return table[static_cast<std::size_t>(k)];
    const double inv = 1.0 / k;
    const double inv2 = inv * inv;
    return k * std::log(k) - k + 0.5 * std::log(2.0 * std::numbers::pi * k) +
           inv * (1.0 / 12.0 - inv2 * (1.0 / 360.0 - inv2 / 1260.0));
}

// An exact Poisson sample of mean `mean` >= 0 (no normal approximation: the photon transfer test needs the
// true variance at every level, and the skew at small means).
//  - mean < 10: inversion by sequential search from 0 (about mean + 1 steps).
//  - mean >= 10: Hormann's PTRS transformed rejection with squeeze (1993), as in NumPy; about 1.1 tries and
//    two uniforms per sample, log(k!) only for the 14% of tries the squeeze does not accept.
double poisson(Rng& rng, double mean) noexcept {
    if (mean <= 0.0) return 0.0;
    if (mean < 10.0) {
        const double u = rng.uniform();
        double p = std::exp(-mean);
        double cdf = p;
        double k = 0.0;
        // The cap only matters when u lands in the last ulps that rounding keeps the sum below 1
        // (P(k > 200) < 1e-200 at mean 10).
        while (u > cdf && k < 200.0) {
            k += 1.0;
            p *= mean / k;
            cdf += p;
        }
        return k;
    }
    const double sqrt_mean = std::sqrt(mean);
    const double b = 0.931 + 2.53 * sqrt_mean;
    const double a = -0.059 + 0.02483 * b;
    const double inv_alpha = 1.1239 + 1.1328 / (b - 3.4);
    const double v_r = 0.9277 - 3.6224 / (b - 2.0);
    for (;;) {
        const double u = rng.uniform() - 0.5;
        const double v = rng.uniform();
        const double us = 0.5 - std::abs(u);  // > 0: uniform() is never 0 or 1
        const double k = std::floor((2.0 * a / us + b) * u + mean + 0.43);
        if (us >= 0.07 && v <= v_r) return k;
        if (k < 0.0 || (us < 0.013 && v > us)) continue;
        if (std::log(v) + std::log(inv_alpha) - std::log(a / (us * us) + b) <=
            -mean + k * std::log(mean) - logFactorial(k)) {
            return k;
        }
    }
}

// A map of `count` normal values, channels interleaved, each channel rescaled to exactly mean 0 and standard
// deviation 1, so that a sensor has the DSNU and PRNU its parameters say (EMVA 1288 reports them as the spatial
// std of one sensor, per channel).
std::vector<float> standardNormalMap(std::uint64_t seed, std::size_t count, std::size_t channels) {
    Rng rng(seed);
    std::vector<double> values(count);
    for (double& value : values) value = rng.normal();
    std::vector<float> map(count);
    for (std::size_t c = 0; c < channels; ++c) {
        double sum = 0.0;
        std::size_t n = 0;
        for (std::size_t i = c; i < count; i += channels, ++n) sum += values[i];
        const double mean = n > 0 ? sum / static_cast<double>(n) : 0.0;
        double sum_sq = 0.0;
        for (std::size_t i = c; i < count; i += channels) sum_sq += (values[i] - mean) * (values[i] - mean);
        // Hard case: a one-pixel sensor has no spatial spread to normalise; its single value is 0.
        const double scale = (n > 1 && sum_sq > 0.0) ? 1.0 / std::sqrt(sum_sq / static_cast<double>(n)) : 0.0;
        for (std::size_t i = c; i < count; i += channels) map[i] = static_cast<float>((values[i] - mean) * scale);
    }
    return map;
}

float loadFloat(const std::uint8_t* bytes) noexcept {
    float value = 0.0f;
    std::memcpy(&value, bytes, sizeof value);
    return value;
}

void storeFloat(std::uint8_t* bytes, float value) noexcept { std::memcpy(bytes, &value, sizeof value); }

constexpr int kMaxSide = 1 << 15;

}  // namespace

Result<SensorModel> SensorModel::create(const SensorParams& params, int width, int height) {
    CL_TRY_VOID(params.validate());
    if (width <= 0 || height <= 0 || width > kMaxSide || height > kMaxSide) {
        return fail(ErrorCode::kBadInput, "sensor size " + std::to_string(width) + "x" + std::to_string(height) +
                                              ": each side must be in [1, " + std::to_string(kMaxSide) + "]");
    }
    return SensorModel(params, width, height);
}

SensorModel::SensorModel(const SensorParams& params, int width, int height)
    : params_(params), width_(width), height_(height) {
    const auto channels = static_cast<std::size_t>(params.channels());
    const std::size_t count = static_cast<std::size_t>(width) * static_cast<std::size_t>(height) * channels;
    // Step 1: the fixed pattern, from the sensor's seed only.
    const std::vector<float> dsnu = standardNormalMap(mixSeed(params.seed, kDsnuStream), count, channels);
    const std::vector<float> prnu = standardNormalMap(mixSeed(params.seed, kPrnuStream), count, channels);
    dsnu_e_.resize(count);
    prnu_gain_.resize(count);
    for (std::size_t i = 0; i < count; ++i) {
        dsnu_e_[i] = static_cast<float>(params.dsnu_e * dsnu[i]);
        // Hard case: at prnu = 0.2 a 5-sigma pixel would get a negative gain; a pixel cannot give back charge.
        prnu_gain_[i] = std::max(0.0f, static_cast<float>(1.0 + params.prnu * prnu[i]));
    }
    // Step 2: the response curve for every DN, so encode8 is one lookup per value.
    const int max_dn = params.maxDn();
    const double black = params.blackLevelDn();
    encode_lut_.resize(static_cast<std::size_t>(max_dn) + 1);
    for (int dn = 0; dn <= max_dn; ++dn) {
        const double v = (dn - black) / (max_dn - black);  // max_dn > black: validate() checked it
        encode_lut_[static_cast<std::size_t>(dn)] =
            static_cast<std::uint8_t>(std::lround(255.0 * applyResponse(params.response, v, params.gamma)));
    }
}

Result<void> SensorModel::expose(const ImageView& radiance, std::uint64_t frame_seed, RawFrame& raw,
                                 Image* electrons_out) const {
    // Step 1: the input is what the renderer promises.
    if (radiance.format != PixelFormat::kRgbF32 || radiance.width != width_ || radiance.height != height_ ||
        radiance.data == nullptr) {
        return fail(ErrorCode::kBadInput, "sensor: radiance must be " +
                                              std::string(pixelFormatName(PixelFormat::kRgbF32)) + " " +
                                              std::to_string(width_) + "x" + std::to_string(height_) + ", got " +
                                              std::string(pixelFormatName(radiance.format)) + " " +
                                              std::to_string(radiance.width) + "x" + std::to_string(radiance.height));
    }
    // Hard case: negative or NaN radiance is a renderer bug, not light; say where it is. +inf is allowed and
    // saturates (a light source seen directly may be that bright).
    for (int y = 0; y < height_; ++y) {
        const std::uint8_t* row = radiance.row(y);
        for (int i = 0; i < 3 * width_; ++i) {
            const float value = loadFloat(row + 4 * static_cast<std::size_t>(i));
            if (!(value >= 0.0f)) {
                static constexpr std::array<char, 3> kChannel{'R', 'G', 'B'};
                std::ostringstream message;
                message << "sensor: radiance at pixel (" << i / 3 << ", " << y << ") channel " << kChannel[i % 3]
                        << " is " << value << ": must be >= 0 and not NaN";
                return fail(ErrorCode::kBadInput, message.str());
            }
        }
    }
    const int channels = params_.channels();
    raw.width = width_;
    raw.height = height_;
    raw.channels = channels;
    raw.bits = params_.bits;
    raw.dn.resize(static_cast<std::size_t>(width_) * static_cast<std::size_t>(height_) *
                  static_cast<std::size_t>(channels));
    if (electrons_out != nullptr) electrons_out->reshape(PixelFormat::kRgbF32, width_, height_);

    // Step 2: constants of this exposure.
    const double t_s = params_.exposureS();
    const double electrons_per_radiance = t_s * params_.electrons_per_radiance_second;
    const double dark_mean_e = params_.dark_current_e_per_s * t_s;
    const double full_well = params_.full_well_e;
    const double gain_dn_per_e = params_.totalGainDnPerE();
    const double black = params_.blackLevelDn();
    const double max_dn = params_.maxDn();
    const double read_sigma = params_.dark_noise_e;
    // Hard case: beyond this mean the pixel saturates with certainty (the full well lies more than 30 standard
    // deviations of the shot noise, and 40 of the read noise and of the DSNU, below it), so we skip sampling. This also
    // takes +inf radiance, and NaN from inf * 0 (an infinitely bright pixel with zero PRNU gain) by the negated
    // comparison.
    const double saturated_mean = 4.0 * full_well + 1000.0 + 40.0 * (read_sigma + params_.dsnu_e);
    const std::uint64_t frame_key = mixSeed(mixSeed(params_.seed, kFrameStream), frame_seed);

    // Step 3: every row with its own generator, so the result does not depend on how TBB splits the rows.
    tbb::parallel_for(tbb::blocked_range<int>(0, height_, 8), [&](const tbb::blocked_range<int>& rows) {
        for (int y = rows.begin(); y != rows.end(); ++y) {
            Rng rng(mixSeed(frame_key, static_cast<std::uint64_t>(y)));
            const std::uint8_t* in = radiance.row(y);
            std::uint8_t* e_row = electrons_out != nullptr ? electrons_out->mutableView().row(y) : nullptr;
            const std::size_t base =
                static_cast<std::size_t>(y) * static_cast<std::size_t>(width_) * static_cast<std::size_t>(channels);
            for (int x = 0; x < width_; ++x) {
                const std::uint8_t* px = in + 12 * static_cast<std::size_t>(x);
                for (int c = 0; c < channels; ++c) {
                    const std::size_t i = base + static_cast<std::size_t>(x * channels + c);
                    // A mono pixel sees the three channels' mean (a flat panchromatic response).
                    const double l =
                        channels == 3
                            ? loadFloat(px + 4 * c)
                            : (static_cast<double>(loadFloat(px)) + loadFloat(px + 4) + loadFloat(px + 8)) / 3.0;
                    const double mean_e = l * electrons_per_radiance * prnu_gain_[i] + dark_mean_e;
                    double electrons = full_well;
                    if (mean_e < saturated_mean) {
                        electrons = poisson(rng, mean_e) + dsnu_e_[i];
                        if (read_sigma > 0.0) electrons += read_sigma * rng.normal();
                        electrons = std::min(electrons, full_well);
                    }
                    // Negative electrons (read noise and DSNU around a dark pixel) stay: the black level holds them,
                    // and the ADC clips at 0.
                    const double dn = std::clamp(std::floor(gain_dn_per_e * electrons + black + 0.5), 0.0, max_dn);
                    raw.dn[i] = static_cast<std::uint16_t>(dn);
                    if (e_row != nullptr) {
                        std::uint8_t* e_px = e_row + 12 * static_cast<std::size_t>(x);
                        if (channels == 3) {
                            storeFloat(e_px + 4 * c, static_cast<float>(electrons));
                        } else {
                            for (int k = 0; k < 3; ++k) storeFloat(e_px + 4 * k, static_cast<float>(electrons));
                        }
                    }
                }
            }
        }
    });
    return {};
}

void SensorModel::encode8(const RawFrame& raw, Image& out) const {
    const PixelFormat format = raw.channels == 3 ? PixelFormat::kRgb8 : PixelFormat::kGray8;
    out.reshape(format, raw.width, raw.height);
    const std::size_t row_values = static_cast<std::size_t>(raw.width) * static_cast<std::size_t>(raw.channels);
    const std::size_t last = encode_lut_.size() - 1;
    for (int y = 0; y < raw.height; ++y) {
        const std::uint16_t* in = raw.dn.data() + static_cast<std::size_t>(y) * row_values;
        std::uint8_t* dst = out.mutableView().row(y);
        // A DN above this sensor's top code (a RawFrame of another bit depth) takes the top code's value.
        for (std::size_t i = 0; i < row_values; ++i) dst[i] = encode_lut_[std::min<std::size_t>(in[i], last)];
    }
}

double meanElectrons(const SensorParams& params, double radiance) {
    const double t_s = params.exposureS();
    return radiance * t_s * params.electrons_per_radiance_second + params.dark_current_e_per_s * t_s;
}

double meanDn(const SensorParams& params, double radiance) {
    return params.blackLevelDn() + params.totalGainDnPerE() * meanElectrons(params, radiance);
}

double radianceFromDn(const SensorParams& params, double dn) {
    const double t_s = params.exposureS();
    const double electrons = (dn - params.blackLevelDn()) / params.totalGainDnPerE();
    return (electrons - params.dark_current_e_per_s * t_s) / (t_s * params.electrons_per_radiance_second);
}

double applyResponse(SensorResponse response, double linear, double gamma) {
    const double v = std::clamp(linear, 0.0, 1.0);
    if (response == SensorResponse::kLinear) return v;
    if (response == SensorResponse::kGamma) return std::pow(v, 1.0 / gamma);
    // sRGB OETF (IEC 61966-2-1): linear segment near black, then a 1/2.4 power.
    return v <= 0.0031308 ? 12.92 * v : 1.055 * std::pow(v, 1.0 / 2.4) - 0.055;
}

double invertResponse(SensorResponse response, double encoded, double gamma) {
    const double e = std::clamp(encoded, 0.0, 1.0);
    if (response == SensorResponse::kLinear) return e;
    if (response == SensorResponse::kGamma) return std::pow(e, gamma);
    return e <= 0.04045 ? e / 12.92 : std::pow((e + 0.055) / 1.055, 2.4);
}

double linearFromPixel(std::uint8_t value, SensorResponse response, double gamma) {
    return invertResponse(response, value / 255.0, gamma);
}

double relativeRadianceFromPixel(std::uint8_t value, const SensorParams& params) {
    return linearFromPixel(value, params.response, params.gamma) / (params.exposureS() * params.analog_gain);
}

double radianceFromPixel(std::uint8_t value, const SensorParams& params) {
    const double black = params.blackLevelDn();
    const double dn = black + linearFromPixel(value, params.response, params.gamma) * (params.maxDn() - black);
    return radianceFromDn(params, dn);
}

}  // namespace commonlight::mocks::sim

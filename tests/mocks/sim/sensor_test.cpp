// The EMVA 1288 sensor model: photon transfer, saturation, fixed pattern, determinism, gain, the 8-bit
// responses and their inverse. Statistics follow EMVA 1288 release 4: temporal variance from the difference
// of two frames, spatial variance of an average of L frames corrected by the temporal variance / L.
#include "mocks/sim/sensor.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <numbers>
#include <vector>

namespace commonlight::mocks::sim {
namespace {

using ::testing::HasSubstr;

// A kRgbF32 image of one radiance per channel [W/(m^2 sr)].
Image flatField(int width, int height, float r, float g, float b) {
    Image image(PixelFormat::kRgbF32, width, height);
    for (int y = 0; y < height; ++y) {
        std::uint8_t* row = image.mutableView().row(y);
        for (int x = 0; x < width; ++x) {
            const float rgb[3] = {r, g, b};
            std::memcpy(row + 12 * static_cast<std::size_t>(x), rgb, sizeof rgb);
        }
    }
    return image;
}
Image flatField(int width, int height, float radiance) {
    return flatField(width, height, radiance, radiance, radiance);
}

void setRadiance(Image& image, int x, int y, int channel, float value) {
    std::memcpy(image.mutableView().row(y) + 12 * static_cast<std::size_t>(x) + 4 * static_cast<std::size_t>(channel),
                &value, sizeof value);
}

// The radiance that gives `electrons` mean photo-electrons per pixel.
float radianceFor(const SensorParams& params, double electrons) {
    return static_cast<float>(electrons / (params.exposureS() * params.electrons_per_radiance_second));
}

SensorModel makeSensor(const SensorParams& params, int width, int height) {
    auto sensor = SensorModel::create(params, width, height);
    EXPECT_TRUE(sensor) << sensor.error().message;
    return std::move(*sensor);
}

RawFrame expose(const SensorModel& sensor, const Image& radiance, std::uint64_t frame_seed) {
    RawFrame raw;
    const auto result = sensor.expose(radiance, frame_seed, raw);
    EXPECT_TRUE(result) << result.error().message;
    return raw;
}

// Mean of channel `c` of a frame.
double channelMean(const RawFrame& raw, int c) {
    double sum = 0.0;
    for (std::size_t i = static_cast<std::size_t>(c); i < raw.dn.size(); i += static_cast<std::size_t>(raw.channels)) {
        sum += raw.dn[i];
    }
    return sum / static_cast<double>(raw.dn.size() / static_cast<std::size_t>(raw.channels));
}

// Temporal variance of channel `c` from two frames: var(A - B) / 2 (the fixed pattern cancels).
double temporalVariance(const RawFrame& a, const RawFrame& b, int c) {
    double sum = 0.0;
    double sum_sq = 0.0;
    std::size_t n = 0;
    for (std::size_t i = static_cast<std::size_t>(c); i < a.dn.size(); i += static_cast<std::size_t>(a.channels)) {
        const double d = static_cast<double>(a.dn[i]) - b.dn[i];
        sum += d;
        sum_sq += d * d;
        ++n;
    }
    const double mean = sum / static_cast<double>(n);
    return (sum_sq - n * mean * mean) / static_cast<double>(n - 1) / 2.0;
}

// EMVA 1288's spatial statistics of L frames of one scene, per channel: the mean, the spatial variance of the
// averaged image with the temporal part removed (s^2 = s^2_measured - sigma^2 / L), and the temporal variance.
struct SpatialStats {
    double mean = 0.0;
    double spatial_variance = 0.0;
    double temporal_variance = 0.0;
};

std::vector<SpatialStats> spatialStats(const SensorModel& sensor, const Image& radiance, int frames,
                                       std::uint64_t first_seed) {
    const std::size_t count = static_cast<std::size_t>(sensor.width()) * static_cast<std::size_t>(sensor.height()) *
                              static_cast<std::size_t>(sensor.params().channels());
    std::vector<double> sum(count, 0.0);
    std::vector<double> sum_sq(count, 0.0);
    for (int f = 0; f < frames; ++f) {
        const RawFrame raw = expose(sensor, radiance, first_seed + static_cast<std::uint64_t>(f));
        for (std::size_t i = 0; i < count; ++i) {
            sum[i] += raw.dn[i];
            sum_sq[i] += static_cast<double>(raw.dn[i]) * raw.dn[i];
        }
    }
    const int channels = sensor.params().channels();
    std::vector<SpatialStats> stats(static_cast<std::size_t>(channels));
    for (int c = 0; c < channels; ++c) {
        double mean_sum = 0.0;
        double mean_sq_sum = 0.0;
        double temporal_sum = 0.0;
        std::size_t n = 0;
        for (std::size_t i = static_cast<std::size_t>(c); i < count; i += static_cast<std::size_t>(channels)) {
            const double mean = sum[i] / frames;
            mean_sum += mean;
            mean_sq_sum += mean * mean;
            temporal_sum += (sum_sq[i] - frames * mean * mean) / (frames - 1);
            ++n;
        }
        SpatialStats& s = stats[static_cast<std::size_t>(c)];
        s.mean = mean_sum / static_cast<double>(n);
        s.temporal_variance = temporal_sum / static_cast<double>(n);
        const double measured = (mean_sq_sum - n * s.mean * s.mean) / static_cast<double>(n - 1);
        s.spatial_variance = measured - s.temporal_variance / frames;
    }
    return stats;
}

SensorParams ptcParams() {
    SensorParams params;
    params.color = SensorColor::kMono;
    params.bits = 12;  // K = 0.384 DN/e-: quantisation noise (1/12 DN^2) is 6% of the dark noise, not dominant
    return params;
}

TEST(Sensor, PhotonTransferCurveFollowsEmva1288) {
    const SensorParams params = ptcParams();
    const SensorModel sensor = makeSensor(params, 512, 512);
    const double k = params.totalGainDnPerE();
    const double dark_e = params.dark_current_e_per_s * params.exposureS();
    // EMVA's sigma_d^2: read noise and the shot noise of the dark current.
    const double sigma_d2 = params.dark_noise_e * params.dark_noise_e + dark_e;
    const double sigma_q2 = 1.0 / 12.0;
    const std::vector<double> fill = {0.0, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.35, 0.5, 0.7, 0.9};

    std::vector<double> signal;    // mu_y - mu_y.dark, DN
    std::vector<double> variance;  // sigma_y^2, DN^2
    double mean_dark = 0.0;
    double worst_mean_error = 0.0;
    double worst_variance_error = 0.0;
    for (std::size_t level = 0; level < fill.size(); ++level) {
        const double mu_e = fill[level] * params.full_well_e;
        const Image radiance = flatField(512, 512, radianceFor(params, mu_e));
        const RawFrame a = expose(sensor, radiance, 2 * level);
        const RawFrame b = expose(sensor, radiance, 2 * level + 1);
        const double mean = (channelMean(a, 0) + channelMean(b, 0)) / 2.0;
        const double var = temporalVariance(a, b, 0);
        if (level == 0) {
            mean_dark = mean;
            // The dark level sits at black + K mu_d (the DSNU map has mean 0); the read noise averages out.
            EXPECT_NEAR(mean, params.blackLevelDn() + k * dark_e, 0.01);
            // sigma_q^2 is accounted for: the dark variance needs it (without it the model is 6% low).
            EXPECT_NEAR(var / (k * k * sigma_d2 + sigma_q2), 1.0, 0.02);
            EXPECT_GT(std::abs(var / (k * k * sigma_d2) - 1.0), 0.03);
        } else {
            // Mean: mu_y - mu_y.dark = K mu_e (EMVA: K eta mu_p).
            const double mean_error = (mean - mean_dark) / (k * mu_e) - 1.0;
            EXPECT_NEAR(mean_error, 0.0, 0.02) << "level " << fill[level];
            worst_mean_error = std::max(worst_mean_error, std::abs(mean_error));
        }
        // Variance: sigma_y^2 = K^2 sigma_d^2 + sigma_q^2 + K (mu_y - mu_y.dark).
        const double model = k * k * sigma_d2 + sigma_q2 + k * (mean - mean_dark);
        const double variance_error = var / model - 1.0;
        EXPECT_NEAR(variance_error, 0.0, 0.02) << "level " << fill[level] << ": var " << var << " model " << model;
        worst_variance_error = std::max(worst_variance_error, std::abs(variance_error));
        signal.push_back(mean - mean_dark);
        variance.push_back(var);
    }
    // K from the slope of the photon transfer curve, as EMVA 1288 measures it: least squares weighted by
    // 1 / variance^2 (every level's variance is known to the same relative precision), so that the bright levels
    // do not drown the intercept.
    double sw = 0.0, sx = 0.0, sy = 0.0, sxx = 0.0, sxy = 0.0;
    for (std::size_t i = 0; i < signal.size(); ++i) {
        const double w = 1.0 / (variance[i] * variance[i]);
        sw += w;
        sx += w * signal[i];
        sy += w * variance[i];
        sxx += w * signal[i] * signal[i];
        sxy += w * signal[i] * variance[i];
    }
    const double slope = (sw * sxy - sx * sy) / (sw * sxx - sx * sx);
    const double intercept = (sy - slope * sx) / sw;
    const double k_error = slope / k - 1.0;
    const double intercept_model = k * k * sigma_d2 + sigma_q2;
    EXPECT_NEAR(k_error, 0.0, 0.02);
    EXPECT_NEAR(intercept / intercept_model, 1.0, 0.05);
    std::printf(
        "PTC: K fitted %.5f DN/e- vs %.5f (%+.2f%%), intercept %.4f vs %.4f DN^2, worst mean error %.2f%%, "
        "worst variance error %.2f%%\n",
        slope, k, 100.0 * k_error, intercept, intercept_model, 100.0 * worst_mean_error, 100.0 * worst_variance_error);
}

TEST(Sensor, ShotNoiseIsPoissonAtSmallAndLargeMeans) {
    // No read noise, no fixed pattern, 1 DN per electron: DN - black is the Poisson sample itself. Means below
    // 10 take the inversion sampler, the others the PTRS rejection sampler; 9.99 and 10 straddle the switch.
    SensorParams params = ptcParams();
    params.dark_noise_e = 0.0;
    params.dark_current_e_per_s = 0.0;
    params.dsnu_e = 0.0;
    params.prnu = 0.0;
    params.system_gain_dn_per_e = 1.0;
    params.black_level_dn = 100.0;
    const SensorModel sensor = makeSensor(params, 256, 256);
    for (const double mean : {0.05, 1.0, 3.0, 9.99, 10.0, 25.0, 400.0}) {
        const RawFrame raw = expose(sensor, flatField(256, 256, radianceFor(params, mean)), 77);
        const double n = static_cast<double>(raw.dn.size());
        std::vector<double> frequency(4096, 0.0);
        for (const std::uint16_t dn : raw.dn) frequency[dn - 100] += 1.0 / n;
        // Every probability of at least 0.5% within 5 standard errors, and the distance between the histogram and
        // the law (total variation) below twice what sampling alone leaves: sum of |N(0, p (1 - p) / n)| / 2.
        double log_p = -mean;  // log P(k) for k = 0
        double total_variation = 0.0;
        double expected_variation = 0.0;
        for (int k = 0; k < 4096 - 100; ++k) {
            if (k > 0) log_p += std::log(mean / k);
            const double p = std::exp(log_p);
            const double standard_error = std::sqrt(p * (1.0 - p) / n);
            total_variation += 0.5 * std::abs(frequency[k] - p);
            expected_variation += 0.5 * standard_error * std::sqrt(2.0 / std::numbers::pi);
            if (p > 0.005) {
                EXPECT_NEAR(frequency[k], p, 5.0 * standard_error) << "mean " << mean << " k " << k;
            }
        }
        EXPECT_LT(total_variation, 2.0 * expected_variation) << "mean " << mean;
    }
}

TEST(Sensor, SaturatesAtFullWellWithoutWrapAround) {
    SensorParams params;
    params.system_gain_dn_per_e = 0.05;  // full well (10000 e-) at 564 DN, below the top code 1023
    const SensorModel sensor = makeSensor(params, 64, 48);
    const double full_well_dn = std::round(params.totalGainDnPerE() * params.full_well_e + params.blackLevelDn());
    for (const float radiance : {radianceFor(params, 3.0 * params.full_well_e), radianceFor(params, 1e9), 1e30f,
                                 std::numeric_limits<float>::max(), std::numeric_limits<float>::infinity()}) {
        const RawFrame raw = expose(sensor, flatField(64, 48, radiance), 7);
        for (const std::uint16_t dn : raw.dn) ASSERT_EQ(dn, full_well_dn) << "radiance " << radiance;
    }
    // With the analog gain, the ADC's top code clips before the full well: never past it, never wrapped.
    params.system_gain_dn_per_e = 10.0;
    params.analog_gain = 1000.0;
    params.bits = 16;
    params.black_level_dn = 0.0;
    const SensorModel loud = makeSensor(params, 64, 48);
    const RawFrame bright = expose(loud, flatField(64, 48, radianceFor(params, 0.5 * params.full_well_e)), 1);
    for (const std::uint16_t dn : bright.dn) ASSERT_EQ(dn, 65535);
    // Without a black level, dark pixels with negative noise clip at 0 (and do not wrap to the top).
    params.system_gain_dn_per_e = 1.0;
    params.analog_gain = 1.0;
    const RawFrame dark = expose(makeSensor(params, 64, 48), flatField(64, 48, 0.0f), 1);
    int zeros = 0;
    for (const std::uint16_t dn : dark.dn) zeros += dn == 0;
    EXPECT_GT(zeros, static_cast<int>(dark.dn.size()) / 3);
    for (const std::uint16_t dn : dark.dn) ASSERT_LT(dn, 30);  // 3 e- read noise, 1 e- DSNU: 7 sigma
}

TEST(Sensor, RejectsNegativeNanAndMismatchedRadiance) {
    const SensorModel sensor = makeSensor(SensorParams{}, 8, 6);
    RawFrame raw;
    Image radiance = flatField(8, 6, 1.0f);
    setRadiance(radiance, 3, 2, 1, -0.5f);
    auto result = sensor.expose(radiance, 0, raw);
    ASSERT_FALSE(result);
    EXPECT_EQ(result.error().code, ErrorCode::kBadInput);
    EXPECT_THAT(result.error().message, HasSubstr("radiance at pixel (3, 2) channel G is -0.5"));
    setRadiance(radiance, 3, 2, 1, 1.0f);
    setRadiance(radiance, 7, 5, 2, std::numeric_limits<float>::quiet_NaN());
    result = sensor.expose(radiance, 0, raw);
    ASSERT_FALSE(result);
    EXPECT_THAT(result.error().message, HasSubstr("pixel (7, 5) channel B is nan"));
    // -0 is zero, not negative.
    setRadiance(radiance, 7, 5, 2, -0.0f);
    EXPECT_TRUE(sensor.expose(radiance, 0, raw));
    EXPECT_FALSE(sensor.expose(flatField(8, 5, 1.0f), 0, raw));
    const Image gray(PixelFormat::kGray8, 8, 6);
    result = sensor.expose(gray, 0, raw);
    ASSERT_FALSE(result);
    EXPECT_THAT(result.error().message, HasSubstr("radiance must be"));
    SensorParams bad;
    bad.bits = 9;
    EXPECT_FALSE(SensorModel::create(bad, 8, 6));
    EXPECT_FALSE(SensorModel::create(SensorParams{}, 0, 6));
}

TEST(Sensor, DsnuAndPrnuMatchTheirParameters) {
    SensorParams params;
    params.bits = 12;
    params.system_gain_dn_per_e = 1.0;  // 1 DN per electron: the 1 e- DSNU is a whole DN
    params.black_level_dn = 256.0;
    params.dsnu_e = 1.0;
    params.prnu = 0.01;
    const SensorModel sensor = makeSensor(params, 256, 256);
    const double k = params.totalGainDnPerE();
    constexpr int kFrames = 32;
    const std::vector<SpatialStats> dark = spatialStats(sensor, flatField(256, 256, 0.0f), kFrames, 100);
    const double mu_e = 3000.0;
    const std::vector<SpatialStats> bright =
        spatialStats(sensor, flatField(256, 256, radianceFor(params, mu_e)), kFrames, 200);
    for (int c = 0; c < 3; ++c) {
        // DSNU1288 = s_y.dark / K, in electrons.
        const double dsnu_e = std::sqrt(dark[c].spatial_variance) / k;
        EXPECT_NEAR(dsnu_e / params.dsnu_e, 1.0, 0.05) << "channel " << c;
        // PRNU1288 = sqrt(s_y^2 - s_y.dark^2) / (mu_y - mu_y.dark).
        const double prnu =
            std::sqrt(bright[c].spatial_variance - dark[c].spatial_variance) / (bright[c].mean - dark[c].mean);
        EXPECT_NEAR(prnu / params.prnu, 1.0, 0.05) << "channel " << c;
        std::printf("channel %d: DSNU %.4f e- (set %.2f), PRNU %.5f (set %.3f)\n", c, dsnu_e, params.dsnu_e, prnu,
                    params.prnu);
    }
    // The maps themselves: exactly the configured spread per channel, gains never negative.
    for (int c = 0; c < 3; ++c) {
        double sum = 0.0, sum_sq = 0.0, gain_sum = 0.0, gain_sq = 0.0;
        std::size_t n = 0;
        for (std::size_t i = static_cast<std::size_t>(c); i < sensor.dsnuMapE().size(); i += 3) {
            sum += sensor.dsnuMapE()[i];
            sum_sq += sensor.dsnuMapE()[i] * sensor.dsnuMapE()[i];
            gain_sum += sensor.prnuMap()[i];
            gain_sq += sensor.prnuMap()[i] * sensor.prnuMap()[i];
            ++n;
        }
        EXPECT_NEAR(sum / n, 0.0, 1e-5);
        EXPECT_NEAR(std::sqrt(sum_sq / n), params.dsnu_e, 1e-5);
        EXPECT_NEAR(gain_sum / n, 1.0, 1e-6);
        EXPECT_NEAR(std::sqrt(gain_sq / n - (gain_sum / n) * (gain_sum / n)), params.prnu, 1e-5);
    }
}

TEST(Sensor, DeterministicPerSeedWithAFixedPatternPerSensor) {
    SensorParams params;
    params.dsnu_e = 5.0;  // a fixed pattern strong enough to see through the temporal noise
    const SensorModel sensor = makeSensor(params, 160, 120);
    const Image radiance = flatField(160, 120, radianceFor(params, 500.0), radianceFor(params, 2000.0), 0.0f);
    const RawFrame first = expose(sensor, radiance, 11);
    // Same bytes again, from another instance of the same sensor, and on one thread.
    EXPECT_EQ(expose(sensor, radiance, 11).dn, first.dn);
    EXPECT_EQ(expose(makeSensor(params, 160, 120), radiance, 11).dn, first.dn);
    RawFrame single;
    tbb::task_arena(1).execute([&] { ASSERT_TRUE(sensor.expose(radiance, 11, single)); });
    EXPECT_EQ(single.dn, first.dn);
    // Another frame seed: other noise.
    const RawFrame second = expose(sensor, radiance, 12);
    std::size_t differ = 0;
    for (std::size_t i = 0; i < first.dn.size(); ++i) differ += first.dn[i] != second.dn[i];
    EXPECT_GT(differ, first.dn.size() / 2);

    // The fixed pattern: frames of the same sensor share it, another sensor seed has its own.
    const auto averagedDark = [&](const SensorModel& s, std::uint64_t first_seed) {
        std::vector<double> mean(first.dn.size(), 0.0);
        for (std::uint64_t f = 0; f < 8; ++f) {
            const RawFrame raw = expose(s, flatField(160, 120, 0.0f), first_seed + f);
            for (std::size_t i = 0; i < mean.size(); ++i) mean[i] += raw.dn[i] / 8.0;
        }
        return mean;
    };
    const auto correlation = [](const std::vector<double>& a, const std::vector<double>& b) {
        double ma = 0.0, mb = 0.0;
        for (std::size_t i = 0; i < a.size(); ++i) ma += a[i] / a.size(), mb += b[i] / b.size();
        double ab = 0.0, aa = 0.0, bb = 0.0;
        for (std::size_t i = 0; i < a.size(); ++i) {
            ab += (a[i] - ma) * (b[i] - mb);
            aa += (a[i] - ma) * (a[i] - ma);
            bb += (b[i] - mb) * (b[i] - mb);
        }
        return ab / std::sqrt(aa * bb);
    };
    const std::vector<double> pattern_a = averagedDark(sensor, 1000);
    const std::vector<double> pattern_b = averagedDark(sensor, 2000);
    params.seed = 99;
    const std::vector<double> other = averagedDark(makeSensor(params, 160, 120), 1000);
    EXPECT_GT(correlation(pattern_a, pattern_b), 0.8);
    EXPECT_LT(std::abs(correlation(pattern_a, other)), 0.05);
}

TEST(Sensor, ElectronsOutputIsWhatTheAdcConverts) {
    const SensorParams params;
    const SensorModel sensor = makeSensor(params, 32, 16);
    RawFrame raw;
    Image electrons;
    ASSERT_TRUE(sensor.expose(flatField(32, 16, radianceFor(params, 4000.0)), 3, raw, &electrons));
    ASSERT_EQ(electrons.format(), PixelFormat::kRgbF32);
    for (int y = 0; y < 16; ++y) {
        for (int x = 0; x < 32; ++x) {
            for (int c = 0; c < 3; ++c) {
                float e = 0.0f;
                std::memcpy(&e, electrons.view().row(y) + 12 * x + 4 * c, sizeof e);
                EXPECT_NEAR(e, 4000.0, 400.0);
                EXPECT_EQ(raw.at(x, y, c), std::round(params.totalGainDnPerE() * e + params.blackLevelDn()));
            }
        }
    }
}

TEST(Sensor, DoublingAnalogGainDoublesTheSignal) {
    SensorParams params = ptcParams();
    const SensorModel unity = makeSensor(params, 256, 256);
    params.analog_gain = 2.0;
    const SensorModel doubled = makeSensor(params, 256, 256);
    const Image radiance = flatField(256, 256, radianceFor(params, 2000.0));
    const double black = params.blackLevelDn();
    const double ratio =
        (channelMean(expose(doubled, radiance, 5), 0) - black) / (channelMean(expose(unity, radiance, 5), 0) - black);
    EXPECT_NEAR(ratio, 2.0, 0.01);
}

TEST(Sensor, GammaResponse) {
    // `response: gamma:1.8` reads, writes back and encodes as a pure power.
    SensorParams params;
    ASSERT_TRUE(setSensorParam(params, "response", "gamma:1.8"));
    EXPECT_EQ(params.response, SensorResponse::kGamma);
    EXPECT_DOUBLE_EQ(params.gamma, 1.8);
    EXPECT_EQ(sensorResponseSpec(params), "gamma:1.8");
    EXPECT_NE(formatSensorParams(params).find("response: gamma:1.8"), std::string::npos);
    EXPECT_NEAR(applyResponse(SensorResponse::kGamma, 0.25, 1.8), std::pow(0.25, 1 / 1.8), 1e-15);
    EXPECT_NEAR(invertResponse(SensorResponse::kGamma, applyResponse(SensorResponse::kGamma, 0.3, 2.6), 2.6), 0.3, 1e-12);
    params.color = SensorColor::kMono;
    const SensorModel sensor = makeSensor(params, 1024, 1);
    RawFrame raw{1024, 1, 1, 10, {}};
    for (int dn = 0; dn < 1024; ++dn) raw.dn.push_back(static_cast<std::uint16_t>(dn));
    Image out;
    sensor.encode8(raw, out);
    const double black = params.blackLevelDn();
    for (int dn = 0; dn < 1024; dn += 7) {
        const double v = std::max(0.0, (dn - black) / (1023.0 - black));
        EXPECT_EQ(out.data()[dn], std::lround(255.0 * std::pow(v, 1 / 1.8))) << "DN " << dn;
    }
    params.gamma = 0.5;
    EXPECT_FALSE(params.validate());
    EXPECT_FALSE(setSensorParam(params, "response", "gamma:5"));
}

TEST(Sensor, Encode8AppliesTheResponseCurve) {
    for (const SensorResponse response : {SensorResponse::kLinear, SensorResponse::kSrgb}) {
        SensorParams params;
        params.color = SensorColor::kMono;
        params.response = response;
        const SensorModel sensor = makeSensor(params, 1024, 1);
        RawFrame raw{1024, 1, 1, 10, {}};
        for (int dn = 0; dn < 1024; ++dn) raw.dn.push_back(static_cast<std::uint16_t>(dn));
        Image out;
        sensor.encode8(raw, out);
        ASSERT_EQ(out.format(), PixelFormat::kGray8);
        const double black = params.blackLevelDn();
        for (int dn = 0; dn < 1024; ++dn) {
            const std::uint8_t value = out.data()[dn];
            const double v = std::max(0.0, (dn - black) / (1023.0 - black));
            EXPECT_EQ(value, std::lround(255.0 * applyResponse(response, v))) << "DN " << dn;
            // linearFromPixel inverts it within the 8-bit step: v lies in the value's quantisation interval.
            EXPECT_GE(v, invertResponse(response, (value - 0.5) / 255.0) - 1e-12) << "DN " << dn;
            EXPECT_LE(v, invertResponse(response, (value + 0.5) / 255.0) + 1e-12) << "DN " << dn;
            EXPECT_NEAR(linearFromPixel(value, response), v, response == SensorResponse::kLinear ? 0.5 / 255 : 0.0046);
        }
        EXPECT_EQ(out.data()[0], 0);       // below the black level
        EXPECT_EQ(out.data()[1023], 255);  // the top code
        // At every code, the inverse and the curve agree exactly.
        for (int value = 0; value < 256; ++value) {
            const auto byte = static_cast<std::uint8_t>(value);
            EXPECT_EQ(std::lround(255.0 * applyResponse(response, linearFromPixel(byte, response))), value);
        }
    }
    EXPECT_NEAR(applyResponse(SensorResponse::kSrgb, 0.18), 0.4614, 1e-4);  // mid grey
}

TEST(Sensor, RadiometryInvertsTheSensorThroughEightBitPixels) {
    SensorParams params;
    params.color = SensorColor::kMono;
    // Noise-free inverse of the mean.
    for (const double radiance : {0.0, 0.3, 2.5, 4.0}) {
        EXPECT_NEAR(radianceFromDn(params, meanDn(params, radiance)), radiance, 1e-12);
    }
    // A flat field through noise, 8-bit sRGB and back: the mean radiance comes back within 2%, at two exposures.
    const float radiance = radianceFor(params, 3000.0);
    std::vector<double> relative;
    for (const double exposure_us : {10000.0, 5000.0}) {
        params.exposure_us = exposure_us;
        const SensorModel sensor = makeSensor(params, 256, 256);
        Image pixels;
        sensor.encode8(expose(sensor, flatField(256, 256, radiance), 9), pixels);
        double absolute = 0.0;
        double rel = 0.0;
        for (std::size_t i = 0; i < pixels.sizeBytes(); ++i) {
            absolute += radianceFromPixel(pixels.data()[i], params);
            rel += relativeRadianceFromPixel(pixels.data()[i], params);
        }
        absolute /= static_cast<double>(pixels.sizeBytes());
        EXPECT_NEAR(absolute / radiance, 1.0, 0.02) << "exposure " << exposure_us << " us";
        relative.push_back(rel / static_cast<double>(pixels.sizeBytes()));
    }
    // Relative radiance (inverse response / (exposure x gain)) does not depend on the exposure.
    EXPECT_NEAR(relative[1] / relative[0], 1.0, 0.02);
    // 255 is a clipped value: its inverse is only a lower bound, the top of the range.
    EXPECT_EQ(linearFromPixel(255, SensorResponse::kSrgb), 1.0);
    EXPECT_EQ(linearFromPixel(0, SensorResponse::kSrgb), 0.0);
}

}  // namespace
}  // namespace commonlight::mocks::sim

#include "mocks/sim/sensor_params.h"

#include <array>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <utility>

#include "core/yaml_util.h"
#include "core/reader_guard.h"

namespace commonlight::mocks::sim {

namespace {

// A plain number field and its valid range [lo, hi] (or (lo, hi] when lo_open).
struct NumberField {
    std::string_view key;
    double SensorParams::*member;
    double lo;
    double hi;
    bool lo_open;
};

constexpr std::array<NumberField, 8> kNumberFields{{
    {"exposure_us", &SensorParams::exposure_us, 0.0, 1e8, true},
    {"analog_gain", &SensorParams::analog_gain, 0.0, 1000.0, true},
    {"electrons_per_radiance_second", &SensorParams::electrons_per_radiance_second, 0.0, 1e12, true},
    {"full_well_e", &SensorParams::full_well_e, 100.0, 1e7, false},
    {"dark_noise_e", &SensorParams::dark_noise_e, 0.0, 1000.0, false},
    {"dark_current_e_per_s", &SensorParams::dark_current_e_per_s, 0.0, 1e6, false},
    {"dsnu_e", &SensorParams::dsnu_e, 0.0, 1000.0, false},
    {"prnu", &SensorParams::prnu, 0.0, 0.2, false},
}};

// Optional fields: a number or `auto` (unset).
constexpr NumberField kSystemGainField{"system_gain_dn_per_e", nullptr, 0.0, 1000.0, true};
constexpr NumberField kBlackLevelField{"black_level_dn", nullptr, 0.0, 65535.0, false};

constexpr std::string_view kAllKeys =
    "exposure_us, analog_gain, electrons_per_radiance_second, full_well_e, dark_noise_e, dark_current_e_per_s, "
    "dsnu_e, prnu, system_gain_dn_per_e, bits, black_level_dn, response, color or seed";

bool validBits(int bits) { return bits == 8 || bits == 10 || bits == 12 || bits == 14 || bits == 16; }

std::optional<std::string> rangeProblem(const NumberField& field, double value) {
    if (!std::isfinite(value)) return "must be finite";
    const bool below = field.lo_open ? !(value > field.lo) : !(value >= field.lo);
    if (below || !(value <= field.hi)) {
        return yaml::formatNumber(value) + " is out of range " + (field.lo_open ? "(" : "[") +
               yaml::formatNumber(field.lo) + ", " + yaml::formatNumber(field.hi) + "]";
    }
    return std::nullopt;
}

// Strict number parsing: the whole text, no trailing characters (yaml-cpp's as<double> accepts "1abc").
std::optional<std::string> parseNumber(std::string_view text, double& out) {
    const char* begin = text.data();
    const char* end = text.data() + text.size();
    if (begin < end && *begin == '+') ++begin;
    const auto [ptr, ec] = std::from_chars(begin, end, out);
    if (ec == std::errc::result_out_of_range) return "must be finite";
    if (ec != std::errc() || ptr != end) {
        // YAML's spellings of infinity and NaN are numbers, just not usable ones.
        if (text.find("inf") != std::string_view::npos || text.find("nan") != std::string_view::npos ||
            text.find("Inf") != std::string_view::npos || text.find("NaN") != std::string_view::npos) {
            return "must be finite";
        }
        return "expected a number, found '" + std::string(text) + "'";
    }
    if (!std::isfinite(out)) return "must be finite";
    return std::nullopt;
}

template <typename Int>
bool parseInteger(std::string_view text, Int& out) {
    const char* begin = text.data();
    const char* end = text.data() + text.size();
    if (begin < end && *begin == '+') ++begin;
    const auto [ptr, ec] = std::from_chars(begin, end, out);
    return ec == std::errc() && ptr == end;
}

std::optional<std::string> assignNumber(const NumberField& field, std::string_view text, double& out) {
    double value = 0.0;
    if (auto problem = parseNumber(text, value)) return problem;
    if (auto problem = rangeProblem(field, value)) return problem;
    out = value;
    return std::nullopt;
}

std::optional<std::string> assignOptional(const NumberField& field, std::string_view text, std::optional<double>& out) {
    if (text == "auto") {
        out.reset();
        return std::nullopt;
    }
    double value = 0.0;
    if (auto problem = assignNumber(field, text, value)) {
        if (problem->starts_with("expected")) *problem = "expected a number or auto, found '" + std::string(text) + "'";
        return problem;
    }
    out = value;
    return std::nullopt;
}

// What a key takes, for values that are lists or maps.
std::string expectation(std::string_view key) {
    if (key == "bits") return "expected an integer (8, 10, 12, 14 or 16)";
    if (key == "response") return "expected linear, srgb or gamma:G (G in [1, 4])";
    if (key == "color") return "expected rgb or mono";
    if (key == "seed") return "expected an integer in [0, 2^64 - 1]";
    if (key == kSystemGainField.key || key == kBlackLevelField.key) return "expected a number or auto";
    return "expected a number";
}

bool knownKey(std::string_view key) {
    for (const NumberField& field : kNumberFields) {
        if (field.key == key) return true;
    }
    return key == kSystemGainField.key || key == kBlackLevelField.key || key == "bits" || key == "response" ||
           key == "color" || key == "seed";
}

// Sets the field `key` (known) from `text`; returns the problem, if any.
std::optional<std::string> assign(SensorParams& params, std::string_view key, std::string_view text) {
    for (const NumberField& field : kNumberFields) {
        if (field.key == key) return assignNumber(field, text, params.*field.member);
    }
    if (key == kSystemGainField.key) return assignOptional(kSystemGainField, text, params.system_gain_dn_per_e);
    if (key == kBlackLevelField.key) return assignOptional(kBlackLevelField, text, params.black_level_dn);
    if (key == "bits") {
        int bits = 0;
        if (!parseInteger(text, bits) || !validBits(bits))
            return expectation(key) + ", found '" + std::string(text) + "'";
        params.bits = bits;
        return std::nullopt;
    }
    if (key == "response") {
        if (text == "linear") {
            params.response = SensorResponse::kLinear;
        } else if (text == "srgb") {
            params.response = SensorResponse::kSrgb;
        } else if (text.starts_with("gamma:")) {
            double g = 0.0;
            const std::string number(text.substr(6));
            char* end = nullptr;
            g = std::strtod(number.c_str(), &end);
            if (number.empty() || end != number.c_str() + number.size() || !(g >= 1.0 && g <= 4.0)) {
                return expectation(key) + ", found '" + std::string(text) + "'";
            }
            params.response = SensorResponse::kGamma;
            params.gamma = g;
        } else {
            return expectation(key) + ", found '" + std::string(text) + "'";
        }
        return std::nullopt;
    }
    if (key == "color") {
        if (text == "rgb") {
            params.color = SensorColor::kRgb;
        } else if (text == "mono") {
            params.color = SensorColor::kMono;
        } else {
            return expectation(key) + ", found '" + std::string(text) + "'";
        }
        return std::nullopt;
    }
    // seed
    std::uint64_t seed = 0;
    if (!parseInteger(text, seed)) return expectation(key) + ", found '" + std::string(text) + "'";
    params.seed = seed;
    return std::nullopt;
}

// The first field that is out of range, alone or against the others: (key, problem).
std::optional<std::pair<std::string_view, std::string>> firstProblem(const SensorParams& params) {
    for (const NumberField& field : kNumberFields) {
        if (auto problem = rangeProblem(field, params.*field.member)) return std::pair{field.key, *problem};
    }
    if (params.response == SensorResponse::kGamma && !(params.gamma >= 1.0 && params.gamma <= 4.0)) {
        return std::pair{std::string_view("response"),
                         "gamma " + yaml::formatNumber(params.gamma) + " is out of range [1, 4]"};
    }
    if (!validBits(params.bits)) {
        return std::pair{std::string_view("bits"), expectation("bits") + ", found " + std::to_string(params.bits)};
    }
    if (params.system_gain_dn_per_e) {
        if (auto problem = rangeProblem(kSystemGainField, *params.system_gain_dn_per_e)) {
            return std::pair{kSystemGainField.key, *problem};
        }
    }
    if (params.black_level_dn) {
        // The black level must leave room for a signal: below the top code of this bit depth.
        const NumberField field{kBlackLevelField.key, nullptr, 0.0, params.maxDn() - 1.0, false};
        if (auto problem = rangeProblem(field, *params.black_level_dn)) {
            return std::pair{kBlackLevelField.key, *problem + " for " + std::to_string(params.bits) + " bits"};
        }
    }
    return std::nullopt;
}

}  // namespace

std::string_view sensorResponseName(SensorResponse response) noexcept {
    switch (response) {
        case SensorResponse::kLinear: return "linear";
        case SensorResponse::kSrgb: return "srgb";
        case SensorResponse::kGamma: return "gamma";
    }
    return "srgb";
}

std::string sensorResponseSpec(const SensorParams& params) {
    if (params.response != SensorResponse::kGamma) return std::string(sensorResponseName(params.response));
    return "gamma:" + yaml::formatNumber(params.gamma);
}

std::string_view sensorColorName(SensorColor color) noexcept { return color == SensorColor::kRgb ? "rgb" : "mono"; }

double SensorParams::blackLevelDn() const noexcept {
    return black_level_dn ? *black_level_dn : static_cast<double>(1 << (bits - 4));
}

double SensorParams::systemGainDnPerE() const noexcept {
    return system_gain_dn_per_e ? *system_gain_dn_per_e : (maxDn() - blackLevelDn()) / full_well_e;
}

Result<void> SensorParams::validate() const {
    if (auto problem = firstProblem(*this)) {
        return fail(ErrorCode::kBadInput, "sensor key '" + std::string(problem->first) + "': " + problem->second);
    }
    return {};
}

Result<SensorParams> parseSensorParams(const std::string& file, const YAML::Node& node, std::string_view path) {
    return guardReader(file, [&]() -> Result<SensorParams> {
        SensorParams params;
        // An absent or empty `sensor:` keeps every default.
        if (!node.IsDefined() || node.IsNull()) return params;
        CL_TRY_VOID(yaml::checkKeys(file, node, path,
                                    {"exposure_us", "analog_gain", "electrons_per_radiance_second", "full_well_e",
                                     "dark_noise_e", "dark_current_e_per_s", "dsnu_e", "prnu", "system_gain_dn_per_e",
                                     "bits", "black_level_dn", "response", "color", "seed"}));
        for (auto it = node.begin(); it != node.end(); ++it) {
            const YAML::Node key_node = it->first;
            const YAML::Node value = it->second;
            const std::string& key = key_node.Scalar();
            const std::string key_path = yaml::joinKey(path, key);
            if (!value.IsDefined() || value.IsNull())
                return fail(yaml::keyError(file, key_node, key_path, "missing value"));
            if (!value.IsScalar()) {
                return fail(yaml::keyError(file, value, key_path,
                                           expectation(key) + (value.IsSequence() ? ", found a list" : ", found a map")));
            }
            if (auto problem = assign(params, key, value.Scalar())) {
                return fail(yaml::keyError(file, value, key_path, *problem));
            }
        }
        // Fields against each other (the black level against the bit depth), at the line of the key at fault.
        if (auto problem = firstProblem(params)) {
            const YAML::Node at = node[std::string(problem->first)];
            return fail(
                yaml::keyError(file, at.IsDefined() ? at : node, yaml::joinKey(path, problem->first), problem->second));
        }
        return params;
    });
}

Result<void> setSensorParam(SensorParams& params, std::string_view key, std::string_view value) {
    std::string name(key);
    for (char& c : name) c = c == '-' ? '_' : c;
    std::string option = "--sensor-" + name;
    for (char& c : option) c = c == '_' ? '-' : c;
    if (!knownKey(name)) {
        std::string expected(kAllKeys);
        for (char& c : expected) c = c == '_' ? '-' : c;
        return fail(ErrorCode::kUsage, option + ": unknown sensor parameter (expected " + expected + ")");
    }
    if (auto problem = assign(params, name, value)) return fail(ErrorCode::kUsage, option + ": " + *problem);
    return {};
}

std::string formatSensorParams(const SensorParams& params) {
    std::string out = "{";
    for (const NumberField& field : kNumberFields) {
        out += std::string(field.key) + ": " + yaml::formatNumber(params.*field.member) + ", ";
    }
    if (params.system_gain_dn_per_e) {
        out += "system_gain_dn_per_e: " + yaml::formatNumber(*params.system_gain_dn_per_e) + ", ";
    }
    out += "bits: " + std::to_string(params.bits) + ", ";
    if (params.black_level_dn) out += "black_level_dn: " + yaml::formatNumber(*params.black_level_dn) + ", ";
    out += "response: " + sensorResponseSpec(params) + ", ";
    out += "color: " + std::string(sensorColorName(params.color)) + ", ";
    out += "seed: " + std::to_string(params.seed) + "}";
    return out;
}

}  // namespace commonlight::mocks::sim

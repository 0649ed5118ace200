#include "core/response.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <span>

#include "core/file_util.h"
#include "core/yaml_util.h"
#include "core/reader_guard.h"

namespace commonlight {

float srgbToLinear(float encoded) noexcept {
    const float e = std::clamp(encoded, 0.0f, 1.0f);
    return e <= 0.04045f ? e / 12.92f : std::pow((e + 0.055f) / 1.055f, 2.4f);
}

float linearToSrgb(float linear) noexcept {
    const float v = std::clamp(linear, 0.0f, 1.0f);
    return v <= 0.0031308f ? 12.92f * v : 1.055f * std::pow(v, 1.0f / 2.4f) - 0.055f;
}

ResponseCurve::ResponseCurve() : ResponseCurve(srgb()) {}

ResponseCurve::ResponseCurve(Kind kind) : kind_(kind) {
    for (int c = 0; c < 3; ++c) {
        for (int code = 0; code < 256; ++code) lut_[c][code] = static_cast<float>(code) / 255.0f;
    }
    name_ = "linear";
}

ResponseCurve ResponseCurve::srgb() {
    ResponseCurve r(Kind::kSrgb);
    r.name_ = "srgb";
    for (int c = 0; c < 3; ++c) {
        for (int code = 0; code < 256; ++code) r.lut_[c][code] = srgbToLinear(static_cast<float>(code) / 255.0f);
    }
    return r;
}

ResponseCurve ResponseCurve::linear() { return ResponseCurve(Kind::kLinear); }

Result<ResponseCurve> ResponseCurve::gamma(double gamma) {
    if (!std::isfinite(gamma) || gamma < 0.2 || gamma > 5.0) {
        char msg[128];
        std::snprintf(msg, sizeof msg, "response gamma %g is out of range [0.2, 5]", gamma);
        return fail(ErrorCode::kBadInput, msg);
    }
    ResponseCurve r(Kind::kGamma);
    r.gamma_ = gamma;
    char name[64];
    std::snprintf(name, sizeof name, "gamma:%g", gamma);
    r.name_ = name;
    for (int c = 0; c < 3; ++c) {
        for (int code = 0; code < 256; ++code) {
            r.lut_[c][code] = static_cast<float>(std::pow(code / 255.0, gamma));
        }
    }
    return r;
}

Result<ResponseCurve> ResponseCurve::fromTable(const Table& table, std::string origin) {
    static constexpr const char* kChannel[3] = {"r", "g", "b"};
    for (int c = 0; c < 3; ++c) {
        for (int code = 0; code < 256; ++code) {
            const float v = table[c][code];
            if (!std::isfinite(v) || v < 0.0f || v > 1.0f) {
                return fail(ErrorCode::kBadInput, origin + ": key 'response." + kChannel[c] + "': value " +
                                                      std::to_string(v) + " of code " + std::to_string(code) +
                                                      " is not in [0, 1]");
            }
            if (code > 0 && v < table[c][code - 1]) {
                return fail(ErrorCode::kBadInput, origin + ": key 'response." + kChannel[c] + "': decreases at code " +
                                                      std::to_string(code) + " (a response must be non-decreasing)");
            }
        }
        if (!(table[c][255] > table[c][0])) {
            return fail(ErrorCode::kBadInput,
                        origin + ": key 'response." + kChannel[c] + "': constant (a response must increase)");
        }
    }
    ResponseCurve r(Kind::kTable);
    r.lut_ = table;
    r.name_ = std::move(origin);
    return r;
}

Result<ResponseCurve> ResponseCurve::parse(std::string_view spec, const std::filesystem::path& base_dir) {
    if (spec == "srgb") return srgb();
    if (spec == "linear") return linear();
    if (spec.starts_with("gamma:")) {
        const std::string_view number = spec.substr(6);
        double g = 0.0;
        const auto [end, ec] = std::from_chars(number.data(), number.data() + number.size(), g);
        if (ec != std::errc() || end != number.data() + number.size()) {
            return fail(ErrorCode::kBadInput, "response '" + std::string(spec) + "': expected gamma:<number>");
        }
        return gamma(g);
    }
    if (spec.empty()) return fail(ErrorCode::kBadInput, "response: empty (expected srgb, linear, gamma:G or a file)");
    std::filesystem::path file(spec);
    if (file.is_relative() && !base_dir.empty()) file = base_dir / file;
    return readFile(file);
}

Result<ResponseCurve> ResponseCurve::readFile(const std::filesystem::path& file) {
    return guardReader(file, [&]() -> Result<ResponseCurve> {
        std::error_code ec;
        if (!std::filesystem::is_regular_file(file, ec)) {
            return fail(ErrorCode::kNotFound, file.string() + ": response file not found (expected srgb, linear, "
                                                              "gamma:G or a response file)");
        }
        const std::string name = file.string();
        CL_TRY(YAML::Node root, yaml::loadFile(file));
        CL_TRY_VOID(yaml::checkKeys(name, root, "", {"response"}));
        if (!yaml::has(root, "response")) return fail(ErrorCode::kBadInput, name + ": key 'response': missing");
        const YAML::Node node = root["response"];
        CL_TRY_VOID(yaml::checkKeys(name, node, "response", {"type", "method", "r", "g", "b", "bits"}));
        CL_TRY(std::string type, yaml::getString(name, node, "response.type"));
        if (type != "table") {
            return fail(yaml::keyError(name, yaml::findKey(node, "type"), "response.type",
                                       "'" + type + "' is not a response type (expected table)"));
        }
        Table table{};
        static constexpr const char* kKeys[3] = {"response.r", "response.g", "response.b"};
        for (int c = 0; c < 3; ++c) {
            CL_TRY(std::vector<double> values, yaml::getDoubles(name, node, kKeys[c], 256));
            for (int code = 0; code < 256; ++code) table[c][code] = static_cast<float>(values[code]);
        }
        return fromTable(table, name);
    });
}

Result<void> ResponseCurve::writeFile(const std::filesystem::path& file, std::string_view method) const {
    std::string text = "# camera response: linear value in [0, 1] of each 8-bit code, per channel (docs/radiometry.md)\n";
    text += "response:\n  type: table\n  method: " + std::string(method) + "\n";
    static constexpr const char* kKeys[3] = {"r", "g", "b"};
    for (int c = 0; c < 3; ++c) {
        text += "  " + std::string(kKeys[c]) + ": [";
        for (int code = 0; code < 256; ++code) {
            char value[32];
            std::snprintf(value, sizeof value, "%s%.9g", code == 0 ? "" : ", ", static_cast<double>(lut_[c][code]));
            text += value;
        }
        text += "]\n";
    }
    const auto* bytes = reinterpret_cast<const std::uint8_t*>(text.data());
    return writeFileAtomic(file, std::span<const std::uint8_t>(bytes, text.size()));
}

float ResponseCurve::toLinear(int channel, float encoded) const noexcept {
    if (kind_ == Kind::kSrgb) return srgbToLinear(encoded);
    if (kind_ == Kind::kLinear) return std::clamp(encoded, 0.0f, 1.0f);
    if (kind_ == Kind::kGamma) return std::pow(std::clamp(encoded, 0.0f, 1.0f), static_cast<float>(gamma_));
    const float x = std::clamp(encoded, 0.0f, 1.0f) * 255.0f;
    const int i = std::min(static_cast<int>(x), 254);
    const float f = x - static_cast<float>(i);
    return lut_[channel][i] * (1.0f - f) + lut_[channel][i + 1] * f;
}

float ResponseCurve::toEncoded(int channel, float linear_value) const noexcept {
    const float v = std::clamp(linear_value, 0.0f, 1.0f);
    if (kind_ == Kind::kSrgb) return linearToSrgb(v);
    if (kind_ == Kind::kLinear) return v;
    if (kind_ == Kind::kGamma) return std::pow(v, 1.0f / static_cast<float>(gamma_));
    // Table: the code interval holding v (the table is non-decreasing), interpolated.
    const auto& t = lut_[channel];
    if (v <= t[0]) return 0.0f;
    if (v >= t[255]) return 1.0f;
    const auto it = std::upper_bound(t.begin(), t.end(), v);
    const int hi = static_cast<int>(it - t.begin());
    const int lo = hi - 1;
    const float span = t[hi] - t[lo];
    const float f = span > 0.0f ? (v - t[lo]) / span : 0.0f;  // a flat step: its lower code
    return (static_cast<float>(lo) + f) / 255.0f;
}

}  // namespace commonlight

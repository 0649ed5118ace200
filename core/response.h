// The camera's response: how linear light (what the sensor integrated, normalised to [0, 1] of
// the top code) became the 8-bit values it delivers, and back.
//
// Radiance inside lighting and render is linear and relative (DESIGN.md section 3):
//     relative radiance = toLinear(code) / (exposure_s x analog_gain)
// The response travels with the camera source: sensor.yaml's `response` for sequences, what a
// backend reads from the device (GenICam Gamma, the V4L2 gamma control), or `--response` on
// the command line. Specifications (parse()):
//     srgb            the sRGB OETF (IEC 61966-2-1), what a webcam's ISP applies
//     linear          code = 255 x linear (machine-vision cameras)
//     gamma:G         code = 255 x linear^(1/G), G in [0.2, 5] (a camera's Gamma setting; gamma:1 = linear)
//     <file>          a response file (response.yaml, written by `commonlight calibrate-response`)
//
// Response file (YAML):
//     response:
//       type: table
//       method: debevec            # how it was measured (informational)
//       r: [256 values]            # linear value of codes 0..255, non-decreasing, in [0, 1]
//       g: [256 values]
//       b: [256 values]
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>

#include "core/result.h"

namespace commonlight {

class ResponseCurve {
public:
    enum class Kind { kSrgb, kLinear, kGamma, kTable };
    using Table = std::array<std::array<float, 256>, 3>;  // [channel][code] -> linear in [0, 1]

    ResponseCurve();  // sRGB
    static ResponseCurve srgb();
    static ResponseCurve linear();
    // code = 255 * linear^(1/gamma); fails (kBadInput) outside [0.2, 5] or when not finite.
    static Result<ResponseCurve> gamma(double gamma);
    // A measured table: per channel, 256 linear values, finite, in [0, 1], non-decreasing, not
    // all equal. `origin` names the table in errors and in name().
    static Result<ResponseCurve> fromTable(const Table& table, std::string origin);
    // "srgb" | "linear" | "gamma:G" | a file path (relative paths against `base_dir`). Errors
    // name the specification or the file and key (kBadInput, kNotFound).
    static Result<ResponseCurve> parse(std::string_view spec, const std::filesystem::path& base_dir = {});
    static Result<ResponseCurve> readFile(const std::filesystem::path& file);
    // Writes the table form (any kind can be written: its table is sampled). `method` goes into
    // the file's `method` key.
    Result<void> writeFile(const std::filesystem::path& file, std::string_view method) const;

    Kind kind() const noexcept { return kind_; }
    double gammaValue() const noexcept { return gamma_; }
    // "srgb", "linear", "gamma:2.2", or the table's origin (its file).
    const std::string& name() const noexcept { return name_; }

    // Linear value in [0, 1] of an 8-bit code, per channel (0 r, 1 g, 2 b).
    float toLinear(int channel, std::uint8_t code) const noexcept { return lut_[channel][code]; }
    // Linear value of an encoded value in [0, 1] (interpolated between codes for tables).
    float toLinear(int channel, float encoded) const noexcept;
    // Encoded value in [0, 1] of a linear value (clamped to [0, 1]); the inverse of toLinear.
    float toEncoded(int channel, float linear) const noexcept;
    const Table& table() const noexcept { return lut_; }

    bool operator==(const ResponseCurve& other) const { return kind_ == other.kind_ && gamma_ == other.gamma_ && lut_ == other.lut_; }

private:
    explicit ResponseCurve(Kind kind);  // identity table, named "linear"

    Kind kind_ = Kind::kSrgb;
    double gamma_ = 0.0;
    std::string name_;
    Table lut_{};
};

// The sRGB OETF and its inverse on [0, 1] (IEC 61966-2-1).
float srgbToLinear(float encoded) noexcept;
float linearToSrgb(float linear) noexcept;

}  // namespace commonlight

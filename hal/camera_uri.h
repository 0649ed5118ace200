// Camera URIs (docs/cli.md): "<scheme>:<path>[?key=value&key=value...]", for example
//   v4l2:/dev/video0?width=1280&height=720&format=mjpeg
//   replay:data/sample?rate=max&loop=1
// Options common to every camera: width, height, fps, format, exposure_us, gain.
#pragma once

#include <map>
#include <optional>
#include <string>
#include <string_view>

#include "core/result.h"
#include "hal/camera.h"

namespace commonlight::hal {

struct CameraUri {
    std::string text;    // as given, for messages
    std::string scheme;  // "v4l2", "replay", ...
    std::string path;    // after the scheme, percent-decoded
    std::map<std::string, std::string, std::less<>> options;

    std::optional<std::string_view> option(std::string_view key) const;
    // Typed option access; a malformed value is a kUsage error naming the URI and the key.
    Result<std::optional<double>> number(std::string_view key) const;
    Result<std::optional<long long>> integer(std::string_view key) const;
    Result<std::optional<bool>> flag(std::string_view key) const;  // 0/1/true/false/yes/no/on/off
};

// Syntax only: "scheme:path?k=v&...". Errors (kUsage) name the URI.
Result<CameraUri> parseCameraUri(std::string_view text);

// The options every camera accepts.
inline constexpr std::string_view kCommonOptions[] = {"width", "height", "fps", "format", "exposure_us", "gain"};

// width/height/fps/format as a StreamConfig (kUsage on malformed values).
Result<StreamConfig> streamConfigFromUri(const CameraUri& uri);

}  // namespace commonlight::hal

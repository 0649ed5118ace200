#include "hal/camera_uri.h"

#include <cctype>
#include <charconv>
#include <cmath>

namespace commonlight::hal {

namespace {

Error usage(const std::string& uri, const std::string& problem) {
    return Error{ErrorCode::kUsage, "camera URI '" + uri + "': " + problem};
}

Result<std::string> percentDecode(std::string_view in, const std::string& uri) {
    std::string out;
    out.reserve(in.size());
    for (std::size_t i = 0; i < in.size(); ++i) {
        if (in[i] != '%') {
            out += in[i];
            continue;
        }
        if (i + 2 >= in.size() || !std::isxdigit(static_cast<unsigned char>(in[i + 1])) ||
            !std::isxdigit(static_cast<unsigned char>(in[i + 2]))) {
            return fail(usage(uri, "bad percent escape"));
        }
        int value = 0;
        std::from_chars(in.data() + i + 1, in.data() + i + 3, value, 16);
        out += static_cast<char>(value);
        i += 2;
    }
    return out;
}

}  // namespace

std::optional<std::string_view> CameraUri::option(std::string_view key) const {
    const auto it = options.find(key);
    if (it == options.end()) return std::nullopt;
    return std::string_view(it->second);
}

Result<std::optional<double>> CameraUri::number(std::string_view key) const {
    const auto value = option(key);
    if (!value) return std::optional<double>();
    double parsed = 0.0;
    const auto [ptr, ec] = std::from_chars(value->data(), value->data() + value->size(), parsed);
    if (ec != std::errc() || ptr != value->data() + value->size() || !std::isfinite(parsed)) {
        return fail(usage(text, "option '" + std::string(key) + "' needs a number, got '" + std::string(*value) + "'"));
    }
    return std::optional<double>(parsed);
}

Result<std::optional<long long>> CameraUri::integer(std::string_view key) const {
    const auto value = option(key);
    if (!value) return std::optional<long long>();
    long long parsed = 0;
    const auto [ptr, ec] = std::from_chars(value->data(), value->data() + value->size(), parsed);
    if (ec != std::errc() || ptr != value->data() + value->size()) {
        return fail(usage(text, "option '" + std::string(key) + "' needs an integer, got '" + std::string(*value) + "'"));
    }
    return std::optional<long long>(parsed);
}

Result<std::optional<bool>> CameraUri::flag(std::string_view key) const {
    const auto value = option(key);
    if (!value) return std::optional<bool>();
    if (*value == "1" || *value == "true" || *value == "yes" || *value == "on") return std::optional<bool>(true);
    if (*value == "0" || *value == "false" || *value == "no" || *value == "off") return std::optional<bool>(false);
    return fail(usage(text, "option '" + std::string(key) + "' needs 0 or 1, got '" + std::string(*value) + "'"));
}

Result<CameraUri> parseCameraUri(std::string_view text) {
    CameraUri uri;
    uri.text = std::string(text);
    const auto colon = text.find(':');
    if (colon == std::string_view::npos || colon == 0) {
        return fail(usage(uri.text, "expected <scheme>:<device>, e.g. v4l2:/dev/video0 or replay:path/to/sequence"));
    }
    uri.scheme = std::string(text.substr(0, colon));
    for (char c : uri.scheme) {
        if (!std::islower(static_cast<unsigned char>(c)) && !std::isdigit(static_cast<unsigned char>(c))) {
            return fail(usage(uri.text, "scheme '" + uri.scheme + "' must be lower-case letters and digits"));
        }
    }
    std::string_view rest = text.substr(colon + 1);
    const auto question = rest.find('?');
    CL_TRY(uri.path, percentDecode(rest.substr(0, question), uri.text));
    if (question != std::string_view::npos) {
        std::string_view query = rest.substr(question + 1);
        while (!query.empty()) {
            const auto amp = query.find('&');
            const std::string_view pair = query.substr(0, amp);
            query = amp == std::string_view::npos ? std::string_view() : query.substr(amp + 1);
            if (pair.empty()) continue;
            const auto eq = pair.find('=');
            if (eq == std::string_view::npos || eq == 0) {
                return fail(usage(uri.text, "option '" + std::string(pair) + "' must be key=value"));
            }
            CL_TRY(std::string key, percentDecode(pair.substr(0, eq), uri.text));
            CL_TRY(std::string value, percentDecode(pair.substr(eq + 1), uri.text));
            if (uri.options.contains(key)) return fail(usage(uri.text, "option '" + key + "' given twice"));
            uri.options.emplace(std::move(key), std::move(value));
        }
    }
    return uri;
}

Result<StreamConfig> streamConfigFromUri(const CameraUri& uri) {
    StreamConfig config;
    CL_TRY(const auto width, uri.integer("width"));
    CL_TRY(const auto height, uri.integer("height"));
    CL_TRY(const auto fps, uri.number("fps"));
    if (width) {
        if (*width <= 0 || *width > 65535) return fail(usage(uri.text, "width must be in 1..65535"));
        config.width = static_cast<int>(*width);
    }
    if (height) {
        if (*height <= 0 || *height > 65535) return fail(usage(uri.text, "height must be in 1..65535"));
        config.height = static_cast<int>(*height);
    }
    if (fps) {
        if (*fps <= 0) return fail(usage(uri.text, "fps must be positive"));
        config.fps = *fps;
    }
    if (const auto format = uri.option("format")) {
        const auto parsed = parsePixelFormat(*format);
        if (!parsed) return fail(usage(uri.text, "unknown format '" + std::string(*format) + "'"));
        config.format = *parsed;
    }
    return config;
}

}  // namespace commonlight::hal

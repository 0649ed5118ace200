// Camera backends keyed by URI scheme. The application builds one registry and registers the
// backends it was built with (hal::registerHardwareBackends, mocks::registerMockBackends).
#pragma once

#include <functional>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "core/result.h"
#include "hal/camera.h"
#include "hal/camera_uri.h"

namespace commonlight::hal {

struct Backend {
    std::string scheme;       // "v4l2", "replay", ...
    std::string description;  // one line for --help
    std::vector<std::string> options;  // options this scheme accepts besides kCommonOptions
    // Opens the camera the URI names (state Opened). Options are already validated.
    std::function<Result<std::unique_ptr<Camera>>(const CameraUri&)> open;
    // Lists the cameras present; empty function when the backend cannot enumerate.
    std::function<Result<std::vector<CameraInfo>>()> enumerate;
};

// Wraps any camera when one of its options appears in a URI (fault injection, say).
struct Wrapper {
    std::string name;
    std::vector<std::string> options;
    std::function<Result<std::unique_ptr<Camera>>(std::unique_ptr<Camera>, const CameraUri&)> wrap;
};

struct EnumerationResult {
    std::vector<CameraInfo> cameras;
    std::vector<Error> errors;  // one per backend that failed to enumerate; the others still list
};

class CameraRegistry {
public:
    void add(Backend backend);
    void addWrapper(Wrapper wrapper);

    const std::vector<Backend>& backends() const noexcept { return backends_; }
    const Backend* find(std::string_view scheme) const noexcept;

    // Parses and validates a URI: unknown scheme or option -> kUsage, listing what is accepted.
    Result<CameraUri> parse(std::string_view uri) const;
    // Opens a camera (state Opened), wrapped as the URI asks.
    Result<std::unique_ptr<Camera>> open(std::string_view uri) const;
    // Opens, configures from width/height/fps/format and applies exposure_us and gain.
    Result<std::unique_ptr<Camera>> openConfigured(std::string_view uri) const;

    EnumerationResult enumerate() const;

private:
    std::vector<Backend> backends_;
    std::vector<Wrapper> wrappers_;
};

}  // namespace commonlight::hal

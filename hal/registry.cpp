#include "hal/registry.h"

#include <algorithm>

namespace commonlight::hal {

void CameraRegistry::add(Backend backend) {
    backends_.erase(std::remove_if(backends_.begin(), backends_.end(),
                                   [&](const Backend& b) { return b.scheme == backend.scheme; }),
                    backends_.end());
    backends_.push_back(std::move(backend));
}

void CameraRegistry::addWrapper(Wrapper wrapper) { wrappers_.push_back(std::move(wrapper)); }

const Backend* CameraRegistry::find(std::string_view scheme) const noexcept {
    for (const auto& b : backends_) {
        if (b.scheme == scheme) return &b;
    }
    return nullptr;
}

namespace {

std::string join(const std::vector<std::string>& items) {
    std::string out;
    for (const auto& s : items) {
        if (!out.empty()) out += ", ";
        out += s;
    }
    return out;
}

}  // namespace

Result<CameraUri> CameraRegistry::parse(std::string_view text) const {
    CL_TRY(CameraUri uri, parseCameraUri(text));
    const Backend* backend = find(uri.scheme);
    if (backend == nullptr) {
        std::vector<std::string> schemes;
        for (const auto& b : backends_) schemes.push_back(b.scheme + ":");
        return fail(ErrorCode::kUsage, "camera URI '" + uri.text + "': unknown scheme '" + uri.scheme +
                                           "' (this build knows: " + join(schemes) + ")");
    }
    for (const auto& [key, value] : uri.options) {
        const auto in = [&](const auto& list) { return std::find(std::begin(list), std::end(list), key) != std::end(list); };
        if (in(kCommonOptions) || in(backend->options)) continue;
        if (std::any_of(wrappers_.begin(), wrappers_.end(), [&](const Wrapper& w) { return in(w.options); })) continue;
        std::vector<std::string> accepted(std::begin(kCommonOptions), std::end(kCommonOptions));
        accepted.insert(accepted.end(), backend->options.begin(), backend->options.end());
        for (const auto& w : wrappers_) accepted.insert(accepted.end(), w.options.begin(), w.options.end());
        return fail(ErrorCode::kUsage, "camera URI '" + uri.text + "': unknown option '" + key + "' (" + uri.scheme +
                                           ": accepts " + join(accepted) + ")");
    }
    return uri;
}

Result<std::unique_ptr<Camera>> CameraRegistry::open(std::string_view text) const {
    CL_TRY(const CameraUri uri, parse(text));
    CL_TRY(std::unique_ptr<Camera> camera, find(uri.scheme)->open(uri));
    for (const auto& wrapper : wrappers_) {
        const bool wanted = std::any_of(wrapper.options.begin(), wrapper.options.end(),
                                        [&](const std::string& o) { return uri.options.contains(o); });
        if (wanted) {
            CL_TRY(camera, wrapper.wrap(std::move(camera), uri));
        }
    }
    return camera;
}

Result<std::unique_ptr<Camera>> CameraRegistry::openConfigured(std::string_view text) const {
    CL_TRY(const CameraUri uri, parse(text));
    CL_TRY(const StreamConfig config, streamConfigFromUri(uri));
    CL_TRY(std::unique_ptr<Camera> camera, open(text));
    CL_TRY_VOID(camera->configure(config));
    CL_TRY(const auto exposure, uri.number("exposure_us"));
    CL_TRY(const auto gain, uri.number("gain"));
    if (exposure) {
        // Cameras without auto exposure have nothing to turn off.
        if (auto off = camera->setControl(Control::kAutoExposure, 0.0); !off && off.error().code != ErrorCode::kUnsupported) {
            return fail(off.error());
        }
        CL_TRY_VOID(camera->setControl(Control::kExposureUs, *exposure));
    }
    if (gain) {
        CL_TRY_VOID(camera->setControl(Control::kAnalogGain, *gain));
    }
    return camera;
}

EnumerationResult CameraRegistry::enumerate() const {
    EnumerationResult result;
    for (const auto& backend : backends_) {
        if (!backend.enumerate) continue;
        auto cameras = backend.enumerate();
        if (!cameras) {
            result.errors.push_back(cameras.error());
            continue;
        }
        for (auto& c : *cameras) result.cameras.push_back(std::move(c));
    }
    return result;
}

}  // namespace commonlight::hal

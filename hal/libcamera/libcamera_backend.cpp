#include "hal/libcamera/libcamera_backend.h"

#include "hal/libcamera/libcamera_camera.h"
#include "hal/libcamera/libcamera_device.h"
#include "hal/libcamera/mapping.h"

namespace commonlight::hal::libcamera_backend {

namespace {

Result<LibcameraOptions> optionsFromUri(const CameraUri& uri) {
    LibcameraOptions options;
    if (const auto role = uri.option("role")) {
        CL_TRY(options.role, parseStreamRole(*role, uri.text));
    }
    CL_TRY(const auto buffers, uri.integer("buffers"));
    if (buffers) {
        if (*buffers < 1 || *buffers > 32) {
            return fail(ErrorCode::kUsage, uri.text + ": buffers must be between 1 and 32");
        }
        options.buffers = static_cast<unsigned>(*buffers);
    }
    return options;
}

Result<std::unique_ptr<Camera>> open(const CameraUri& uri) {
    if (uri.path.empty()) {
        return fail(ErrorCode::kUsage, uri.text + ": name a camera: libcamera:<index> or libcamera:<camera id> (see `commonlight cameras`)");
    }
    CL_TRY(const LibcameraOptions options, optionsFromUri(uri));
    CL_TRY(std::unique_ptr<Device> device, openDevice(uri.path, uri.text));
    return std::unique_ptr<Camera>(std::make_unique<LibcameraCamera>(uri.text, std::move(device), options));
}

// Camera ids are paths or USB topology strings; escape what a URI path cannot hold as is.
std::string escapeForUri(std::string_view id) {
    std::string out;
    for (char c : id) {
        switch (c) {
            case '%': out += "%25"; break;
            case '?': out += "%3F"; break;
            case '&': out += "%26"; break;
            case ' ': out += "%20"; break;
            default: out += c;
        }
    }
    return out;
}

Result<std::vector<CameraInfo>> enumerate() {
    CL_TRY(const std::vector<CameraListing> cameras, listCameras(StreamRole::kViewfinder));
    std::vector<CameraInfo> out;
    for (const auto& camera : cameras) {
        out.push_back({"libcamera:" + escapeForUri(camera.id), camera.model, "libcamera", offeredFormats(camera.formats)});
    }
    return out;
}

}  // namespace

void registerBackend(CameraRegistry& registry) {
    registry.add(Backend{
        "libcamera",
        "a camera through libcamera: libcamera:<index or camera id>?role=viewfinder|video|still|raw&buffers=<n>",
        {"role", "buffers"},
        open,
        enumerate,
    });
}

}  // namespace commonlight::hal::libcamera_backend

#include "hal/v4l2/v4l2_backend.h"

#include <algorithm>
#include <cctype>

#include "hal/v4l2/v4l2_camera.h"

namespace commonlight::hal::v4l2 {

namespace {

Result<std::unique_ptr<Camera>> openUri(const CameraUri& uri) {
    V4l2Options options;
    CL_TRY(const auto buffers, uri.integer("buffers"));
    if (buffers) {
        if (*buffers < 2 || *buffers > 32) return fail(ErrorCode::kUsage, uri.text + ": buffers must be between 2 and 32");
        options.buffers = static_cast<int>(*buffers);
    }
    CL_TRY(const auto timeout, uri.integer("timeout_ms"));
    if (timeout) {
        if (*timeout < 0 || *timeout > 3'600'000) return fail(ErrorCode::kUsage, uri.text + ": timeout_ms must be between 0 and 3600000");
        options.timeout_ms = static_cast<int>(*timeout);
    }
    std::string path = uri.path;
    if (path.empty()) return fail(ErrorCode::kUsage, uri.text + ": name a device, e.g. v4l2:/dev/video0");
    // v4l2:0 is /dev/video0.
    if (std::all_of(path.begin(), path.end(), [](unsigned char c) { return std::isdigit(c) != 0; })) {
        path = "/dev/video" + path;
    }
    CL_TRY(auto camera, V4l2Camera::open(realSystem(), path, options));
    return std::unique_ptr<Camera>(std::move(camera));
}

}  // namespace

void registerBackend(CameraRegistry& registry) {
    Backend backend;
    backend.scheme = "v4l2";
    backend.description = "Video4Linux2 capture device: v4l2:/dev/videoN (or v4l2:N); YUYV, MJPEG, NV12, GREY";
    backend.options = {"buffers", "timeout_ms"};
    backend.open = openUri;
    backend.enumerate = []() -> Result<std::vector<CameraInfo>> { return enumerateCameras(realSystem()); };
    registry.add(std::move(backend));
}

}  // namespace commonlight::hal::v4l2

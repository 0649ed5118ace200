#include "hal/aravis/aravis_backend.h"

#include "hal/aravis/aravis_camera.h"

namespace commonlight::hal::aravis {

void registerBackend(CameraRegistry& registry) {
    Backend backend;
    backend.scheme = "aravis";
    backend.description = "GigE Vision / USB3 Vision camera through Aravis: aravis:<address or device id>";
    backend.options = aravisOptionNames();
    backend.open = [](const CameraUri& uri) -> Result<std::unique_ptr<Camera>> {
        CL_TRY(auto camera, AravisCamera::open(uri));
        return std::unique_ptr<Camera>(std::move(camera));
    };
    backend.enumerate = enumerateCameras;
    registry.add(std::move(backend));
}

}  // namespace commonlight::hal::aravis

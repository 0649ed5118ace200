#include "hal/hardware.h"

// Each backend folder adds its sources to commonlight::hal and defines COMMONLIGHT_HAVE_<NAME>
// when its library was found (hal/CMakeLists.txt).
#ifdef COMMONLIGHT_HAVE_V4L2
#include "hal/v4l2/v4l2_backend.h"
#endif
#ifdef COMMONLIGHT_HAVE_LIBCAMERA
#include "hal/libcamera/libcamera_backend.h"
#endif
#ifdef COMMONLIGHT_HAVE_ARAVIS
#include "hal/aravis/aravis_backend.h"
#endif

namespace commonlight::hal {

void registerHardwareBackends([[maybe_unused]] CameraRegistry& registry) {
#ifdef COMMONLIGHT_HAVE_V4L2
    v4l2::registerBackend(registry);
#endif
#ifdef COMMONLIGHT_HAVE_LIBCAMERA
    libcamera_backend::registerBackend(registry);
#endif
#ifdef COMMONLIGHT_HAVE_ARAVIS
    aravis::registerBackend(registry);
#endif
}

std::vector<LeftOutBackend> leftOutBackends() {
    std::vector<LeftOutBackend> out;
#ifndef COMMONLIGHT_HAVE_V4L2
    out.push_back({"v4l2", "built without linux/videodev2.h and libv4l-dev"});
#endif
#ifndef COMMONLIGHT_HAVE_LIBCAMERA
    out.push_back({"libcamera", "built without libcamera-dev"});
#endif
#ifndef COMMONLIGHT_HAVE_ARAVIS
    out.push_back({"aravis", "built without libaravis-dev"});
#endif
    return out;
}

}  // namespace commonlight::hal

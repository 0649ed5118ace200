// Registers the libcamera backend: `libcamera:<index or camera id>[?role=...&buffers=N]`
// (docs/cameras-libcamera.md).
#pragma once

#include "hal/registry.h"

namespace commonlight::hal::libcamera_backend {

void registerBackend(CameraRegistry& registry);

}  // namespace commonlight::hal::libcamera_backend

// Registers the "v4l2" camera scheme: v4l2:/dev/videoN[?buffers=4&timeout_ms=10000] (or v4l2:N).
#pragma once

#include "hal/registry.h"

namespace commonlight::hal::v4l2 {

void registerBackend(CameraRegistry& registry);

}  // namespace commonlight::hal::v4l2

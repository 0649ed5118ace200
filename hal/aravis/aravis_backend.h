// The Aravis backend (GigE Vision / USB3 Vision cameras): scheme "aravis". docs/cameras-aravis.md.
#pragma once

#include "hal/registry.h"

namespace commonlight::hal::aravis {

void registerBackend(CameraRegistry& registry);

}  // namespace commonlight::hal::aravis

// The hardware camera backends this build was compiled with (hal/v4l2, hal/libcamera,
// hal/aravis). A backend whose library was missing at build time is left out; leftOutBackends()
// says which and why, so `commonlight cameras` can tell the user.
#pragma once

#include <string>
#include <vector>

#include "hal/registry.h"

namespace commonlight::hal {

void registerHardwareBackends(CameraRegistry& registry);

struct LeftOutBackend {
    std::string scheme;
    std::string reason;  // the package that was missing at build time
};
std::vector<LeftOutBackend> leftOutBackends();

}  // namespace commonlight::hal

// The real libcamera_backend::Device: a thin layer over libcamera::Camera. This header needs no
// libcamera header; libcamera_device.cpp is the only file that includes libcamera.
//
// One libcamera::CameraManager serves the process: started on first use and stopped when the
// last camera or listing using it is gone (libcamera allows one manager at a time).
#pragma once

#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "core/result.h"
#include "hal/libcamera/device.h"

namespace commonlight::hal::libcamera_backend {

struct CameraListing {
    std::string id;     // Camera::id()
    std::string model;  // properties::Model, or the id when the camera has none
    std::vector<DeviceFormat> formats;  // what generateConfiguration({role}) offers
};

// Starts (or shares) the camera manager and lists the cameras in libcamera's order.
Result<std::vector<CameraListing>> listCameras(StreamRole role);

// Acquires the camera named by `selector`: its index in listCameras() or its Camera::id().
// kNotFound (listing what is present) or kDevice (busy) naming `uri`.
Result<std::unique_ptr<Device>> openDevice(std::string_view selector, const std::string& uri);

// libcamera's version as it reports it at run time ("v0.0.3"), and the one we compiled against.
std::string libcameraVersion();
std::string_view compiledLibcameraVersion() noexcept;

}  // namespace commonlight::hal::libcamera_backend

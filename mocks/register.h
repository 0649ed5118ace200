// Registers the cameras that are not hardware: replay:<SEQ>, video:<file>, and the fault
// injection wrapper (the fault_* options, on any scheme).
#pragma once

#include "core/clock.h"
#include "hal/registry.h"

namespace commonlight::mocks {

// `clock` paces playback, stamps arrival times and times injected stalls; it is borrowed and must
// outlive every camera the registry opens (tests pass a ManualClock).
void registerMockBackends(hal::CameraRegistry& registry, Clock& clock = SteadyClock::instance());

}  // namespace commonlight::mocks

#include "apps/app.h"

#include <csignal>
#include <cstdio>
#include <thread>

#include <pthread.h>

#include "core/log.h"
#include "hal/hardware.h"
#include "mocks/register.h"
#include "mocks/sim/sim_camera.h"

namespace commonlight::apps {

int reportError(const Error& error) {
    log::error(error.message);
    return exitCodeFor(error.code);
}

void addRealTimeOptions(CLI::App& sub, int& lighting_every, bool& fixed_quality) {
    sub.add_option("--lighting-every", lighting_every,
                   "In real time, update the lighting for every N-th frame at most (1: as often as it can; "
                   "0: every frame while the camera's frames keep up, fewer while frames are dropped)")
        ->check(CLI::Range(0, 1000))
        ->capture_default_str();
    sub.add_flag("--fixed-quality", fixed_quality,
                 "Composite at full quality always (default: MSAA off, then fewer light samples, while compositing falls behind the camera)");
}

hal::CameraRegistry makeCameraRegistry() {
    hal::CameraRegistry registry;
    hal::registerHardwareBackends(registry);
    mocks::registerMockBackends(registry);
    mocks::sim::registerSimBackend(registry);
    return registry;
}

namespace {
std::stop_source g_stop;
}

void installStopSignals() {
    sigset_t set;
    sigemptyset(&set);
    sigaddset(&set, SIGINT);
    sigaddset(&set, SIGTERM);
    pthread_sigmask(SIG_BLOCK, &set, nullptr);  // inherited by every thread started later
    std::thread([set] {
        int signal = 0;
        while (sigwait(&set, &signal) == 0) {
            if (g_stop.stop_requested()) {
                // Second Ctrl-C: the user insists. Files written so far are complete (see
                // docs/formats-sequence.md), so leaving at once loses nothing committed.
                std::_Exit(130);
            }
            log::warning(signal == SIGINT ? "interrupted (Ctrl-C): finishing; press again to quit at once"
                                          : "terminated: finishing");
            g_stop.request_stop();
        }
    }).detach();
}

std::stop_token stopToken() { return g_stop.get_token(); }

}  // namespace commonlight::apps

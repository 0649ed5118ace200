#include "mocks/register.h"

#include <iterator>

#include "mocks/fault_injecting_camera.h"
#include "mocks/pacer.h"
#include "mocks/replay_camera.h"
#include "mocks/video_camera.h"

namespace commonlight::mocks {

namespace {

template <typename Concrete>
Result<std::unique_ptr<hal::Camera>> asCamera(Result<std::unique_ptr<Concrete>> opened) {
    if (!opened) return fail(std::move(opened).error());
    return std::unique_ptr<hal::Camera>(std::move(*opened));
}

}  // namespace

void registerMockBackends(hal::CameraRegistry& registry, Clock& clock) {
    const std::vector<std::string> playback(std::begin(kPlaybackOptionNames), std::end(kPlaybackOptionNames));
    registry.add(hal::Backend{
        "replay",
        "replays a recorded sequence: replay:<SEQ>?rate=realtime|max|step&loop=0|1&speed=<factor>",
        playback,
        [&clock](const hal::CameraUri& uri) { return asCamera(ReplayCamera::open(uri, clock)); },
        {},
    });
    registry.add(hal::Backend{
        "video",
        "plays a video file (mp4, avi, mkv): video:<file>?rate=realtime|max|step&loop=0|1&speed=<factor>",
        playback,
        [&clock](const hal::CameraUri& uri) { return asCamera(VideoCamera::open(uri, clock)); },
        {},
    });
    registry.addWrapper(hal::Wrapper{
        "fault",
        std::vector<std::string>(std::begin(kFaultOptionNames), std::end(kFaultOptionNames)),
        [&clock](std::unique_ptr<hal::Camera> camera,
                 const hal::CameraUri& uri) -> Result<std::unique_ptr<hal::Camera>> {
            CL_TRY(const FaultOptions options, FaultOptions::fromUri(uri));
            return asCamera(FaultInjectingCamera::wrap(std::move(camera), options, clock));
        },
    });
}

}  // namespace commonlight::mocks

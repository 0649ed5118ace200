// Helpers shared by the replay: camera tests.
#pragma once

#include <filesystem>
#include <memory>

#include <gtest/gtest.h>

#include "mocks/replay_camera.h"
#include "tests/mocks/mock_test_support.h"

namespace commonlight::testing {

using mocks::PlaybackOptions;
using mocks::PlaybackRate;
using mocks::ReplayCamera;

inline constexpr std::int64_t kInterval = 33'333'334;  // 30 fps, even so that speed=2 halves it exactly

inline PlaybackOptions rate(PlaybackRate r, bool loop = false, double speed = 1.0) {
    return PlaybackOptions{r, loop, speed};
}

inline std::unique_ptr<ReplayCamera> openReplay(const std::filesystem::path& dir, PlaybackOptions options,
                                                Clock& clock) {
    auto camera = ReplayCamera::open(dir, options, clock);
    if (!camera) ADD_FAILURE() << camera.error().message;
    return camera ? std::move(*camera) : nullptr;
}

// Attaches the sink and the pool, configures the default format and starts.
inline void configureAndStart(hal::Camera& camera, FrameSink& sink, TestFramePool& pool) {
    sink.attach(camera, pool);
    auto configured = camera.configure({});
    ASSERT_TRUE(configured) << configured.error().message;
    auto started = camera.start();
    ASSERT_TRUE(started) << started.error().message;
}

}  // namespace commonlight::testing

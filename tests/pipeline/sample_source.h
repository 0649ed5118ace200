// The bundled sample's frames as a FrameSource for the pipeline's tests, and a runner for them.
#pragma once

#include <gtest/gtest.h>

#include <array>
#include <cstdio>
#include <cstdlib>
#include <atomic>
#include <optional>
#include <thread>
#include <vector>

#include "core/clock.h"
#include "core/frame_file.h"
#include "core/scene_io.h"
#include "core/sequence_io.h"
#include "pipeline/frame_loop.h"
#include "pipeline/runner.h"
#include "render/gl_context.h"
#include "tests/test_support.h"

namespace commonlight::pipeline {

// The bundled sample's frames, as stored (MJPEG), read once.
struct Sample {
    Sequence sequence;
    Scene scene;
    std::vector<Frame> frames;
};

inline const Sample& sample() {
    static const Sample s = [] {
        Sample out;
        const auto root = testing::sourceDir() / "data/sample";
        auto seq = readSequence(root);
        auto scene = readScene(root / "scene.yaml");
        if (!seq || !scene) {
            ADD_FAILURE() << "the bundled sample: " << (seq ? scene.error().message : seq.error().message);
            return out;
        }
        out.sequence = std::move(*seq);
        out.scene = std::move(*scene);
        FrameFileReader reader;
        for (std::size_t i = 0; i < out.sequence.frames.size(); ++i) {
            Frame frame;
            auto read = reader.read(out.sequence.framePath(i), out.sequence.sensor.pixel_format, out.sequence.sensor.width,
                                    out.sequence.sensor.height, frame.image);
            EXPECT_TRUE(read) << (read ? "" : read.error().message);
            frame.meta.sequence = i;
            frame.meta.timestamp_ns = out.sequence.frames[i].timestamp_ns;
            frame.meta.timestamp_source = TimestampSource::kRecording;
            out.frames.push_back(std::move(frame));
        }
        return out;
    }();
    return s;
}

// The sample's frames one after the other (lent, never dropped), then the end or `end_error`.
// Records on which thread next() ran and how many frames it handed out.
class SampleSource final : public FrameSource {
public:
    explicit SampleSource(std::size_t count, std::optional<Error> end_error = std::nullopt)
        : count_(std::min(count, sample().frames.size())), end_error_(std::move(end_error)) {}
    Result<std::optional<FrameHandle>> next(std::stop_token stop) override {
        thread_ = std::this_thread::get_id();
        if (stop.stop_requested()) return fail(ErrorCode::kCancelled, "stopped");
        if (given_ == count_) {
            if (end_error_) return fail(*end_error_);
            return std::optional<FrameHandle>();
        }
        Frame& frame = frames_[given_ % frames_.size()];
        const Frame& original = sample().frames[given_];
        frame.image.assign(original.image.view());
        frame.meta = original.meta;
        frame.meta.arrival_ns = monotonicNowNs();
        if (given_ == bad_at_) frame.image.reshapeCompressed(640, 480, 16);  // a truncated JPEG
        ++given_;
        return std::optional<FrameHandle>(FrameHandle(&frame, nullptr));
    }
    std::size_t given() const { return given_; }
    std::thread::id thread() const { return thread_; }
    std::size_t bad_at_ = static_cast<std::size_t>(-1);

private:
    std::size_t count_;
    std::optional<Error> end_error_;
    std::atomic<std::size_t> given_{0};
    std::array<Frame, 2> frames_;  // the loop gives a frame's slot back before it asks for the next
    std::atomic<std::thread::id> thread_{};
};

// Without any GL context (no EGL, no display) the test exits 77 (skip).
inline void skipWithoutGl() {
    auto context = render::GlContext::create({});
    if (!context) {
        std::fprintf(stderr, "skipped: no offscreen GL context: %s\n", context.error().message.c_str());
        std::exit(77);
    }
}

// `with_truth`: the sample's sequence given for the lighting's ground truth (the ratio error).
inline std::unique_ptr<FrameRunner> makeRunner(bool sync, bool lighting, bool composite = false, bool with_truth = false) {
    if (sample().frames.empty() || !sample().sequence.sensor.camera) return nullptr;
    RunnerOptions options;
    if (with_truth) options.sequence = &sample().sequence;
    options.composite = composite;
    options.sync = sync;
    options.lighting = lighting;
    options.response = ResponseCurve::srgb();
    options.radiance_scale = sample().sequence.sensor.radiance_scale;
    auto runner = FrameRunner::create(sample().scene, *sample().sequence.sensor.camera, options);
    EXPECT_TRUE(runner) << (runner ? "" : runner.error().message);
    return runner ? std::move(*runner) : nullptr;
}

}  // namespace commonlight::pipeline

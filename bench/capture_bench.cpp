// Capture pipeline overhead per frame at 1280x720, and allocations per frame in steady state,
// side by side with cv::VideoCapture reading the same frames.
//
//   BM_Pipeline/<format>: an in-memory camera (its thread copies a prepared frame into a pool slot,
//     as a real backend copies out of a driver buffer) -> CaptureSession (lossless mailbox) ->
//     consumer converts to RGB8. Measures what our pipeline adds around the pixels.
//   BM_Replay/<png|jpeg>: the same frames from a sequence on disk through replay: -> session ->
//     RGB8, against BM_VideoCapture/<png|jpeg>: cv::VideoCapture reading the same files
//     (image-sequence mode) into BGR.
//
// Counters: frames_per_second, allocs_per_frame (every thread, measured over the timed loop).
#include <benchmark/benchmark.h>

#include <cstring>
#include <filesystem>
#include <memory>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/videoio.hpp>

#include "bench/alloc_counter.h"
#include "capture/capture_session.h"
#include "capture/convert.h"
#include "core/sequence_writer.h"
#include "mocks/memory_camera.h"
#include "mocks/replay_camera.h"

namespace commonlight::bench {
namespace {

namespace fs = std::filesystem;
constexpr int kWidth = 1280;
constexpr int kHeight = 720;
constexpr int kSequenceFrames = 30;

Image testFrame(PixelFormat format) {
    Image image(format, kWidth, kHeight);
    for (std::size_t i = 0; i < image.sizeBytes(); ++i) image.data()[i] = static_cast<std::uint8_t>((i * 7) ^ (i >> 11));
    return image;
}

// Runs the consumer loop of a started session for the benchmark's iterations (one frame each).
void consume(benchmark::State& state, capture::CaptureSession& session) {
    capture::PixelConverter converter;
    Image rgb(PixelFormat::kRgb8, kWidth, kHeight);
    std::stop_source never;
    // Warm up: the first frames size every buffer.
    for (int i = 0; i < 5; ++i) {
        auto next = session.next(never.get_token(), std::chrono::seconds(10));
        if (!next || !next->has_value()) {
            state.SkipWithError("no frame during warm-up");
            return;
        }
        if (!converter.convert((**next)->image, PixelFormat::kRgb8, rgb)) state.SkipWithError("convert failed");
    }
    const std::uint64_t allocs_before = allocationCount();
    for (auto _ : state) {
        auto next = session.next(never.get_token(), std::chrono::seconds(10));
        if (!next || !next->has_value()) {
            state.SkipWithError("stream ended");
            break;
        }
        if (!converter.convert((**next)->image, PixelFormat::kRgb8, rgb)) {
            state.SkipWithError("convert failed");
            break;
        }
        benchmark::DoNotOptimize(rgb.data());
    }
    const double frames = static_cast<double>(state.iterations());
    state.counters["allocs_per_frame"] = static_cast<double>(allocationCount() - allocs_before) / std::max(frames, 1.0);
    state.counters["frames_per_second"] = benchmark::Counter(frames, benchmark::Counter::kIsRate);
    state.SetBytesProcessed(static_cast<std::int64_t>(frames) * kWidth * kHeight * 3);
}

void BM_Pipeline(benchmark::State& state, PixelFormat format) {
    mocks::PlaybackOptions max_rate;
    max_rate.rate = mocks::PlaybackRate::kMax;
    auto camera = std::make_unique<mocks::MemoryCamera>(testFrame(format), 30.0, max_rate);
    if (!camera->configure({})) return state.SkipWithError("configure failed");
    capture::CaptureOptions options;
    options.sync = true;
    auto session = capture::CaptureSession::create(std::move(camera), options);
    if (!session || !(*session)->start()) return state.SkipWithError("session failed to start");
    consume(state, **session);
    (*session)->stop();
}
BENCHMARK_CAPTURE(BM_Pipeline, rgb8, PixelFormat::kRgb8)->UseRealTime()->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(BM_Pipeline, yuyv_to_rgb8, PixelFormat::kYuyv)->UseRealTime()->Unit(benchmark::kMicrosecond);

// A 1280x720 sequence of 30 distinct frames on disk (PNG or JPEG), plus the same files under
// the names cv::VideoCapture's image-sequence mode needs (frame_%04d.ext).
struct DiskSequence {
    fs::path root;
    std::string pattern;
};

const DiskSequence& diskSequence(bool jpeg) {
    static DiskSequence sequences[2];
    DiskSequence& seq = sequences[jpeg ? 1 : 0];
    if (!seq.root.empty()) return seq;
    seq.root = fs::temp_directory_path() / (jpeg ? "commonlight-bench-jpeg" : "commonlight-bench-png");
    fs::remove_all(seq.root);
    auto writer = SequenceWriter::create(seq.root, {}, {.sync = false});
    if (!writer) return seq;
    const fs::path by_index = seq.root / "by_index";
    fs::create_directories(by_index);
    cv::Mat bgr(kHeight, kWidth, CV_8UC3);
    std::vector<std::uint8_t> bytes;
    for (int i = 0; i < kSequenceFrames; ++i) {
        // Smooth gradients plus texture, like a camera image (pure noise would not compress).
        for (int y = 0; y < kHeight; ++y) {
            for (int x = 0; x < kWidth; ++x) {
                bgr.at<cv::Vec3b>(y, x) = cv::Vec3b(static_cast<std::uint8_t>((x + 4 * i) / 5), static_cast<std::uint8_t>(y / 3),
                                                    static_cast<std::uint8_t>(((x / 16 + y / 16) % 2) * 60 + i));
            }
        }
        FrameMetadata meta;
        meta.timestamp_ns = 1'000'000'000 + static_cast<std::int64_t>(i) * 33'333'333;
        meta.sequence = static_cast<std::uint64_t>(i);
        Image frame;
        if (jpeg) {
            cv::imencode(".jpg", bgr, bytes, {cv::IMWRITE_JPEG_QUALITY, 95});
            frame.reshapeCompressed(kWidth, kHeight, bytes.size());
            std::memcpy(frame.data(), bytes.data(), bytes.size());
        } else {
            frame.reshape(PixelFormat::kBgr8, kWidth, kHeight);
            std::memcpy(frame.data(), bgr.data, frame.sizeBytes());
        }
        if (!writer->write(frame, meta)) return seq;
        const std::string ext = jpeg ? ".jpg" : ".png";
        char name[32];
        std::snprintf(name, sizeof(name), "frame_%04d%s", i, ext.c_str());
        fs::create_symlink(seq.root / "cam0" / "data" / (std::to_string(meta.timestamp_ns) + ext), by_index / name);
    }
    seq.pattern = (by_index / (jpeg ? "frame_%04d.jpg" : "frame_%04d.png")).string();
    return seq;
}

void BM_Replay(benchmark::State& state, bool jpeg) {
    const DiskSequence& seq = diskSequence(jpeg);
    if (seq.pattern.empty()) return state.SkipWithError("cannot write the test sequence");
    mocks::PlaybackOptions playback;
    playback.rate = mocks::PlaybackRate::kMax;
    playback.loop = true;
    auto camera = mocks::ReplayCamera::open(seq.root, playback, SteadyClock::instance());
    if (!camera || !(*camera)->configure({})) return state.SkipWithError("cannot open the sequence");
    capture::CaptureOptions options;
    options.sync = true;
    auto session = capture::CaptureSession::create(std::move(*camera), options);
    if (!session || !(*session)->start()) return state.SkipWithError("session failed to start");
    consume(state, **session);
    (*session)->stop();
}
BENCHMARK_CAPTURE(BM_Replay, png, false)->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_Replay, jpeg, true)->UseRealTime()->Unit(benchmark::kMillisecond);

void BM_VideoCapture(benchmark::State& state, bool jpeg) {
    const DiskSequence& seq = diskSequence(jpeg);
    if (seq.pattern.empty()) return state.SkipWithError("cannot write the test sequence");
    cv::VideoCapture capture(seq.pattern, cv::CAP_IMAGES);
    if (!capture.isOpened()) return state.SkipWithError("cv::VideoCapture cannot open the sequence");
    cv::Mat frame;
    int index = 0;
    auto read = [&] {
        if (index == kSequenceFrames) {  // loop like replay:?loop=1
            capture.set(cv::CAP_PROP_POS_FRAMES, 0);
            index = 0;
        }
        ++index;
        return capture.read(frame);
    };
    for (int i = 0; i < 5; ++i) read();
    const std::uint64_t allocs_before = allocationCount();
    for (auto _ : state) {
        if (!read()) {
            state.SkipWithError("read failed");
            break;
        }
        benchmark::DoNotOptimize(frame.data);
    }
    const double frames = static_cast<double>(state.iterations());
    state.counters["allocs_per_frame"] = static_cast<double>(allocationCount() - allocs_before) / std::max(frames, 1.0);
    state.counters["frames_per_second"] = benchmark::Counter(frames, benchmark::Counter::kIsRate);
}
BENCHMARK_CAPTURE(BM_VideoCapture, png, false)->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_VideoCapture, jpeg, true)->UseRealTime()->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace commonlight::bench

BENCHMARK_MAIN();

// Test helpers for cameras: a tiny frame pool, a frame sink that records what a camera delivers,
// and a builder for small sequences. Header-only; used by tests/mocks and tests/hal.
#pragma once

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <filesystem>
#include <mutex>
#include <stdexcept>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "core/frame.h"
#include "core/image.h"
#include "core/sequence_writer.h"
#include "hal/camera.h"

namespace commonlight::testing {

// A fixed set of frame slots with a free list (the real pool is capture::FramePool).
class TestFramePool final : public FrameAllocator, public FrameRecycler {
public:
    explicit TestFramePool(std::size_t slots) : frames_(slots) {
        free_.reserve(slots);
        for (auto& frame : frames_) free_.push_back(&frame);
    }
    ~TestFramePool() = default;
    TestFramePool(const TestFramePool&) = delete;
    TestFramePool& operator=(const TestFramePool&) = delete;

    FrameHandle acquire() noexcept override {
        std::lock_guard lock(mutex_);
        if (free_.empty()) return FrameHandle();
        Frame* frame = free_.back();
        free_.pop_back();
        return FrameHandle(frame, this);
    }
    void recycle(Frame* frame) noexcept override {
        std::lock_guard lock(mutex_);
        free_.push_back(frame);
    }
    std::size_t available() const {
        std::lock_guard lock(mutex_);
        return free_.size();
    }

private:
    std::vector<Frame> frames_;
    mutable std::mutex mutex_;
    std::vector<Frame*> free_;
};

struct ReceivedFrame {
    FrameMetadata meta;
    Image image;  // a copy (empty unless the sink keeps images)
};

// Records frames and events from a camera. Its callbacks run on the camera thread and only take
// a short lock (copying the image when asked: tests only).
class FrameSink {
public:
    struct Options {
        bool keep_images = false;
        std::size_t hold = 0;  // keep the handles of the first `hold` frames (pool exhaustion)
    };
    FrameSink() = default;
    explicit FrameSink(Options options) : options_(options) {}

    // Sets the allocator and both callbacks on `camera`.
    void attach(hal::Camera& camera, FrameAllocator& pool) {
        camera.setFrameAllocator(&pool);
        camera.setFrameCallback([this](FrameHandle frame) { onFrame(std::move(frame)); });
        camera.setEventCallback([this](const hal::CameraEvent& event) { onEvent(event); });
    }

    // Wait until at least `n` frames (events) arrived; false after a generous timeout so a broken
    // camera fails the test instead of hanging it.
    bool waitForFrames(std::size_t n) {
        std::unique_lock lock(mutex_);
        return changed_.wait_for(lock, kTimeout, [&] { return frames_.size() >= n; });
    }
    bool waitForEvents(std::size_t n) {
        std::unique_lock lock(mutex_);
        return changed_.wait_for(lock, kTimeout, [&] { return events_.size() >= n; });
    }

    std::size_t frameCount() const {
        std::lock_guard lock(mutex_);
        return frames_.size();
    }
    std::size_t eventCount() const {
        std::lock_guard lock(mutex_);
        return events_.size();
    }
    std::vector<FrameMetadata> metas() const {
        std::lock_guard lock(mutex_);
        std::vector<FrameMetadata> out;
        for (const auto& f : frames_) out.push_back(f.meta);
        return out;
    }
    std::vector<std::uint64_t> sequences() const {
        std::vector<std::uint64_t> out;
        for (const auto& m : metas()) out.push_back(m.sequence);
        return out;
    }
    // Only after the camera stopped (no more callbacks).
    const std::vector<ReceivedFrame>& frames() const { return frames_; }
    std::vector<hal::CameraEvent> events() const {
        std::lock_guard lock(mutex_);
        return events_;
    }
    void releaseHeld() {
        std::lock_guard lock(mutex_);
        held_.clear();
    }

private:
    static constexpr std::chrono::seconds kTimeout{60};

    void onFrame(FrameHandle frame) {
        ReceivedFrame received;
        received.meta = frame->meta;
        if (options_.keep_images) received.image = frame->image.clone();
        {
            std::lock_guard lock(mutex_);
            frames_.push_back(std::move(received));
            if (held_.size() < options_.hold) held_.push_back(std::move(frame));
        }
        changed_.notify_all();
    }
    void onEvent(const hal::CameraEvent& event) {
        {
            std::lock_guard lock(mutex_);
            events_.push_back(event);
        }
        changed_.notify_all();
    }

    Options options_;
    mutable std::mutex mutex_;
    std::condition_variable changed_;
    std::vector<ReceivedFrame> frames_;
    std::vector<hal::CameraEvent> events_;
    std::vector<FrameHandle> held_;
};

// A deterministic test pattern; MJPEG frames are real JPEG images of a pattern.
inline Image patternImage(PixelFormat format, int width, int height, int seed) {
    if (format == PixelFormat::kMjpeg) {
        cv::Mat bgr(height, width, CV_8UC3);
        for (int y = 0; y < height; ++y) {
            for (int x = 0; x < width; ++x) {
                bgr.at<cv::Vec3b>(y, x) =
                    cv::Vec3b(static_cast<std::uint8_t>(x * 4 + seed * 20), static_cast<std::uint8_t>(y * 4),
                              static_cast<std::uint8_t>(seed * 50));
            }
        }
        std::vector<std::uint8_t> jpeg;
        cv::imencode(".jpg", bgr, jpeg);
        Image image;
        image.reshapeCompressed(width, height, jpeg.size());
        std::copy(jpeg.begin(), jpeg.end(), image.data());
        return image;
    }
    Image image(format, width, height);
    for (std::size_t i = 0; i < image.sizeBytes(); ++i) {
        image.data()[i] = static_cast<std::uint8_t>((i * 31 + static_cast<std::size_t>(seed) * 7 + i / 97) & 0xFF);
    }
    return image;
}

struct TestSequence {
    std::vector<Image> images;
    std::vector<FrameMetadata> metas;
};

// Writes `count` frames to `root` (a SequenceWriter sequence with meta.csv): timestamps
// first_ns + i * interval_ns, sequence numbers first_sequence + i.
inline TestSequence writeTestSequence(const std::filesystem::path& root, PixelFormat format, int count,
                                      std::int64_t interval_ns, double rate_hz = 30.0, int width = 32, int height = 24,
                                      std::uint64_t first_sequence = 0, std::int64_t first_ns = 1'000'000'000) {
    SensorInfo sensor;
    sensor.rate_hz = rate_hz;
    auto writer = SequenceWriter::create(root, sensor, SequenceWriterOptions{.sync = false});
    if (!writer) throw std::runtime_error(writer.error().message);
    TestSequence written;
    for (int i = 0; i < count; ++i) {
        FrameMetadata meta;
        meta.timestamp_ns = first_ns + i * interval_ns;
        meta.sequence = first_sequence + static_cast<std::uint64_t>(i);
        meta.exposure_us = 1000.0 + i;
        meta.analog_gain = 1.5;
        written.images.push_back(patternImage(format, width, height, i));
        if (auto w = writer->write(written.images.back(), meta); !w) throw std::runtime_error(w.error().message);
        written.metas.push_back(meta);
    }
    return written;
}

}  // namespace commonlight::testing

// A fake libcamera_backend::Device that behaves like libcamera's Camera for the backend: it
// completes queued requests on its own thread (as libcamera's pipeline thread does), with a
// pattern in the buffer, a frame sequence (with injectable gaps), the metadata of the controls
// applied, and, on stop(), every request still queued completes as cancelled before stop()
// returns. The test keeps a pointer to it while the camera owns it.
#pragma once

#include <algorithm>
#include <condition_variable>
#include <cstring>
#include <mutex>
#include <set>
#include <thread>
#include <vector>

#include "hal/libcamera/device.h"
#include "hal/libcamera/mapping.h"

namespace commonlight::testing {

namespace lc = hal::libcamera_backend;

class FakeLibcameraDevice final : public lc::Device {
public:
    FakeLibcameraDevice() {
        formats_ = {{{lc::kFourccYuyv, 0}, 640, 480}, {{lc::kFourccYuyv, 0}, 320, 240},
                    {{lc::kFourccMjpeg, 0}, 1280, 720}, {{lc::kFourccNv12, 0}, 64, 48},
                    {{lc::kFourccRgb888, 0}, 32, 24},  {{lc::fourcc('p', 'R', 'A', 'A'), 0}, 1920, 1080}};
        controls_.exposure_time_us = lc::DeviceRange{14, 66666, 10000};
        controls_.analogue_gain = lc::DeviceRange{1.0, 16.0, 1.0};
        controls_.ae_enable = lc::DeviceRange{0, 1, 1};
        controls_.awb_enable = lc::DeviceRange{0, 1, 1};
        controls_.frame_duration_us = lc::DeviceRange{33333, 1000000, 33333};
    }
    ~FakeLibcameraDevice() override { stop(); }

    // ---- knobs (test thread, before start) ----
    std::vector<lc::DeviceFormat> formats_;
    lc::DeviceControls controls_;
    std::optional<lc::ConfigureResult> configure_override;  // returned instead of the echo
    unsigned row_padding = 0;             // extra bytes per row (stride > packed)
    std::uint32_t first_sequence = 0;
    std::set<std::uint32_t> drop_sequences;  // sequence numbers the "sensor" loses
    std::size_t max_frames = 1u << 30;       // complete at most this many, then hold requests
    bool report_sensor_timestamp = true;
    bool fail_frames = false;                // FrameMetadata FrameError

    // ---- what happened (read after stop(), or under mutex_ via the accessors) ----
    int configure_calls = 0;
    int allocate_calls = 0;
    int release_calls = 0;
    lc::StreamRole last_role = lc::StreamRole::kRaw;
    lc::DeviceStreamConfig last_wanted;
    lc::RequestControls start_controls;

    std::size_t queueCalls() const {
        std::lock_guard lock(mutex_);
        return queue_calls_;
    }
    std::size_t queueCallsAfterStop() const {
        std::lock_guard lock(mutex_);
        return queue_calls_after_stop_;
    }
    std::size_t cancelledOnStop() const {
        std::lock_guard lock(mutex_);
        return cancelled_on_stop_;
    }
    std::size_t completed() const {
        std::lock_guard lock(mutex_);
        return completed_;
    }
    // The controls every queue() carried merged: what the "sensor" applies.
    lc::RequestControls applied() const {
        std::lock_guard lock(mutex_);
        return applied_;
    }
    std::size_t queuesWithControls() const {
        std::lock_guard lock(mutex_);
        return queues_with_controls_;
    }
    std::set<unsigned> indicesSeen() const {
        std::lock_guard lock(mutex_);
        return indices_seen_;
    }
    // Makes the camera vanish: the disconnect handler runs on the device thread.
    void disconnect() {
        {
            std::lock_guard lock(mutex_);
            disconnect_requested_ = true;
        }
        wake_.notify_all();
    }
    // Lets `n` more frames complete (after max_frames held them).
    void allowMore(std::size_t n) {
        {
            std::lock_guard lock(mutex_);
            max_frames += n;
        }
        wake_.notify_all();
    }

    // ---- lc::Device ----
    const std::string& cameraId() const override { return id_; }
    const std::string& model() const override { return model_; }
    std::vector<lc::DeviceFormat> formats(lc::StreamRole) const override { return formats_; }
    lc::DeviceControls controls() const override { return controls_; }

    Result<lc::ConfigureResult> configure(lc::StreamRole role, const lc::DeviceStreamConfig& wanted) override {
        ++configure_calls;
        last_role = role;
        last_wanted = wanted;
        if (configure_override) {
            config_ = configure_override->config;
            return *configure_override;
        }
        lc::ConfigureResult result{lc::ValidationStatus::kValid, wanted};
        const auto format = lc::pixelFormatFromDevice(wanted.format);
        result.config.stride = format && !isCompressed(*format)
                                    ? static_cast<unsigned>(minStride(*format, wanted.width)) + row_padding
                                    : 0;
        result.config.buffer_count = wanted.buffer_count ? wanted.buffer_count : 4;
        config_ = result.config;
        return result;
    }

    Result<unsigned> allocate() override {
        ++allocate_calls;
        const auto format = lc::pixelFormatFromDevice(config_.format);
        if (!format) return fail(ErrorCode::kDevice, "fake: nothing configured");
        std::size_t bytes = 0;
        if (*format == PixelFormat::kMjpeg) {
            bytes = static_cast<std::size_t>(config_.width) * static_cast<std::size_t>(config_.height);
        } else {
            bytes = imageBytes(*format, config_.width, config_.height, config_.stride);
        }
        buffers_.assign(config_.buffer_count, std::vector<std::uint8_t>(bytes));
        std::lock_guard lock(mutex_);
        ring_.assign(config_.buffer_count, 0);
        queued_head_ = 0;
        queued_count_ = 0;
        return config_.buffer_count;
    }
    void release() noexcept override {
        ++release_calls;
        buffers_.clear();
    }
    void setHandlers(CompletionHandler on_complete, DisconnectHandler on_disconnect) override {
        on_complete_ = std::move(on_complete);
        on_disconnect_ = std::move(on_disconnect);
    }

    Result<void> start(const lc::RequestControls& initial) override {
        start_controls = initial;
        {
            std::lock_guard lock(mutex_);
            applied_.merge(initial);
            running_ = true;
            stop_requested_ = false;
            sequence_ = first_sequence;
        }
        thread_ = std::thread([this] { run(); });
        return {};
    }

    Result<void> queue(unsigned index, const lc::RequestControls& controls) override {
        {
            std::lock_guard lock(mutex_);
            ++queue_calls_;
            if (!running_) {
                ++queue_calls_after_stop_;
                return fail(ErrorCode::kDevice, "fake: queue while stopped");
            }
            if (index >= buffers_.size()) return fail(ErrorCode::kDevice, "fake: bad request index");
            if (!controls.empty()) {
                ++queues_with_controls_;
                applied_.merge(controls);
            }
            indices_seen_.insert(index);
            if (queued_count_ == ring_.size()) return fail(ErrorCode::kDevice, "fake: request queued twice");
            ring_[(queued_head_ + queued_count_++) % ring_.size()] = index;  // fixed ring: no allocation
        }
        wake_.notify_all();
        return {};
    }

    void stop() noexcept override {
        {
            std::lock_guard lock(mutex_);
            if (!running_ && !thread_.joinable()) return;
            stop_requested_ = true;
        }
        wake_.notify_all();
        if (thread_.joinable()) thread_.join();
        std::vector<unsigned> pending;
        {
            std::lock_guard lock(mutex_);
            running_ = false;
            for (; queued_count_ > 0; --queued_count_) {
                pending.push_back(ring_[queued_head_]);
                queued_head_ = (queued_head_ + 1) % ring_.size();
            }
            cancelled_on_stop_ += pending.size();
        }
        for (unsigned index : pending) {
            lc::CompletedRequest cancelled;
            cancelled.index = index;
            cancelled.status = lc::CompletedRequest::Status::kCancelled;
            if (on_complete_) on_complete_(cancelled);
        }
    }

private:
    void run() {
        std::unique_lock lock(mutex_);
        for (;;) {
            wake_.wait(lock, [&] {
                return stop_requested_ || disconnect_requested_ || (queued_count_ > 0 && completed_ < max_frames);
            });
            if (stop_requested_) return;
            if (disconnect_requested_) {
                disconnect_requested_ = false;
                lock.unlock();
                if (on_disconnect_) on_disconnect_();
                lock.lock();
                continue;
            }
            const unsigned index = ring_[queued_head_];
            queued_head_ = (queued_head_ + 1) % ring_.size();
            --queued_count_;
            while (drop_sequences.count(sequence_) != 0) ++sequence_;  // lost at the "sensor"
            const std::uint32_t sequence = sequence_++;
            ++completed_;
            const lc::RequestControls applied = applied_;
            lock.unlock();
            complete(index, sequence, applied);
            lock.lock();
        }
    }

    void complete(unsigned index, std::uint32_t sequence, const lc::RequestControls& applied) {
        auto& buffer = buffers_[index];
        for (std::size_t i = 0; i < buffer.size(); ++i) buffer[i] = static_cast<std::uint8_t>(i * 7 + sequence);
        lc::CompletedRequest done;
        done.index = index;
        done.status = fail_frames ? lc::CompletedRequest::Status::kError : lc::CompletedRequest::Status::kOk;
        done.sequence = sequence;
        done.buffer_timestamp_ns = 5'000'000'000ull + sequence * 33'333'333ull;
        if (report_sensor_timestamp) done.sensor_timestamp_ns = 4'990'000'000ll + sequence * 33'333'333ll;
        done.exposure_time_us = applied.exposure_time_us.value_or(10000);
        done.analogue_gain = applied.analogue_gain.value_or(2.0f);
        done.frame_duration_us = applied.frame_duration_us.value_or(33333);
        const auto format = lc::pixelFormatFromDevice(config_.format);
        if (format == PixelFormat::kNv12) {
            const std::size_t y_bytes = static_cast<std::size_t>(config_.stride) * static_cast<std::size_t>(config_.height);
            done.planes[0] = {buffer.data(), y_bytes, y_bytes};
            done.planes[1] = {buffer.data() + y_bytes, buffer.size() - y_bytes, buffer.size() - y_bytes};
            done.plane_count = 2;
        } else {
            const std::size_t used = format == PixelFormat::kMjpeg ? buffer.size() / 3 : buffer.size();
            done.planes[0] = {buffer.data(), used, buffer.size()};
            done.plane_count = 1;
        }
        if (on_complete_) on_complete_(done);
    }

    std::string id_ = "/base/fake/sensor@10";
    std::string model_ = "fake sensor";
    lc::DeviceStreamConfig config_;
    std::vector<std::vector<std::uint8_t>> buffers_;
    CompletionHandler on_complete_;
    DisconnectHandler on_disconnect_;
    std::thread thread_;

    mutable std::mutex mutex_;
    std::condition_variable wake_;
    std::vector<unsigned> ring_;  // requests queued, oldest at queued_head_
    std::size_t queued_head_ = 0;
    std::size_t queued_count_ = 0;
    bool running_ = false;
    bool stop_requested_ = false;
    bool disconnect_requested_ = false;
    std::uint32_t sequence_ = 0;
    std::size_t completed_ = 0;
    std::size_t queue_calls_ = 0;
    std::size_t queue_calls_after_stop_ = 0;
    std::size_t queues_with_controls_ = 0;
    std::size_t cancelled_on_stop_ = 0;
    lc::RequestControls applied_;
    std::set<unsigned> indices_seen_;
};

}  // namespace commonlight::testing

// The Aravis backend against the GigE server (Aravis's fake camera serving a sequence), in one
// process, over loopback in a private network namespace: frames bit-identical and in order,
// metadata, controls, and the device error when the server goes away.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <filesystem>
#include <mutex>
#include <optional>
#include <thread>
#include <vector>

#include "bench/alloc_counter.h"
#include "capture/frame_pool.h"
#include "core/sequence_writer.h"
#include "hal/aravis/aravis_backend.h"
#include "hal/aravis/aravis_camera.h"
#include "hal/registry.h"
#include "mocks/gige/gige_server.h"
#include "tests/mocks/private_network.h"

namespace commonlight {
namespace {

const bool kPrivateNetwork = (testing::requirePrivateNetwork(), true);

namespace fs = std::filesystem;

// A gray8 sequence whose frames differ (their index is in the first two bytes).
fs::path makeSequence(int frames, int width, int height, double rate) {
    const fs::path dir = fs::temp_directory_path() / ("commonlight-gige-" + std::to_string(::getpid()));
    fs::remove_all(dir);
    SensorInfo sensor;
    sensor.rate_hz = rate;
    auto writer = SequenceWriter::create(dir, sensor, SequenceWriterOptions{false});
    EXPECT_TRUE(writer) << writer.error().message;
    Image image(PixelFormat::kGray8, width, height);
    for (int i = 0; i < frames; ++i) {
        for (int y = 0; y < height; ++y) {
            for (int x = 0; x < width; ++x) image.data()[y * image.stride() + x] = static_cast<std::uint8_t>(x + 2 * y + 5 * i);
        }
        image.data()[0] = static_cast<std::uint8_t>(i);
        FrameMetadata meta;
        meta.timestamp_ns = 1'000'000'000 + i * 10'000'000LL;
        EXPECT_TRUE(writer->write(image.view(), meta));
    }
    return dir;
}

struct Received {
    std::mutex mutex;
    std::condition_variable changed;
    std::vector<Image> images;
    std::vector<FrameMetadata> meta;
    std::optional<hal::CameraEvent> event;
};

class GigeLoopback : public ::testing::Test {
protected:
    void SetUp() override {
        ASSERT_TRUE(kPrivateNetwork);
        sequence_ = makeSequence(12, 64, 48, 100.0);
        mocks::GigeServerOptions options;
        options.sequence = sequence_;
        options.loop = true;
        auto server = mocks::GigeServer::start(options);
        ASSERT_TRUE(server) << server.error().message;
        server_ = std::move(*server);
        hal::aravis::registerBackend(registry_);
    }
    void TearDown() override {
        server_.reset();
        fs::remove_all(sequence_);
    }

    std::unique_ptr<hal::Camera> openStreaming(const std::string& uri) {
        auto camera = registry_.openConfigured(uri);
        EXPECT_TRUE(camera) << camera.error().message;
        if (!camera) return nullptr;
        (*camera)->setFrameAllocator(&pool_);
        (*camera)->setFrameCallback([this](FrameHandle frame) {
            std::lock_guard lock(received_.mutex);
            received_.images.push_back(Image::copyOf(frame->image.view()));
            received_.meta.push_back(frame->meta);
            received_.changed.notify_all();
        });
        (*camera)->setEventCallback([this](const hal::CameraEvent& event) {
            std::lock_guard lock(received_.mutex);
            received_.event = event;
            received_.changed.notify_all();
        });
        auto started = (*camera)->start();
        EXPECT_TRUE(started) << started.error().message;
        return std::move(*camera);
    }

    // Waits for a condition on the received frames (generous bound: this is not a timing test).
    template <typename Pred>
    bool waitFor(Pred pred) {
        std::unique_lock lock(received_.mutex);
        return received_.changed.wait_for(lock, std::chrono::seconds(20), [&] { return pred(received_); });
    }

    fs::path sequence_;
    std::unique_ptr<mocks::GigeServer> server_;
    hal::CameraRegistry registry_;
    capture::FramePool pool_{8, PixelFormat::kGray8, 64, 48};
    Received received_;
};

TEST_F(GigeLoopback, FramesAreTheSequenceInOrderWithDeviceTimestamps) {
    auto camera = openStreaming("aravis:127.0.0.1?timeout_ms=3000");
    ASSERT_TRUE(camera);
    EXPECT_EQ(camera->activeFormat().format, PixelFormat::kGray8);
    EXPECT_EQ(camera->activeFormat().width, 64);
    EXPECT_EQ(camera->activeFormat().height, 48);
    ASSERT_TRUE(waitFor([](Received& r) { return r.images.size() >= 30; }));
    camera->stop();

    std::vector<Image> served(server_->sequenceFrames());
    for (std::size_t i = 0; i < served.size(); ++i) ASSERT_TRUE(server_->servedFrame(i, served[i]));
    std::lock_guard lock(received_.mutex);
    std::size_t first_index = 0;
    for (std::size_t k = 0; k < received_.images.size(); ++k) {
        const Image& got = received_.images[k];
        std::optional<std::size_t> index;
        for (std::size_t i = 0; i < served.size(); ++i) {
            if (samePixels(got.view(), served[i].view())) index = i;
        }
        ASSERT_TRUE(index) << "frame " << k << " is not a served frame";
        const FrameMetadata& m = received_.meta[k];
        // The served frame advances with the device's frame counter: a frame lost on the way
        // (a loaded machine) is a gap in both, never a reordering.
        if (k == 0) {
            first_index = *index;
        } else {
            EXPECT_EQ(*index, (first_index + (m.sequence - received_.meta[0].sequence)) % served.size()) << "frame " << k;
        }
        EXPECT_EQ(m.status, FrameStatus::kOk);
        EXPECT_EQ(m.timestamp_source, TimestampSource::kSensor);
        EXPECT_LE(m.timestamp_ns, m.arrival_ns);
        EXPECT_GT(m.exposure_us, 0.0) << "the device's current exposure";
        if (k > 0) {
            EXPECT_GT(m.sequence, received_.meta[k - 1].sequence);
            EXPECT_GT(m.timestamp_ns, received_.meta[k - 1].timestamp_ns);
        }
    }
}

TEST_F(GigeLoopback, ExposureAndGainReachTheDeviceAndTheMetadata) {
    auto camera = openStreaming("aravis:127.0.0.1?exposure_us=2500&gain=3");
    ASSERT_TRUE(camera);
    auto exposure = camera->getControl(hal::Control::kExposureUs);
    ASSERT_TRUE(exposure) << exposure.error().message;
    EXPECT_DOUBLE_EQ(*exposure, 2500.0);
    auto gain = camera->getControl(hal::Control::kAnalogGain);
    ASSERT_TRUE(gain) << gain.error().message;
    EXPECT_DOUBLE_EQ(*gain, 3.0);
    ASSERT_TRUE(waitFor([](Received& r) { return r.meta.size() >= 3; }));
    {
        std::lock_guard lock(received_.mutex);
        EXPECT_DOUBLE_EQ(received_.meta.back().exposure_us, 2500.0);
        EXPECT_DOUBLE_EQ(received_.meta.back().analog_gain, 3.0);
    }
    ASSERT_TRUE(camera->setControl(hal::Control::kExposureUs, 4000.0));
    EXPECT_DOUBLE_EQ(*camera->getControl(hal::Control::kExposureUs), 4000.0);
    std::size_t after = 0;
    {
        std::lock_guard lock(received_.mutex);
        after = received_.meta.size();
    }
    ASSERT_TRUE(waitFor([&](Received& r) { return r.meta.size() >= after + 2; }));
    {
        std::lock_guard lock(received_.mutex);
        EXPECT_DOUBLE_EQ(received_.meta.back().exposure_us, 4000.0);
    }
    const auto bad = camera->setControl(hal::Control::kAnalogGain, 1000.0);
    ASSERT_FALSE(bad);
    EXPECT_NE(bad.error().message.find("aravis:127.0.0.1"), std::string::npos) << bad.error().message;
    const auto awb = camera->setControl(hal::Control::kAutoWhiteBalance, 1.0);
    ASSERT_FALSE(awb);
    EXPECT_EQ(awb.error().code, ErrorCode::kUnsupported);
    camera->stop();
}

TEST_F(GigeLoopback, AServerThatGoesAwayIsADeviceErrorNamingTheCamera) {
    auto camera = openStreaming("aravis:127.0.0.1?timeout_ms=500");
    ASSERT_TRUE(camera);
    ASSERT_TRUE(waitFor([](Received& r) { return r.images.size() >= 3; }));
    server_.reset();
    ASSERT_TRUE(waitFor([](Received& r) { return r.event.has_value(); }));
    {
        std::lock_guard lock(received_.mutex);
        EXPECT_EQ(received_.event->type, hal::CameraEvent::Type::kDeviceError);
        EXPECT_EQ(received_.event->error.code, ErrorCode::kDevice);
        EXPECT_NE(received_.event->error.message.find("aravis:127.0.0.1"), std::string::npos)
            << received_.event->error.message;
    }
    camera->stop();  // still fine after the error
    EXPECT_EQ(camera->state(), hal::Camera::State::kConfigured);
}

TEST_F(GigeLoopback, UnknownFormatsAndSizesListWhatTheDeviceOffers) {
    auto camera = registry_.openConfigured("aravis:127.0.0.1?format=yuyv");
    ASSERT_FALSE(camera);
    EXPECT_EQ(camera.error().code, ErrorCode::kUnsupported);
    EXPECT_NE(camera.error().message.find("gray8 64x48"), std::string::npos) << camera.error().message;
    auto too_big = registry_.openConfigured("aravis:127.0.0.1?width=640&height=480");
    ASSERT_FALSE(too_big);
    EXPECT_NE(too_big.error().message.find("offers"), std::string::npos) << too_big.error().message;
    auto roi = registry_.openConfigured("aravis:127.0.0.1?width=32&height=16&x=8&y=4");
    ASSERT_TRUE(roi) << roi.error().message;
    EXPECT_EQ((*roi)->activeFormat().width, 32);
    EXPECT_EQ((*roi)->activeFormat().height, 16);
}

// In steady state the backend's camera thread (pop, copy into a pool slot, requeue) and the
// server's fill allocate nothing (operator new, counted over the process; GLib's own malloc
// inside Aravis is not ours and not counted).
TEST_F(GigeLoopback, NoAllocationPerFrame) {
    auto camera = registry_.openConfigured("aravis:127.0.0.1");
    ASSERT_TRUE(camera) << camera.error().message;
    std::atomic<std::uint64_t> frames{0};
    (*camera)->setFrameAllocator(&pool_);
    (*camera)->setFrameCallback([&](FrameHandle frame) {
        if (frame->meta.status == FrameStatus::kOk) frames.fetch_add(1);
    });
    ASSERT_TRUE((*camera)->start());
    const auto waitFrames = [&](std::uint64_t n) {
        for (int i = 0; i < 2000 && frames.load() < n; ++i) std::this_thread::sleep_for(std::chrono::milliseconds(10));
        return frames.load() >= n;
    };
    ASSERT_TRUE(waitFrames(10));  // warm-up: every slot and buffer sized
    const std::uint64_t before = bench::allocationCount();
    const std::uint64_t first = frames.load();
    ASSERT_TRUE(waitFrames(first + 60));
    const std::uint64_t allocations = bench::allocationCount() - before;
    (*camera)->stop();
    EXPECT_EQ(allocations, 0u) << "over " << frames.load() - first << " frames";
}

TEST(GigeServerLimit, SendsNFramesThenStops) {
    const fs::path sequence = makeSequence(10, 32, 24, 100.0);
    mocks::GigeServerOptions options;
    options.sequence = sequence;
    options.frames = 15;
    options.loop = true;  // the limit ends it, not the end of the sequence
    auto server = mocks::GigeServer::start(options);
    ASSERT_TRUE(server) << server.error().message;
    hal::CameraRegistry registry;
    hal::aravis::registerBackend(registry);
    auto camera = registry.openConfigured("aravis:127.0.0.1?timeout_ms=60000");
    ASSERT_TRUE(camera) << camera.error().message;
    capture::FramePool pool(4, PixelFormat::kGray8, 32, 24);
    std::atomic<int> frames{0};
    (*camera)->setFrameAllocator(&pool);
    (*camera)->setFrameCallback([&](FrameHandle) { frames.fetch_add(1); });
    ASSERT_TRUE((*camera)->start());
    for (int i = 0; i < 2000 && !(*server)->finished(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(10));
    ASSERT_TRUE((*server)->finished());
    std::this_thread::sleep_for(std::chrono::milliseconds(300));  // room for a frame too many
    (*camera)->stop();
    EXPECT_EQ((*server)->framesServed(), 15u);
    EXPECT_LE(frames.load(), 15);
    EXPECT_GE(frames.load(), 1);
    server->reset();
    fs::remove_all(sequence);
}

TEST(GigeServerErrors, AMissingSequenceIsNamed) {
    mocks::GigeServerOptions options;
    options.sequence = "/nonexistent/sequence";
    auto server = mocks::GigeServer::start(options);
    ASSERT_FALSE(server);
    EXPECT_NE(server.error().message.find("/nonexistent/sequence"), std::string::npos) << server.error().message;
}

}  // namespace
}  // namespace commonlight

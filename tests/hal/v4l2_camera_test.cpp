// The V4L2 backend against the fake device of mocks/fake_v4l2_device.h: negotiation, streaming of
// every format through a CaptureSession, drop counting, disconnect, controls, timestamps and
// enumeration. The fake runs the kernel's buffer state machine, so a backend that misuses it
// (double QBUF, DQBUF before STREAMON, REQBUFS while mapped) fails here.
#include <linux/videodev2.h>

#include <chrono>
#include <cstring>
#include <memory>
#include <optional>
#include <thread>

#include <gtest/gtest.h>

#include "capture/capture_session.h"
#include "core/response.h"
#include "hal/registry.h"
#include "hal/v4l2/v4l2_backend.h"
#include "hal/v4l2/v4l2_camera.h"
#include "mocks/fake_v4l2_device.h"

namespace commonlight::hal::v4l2 {
namespace {

using mocks::FakeV4l2Config;
using mocks::FakeV4l2Device;
using mocks::FakeV4l2Frame;
using mocks::FakeV4l2System;
using namespace std::chrono_literals;

constexpr auto kWait = 20s;  // a bound for waits that should end at once; never a timing assert

V4l2Options testOptions() {
    V4l2Options o;
    o.timeout_ms = 0;  // frames come when the test produces them
    return o;
}

std::unique_ptr<V4l2Camera> openCamera(FakeV4l2System& system, const std::string& path = "/dev/video0",
                                       V4l2Options options = testOptions()) {
    auto camera = V4l2Camera::open(system, path, options);
    EXPECT_TRUE(camera) << (camera ? "" : camera.error().message);
    return camera ? std::move(*camera) : nullptr;
}

// Waits until `done` holds (polling), for conditions another thread makes true.
template <typename F>
bool eventually(F done) {
    const auto deadline = std::chrono::steady_clock::now() + kWait;
    while (!done()) {
        if (std::chrono::steady_clock::now() > deadline) return false;
        std::this_thread::sleep_for(1ms);
    }
    return true;
}

struct Streaming {
    std::unique_ptr<capture::CaptureSession> session;
    FakeV4l2Device* device = nullptr;

    FrameHandle next() {
        std::stop_source never;
        auto frame = session->next(never.get_token(), kWait);
        EXPECT_TRUE(frame) << (frame ? "" : frame.error().message);
        if (!frame || !frame->has_value()) return {};
        return std::move(**frame);
    }
};

Streaming startStreaming(FakeV4l2System& system, const StreamConfig& config, capture::CaptureOptions options = {}) {
    Streaming s;
    s.device = system.device("/dev/video0");
    auto camera = openCamera(system);
    if (!camera) return s;
    auto format = camera->configure(config);
    EXPECT_TRUE(format) << (format ? "" : format.error().message);
    auto session = capture::CaptureSession::create(std::move(camera), options);
    EXPECT_TRUE(session);
    s.session = std::move(*session);
    auto started = s.session->start();
    EXPECT_TRUE(started) << (started ? "" : started.error().message);
    EXPECT_TRUE(s.device->waitStreaming(kWait));
    return s;
}

// --- opening ---

TEST(V4l2Open, MissingDeviceIsNotFoundNamingThePath) {
    FakeV4l2System system;
    auto camera = V4l2Camera::open(system, "/dev/video7");
    ASSERT_FALSE(camera);
    EXPECT_EQ(camera.error().code, ErrorCode::kNotFound);
    EXPECT_NE(camera.error().message.find("/dev/video7"), std::string::npos) << camera.error().message;
}

TEST(V4l2Open, PermissionAndBusyAreDeviceErrors) {
    for (int error : {EACCES, EBUSY}) {
        FakeV4l2System system;
        FakeV4l2Config config = FakeV4l2Config::webcam();
        config.open_errno = error;
        system.add("/dev/video0", config);
        auto camera = V4l2Camera::open(system, "/dev/video0");
        ASSERT_FALSE(camera);
        EXPECT_EQ(camera.error().code, ErrorCode::kDevice);
        EXPECT_NE(camera.error().message.find("/dev/video0"), std::string::npos);
        EXPECT_NE(camera.error().message.find(error == EACCES ? "permission" : "busy"), std::string::npos)
            << camera.error().message;
    }
}

TEST(V4l2Open, NonCaptureDeviceIsUnsupported) {
    FakeV4l2System system;
    FakeV4l2Config config = FakeV4l2Config::webcam();
    config.capabilities = V4L2_CAP_META_CAPTURE | V4L2_CAP_STREAMING;
    system.add("/dev/video1", config);
    auto camera = V4l2Camera::open(system, "/dev/video1");
    ASSERT_FALSE(camera);
    EXPECT_EQ(camera.error().code, ErrorCode::kUnsupported);
    EXPECT_NE(camera.error().message.find("not a video capture device"), std::string::npos) << camera.error().message;
    EXPECT_EQ(system.openCount(), 0) << "the descriptor of a refused device must be closed";
}

TEST(V4l2Open, ListsFormatsSizesAndRates) {
    FakeV4l2System system;
    system.add("/dev/video0", FakeV4l2Config::webcam());
    auto camera = openCamera(system);
    ASSERT_TRUE(camera);
    EXPECT_EQ(camera->card(), "Fake V4L2 camera");
    const std::vector<StreamFormat> expected = {
        {PixelFormat::kYuyv, 640, 480, {30, 15}, 0}, {PixelFormat::kYuyv, 320, 240, {30}, 0},
        {PixelFormat::kMjpeg, 1280, 720, {30}, 0},   {PixelFormat::kMjpeg, 640, 480, {30}, 0},
        {PixelFormat::kNv12, 640, 480, {30}, 0},     {PixelFormat::kGray8, 640, 480, {30}, 0},
    };
    EXPECT_EQ(camera->formats(), expected);
}

TEST(V4l2Open, FormatsTheBackendCannotStreamAreLeftOut) {
    FakeV4l2System system;
    FakeV4l2Config config = FakeV4l2Config::webcam();
    config.formats.insert(config.formats.begin(), {V4L2_PIX_FMT_H264, {{1920, 1080, 0, 0, 0, 0, {30}}}});
    system.add("/dev/video0", config);
    auto camera = openCamera(system);
    ASSERT_TRUE(camera);
    for (const auto& f : camera->formats()) EXPECT_NE(f.format, PixelFormat::kInvalid);
    EXPECT_EQ(camera->formats().size(), 6u);
}

// --- negotiation ---

TEST(V4l2Negotiate, ExactMatchSetsTheDriverFormatAndRate) {
    FakeV4l2System system;
    FakeV4l2Device& device = system.add("/dev/video0", FakeV4l2Config::webcam());
    auto camera = openCamera(system);
    ASSERT_TRUE(camera);
    auto format = camera->configure({PixelFormat::kYuyv, 640, 480, 15});
    ASSERT_TRUE(format) << format.error().message;
    EXPECT_EQ(format->format, PixelFormat::kYuyv);
    EXPECT_EQ(format->width, 640);
    EXPECT_DOUBLE_EQ(format->fps, 15.0);
    EXPECT_EQ(device.currentFourcc(), V4L2_PIX_FMT_YUYV);
    EXPECT_EQ(device.currentWidth(), 640u);
    EXPECT_DOUBLE_EQ(device.currentFps(), 15.0);
}

TEST(V4l2Negotiate, SizeFreePicksTheLargest) {
    FakeV4l2System system;
    FakeV4l2Device& device = system.add("/dev/video0", FakeV4l2Config::webcam());
    auto camera = openCamera(system);
    ASSERT_TRUE(camera);
    auto format = camera->configure({PixelFormat::kMjpeg, 0, 0, 0});
    ASSERT_TRUE(format) << format.error().message;
    EXPECT_EQ(format->width, 1280);
    EXPECT_EQ(format->height, 720);
    EXPECT_EQ(device.currentFourcc(), V4L2_PIX_FMT_MJPEG);
    EXPECT_EQ(device.currentWidth(), 1280u);
}

TEST(V4l2Negotiate, NoMatchListsWhatTheDeviceOffers) {
    FakeV4l2System system;
    system.add("/dev/video0", FakeV4l2Config::webcam());
    auto camera = openCamera(system);
    ASSERT_TRUE(camera);
    auto format = camera->configure({PixelFormat::kYuyv, 1920, 1080, 0});
    ASSERT_FALSE(format);
    EXPECT_EQ(format.error().code, ErrorCode::kUnsupported);
    const std::string& m = format.error().message;
    EXPECT_NE(m.find("v4l2:/dev/video0"), std::string::npos) << m;
    EXPECT_NE(m.find("yuyv 640x480 @30/15 fps"), std::string::npos) << m;
    EXPECT_NE(m.find("mjpeg 1280x720"), std::string::npos) << m;
    EXPECT_EQ(camera->state(), Camera::State::kOpened);
}

TEST(V4l2Negotiate, DriverAdjustingTheSizeIsAnError) {
    FakeV4l2System system;
    FakeV4l2Config config = FakeV4l2Config::webcam();
    config.max_set_width = 640;  // lists 1280x720 MJPEG but sets at most 640 wide
    system.add("/dev/video0", config);
    auto camera = openCamera(system);
    ASSERT_TRUE(camera);
    auto format = camera->configure({PixelFormat::kMjpeg, 1280, 720, 0});
    ASSERT_FALSE(format);
    EXPECT_EQ(format.error().code, ErrorCode::kUnsupported);
    EXPECT_NE(format.error().message.find("VIDIOC_S_FMT"), std::string::npos) << format.error().message;
    EXPECT_NE(format.error().message.find("640x480"), std::string::npos) << format.error().message;
}

TEST(V4l2Negotiate, StepwiseSizesAcceptAnySizeOnTheGrid) {
    FakeV4l2System system;
    FakeV4l2Config config;
    config.formats = {{V4L2_PIX_FMT_GREY, {{1280, 1024, 16, 16, 16, 8, {60, 30}}}}};
    FakeV4l2Device& device = system.add("/dev/video0", config);
    auto camera = openCamera(system);
    ASSERT_TRUE(camera);
    // The list holds the common sizes on the grid and the largest.
    bool has_vga = false, has_max = false;
    for (const auto& f : camera->formats()) {
        has_vga = has_vga || (f.width == 640 && f.height == 480);
        has_max = has_max || (f.width == 1280 && f.height == 1024);
    }
    EXPECT_TRUE(has_vga && has_max);
    auto format = camera->configure({PixelFormat::kGray8, 528, 392, 0});
    ASSERT_TRUE(format) << format.error().message;
    EXPECT_EQ(device.currentWidth(), 528u);
    EXPECT_EQ(device.currentHeight(), 392u);
    EXPECT_FALSE(camera->configure({PixelFormat::kGray8, 530, 392, 0})) << "530 is off the 16-pixel grid";
}

// --- streaming ---

// Checks an uncompressed frame against the fake's pattern, row by row (the driver's rows may be
// padded; ours are packed).
void expectPattern(const Frame& frame, std::uint32_t sequence, std::size_t bytes_per_line) {
    const Image& image = frame.image;
    const int rows = image.format() == PixelFormat::kNv12 ? image.height() * 3 / 2 : image.height();
    const std::size_t line = minStride(image.format(), image.width());
    for (int y = 0; y < rows; ++y) {
        for (std::size_t x = 0; x < line; x += 97) {  // a sample of every row
            const std::size_t i = static_cast<std::size_t>(y) * bytes_per_line + x;
            ASSERT_EQ(image.data()[static_cast<std::size_t>(y) * image.stride() + x], FakeV4l2Device::patternByte(sequence, i))
                << "row " << y << " byte " << x;
        }
    }
}

struct FormatCase {
    PixelFormat format;
    int width;
    int height;
};

class V4l2Stream : public ::testing::TestWithParam<FormatCase> {};

TEST_P(V4l2Stream, DeliversTheDeviceBytesAndMetadata) {
    const FormatCase c = GetParam();
    FakeV4l2System system;
    FakeV4l2Config config = FakeV4l2Config::webcam();
    config.line_padding = 64;  // the driver's rows are longer than ours
    system.add("/dev/video0", config);
    Streaming s = startStreaming(system, {c.format, c.width, c.height, 0});
    ASSERT_TRUE(s.session);
    const std::size_t bpl = s.device->bytesPerLine();
    for (std::uint32_t n = 0; n < 5; ++n) {
        std::optional<std::uint32_t> sequence;
        FakeV4l2Frame spec;
        if (c.format == PixelFormat::kMjpeg) {
            std::vector<std::uint8_t> jpeg(3000 + n * 10);
            for (std::size_t i = 0; i < jpeg.size(); ++i) jpeg[i] = static_cast<std::uint8_t>(i * 3 + n);
            spec.payload = jpeg;
        }
        ASSERT_TRUE(s.device->waitAllQueued(kWait));
        sequence = s.device->produceFrame(spec);
        ASSERT_TRUE(sequence);
        FrameHandle frame = s.next();
        ASSERT_TRUE(frame);
        EXPECT_EQ(frame->meta.sequence, *sequence);
        EXPECT_EQ(frame->meta.status, FrameStatus::kOk);
        EXPECT_EQ(frame->meta.timestamp_source, TimestampSource::kSensor);
        EXPECT_GT(frame->meta.arrival_ns, 0);
        EXPECT_LE(frame->meta.timestamp_ns, frame->meta.arrival_ns);
        EXPECT_DOUBLE_EQ(frame->meta.exposure_us, 15600.0);
        EXPECT_DOUBLE_EQ(frame->meta.analog_gain, 32.0);
        EXPECT_EQ(frame->image.format(), c.format);
        EXPECT_EQ(frame->image.width(), c.width);
        EXPECT_EQ(frame->image.height(), c.height);
        if (c.format == PixelFormat::kMjpeg) {
            ASSERT_EQ(frame->image.sizeBytes(), spec.payload->size());
            EXPECT_EQ(std::memcmp(frame->image.data(), spec.payload->data(), spec.payload->size()), 0);
        } else {
            expectPattern(*frame, *sequence, bpl);
        }
    }
    s.session->stop();
    EXPECT_EQ(s.session->stats().frames_delivered, 5u);
    EXPECT_EQ(s.session->stats().drops.total(), 0u);
    EXPECT_FALSE(s.device->streaming());
    EXPECT_EQ(s.device->mappedCount(), 0u) << "stop() unmaps every buffer";
    EXPECT_EQ(s.device->bufferCount(), 0u) << "stop() frees the buffers (REQBUFS 0)";
}

INSTANTIATE_TEST_SUITE_P(Formats, V4l2Stream,
                         ::testing::Values(FormatCase{PixelFormat::kYuyv, 640, 480}, FormatCase{PixelFormat::kMjpeg, 1280, 720},
                                           FormatCase{PixelFormat::kNv12, 640, 480}, FormatCase{PixelFormat::kGray8, 640, 480}),
                         [](const auto& p) { return std::string(pixelFormatName(p.param.format)); });

TEST(V4l2Stream, RestartsAfterStop) {
    FakeV4l2System system;
    system.add("/dev/video0", FakeV4l2Config::webcam());
    Streaming s = startStreaming(system, {PixelFormat::kGray8, 0, 0, 0});
    ASSERT_TRUE(s.session);
    for (int run = 0; run < 3; ++run) {
        if (run > 0) {
            ASSERT_TRUE(s.session->start());
            ASSERT_TRUE(s.device->waitStreaming(kWait));
        }
        ASSERT_TRUE(s.device->waitAllQueued(kWait));
        ASSERT_TRUE(s.device->produceFrame());
        EXPECT_TRUE(s.next());
        s.session->stop();
        EXPECT_FALSE(s.device->streaming());
    }
}

TEST(V4l2Status, ErrorFlagAndShortBuffersAreIncomplete) {
    FakeV4l2System system;
    system.add("/dev/video0", FakeV4l2Config::webcam());
    Streaming s = startStreaming(system, {PixelFormat::kYuyv, 640, 480, 0});
    ASSERT_TRUE(s.session);
    FakeV4l2Frame error;
    error.flags = V4L2_BUF_FLAG_ERROR;
    FakeV4l2Frame short_frame;
    short_frame.bytesused = 640 * 2 * 100;  // 100 of 480 rows
    FakeV4l2Frame ok;
    for (const FakeV4l2Frame* spec : {&error, &short_frame, &ok}) {
        ASSERT_TRUE(s.device->waitAllQueued(kWait));
        ASSERT_TRUE(s.device->produceFrame(*spec));
        FrameHandle frame = s.next();
        ASSERT_TRUE(frame);
        EXPECT_EQ(frame->meta.status, spec == &ok ? FrameStatus::kOk : FrameStatus::kIncomplete);
        if (spec == &short_frame) {
            EXPECT_EQ(frame->image.data()[640 * 2 * 100 + 5], 0) << "rows the device did not send are blank";
        }
    }
    EXPECT_EQ(s.session->stats().drops.corrupt, 2u);
}

// --- timestamps ---

struct TimestampCase {
    std::uint32_t flags;
    TimestampSource expected;
};

class V4l2Timestamps : public ::testing::TestWithParam<TimestampCase> {};

TEST_P(V4l2Timestamps, FlagsChooseTheSource) {
    FakeV4l2System system;
    FakeV4l2Config config = FakeV4l2Config::webcam();
    config.timestamp_flags = GetParam().flags;
    system.add("/dev/video0", config);
    Streaming s = startStreaming(system, {PixelFormat::kGray8, 0, 0, 0});
    ASSERT_TRUE(s.session);
    FakeV4l2Frame spec;
    spec.timestamp = timeval{1234, 567890};
    ASSERT_TRUE(s.device->waitAllQueued(kWait));
    ASSERT_TRUE(s.device->produceFrame(spec));
    FrameHandle frame = s.next();
    ASSERT_TRUE(frame);
    EXPECT_EQ(frame->meta.timestamp_source, GetParam().expected);
    if (GetParam().expected == TimestampSource::kHost) {
        EXPECT_EQ(frame->meta.timestamp_ns, frame->meta.arrival_ns) << "no device time base: our arrival time";
    } else {
        EXPECT_EQ(frame->meta.timestamp_ns, 1234'567'890'000);
    }
}

INSTANTIATE_TEST_SUITE_P(
    Flags, V4l2Timestamps,
    ::testing::Values(TimestampCase{V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC | V4L2_BUF_FLAG_TSTAMP_SRC_SOE, TimestampSource::kSensor},
                      TimestampCase{V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC | V4L2_BUF_FLAG_TSTAMP_SRC_EOF, TimestampSource::kDriver},
                      TimestampCase{V4L2_BUF_FLAG_TIMESTAMP_UNKNOWN, TimestampSource::kHost},
                      TimestampCase{V4L2_BUF_FLAG_TIMESTAMP_COPY, TimestampSource::kHost}));

// --- drops ---

TEST(V4l2Drops, DeviceGapsPoolExhaustionAndMailboxAreCountedApart) {
    FakeV4l2System system;
    system.add("/dev/video0", FakeV4l2Config::webcam());
    capture::CaptureOptions options;
    options.slots = 3;
    Streaming s = startStreaming(system, {PixelFormat::kGray8, 0, 0, 0}, options);
    ASSERT_TRUE(s.session);
    auto produce = [&] {
        ASSERT_TRUE(s.device->waitAllQueued(kWait));
        ASSERT_TRUE(s.device->produceFrame());
        ASSERT_TRUE(s.device->waitAllQueued(kWait));  // the camera thread took and requeued it
    };
    // Device: 3 frames lost at the device between two delivered ones.
    produce();
    FrameHandle a = s.next();
    s.device->skipSequence(3);
    produce();
    FrameHandle b = s.next();  // the consumer now holds 2 of the 3 slots
    ASSERT_TRUE(a && b);
    EXPECT_EQ(b->meta.sequence, a->meta.sequence + 4);
    // No slot: the next frame takes the third slot into the mailbox; the one after finds none.
    produce();
    produce();
    ASSERT_TRUE(eventually([&] { return s.session->stats().drops.no_slot == 1; }));
    // Mailbox: with a slot back, a frame arrives before the consumer took the waiting one. It
    // counts as dropped once the consumer takes the newer frame (until then it may be a frame
    // made after the consumer stopped).
    a.reset();
    produce();
    ASSERT_TRUE(eventually([&] { return s.session->stats().frames_discarded == 1; }));
    EXPECT_EQ(s.session->stats().drops.mailbox, 0u);
    b.reset();
    FrameHandle c = s.next();
    ASSERT_TRUE(c);
    EXPECT_EQ(s.session->stats().drops.mailbox, 1u);
    EXPECT_EQ(s.session->stats().frames_discarded, 0u);
    produce();
    FrameHandle d = s.next();
    ASSERT_TRUE(d);
    const capture::CaptureStats stats = s.session->stats();
    EXPECT_EQ(stats.drops.device, 3u);
    EXPECT_EQ(stats.drops.mailbox, 1u);
    EXPECT_EQ(stats.drops.no_slot, 1u);
    EXPECT_EQ(stats.frames_delivered, 4u);
}

TEST(V4l2Drops, SlowConsumerLosesFramesAtTheDevice) {
    // The camera thread is stuck in the frame callback: the driver's queue runs dry and the
    // device drops frames, which show as a sequence gap once the thread catches up.
    FakeV4l2System system;
    FakeV4l2Device& device = system.add("/dev/video0", FakeV4l2Config::webcam());
    auto camera = openCamera(system);
    ASSERT_TRUE(camera);
    ASSERT_TRUE(camera->configure({PixelFormat::kGray8, 0, 0, 0}));
    capture::FramePool pool(8, PixelFormat::kGray8, 640, 480);
    std::mutex mutex;
    std::condition_variable cv;
    bool release = false;
    std::vector<std::uint64_t> sequences;
    camera->setFrameAllocator(&pool);
    camera->setFrameCallback([&](FrameHandle frame) {
        std::unique_lock lock(mutex);
        sequences.push_back(frame->meta.sequence);
        cv.notify_all();
        cv.wait(lock, [&] { return release; });
    });
    ASSERT_TRUE(camera->start());
    ASSERT_TRUE(device.waitAllQueued(kWait));
    ASSERT_TRUE(device.produceFrame());
    {
        std::unique_lock lock(mutex);
        ASSERT_TRUE(cv.wait_for(lock, kWait, [&] { return sequences.size() == 1; }));
    }
    // The thread requeued before calling back, so 4 buffers take 4 frames; the next 2 are lost.
    ASSERT_TRUE(device.waitAllQueued(kWait));
    for (int i = 0; i < 4; ++i) EXPECT_TRUE(device.produceFrame());
    EXPECT_FALSE(device.produceFrame());
    EXPECT_FALSE(device.produceFrame());
    EXPECT_EQ(device.framesLost(), 2u);
    {
        std::lock_guard lock(mutex);
        release = true;
        cv.notify_all();
    }
    ASSERT_TRUE(device.waitAllQueued(kWait));
    ASSERT_TRUE(device.produceFrame());
    ASSERT_TRUE(eventually([&] {
        std::lock_guard lock(mutex);
        return sequences.size() == 6;
    }));
    camera->stop();
    EXPECT_EQ(sequences, (std::vector<std::uint64_t>{0, 1, 2, 3, 4, 7}));
}

TEST(V4l2Errors, SpuriousWakeupsAndEagainAreRetried) {
    FakeV4l2System system;
    system.add("/dev/video0", FakeV4l2Config::webcam());
    Streaming s = startStreaming(system, {PixelFormat::kGray8, 0, 0, 0});
    ASSERT_TRUE(s.session);
    const int before = s.device->dqbufEagainCount();
    s.device->spuriousWakeup();
    ASSERT_TRUE(eventually([&] { return s.device->dqbufEagainCount() > before; }));
    ASSERT_TRUE(s.device->produceFrame());
    EXPECT_TRUE(s.next());
}

TEST(V4l2Errors, DisconnectMidStreamEndsWithADeviceErrorNamingTheDevice) {
    FakeV4l2System system;
    system.add("/dev/video0", FakeV4l2Config::webcam());
    Streaming s = startStreaming(system, {PixelFormat::kGray8, 0, 0, 0});
    ASSERT_TRUE(s.session);
    ASSERT_TRUE(s.device->waitAllQueued(kWait));
    ASSERT_TRUE(s.device->produceFrame());
    ASSERT_TRUE(s.next());
    s.device->disconnect();
    std::stop_source never;
    auto next = s.session->next(never.get_token(), kWait);
    ASSERT_FALSE(next);
    EXPECT_EQ(next.error().code, ErrorCode::kDevice);
    EXPECT_NE(next.error().message.find("v4l2:/dev/video0"), std::string::npos) << next.error().message;
    EXPECT_NE(next.error().message.find("disconnected"), std::string::npos) << next.error().message;
    s.session->stop();  // clean: joins, unmaps, does not hang on the dead device
    EXPECT_EQ(s.device->mappedCount(), 0u);
    s.session.reset();
    EXPECT_EQ(system.openCount(), 0);
}

TEST(V4l2Errors, NoFrameWithinTheTimeoutIsADeviceError) {
    FakeV4l2System system;
    FakeV4l2Device& device = system.add("/dev/video0", FakeV4l2Config::webcam());
    V4l2Options options = testOptions();
    options.timeout_ms = 50;
    auto camera = openCamera(system, "/dev/video0", options);
    ASSERT_TRUE(camera);
    ASSERT_TRUE(camera->configure({}));
    auto session = capture::CaptureSession::create(std::move(camera), {});
    ASSERT_TRUE(session);
    ASSERT_TRUE((*session)->start());
    ASSERT_TRUE(device.waitStreaming(kWait));
    std::stop_source never;
    auto next = (*session)->next(never.get_token(), kWait);
    ASSERT_FALSE(next);
    EXPECT_EQ(next.error().code, ErrorCode::kDevice);
    EXPECT_NE(next.error().message.find("timeout_ms"), std::string::npos) << next.error().message;
}

// --- controls ---

TEST(V4l2Controls, RangesByNumericId) {
    FakeV4l2System system;
    system.add("/dev/video0", FakeV4l2Config::webcam());
    auto camera = openCamera(system);
    ASSERT_TRUE(camera);
    ASSERT_TRUE(camera->configure({PixelFormat::kYuyv, 640, 480, 0}));
    bool exposure = false, gain = false, ae = false, awb = false, fps = false;
    for (const ControlInfo& c : camera->controls()) {
        switch (c.id) {
            case Control::kExposureUs:
                exposure = true;
                EXPECT_DOUBLE_EQ(c.min, 100.0);
                EXPECT_DOUBLE_EQ(c.max, 500000.0);
                EXPECT_DOUBLE_EQ(c.default_value, 15600.0);
                break;
            case Control::kAnalogGain:
                gain = true;
                EXPECT_DOUBLE_EQ(c.max, 255.0);
                break;
            case Control::kAutoExposure: ae = true; break;
            case Control::kAutoWhiteBalance: awb = true; break;
            case Control::kFrameRate:
                fps = true;
                EXPECT_DOUBLE_EQ(c.min, 15.0);
                EXPECT_DOUBLE_EQ(c.max, 30.0);
                break;
        }
    }
    EXPECT_TRUE(exposure && gain && ae && awb && fps);
}

TEST(V4l2Controls, SetAndGetGoToTheDevice) {
    FakeV4l2System system;
    FakeV4l2Device& device = system.add("/dev/video0", FakeV4l2Config::webcam());
    auto camera = openCamera(system);
    ASSERT_TRUE(camera);
    ASSERT_TRUE(camera->configure({PixelFormat::kYuyv, 640, 480, 0}));
    EXPECT_EQ(*camera->getControl(Control::kAutoExposure), 1.0);
    ASSERT_TRUE(camera->setControl(Control::kAutoExposure, 0));
    EXPECT_EQ(device.controlValue(V4L2_CID_EXPOSURE_AUTO), V4L2_EXPOSURE_MANUAL);
    ASSERT_TRUE(camera->setControl(Control::kExposureUs, 20000));
    EXPECT_EQ(device.controlValue(V4L2_CID_EXPOSURE_ABSOLUTE), 200);
    EXPECT_EQ(*camera->getControl(Control::kExposureUs), 20000.0);
    ASSERT_TRUE(camera->setControl(Control::kAnalogGain, 64));
    EXPECT_EQ(*camera->getControl(Control::kAnalogGain), 64.0);
    ASSERT_TRUE(camera->setControl(Control::kAutoWhiteBalance, 0));
    EXPECT_EQ(device.controlValue(V4L2_CID_AUTO_WHITE_BALANCE), 0);
    EXPECT_EQ(*camera->getControl(Control::kAutoWhiteBalance), 0.0);
    ASSERT_TRUE(camera->setControl(Control::kFrameRate, 15));
    EXPECT_DOUBLE_EQ(device.currentFps(), 15.0);
    EXPECT_DOUBLE_EQ(*camera->getControl(Control::kFrameRate), 15.0);
    ASSERT_TRUE(camera->setControl(Control::kAutoExposure, 1));
    EXPECT_EQ(device.controlValue(V4L2_CID_EXPOSURE_AUTO), V4L2_EXPOSURE_APERTURE_PRIORITY);

    auto out_of_range = camera->setControl(Control::kExposureUs, 1e9);
    ASSERT_FALSE(out_of_range);
    EXPECT_EQ(out_of_range.error().code, ErrorCode::kUsage);
    EXPECT_NE(out_of_range.error().message.find("exposure_us"), std::string::npos) << out_of_range.error().message;
}

TEST(V4l2Controls, AnalogueGainIsPreferredAndMissingControlsAreUnsupported) {
    FakeV4l2System system;
    FakeV4l2Config config = FakeV4l2Config::webcam();
    config.controls = {{V4L2_CID_ANALOGUE_GAIN, 16, 160, 1, 16, 16}, {V4L2_CID_GAIN, 0, 10, 1, 0, 0}};
    FakeV4l2Device& device = system.add("/dev/video0", config);
    auto camera = openCamera(system);
    ASSERT_TRUE(camera);
    ASSERT_TRUE(camera->setControl(Control::kAnalogGain, 32));
    EXPECT_EQ(device.controlValue(V4L2_CID_ANALOGUE_GAIN), 32);
    EXPECT_EQ(device.controlValue(V4L2_CID_GAIN), 0);
    for (Control c : {Control::kExposureUs, Control::kAutoExposure, Control::kAutoWhiteBalance}) {
        auto set = camera->setControl(c, 1);
        ASSERT_FALSE(set);
        EXPECT_EQ(set.error().code, ErrorCode::kUnsupported);
        EXPECT_NE(set.error().message.find(std::string(controlName(c))), std::string::npos) << set.error().message;
        EXPECT_NE(set.error().message.find("/dev/video0"), std::string::npos) << set.error().message;
        auto get = camera->getControl(c);
        ASSERT_FALSE(get);
        EXPECT_EQ(get.error().code, ErrorCode::kUnsupported);
    }
}

TEST(V4l2Controls, TheResponseFollowsTheGammaControl) {
    struct Case {
        std::optional<mocks::FakeV4l2Control> gamma;
        std::string spec;
    };
    const std::vector<Case> cases = {
        {std::nullopt, "srgb"},                                 // no control: a webcam's sRGB
        {mocks::FakeV4l2Control{V4L2_CID_GAMMA, 72, 500, 1, 100, 100}, "srgb"},  // at its default
        {mocks::FakeV4l2Control{V4L2_CID_GAMMA, 72, 500, 1, 100, 150}, "gamma:3.3"},
        {mocks::FakeV4l2Control{V4L2_CID_GAMMA, 1, 500, 1, 220, 110}, "gamma:1.1"},
    };
    for (const Case& c : cases) {
        FakeV4l2System system;
        FakeV4l2Config config = FakeV4l2Config::webcam();
        if (c.gamma) config.controls.push_back(*c.gamma);
        system.add("/dev/video0", config);
        auto camera = openCamera(system);
        ASSERT_TRUE(camera);
        EXPECT_EQ(camera->responseSpec(), c.spec);
        EXPECT_TRUE(ResponseCurve::parse(camera->responseSpec(), "."));
    }
}

TEST(V4l2Controls, FramesCarryTheExposureTheCameraChose) {
    FakeV4l2System system;
    system.add("/dev/video0", FakeV4l2Config::webcam());
    Streaming s = startStreaming(system, {PixelFormat::kGray8, 0, 0, 0});
    ASSERT_TRUE(s.session);
    // Auto exposure on: the camera moves exposure and gain; frames catch up within a few frames.
    s.device->setControlValue(V4L2_CID_EXPOSURE_ABSOLUTE, 300);
    s.device->setControlValue(V4L2_CID_GAIN, 77);
    FrameMetadata last;
    for (int i = 0; i < 20; ++i) {
        ASSERT_TRUE(s.device->waitAllQueued(kWait));
        ASSERT_TRUE(s.device->produceFrame());
        FrameHandle frame = s.next();
        ASSERT_TRUE(frame);
        last = frame->meta;
    }
    EXPECT_DOUBLE_EQ(last.exposure_us, 30000.0);
    EXPECT_DOUBLE_EQ(last.analog_gain, 77.0);
    // Locked (auto off, set by us): frames carry what we set.
    ASSERT_TRUE(s.session->camera().setControl(Control::kAutoExposure, 0));
    ASSERT_TRUE(s.session->camera().setControl(Control::kExposureUs, 5000));
    ASSERT_TRUE(s.device->waitAllQueued(kWait));
    ASSERT_TRUE(s.device->produceFrame());
    FrameHandle frame = s.next();
    ASSERT_TRUE(frame);
    EXPECT_DOUBLE_EQ(frame->meta.exposure_us, 5000.0);
}

// --- the fake's state machine (what the backend is tested against) ---

TEST(FakeV4l2, RefusesIllegalBufferTransitions) {
    FakeV4l2System system;
    system.add("/dev/video0", FakeV4l2Config::webcam());
    const int fd = system.open("/dev/video0", 0);
    ASSERT_GE(fd, 0);
    v4l2_requestbuffers req{};
    req.count = 2;
    req.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    req.memory = V4L2_MEMORY_MMAP;
    ASSERT_EQ(system.ioctl(fd, VIDIOC_REQBUFS, &req), 0);
    v4l2_buffer buf{};
    buf.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    buf.memory = V4L2_MEMORY_MMAP;
    EXPECT_EQ(system.ioctl(fd, VIDIOC_DQBUF, &buf), -1);
    EXPECT_EQ(errno, EINVAL) << "DQBUF before STREAMON";
    buf.index = 0;
    ASSERT_EQ(system.ioctl(fd, VIDIOC_QBUF, &buf), 0);
    EXPECT_EQ(system.ioctl(fd, VIDIOC_QBUF, &buf), -1);
    EXPECT_EQ(errno, EINVAL) << "QBUF of a queued buffer";
    int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    ASSERT_EQ(system.ioctl(fd, VIDIOC_STREAMON, &type), 0);
    EXPECT_EQ(system.ioctl(fd, VIDIOC_REQBUFS, &req), -1);
    EXPECT_EQ(errno, EBUSY) << "REQBUFS while streaming";
    v4l2_buffer out{};
    out.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    out.memory = V4L2_MEMORY_MMAP;
    EXPECT_EQ(system.ioctl(fd, VIDIOC_DQBUF, &out), -1);
    EXPECT_EQ(errno, EAGAIN) << "nothing done yet";
    ASSERT_EQ(system.ioctl(fd, VIDIOC_STREAMOFF, &type), 0);
    EXPECT_EQ(system.close(fd), 0);
}

// --- enumeration and registration ---

TEST(V4l2Enumerate, ListsCaptureDevicesOnly) {
    FakeV4l2System system;
    FakeV4l2Config first = FakeV4l2Config::webcam();
    first.card = "First cam";
    FakeV4l2Config meta = FakeV4l2Config::webcam();
    meta.capabilities = V4L2_CAP_META_CAPTURE | V4L2_CAP_STREAMING;  // a UVC metadata node
    FakeV4l2Config second;
    second.card = "Second cam";
    second.formats = {{V4L2_PIX_FMT_GREY, {{752, 480, 0, 0, 0, 0, {60}}}}};
    system.add("/dev/video0", first);
    system.add("/dev/video1", meta);
    system.add("/dev/video4", second);
    const std::vector<CameraInfo> cameras = enumerateCameras(system);
    ASSERT_EQ(cameras.size(), 2u);
    EXPECT_EQ(cameras[0].uri, "v4l2:/dev/video0");
    EXPECT_EQ(cameras[0].name, "First cam");
    EXPECT_EQ(cameras[0].backend, "v4l2");
    EXPECT_EQ(cameras[0].formats.size(), 6u);
    EXPECT_EQ(cameras[1].uri, "v4l2:/dev/video4");
    EXPECT_EQ(cameras[1].name, "Second cam");
    EXPECT_EQ(cameras[1].formats, (std::vector<StreamFormat>{{PixelFormat::kGray8, 752, 480, {60}, 0}}));
    EXPECT_EQ(system.openCount(), 0) << "enumeration closes every device";
}

TEST(V4l2Backend, RegistersTheSchemeAndItsOptions) {
    CameraRegistry registry;
    registerBackend(registry);
    const Backend* backend = registry.find("v4l2");
    ASSERT_NE(backend, nullptr);
    EXPECT_TRUE(backend->enumerate);
    EXPECT_TRUE(registry.parse("v4l2:/dev/video0?buffers=3&timeout_ms=500&format=yuyv"));
    auto bad = registry.parse("v4l2:/dev/video0?bogus=1");
    ASSERT_FALSE(bad);
    EXPECT_EQ(bad.error().code, ErrorCode::kUsage);
    auto few = registry.open("v4l2:/dev/video0?buffers=1");
    ASSERT_FALSE(few);
    EXPECT_EQ(few.error().code, ErrorCode::kUsage);
    auto missing = registry.open("v4l2:/nonexistent/commonlight-video99");
    ASSERT_FALSE(missing);
    EXPECT_EQ(missing.error().code, ErrorCode::kNotFound);
    EXPECT_NE(missing.error().message.find("/nonexistent/commonlight-video99"), std::string::npos);
}

}  // namespace
}  // namespace commonlight::hal::v4l2

#include "capture/recorder.h"

#include <csignal>
#include <fstream>
#include <string>
#include <vector>

#include <sys/resource.h>

#include <gtest/gtest.h>

#include "core/frame_file.h"
#include "core/sequence_io.h"
#include "tests/test_support.h"


namespace commonlight::capture {
namespace {

namespace fs = std::filesystem;
using testing::TempDir;

constexpr int kW = 64;
constexpr int kH = 48;
constexpr std::int64_t kPeriodNs = 33'333'333;

// Pixels from a seed; `noisy` makes them hard to compress (a large PNG).
Frame makeFrame(std::uint64_t sequence, int seed, bool noisy = false) {
    Frame frame;
    frame.image.reshape(PixelFormat::kRgb8, kW, kH);
    std::uint32_t state = static_cast<std::uint32_t>(seed) * 2654435761u + 1;
    for (std::size_t i = 0; i < frame.image.sizeBytes(); ++i) {
        state = state * 1664525u + 1013904223u;
        frame.image.data()[i] = noisy ? static_cast<std::uint8_t>(state >> 24) : static_cast<std::uint8_t>(seed * 40);
    }
    frame.meta.sequence = sequence;
    frame.meta.timestamp_ns = 1'000'000'000 + static_cast<std::int64_t>(sequence) * kPeriodNs;
    frame.meta.exposure_us = 5000;
    frame.meta.analog_gain = 2;
    return frame;
}

RecorderOptions fastOptions(std::size_t queue_frames) {
    RecorderOptions options;
    options.queue_frames = queue_frames;
    options.sync = false;  // tests need no power-loss safety
    return options;
}

void expectFramesOnDisk(const fs::path& root, const std::vector<const Frame*>& expected) {
    auto sequence = readSequence(root);
    ASSERT_TRUE(sequence) << sequence.error().message;
    ASSERT_EQ(sequence->frames.size(), expected.size());
    FrameFileReader reader;
    for (std::size_t i = 0; i < expected.size(); ++i) {
        EXPECT_EQ(sequence->frames[i].timestamp_ns, expected[i]->meta.timestamp_ns);
        Image back;
        auto read = reader.read(sequence->framePath(i), sequence->sensor.pixel_format, sequence->sensor.width,
                                sequence->sensor.height, back);
        ASSERT_TRUE(read) << read.error().message;
        EXPECT_TRUE(samePixels(back, expected[i]->image)) << "frame " << i;
        ASSERT_TRUE(i < sequence->meta.size() && sequence->meta[i]);
        EXPECT_EQ(sequence->meta[i]->sequence, expected[i]->meta.sequence);
        EXPECT_EQ(sequence->meta[i]->status, expected[i]->meta.status);
    }
}

TEST(Recorder, WritesEveryFrameBitIdenticalWithItsStatus) {
    TempDir dir;
    SensorInfo sensor;
    sensor.width = kW;
    sensor.height = kH;
    sensor.pixel_format = PixelFormat::kRgb8;  // known: the copies are allocated at start
    sensor.rate_hz = 30;
    auto recorder = Recorder::start(dir / "seq", sensor, fastOptions(8));
    ASSERT_TRUE(recorder) << recorder.error().message;

    std::vector<Frame> frames;
    for (int i = 0; i < 5; ++i) frames.push_back(makeFrame(static_cast<std::uint64_t>(i), i, i % 2 == 1));
    frames[3].meta.status = FrameStatus::kCorrupt;  // kept: the data must not be lost
    for (const Frame& frame : frames) EXPECT_TRUE((*recorder)->push(frame));  // 5 <= 8 slots: never full
    Frame empty;
    empty.meta.timestamp_ns = 2'000'000'000;
    EXPECT_FALSE((*recorder)->push(empty));

    const RecorderSummary summary = (*recorder)->finish();
    EXPECT_EQ(summary.frames_written, 5u);
    EXPECT_EQ(summary.frames_queued, 5u);
    EXPECT_EQ(summary.dropped, 0u);
    EXPECT_EQ(summary.rejected, 0u);
    EXPECT_EQ(summary.skipped_empty, 1u);
    EXPECT_EQ(summary.corrupt_written, 1u);
    EXPECT_FALSE(summary.write_error);
    EXPECT_EQ((*recorder)->finish().frames_written, 5u);  // finish() again: same summary

    std::vector<const Frame*> expected;
    for (const Frame& frame : frames) expected.push_back(&frame);
    expectFramesOnDisk(dir / "seq", expected);
}

TEST(Recorder, FullQueueDropsExactlyTheFramesThatFoundNoSlot) {
    TempDir dir;
    RecorderOptions options = fastOptions(3);
    options.start_paused = true;  // the writer waits: the queue fills deterministically
    auto recorder = Recorder::start(dir / "seq", SensorInfo{}, options);
    ASSERT_TRUE(recorder) << recorder.error().message;
    std::vector<Frame> frames;
    for (int i = 0; i < 10; ++i) frames.push_back(makeFrame(static_cast<std::uint64_t>(i), i));
    int queued = 0;
    for (const Frame& frame : frames) queued += (*recorder)->push(frame) ? 1 : 0;
    EXPECT_EQ(queued, 3);
    EXPECT_EQ((*recorder)->summary().dropped, 7u);
    EXPECT_EQ((*recorder)->summary().frames_written, 0u);

    (*recorder)->resume();
    (*recorder)->flush();
    EXPECT_EQ((*recorder)->summary().frames_written, 3u);
    EXPECT_TRUE((*recorder)->push(makeFrame(20, 20)));  // slots are free again
    const RecorderSummary summary = (*recorder)->finish();
    EXPECT_EQ(summary.frames_written, 4u);
    EXPECT_EQ(summary.dropped, 7u);
    const Frame last = makeFrame(20, 20);
    expectFramesOnDisk(dir / "seq", {&frames[0], &frames[1], &frames[2], &last});
}

TEST(Recorder, FinishWritesWhatIsQueuedEvenWhenPaused) {
    TempDir dir;
    RecorderOptions options = fastOptions(4);
    options.start_paused = true;
    auto recorder = Recorder::start(dir / "seq", SensorInfo{}, options);
    ASSERT_TRUE(recorder);
    const Frame a = makeFrame(1, 1);
    const Frame b = makeFrame(2, 2);
    (*recorder)->push(a);
    (*recorder)->push(b);
    (*recorder)->flush();  // returns at once while paused
    EXPECT_EQ((*recorder)->finish().frames_written, 2u);
    EXPECT_FALSE((*recorder)->push(a));  // after finish: counted as dropped
    EXPECT_EQ((*recorder)->summary().dropped, 1u);
    expectFramesOnDisk(dir / "seq", {&a, &b});
}

TEST(Recorder, UnwritableFolderIsAnErrorNamingIt) {
    TempDir dir;
    std::ofstream(dir / "file.txt") << "not a folder";
    auto under_file = Recorder::start(dir / "file.txt" / "seq", SensorInfo{}, fastOptions(2));
    ASSERT_FALSE(under_file);
    EXPECT_EQ(under_file.error().code, ErrorCode::kIo);
    EXPECT_NE(under_file.error().message.find((dir / "file.txt" / "seq").string()), std::string::npos)
        << under_file.error().message;

    auto in_proc = Recorder::start("/proc/commonlight-recorder-test", SensorInfo{}, fastOptions(2));
    ASSERT_FALSE(in_proc);
    EXPECT_NE(in_proc.error().message.find("/proc/commonlight-recorder-test"), std::string::npos)
        << in_proc.error().message;
}

TEST(Recorder, RefusesAFolderThatHoldsASequenceAndBadOptions) {
    TempDir dir;
    {
        auto first = Recorder::start(dir / "seq", SensorInfo{}, fastOptions(2));
        ASSERT_TRUE(first);
        (*first)->push(makeFrame(0, 0));
    }  // the destructor finishes
    auto second = Recorder::start(dir / "seq", SensorInfo{}, fastOptions(2));
    ASSERT_FALSE(second);
    EXPECT_NE(second.error().message.find("already holds a sequence"), std::string::npos) << second.error().message;

    auto bad = Recorder::start(dir / "other", SensorInfo{}, fastOptions(0));
    ASSERT_FALSE(bad);
    EXPECT_EQ(bad.error().code, ErrorCode::kUsage);
}

TEST(Recorder, FrameTheSequenceCannotTakeIsRejectedAndRecordingGoesOn) {
    TempDir dir;
    auto recorder = Recorder::start(dir / "seq", SensorInfo{}, fastOptions(4));
    ASSERT_TRUE(recorder);
    const Frame a = makeFrame(5, 1);
    Frame same_time = makeFrame(6, 2);
    same_time.meta.timestamp_ns = a.meta.timestamp_ns;  // not after the previous frame
    const Frame c = makeFrame(7, 3);
    (*recorder)->push(a);
    (*recorder)->flush();
    (*recorder)->push(same_time);
    (*recorder)->flush();
    (*recorder)->push(c);
    const RecorderSummary summary = (*recorder)->finish();
    EXPECT_EQ(summary.frames_written, 2u);
    EXPECT_EQ(summary.rejected, 1u);
    ASSERT_TRUE(summary.first_rejection);
    EXPECT_NE(summary.first_rejection->message.find("frame 6"), std::string::npos) << summary.first_rejection->message;
    EXPECT_FALSE(summary.write_error);
    expectFramesOnDisk(dir / "seq", {&a, &c});
}

// Simulates a full disk: RLIMIT_FSIZE makes write(2) fail with EFBIG (for root too) once a file
// would grow past the limit. Small frames fit, a noisy one does not.
class FileSizeLimit {
public:
    explicit FileSizeLimit(rlim_t bytes) {
        previous_handler_ = std::signal(SIGXFSZ, SIG_IGN);  // else the process is killed
        getrlimit(RLIMIT_FSIZE, &previous_);
        rlimit limited = previous_;
        limited.rlim_cur = bytes;
        ok_ = setrlimit(RLIMIT_FSIZE, &limited) == 0;
    }
    ~FileSizeLimit() {
        setrlimit(RLIMIT_FSIZE, &previous_);
        std::signal(SIGXFSZ, previous_handler_);
    }
    bool ok() const { return ok_; }

private:
    rlimit previous_{};
    void (*previous_handler_)(int) = nullptr;
    bool ok_ = false;
};

TEST(Recorder, WriteErrorStopsRecordingKeepsWrittenFramesAndNamesTheFile) {
    TempDir dir;
    auto recorder = Recorder::start(dir / "seq", SensorInfo{}, fastOptions(4));
    ASSERT_TRUE(recorder) << recorder.error().message;
    const Frame a = makeFrame(0, 1);  // constant colour: a tiny PNG
    const Frame b = makeFrame(1, 2);
    (*recorder)->push(a);
    (*recorder)->push(b);
    (*recorder)->flush();
    ASSERT_EQ((*recorder)->summary().frames_written, 2u);
    {
        FileSizeLimit limit(4096);  // the noisy 64x48 RGB frame needs about 9 KB
        ASSERT_TRUE(limit.ok());
        EXPECT_TRUE((*recorder)->push(makeFrame(2, 3, true)));
        (*recorder)->flush();
    }
    const RecorderSummary failed = (*recorder)->summary();
    ASSERT_TRUE(failed.write_error);
    EXPECT_EQ(failed.write_error->code, ErrorCode::kIo);
    EXPECT_NE(failed.write_error->message.find((dir / "seq" / "cam0" / "data").string()), std::string::npos)
        << failed.write_error->message;
    EXPECT_NE(failed.write_error->message.find("File too large"), std::string::npos) << failed.write_error->message;
    EXPECT_NE(failed.write_error->message.find("stopped after 2 frames"), std::string::npos)
        << failed.write_error->message;

    EXPECT_FALSE((*recorder)->push(makeFrame(3, 4)));  // recording stopped: counted as dropped
    const RecorderSummary summary = (*recorder)->finish();
    EXPECT_EQ(summary.frames_written, 2u);
    EXPECT_EQ(summary.dropped, 1u);
    expectFramesOnDisk(dir / "seq", {&a, &b});
}

}  // namespace
}  // namespace commonlight::capture

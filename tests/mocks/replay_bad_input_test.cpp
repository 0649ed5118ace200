#include "mocks/replay_camera.h"

#include <fstream>

#include <gtest/gtest.h>

#include "core/frame_file.h"
#include "tests/mocks/replay_test_support.h"
#include "tests/test_support.h"

namespace commonlight::mocks {
namespace {

namespace fs = std::filesystem;
using testing::configureAndStart;
using testing::FrameSink;
using testing::kInterval;
using testing::openReplay;
using testing::rate;
using testing::TempDir;
using testing::TestFramePool;
using testing::writeTestSequence;

// ---- bad input ------------------------------------------------------------------------------

// Flips bytes in the middle of a file: the PNG's header stays valid, its image data fails its CRC.
void damageMiddle(const fs::path& file) {
    std::fstream io(file, std::ios::in | std::ios::out | std::ios::binary);
    const auto size = static_cast<std::streamoff>(fs::file_size(file));
    for (std::streamoff at = size / 2; at < size / 2 + 16 && at < size; ++at) {
        io.seekg(at);
        const char byte = static_cast<char>(io.get());
        io.seekp(at);
        io.put(static_cast<char>(byte ^ 0x5A));
    }
}

TEST(ReplayBadInput, CorruptAndTruncatedPngsBecomeCorruptFramesAndPlaybackGoesOn) {
    TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kRgb8, 5, kInterval);
    auto sequence = readSequence(dir.path());
    ASSERT_TRUE(sequence);
    const fs::path corrupt = sequence->framePath(1);
    const fs::path truncated = sequence->framePath(3);
    damageMiddle(corrupt);
    fs::resize_file(truncated, fs::file_size(truncated) / 2);

    ManualClock clock;
    TestFramePool pool(2);
    FrameSink sink;
    auto camera = openReplay(dir.path(), rate(PlaybackRate::kMax), clock);
    ASSERT_TRUE(camera);
    ::testing::internal::CaptureStderr();
    configureAndStart(*camera, sink, pool);
    ASSERT_TRUE(sink.waitForEvents(1));
    camera->stop();
    const std::string log = ::testing::internal::GetCapturedStderr();

    const auto metas = sink.metas();
    ASSERT_EQ(metas.size(), 5u);
    const FrameStatus expected[] = {FrameStatus::kOk, FrameStatus::kCorrupt, FrameStatus::kOk, FrameStatus::kCorrupt,
                                    FrameStatus::kOk};
    for (std::size_t i = 0; i < 5; ++i) EXPECT_EQ(metas[i].status, expected[i]) << "frame " << i;
    EXPECT_EQ(metas[1].timestamp_ns, sequence->frames[1].timestamp_ns) << "a corrupt frame keeps its metadata";
    EXPECT_EQ(metas[1].sequence, 1u);
    EXPECT_EQ(camera->corruptFrames(), 2u);
    EXPECT_NE(log.find("warning"), std::string::npos);
    EXPECT_NE(log.find(corrupt.string()), std::string::npos) << log;
    EXPECT_NE(log.find(truncated.string()), std::string::npos) << log;
}

TEST(ReplayBadInput, CorruptFramesCarryAnEmptyImage) {
    TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kGray16, 3, kInterval);
    auto sequence = readSequence(dir.path());
    ASSERT_TRUE(sequence);
    fs::resize_file(sequence->framePath(2), fs::file_size(sequence->framePath(2)) / 2);
    ManualClock clock;
    TestFramePool pool(1);  // one slot: frame 2 reuses the slot that held frame 1's pixels
    FrameSink sink({.keep_images = true});
    auto camera = openReplay(dir.path(), rate(PlaybackRate::kMax), clock);
    ASSERT_TRUE(camera);
    ::testing::internal::CaptureStderr();
    configureAndStart(*camera, sink, pool);
    ASSERT_TRUE(sink.waitForEvents(1));
    camera->stop();
    ::testing::internal::GetCapturedStderr();
    ASSERT_EQ(sink.frames().size(), 3u);
    EXPECT_FALSE(sink.frames()[1].image.empty());
    EXPECT_TRUE(sink.frames()[2].image.empty()) << "no stale pixels from the previous frame";
    EXPECT_EQ(sink.frames()[2].meta.status, FrameStatus::kCorrupt);
}

TEST(ReplayBadInput, AFileThatIsNoImageBecomesACorruptFrame) {
    TempDir dir;
    writeTestSequence(dir.path() / "seq", PixelFormat::kRgb8, 3, kInterval);
    auto sequence = readSequence(dir.path() / "seq");
    ASSERT_TRUE(sequence);
    testing::writeText(sequence->framePath(1), "\x89PNG\r\n\x1a\n not a PNG body");
    ManualClock clock;
    TestFramePool pool(2);
    FrameSink sink;
    auto camera = openReplay(dir.path() / "seq", rate(PlaybackRate::kMax), clock);
    ASSERT_TRUE(camera);
    ::testing::internal::CaptureStderr();
    configureAndStart(*camera, sink, pool);
    ASSERT_TRUE(sink.waitForEvents(1));
    camera->stop();
    const std::string log = ::testing::internal::GetCapturedStderr();
    const auto metas = sink.metas();
    ASSERT_EQ(metas.size(), 3u);
    EXPECT_EQ(metas[1].status, FrameStatus::kCorrupt);
    EXPECT_NE(log.find(sequence->framePath(1).string()), std::string::npos) << log;
}

TEST(ReplayBadInput, MissingFileBecomesACorruptFrameWithAWarning) {
    TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kRgb8, 4, kInterval);
    auto sequence = readSequence(dir.path());
    ASSERT_TRUE(sequence);
    const fs::path missing = sequence->framePath(2);
    fs::remove(missing);
    ManualClock clock;
    TestFramePool pool(2);
    FrameSink sink;
    auto camera = openReplay(dir.path(), rate(PlaybackRate::kMax), clock);
    ASSERT_TRUE(camera);
    ::testing::internal::CaptureStderr();
    configureAndStart(*camera, sink, pool);
    ASSERT_TRUE(sink.waitForEvents(1));
    camera->stop();
    const std::string log = ::testing::internal::GetCapturedStderr();
    const auto metas = sink.metas();
    ASSERT_EQ(metas.size(), 4u);
    EXPECT_EQ(metas[2].status, FrameStatus::kCorrupt);
    EXPECT_EQ(metas[3].status, FrameStatus::kOk);
    EXPECT_EQ(camera->corruptFrames(), 1u);
    EXPECT_NE(log.find(missing.string()), std::string::npos) << log;
}

TEST(ReplayBadInput, MalformedSequenceFailsToOpenNamingTheFile) {
    TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kRgb8, 2, kInterval);
    const fs::path data_csv = dir.path() / "cam0" / "data.csv";
    testing::writeText(data_csv, "#timestamp [ns],filename\n1000,a.png\nnot-a-number,b.png\n");
    ManualClock clock;
    const auto opened = ReplayCamera::open(dir.path(), {}, clock);
    ASSERT_FALSE(opened);
    EXPECT_EQ(opened.error().code, ErrorCode::kBadInput);
    EXPECT_NE(opened.error().message.find(data_csv.string()), std::string::npos) << opened.error().message;
}

TEST(ReplayBadInput, MalformedSensorYamlFailsToOpenNamingTheFile) {
    TempDir dir;
    writeTestSequence(dir.path(), PixelFormat::kRgb8, 2, kInterval);
    const fs::path sensor = dir.path() / "cam0" / "sensor.yaml";
    testing::writeText(sensor, "resolution: [32]\n");
    ManualClock clock;
    const auto opened = ReplayCamera::open(dir.path(), {}, clock);
    ASSERT_FALSE(opened);
    EXPECT_EQ(opened.error().code, ErrorCode::kBadInput);
    EXPECT_NE(opened.error().message.find(sensor.string()), std::string::npos) << opened.error().message;
}

TEST(ReplayBadInput, EmptySequenceAndMissingFolder) {
    TempDir dir;
    testing::writeText(dir.path() / "cam0" / "data.csv", "#timestamp [ns],filename\n");
    testing::writeText(dir.path() / "cam0" / "sensor.yaml", "resolution: [32, 24]\n");
    ManualClock clock;
    const auto empty = ReplayCamera::open(dir.path(), {}, clock);
    ASSERT_FALSE(empty);
    EXPECT_EQ(empty.error().code, ErrorCode::kBadInput);
    EXPECT_NE(empty.error().message.find("data.csv"), std::string::npos);

    const auto missing = ReplayCamera::open(dir.path() / "nope", {}, clock);
    ASSERT_FALSE(missing);
    EXPECT_EQ(missing.error().code, ErrorCode::kNotFound);
    EXPECT_NE(missing.error().message.find("nope"), std::string::npos);
}

}  // namespace
}  // namespace commonlight::mocks

#include "core/sequence_io.h"

#include <fstream>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "core/frame_file.h"
#include "core/sequence_writer.h"
#include "tests/test_support.h"

namespace commonlight {
namespace {

namespace fs = std::filesystem;
using testing::TempDir;
using testing::writeText;

Image patternImage(PixelFormat format, int width, int height, int seed) {
    Image image(format, width, height);
    for (std::size_t i = 0; i < image.sizeBytes(); ++i) {
        image.data()[i] = static_cast<std::uint8_t>((i * 31 + static_cast<std::size_t>(seed) * 7 + i / 97) & 0xFF);
    }
    return image;
}

FrameMetadata metaAt(std::int64_t t, std::uint64_t seq) {
    FrameMetadata m;
    m.timestamp_ns = t;
    m.sequence = seq;
    m.exposure_us = 8000.5;
    m.analog_gain = 1.25;
    return m;
}

class SequenceRoundTrip : public ::testing::TestWithParam<PixelFormat> {};

TEST_P(SequenceRoundTrip, WriteThenReadIsBitIdentical) {
    const PixelFormat format = GetParam();
    TempDir dir;
    SensorInfo sensor;
    sensor.rate_hz = 30.0;
    CameraModel cam;
    cam.width = 64;
    cam.height = 48;
    cam.fx = 50.25;
    cam.fy = 51.5;
    cam.cx = 31.75;
    cam.cy = 23.5;
    cam.distortion = {-0.1, 0.01, 0.001, -0.002, 0.0005};
    sensor.camera = cam;
    auto writer = SequenceWriter::create(dir.path(), sensor);
    ASSERT_TRUE(writer) << writer.error().message;
    std::vector<Image> written;
    for (int i = 0; i < 3; ++i) {
        written.push_back(patternImage(format, 64, 48, i));
        auto r = writer->write(written.back(), metaAt(1'000'000'000 + i * 33'333'333, 10 + i));
        ASSERT_TRUE(r) << r.error().message;
    }
    auto seq = readSequence(dir.path());
    ASSERT_TRUE(seq) << seq.error().message;
    EXPECT_EQ(seq->sensor.width, 64);
    EXPECT_EQ(seq->sensor.pixel_format, format);
    ASSERT_TRUE(seq->sensor.camera);
    EXPECT_EQ(*seq->sensor.camera, cam);  // %.17g: exact
    EXPECT_EQ(seq->sensor.rate_hz, 30.0);
    ASSERT_EQ(seq->frames.size(), 3u);
    ASSERT_EQ(seq->meta.size(), 3u);
    FrameFileReader reader;
    for (int i = 0; i < 3; ++i) {
        EXPECT_EQ(seq->frames[i].timestamp_ns, 1'000'000'000 + i * 33'333'333);
        ASSERT_TRUE(seq->meta[i]);
        EXPECT_EQ(seq->meta[i]->sequence, 10u + i);
        EXPECT_EQ(seq->meta[i]->exposure_us, 8000.5);
        EXPECT_EQ(seq->meta[i]->analog_gain, 1.25);
        Image back;
        auto r = reader.read(seq->framePath(i), seq->sensor.pixel_format, seq->sensor.width, seq->sensor.height, back);
        ASSERT_TRUE(r) << r.error().message;
        EXPECT_TRUE(samePixels(back, written[i])) << "frame " << i;
    }
}

INSTANTIATE_TEST_SUITE_P(AllStorableFormats, SequenceRoundTrip,
                         ::testing::Values(PixelFormat::kGray8, PixelFormat::kGray16, PixelFormat::kRgb8,
                                           PixelFormat::kBgr8, PixelFormat::kRgba8, PixelFormat::kYuyv,
                                           PixelFormat::kNv12, PixelFormat::kBayerRggb8, PixelFormat::kBayerGrbg8,
                                           PixelFormat::kBayerGbrg8, PixelFormat::kBayerBggr8),
                         [](const auto& p) { return std::string(pixelFormatName(p.param)); });

TEST(SequenceIo, MjpegFramesAreStoredAsTheCameraSentThem) {
    TempDir dir;
    auto writer = SequenceWriter::create(dir.path(), {});
    ASSERT_TRUE(writer);
    std::vector<std::uint8_t> jpeg = {0xFF, 0xD8, 1, 2, 3, 4, 5, 0xFF, 0xD9};
    Image image;
    image.reshapeCompressed(320, 240, jpeg.size());
    std::copy(jpeg.begin(), jpeg.end(), image.data());
    ASSERT_TRUE(writer->write(image, metaAt(5, 0)));
    auto seq = readSequence(dir.path() / "cam0");  // the cam0 folder reads too
    ASSERT_TRUE(seq) << seq.error().message;
    EXPECT_EQ(seq->frames[0].filename, "5.jpg");
    EXPECT_EQ(seq->sensor.pixel_format, PixelFormat::kMjpeg);
    Image back;
    ASSERT_TRUE(FrameFileReader().read(seq->framePath(0), PixelFormat::kMjpeg, 320, 240, back));
    EXPECT_TRUE(samePixels(back, image));
}

TEST(SequenceIo, WriterRefusesToOverwriteAndNonIncreasingTimestamps) {
    TempDir dir;
    auto writer = SequenceWriter::create(dir.path(), {});
    ASSERT_TRUE(writer);
    Image image = patternImage(PixelFormat::kGray8, 8, 8, 0);
    ASSERT_TRUE(writer->write(image, metaAt(100, 0)));
    EXPECT_FALSE(writer->write(image, metaAt(100, 1)));
    EXPECT_FALSE(writer->write(image, metaAt(50, 1)));
    Image other = patternImage(PixelFormat::kGray8, 9, 8, 0);
    EXPECT_FALSE(writer->write(other, metaAt(200, 1)));
    auto again = SequenceWriter::create(dir.path(), {});
    ASSERT_FALSE(again);
    EXPECT_NE(again.error().message.find("refusing to overwrite"), std::string::npos);
}

// A EuRoC mav0/cam0 folder as distributed (OpenCV's "%YAML:1.0" header, 4 coefficients).
void writeEurocFolder(const fs::path& root) {
    writeText(root / "mav0/cam0/sensor.yaml", R"(%YAML:1.0
---
# General sensor definitions.
sensor_type: camera
comment: VI-Sensor cam0 (MT9M034)

# Sensor extrinsics wrt. the body-frame.
T_BS:
  cols: 4
  rows: 4
  data: [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975,
         0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768,
        -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949,
         0.0, 0.0, 0.0, 1.0]

# Camera specific definitions.
rate_hz: 20
resolution: [752, 480]
camera_model: pinhole
intrinsics: [458.654, 457.296, 367.215, 248.375] #fu, fv, cu, cv
distortion_model: radial-tangential
distortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
)");
    writeText(root / "mav0/cam0/data.csv",
              "#timestamp [ns],filename\r\n1403636579763555584,1403636579763555584.png\r\n"
              "1403636579813555456,1403636579813555456.png\r\n");
}

TEST(SequenceIo, ReadsAEurocFolderAsIs) {
    TempDir dir;
    writeEurocFolder(dir.path());
    for (const fs::path& p : {dir.path(), dir.path() / "mav0", dir.path() / "mav0/cam0"}) {
        auto seq = readSequence(p);
        ASSERT_TRUE(seq) << seq.error().message;
        EXPECT_EQ(seq->sensor.width, 752);
        EXPECT_EQ(seq->sensor.rate_hz, 20.0);
        ASSERT_TRUE(seq->sensor.camera);
        EXPECT_DOUBLE_EQ(seq->sensor.camera->fx, 458.654);
        EXPECT_DOUBLE_EQ(seq->sensor.camera->distortion.k1, -0.28340811);
        EXPECT_DOUBLE_EQ(seq->sensor.body_from_sensor(0, 1), -0.999880929698);
        ASSERT_EQ(seq->frames.size(), 2u);
        EXPECT_EQ(seq->frames[1].timestamp_ns, 1403636579813555456);
        EXPECT_EQ(seq->framePath(0), dir.path() / "mav0/cam0/data/1403636579763555584.png");
        EXPECT_TRUE(seq->meta.empty());
    }
}

// Each bad input: the error names the file and the line or key.
struct BadCase {
    const char* name;
    const char* file;      // relative to the sequence root
    const char* contents;
    const char* expected;  // substring of the message
};

class BadSequence : public ::testing::TestWithParam<BadCase> {};

TEST_P(BadSequence, FailsWithFileAndLine) {
    TempDir dir;
    writeEurocFolder(dir.path());
    const fs::path root = dir.path() / "mav0";
    writeText(root / GetParam().file, GetParam().contents);
    auto seq = readSequence(root);
    ASSERT_FALSE(seq);
    EXPECT_EQ(seq.error().code, ErrorCode::kBadInput);
    EXPECT_NE(seq.error().message.find(GetParam().file), std::string::npos) << seq.error().message;
    EXPECT_NE(seq.error().message.find(GetParam().expected), std::string::npos) << seq.error().message;
}

INSTANTIATE_TEST_SUITE_P(
    Cases, BadSequence,
    ::testing::Values(
        BadCase{"Truncated", "cam0/data.csv", "#timestamp [ns],filename\n100,100.png\n200", ":3: expected 2 columns"},
        BadCase{"NonNumeric", "cam0/data.csv", "#h\n10x,a.png\n", ":2: column 'timestamp [ns]'"},
        BadCase{"Duplicate", "cam0/data.csv", "#h\n100,a.png\n100,b.png\n", ":3: duplicate timestamp 100"},
        BadCase{"Decreasing", "cam0/data.csv", "#h\n100,a.png\n200,b.png\n150,c.png\n", ":4: decreasing timestamp 150"},
        BadCase{"EscapingName", "cam0/data.csv", "#h\n100,../../etc/passwd\n", ":2: filename"},
        BadCase{"SensorSyntax", "cam0/sensor.yaml", "resolution: [752, 480\nrate_hz: 20\n", "YAML syntax error"},
        BadCase{"SensorMissingResolution", "cam0/sensor.yaml", "rate_hz: 20\n", "key 'resolution': missing"},
        BadCase{"SensorBadIntrinsics", "cam0/sensor.yaml", "resolution: [752, 480]\nintrinsics: [1, 2, 3]\n",
                ":2: key 'intrinsics': expected 4 numbers, found 3"},
        // Issue 14: the range was checked after the cast to int (UB for 1e10).
        BadCase{"SensorHugeResolution", "cam0/sensor.yaml", "resolution: [1e10, 480]\n",
                ":1: key 'resolution': expected two whole numbers from 1 to 65535, found 1e+10"},
        BadCase{"SensorNegativeResolution", "cam0/sensor.yaml", "resolution: [640, -1e300]\n",
                "key 'resolution': expected two whole numbers from 1 to 65535, found -1e+300"},
        BadCase{"SensorFractionalResolution", "cam0/sensor.yaml", "resolution: [640.5, 480]\n",
                "key 'resolution': expected two whole numbers from 1 to 65535, found 640.5"},
        BadCase{"SensorZeroResolution", "cam0/sensor.yaml", "resolution: [640, 0]\n",
                "key 'resolution': expected two whole numbers from 1 to 65535, found 0"},
        BadCase{"SensorNonNumber", "cam0/sensor.yaml", "resolution: [752, abc]\n", "key 'resolution[1]': expected a number"},
        BadCase{"SensorModel", "cam0/sensor.yaml", "resolution: [752, 480]\ncamera_model: omni\nintrinsics: [1,1,1,1]\n",
                ":2: key 'camera_model': 'omni' is not supported"},
        BadCase{"SensorPixelFormat", "cam0/sensor.yaml", "resolution: [752, 480]\npixel_format: bayer_xyz\n",
                "key 'pixel_format': unknown pixel format"},
        BadCase{"MetaStatus", "cam0/meta.csv", "#h\n1403636579763555584,0,100,1,broken\n", ":2: status must be"},
        BadCase{"PosesQuaternion", "groundtruth/cam_poses.csv", "#h\n1,0,0,0,2,0,0,0\n", ":2: quaternion is not unit"}),
    [](const auto& p) { return std::string(p.param.name); });

TEST(SequenceIo, NotASequenceFolder) {
    TempDir dir;
    auto seq = readSequence(dir.path());
    ASSERT_FALSE(seq);
    EXPECT_NE(seq.error().message.find("cam0/data.csv"), std::string::npos);
    auto missing = readSequence(dir / "nope");
    ASSERT_FALSE(missing);
    EXPECT_EQ(missing.error().code, ErrorCode::kNotFound);
}

TEST(SequenceIo, PosesRoundTripExactly) {
    TempDir dir;
    std::vector<PoseRecord> poses;
    for (int i = 0; i < 5; ++i) {
        poses.push_back({i * 1000 + 7, Rigid3d::fromRpyDeg({0.1 * i, -0.3, 1.7}, {3.0 * i, 45.0, -10.0 * i})});
    }
    ASSERT_TRUE(writePosesCsv(dir / "p.csv", poses));
    auto back = readPosesCsv(dir / "p.csv");
    ASSERT_TRUE(back);
    ASSERT_EQ(back->size(), poses.size());
    for (std::size_t i = 0; i < poses.size(); ++i) {
        EXPECT_EQ((*back)[i].timestamp_ns, poses[i].timestamp_ns);
        EXPECT_EQ((*back)[i].world_from_cam.translation, poses[i].world_from_cam.translation);
        EXPECT_LT(rotationErrorDeg((*back)[i].world_from_cam, poses[i].world_from_cam), 1e-12);
    }
}

// Which true pose a frame is compared with: the one at the middle of its exposure.
TEST(SequenceIo, GroundTruthOfAFrameIsAtTheMiddleOfItsExposure) {
    // A camera moving along x at 1 m/s, turning about z at 1 rad/s.
    const auto truthAt = [](std::int64_t t_ns) {
        const double t = t_ns * 1e-9;
        return Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(t, Eigen::Vector3d::UnitZ())), Eigen::Vector3d(t, 0, 1));
    };
    Sequence seq;
    for (int i = 0; i < 3; ++i) {
        const std::int64_t t = 100'000'000 * i;
        seq.frames.push_back({t, std::to_string(t) + ".png"});
        seq.meta.push_back(FrameMetaRecord{t, static_cast<std::uint64_t>(i), 20000.0, 1.0, FrameStatus::kOk});
        seq.groundtruth_poses.push_back({t, truthAt(t)});
    }
    EXPECT_EQ(framePoseInstantNs(seq, 1), 110'000'000);
    // Written before the mid-exposure file: the row at the frame's own timestamp (the simulator
    // rendered the frame at that instant then).
    EXPECT_LT(translationError(*groundTruthOfFrame(seq, 1), truthAt(100'000'000)), 1e-12);
    // With it: the mid-exposure row.
    for (int i = 0; i < 3; ++i) {
        const std::int64_t t = 100'000'000 * i + 10'000'000;
        seq.groundtruth_mid_exposure_poses.push_back({t, truthAt(t)});
    }
    EXPECT_LT(translationError(*groundTruthOfFrame(seq, 1), truthAt(110'000'000)), 1e-12);
    EXPECT_LT(translationError(*groundTruthAt(seq, 210'000'000), truthAt(210'000'000)), 1e-12);
    // Between rows (of either file): interpolated on SE(3) (the rotation exactly; the screw
    // motion's translation differs from this straight line by 12 micrometres over these 10 ms).
    const auto between = groundTruthAt(seq, 105'000'000);
    ASSERT_TRUE(between);
    EXPECT_LT(rotationErrorDeg(*between, truthAt(105'000'000)), 1e-9);
    EXPECT_LT(translationError(*between, truthAt(105'000'000)), 2e-5);
    // Outside the rows: nothing.
    EXPECT_FALSE(groundTruthAt(seq, -1));
    EXPECT_FALSE(groundTruthAt(seq, 210'000'001));

    // A motion-capture trajectory at its own rate (no row at any frame's timestamp): interpolated
    // at the frame's middle; rows more than 0.25 s apart are a gap, not interpolated.
    Sequence mocap = seq;
    mocap.groundtruth_mid_exposure_poses.clear();
    mocap.groundtruth_poses.clear();
    for (std::int64_t t = -5'000'000; t < 150'000'000; t += 5'000'000) {
        mocap.groundtruth_poses.push_back({t + 1'000'000, truthAt(t + 1'000'000)});
    }
    EXPECT_LT(rotationErrorDeg(*groundTruthOfFrame(mocap, 1), truthAt(110'000'000)), 1e-9);
    EXPECT_LT(translationError(*groundTruthOfFrame(mocap, 1), truthAt(110'000'000)), 5e-6);
    mocap.groundtruth_poses = {{0, truthAt(0)}, {300'000'000, truthAt(300'000'000)}};
    EXPECT_FALSE(groundTruthOfFrame(mocap, 1));
    // Without meta.csv the exposure is unknown: the frame's timestamp.
    mocap.meta.clear();
    EXPECT_EQ(framePoseInstantNs(mocap, 1), 100'000'000);
}

// A PNG header with a valid CRC declaring `width` x `height`, and one tiny zlib block of pixels.
std::string pngDeclaring(std::uint32_t width, std::uint32_t height) {
    const auto be32 = [](std::uint32_t v) {
        return std::string{static_cast<char>(v >> 24), static_cast<char>(v >> 16), static_cast<char>(v >> 8), static_cast<char>(v)};
    };
    const auto crc32 = [](const std::string& data) {
        std::uint32_t crc = 0xFFFFFFFFu;
        for (const char c : data) {
            crc ^= static_cast<std::uint8_t>(c);
            for (int k = 0; k < 8; ++k) crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
        }
        return crc ^ 0xFFFFFFFFu;
    };
    const auto chunk = [&](const std::string& type, const std::string& body) {
        return be32(static_cast<std::uint32_t>(body.size())) + type + body + be32(crc32(type + body));
    };
    const std::string ihdr = be32(width) + be32(height) + std::string("\x10\x06\x00\x00\x00", 5);  // RGBA16
    const std::string idat("\x78\x9c\x63\x00\x00\x00\x01\x00\x01", 9);                         // zlib of one 0 byte
    return std::string("\x89PNG\r\n\x1a\n", 8) + chunk("IHDR", ihdr) + chunk("IDAT", idat) + chunk("IEND", "");
}

// Issue 14, a crafted input run through fuzz_frame_file: a 69-byte PNG declaring 30000 x 30000
// RGBA16 made OpenCV allocate 7.2 GB before it found the pixels missing. The header is checked
// first; and only PNG and JPEG go to the decoder.
TEST(FrameFile, HeaderSizeIsCheckedBeforeDecoding) {
    TempDir dir;
    FrameFileReader reader;
    Image out;
    writeText(dir / "huge.png", pngDeclaring(30000, 30000));
    auto r = reader.read(dir / "huge.png", PixelFormat::kInvalid, 0, 0, out);
    ASSERT_FALSE(r);
    EXPECT_EQ(r.error().code, ErrorCode::kBadInput);
    EXPECT_NE(r.error().message.find("huge.png: the header declares a 30000x30000 image, larger than 67108864 pixels"),
              std::string::npos)
        << r.error().message;
    r = reader.read(dir / "huge.png", PixelFormat::kRgba8, 640, 480, out);
    ASSERT_FALSE(r);
    EXPECT_NE(r.error().message.find("declares a 30000x30000 image, but the sequence is 640x480"), std::string::npos)
        << r.error().message;
    writeText(dir / "empty.png", pngDeclaring(0, 480));
    r = reader.read(dir / "empty.png", PixelFormat::kInvalid, 0, 0, out);
    ASSERT_FALSE(r);
    EXPECT_NE(r.error().message.find("declares a 0x480 image"), std::string::npos) << r.error().message;
    // A JPEG's frame header says the same (SOF0: 40000 x 30000), for a sequence of gray frames.
    std::string jpeg("\xFF\xD8\xFF\xE0\x00\x04\x00\x00\xFF\xC0\x00\x0B\x08\x75\x30\x9C\x40\x01\x01\x11\x00\xFF\xD9", 23);
    writeText(dir / "huge.jpg", jpeg);
    r = reader.read(dir / "huge.jpg", PixelFormat::kGray8, 0, 0, out);
    ASSERT_FALSE(r);
    EXPECT_NE(r.error().message.find("huge.jpg: the header declares a 40000x30000 image"), std::string::npos)
        << r.error().message;
    // Another format OpenCV would decode (BMP) is not a frame file.
    std::vector<std::uint8_t> bmp;
    ASSERT_TRUE(cv::imencode(".bmp", cv::Mat(4, 4, CV_8UC3, cv::Scalar(1, 2, 3)), bmp));
    writeText(dir / "f.png", std::string(bmp.begin(), bmp.end()));
    r = reader.read(dir / "f.png", PixelFormat::kInvalid, 0, 0, out);
    ASSERT_FALSE(r);
    EXPECT_NE(r.error().message.find("f.png: not a PNG or JPEG file"), std::string::npos) << r.error().message;
}

TEST(FrameFile, CorruptAndTruncatedFilesAreErrorsNamingTheFile) {
    TempDir dir;
    FrameFileWriter encoder;
    std::vector<std::uint8_t> png;
    ASSERT_TRUE(encoder.encode(patternImage(PixelFormat::kRgb8, 32, 32, 1), png));
    FrameFileReader reader;
    Image out;
    // Truncated PNG.
    {
        std::ofstream f(dir / "t.png", std::ios::binary);
        f.write(reinterpret_cast<const char*>(png.data()), static_cast<std::streamsize>(png.size() / 2));
    }
    auto r = reader.read(dir / "t.png", PixelFormat::kRgb8, 32, 32, out);
    ASSERT_FALSE(r);
    EXPECT_NE(r.error().message.find("t.png"), std::string::npos);
    // Garbage, right after a good frame: the decoder must not hand back the previous pixels.
    {
        std::ofstream f(dir / "good.png", std::ios::binary);
        f.write(reinterpret_cast<const char*>(png.data()), static_cast<std::streamsize>(png.size()));
    }
    ASSERT_TRUE(reader.read(dir / "good.png", PixelFormat::kRgb8, 32, 32, out));
    writeText(dir / "g.png", "this is not an image at all");
    EXPECT_FALSE(reader.read(dir / "g.png", PixelFormat::kRgb8, 32, 32, out));
    writeText(dir / "sig.png", "\x89PNG\r\n\x1a\n not a PNG body");
    EXPECT_FALSE(reader.read(dir / "sig.png", PixelFormat::kRgb8, 32, 32, out));
    // Missing.
    r = reader.read(dir / "missing.png", PixelFormat::kRgb8, 32, 32, out);
    ASSERT_FALSE(r);
    EXPECT_EQ(r.error().code, ErrorCode::kNotFound);
    // Wrong size for the sequence.
    {
        std::ofstream f(dir / "ok.png", std::ios::binary);
        f.write(reinterpret_cast<const char*>(png.data()), static_cast<std::streamsize>(png.size()));
    }
    EXPECT_TRUE(reader.read(dir / "ok.png", PixelFormat::kRgb8, 32, 32, out));
    r = reader.read(dir / "ok.png", PixelFormat::kRgb8, 64, 32, out);
    ASSERT_FALSE(r);
    EXPECT_NE(r.error().message.find("32x32 but the sequence is 64x32"), std::string::npos);
    // Truncated JPEG.
    writeText(dir / "j.jpg", std::string("\xFF\xD8\x01\x02\x03", 5));
    r = reader.read(dir / "j.jpg", PixelFormat::kMjpeg, 0, 0, out);
    ASSERT_FALSE(r);
    EXPECT_NE(r.error().message.find("truncated JPEG"), std::string::npos);
}

}  // namespace
}  // namespace commonlight

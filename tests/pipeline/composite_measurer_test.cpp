// CompositeMeasurer: the composites' error against ground truth, measured on the caller's thread
// or on its own, with the same figures either way, and bad truth files reported by name.
#include <gtest/gtest.h>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>

#include <unistd.h>

#include "pipeline/composite_measurer.h"

namespace commonlight::pipeline {
namespace {

namespace fs = std::filesystem;

constexpr int kWidth = 64, kHeight = 48;

// A pseudo-random RGB8 image (a fixed linear congruential sequence per seed).
Image noiseImage(std::uint32_t seed) {
    Image image(PixelFormat::kRgb8, kWidth, kHeight);
    std::uint32_t state = seed * 2654435761u + 1u;
    for (int y = 0; y < kHeight; ++y) {
        std::uint8_t* row = image.mutableView().row(y);
        for (int x = 0; x < 3 * kWidth; ++x) {
            state = state * 1664525u + 1013904223u;
            row[x] = static_cast<std::uint8_t>(state >> 24);
        }
    }
    return image;
}

// As OpenCV writes it (BGR).
cv::Mat asBgr(const Image& image) {
    const ImageView v = image.view();
    cv::Mat bgr;
    cv::cvtColor(cv::Mat(v.height, v.width, CV_8UC3, const_cast<std::uint8_t*>(v.data), v.stride), bgr, cv::COLOR_RGB2BGR);
    return bgr;
}

// A sequence folder with `frames` frames of ground truth (composite and changed mask) in a fresh
// temporary folder; the frames' own images are not needed by the measurer.
class MeasurerTest : public ::testing::Test {
protected:
    void SetUp() override {
        const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
        std::string name = "cl_measurer_";
        name += info->name();
        name += "_";
        name += std::to_string(::getpid());
        sequence_.root = fs::temp_directory_path() / name;
        fs::remove_all(sequence_.root);
        fs::create_directories(sequence_.root / "groundtruth/composite");
        fs::create_directories(sequence_.root / "groundtruth/masks/changed");
        sequence_.cam_dir = sequence_.root / "cam0";
        for (int i = 0; i < kFrames; ++i) {
            std::string stem = "f";  // (appended: GCC 12's -Wrestrict misfires on "f" + to_string)
            stem += std::to_string(i);
            sequence_.frames.push_back({timestamp(i), stem + ".png"});
            cv::Mat bgr = asBgr(noiseImage(100 + static_cast<std::uint32_t>(i)));
            ASSERT_TRUE(cv::imwrite((sequence_.root / "groundtruth/composite" / (stem + ".png")).string(), bgr));
            cv::Mat mask(kHeight, kWidth, CV_8UC1, cv::Scalar(0));
            mask(cv::Rect(8 + i, 4, 20, 16)).setTo(255);
            ASSERT_TRUE(cv::imwrite((sequence_.root / "groundtruth/masks/changed" / (stem + ".png")).string(), mask));
        }
    }
    void TearDown() override { fs::remove_all(sequence_.root); }

    static std::int64_t timestamp(int i) { return 1'000'000 + 33'333'333LL * i; }

    static constexpr int kFrames = 6;
    Sequence sequence_;
};

TEST_F(MeasurerTest, InTheBackgroundTheFiguresAreTheForegroundsExactly) {
    CompositeMeasurerOptions foreground_options;
    CompositeMeasurerOptions background_options;
    background_options.background = true;
    background_options.buffers = kFrames;  // room for every frame: none goes unmeasured
    CompositeMeasurer foreground(sequence_, ResponseCurve::srgb(), foreground_options);
    CompositeMeasurer background(sequence_, ResponseCurve::srgb(), background_options);
    for (int i = 0; i < kFrames; ++i) {
        const Image composite = noiseImage(7 + static_cast<std::uint32_t>(i));
        const double gain = 0.01 * (i + 1);
        ASSERT_TRUE(foreground.add(composite.view(), timestamp(i), gain));
        ASSERT_TRUE(background.add(composite.view(), timestamp(i), gain));
    }
    ASSERT_TRUE(foreground.finish());
    ASSERT_TRUE(background.finish());
    EXPECT_EQ(foreground.errors().frames(), static_cast<std::size_t>(kFrames));
    EXPECT_EQ(background.errors().frames(), static_cast<std::size_t>(kFrames));
    EXPECT_EQ(background.unmeasured(), 0u);
    EXPECT_GT(foreground.errors().json()["changed_pixels"].get<std::uint64_t>(), 0u);
    EXPECT_EQ(foreground.errors().json().dump(), background.errors().json().dump());
    // The composite equal to its truth: PSNR capped at 99 dB (the comparison is real).
    CompositeMeasurer same(sequence_, ResponseCurve::srgb(), foreground_options);
    ASSERT_TRUE(same.add(noiseImage(100).view(), timestamp(0), 1.0));
    EXPECT_DOUBLE_EQ(same.errors().psnrDb(), 99.0);
    EXPECT_LT(foreground.errors().psnrDb(), 20.0);
}

TEST_F(MeasurerTest, AFrameWithoutTruthIsNotCounted) {
    CompositeMeasurerOptions options;
    options.background = true;
    CompositeMeasurer measurer(sequence_, ResponseCurve::srgb(), options);
    ASSERT_TRUE(measurer.add(noiseImage(1).view(), timestamp(kFrames + 3), 1.0));  // no such frame
    fs::remove(sequence_.root / "groundtruth/composite/f2.png");
    ASSERT_TRUE(measurer.add(noiseImage(1).view(), timestamp(2), 1.0));  // a frame whose truth is absent
    ASSERT_TRUE(measurer.add(noiseImage(1).view(), timestamp(1), 1.0));
    ASSERT_TRUE(measurer.finish());
    EXPECT_EQ(measurer.errors().frames(), 1u);
}

TEST_F(MeasurerTest, AnUnreadableTruthIsAnErrorNamingItsFile) {
    const fs::path bad = sequence_.root / "groundtruth/composite/f3.png";
    std::ofstream(bad, std::ios::trunc) << "not a PNG";
    for (const bool background : {false, true}) {
        SCOPED_TRACE(background ? "background" : "foreground");
        CompositeMeasurerOptions options;
        options.background = background;
        CompositeMeasurer measurer(sequence_, ResponseCurve::srgb(), options);
        ASSERT_TRUE(measurer.add(noiseImage(1).view(), timestamp(2), 1.0));
        Result<void> added = measurer.add(noiseImage(1).view(), timestamp(3), 1.0);
        Result<void> finished = measurer.finish();
        // In the foreground add() fails; in the background finish() reports it, and so does the
        // next add().
        const Result<void>& failed = background ? finished : added;
        ASSERT_FALSE(failed);
        EXPECT_EQ(failed.error().code, ErrorCode::kBadInput);
        EXPECT_NE(failed.error().message.find(bad.string()), std::string::npos) << failed.error().message;
        if (background) {
            EXPECT_TRUE(added);
            Result<void> after = measurer.add(noiseImage(1).view(), timestamp(4), 1.0);
            ASSERT_FALSE(after);
            EXPECT_NE(after.error().message.find(bad.string()), std::string::npos);
        }
        EXPECT_EQ(measurer.errors().frames(), 1u);  // frame 2, measured before the bad one
    }
}

TEST_F(MeasurerTest, EveryFrameGivenIsMeasuredOrCountedUnmeasured) {
    CompositeMeasurerOptions options;
    options.background = true;
    options.buffers = 1;
    CompositeMeasurer measurer(sequence_, ResponseCurve::srgb(), options);
    constexpr int kRounds = 10;
    for (int r = 0; r < kRounds; ++r) {
        for (int i = 0; i < kFrames; ++i) ASSERT_TRUE(measurer.add(noiseImage(3).view(), timestamp(i), 1.0));
    }
    ASSERT_TRUE(measurer.finish());
    EXPECT_EQ(measurer.errors().frames() + measurer.unmeasured(), static_cast<std::size_t>(kRounds * kFrames));
    // A later add() starts the thread again.
    ASSERT_TRUE(measurer.add(noiseImage(3).view(), timestamp(0), 1.0));
    ASSERT_TRUE(measurer.finish());
    EXPECT_EQ(measurer.errors().frames() + measurer.unmeasured(), static_cast<std::size_t>(kRounds * kFrames + 1));
}

}  // namespace
}  // namespace commonlight::pipeline

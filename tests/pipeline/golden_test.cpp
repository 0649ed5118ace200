// Golden image of the whole pipeline (offscreen, EGL surfaceless): tracking, the lighting thread
// in sync mode and the compositor on the bundled sample, against its path-traced composite.
// Not labelled "threads": under TSan the lighting of 21 frames is minutes; frame_loop_gl covers
// the threads.
#include <gtest/gtest.h>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <cmath>
#include <cstdio>
#include <filesystem>

#include "tests/pipeline/sample_source.h"

namespace commonlight::pipeline {
namespace {

// Golden image: the sample's frame 20 composited with the lighting of frames 0-20 (--sync),
// against the path-traced composite in groundtruth/composite (rendered by mocks/sim, which shares
// no code with lighting/ or render/). Tolerance: PSNR at least 36 dB over the frame and at least
// 30 dB where the virtual objects change it (masks/changed); measured 40-41 dB and 35-36 dB. On
// failure the frame, the composite, the truth and their difference (x8) are written to
// golden-diff/ in the test's working folder (the build tree), and the test says where.
TEST(FrameRunnerRunGl, TheSampleCompositeMatchesThePathTracedGroundTruth) {
    skipWithoutGl();
    constexpr std::size_t kFrame = 20;
    ASSERT_GT(sample().frames.size(), kFrame);
    auto runner = makeRunner(/*sync=*/true, /*lighting=*/true, /*composite=*/true);
    ASSERT_TRUE(runner);
    SampleSource source(kFrame + 1);
    Image frame_rgb;
    LoopCallbacks callbacks;
    callbacks.on_frame = [&](const TrackedFrame& f) {
        if (f.index == kFrame) frame_rgb = f.rgb.clone();
        return true;
    };
    const LoopStats stats = runner->run(source, callbacks, std::stop_token());
    runner->stop();
    ASSERT_FALSE(stats.failure) << stats.failure->message;
    ASSERT_EQ(stats.composited, kFrame + 1);
    const Image& composite = runner->compositeImage();

    const std::string stem = std::filesystem::path(sample().sequence.frames[kFrame].filename).stem().string();
    const auto truth_dir = sample().sequence.root / "groundtruth";
    cv::Mat truth_bgr;
    for (const char* ext : {".png", ".jpg"}) {
        if (truth_bgr.empty() && std::filesystem::exists(truth_dir / "composite" / (stem + ext))) {
            truth_bgr = cv::imread((truth_dir / "composite" / (stem + ext)).string());
        }
    }
    const cv::Mat changed = cv::imread((truth_dir / "masks/changed" / (stem + ".png")).string(), cv::IMREAD_GRAYSCALE);
    ASSERT_FALSE(truth_bgr.empty()) << "no ground-truth composite for " << stem;
    ASSERT_FALSE(changed.empty()) << "no masks/changed for " << stem;
    ASSERT_EQ(truth_bgr.cols, composite.width());
    ASSERT_EQ(truth_bgr.rows, composite.height());
    cv::Mat truth;
    cv::cvtColor(truth_bgr, truth, cv::COLOR_BGR2RGB);
    const cv::Mat ours(composite.height(), composite.width(), CV_8UC3, const_cast<std::uint8_t*>(composite.view().data),
                       composite.view().stride);
    cv::Mat diff;
    cv::absdiff(ours, truth, diff);
    double sum = 0.0, sum_changed = 0.0;
    std::size_t n_changed = 0;
    for (int y = 0; y < diff.rows; ++y) {
        for (int x = 0; x < diff.cols; ++x) {
            const cv::Vec3b d = diff.at<cv::Vec3b>(y, x);
            const double e = double(d[0]) * d[0] + double(d[1]) * d[1] + double(d[2]) * d[2];
            sum += e;
            if (changed.at<std::uint8_t>(y, x) > 127) {
                sum_changed += e;
                ++n_changed;
            }
        }
    }
    const auto psnr = [](double sse, double samples) { return 10.0 * std::log10(255.0 * 255.0 / std::max(sse / samples, 1e-12)); };
    const double psnr_frame = psnr(sum, 3.0 * diff.rows * diff.cols);
    ASSERT_GT(n_changed, 1000u);
    const double psnr_changed = psnr(sum_changed, 3.0 * static_cast<double>(n_changed));
    RecordProperty("psnr_db", std::to_string(psnr_frame));
    RecordProperty("psnr_changed_db", std::to_string(psnr_changed));
    std::printf("frame %zu against the path-traced composite: PSNR %.2f dB, %.2f dB where the virtual objects change it\n", kFrame,
                psnr_frame, psnr_changed);
    const bool ok = psnr_frame >= 36.0 && psnr_changed >= 30.0;
    if (!ok) {
        const std::filesystem::path out = std::filesystem::absolute("golden-diff");
        std::filesystem::create_directories(out);
        cv::Mat bgr;
        cv::cvtColor(ours, bgr, cv::COLOR_RGB2BGR);
        cv::imwrite((out / "composite.png").string(), bgr);
        cv::imwrite((out / "truth.png").string(), truth_bgr);
        if (!frame_rgb.view().empty()) {
            const cv::Mat f(frame_rgb.height(), frame_rgb.width(), CV_8UC3, frame_rgb.data(), frame_rgb.stride());
            cv::cvtColor(f, bgr, cv::COLOR_RGB2BGR);
            cv::imwrite((out / "frame.png").string(), bgr);
        }
        cv::Mat scaled;
        diff.convertTo(scaled, CV_8UC3, 8.0);
        cv::cvtColor(scaled, bgr, cv::COLOR_RGB2BGR);
        cv::imwrite((out / "diff_x8.png").string(), bgr);
        ADD_FAILURE() << "the composite of frame " << kFrame << " is off the ground truth (PSNR " << psnr_frame << " dB, "
                      << psnr_changed << " dB where changed); images in " << out.string();
    }
}

}  // namespace
}  // namespace commonlight::pipeline

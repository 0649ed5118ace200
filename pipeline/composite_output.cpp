#include "pipeline/composite_output.h"

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include <unistd.h>

#include <algorithm>
#include <cmath>

namespace commonlight::pipeline {

namespace fs = std::filesystem;

namespace {

cv::Mat asMat(const ImageView& view) {
    // OpenCV wants a non-const pointer; the Mat is only read.
    return cv::Mat(view.height, view.width, view.format == PixelFormat::kGray8 ? CV_8UC1 : CV_8UC3,
                   const_cast<std::uint8_t*>(view.data), view.stride);
}

Image fromMat(const cv::Mat& m, PixelFormat format) {
    Image image(format, m.cols, m.rows);
    for (int y = 0; y < m.rows; ++y) {
        std::copy_n(m.ptr<std::uint8_t>(y), static_cast<std::size_t>(m.cols) * m.elemSize(), image.mutableView().row(y));
    }
    return image;
}

}  // namespace

void CompositeErrors::add(const ImageView& composite, const ImageView& truth, const ImageView& changed,
                          const ResponseCurve& response, double exposure_gain) {
    if (composite.width != truth.width || composite.height != truth.height) return;
    const double scale = exposure_gain > 0.0 && std::isfinite(exposure_gain) ? 1.0 / exposure_gain : 1.0;
    const bool have_mask = !changed.empty() && changed.width == composite.width && changed.height == composite.height;
    ++frames_;
    for (int y = 0; y < composite.height; ++y) {
        const std::uint8_t* a = composite.row(y);
        const std::uint8_t* b = truth.row(y);
        const std::uint8_t* m = have_mask ? changed.row(y) : nullptr;
        for (int x = 0; x < composite.width; ++x) {
            double pixel_se = 0.0;
            for (int c = 0; c < 3; ++c) {
                const double d8 = static_cast<double>(a[3 * x + c]) - static_cast<double>(b[3 * x + c]);
                se8_ += d8 * d8;
                const double d = (static_cast<double>(response.toLinear(c, a[3 * x + c])) -
                                  static_cast<double>(response.toLinear(c, b[3 * x + c]))) * scale;
                pixel_se += d * d;
            }
            n8_ += 3;
            se_lin_ += pixel_se;
            n_lin_ += 3;
            if (m && m[x] >= 128) {
                se_lin_changed_ += pixel_se;
                n_lin_changed_ += 3;
            }
        }
    }
}

double CompositeErrors::psnrDb() const {
    if (n8_ == 0) return 0.0;
    const double mse = se8_ / static_cast<double>(n8_);
    return mse > 0.0 ? std::min(99.0, 10.0 * std::log10(255.0 * 255.0 / mse)) : 99.0;
}

nlohmann::json CompositeErrors::json() const {
    return {{"psnr_db", psnrDb()},
            {"rmse_linear", n_lin_ > 0 ? std::sqrt(se_lin_ / static_cast<double>(n_lin_)) : 0.0},
            {"rmse_linear_changed", n_lin_changed_ > 0 ? std::sqrt(se_lin_changed_ / static_cast<double>(n_lin_changed_)) : 0.0},
            {"changed_pixels", n_lin_changed_ / 3},
            {"frames", frames_}};
}

Result<std::optional<FrameTruth>> readFrameTruth(const Sequence& sequence, std::int64_t timestamp_ns) {
    std::string stem;
    for (const SequenceFrame& f : sequence.frames) {
        if (f.timestamp_ns == timestamp_ns) stem = fs::path(f.filename).stem().string();
    }
    if (stem.empty()) return std::optional<FrameTruth>();
    const fs::path gt = sequence.root / "groundtruth";
    fs::path composite_file;
    std::error_code ec;
    for (const char* ext : {".png", ".jpg"}) {
        if (fs::exists(gt / "composite" / (stem + ext), ec)) composite_file = gt / "composite" / (stem + ext);
    }
    if (composite_file.empty()) return std::optional<FrameTruth>();
    const cv::Mat bgr = cv::imread(composite_file.string(), cv::IMREAD_COLOR);
    if (bgr.empty()) return fail(ErrorCode::kBadInput, composite_file.string() + ": unreadable image (ground truth)");
    cv::Mat rgb;
    cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
    FrameTruth truth;
    truth.composite = fromMat(rgb, PixelFormat::kRgb8);
    const fs::path changed_file = gt / "masks/changed" / (stem + ".png");
    if (fs::exists(changed_file, ec)) {
        const cv::Mat changed = cv::imread(changed_file.string(), cv::IMREAD_GRAYSCALE);
        if (changed.empty() || changed.cols != rgb.cols || changed.rows != rgb.rows) {
            return fail(ErrorCode::kBadInput, changed_file.string() + ": unreadable or not the composite's size (ground truth)");
        }
        truth.changed = fromMat(changed, PixelFormat::kGray8);
    }
    return std::optional<FrameTruth>(std::move(truth));
}

struct CompositeWriter::Video {
    cv::VideoWriter writer;
    fs::path path;
    cv::Mat bgr;
};

CompositeWriter::~CompositeWriter() { finish(); }

Result<std::unique_ptr<CompositeWriter>> CompositeWriter::open(const fs::path& frames_dir, const fs::path& video, int width,
                                                               int height, double fps) {
    auto writer = std::unique_ptr<CompositeWriter>(new CompositeWriter());
    if (!frames_dir.empty()) {
        std::error_code ec;
        fs::create_directories(frames_dir, ec);
        if (ec || !fs::is_directory(frames_dir, ec)) {
            return fail(ErrorCode::kIo, frames_dir.string() + ": cannot create the output folder" + (ec ? ": " + ec.message() : ""));
        }
        writer->frames_dir_ = frames_dir;
    }
    if (!video.empty()) {
        auto v = std::make_unique<Video>();
        v->path = video;
        const double rate = fps > 0.0 && std::isfinite(fps) ? fps : 30.0;
        try {
            v->writer.open(video.string(), cv::VideoWriter::fourcc('m', 'p', '4', 'v'), rate, cv::Size(width, height), true);
        } catch (const cv::Exception& e) {
            return fail(ErrorCode::kIo, video.string() + ": cannot write the video: " + e.what());
        }
        if (!v->writer.isOpened()) {
            return fail(ErrorCode::kIo, video.string() + ": cannot write the video (folder missing or not writable, or no MP4 encoder)");
        }
        writer->video_ = std::move(v);
    }
    return writer;
}

Result<void> CompositeWriter::write(const ImageView& composite, const std::string& stem) {
    cv::Mat bgr;
    cv::cvtColor(asMat(composite), bgr, cv::COLOR_RGB2BGR);
    if (!frames_dir_.empty()) {
        const fs::path file = frames_dir_ / (stem + ".png");
        bool ok = false;
        try {
            ok = cv::imwrite(file.string(), bgr);
        } catch (const cv::Exception&) {
            ok = false;
        }
        if (!ok) return fail(ErrorCode::kIo, file.string() + ": cannot write the composited frame");
    }
    if (video_) video_->writer.write(bgr);
    ++written_;
    return {};
}

void CompositeWriter::finish() {
    if (video_) video_->writer.release();
}

Result<void> writePng(const fs::path& file, const ImageView& rgb8) {
    cv::Mat bgr;
    cv::cvtColor(asMat(rgb8), bgr, cv::COLOR_RGB2BGR);
    bool ok = false;
    try {
        ok = cv::imwrite(file.string(), bgr);
    } catch (const cv::Exception&) {
        ok = false;
    }
    if (!ok) return fail(ErrorCode::kIo, file.string() + ": cannot write the image");
    return {};
}

Result<void> writeSideBySide(const fs::path& file, const ImageView& frame, const ImageView& composite, const ImageView* truth) {
    std::vector<std::pair<cv::Mat, std::string>> panels{{asMat(frame), "camera frame"}, {asMat(composite), "composite"}};
    if (truth) panels.emplace_back(asMat(*truth), "ground truth");
    const int caption = 28;
    cv::Mat out(frame.height + caption, frame.width * static_cast<int>(panels.size()), CV_8UC3, cv::Scalar(24, 24, 24));
    for (std::size_t i = 0; i < panels.size(); ++i) {
        cv::Mat bgr;
        cv::cvtColor(panels[i].first, bgr, cv::COLOR_RGB2BGR);
        const int x0 = static_cast<int>(i) * frame.width;
        bgr.copyTo(out(cv::Rect(x0, caption, frame.width, frame.height)));
        cv::putText(out, panels[i].second, cv::Point(x0 + 8, 20), cv::FONT_HERSHEY_SIMPLEX, 0.6, cv::Scalar(235, 235, 235), 1,
                    cv::LINE_AA);
    }
    bool ok = false;
    try {
        ok = cv::imwrite(file.string(), out);
    } catch (const cv::Exception&) {
        ok = false;
    }
    if (!ok) return fail(ErrorCode::kIo, file.string() + ": cannot write the side-by-side picture");
    return {};
}

Result<void> checkImagePath(const std::filesystem::path& file, const std::string& what) {
    const std::filesystem::path folder = file.has_parent_path() ? file.parent_path() : std::filesystem::path(".");
    std::error_code ec;
    if (!std::filesystem::is_directory(folder, ec)) {
        return fail(ErrorCode::kIo, file.string() + ": cannot write the " + what + ": the folder " + folder.string() + " does not exist");
    }
    if (::access(folder.c_str(), W_OK) != 0) {
        return fail(ErrorCode::kIo, file.string() + ": cannot write the " + what + ": the folder " + folder.string() + " is not writable");
    }
    bool writer = false;
    try {
        writer = cv::haveImageWriter(file.string());
    } catch (const cv::Exception&) {
        writer = false;
    }
    if (!writer) return fail(ErrorCode::kIo, file.string() + ": cannot write the " + what + ": no image writer for that extension (use .png or .jpg)");
    return {};
}

}  // namespace commonlight::pipeline

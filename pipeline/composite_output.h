// What the compositor's frames become: the error against the recording's ground truth
// (groundtruth/composite/, groundtruth/masks/changed/), composited frames as PNG files, an MP4,
// and the side-by-side picture of one frame (frame | composite | ground truth).
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/image.h"
#include "core/response.h"
#include "core/result.h"
#include "core/sequence_io.h"

namespace commonlight::pipeline {

// Composite error against ground truth, accumulated over frames: PSNR on the encoded 8-bit frames
// (from the mean squared error over every pixel and channel of every frame), and RMSE of relative
// radiance (both images linearised with the camera's response, divided by exposure x gain) over
// the whole frame and over the pixels the virtual objects change (masks/changed).
class CompositeErrors {
public:
    // RGB8 images of the same size; `changed` GRAY8 (>= 128: changed) or empty.
    void add(const ImageView& composite, const ImageView& truth, const ImageView& changed, const ResponseCurve& response,
             double exposure_gain);
    std::size_t frames() const noexcept { return frames_; }
    // {"psnr_db", "rmse_linear", "rmse_linear_changed", "changed_pixels", "frames"}; PSNR is
    // capped at 99 dB when the images are equal.
    nlohmann::json json() const;
    double psnrDb() const;

private:
    double se8_ = 0.0;           // squared 8-bit code errors
    std::uint64_t n8_ = 0;       // channel samples
    double se_lin_ = 0.0, se_lin_changed_ = 0.0;
    std::uint64_t n_lin_ = 0, n_lin_changed_ = 0;
    std::size_t frames_ = 0;
};

// The ground truth of one frame of a sequence, found by its timestamp: the composite (RGB8) and
// the changed mask (GRAY8, possibly empty). nullopt when the sequence has none for that frame.
struct FrameTruth {
    Image composite;
    Image changed;
};
Result<std::optional<FrameTruth>> readFrameTruth(const Sequence& sequence, std::int64_t timestamp_ns);

// Writes composited frames: PNG files into a folder (named like the recording's frames, or by
// timestamp), an MP4 (OpenCV videoio, 'mp4v'), both optional. open() checks that every path can
// be written before any work (errors kIo naming the path).
class CompositeWriter {
public:
    static Result<std::unique_ptr<CompositeWriter>> open(const std::filesystem::path& frames_dir,
                                                         const std::filesystem::path& video, int width, int height,
                                                         double fps);
    ~CompositeWriter();
    Result<void> write(const ImageView& composite_rgb8, const std::string& stem);
    // Closes the video (its index is written on close).
    void finish();
    std::uint64_t written() const noexcept { return written_; }

private:
    CompositeWriter() = default;
    struct Video;
    std::filesystem::path frames_dir_;
    std::unique_ptr<Video> video_;
    std::uint64_t written_ = 0;
};

// An RGB8 image as a PNG; errors (kIo) name the file.
Result<void> writePng(const std::filesystem::path& file, const ImageView& rgb8);

// Frame | composite | ground truth (when given) side by side with a caption strip, as one PNG.
// Whether an image can be written at `file` (checked before any work): its folder exists and is
// writable and OpenCV has a writer for its extension. kIo naming the file and what is wrong.
Result<void> checkImagePath(const std::filesystem::path& file, const std::string& what);

Result<void> writeSideBySide(const std::filesystem::path& file, const ImageView& frame_rgb8, const ImageView& composite_rgb8,
                             const ImageView* truth_rgb8);

}  // namespace commonlight::pipeline

// Reading and writing single frame files of a sequence (docs/formats-sequence.md):
//   rgb8/bgr8/rgba8/gray8/gray16 -> PNG of that layout (lossless)
//   yuyv -> GRAY8 PNG of 2*width x height holding the raw bytes
//   nv12 -> GRAY8 PNG of width x (height * 3 / 2) holding the raw planes
//   mjpeg -> the JPEG bytes as the camera sent them (.jpg)
// Both classes keep their scratch buffers between frames: after the first frame of a stream
// they do not grow them again.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

#include "core/image.h"
#include "core/result.h"

namespace commonlight {

class FrameFileReader {
public:
    // Reads `file` into `out`. `stored` is the sequence's pixel_format (kInvalid: decide by the
    // file's contents); width/height are the sequence's resolution (0: accept any). A file that
    // is missing, truncated or not decodable, or whose size or layout does not match, is an
    // error naming the file (the caller marks the frame Corrupt).
    Result<void> read(const std::filesystem::path& file, PixelFormat stored, int width, int height, Image& out);

private:
    std::vector<std::uint8_t> bytes_;
    cv::Mat decoded_;
};

class FrameFileWriter {
public:
    // The pixel_format to record in sensor.yaml for frames of this format.
    static PixelFormat storedFormat(PixelFormat format) noexcept { return format; }
    // File extension (with dot) for frames of this format.
    static const char* extension(PixelFormat format) noexcept;
    // Encodes a frame into `out`. RGBF32 is not storable in a sequence (kUnsupported).
    Result<void> encode(const ImageView& image, std::vector<std::uint8_t>& out);

private:
    cv::Mat scratch_;
};

}  // namespace commonlight

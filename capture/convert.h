// Pixel-format conversion of camera frames to RGB8 or GRAY8, for the pipeline's algorithms.
//
//   source   -> RGB8                               -> GRAY8
//   GRAY8       replicated                            copy
//   GRAY16      high byte (>> 8), replicated          high byte (>> 8)
//   RGB8        copy                                  0.299 R + 0.587 G + 0.114 B (OpenCV)
//   BGR8        channels swapped                      as RGB8
//   RGBA8       alpha dropped                         as RGB8
//   YUYV        BT.601 limited range (OpenCV)          the Y samples
//   NV12        BT.601 limited range (OpenCV)          the Y plane
//   MJPEG       libjpeg-turbo decode                  libjpeg-turbo decode (luma)
//   BAYER_*8    OpenCV bilinear demosaic              OpenCV demosaic to gray
//
// OpenCV works on Mat headers over the caller's buffers: no pixel is copied on the way in and
// the result is written straight into `dst`. `dst` is reshaped within its capacity, so after the
// first frame of a stream nothing is allocated. A corrupt or truncated JPEG, or a view whose
// size does not match its format, is an error (kBadInput), never a crash; the caller then marks
// the frame kCorrupt.
#pragma once

#include "core/image.h"
#include "core/result.h"

namespace commonlight::capture {

class PixelConverter {
public:
    PixelConverter() noexcept = default;
    ~PixelConverter();
    PixelConverter(PixelConverter&& other) noexcept;
    PixelConverter& operator=(PixelConverter&& other) noexcept;
    PixelConverter(const PixelConverter&) = delete;
    PixelConverter& operator=(const PixelConverter&) = delete;

    // True for the pairs in the table above (dst is kRgb8 or kGray8).
    static bool canConvert(PixelFormat src, PixelFormat dst) noexcept;

    // Converts `src` into `dst` as `dst_format` (kRgb8 or kGray8), with src's size (for MJPEG:
    // the size in the JPEG header, which must match src.width x src.height when those are set).
    // `dst` must not share memory with `src`. On error the contents of `dst` are unspecified.
    // One thread at a time per converter.
    Result<void> convert(const ImageView& src, PixelFormat dst_format, Image& dst);

private:
    Result<void> decodeJpeg(const ImageView& src, PixelFormat dst_format, Image& dst);

    void* jpeg_ = nullptr;  // tjhandle, owned: made at the first MJPEG frame, tjDestroy()ed by ~PixelConverter
};

}  // namespace commonlight::capture

#include "capture/convert.h"

#include <cassert>
#include <cstring>
#include <string>
#include <utility>

#include <turbojpeg.h>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

namespace commonlight::capture {

namespace {

std::string describe(const ImageView& view) {
    return std::string(pixelFormatName(view.format)) + " " + std::to_string(view.width) + "x" +
           std::to_string(view.height);
}

// A view must hold every byte its format, size and stride call for.
Result<void> checkSource(const ImageView& src) {
    if (src.empty()) return fail(ErrorCode::kBadInput, describe(src) + " frame has no pixels");
    if (isCompressed(src.format)) return {};
    if (src.width <= 0 || src.height <= 0) return fail(ErrorCode::kBadInput, describe(src) + " frame has no size");
    if ((src.format == PixelFormat::kYuyv || src.format == PixelFormat::kNv12) && src.width % 2 != 0) {
        return fail(ErrorCode::kBadInput, describe(src) + " frame: the width must be even");
    }
    if (isBayer(src.format) && (src.width < 2 || src.height < 2)) {
        return fail(ErrorCode::kBadInput, describe(src) + " frame: a Bayer mosaic needs at least 2x2 pixels");
    }
    if (src.format == PixelFormat::kNv12 && src.height % 2 != 0) {
        return fail(ErrorCode::kBadInput, describe(src) + " frame: the height must be even");
    }
    if (src.stride < minStride(src.format, src.width)) {
        return fail(ErrorCode::kBadInput, describe(src) + " frame: stride " + std::to_string(src.stride) +
                                              " is shorter than a row");
    }
    const std::size_t needed = imageBytes(src.format, src.width, src.height, src.stride);
    if (src.size_bytes < needed) {
        return fail(ErrorCode::kBadInput, describe(src) + " frame holds " + std::to_string(src.size_bytes) +
                                              " bytes, its format needs " + std::to_string(needed));
    }
    return {};
}

// GRAY16 keeps the sensor's value in its high bits: the high byte is the 8-bit value.
void gray16HighByte(const ImageView& src, Image& dst, int channels) {
    for (int y = 0; y < src.height; ++y) {
        const std::uint8_t* in = src.row(y);
        std::uint8_t* out = dst.data() + static_cast<std::size_t>(y) * dst.stride();
        for (int x = 0; x < src.width; ++x) {
            std::uint16_t v = 0;
            std::memcpy(&v, in + 2 * static_cast<std::size_t>(x), sizeof v);  // rows need not be aligned
            const auto high = static_cast<std::uint8_t>(v >> 8);
            for (int c = 0; c < channels; ++c) *out++ = high;
        }
    }
}

// The OpenCV conversion code for a source format, or -1 for a plain copy.
int cvtCode(PixelFormat src, PixelFormat dst) noexcept {
    const bool rgb = dst == PixelFormat::kRgb8;
    switch (src) {
        case PixelFormat::kGray8: return rgb ? cv::COLOR_GRAY2RGB : -1;
        case PixelFormat::kRgb8: return rgb ? -1 : cv::COLOR_RGB2GRAY;
        case PixelFormat::kBgr8: return rgb ? cv::COLOR_BGR2RGB : cv::COLOR_BGR2GRAY;
        case PixelFormat::kRgba8: return rgb ? cv::COLOR_RGBA2RGB : cv::COLOR_RGBA2GRAY;
        case PixelFormat::kYuyv: return rgb ? cv::COLOR_YUV2RGB_YUYV : cv::COLOR_YUV2GRAY_YUYV;
        case PixelFormat::kNv12: return rgb ? cv::COLOR_YUV2RGB_NV12 : cv::COLOR_YUV2GRAY_NV12;
        // OpenCV names a mosaic by the 2x2 block starting at its second row and column, so a
        // sensor whose top-left block is R G / G B is OpenCV's "BayerBG" (checked by a test on a
        // mosaic of known colours).
        case PixelFormat::kBayerRggb8: return rgb ? cv::COLOR_BayerBG2RGB : cv::COLOR_BayerBG2GRAY;
        case PixelFormat::kBayerGrbg8: return rgb ? cv::COLOR_BayerGB2RGB : cv::COLOR_BayerGB2GRAY;
        case PixelFormat::kBayerGbrg8: return rgb ? cv::COLOR_BayerGR2RGB : cv::COLOR_BayerGR2GRAY;
        case PixelFormat::kBayerBggr8: return rgb ? cv::COLOR_BayerRG2RGB : cv::COLOR_BayerRG2GRAY;
        default: return -1;
    }
}

// A Mat header over a view's bytes (NV12: both planes, as one (height * 3/2) x width matrix).
cv::Mat matOf(const ImageView& src) {
    auto* data = const_cast<std::uint8_t*>(src.data);  // cv::Mat has no const header; we only read
    switch (src.format) {
        case PixelFormat::kGray8:
        case PixelFormat::kBayerRggb8:
        case PixelFormat::kBayerGrbg8:
        case PixelFormat::kBayerGbrg8:
        case PixelFormat::kBayerBggr8: return cv::Mat(src.height, src.width, CV_8UC1, data, src.stride);
        case PixelFormat::kRgb8:
        case PixelFormat::kBgr8: return cv::Mat(src.height, src.width, CV_8UC3, data, src.stride);
        case PixelFormat::kRgba8: return cv::Mat(src.height, src.width, CV_8UC4, data, src.stride);
        case PixelFormat::kYuyv: return cv::Mat(src.height, src.width, CV_8UC2, data, src.stride);
        case PixelFormat::kNv12: return cv::Mat(src.height * 3 / 2, src.width, CV_8UC1, data, src.stride);
        default: return {};
    }
}

}  // namespace

PixelConverter::~PixelConverter() {
    if (jpeg_ != nullptr) tjDestroy(jpeg_);
}

PixelConverter::PixelConverter(PixelConverter&& other) noexcept : jpeg_(std::exchange(other.jpeg_, nullptr)) {}

PixelConverter& PixelConverter::operator=(PixelConverter&& other) noexcept {
    if (this != &other) {
        if (jpeg_ != nullptr) tjDestroy(jpeg_);
        jpeg_ = std::exchange(other.jpeg_, nullptr);
    }
    return *this;
}

bool PixelConverter::canConvert(PixelFormat src, PixelFormat dst) noexcept {
    if (dst != PixelFormat::kRgb8 && dst != PixelFormat::kGray8) return false;
    switch (src) {
        case PixelFormat::kGray8:
        case PixelFormat::kGray16:
        case PixelFormat::kRgb8:
        case PixelFormat::kBgr8:
        case PixelFormat::kRgba8:
        case PixelFormat::kYuyv:
        case PixelFormat::kNv12:
        case PixelFormat::kMjpeg:
        case PixelFormat::kBayerRggb8:
        case PixelFormat::kBayerGrbg8:
        case PixelFormat::kBayerGbrg8:
        case PixelFormat::kBayerBggr8: return true;
        default: return false;
    }
}

Result<void> PixelConverter::convert(const ImageView& src, PixelFormat dst_format, Image& dst) {
    if (!canConvert(src.format, dst_format)) {
        return fail(ErrorCode::kUnsupported, "cannot convert " + std::string(pixelFormatName(src.format)) + " to " +
                                                 std::string(pixelFormatName(dst_format)));
    }
    CL_TRY_VOID(checkSource(src));
    assert((dst.data() == nullptr || dst.data() + dst.capacity() <= src.data ||
            src.data + src.size_bytes <= dst.data()) &&
           "dst must not overlap src");
    if (src.format == PixelFormat::kMjpeg) return decodeJpeg(src, dst_format, dst);

    dst.reshape(dst_format, src.width, src.height);  // within capacity: no allocation
    const int channels = dst_format == PixelFormat::kRgb8 ? 3 : 1;
    if (src.format == PixelFormat::kGray16) {
        gray16HighByte(src, dst, channels);
        return {};
    }
    cv::Mat out(dst.height(), dst.width(), CV_8UC(channels), dst.data(), dst.stride());
    const std::uint8_t* out_data = out.data;
    try {
        const cv::Mat in = matOf(src);
        const int code = cvtCode(src.format, dst_format);
        if (code < 0) {
            in.copyTo(out);
        } else {
            cv::cvtColor(in, out, code);
        }
    } catch (const cv::Exception& e) {
        return fail(ErrorCode::kInternal, "converting a " + describe(src) + " frame: " + e.what());
    }
    // Same size and type: OpenCV wrote into our buffer rather than allocating its own.
    assert(out.data == out_data && "cv::cvtColor reallocated the destination");
    (void)out_data;
    return {};
}

Result<void> PixelConverter::decodeJpeg(const ImageView& src, PixelFormat dst_format, Image& dst) {
    if (jpeg_ == nullptr) {
        jpeg_ = tjInitDecompress();
        if (jpeg_ == nullptr) {
            return fail(ErrorCode::kInternal,
                        std::string("cannot create a libjpeg-turbo decompressor: ") + tjGetErrorStr2(nullptr));
        }
    }
    const auto size = static_cast<unsigned long>(src.size_bytes);
    int width = 0;
    int height = 0;
    int subsampling = 0;
    int colorspace = 0;
    if (tjDecompressHeader3(jpeg_, src.data, size, &width, &height, &subsampling, &colorspace) != 0) {
        return fail(ErrorCode::kBadInput, "corrupt MJPEG frame (" + std::to_string(src.size_bytes) +
                                              " bytes): " + tjGetErrorStr2(jpeg_));
    }
    const bool size_differs = (src.width > 0 && width != src.width) || (src.height > 0 && height != src.height);
    if (width <= 0 || height <= 0 || size_differs) {
        return fail(ErrorCode::kBadInput, "MJPEG frame is " + std::to_string(width) + "x" + std::to_string(height) +
                                              " but the stream is " + std::to_string(src.width) + "x" +
                                              std::to_string(src.height));
    }
    dst.reshape(dst_format, width, height);  // within capacity: no allocation
    const int pixel_format = dst_format == PixelFormat::kRgb8 ? TJPF_RGB : TJPF_GRAY;
    // Hard case: a truncated JPEG only raises a libjpeg warning (the rest would decode grey);
    // TJFLAG_STOPONWARNING makes it a failure, as it should be for a frame cut short.
    if (tjDecompress2(jpeg_, src.data, size, dst.data(), width, static_cast<int>(dst.stride()), height, pixel_format,
                      TJFLAG_STOPONWARNING) != 0) {
        return fail(ErrorCode::kBadInput, "corrupt or truncated MJPEG frame (" + std::to_string(src.size_bytes) +
                                              " bytes, " + std::to_string(width) + "x" + std::to_string(height) +
                                              "): " + tjGetErrorStr2(jpeg_));
    }
    return {};
}

}  // namespace commonlight::capture

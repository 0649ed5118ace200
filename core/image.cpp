#include "core/image.h"

#include <algorithm>
#include <cassert>
#include <cstring>

namespace commonlight {

std::string_view pixelFormatName(PixelFormat format) noexcept {
    switch (format) {
        case PixelFormat::kInvalid: return "invalid";
        case PixelFormat::kGray8: return "gray8";
        case PixelFormat::kGray16: return "gray16";
        case PixelFormat::kRgb8: return "rgb8";
        case PixelFormat::kBgr8: return "bgr8";
        case PixelFormat::kRgba8: return "rgba8";
        case PixelFormat::kYuyv: return "yuyv";
        case PixelFormat::kNv12: return "nv12";
        case PixelFormat::kMjpeg: return "mjpeg";
        case PixelFormat::kRgbF32: return "rgbf32";
        case PixelFormat::kBayerRggb8: return "bayer_rggb8";
        case PixelFormat::kBayerGrbg8: return "bayer_grbg8";
        case PixelFormat::kBayerGbrg8: return "bayer_gbrg8";
        case PixelFormat::kBayerBggr8: return "bayer_bggr8";
    }
    return "invalid";
}

std::optional<PixelFormat> parsePixelFormat(std::string_view name) noexcept {
    static constexpr PixelFormat kAll[] = {PixelFormat::kGray8, PixelFormat::kGray16, PixelFormat::kRgb8,
                                           PixelFormat::kBgr8,  PixelFormat::kRgba8,  PixelFormat::kYuyv,
                                           PixelFormat::kNv12,  PixelFormat::kMjpeg,  PixelFormat::kRgbF32,
                                           PixelFormat::kBayerRggb8, PixelFormat::kBayerGrbg8, PixelFormat::kBayerGbrg8,
                                           PixelFormat::kBayerBggr8};
    for (PixelFormat f : kAll) {
        if (pixelFormatName(f) == name) return f;
    }
    // Common aliases (V4L2 fourcc names, ROS encodings).
    if (name == "mono8" || name == "grey") return PixelFormat::kGray8;
    if (name == "mono16") return PixelFormat::kGray16;
    if (name == "yuy2" || name == "yuv422") return PixelFormat::kYuyv;
    if (name == "jpeg" || name == "mjpg") return PixelFormat::kMjpeg;
    // GenICam / ROS names of the Bayer mosaics.
    if (name == "bayerrg8" || name == "bayer_rggb") return PixelFormat::kBayerRggb8;
    if (name == "bayergr8" || name == "bayer_grbg") return PixelFormat::kBayerGrbg8;
    if (name == "bayergb8" || name == "bayer_gbrg") return PixelFormat::kBayerGbrg8;
    if (name == "bayerbg8" || name == "bayer_bggr") return PixelFormat::kBayerBggr8;
    return std::nullopt;
}

std::size_t bytesPerPixel(PixelFormat format) noexcept {
    switch (format) {
        case PixelFormat::kGray8:
        case PixelFormat::kBayerRggb8:
        case PixelFormat::kBayerGrbg8:
        case PixelFormat::kBayerGbrg8:
        case PixelFormat::kBayerBggr8: return 1;
        case PixelFormat::kGray16: return 2;
        case PixelFormat::kRgb8:
        case PixelFormat::kBgr8: return 3;
        case PixelFormat::kRgba8: return 4;
        case PixelFormat::kYuyv: return 2;
        case PixelFormat::kRgbF32: return 12;
        case PixelFormat::kNv12:
        case PixelFormat::kMjpeg:
        case PixelFormat::kInvalid: return 0;
    }
    return 0;
}

bool isBayer(PixelFormat format) noexcept {
    return format == PixelFormat::kBayerRggb8 || format == PixelFormat::kBayerGrbg8 ||
           format == PixelFormat::kBayerGbrg8 || format == PixelFormat::kBayerBggr8;
}

bool isCompressed(PixelFormat format) noexcept { return format == PixelFormat::kMjpeg; }

std::size_t minStride(PixelFormat format, int width) noexcept {
    if (width <= 0) return 0;
    if (format == PixelFormat::kNv12) return static_cast<std::size_t>(width);
    return bytesPerPixel(format) * static_cast<std::size_t>(width);
}

std::size_t imageBytes(PixelFormat format, int width, int height, std::size_t stride) noexcept {
    if (width <= 0 || height <= 0) return 0;
    const auto h = static_cast<std::size_t>(height);
    if (format == PixelFormat::kNv12) return stride * (h + (h + 1) / 2);
    return stride * h;
}

Image::Image(PixelFormat format, int width, int height) { reshape(format, width, height); }

Image Image::clone() const {
    Image copy;
    copy.assign(view());
    return copy;
}

Image Image::copyOf(const ImageView& view) {
    Image copy;
    copy.assign(view);
    return copy;
}

void Image::reserve(std::size_t bytes) {
    if (bytes <= capacity_) return;
    auto fresh = std::make_unique_for_overwrite<std::uint8_t[]>(bytes);
    if (size_bytes_ > 0) std::memcpy(fresh.get(), data_.get(), size_bytes_);
    data_ = std::move(fresh);
    capacity_ = bytes;
}

void Image::reshape(PixelFormat format, int width, int height) {
    assert(!isCompressed(format) && "use reshapeCompressed for MJPEG");
    assert(width >= 0 && height >= 0);
    const std::size_t stride = minStride(format, width);
    const std::size_t bytes = imageBytes(format, width, height, stride);
    if (bytes > capacity_) {
        data_ = std::make_unique_for_overwrite<std::uint8_t[]>(bytes);
        capacity_ = bytes;
    }
    format_ = format;
    width_ = width;
    height_ = height;
    stride_ = stride;
    size_bytes_ = bytes;
}

void Image::reshapeCompressed(int width, int height, std::size_t compressed_bytes) {
    if (compressed_bytes > capacity_) {
        data_ = std::make_unique_for_overwrite<std::uint8_t[]>(compressed_bytes);
        capacity_ = compressed_bytes;
    }
    format_ = PixelFormat::kMjpeg;
    width_ = width;
    height_ = height;
    stride_ = 0;
    size_bytes_ = compressed_bytes;
}

void Image::assign(const ImageView& view) {
    if (view.format == PixelFormat::kInvalid || view.empty()) {
        clear();
        return;
    }
    if (isCompressed(view.format)) {
        reshapeCompressed(view.width, view.height, view.size_bytes);
        std::memcpy(data_.get(), view.data, view.size_bytes);
        return;
    }
    reshape(view.format, view.width, view.height);
    const std::size_t row_bytes = minStride(view.format, view.width);
    const int rows = view.format == PixelFormat::kNv12 ? view.height + (view.height + 1) / 2 : view.height;
    for (int y = 0; y < rows; ++y) {
        std::memcpy(data_.get() + static_cast<std::size_t>(y) * stride_, view.row(y), row_bytes);
    }
}

void Image::clear() noexcept {
    format_ = PixelFormat::kInvalid;
    width_ = height_ = 0;
    stride_ = size_bytes_ = 0;
}

bool samePixels(const ImageView& a, const ImageView& b) noexcept {
    if (a.format != b.format || a.width != b.width || a.height != b.height) return false;
    if (isCompressed(a.format)) {
        return a.size_bytes == b.size_bytes && std::equal(a.data, a.data + a.size_bytes, b.data);
    }
    const std::size_t row_bytes = minStride(a.format, a.width);
    const int rows = a.format == PixelFormat::kNv12 ? a.height + (a.height + 1) / 2 : a.height;
    for (int y = 0; y < rows; ++y) {
        if (std::memcmp(a.row(y), b.row(y), row_bytes) != 0) return false;
    }
    return true;
}

}  // namespace commonlight

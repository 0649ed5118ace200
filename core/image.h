// Image (owning) and ImageView / MutableImageView (borrowed) for every pixel format we move.
//
// Rows are `stride` bytes apart. Packed formats have width * bytesPerPixel() <= stride.
// Planar NV12 is a Y plane of height rows followed by an interleaved UV plane of height / 2
// rows, both with the same stride. MJPEG holds `size_bytes` compressed bytes; width and height
// are what the stream announced (0 when unknown).
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string_view>

namespace commonlight {

enum class PixelFormat : std::uint8_t {
    kInvalid,
    kGray8,
    kGray16,  // native-endian 16-bit, values use the high bits of the sensor's range
    kRgb8,
    kBgr8,
    kRgba8,
    kYuyv,    // 4:2:2 packed Y0 U Y1 V
    kNv12,    // 4:2:0 Y plane + interleaved UV plane
    kMjpeg,   // one JPEG image per frame
    kRgbF32,  // linear float RGB
    // Raw colour-filter-array mosaics, 8 bits per pixel, named by the colours of the top-left 2x2
    // block read row by row (GenICam BayerRG8 = kBayerRggb8). Demosaiced by capture/convert.
    kBayerRggb8,
    kBayerGrbg8,
    kBayerGbrg8,
    kBayerBggr8,
};

std::string_view pixelFormatName(PixelFormat format) noexcept;
// Parses the lower-case names used in URIs and sensor.yaml ("rgb8", "yuyv", "mjpeg", ...).
std::optional<PixelFormat> parsePixelFormat(std::string_view name) noexcept;

// Bytes per pixel of a packed format; 0 for NV12 and MJPEG.
std::size_t bytesPerPixel(PixelFormat format) noexcept;
bool isBayer(PixelFormat format) noexcept;
bool isCompressed(PixelFormat format) noexcept;
// Smallest legal stride for a width (0 for MJPEG).
std::size_t minStride(PixelFormat format, int width) noexcept;
// Bytes an uncompressed image of this size needs with the given stride.
std::size_t imageBytes(PixelFormat format, int width, int height, std::size_t stride) noexcept;

// Borrowed, read-only pixels. Valid only while the owner lives; algorithms take it for one call.
struct ImageView {
    PixelFormat format = PixelFormat::kInvalid;
    int width = 0;
    int height = 0;
    std::size_t stride = 0;        // bytes between rows
    const std::uint8_t* data = nullptr;
    std::size_t size_bytes = 0;    // bytes valid at data (the compressed size for MJPEG)

    bool empty() const noexcept { return data == nullptr || size_bytes == 0; }
    const std::uint8_t* row(int y) const noexcept { return data + static_cast<std::size_t>(y) * stride; }
    std::span<const std::uint8_t> bytes() const noexcept { return {data, size_bytes}; }
};

// Borrowed, writable pixels.
struct MutableImageView {
    PixelFormat format = PixelFormat::kInvalid;
    int width = 0;
    int height = 0;
    std::size_t stride = 0;
    std::uint8_t* data = nullptr;
    std::size_t size_bytes = 0;

    std::uint8_t* row(int y) const noexcept { return data + static_cast<std::size_t>(y) * stride; }
    operator ImageView() const noexcept { return {format, width, height, stride, data, size_bytes}; }
};

// Owns its pixels. Reshaping to a size that fits the capacity never allocates, so a pool slot
// allocated once serves every frame of a stream.
class Image {
public:
    Image() = default;
    // Allocates a tightly packed image (stride = minStride).
    Image(PixelFormat format, int width, int height);
    Image(Image&&) noexcept = default;
    Image& operator=(Image&&) noexcept = default;
    Image(const Image&) = delete;
    Image& operator=(const Image&) = delete;

    // Deep copy.
    Image clone() const;
    static Image copyOf(const ImageView& view);

    // Makes room for at least `bytes` bytes (allocates only when the capacity is smaller).
    void reserve(std::size_t bytes);
    // Sets format and size with a packed stride; allocates only when the capacity is too small.
    void reshape(PixelFormat format, int width, int height);
    // For MJPEG: sets the compressed size (and the announced width/height).
    void reshapeCompressed(int width, int height, std::size_t compressed_bytes);
    // Copies a view into this image, reusing the capacity.
    void assign(const ImageView& view);
    void clear() noexcept;  // keeps the capacity

    PixelFormat format() const noexcept { return format_; }
    int width() const noexcept { return width_; }
    int height() const noexcept { return height_; }
    std::size_t stride() const noexcept { return stride_; }
    std::size_t sizeBytes() const noexcept { return size_bytes_; }
    std::size_t capacity() const noexcept { return capacity_; }
    bool empty() const noexcept { return size_bytes_ == 0; }
    std::uint8_t* data() noexcept { return data_.get(); }
    const std::uint8_t* data() const noexcept { return data_.get(); }

    ImageView view() const noexcept { return {format_, width_, height_, stride_, data_.get(), size_bytes_}; }
    MutableImageView mutableView() noexcept { return {format_, width_, height_, stride_, data_.get(), size_bytes_}; }
    operator ImageView() const noexcept { return view(); }

private:
    std::unique_ptr<std::uint8_t[]> data_;
    std::size_t capacity_ = 0;
    std::size_t size_bytes_ = 0;
    std::size_t stride_ = 0;
    int width_ = 0;
    int height_ = 0;
    PixelFormat format_ = PixelFormat::kInvalid;
};

// True when two views hold the same format, size and pixel bytes (row padding ignored).
bool samePixels(const ImageView& a, const ImageView& b) noexcept;

}  // namespace commonlight

#include "core/frame_file.h"

#include <algorithm>
#include <cstring>
#include <iterator>
#include <optional>
#include <utility>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/file_util.h"
#include "core/reader_guard.h"

namespace commonlight {

namespace fs = std::filesystem;

namespace {

Error corrupt(const fs::path& file, const std::string& problem) {
    return Error{ErrorCode::kBadInput, file.string() + ": " + problem};
}

// A complete JPEG starts with SOI (FF D8) and ends with EOI (FF D9). A frame cut short by a
// crash or a USB hiccup fails the second test; decoding it would show a grey lower part.
bool looksLikeCompleteJpeg(const std::vector<std::uint8_t>& b) {
    if (b.size() < 4 || b[0] != 0xFF || b[1] != 0xD8) return false;
    std::size_t end = b.size();
    while (end > 2 && b[end - 1] == 0x00) --end;  // some cameras pad buffers with zeros
    return b[end - 2] == 0xFF && b[end - 1] == 0xD9;
}

// Frames without a resolution to match are decoded up to 64 Mpx (8192 x 8192; 512 MB at RGBA16).
constexpr std::uint64_t kMaxDecodedPixels = std::uint64_t{1} << 26;

std::uint32_t bigEndian(const std::vector<std::uint8_t>& b, std::size_t at, int bytes) {
    std::uint32_t v = 0;
    for (int i = 0; i < bytes; ++i) v = (v << 8) | b[at + static_cast<std::size_t>(i)];
    return v;
}

// Width and height a PNG (IHDR) or JPEG (its SOFn frame header) declares, read before decoding;
// nullopt for another format or a header cut short.
std::optional<std::pair<std::uint32_t, std::uint32_t>> declaredSize(const std::vector<std::uint8_t>& b) {
    static constexpr std::uint8_t kPng[] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
    if (b.size() >= 24 && std::equal(std::begin(kPng), std::end(kPng), b.begin()) && bigEndian(b, 12, 4) == 0x49484452u) {
        return std::pair{bigEndian(b, 16, 4), bigEndian(b, 20, 4)};  // "IHDR": width, height
    }
    if (b.size() < 4 || b[0] != 0xFF || b[1] != 0xD8) return std::nullopt;
    // JPEG: markers FF xx, each segment with a 2-byte length, until a start-of-frame.
    std::size_t at = 2;
    while (at + 4 <= b.size()) {
        if (b[at] != 0xFF) return std::nullopt;
        const std::uint8_t marker = b[at + 1];
        if (marker == 0xFF) {  // fill byte
            ++at;
            continue;
        }
        const std::size_t length = bigEndian(b, at + 2, 2);
        const bool start_of_frame = marker >= 0xC0 && marker <= 0xCF && marker != 0xC4 && marker != 0xC8 && marker != 0xCC;
        if (start_of_frame) {
            if (length < 7 || at + 9 > b.size()) return std::nullopt;
            return std::pair{bigEndian(b, at + 7, 2), bigEndian(b, at + 5, 2)};  // width, height (lines)
        }
        if (length < 2) return std::nullopt;
        at += 2 + length;
    }
    return std::nullopt;
}

// Copies a decoded Mat into `out` as `format` (rows of the Mat are packed into out's stride).
void copyMat(const cv::Mat& m, PixelFormat format, int width, int height, Image& out) {
    out.reshape(format, width, height);
    const std::size_t row_bytes = m.cols * m.elemSize();
    for (int y = 0; y < m.rows; ++y) std::memcpy(out.data() + y * row_bytes, m.ptr(y), row_bytes);
}

}  // namespace

Result<void> FrameFileReader::read(const fs::path& file, PixelFormat stored, int width, int height, Image& out) {
    return guardReader(file, [&]() -> Result<void> {
        CL_TRY_VOID(readFileInto(file, bytes_));
        if (bytes_.empty()) return fail(corrupt(file, "empty file"));
        const bool is_jpeg = bytes_.size() >= 2 && bytes_[0] == 0xFF && bytes_[1] == 0xD8;

        if (is_jpeg && (stored == PixelFormat::kMjpeg || stored == PixelFormat::kInvalid)) {
            if (!looksLikeCompleteJpeg(bytes_)) return fail(corrupt(file, "truncated JPEG (no end-of-image marker)"));
            out.reshapeCompressed(width, height, bytes_.size());
            std::memcpy(out.data(), bytes_.data(), bytes_.size());
            return {};
        }
        if (stored == PixelFormat::kMjpeg) return fail(corrupt(file, "not a JPEG file, but the sequence is mjpeg"));
        if (stored == PixelFormat::kRgbF32) return fail(ErrorCode::kUnsupported, file.string() + ": rgbf32 frames are not supported in sequences");

        // imdecode leaves its output untouched when it cannot even read the header (garbage, a
        // broken signature): release it first so a failure can never pass off the previous frame's
        // pixels as this one's. Costs one allocation per decoded frame.
        decoded_.release();
        // The header's size, checked before OpenCV allocates for it: a 69-byte PNG can declare
        // 30000 x 30000 RGBA16 (7.2 GB). Frames are PNG or JPEG (docs/formats-sequence.md); no
        // other format goes to the decoder.
        const auto declared = declaredSize(bytes_);
        if (!declared) return fail(corrupt(file, "not a PNG or JPEG file, or its header is cut short"));
        const std::uint64_t pixels = std::uint64_t{declared->first} * std::uint64_t{declared->second};
        // YUYV and NV12 frames are stored as GRAY8 images of up to twice the frame's pixels.
        const std::uint64_t limit = width > 0 && height > 0 ? 2 * std::uint64_t{static_cast<unsigned>(width)} *
                                                                  std::uint64_t{static_cast<unsigned>(height)}
                                                            : kMaxDecodedPixels;
        if (pixels == 0 || pixels > limit) {
            return fail(corrupt(file, "the header declares a " + std::to_string(declared->first) + "x" +
                                          std::to_string(declared->second) + " image" +
                                          (width > 0 && height > 0
                                               ? ", but the sequence is " + std::to_string(width) + "x" + std::to_string(height)
                                               : ", larger than " + std::to_string(kMaxDecodedPixels) + " pixels")));
        }
        try {
            cv::imdecode(cv::Mat(1, static_cast<int>(bytes_.size()), CV_8UC1, bytes_.data()), cv::IMREAD_UNCHANGED,
                         &decoded_);
        } catch (const cv::Exception& e) {
            return fail(corrupt(file, std::string("cannot decode: ") + e.what()));
        }
        if (decoded_.empty()) return fail(corrupt(file, "cannot decode image (corrupt or truncated)"));

        const int channels = decoded_.channels();
        const int depth = decoded_.depth();
        auto expectSize = [&](int w, int h) -> Result<void> {
            if ((width > 0 && w != width) || (height > 0 && h != height)) {
                return fail(corrupt(file, "image is " + std::to_string(w) + "x" + std::to_string(h) +
                                              " but the sequence is " + std::to_string(width) + "x" + std::to_string(height)));
            }
            return {};
        };
        auto layoutError = [&](const char* expected) {
            return fail(corrupt(file, std::string("expected ") + expected + ", found a " + std::to_string(channels) +
                                          "-channel " + (depth == CV_16U ? "16" : "8") + "-bit image"));
        };

        PixelFormat format = stored;
        if (format == PixelFormat::kInvalid) {
            if (depth == CV_8U && channels == 1) format = PixelFormat::kGray8;
            else if (depth == CV_16U && channels == 1) format = PixelFormat::kGray16;
            else if (depth == CV_8U && channels == 3) format = PixelFormat::kRgb8;
            else if (depth == CV_8U && channels == 4) format = PixelFormat::kRgba8;
            else return layoutError("8-bit gray/RGB/RGBA or 16-bit gray");
        }
        switch (format) {
            case PixelFormat::kGray8:
            case PixelFormat::kBayerRggb8:
            case PixelFormat::kBayerGrbg8:
            case PixelFormat::kBayerGbrg8:
            case PixelFormat::kBayerBggr8:
                if (depth != CV_8U || channels != 1) {
                    return layoutError(format == PixelFormat::kGray8 ? "an 8-bit gray image" : "an 8-bit gray PNG of the raw mosaic");
                }
                CL_TRY_VOID(expectSize(decoded_.cols, decoded_.rows));
                copyMat(decoded_, format, decoded_.cols, decoded_.rows, out);
                return {};
            case PixelFormat::kGray16:
                if (depth != CV_16U || channels != 1) return layoutError("a 16-bit gray image");
                CL_TRY_VOID(expectSize(decoded_.cols, decoded_.rows));
                copyMat(decoded_, format, decoded_.cols, decoded_.rows, out);
                return {};
            case PixelFormat::kBgr8:
                if (depth != CV_8U || channels != 3) return layoutError("an 8-bit colour image");
                CL_TRY_VOID(expectSize(decoded_.cols, decoded_.rows));
                copyMat(decoded_, format, decoded_.cols, decoded_.rows, out);
                return {};
            case PixelFormat::kRgb8:
            case PixelFormat::kRgba8: {
                const int want = format == PixelFormat::kRgb8 ? 3 : 4;
                if (depth != CV_8U || channels != want) return layoutError(want == 3 ? "an 8-bit RGB image" : "an 8-bit RGBA image");
                CL_TRY_VOID(expectSize(decoded_.cols, decoded_.rows));
                out.reshape(format, decoded_.cols, decoded_.rows);
                cv::Mat dst(decoded_.rows, decoded_.cols, CV_8UC(want), out.data(), out.stride());
                cv::cvtColor(decoded_, dst, want == 3 ? cv::COLOR_BGR2RGB : cv::COLOR_BGRA2RGBA);
                return {};
            }
            case PixelFormat::kYuyv:
                if (depth != CV_8U || channels != 1 || decoded_.cols % 4 != 0) return layoutError("a GRAY8 PNG of 2*width columns");
                CL_TRY_VOID(expectSize(decoded_.cols / 2, decoded_.rows));
                copyMat(decoded_, format, decoded_.cols / 2, decoded_.rows, out);
                return {};
            case PixelFormat::kNv12:
                if (depth != CV_8U || channels != 1 || decoded_.rows % 3 != 0) return layoutError("a GRAY8 PNG of height*3/2 rows");
                CL_TRY_VOID(expectSize(decoded_.cols, decoded_.rows * 2 / 3));
                copyMat(decoded_, format, decoded_.cols, decoded_.rows * 2 / 3, out);
                return {};
            default:
                return fail(ErrorCode::kUnsupported, file.string() + ": cannot read frames of format " +
                                                         std::string(pixelFormatName(format)));
        }
    });
}

const char* FrameFileWriter::extension(PixelFormat format) noexcept {
    return format == PixelFormat::kMjpeg ? ".jpg" : ".png";
}

Result<void> FrameFileWriter::encode(const ImageView& image, std::vector<std::uint8_t>& out) {
    if (image.empty()) return fail(ErrorCode::kBadInput, "cannot store an empty frame");
    if (image.format == PixelFormat::kMjpeg) {
        out.assign(image.data, image.data + image.size_bytes);
        return {};
    }
    auto* data = const_cast<std::uint8_t*>(image.data);  // cv::Mat needs non-const; we only read it
    cv::Mat view;
    switch (image.format) {
        case PixelFormat::kGray8:
        case PixelFormat::kBayerRggb8:
        case PixelFormat::kBayerGrbg8:
        case PixelFormat::kBayerGbrg8:
        case PixelFormat::kBayerBggr8: view = cv::Mat(image.height, image.width, CV_8UC1, data, image.stride); break;
        case PixelFormat::kGray16: view = cv::Mat(image.height, image.width, CV_16UC1, data, image.stride); break;
        case PixelFormat::kBgr8: view = cv::Mat(image.height, image.width, CV_8UC3, data, image.stride); break;
        case PixelFormat::kRgb8:
            cv::cvtColor(cv::Mat(image.height, image.width, CV_8UC3, data, image.stride), scratch_, cv::COLOR_RGB2BGR);
            view = scratch_;
            break;
        case PixelFormat::kRgba8:
            cv::cvtColor(cv::Mat(image.height, image.width, CV_8UC4, data, image.stride), scratch_, cv::COLOR_RGBA2BGRA);
            view = scratch_;
            break;
        case PixelFormat::kYuyv: view = cv::Mat(image.height, image.width * 2, CV_8UC1, data, image.stride); break;
        case PixelFormat::kNv12: view = cv::Mat(image.height * 3 / 2, image.width, CV_8UC1, data, image.stride); break;
        default:
            return fail(ErrorCode::kUnsupported,
                        std::string("frames of format ") + std::string(pixelFormatName(image.format)) +
                            " cannot be stored in a sequence");
    }
    // Level 1: lossless like every level, and several times faster than the default 3, which
    // matters when recording 30 fps.
    static const std::vector<int> kParams = {cv::IMWRITE_PNG_COMPRESSION, 1};
    try {
        if (!cv::imencode(".png", view, out, kParams)) return fail(ErrorCode::kInternal, "PNG encoding failed");
    } catch (const cv::Exception& e) {
        return fail(ErrorCode::kInternal, std::string("PNG encoding failed: ") + e.what());
    }
    return {};
}

}  // namespace commonlight

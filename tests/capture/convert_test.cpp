#include "capture/convert.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <functional>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace commonlight::capture {
namespace {

constexpr int kW = 16;
constexpr int kH = 8;

struct Rgb {
    int r, g, b;
};

// A test pattern with every channel varying independently.
Rgb patternAt(int x, int y) {
    return {(x * 37 + y * 11) % 256, (x * 5 + y * 53 + 40) % 256, (255 - x * 13 - y * 7 + 512) % 256};
}

Image patternRgb(int width = kW, int height = kH) {
    Image image(PixelFormat::kRgb8, width, height);
    for (int y = 0; y < height; ++y) {
        for (int x = 0; x < width; ++x) {
            const Rgb c = patternAt(x, y);
            std::uint8_t* p = image.data() + y * image.stride() + 3 * x;
            p[0] = static_cast<std::uint8_t>(c.r);
            p[1] = static_cast<std::uint8_t>(c.g);
            p[2] = static_cast<std::uint8_t>(c.b);
        }
    }
    return image;
}

int at(const Image& image, int x, int y, int c) {
    const int channels = image.format() == PixelFormat::kRgb8 ? 3 : 1;
    return image.data()[y * image.stride() + x * channels + c];
}

int lumaBt601(int r, int g, int b) { return static_cast<int>(std::lround(0.299 * r + 0.587 * g + 0.114 * b)); }

int clamp8(double v) { return static_cast<int>(std::lround(std::clamp(v, 0.0, 255.0))); }

// BT.601 limited range ("video range"), the matrix UVC cameras and OpenCV use for YUYV / NV12.
Rgb yuvToRgb(int y, int u, int v) {
    const double c = 1.164 * (y - 16);
    return {clamp8(c + 1.596 * (v - 128)), clamp8(c - 0.391 * (u - 128) - 0.813 * (v - 128)),
            clamp8(c + 2.018 * (u - 128))};
}

// Y, U, V samples of the test pattern, inside the legal ranges.
int lumaAt(int x, int y) { return 16 + (x * 23 + y * 41) % 220; }
int chromaU(int x2, int y2) { return 16 + (x2 * 67 + y2 * 29 + 100) % 225; }
int chromaV(int x2, int y2) { return 16 + (x2 * 31 + y2 * 83 + 7) % 225; }

void expectRgbNear(const Image& out, const std::function<Rgb(int, int)>& expected, int tolerance) {
    ASSERT_EQ(out.format(), PixelFormat::kRgb8);
    for (int y = 0; y < out.height(); ++y) {
        for (int x = 0; x < out.width(); ++x) {
            const Rgb e = expected(x, y);
            ASSERT_NEAR(at(out, x, y, 0), e.r, tolerance) << "R at " << x << "," << y;
            ASSERT_NEAR(at(out, x, y, 1), e.g, tolerance) << "G at " << x << "," << y;
            ASSERT_NEAR(at(out, x, y, 2), e.b, tolerance) << "B at " << x << "," << y;
        }
    }
}

void expectGrayNear(const Image& out, const std::function<int(int, int)>& expected, int tolerance) {
    ASSERT_EQ(out.format(), PixelFormat::kGray8);
    for (int y = 0; y < out.height(); ++y) {
        for (int x = 0; x < out.width(); ++x) ASSERT_NEAR(at(out, x, y, 0), expected(x, y), tolerance) << x << "," << y;
    }
}

TEST(PixelConverter, Rgb8ToRgbCopiesAndToGrayUsesBt601Weights) {
    PixelConverter converter;
    const Image src = patternRgb();
    Image out;
    ASSERT_TRUE(converter.convert(src, PixelFormat::kRgb8, out));
    EXPECT_TRUE(samePixels(out, src));
    ASSERT_TRUE(converter.convert(src, PixelFormat::kGray8, out));
    expectGrayNear(out, [](int x, int y) { const Rgb c = patternAt(x, y); return lumaBt601(c.r, c.g, c.b); }, 1);
}

TEST(PixelConverter, Bgr8AndRgba8) {
    PixelConverter converter;
    Image bgr(PixelFormat::kBgr8, kW, kH);
    Image rgba(PixelFormat::kRgba8, kW, kH);
    for (int y = 0; y < kH; ++y) {
        for (int x = 0; x < kW; ++x) {
            const Rgb c = patternAt(x, y);
            std::uint8_t* b = bgr.data() + y * bgr.stride() + 3 * x;
            b[0] = static_cast<std::uint8_t>(c.b);
            b[1] = static_cast<std::uint8_t>(c.g);
            b[2] = static_cast<std::uint8_t>(c.r);
            std::uint8_t* a = rgba.data() + y * rgba.stride() + 4 * x;
            a[0] = static_cast<std::uint8_t>(c.r);
            a[1] = static_cast<std::uint8_t>(c.g);
            a[2] = static_cast<std::uint8_t>(c.b);
            a[3] = static_cast<std::uint8_t>(x * 16);
        }
    }
    const Image reference = patternRgb();
    for (const Image* src : {&bgr, &rgba}) {
        Image out;
        ASSERT_TRUE(converter.convert(*src, PixelFormat::kRgb8, out));
        EXPECT_TRUE(samePixels(out, reference)) << pixelFormatName(src->format());
        ASSERT_TRUE(converter.convert(*src, PixelFormat::kGray8, out));
        expectGrayNear(out, [](int x, int y) { const Rgb c = patternAt(x, y); return lumaBt601(c.r, c.g, c.b); }, 1);
    }
}

TEST(PixelConverter, Gray8AndGray16TakeTheHighByte) {
    PixelConverter converter;
    Image gray(PixelFormat::kGray8, kW, kH);
    Image gray16(PixelFormat::kGray16, kW, kH);
    for (int y = 0; y < kH; ++y) {
        for (int x = 0; x < kW; ++x) {
            gray.data()[y * gray.stride() + x] = static_cast<std::uint8_t>(x * 16 + y);
            const auto v = static_cast<std::uint16_t>((x * 16 + y) * 256 + 255 - x);  // low byte is noise
            std::memcpy(gray16.data() + y * gray16.stride() + 2 * x, &v, 2);
        }
    }
    for (const Image* src : {&gray, &gray16}) {
        Image out;
        ASSERT_TRUE(converter.convert(*src, PixelFormat::kGray8, out));
        expectGrayNear(out, [](int x, int y) { return x * 16 + y; }, 0);
        ASSERT_TRUE(converter.convert(*src, PixelFormat::kRgb8, out));
        expectRgbNear(out, [](int x, int y) { return Rgb{x * 16 + y, x * 16 + y, x * 16 + y}; }, 0);
    }
}

// YUYV with padded rows (stride > 2 * width) from known Y/U/V samples.
TEST(PixelConverter, YuyvMatchesBt601Formulas) {
    const std::size_t stride = 2 * kW + 8;
    std::vector<std::uint8_t> bytes(stride * kH, 0xEE);
    for (int y = 0; y < kH; ++y) {
        for (int x2 = 0; x2 < kW / 2; ++x2) {
            std::uint8_t* p = bytes.data() + y * stride + 4 * x2;
            p[0] = static_cast<std::uint8_t>(lumaAt(2 * x2, y));
            p[1] = static_cast<std::uint8_t>(chromaU(x2, y));
            p[2] = static_cast<std::uint8_t>(lumaAt(2 * x2 + 1, y));
            p[3] = static_cast<std::uint8_t>(chromaV(x2, y));
        }
    }
    const ImageView src{PixelFormat::kYuyv, kW, kH, stride, bytes.data(), bytes.size()};
    PixelConverter converter;
    Image out;
    ASSERT_TRUE(converter.convert(src, PixelFormat::kRgb8, out));
    expectRgbNear(out, [](int x, int y) { return yuvToRgb(lumaAt(x, y), chromaU(x / 2, y), chromaV(x / 2, y)); }, 2);
    ASSERT_TRUE(converter.convert(src, PixelFormat::kGray8, out));
    expectGrayNear(out, lumaAt, 0);
}

TEST(PixelConverter, Nv12MatchesBt601Formulas) {
    const std::size_t stride = kW + 4;
    std::vector<std::uint8_t> bytes(stride * (kH + kH / 2), 0xEE);
    for (int y = 0; y < kH; ++y) {
        for (int x = 0; x < kW; ++x) bytes[y * stride + x] = static_cast<std::uint8_t>(lumaAt(x, y));
    }
    for (int y2 = 0; y2 < kH / 2; ++y2) {
        for (int x2 = 0; x2 < kW / 2; ++x2) {
            std::uint8_t* uv = bytes.data() + (kH + y2) * stride + 2 * x2;
            uv[0] = static_cast<std::uint8_t>(chromaU(x2, y2));
            uv[1] = static_cast<std::uint8_t>(chromaV(x2, y2));
        }
    }
    const ImageView src{PixelFormat::kNv12, kW, kH, stride, bytes.data(), bytes.size()};
    PixelConverter converter;
    Image out;
    ASSERT_TRUE(converter.convert(src, PixelFormat::kRgb8, out));
    expectRgbNear(
        out, [](int x, int y) { return yuvToRgb(lumaAt(x, y), chromaU(x / 2, y / 2), chromaV(x / 2, y / 2)); }, 2);
    ASSERT_TRUE(converter.convert(src, PixelFormat::kGray8, out));
    expectGrayNear(out, lumaAt, 0);
}

// A smooth image survives JPEG well: compare with the source and with OpenCV's own decoder.
std::vector<std::uint8_t> encodeJpeg(const Image& rgb, int quality = 95) {
    cv::Mat bgr;
    cv::cvtColor(cv::Mat(rgb.height(), rgb.width(), CV_8UC3, const_cast<std::uint8_t*>(rgb.data()), rgb.stride()), bgr,
                 cv::COLOR_RGB2BGR);
    std::vector<std::uint8_t> jpeg;
    EXPECT_TRUE(cv::imencode(".jpg", bgr, jpeg, {cv::IMWRITE_JPEG_QUALITY, quality}));
    return jpeg;
}

Image smoothRgb(int width, int height) {
    Image image(PixelFormat::kRgb8, width, height);
    for (int y = 0; y < height; ++y) {
        for (int x = 0; x < width; ++x) {
            std::uint8_t* p = image.data() + y * image.stride() + 3 * x;
            p[0] = static_cast<std::uint8_t>(x * 255 / (width - 1));
            p[1] = static_cast<std::uint8_t>(y * 255 / (height - 1));
            p[2] = static_cast<std::uint8_t>(128);
        }
    }
    return image;
}

// A mosaic of a flat colour laid out as the format says: `layout` is the colour (0 R, 1 G, 2 B)
// of the top-left 2x2 block, row by row.
Image mosaicOf(PixelFormat format, const std::array<int, 4>& layout, Rgb colour, int width, int height) {
    Image image(format, width, height);
    const int channel[3] = {colour.r, colour.g, colour.b};
    for (int y = 0; y < height; ++y) {
        for (int x = 0; x < width; ++x) {
            image.data()[y * image.stride() + x] = static_cast<std::uint8_t>(channel[layout[(y % 2) * 2 + x % 2]]);
        }
    }
    return image;
}

TEST(PixelConverter, BayerMosaicsDemosaicToTheColourTheyWereMadeOf) {
    struct Case {
        PixelFormat format;
        std::array<int, 4> layout;
    };
    const Case cases[] = {{PixelFormat::kBayerRggb8, {0, 1, 1, 2}},
                          {PixelFormat::kBayerGrbg8, {1, 0, 2, 1}},
                          {PixelFormat::kBayerGbrg8, {1, 2, 0, 1}},
                          {PixelFormat::kBayerBggr8, {2, 1, 1, 0}}};
    const Rgb colour{200, 100, 30};  // every channel different: a swapped pattern shows
    PixelConverter converter;
    for (const Case& c : cases) {
        SCOPED_TRACE(std::string(pixelFormatName(c.format)));
        EXPECT_TRUE(PixelConverter::canConvert(c.format, PixelFormat::kRgb8));
        const Image mosaic = mosaicOf(c.format, c.layout, colour, 16, 12);
        Image rgb;
        ASSERT_TRUE(converter.convert(mosaic.view(), PixelFormat::kRgb8, rgb));
        ASSERT_EQ(rgb.format(), PixelFormat::kRgb8);
        ASSERT_EQ(rgb.width(), 16);
        // Away from the border a flat colour demosaics to itself exactly.
        for (int y = 2; y < 10; ++y) {
            for (int x = 2; x < 14; ++x) {
                const std::uint8_t* p = rgb.data() + y * rgb.stride() + 3 * x;
                ASSERT_EQ(p[0], colour.r) << x << "," << y;
                ASSERT_EQ(p[1], colour.g) << x << "," << y;
                ASSERT_EQ(p[2], colour.b) << x << "," << y;
            }
        }
        Image gray;
        ASSERT_TRUE(converter.convert(mosaic.view(), PixelFormat::kGray8, gray));
        const int expected = static_cast<int>(std::lround(0.299 * colour.r + 0.587 * colour.g + 0.114 * colour.b));
        EXPECT_NEAR(gray.data()[5 * gray.stride() + 5], expected, 1);
    }
    // Too small to demosaic: an error, not a crash.
    Image tiny(PixelFormat::kBayerRggb8, 1, 4);
    Image out;
    EXPECT_FALSE(converter.convert(tiny.view(), PixelFormat::kRgb8, out));
}

TEST(PixelConverter, MjpegDecodesWhatOpenCvEncoded) {
    const Image source = smoothRgb(64, 48);
    const std::vector<std::uint8_t> jpeg = encodeJpeg(source);
    const ImageView src{PixelFormat::kMjpeg, 64, 48, 0, jpeg.data(), jpeg.size()};
    const cv::Mat reference_bgr = cv::imdecode(jpeg, cv::IMREAD_COLOR);
    const cv::Mat reference_gray = cv::imdecode(jpeg, cv::IMREAD_GRAYSCALE);
    ASSERT_FALSE(reference_bgr.empty());

    PixelConverter converter;
    Image out;
    ASSERT_TRUE(converter.convert(src, PixelFormat::kRgb8, out));
    ASSERT_EQ(out.width(), 64);
    ASSERT_EQ(out.height(), 48);
    double error_sum = 0.0;
    for (int y = 0; y < 48; ++y) {
        for (int x = 0; x < 64; ++x) {
            const cv::Vec3b ref = reference_bgr.at<cv::Vec3b>(y, x);
            for (int c = 0; c < 3; ++c) {
                ASSERT_NEAR(at(out, x, y, c), ref[2 - c], 2) << x << "," << y << " channel " << c;
                error_sum += std::abs(at(out, x, y, c) - at(source, x, y, c));
            }
        }
    }
    EXPECT_LT(error_sum / (64 * 48 * 3), 3.0);  // close to the encoded image

    ASSERT_TRUE(converter.convert(src, PixelFormat::kGray8, out));
    expectGrayNear(out, [&](int x, int y) { return static_cast<int>(reference_gray.at<std::uint8_t>(y, x)); }, 2);
}

TEST(PixelConverter, MjpegOfUnknownSizeTakesTheHeaderSize) {
    const Image source = smoothRgb(32, 16);
    const std::vector<std::uint8_t> jpeg = encodeJpeg(source);
    PixelConverter converter;
    Image out;
    ASSERT_TRUE(converter.convert(ImageView{PixelFormat::kMjpeg, 0, 0, 0, jpeg.data(), jpeg.size()},
                                  PixelFormat::kRgb8, out));
    EXPECT_EQ(out.width(), 32);
    EXPECT_EQ(out.height(), 16);
}

TEST(PixelConverter, CorruptOrTruncatedJpegIsAnError) {
    const Image source = patternRgb(64, 48);  // busy image: long entropy-coded data
    const std::vector<std::uint8_t> jpeg = encodeJpeg(source);
    PixelConverter converter;
    Image out;

    const ImageView truncated{PixelFormat::kMjpeg, 64, 48, 0, jpeg.data(), jpeg.size() / 2};
    auto r = converter.convert(truncated, PixelFormat::kRgb8, out);
    ASSERT_FALSE(r);
    EXPECT_EQ(r.error().code, ErrorCode::kBadInput);
    EXPECT_NE(r.error().message.find("MJPEG"), std::string::npos) << r.error().message;

    std::vector<std::uint8_t> garbage(500);
    for (std::size_t i = 0; i < garbage.size(); ++i) garbage[i] = static_cast<std::uint8_t>(i * 131 + 7);
    r = converter.convert(ImageView{PixelFormat::kMjpeg, 64, 48, 0, garbage.data(), garbage.size()},
                          PixelFormat::kRgb8, out);
    ASSERT_FALSE(r);
    EXPECT_EQ(r.error().code, ErrorCode::kBadInput);

    const std::vector<std::uint8_t> header_only(jpeg.begin(), jpeg.begin() + 20);
    r = converter.convert(ImageView{PixelFormat::kMjpeg, 64, 48, 0, header_only.data(), header_only.size()},
                          PixelFormat::kGray8, out);
    ASSERT_FALSE(r);

    // A JPEG of another size than the stream announced.
    r = converter.convert(ImageView{PixelFormat::kMjpeg, 32, 32, 0, jpeg.data(), jpeg.size()}, PixelFormat::kRgb8, out);
    ASSERT_FALSE(r);
    EXPECT_NE(r.error().message.find("64x48"), std::string::npos) << r.error().message;

    // The converter still works after errors.
    EXPECT_TRUE(converter.convert(ImageView{PixelFormat::kMjpeg, 64, 48, 0, jpeg.data(), jpeg.size()},
                                  PixelFormat::kRgb8, out));
}

TEST(PixelConverter, SteadyStateReusesTheDestinationBuffer) {
    const Image source = smoothRgb(64, 48);
    const std::vector<std::uint8_t> jpeg = encodeJpeg(source);
    PixelConverter converter;
    Image out;
    ASSERT_TRUE(converter.convert(source, PixelFormat::kRgb8, out));
    const std::uint8_t* buffer = out.data();
    const std::size_t capacity = out.capacity();
    for (int i = 0; i < 3; ++i) {
        ASSERT_TRUE(converter.convert(source, PixelFormat::kGray8, out));
        ASSERT_TRUE(converter.convert(ImageView{PixelFormat::kMjpeg, 64, 48, 0, jpeg.data(), jpeg.size()},
                                      PixelFormat::kRgb8, out));
        ASSERT_TRUE(converter.convert(source, PixelFormat::kRgb8, out));
    }
    EXPECT_EQ(out.data(), buffer);
    EXPECT_EQ(out.capacity(), capacity);

    PixelConverter moved = std::move(converter);  // the decoder handle moves with it
    EXPECT_TRUE(moved.convert(ImageView{PixelFormat::kMjpeg, 64, 48, 0, jpeg.data(), jpeg.size()},
                              PixelFormat::kGray8, out));
}

TEST(PixelConverter, RejectsMalformedViewsAndUnsupportedPairs) {
    PixelConverter converter;
    Image out;
    std::vector<std::uint8_t> bytes(1024, 0);
    // Odd width for a 4:2:x format.
    auto r = converter.convert(ImageView{PixelFormat::kNv12, 15, 8, 15, bytes.data(), bytes.size()},
                               PixelFormat::kRgb8, out);
    ASSERT_FALSE(r);
    EXPECT_EQ(r.error().code, ErrorCode::kBadInput);
    // Fewer bytes than the format needs.
    r = converter.convert(ImageView{PixelFormat::kRgb8, 32, 32, 96, bytes.data(), bytes.size()}, PixelFormat::kGray8,
                          out);
    ASSERT_FALSE(r);
    EXPECT_NE(r.error().message.find("needs 3072"), std::string::npos) << r.error().message;
    // A stride shorter than a row.
    r = converter.convert(ImageView{PixelFormat::kRgb8, 8, 8, 16, bytes.data(), bytes.size()}, PixelFormat::kGray8,
                          out);
    ASSERT_FALSE(r);
    // No pixels.
    r = converter.convert(ImageView{}, PixelFormat::kRgb8, out);
    ASSERT_FALSE(r);
    // Only RGB8 and GRAY8 are produced.
    r = converter.convert(patternRgb(), PixelFormat::kBgr8, out);
    ASSERT_FALSE(r);
    EXPECT_EQ(r.error().code, ErrorCode::kUnsupported);
    EXPECT_FALSE(PixelConverter::canConvert(PixelFormat::kRgbF32, PixelFormat::kRgb8));
    EXPECT_TRUE(PixelConverter::canConvert(PixelFormat::kMjpeg, PixelFormat::kGray8));
}

}  // namespace
}  // namespace commonlight::capture

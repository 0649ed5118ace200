#include "core/image.h"

#include <gtest/gtest.h>

namespace commonlight {
namespace {

TEST(Image, SizesPerFormat) {
    EXPECT_EQ(Image(PixelFormat::kRgb8, 640, 480).sizeBytes(), 640u * 480u * 3u);
    EXPECT_EQ(Image(PixelFormat::kYuyv, 640, 480).sizeBytes(), 640u * 480u * 2u);
    EXPECT_EQ(Image(PixelFormat::kNv12, 640, 480).sizeBytes(), 640u * 480u * 3u / 2u);
    EXPECT_EQ(Image(PixelFormat::kGray16, 10, 10).stride(), 20u);
    EXPECT_EQ(Image(PixelFormat::kRgbF32, 2, 2).sizeBytes(), 48u);
}

TEST(Image, ReshapeWithinCapacityDoesNotReallocate) {
    Image image(PixelFormat::kRgb8, 1280, 720);
    const std::uint8_t* before = image.data();
    image.reshape(PixelFormat::kYuyv, 1280, 720);
    EXPECT_EQ(image.data(), before);
    image.reshapeCompressed(1280, 720, 100000);
    EXPECT_EQ(image.data(), before);
    EXPECT_EQ(image.format(), PixelFormat::kMjpeg);
    EXPECT_EQ(image.sizeBytes(), 100000u);
}

TEST(Image, AssignCopiesStridedViews) {
    // A 4x2 GRAY8 view with stride 6 (padding bytes must not be copied or compared).
    std::uint8_t bytes[12] = {1, 2, 3, 4, 99, 99, 5, 6, 7, 8, 98, 98};
    const ImageView view{PixelFormat::kGray8, 4, 2, 6, bytes, sizeof(bytes)};
    Image copy = Image::copyOf(view);
    EXPECT_EQ(copy.stride(), 4u);
    EXPECT_EQ(copy.data()[4], 5);
    EXPECT_TRUE(samePixels(copy, view));
    copy.data()[7] = 0;
    EXPECT_FALSE(samePixels(copy, view));
}

TEST(Image, PixelFormatNamesRoundTrip) {
    for (auto f : {PixelFormat::kGray8, PixelFormat::kGray16, PixelFormat::kRgb8, PixelFormat::kBgr8,
                   PixelFormat::kRgba8, PixelFormat::kYuyv, PixelFormat::kNv12, PixelFormat::kMjpeg,
                   PixelFormat::kRgbF32, PixelFormat::kBayerRggb8, PixelFormat::kBayerGrbg8,
                   PixelFormat::kBayerGbrg8, PixelFormat::kBayerBggr8}) {
        EXPECT_EQ(parsePixelFormat(pixelFormatName(f)), f);
    }
    EXPECT_EQ(parsePixelFormat("mono8"), PixelFormat::kGray8);
    EXPECT_FALSE(parsePixelFormat("bayer_weird"));
}

}  // namespace
}  // namespace commonlight

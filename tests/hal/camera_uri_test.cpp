#include "hal/camera_uri.h"

#include <gtest/gtest.h>

namespace commonlight::hal {
namespace {

CameraUri parsed(std::string_view text) {
    auto uri = parseCameraUri(text);
    if (!uri) {
        ADD_FAILURE() << uri.error().message;
        return {};
    }
    return *uri;
}

void expectUsageError(std::string_view text, std::string_view mentions) {
    const auto uri = parseCameraUri(text);
    ASSERT_FALSE(uri) << text;
    EXPECT_EQ(uri.error().code, ErrorCode::kUsage) << text;
    EXPECT_NE(uri.error().message.find("camera URI '" + std::string(text) + "'"), std::string::npos)
        << uri.error().message;
    EXPECT_NE(uri.error().message.find(mentions), std::string::npos) << uri.error().message;
}

TEST(CameraUri, SchemePathAndOptions) {
    const CameraUri uri = parsed("v4l2:/dev/video0?width=1280&height=720&format=mjpeg");
    EXPECT_EQ(uri.text, "v4l2:/dev/video0?width=1280&height=720&format=mjpeg");
    EXPECT_EQ(uri.scheme, "v4l2");
    EXPECT_EQ(uri.path, "/dev/video0");
    EXPECT_EQ(uri.options.size(), 3u);
    EXPECT_EQ(uri.option("format"), "mjpeg");
    EXPECT_FALSE(uri.option("fps"));
}

TEST(CameraUri, PathMayContainColons) {
    EXPECT_EQ(parsed("aravis:192.168.1.20:3956").path, "192.168.1.20:3956");
    EXPECT_EQ(parsed("replay:data/a:b/seq?rate=max").path, "data/a:b/seq");
    EXPECT_EQ(parsed("libcamera:0").path, "0");
    EXPECT_EQ(parsed("replay:").path, "") << "the backend decides whether an empty path is fine";
}

TEST(CameraUri, PercentEscapesInPathKeysAndValues) {
    const CameraUri uri = parsed("video:my%20clips/take%3F1.mp4?na%6De=a%26b%3Dc");
    EXPECT_EQ(uri.path, "my clips/take?1.mp4");
    EXPECT_EQ(uri.option("name"), "a&b=c");
    EXPECT_EQ(parsed("replay:%2fabs%2Fpath").path, "/abs/path") << "hex digits in either case";
}

TEST(CameraUri, EmptyPairsAreSkipped) {
    const CameraUri uri = parsed("replay:seq?&rate=max&&loop=1&");
    EXPECT_EQ(uri.options.size(), 2u);
    EXPECT_EQ(uri.option("loop"), "1");
    EXPECT_TRUE(parsed("replay:seq?").options.empty());
}

TEST(CameraUri, EmptyValuesAreKept) { EXPECT_EQ(parsed("replay:seq?rate=").option("rate"), ""); }

TEST(CameraUri, MalformedUrisAreUsageErrorsNamingTheUri) {
    expectUsageError("/dev/video0", "expected <scheme>:<device>");
    expectUsageError(":/dev/video0", "expected <scheme>:<device>");
    expectUsageError("", "expected <scheme>:<device>");
    expectUsageError("V4L2:/dev/video0", "scheme 'V4L2' must be lower-case");
    expectUsageError("my-cam:0", "scheme 'my-cam'");
    expectUsageError("replay:seq?loop", "option 'loop' must be key=value");
    expectUsageError("replay:seq?=1", "option '=1' must be key=value");
    expectUsageError("replay:seq?rate=max&rate=step", "option 'rate' given twice");
    expectUsageError("replay:seq?rate=max&r%61te=step", "option 'rate' given twice");
}

TEST(CameraUri, BadPercentEscapes) {
    expectUsageError("video:a%2", "bad percent escape");
    expectUsageError("video:a%", "bad percent escape");
    expectUsageError("video:a%zz.mp4", "bad percent escape");
    expectUsageError("video:a.mp4?k=%g1", "bad percent escape");
}

TEST(CameraUri, TypedOptions) {
    const CameraUri uri = parsed("x:y?n=2.5&i=-3&f=yes&g=off&bad=abc&half=1.5&big=1e999");
    EXPECT_EQ(uri.number("n").value(), 2.5);
    EXPECT_EQ(uri.integer("i").value(), -3);
    EXPECT_EQ(uri.flag("f").value(), true);
    EXPECT_EQ(uri.flag("g").value(), false);
    EXPECT_EQ(uri.number("missing").value(), std::nullopt);
    EXPECT_EQ(uri.integer("missing").value(), std::nullopt);
    EXPECT_EQ(uri.flag("missing").value(), std::nullopt);
    for (const auto& error : {uri.number("bad").error(), uri.integer("half").error(), uri.flag("bad").error(),
                              uri.number("big").error(), uri.integer("n").error()}) {
        EXPECT_EQ(error.code, ErrorCode::kUsage);
        EXPECT_NE(error.message.find("camera URI 'x:y?"), std::string::npos) << error.message;
        EXPECT_NE(error.message.find("option '"), std::string::npos) << error.message;
    }
    EXPECT_NE(uri.flag("bad").error().message.find("option 'bad' needs 0 or 1, got 'abc'"), std::string::npos);
}

TEST(CameraUri, StreamConfigFromCommonOptions) {
    const auto config = streamConfigFromUri(parsed("v4l2:/dev/video0?width=1280&height=720&fps=30&format=yuy2"));
    ASSERT_TRUE(config) << config.error().message;
    EXPECT_EQ(config->width, 1280);
    EXPECT_EQ(config->height, 720);
    EXPECT_EQ(config->fps, 30.0);
    EXPECT_EQ(config->format, PixelFormat::kYuyv) << "V4L2 alias";
    const auto empty = streamConfigFromUri(parsed("v4l2:/dev/video0"));
    ASSERT_TRUE(empty);
    EXPECT_EQ(empty->format, PixelFormat::kInvalid);
    EXPECT_EQ(empty->width, 0);
    EXPECT_EQ(empty->fps, 0.0);
}

TEST(CameraUri, StreamConfigRejectsBadValues) {
    for (const char* text : {"v4l2:x?width=0", "v4l2:x?height=70000", "v4l2:x?fps=-1", "v4l2:x?fps=0",
                             "v4l2:x?format=rgb9", "v4l2:x?width=wide"}) {
        const auto config = streamConfigFromUri(parsed(text));
        ASSERT_FALSE(config) << text;
        EXPECT_EQ(config.error().code, ErrorCode::kUsage) << text;
        EXPECT_NE(config.error().message.find(text), std::string::npos) << config.error().message;
    }
}

}  // namespace
}  // namespace commonlight::hal

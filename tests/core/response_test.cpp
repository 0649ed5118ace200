#include "core/response.h"

#include <gtest/gtest.h>

#include <cmath>

#include "tests/test_support.h"

namespace commonlight {
namespace {

TEST(ResponseCurve, SrgbMatchesTheStandardAtKnownCodes) {
    const ResponseCurve r = ResponseCurve::srgb();
    EXPECT_EQ(r.toLinear(0, std::uint8_t{0}), 0.0f);
    EXPECT_FLOAT_EQ(r.toLinear(1, std::uint8_t{255}), 1.0f);
    // Code 128: ((128/255 + 0.055) / 1.055)^2.4 = 0.2158605
    EXPECT_NEAR(r.toLinear(2, std::uint8_t{128}), 0.2158605f, 1e-6f);
    // Linear segment: code 10 -> 10/255/12.92
    EXPECT_NEAR(r.toLinear(0, std::uint8_t{10}), 10.0f / 255.0f / 12.92f, 1e-7f);
}

TEST(ResponseCurve, EncodeInvertsDecodeForEveryKind) {
    std::vector<ResponseCurve> curves{ResponseCurve::srgb(), ResponseCurve::linear(), *ResponseCurve::gamma(1.8),
                                      *ResponseCurve::gamma(2.6)};
    ResponseCurve::Table table{};
    for (int c = 0; c < 3; ++c) {
        for (int code = 0; code < 256; ++code) table[c][code] = std::pow(code / 255.0f, 2.0f + 0.2f * c);
    }
    curves.push_back(*ResponseCurve::fromTable(table, "test table"));
    for (const ResponseCurve& r : curves) {
        for (int c = 0; c < 3; ++c) {
            for (int code = 1; code < 256; code += 7) {
                const float lin = r.toLinear(c, static_cast<std::uint8_t>(code));
                EXPECT_NEAR(r.toEncoded(c, lin) * 255.0f, static_cast<float>(code), 2e-3f) << r.name() << " code " << code;
            }
        }
    }
}

TEST(ResponseCurve, ParsesEveryForm) {
    EXPECT_EQ(ResponseCurve::parse("srgb")->kind(), ResponseCurve::Kind::kSrgb);
    EXPECT_EQ(ResponseCurve::parse("linear")->kind(), ResponseCurve::Kind::kLinear);
    auto g = ResponseCurve::parse("gamma:2.2");
    ASSERT_TRUE(g) << g.error().message;
    EXPECT_EQ(g->kind(), ResponseCurve::Kind::kGamma);
    EXPECT_DOUBLE_EQ(g->gammaValue(), 2.2);
    EXPECT_EQ(g->name(), "gamma:2.2");
}

TEST(ResponseCurve, BadSpecificationsNameTheProblem) {
    auto bad_gamma = ResponseCurve::parse("gamma:abc");
    ASSERT_FALSE(bad_gamma);
    EXPECT_EQ(bad_gamma.error().code, ErrorCode::kBadInput);
    EXPECT_NE(bad_gamma.error().message.find("gamma:abc"), std::string::npos);
    auto out_of_range = ResponseCurve::parse("gamma:9");
    ASSERT_FALSE(out_of_range);
    EXPECT_NE(out_of_range.error().message.find("out of range"), std::string::npos);
    auto nan_gamma = ResponseCurve::gamma(std::nan(""));
    ASSERT_FALSE(nan_gamma);
    auto missing = ResponseCurve::parse("/nonexistent/response.yaml");
    ASSERT_FALSE(missing);
    EXPECT_EQ(missing.error().code, ErrorCode::kNotFound);
    EXPECT_NE(missing.error().message.find("/nonexistent/response.yaml"), std::string::npos);
}

TEST(ResponseCurve, FileRoundTripsAndRelativePathsResolveAgainstTheBase) {
    testing::TempDir dir;
    const ResponseCurve g = *ResponseCurve::gamma(2.6);
    ASSERT_TRUE(g.writeFile(dir / "response.yaml", "test"));
    auto back = ResponseCurve::parse("response.yaml", dir.path());
    ASSERT_TRUE(back) << back.error().message;
    EXPECT_EQ(back->kind(), ResponseCurve::Kind::kTable);
    for (int c = 0; c < 3; ++c) {
        for (int code = 0; code < 256; ++code) {
            EXPECT_FLOAT_EQ(back->toLinear(c, static_cast<std::uint8_t>(code)), g.toLinear(c, static_cast<std::uint8_t>(code)));
        }
    }
}

TEST(ResponseCurve, MalformedFilesAreErrorsNamingFileAndKey) {
    testing::TempDir dir;
    struct Case {
        std::string text;
        std::string expect;
    };
    std::string ramp = "[";
    for (int i = 0; i < 256; ++i) ramp += (i ? ", " : "") + std::to_string(i / 255.0);
    ramp += "]";
    std::string falling = "[";
    for (int i = 0; i < 256; ++i) falling += (i ? ", " : "") + std::to_string(1.0 - i / 255.0);
    falling += "]";
    const std::vector<Case> cases{
        {"response: {type: table, r: [0, 1], g: " + ramp + ", b: " + ramp + "}", "response.r"},
        {"response: {type: table, r: " + ramp + ", g: " + falling + ", b: " + ramp + "}", "decreases"},
        {"response: {type: curve, r: " + ramp + ", g: " + ramp + ", b: " + ramp + "}", "response.type"},
        {"response: {type: table, r: " + ramp + ", g: " + ramp + "}", "response.b"},
        {"respons: {}", "respons"},
        {"response: [1, 2", "response.yaml"},
        {"response: {type: table, r: " + ramp + ", g: " + ramp + ", b: " + ramp + ", extra: 1}", "extra"},
    };
    for (const Case& c : cases) {
        testing::writeText(dir / "response.yaml", c.text);
        auto read = ResponseCurve::readFile(dir / "response.yaml");
        ASSERT_FALSE(read) << c.text;
        EXPECT_EQ(read.error().code, ErrorCode::kBadInput) << read.error().message;
        EXPECT_NE(read.error().message.find(c.expect), std::string::npos) << read.error().message;
        EXPECT_NE(read.error().message.find("response.yaml"), std::string::npos) << read.error().message;
    }
}

}  // namespace
}  // namespace commonlight

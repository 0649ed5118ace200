#include "core/reader_guard.h"

#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include <new>
#include <opencv2/core.hpp>
#include <stdexcept>
#include <string>

namespace commonlight {
namespace {

TEST(ReaderGuard, PassesValuesAndErrorsThrough) {
    const auto ok = guardReader("a.yaml", []() -> Result<int> { return 7; });
    ASSERT_TRUE(ok);
    EXPECT_EQ(*ok, 7);
    const auto failed = guardReader("a.yaml", []() -> Result<int> { return fail(ErrorCode::kNotFound, "x"); });
    ASSERT_FALSE(failed);
    EXPECT_EQ(failed.error().code, ErrorCode::kNotFound);
    EXPECT_EQ(failed.error().message, "x");
}

TEST(ReaderGuard, YamlExceptionBecomesBadInputWithFileAndLine) {
    const auto result = guardReader("dir/calib.yaml", []() -> Result<int> {
        const YAML::Node root = YAML::Load("a: 1\nb: [2, 3]\n");
        return root["b"].as<int>();  // a list read as a number: YAML::TypedBadConversion
    });
    ASSERT_FALSE(result);
    EXPECT_EQ(result.error().code, ErrorCode::kBadInput);
    EXPECT_EQ(result.error().message.rfind("dir/calib.yaml:2:", 0), 0u) << result.error().message;
    EXPECT_NE(result.error().message.find("cannot be read: YAML: bad conversion"), std::string::npos)
        << result.error().message;
}

TEST(ReaderGuard, OpenCvStandardAndUnknownExceptionsBecomeBadInput) {
    const auto cv_error = guardReader("f.png", []() -> Result<void> {
        cv::Mat m(2, 2, CV_8UC1);
        (void)m.reshape(3);  // 4 elements into 3 channels: cv::Exception
        return {};
    });
    ASSERT_FALSE(cv_error);
    EXPECT_EQ(cv_error.error().code, ErrorCode::kBadInput);
    EXPECT_EQ(cv_error.error().message.rfind("f.png: cannot be read: OpenCV: ", 0), 0u) << cv_error.error().message;

    const auto alloc = guardReader("m.glb", []() -> Result<void> { throw std::bad_alloc(); });
    ASSERT_FALSE(alloc);
    EXPECT_EQ(alloc.error().message, "m.glb: cannot be read: it asks for more memory than there is");

    const auto standard = guardReader("m.obj", []() -> Result<void> { throw std::length_error("vector too long"); });
    ASSERT_FALSE(standard);
    EXPECT_EQ(standard.error().message, "m.obj: cannot be read: vector too long");

    const auto unknown = guardReader("m.obj", []() -> Result<void> { throw 42; });
    ASSERT_FALSE(unknown);
    EXPECT_EQ(unknown.error().code, ErrorCode::kBadInput);
    EXPECT_EQ(unknown.error().message, "m.obj: cannot be read: unknown exception");
}

}  // namespace
}  // namespace commonlight

#include "hal/registry.h"

#include <gtest/gtest.h>

#include "tests/hal/fake_camera.h"

namespace commonlight::hal {
namespace {

using testing::FakeCamera;

// What the test wrapper returns: a decorator that remembers its tag, so tests see it was applied.
class TaggedCamera final : public Camera {
public:
    TaggedCamera(std::unique_ptr<Camera> inner, std::string tag)
        : Camera(inner->id()), inner_(std::move(inner)), tag_(std::move(tag)) {}
    const std::string& tag() const { return tag_; }
    Camera& inner() { return *inner_; }

private:
    std::vector<StreamFormat> doFormats() const override { return inner_->formats(); }
    Result<StreamFormat> doConfigure(const StreamConfig& config) override { return inner_->configure(config); }
    Result<void> doStart() override { return {}; }
    void doStop() noexcept override {}
    Result<void> doSetControl(Control control, double value) override { return inner_->setControl(control, value); }
    Result<double> doGetControl(Control control) const override { return inner_->getControl(control); }

    std::unique_ptr<Camera> inner_;
    std::string tag_;
};

Result<std::unique_ptr<Camera>> openFake(const CameraUri& uri) {
    if (uri.path == "missing") return fail(ErrorCode::kNotFound, uri.text + ": no such camera");
    return std::unique_ptr<Camera>(std::make_unique<FakeCamera>(uri.text));
}

Result<std::vector<CameraInfo>> listFakes() {
    return std::vector<CameraInfo>{CameraInfo{"fake:0", "Fake", "fake", {}}, CameraInfo{"fake:1", "Fake", "fake", {}}};
}

Result<std::vector<CameraInfo>> listBroken() { return fail(ErrorCode::kDevice, "broken: bus error"); }

Result<std::unique_ptr<Camera>> wrapTagged(std::unique_ptr<Camera> camera, const CameraUri& uri) {
    const auto tag = uri.option("tag");
    if (tag == "bad") return fail(ErrorCode::kUsage, uri.text + ": bad tag");
    return std::unique_ptr<Camera>(std::make_unique<TaggedCamera>(std::move(camera), std::string(tag.value_or(""))));
}

class Registry : public ::testing::Test {
protected:
    void SetUp() override {
        registry_.add(Backend{"fake", "a fake camera", {"mode"}, openFake, listFakes});
        registry_.add(Backend{"broken", "cannot enumerate", {}, nullptr, listBroken});
        registry_.add(Backend{"quiet", "no enumeration", {}, nullptr, {}});
        registry_.addWrapper(Wrapper{"tag", {"tag", "tag_twice"}, wrapTagged});
    }
    CameraRegistry registry_;
};

TEST_F(Registry, UnknownSchemeListsTheKnownSchemes) {
    const auto camera = registry_.open("gige:cam0");
    ASSERT_FALSE(camera);
    EXPECT_EQ(camera.error().code, ErrorCode::kUsage);
    EXPECT_EQ(camera.error().message,
              "camera URI 'gige:cam0': unknown scheme 'gige' (this build knows: fake:, broken:, quiet:)");
}

TEST_F(Registry, UnknownOptionListsTheAcceptedOptions) {
    const auto camera = registry_.open("fake:0?speed=2");
    ASSERT_FALSE(camera);
    EXPECT_EQ(camera.error().code, ErrorCode::kUsage);
    EXPECT_EQ(camera.error().message,
              "camera URI 'fake:0?speed=2': unknown option 'speed' (fake: accepts width, height, fps, format, "
              "exposure_us, gain, mode, tag, tag_twice)");
}

TEST_F(Registry, CommonBackendAndWrapperOptionsAreAccepted) {
    auto parsed = registry_.parse("fake:0?width=640&mode=x&tag=t&exposure_us=100");
    ASSERT_TRUE(parsed) << parsed.error().message;
    EXPECT_EQ(parsed->options.size(), 4u);
    EXPECT_FALSE(registry_.parse("quiet:0?mode=x")) << "a backend option belongs to its backend only";
}

TEST_F(Registry, AWrapperAppliesOnlyWhenItsOptionIsGiven) {
    auto plain = registry_.open("fake:0");
    ASSERT_TRUE(plain);
    EXPECT_NE(dynamic_cast<FakeCamera*>(plain->get()), nullptr);
    EXPECT_EQ((*plain)->state(), Camera::State::kOpened);

    auto wrapped = registry_.open("fake:0?tag=red");
    ASSERT_TRUE(wrapped) << wrapped.error().message;
    auto* tagged = dynamic_cast<TaggedCamera*>(wrapped->get());
    ASSERT_NE(tagged, nullptr);
    EXPECT_EQ(tagged->tag(), "red");
    EXPECT_EQ(tagged->id(), "fake:0?tag=red");
    EXPECT_NE(dynamic_cast<FakeCamera*>(&tagged->inner()), nullptr);

    auto once = registry_.open("fake:0?tag=a&tag_twice=1");
    ASSERT_TRUE(once);
    auto* outer = dynamic_cast<TaggedCamera*>(once->get());
    ASSERT_NE(outer, nullptr);
    EXPECT_EQ(dynamic_cast<TaggedCamera*>(&outer->inner()), nullptr) << "one wrapper wraps once";
}

TEST_F(Registry, BackendAndWrapperErrorsPassThrough) {
    const auto missing = registry_.open("fake:missing");
    ASSERT_FALSE(missing);
    EXPECT_EQ(missing.error().code, ErrorCode::kNotFound);
    EXPECT_EQ(missing.error().message, "fake:missing: no such camera");
    const auto bad = registry_.open("fake:0?tag=bad");
    ASSERT_FALSE(bad);
    EXPECT_EQ(bad.error().message, "fake:0?tag=bad: bad tag");
    const auto syntax = registry_.open("fake:0?tag");
    ASSERT_FALSE(syntax);
    EXPECT_EQ(syntax.error().code, ErrorCode::kUsage);
}

TEST_F(Registry, OpenConfiguredNegotiatesAndAppliesControls) {
    auto camera = registry_.openConfigured("fake:0?width=320&height=240&fps=60&exposure_us=2000");
    ASSERT_TRUE(camera) << camera.error().message;
    EXPECT_EQ((*camera)->state(), Camera::State::kConfigured);
    EXPECT_EQ((*camera)->activeFormat().width, 320);
    EXPECT_EQ((*camera)->activeFormat().fps, 60.0);
    EXPECT_EQ((*camera)->getControl(Control::kExposureUs).value(), 2000.0)
        << "a camera without auto exposure still gets its exposure";

    const auto wrong = registry_.openConfigured("fake:0?format=rgb8");
    ASSERT_FALSE(wrong);
    EXPECT_EQ(wrong.error().code, ErrorCode::kUnsupported);
    EXPECT_NE(wrong.error().message.find("the device offers:"), std::string::npos);

    const auto gain = registry_.openConfigured("fake:0?gain=2");
    ASSERT_FALSE(gain);
    EXPECT_EQ(gain.error().code, ErrorCode::kUnsupported);

    const auto malformed = registry_.openConfigured("fake:0?width=-5");
    ASSERT_FALSE(malformed);
    EXPECT_EQ(malformed.error().code, ErrorCode::kUsage);
}

TEST_F(Registry, AddingASchemeAgainReplacesIt) {
    registry_.add(Backend{"fake", "replacement", {}, nullptr, {}});
    EXPECT_EQ(registry_.backends().size(), 3u);
    ASSERT_NE(registry_.find("fake"), nullptr);
    EXPECT_EQ(registry_.find("fake")->description, "replacement");
    EXPECT_EQ(registry_.find("nope"), nullptr);
}

TEST_F(Registry, EnumerationCollectsCamerasAndPerBackendErrors) {
    const EnumerationResult result = registry_.enumerate();
    ASSERT_EQ(result.cameras.size(), 2u);
    EXPECT_EQ(result.cameras[1].uri, "fake:1");
    ASSERT_EQ(result.errors.size(), 1u);
    EXPECT_EQ(result.errors[0].message, "broken: bus error");
}

}  // namespace
}  // namespace commonlight::hal

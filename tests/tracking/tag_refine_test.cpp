// Corner refinement from the tags' edges, against the true corners of the bundled sample (the
// desk scene rendered by mocks/sim: corners projected from the true camera pose).
#include <cstdlib>
#include <filesystem>
#include <map>

#include <gtest/gtest.h>

#include "capture/convert.h"
#include "core/frame_file.h"
#include "core/scene_io.h"
#include "core/sequence_io.h"
#include "tracking/tag_detector.h"
#include "tracking/tag_refine.h"

namespace commonlight::tracking {
namespace {

namespace fs = std::filesystem;

fs::path sourceDir() {
    const char* src = std::getenv("COMMONLIGHT_SOURCE_DIR");
    return src ? fs::path(src) : fs::current_path();
}

struct CornerErrors {
    double raw_rms = 0, refined_rms = 0;
    Eigen::Vector2d raw_bias = Eigen::Vector2d::Zero();
    int corners = 0, refused = 0;
    double raw_radial = 0, refined_radial = 0;  // mean outward offset of a corner, pixels
};

CornerErrors measure(double decimate) {
    auto seq = readSequence(sourceDir() / "data/sample");
    auto scene = readScene(sourceDir() / "data/sample/scene.yaml");
    EXPECT_TRUE(seq && scene);
    const CameraModel cam = *seq->sensor.camera;
    std::map<std::int64_t, Rigid3d> truth;
    for (const auto& p : seq->groundtruth_poses) truth[p.timestamp_ns] = p.world_from_cam.inverse();
    TagDetectorOptions options;
    options.decimate = decimate;
    auto detector = TagDetector::create(options);
    EXPECT_TRUE(detector);
    FrameFileReader reader;
    capture::PixelConverter converter;
    Image raw, grey;
    CornerErrors e;
    double raw2 = 0, ref2 = 0;
    for (std::size_t i = 0; i < seq->frames.size(); i += 2) {
        EXPECT_TRUE(reader.read(seq->framePath(i), seq->sensor.pixel_format, 0, 0, raw));
        EXPECT_TRUE(converter.convert(raw.view(), PixelFormat::kGray8, grey));
        auto detections = detector->detect(grey.view());
        EXPECT_TRUE(detections);
        for (const TagDetection& d : *detections) {
            const TagItem* item = scene->tags.find(d.id);
            EXPECT_NE(item, nullptr);
            auto corners = d.corners;
            if (!refineTagCorners(grey.view(), cam, corners)) {
                ++e.refused;
                continue;
            }
            std::array<Eigen::Vector2d, 4> truths;
            Eigen::Vector2d centre = Eigen::Vector2d::Zero();
            for (int k = 0; k < 4; ++k) {
                truths[k] = *cam.project(truth.at(seq->frames[i].timestamp_ns) *
                                         (item->world_from_tag * tagCornerInTag(k, item->size)));
                centre += truths[k] / 4.0;
            }
            for (int k = 0; k < 4; ++k) {
                const Eigen::Vector2d out = (truths[k] - centre).normalized();
                e.raw_radial += out.dot(d.corners[k] - truths[k]);
                e.refined_radial += out.dot(corners[k] - truths[k]);
            }
            for (int k = 0; k < 4; ++k) {
                const auto p = cam.project(truth.at(seq->frames[i].timestamp_ns) *
                                           (item->world_from_tag * tagCornerInTag(k, item->size)));
                raw2 += (d.corners[k] - *p).squaredNorm();
                ref2 += (corners[k] - *p).squaredNorm();
                e.raw_bias += d.corners[k] - *p;
                ++e.corners;
            }
        }
    }
    e.raw_rms = std::sqrt(raw2 / e.corners);
    e.refined_rms = std::sqrt(ref2 / e.corners);
    e.raw_bias /= e.corners;
    e.raw_radial /= e.corners;
    e.refined_radial /= e.corners;
    return e;
}

TEST(TagRefine, RefinedCornersAreCloserToTheTruthThanLibapriltags) {
    for (const double decimate : {1.0, 2.0}) {
        const CornerErrors e = measure(decimate);
        std::printf("  decimate %.0f: %d corners, libapriltag rms %.3f px (mean offset %.3f, %.3f), refined rms %.3f px; "
                    "%d tags refused; mean outward offset %.3f -> %.3f px\n",
                    decimate, e.corners, e.raw_rms, e.raw_bias.x(), e.raw_bias.y(), e.refined_rms, e.refused, e.raw_radial, e.refined_radial);
        EXPECT_GT(e.corners, 100);
        EXPECT_LT(e.refined_rms, 0.7 * e.raw_rms) << "decimate " << decimate;
        EXPECT_LE(e.refused, 2);
    }
}

}  // namespace
}  // namespace commonlight::tracking

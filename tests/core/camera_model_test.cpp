#include "core/camera_model.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

namespace commonlight {
namespace {

CameraModel makeCamera(Distortion d = {}) {
    CameraModel cam;
    cam.width = 1280;
    cam.height = 720;
    cam.fx = 900.0;
    cam.fy = 905.0;
    cam.cx = 641.3;
    cam.cy = 358.7;
    cam.distortion = d;
    return cam;
}

TEST(CameraModel, ProjectUnprojectRoundTripWithoutDistortion) {
    const CameraModel cam = makeCamera();
    const Eigen::Vector3d p(0.3, -0.2, 2.0);
    const auto pixel = cam.project(p);
    ASSERT_TRUE(pixel);
    EXPECT_NEAR(pixel->x(), 900.0 * 0.15 + 641.3, 1e-12);
    EXPECT_NEAR(pixel->y(), 905.0 * -0.1 + 358.7, 1e-12);
    const auto ray = cam.unproject(*pixel);
    ASSERT_TRUE(ray);
    EXPECT_NEAR((*ray * 2.0 - p).norm(), 0.0, 1e-12);
}

TEST(CameraModel, PointsBehindTheCameraDoNotProject) {
    const CameraModel cam = makeCamera();
    EXPECT_FALSE(cam.project({0.0, 0.0, -1.0}));
    EXPECT_FALSE(cam.project({0.1, 0.0, 0.0}));
    EXPECT_FALSE(cam.project({NAN, 0.0, 1.0}));
}

// The hard case: strong barrel distortion, k1 = -0.4, over the whole image.
TEST(CameraModel, UndistortConvergesOnStrongBarrelDistortion) {
    const CameraModel cam = makeCamera({-0.4, 0.12, 0.001, -0.0015, 0.0});
    double worst = 0.0;
    int tested = 0;
    for (int v = 0; v < cam.height; v += 20) {
        for (int u = 0; u < cam.width; u += 20) {
            const Eigen::Vector2d pixel(u, v);
            const auto ideal = cam.undistortPixel(pixel);
            if (!ideal) continue;  // beyond the model's fold: reported, never garbage
            const Eigen::Vector2d back = cam.distortPixel(*ideal);
            worst = std::max(worst, (back - pixel).norm());
            ++tested;
        }
    }
    EXPECT_LT(worst, 1e-6);
    // With these coefficients the whole image lies inside the monotonic region.
    EXPECT_EQ(tested, (cam.height / 20 + (cam.height % 20 ? 1 : 0)) * (cam.width / 20));
}

TEST(CameraModel, UndistortK1MinusPointFourRoundTripsRandomPoints) {
    const CameraModel cam = makeCamera({-0.4, 0.0, 0.0, 0.0, 0.0});
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> coord(-0.9, 0.9);
    const double max_r = cam.maxValidRadius();
    EXPECT_NEAR(max_r, std::sqrt(1.0 / 1.2), 1e-6);  // d/dr r(1 - 0.4 r^2) = 0
    for (int i = 0; i < 2000; ++i) {
        const Eigen::Vector2d xy(coord(rng), coord(rng));
        if (xy.norm() >= max_r * 0.999) continue;
        const auto back = cam.undistortNormalized(cam.distortNormalized(xy));
        ASSERT_TRUE(back) << xy.transpose();
        EXPECT_LT((*back - xy).norm(), 1e-9) << xy.transpose();
    }
}

TEST(CameraModel, UndistortRefusesPointsBeyondTheFold) {
    // r_d = r (1 - 0.4 r^2) peaks at 0.6086; a distorted radius beyond it has no real preimage.
    const CameraModel cam = makeCamera({-0.4, 0.0, 0.0, 0.0, 0.0});
    EXPECT_FALSE(cam.undistortNormalized({0.7, 0.0}));
    EXPECT_FALSE(cam.undistortNormalized({NAN, 0.0}));
    // Projection of a point beyond the fold is refused instead of folding back into the image.
    EXPECT_FALSE(cam.project({1.2, 0.0, 1.0}));
}

// The slope 1 + 3 k1 s + 5 k2 s^2 + 7 k3 s^3 at 64 samples of [0, r2]: radialMonotonicUpTo's definition.
bool sampledMonotonic(const Distortion& d, double r2) {
    for (int i = 1; i <= 64; ++i) {
        const double s = r2 * i / 64;
        if (1.0 + s * (3.0 * d.k1 + s * (5.0 * d.k2 + s * 7.0 * d.k3)) <= 0.0) return false;
    }
    return true;
}

// The slope's lower bound over [0, r2] from its negative terms alone: positive, no sampling needed.
double quickBound(const Distortion& d, double r2) {
    return 1.0 + r2 * (3.0 * std::min(d.k1, 0.0) + r2 * (5.0 * std::min(d.k2, 0.0) + r2 * 7.0 * std::min(d.k3, 0.0)));
}

TEST(CameraModel, MonotonicCheckAgreesWithSamplingTheSlope) {
    // radialMonotonicUpTo answers most calls from a bound without sampling; its answer must be
    // the sampled one (sampledMonotonic()).
    const auto sampled = sampledMonotonic;
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> k(-0.6, 0.6), r2(0.0, 3.0);
    int folded = 0, fast = 0;
    for (int trial = 0; trial < 20000; ++trial) {
        const Distortion d{k(rng), k(rng) * 0.5, 0.0, 0.0, k(rng) * 0.2};
        const CameraModel cam = makeCamera(d);
        const double r = r2(rng);
        ASSERT_EQ(cam.radialMonotonicUpTo(r), sampled(d, r)) << d.k1 << " " << d.k2 << " " << d.k3 << " r2 " << r;
        folded += sampled(d, r) ? 0 : 1;
        fast += quickBound(d, r) > 0.0 ? 1 : 0;
    }
    // Both answers occur, and both paths are taken.
    EXPECT_GT(folded, 1000);
    EXPECT_GT(fast, 1000);
    EXPECT_LT(fast, 19000);
}

// Past the bound, radialMonotonicUpTo answers from the squared radius up to which it proved the
// slope positive, cached per camera: the same answers as sampling, on many radii of one camera,
// near the hard cases: the wide lens (monotonic everywhere), a fold, a slope that touches zero
// (a double root) and one that dips under zero briefly and recovers (which 64 samples of a
// large r2 miss: the cached answer must miss it too).
TEST(CameraModel, CachedMonotonicRadiusGivesTheSampledAnswers) {
    const Distortion cases[] = {{-0.4, 0.12, 0.0005, -0.0008, 0.0}, {-0.4, 0.0, 0.0, 0.0, 0.0},
                                {-0.4, 0.072, 0.0, 0.0, 0.0},       {-0.4, 0.071995, 0.0, 0.0, 0.0},
                                {-0.3, 0.05, 0.0, 0.0, -0.01},      {0.1, -0.2, 0.0, 0.0, 0.03}};
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> r2(0.0, 6.0);
    int folded = 0, past_bound = 0;
    for (const Distortion& d : cases) {
        const CameraModel cam = makeCamera(d);
        std::vector<double> radii = {0.0, 1.0 / 1.2, 1.6667, 1.7, 100.0, 101.0, 1e6, -1.0, NAN};
        for (int k = 0; k < 20000; ++k) radii.push_back(r2(rng));
        for (const double r : radii) {
            ASSERT_EQ(cam.radialMonotonicUpTo(r), sampledMonotonic(d, r)) << d.k1 << " " << d.k2 << " r2 " << r;
            folded += sampledMonotonic(d, r) ? 0 : 1;
            past_bound += quickBound(d, r) > 0.0 ? 0 : 1;
        }
    }
    EXPECT_GT(folded, 10000);
    EXPECT_GT(past_bound, 50000);
    // The narrow dip (k2 = 0.071995: negative for s in 1.653-1.681) is missed by the samples of some radii.
    const Distortion dip{-0.4, 0.071995, 0.0, 0.0, 0.0};
    int missed = 0;
    for (double r = 1.8; r < 6.0; r += 0.01) missed += sampledMonotonic(dip, r) ? 1 : 0;
    EXPECT_GT(missed, 0);
}

// The cache is keyed by the coefficients (the fields are public): a camera whose distortion
// changes answers for the new one; a copy answers as its original; == ignores the cache.
TEST(CameraModel, CachedMonotonicRadiusFollowsTheDistortion) {
    CameraModel cam = makeCamera({-0.4, 0.12, 0.0, 0.0, 0.0});
    const CameraModel fresh = cam;
    EXPECT_TRUE(cam.radialMonotonicUpTo(1.5));  // k2 lifts the slope: monotonic everywhere
    EXPECT_TRUE(cam == fresh);                  // one has its cache filled, the other not
    const CameraModel copy = cam;
    EXPECT_TRUE(copy.radialMonotonicUpTo(1.5));
    cam.distortion.k2 = 0.0;  // folds at r2 = 1 / 1.2
    EXPECT_FALSE(cam.radialMonotonicUpTo(1.5));
    EXPECT_TRUE(cam.radialMonotonicUpTo(0.8));
    EXPECT_FALSE(cam.project({1.2, 0.0, 1.0}));
    EXPECT_TRUE(copy.radialMonotonicUpTo(1.5));
    cam.distortion.k2 = 0.12;
    EXPECT_TRUE(cam.radialMonotonicUpTo(1.5));
    CameraModel assigned;
    assigned = copy;
    EXPECT_TRUE(assigned == copy);
    EXPECT_TRUE(assigned.radialMonotonicUpTo(1.5));
    assigned.distortion.k1 = -0.6;  // 1 - 1.8 s + 0.6 s^2: folds at s = 0.70
    EXPECT_EQ(assigned.radialMonotonicUpTo(1.5), sampledMonotonic(assigned.distortion, 1.5));
    EXPECT_FALSE(assigned.radialMonotonicUpTo(1.5));
}

// Threads share one camera (the tracker and lighting project from several): they fill and read
// its cache at once, and copies are made meanwhile; every answer is the sampled one.
TEST(CameraModel, CachedMonotonicRadiusIsSharedByThreads) {
    for (const Distortion& d : {Distortion{-0.4, 0.12, 0.0, 0.0, 0.0}, Distortion{-0.4, 0.071995, 0.0, 0.0, 0.0}}) {
        const CameraModel cam = makeCamera(d);
        std::vector<int> wrong(4, 0);
        std::vector<std::thread> threads;
        for (int t = 0; t < 4; ++t) {
            threads.emplace_back([&, t] {
                std::mt19937 rng(static_cast<unsigned>(100 + t));
                std::uniform_real_distribution<double> r2(0.0, 4.0);
                for (int k = 0; k < 5000; ++k) {
                    const double r = r2(rng);
                    if (t == 3 && k % 50 == 0) {
                        const CameraModel copy = cam;
                        wrong[3] += copy.radialMonotonicUpTo(r) != sampledMonotonic(d, r) ? 1 : 0;
                    }
                    wrong[static_cast<std::size_t>(t)] += cam.radialMonotonicUpTo(r) != sampledMonotonic(d, r) ? 1 : 0;
                }
            });
        }
        for (std::thread& t : threads) t.join();
        for (int t = 0; t < 4; ++t) EXPECT_EQ(wrong[static_cast<std::size_t>(t)], 0) << "thread " << t;
    }
}

TEST(CameraModel, ValidateRejectsBadIntrinsics) {
    CameraModel cam = makeCamera();
    EXPECT_TRUE(cam.validate());
    cam.fx = 0.0;
    EXPECT_FALSE(cam.validate());
    cam = makeCamera();
    cam.cx = 5000.0;
    auto r = cam.validate();
    ASSERT_FALSE(r);
    EXPECT_NE(r.error().message.find("principal point"), std::string::npos);
    cam = makeCamera({NAN, 0, 0, 0, 0});
    EXPECT_FALSE(cam.validate());
}

TEST(CameraModel, ImageSizeCheckNamesBothSizes) {
    const CameraModel cam = makeCamera();
    EXPECT_TRUE(cam.checkImageSize(1280, 720));
    const auto r = cam.checkImageSize(640, 480);
    ASSERT_FALSE(r);
    EXPECT_EQ(r.error().code, ErrorCode::kBadInput);
    EXPECT_NE(r.error().message.find("640x480"), std::string::npos);
    EXPECT_NE(r.error().message.find("1280x720"), std::string::npos);
}

TEST(CameraModel, ScaledToKeepsRaysOnTheSamePixelCentres) {
    const CameraModel cam = makeCamera();
    const CameraModel half = cam.scaledTo(640, 360);
    const Eigen::Vector3d p(0.1, 0.05, 1.0);
    const Eigen::Vector2d full = *cam.project(p);
    const Eigen::Vector2d small = *half.project(p);
    EXPECT_NEAR((full.x() + 0.5) / 2.0 - 0.5, small.x(), 1e-12);
    EXPECT_NEAR((full.y() + 0.5) / 2.0 - 0.5, small.y(), 1e-12);
}

TEST(CameraModel, GlProjectionMatchesPixelProjection) {
    const CameraModel cam = makeCamera();
    const Eigen::Matrix4d proj = cam.glProjection(0.1, 100.0);
    const Eigen::Vector3d p_in_cam(0.4, -0.3, 3.0);
    const Eigen::Vector4d p_gl(p_in_cam.x(), -p_in_cam.y(), -p_in_cam.z(), 1.0);
    const Eigen::Vector4d clip = proj * p_gl;
    const double x_ndc = clip.x() / clip.w();
    const double y_ndc = clip.y() / clip.w();
    const double u = (x_ndc + 1.0) * 0.5 * cam.width - 0.5;
    const double v = (1.0 - y_ndc) * 0.5 * cam.height - 0.5;
    const Eigen::Vector2d pixel = *cam.project(p_in_cam);
    EXPECT_NEAR(u, pixel.x(), 1e-9);
    EXPECT_NEAR(v, pixel.y(), 1e-9);
    // Depth maps near -> -1 and far -> +1.
    const Eigen::Vector4d near_clip = proj * Eigen::Vector4d(0, 0, -0.1, 1);
    EXPECT_NEAR(near_clip.z() / near_clip.w(), -1.0, 1e-9);
}

}  // namespace
}  // namespace commonlight

// What the cases of `commonlight bench lighting` share (apps/bench_lighting.cpp and
// apps/bench_lighting_incremental.cpp): sequences rendered by mocks/sim and kept between runs, the
// camera frames the estimator sees, and the ratio B/B~ against the simulator's truth.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "apps/bench_lighting.h"
#include "core/camera_model.h"
#include "core/image.h"
#include "core/pose.h"
#include "core/result.h"
#include "core/scene.h"
#include "mocks/sim/embree_scene.h"
#include "mocks/sim/trajectory.h"

namespace commonlight::apps::bench_common {

double luma(const Eigen::Vector3d& v);
double percentile(std::vector<double> v, double p);
std::string fmt(double v, const char* f = "%.2f");

// A rendered sequence with its truth: linear radiance with and without the virtual objects, the
// simulator's masks, the poses.
struct SimSequence {
    CameraModel camera;
    std::vector<Rigid3d> world_from_cam;
    std::vector<cv::Mat> radiance;    // CV_32FC3, RGB, W/(m^2 sr)
    std::vector<cv::Mat> composite;   // same, with the virtual objects
    std::vector<cv::Mat> changed;     // CV_8U: 255 where the virtual objects change real surfaces by > 1%
    std::vector<cv::Mat> virtual_coverage;  // CV_8U: 0..255 fraction of samples on a virtual object
};

// Renders the scene file along the trajectory file once into options.data_dir (kept for later runs)
// at options.width and options.spp, then reads it.
Result<SimSequence> renderOrLoad(const std::filesystem::path& scene_file, const std::filesystem::path& trajectory_file,
                                 const BenchLightingOptions& o, const std::string& name, int frames);
// The same for a scene and trajectory in memory, into `dir`.
Result<SimSequence> renderOrLoadScene(const Scene& truth, const mocks::sim::Trajectory& trajectory, const CameraModel& camera, int spp,
                                      const std::filesystem::path& dir, const std::string& name, int frames);

// The camera the estimator sees: linear radiance x scale, multiplicative Gaussian noise, clipped,
// sRGB-encoded to 8 bits.
Image encodeFrame(const cv::Mat& radiance, double scale, double noise, std::uint64_t seed);
// A scale that puts the 99.9th percentile of the frame's luminance at 0.85 of full scale.
double exposureFor(const cv::Mat& radiance);

// The truth's ratio composite / plain (luminance) over the bounding box of masks/changed of frame
// `frame`, path-traced again at `spp` with another seed (NaN outside the box).
Result<cv::Mat> referenceRatio(const mocks::sim::SimScene& plain, const mocks::sim::SimScene& composite, const SimSequence& seq,
                               std::size_t frame, int spp);

// Ratio error over masks/changed, pixels not on a virtual object: the predicted B/B~ (luminance)
// against the truth's composite / plain radiance.
struct RatioError {
    std::vector<double> errors;  // predicted - true, per pixel
    void add(const Image& predicted, const cv::Mat& plain, const cv::Mat& composite, const cv::Mat& changed,
             const cv::Mat& coverage);
    double rms() const;
    double mean() const;
};

}  // namespace commonlight::apps::bench_common

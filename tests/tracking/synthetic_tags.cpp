#include "tests/tracking/synthetic_tags.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

#include "mocks/sim/sensor.h"
#include "mocks/sim/tag_texture.h"

namespace commonlight::tracking::testing {
namespace {

// Adds the tags' linear albedo image (the background elsewhere) to `sum`.
void accumulate(const CameraModel& cam, const std::vector<SyntheticTag>& tags, const SyntheticImageOptions& o,
                cv::Mat& sum) {
    cv::Mat linear(cam.height, cam.width, CV_32F, cv::Scalar(o.background));
    for (const SyntheticTag& placed : tags) {
        auto texture = mocks::sim::TagTexture::make("tag36h11", placed.id);
        if (!texture) throw std::runtime_error("no tag36h11 texture for id " + std::to_string(placed.id));
        mocks::sim::PlacedTag tag;
        tag.texture = *texture;
        tag.size = placed.size;
        tag.half_extent = 0.5 * placed.size / texture->widthAtBorder() * texture->totalWidth();
        const Rigid3d tag_from_cam = placed.cam_from_tag.inverse();
        // Only the pixels around the printed square are traced.
        Eigen::AlignedBox2d box;
        for (const double x : {-tag.half_extent, tag.half_extent}) {
            for (const double y : {-tag.half_extent, tag.half_extent}) {
                const Eigen::Vector3d p = placed.cam_from_tag * Eigen::Vector3d(x, y, 0);
                if (p.z() <= 0) throw std::runtime_error("a synthetic tag behind the camera");
                box.extend(Eigen::Vector2d(cam.fx * p.x() / p.z() + cam.cx, cam.fy * p.y() / p.z() + cam.cy));
            }
        }
        const int u0 = std::max(0, static_cast<int>(box.min().x()) - 3);
        const int u1 = std::min(cam.width, static_cast<int>(box.max().x()) + 4);
        const int v0 = std::max(0, static_cast<int>(box.min().y()) - 3);
        const int v1 = std::min(cam.height, static_cast<int>(box.max().y()) + 4);
        const int n = o.supersample;
        for (int v = v0; v < v1; ++v) {
            for (int u = u0; u < u1; ++u) {
                double acc = 0;
                int hits = 0;
                for (int sy = 0; sy < n; ++sy) {
                    for (int sx = 0; sx < n; ++sx) {
                        const Eigen::Vector3d ray((u - 0.5 + (sx + 0.5) / n - cam.cx) / cam.fx,
                                                  (v - 0.5 + (sy + 0.5) / n - cam.cy) / cam.fy, 1.0);
                        const Eigen::Vector3d origin = tag_from_cam.translation;
                        const Eigen::Vector3d dir = tag_from_cam.rotation * ray;
                        const double lambda = -origin.z() / dir.z();
                        const Eigen::Vector3d p = origin + lambda * dir;
                        if (lambda > 0 && tag.contains(p.x(), p.y())) {
                            acc += tag.albedoAt(p.x(), p.y());
                            ++hits;
                        }
                    }
                }
                float& px = linear.at<float>(v, u);
                px = static_cast<float>((acc + (n * n - hits) * px) / (n * n));
            }
        }
    }
    sum += linear;
}

Image encode(const CameraModel& cam, cv::Mat linear, const SyntheticImageOptions& o) {
    if (o.blur_sigma_px > 0) cv::GaussianBlur(linear, linear, cv::Size(0, 0), o.blur_sigma_px);
    cv::Mat noise(cam.height, cam.width, CV_32F, cv::Scalar(0));
    if (o.noise_sigma > 0) {
        cv::RNG rng(o.seed);
        rng.fill(noise, cv::RNG::NORMAL, 0.0, o.noise_sigma);
    }
    Image out(PixelFormat::kGray8, cam.width, cam.height);
    for (int v = 0; v < cam.height; ++v) {
        for (int u = 0; u < cam.width; ++u) {
            // Exposed so that white (albedo 0.8) is at 90 % of full scale.
            const double value = mocks::sim::applyResponse(mocks::sim::SensorResponse::kSrgb,
                                                           std::clamp(0.9 / 0.8 * linear.at<float>(v, u), 0.0, 1.0));
            const double grey = std::clamp(255.0 * value + noise.at<float>(v, u), 0.0, 255.0);
            out.data()[v * out.stride() + u] = static_cast<std::uint8_t>(std::lround(grey));
        }
    }
    return out;
}

}  // namespace

CameraModel syntheticCamera() {
    CameraModel cam;
    cam.width = 640;
    cam.height = 480;
    cam.fx = cam.fy = 500;
    cam.cx = 319.5;
    cam.cy = 239.5;
    return cam;
}

Image renderSyntheticTags(const CameraModel& camera, const std::vector<SyntheticTag>& tags,
                          const SyntheticImageOptions& options) {
    cv::Mat sum(camera.height, camera.width, CV_32F, cv::Scalar(0));
    accumulate(camera, tags, options, sum);
    return encode(camera, sum, options);
}

Image renderSyntheticTagsBlurred(const CameraModel& camera,
                                 const std::function<std::vector<SyntheticTag>(double)>& tags_at, int time_samples,
                                 const SyntheticImageOptions& options) {
    cv::Mat sum(camera.height, camera.width, CV_32F, cv::Scalar(0));
    for (int k = 0; k < time_samples; ++k) accumulate(camera, tags_at((k + 0.5) / time_samples), options, sum);
    sum /= static_cast<double>(time_samples);
    return encode(camera, sum, options);
}

void addForeshortenedGrid(TagSet& tags, double turn0_deg, double turn_step_deg, double size0, double size_step) {
    for (int k = 0; k < 8; ++k) {
        const double turn = (turn0_deg + turn_step_deg * (k % 3)) * std::numbers::pi / 180.0;
        const Eigen::Quaterniond q(Eigen::AngleAxisd(turn, Eigen::Vector3d::UnitY()));
        tags.items.push_back({30 + k, size0 + size_step * k,
                              Rigid3d(q, Eigen::Vector3d(-0.18 + 0.12 * (k % 4), k < 4 ? -0.12 : 0.12, 0)), 0.04, 0.8});
    }
}

}  // namespace commonlight::tracking::testing

// Draws the bundled sample sequence (data/sample): a table with a 2x2 board of AprilTags
// (tag36h11, drawn by libapriltag) in a room corner, seen by a slowly panning 640x480 camera
// with mild barrel distortion, sensor noise and JPEG frames as an MJPEG webcam delivers them.
// Ground truth camera poses and the scene file are written beside the frames.
//
// It ray-casts every pixel through CameraModel::unproject, so lens distortion is exact. This is
// a stand-in until the physically based simulated camera (mocks/sim) renders the sample.
//
// Usage: commonlight-make-sample OUT_DIR [--frames N]
#include <apriltag/apriltag.h>
#include <apriltag/tag36h11.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <numbers>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>

#include "core/camera_model.h"
#include "core/file_util.h"
#include "core/pose.h"
#include "core/sequence_io.h"
#include "core/sequence_writer.h"

namespace {

using namespace commonlight;
using Eigen::Vector2d;
using Eigen::Vector3d;

constexpr int kWidth = 640;
constexpr int kHeight = 480;
constexpr double kTagSize = 0.08;      // edge of the black square, metres
constexpr double kTagPitch = 0.12;     // centre-to-centre on the board
constexpr double kTableHeight = 0.75;  // table top, metres

struct TagTexture {
    int id = 0;
    Rigid3d world_from_tag;
    std::vector<std::uint8_t> cells;  // total_width^2, 0 = black, 255 = white
    int total_width = 0;
    int width_at_border = 0;
};

std::vector<TagTexture> makeTags() {
    apriltag_family_t* family = tag36h11_create();  // owned here, destroyed below
    std::vector<TagTexture> tags;
    for (int id = 0; id < 4; ++id) {
        image_u8_t* image = apriltag_to_image(family, id);  // owned here; image_u8_destroy is not exported
        TagTexture tag;
        tag.id = id;
        tag.total_width = image->width;
        tag.width_at_border = family->width_at_border;
        for (int y = 0; y < image->height; ++y) {
            for (int x = 0; x < image->width; ++x) tag.cells.push_back(image->buf[y * image->stride + x]);
        }
        std::free(image->buf);
        std::free(image);
        const double x = (id % 2 == 0 ? -0.5 : 0.5) * kTagPitch;
        const double y = (id < 2 ? 0.5 : -0.5) * kTagPitch;
        tag.world_from_tag = Rigid3d::fromRpyDeg({x, y + 0.05, kTableHeight + 0.0005}, {0, 0, 0});
        tags.push_back(std::move(tag));
    }
    tag36h11_destroy(family);
    return tags;
}

// Linear albedo of a world point on the table top (tags, else the table's wood colour).
Vector3d tableAlbedo(const Vector3d& p_in_world, const std::vector<TagTexture>& tags) {
    for (const auto& tag : tags) {
        const Vector3d p = tag.world_from_tag.inverse() * p_in_world;
        const double cell = kTagSize / tag.width_at_border;
        const double half = 0.5 * cell * tag.total_width;
        if (std::abs(p.x()) < half && std::abs(p.y()) < half) {
            const int col = static_cast<int>((p.x() + half) / cell);
            const int row = static_cast<int>((half - p.y()) / cell);  // image top edge towards +y
            const bool white = tag.cells[row * tag.total_width + col] > 127;
            return Vector3d::Constant(white ? 0.8 : 0.04);
        }
    }
    // Faint grain so the table is not a flat colour.
    const double grain = 0.015 * std::sin(p_in_world.x() * 90.0 + 3.0 * std::sin(p_in_world.y() * 20.0));
    return Vector3d(0.45 + grain, 0.32 + grain, 0.2);
}

struct Hit {
    double distance = 0.0;
    Vector3d albedo;
    Vector3d normal;
};

// Intersects a camera ray with the proxy geometry: floor z = 0, back wall y = 1.2, side wall
// x = -1.5, and the table top (1.2 x 0.8 at kTableHeight, centred at the origin).
std::optional<Hit> castRay(const Vector3d& origin, const Vector3d& dir, const std::vector<TagTexture>& tags) {
    std::optional<Hit> best;
    auto consider = [&](double t, const Vector3d& albedo, const Vector3d& normal) {
        if (t > 1e-6 && (!best || t < best->distance)) best = Hit{t, albedo, normal};
    };
    if (std::abs(dir.z()) > 1e-12) {
        const double t_table = (kTableHeight - origin.z()) / dir.z();
        const Vector3d p = origin + t_table * dir;
        if (std::abs(p.x()) <= 0.6 && std::abs(p.y()) <= 0.4) consider(t_table, tableAlbedo(p, tags), Vector3d::UnitZ());
        const double t_floor = -origin.z() / dir.z();
        const Vector3d f = origin + t_floor * dir;
        const bool tile = (static_cast<int>(std::floor(f.x() / 0.3)) + static_cast<int>(std::floor(f.y() / 0.3))) % 2 == 0;
        consider(t_floor, Vector3d::Constant(tile ? 0.35 : 0.3), Vector3d::UnitZ());
    }
    if (std::abs(dir.y()) > 1e-12) consider((1.2 - origin.y()) / dir.y(), Vector3d(0.7, 0.68, 0.62), -Vector3d::UnitY());
    if (std::abs(dir.x()) > 1e-12) consider((-1.5 - origin.x()) / dir.x(), Vector3d(0.6, 0.65, 0.7), Vector3d::UnitX());
    return best;
}

std::uint8_t encodeSrgb(double linear) {
    linear = std::clamp(linear, 0.0, 1.0);
    const double s = linear <= 0.0031308 ? 12.92 * linear : 1.055 * std::pow(linear, 1.0 / 2.4) - 0.055;
    return static_cast<std::uint8_t>(std::lround(s * 255.0));
}

Rigid3d lookAt(const Vector3d& eye, const Vector3d& target) {
    const Vector3d z = (target - eye).normalized();
    const Vector3d x = z.cross(Vector3d::UnitZ()).normalized();
    const Vector3d y = z.cross(x);
    Eigen::Matrix3d r;
    r.col(0) = x;
    r.col(1) = y;
    r.col(2) = z;
    return {Eigen::Quaterniond(r), eye};  // world_from_cam
}

std::string sceneYaml(const std::vector<TagTexture>& tags) {
    std::string s =
        "# The bundled sample: a table with a 2x2 AprilTag board in a room corner (docs/formats-scene.md).\n"
        "tags:\n  family: tag36h11\n  items:\n";
    char line[256];
    for (const auto& tag : tags) {
        const auto& t = tag.world_from_tag.translation;
        std::snprintf(line, sizeof(line), "    - {id: %d, size: %.3f, world_from_tag: {t: [%.4f, %.4f, %.4f], rpy_deg: [0, 0, 0]}}\n",
                      tag.id, kTagSize, t.x(), t.y(), t.z());
        s += line;
    }
    s +=
        "real:\n"
        "  - {name: floor, plane: {size: [4, 4]}, world_from_object: {t: [0, 0, 0]}, albedo: estimate}\n"
        "  - {name: back_wall, plane: {size: [4, 3]}, world_from_object: {t: [0, 1.2, 1.5], rpy_deg: [90, 0, 0]}, albedo: estimate}\n"
        "  - {name: side_wall, plane: {size: [4, 3]}, world_from_object: {t: [-1.5, 0, 1.5], rpy_deg: [0, 90, 0]}, albedo: estimate}\n"
        "  - {name: table, box: {size: [1.2, 0.8, 0.75]}, world_from_object: {t: [0, 0, 0.375]}, albedo: estimate}\n"
        "lights:\n"
        "  - {name: sun, directional: {direction: [0.3, 0.4, -0.866]}, irradiance: estimate}\n";
    return s;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc < 2) {
        std::fprintf(stderr, "usage: %s OUT_DIR [--frames N]\n", argv[0]);
        return 2;
    }
    const std::filesystem::path out = argv[1];
    int frames = 60;
    if (argc == 4 && std::string(argv[2]) == "--frames") frames = std::atoi(argv[3]);
    if (frames <= 0) {
        std::fprintf(stderr, "--frames must be positive\n");
        return 2;
    }

    CameraModel cam;
    cam.width = kWidth;
    cam.height = kHeight;
    cam.fx = 525.0;
    cam.fy = 525.0;
    cam.cx = 319.5;
    cam.cy = 239.5;
    cam.distortion = {-0.08, 0.02, 0.0, 0.0, 0.0};

    SensorInfo sensor;
    sensor.rate_hz = 30.0;
    sensor.camera = cam;
    sensor.comment = "commonlight sample: drawn with OpenCV and libapriltag (apps/tools/make_sample_sequence.cpp)";
    auto writer = SequenceWriter::create(out, sensor, {.sync = false});
    if (!writer) {
        std::fprintf(stderr, "%s\n", writer.error().message.c_str());
        return 3;
    }

    const std::vector<TagTexture> tags = makeTags();
    const Vector3d light_dir = -Vector3d(0.3, 0.4, -0.866).normalized();  // towards the light
    std::mt19937 rng(1234);
    std::normal_distribution<double> noise(0.0, 1.5);  // DN
    std::vector<PoseRecord> poses;
    cv::Mat rgb(kHeight, kWidth, CV_8UC3);
    std::vector<std::uint8_t> jpeg;
    const std::int64_t t0 = 1'700'000'000'000'000'000;
    constexpr int kSuper = 2;  // 2x2 samples per pixel

    for (int i = 0; i < frames; ++i) {
        const double phase = frames > 1 ? static_cast<double>(i) / (frames - 1) : 0.0;
        const double angle = (-12.0 + 24.0 * phase) * std::numbers::pi / 180.0;
        const Vector3d target(0.0, 0.05, kTableHeight);
        const Vector3d eye = target + Vector3d(0.75 * std::sin(angle), -0.75 * std::cos(angle), 0.55);
        const Rigid3d world_from_cam = lookAt(eye, target);
        const std::int64_t timestamp = t0 + static_cast<std::int64_t>(i) * 33'333'333;
        poses.push_back({timestamp, world_from_cam});

        for (int v = 0; v < kHeight; ++v) {
            auto* row = rgb.ptr<std::uint8_t>(v);
            for (int u = 0; u < kWidth; ++u) {
                Vector3d sum = Vector3d::Zero();
                for (int s = 0; s < kSuper * kSuper; ++s) {
                    const Vector2d pixel(u - 0.25 + 0.5 * (s % kSuper), v - 0.25 + 0.5 * (s / kSuper));
                    const auto ray = cam.unproject(pixel);
                    if (!ray) continue;
                    const Vector3d dir = world_from_cam.rotation * ray->normalized();
                    const auto hit = castRay(world_from_cam.translation, dir, tags);
                    if (!hit) continue;
                    const double shade = 0.35 + 0.65 * std::max(0.0, hit->normal.dot(light_dir));
                    sum += hit->albedo * shade;
                }
                const Vector3d linear = sum / (kSuper * kSuper);
                for (int c = 0; c < 3; ++c) {
                    const double dn = encodeSrgb(linear[2 - c]) + noise(rng);  // BGR for OpenCV
                    row[3 * u + c] = static_cast<std::uint8_t>(std::clamp(std::lround(dn), 0L, 255L));
                }
            }
        }
        cv::imencode(".jpg", rgb, jpeg, {cv::IMWRITE_JPEG_QUALITY, 95});
        Image frame;
        frame.reshapeCompressed(kWidth, kHeight, jpeg.size());
        std::copy(jpeg.begin(), jpeg.end(), frame.data());
        FrameMetadata meta;
        meta.timestamp_ns = timestamp;
        meta.sequence = static_cast<std::uint64_t>(i);
        meta.exposure_us = 10000.0;
        meta.analog_gain = 1.0;
        if (auto r = writer->write(frame, meta); !r) {
            std::fprintf(stderr, "%s\n", r.error().message.c_str());
            return 3;
        }
        std::fprintf(stderr, "\rframe %d/%d", i + 1, frames);
    }
    std::fprintf(stderr, "\n");
    std::filesystem::create_directories(out / "groundtruth");
    if (auto r = writePosesCsv(out / "groundtruth" / "cam_poses.csv", poses); !r) {
        std::fprintf(stderr, "%s\n", r.error().message.c_str());
        return 3;
    }
    if (auto r = writeTextFileAtomic(out / "scene.yaml", sceneYaml(tags)); !r) {
        std::fprintf(stderr, "%s\n", r.error().message.c_str());
        return 3;
    }
    std::printf("wrote %d frames to %s\n", frames, out.c_str());
    return 0;
}

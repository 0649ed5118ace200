#include "render/light_samples.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include <Eigen/Geometry>

namespace commonlight::render {

namespace {

// A look-at view matrix (GL camera: looks along -z).
Eigen::Matrix4d lookAt(const Eigen::Vector3d& eye, const Eigen::Vector3d& target) {
    const Eigen::Vector3d f = (target - eye).normalized();
    Eigen::Vector3d up = std::abs(f.z()) < 0.9 ? Eigen::Vector3d::UnitZ() : Eigen::Vector3d::UnitX();
    const Eigen::Vector3d s = f.cross(up).normalized();
    const Eigen::Vector3d u = s.cross(f);
    Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
    m.row(0).head<3>() = s;
    m.row(1).head<3>() = u;
    m.row(2).head<3>() = -f;
    m(0, 3) = -s.dot(eye);
    m(1, 3) = -u.dot(eye);
    m(2, 3) = f.dot(eye);
    return m;
}

Eigen::Matrix4d perspective(double half_angle, double near_m, double far_m) {
    const double f = 1.0 / std::tan(half_angle);
    Eigen::Matrix4d p = Eigen::Matrix4d::Zero();
    p(0, 0) = f;
    p(1, 1) = f;
    p(2, 2) = -(far_m + near_m) / (far_m - near_m);
    p(2, 3) = -2.0 * far_m * near_m / (far_m - near_m);
    p(3, 2) = -1.0;
    return p;
}

Eigen::Matrix4d orthographic(double half, double near_m, double far_m) {
    Eigen::Matrix4d p = Eigen::Matrix4d::Identity();
    p(0, 0) = 1.0 / half;
    p(1, 1) = 1.0 / half;
    p(2, 2) = -2.0 / (far_m - near_m);
    p(2, 3) = -(far_m + near_m) / (far_m - near_m);
    return p;
}

}  // namespace

Eigen::Matrix4f toGl(const Rigid3d& pose) {
    Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
    m.topLeftCorner<3, 3>() = pose.rotation.toRotationMatrix();
    m.topRightCorner<3, 1>() = pose.translation;
    return m.cast<float>();
}

std::vector<LightSample> lightSamples(const lighting::LightingSnapshot& snapshot, int per_area) {
    std::vector<LightSample> samples;
    const double scale = snapshot.radiance_scale > 0.0 && std::isfinite(snapshot.radiance_scale) ? snapshot.radiance_scale : 1.0;
    per_area = std::clamp(per_area, 1, 8);
    for (const lighting::EstimatedLight& light : snapshot.lights) {
        if (!light.emission.allFinite() || light.emission.maxCoeff() <= 0.0) continue;
        const Eigen::Vector3d power = light.emission * scale;
        const Eigen::Matrix3d r = light.world_from_object.rotation.toRotationMatrix();
        if (light.kind == lighting::LightKind::kDirectional) {
            LightSample s;
            s.kind = 2;
            s.axis = light.direction.normalized();
            s.power = power;
            samples.push_back(s);
        } else if (light.kind == lighting::LightKind::kPoint) {
            LightSample s;
            s.kind = 1;
            s.position = light.world_from_object.translation;
            s.power = power;
            samples.push_back(s);
        } else {
            const bool disc = light.kind == lighting::LightKind::kDisc;
            const double area = disc ? std::numbers::pi * light.radius * light.radius : light.size.x() * light.size.y();
            const int grid = static_cast<int>(std::ceil(std::sqrt(static_cast<double>(per_area))));
            for (int k = 0; k < per_area; ++k) {
                Eigen::Vector3d local = Eigen::Vector3d::Zero();
                if (disc) {
                    const double rr = light.radius * std::sqrt((k + 0.5) / per_area);
                    const double phi = k * 2.399963229728653;  // golden angle
                    local = Eigen::Vector3d(rr * std::cos(phi), rr * std::sin(phi), 0.0);
                } else {
                    const int gx = k % grid, gy = k / grid;
                    const int rows = (per_area + grid - 1) / grid;
                    local = Eigen::Vector3d(((gx + 0.5) / grid - 0.5) * light.size.x(), ((gy + 0.5) / rows - 0.5) * light.size.y(), 0.0);
                }
                LightSample s;
                s.kind = 0;
                s.position = light.world_from_object.rotation * local + light.world_from_object.translation;
                s.axis = r.col(2);
                s.power = power * (area / per_area);
                s.radius = std::sqrt(area / (per_area * std::numbers::pi));
                samples.push_back(s);
            }
        }
        if (static_cast<int>(samples.size()) >= kMaxLightSamples) break;
    }
    if (static_cast<int>(samples.size()) > kMaxLightSamples) samples.resize(kMaxLightSamples);
    return samples;
}

Eigen::Matrix4f shadowView(const LightSample& s, const Eigen::Vector3d& centre, double radius) {
    radius = std::max(radius, 1e-3);
    Eigen::Matrix4d vp;
    if (s.kind == 2) {
        const double back = radius + 10.0;
        vp = orthographic(radius * 1.05, 0.0, back + radius * 1.05) * lookAt(centre - s.axis * back, centre);
    } else {
        const double dist = (centre - s.position).norm();
        if (dist > radius * 1.05) {
            // The sphere, seen from the light; nothing beyond its far side can shadow it.
            const double half = std::asin(std::min(0.99, radius * 1.05 / dist));
            vp = perspective(half, std::max(0.01, 0.02 * dist), dist + 1.05 * radius) * lookAt(s.position, centre);
        } else {
            // Hard case: the light is among the objects. A wide frustum along its axis (area,
            // disc) or towards the objects (point).
            Eigen::Vector3d axis = s.kind == 0 ? s.axis
                                               : (dist > 1e-6 ? Eigen::Vector3d(centre - s.position) : Eigen::Vector3d(-Eigen::Vector3d::UnitZ()));
            axis.normalize();
            vp = perspective(75.0 * std::numbers::pi / 180.0, 0.01, dist + 2.0 * radius) * lookAt(s.position, s.position + axis);
        }
    }
    return vp.cast<float>();
}

void fitShadowViews(std::vector<LightSample>& samples, const Eigen::Vector3d& vmin, const Eigen::Vector3d& vmax) {
    const Eigen::Vector3d centre = 0.5 * (vmin + vmax);
    const double radius = std::max(0.5 * (vmax - vmin).norm(), 1e-3);
    int layers = 0;
    for (LightSample& s : samples) {
        s.view_proj = shadowView(s, centre, radius);
        s.layer = layers++;
    }
}

int virtualShadowMapSize(double footprint_px, int current, int max_size) {
    const double needed = footprint_px;
    if (!(needed < static_cast<double>(max_size))) return max_size;
    if (current >= 64 && current <= max_size && current >= needed && current <= 2.5 * needed) return current;
    int size = 64;
    while (size < needed && size < max_size) size *= 2;
    return std::min(size, max_size);
}

}  // namespace commonlight::render

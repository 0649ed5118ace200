#include "mocks/sim/lights.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <variant>

#include "mocks/sim/sampling.h"

namespace commonlight::mocks::sim {

namespace {

constexpr double kMinPdf = 1e-12;
// Below this cosine (about 0.00006 degrees from grazing) an area light's density is treated as
// unsampleable; the light then carries nothing in that direction, which is its limit anyway.
constexpr double kMinCos = 1e-9;

Result<Eigen::Vector3d> trueEmission(const Light& light) {
    if (light.emission.isEstimate()) {
        return fail(ErrorCode::kBadInput, "light '" + light.name + "': " + emissionKey(light.shape) +
                                              " is 'estimate'; the simulated camera needs its true value");
    }
    const Eigen::Vector3d& value = *light.emission.value;
    if (!value.allFinite() || value.minCoeff() < 0.0) {
        return fail(ErrorCode::kBadInput,
                    "light '" + light.name + "': " + emissionKey(light.shape) + " must be finite and >= 0");
    }
    return value;
}

}  // namespace

Result<std::vector<SimLight>> makeSimLights(const Scene& scene) {
    std::vector<SimLight> lights;
    for (std::size_t i = 0; i < scene.lights.size(); ++i) {
        const Light& light = scene.lights[i];
        if (std::holds_alternative<DistantLightShape>(light.shape)) continue;
        CL_TRY(const Eigen::Vector3d emission, trueEmission(light));
        SimLight out;
        out.name = light.name;
        out.scene_index = static_cast<int>(i);
        out.emission = emission;
        const Eigen::Matrix3d r = light.world_from_object.rotationMatrix();
        out.position = light.world_from_object.translation;
        out.normal = r.col(2);
        if (const auto* rect = std::get_if<AreaLightShape>(&light.shape)) {
            out.kind = LightKind::kRectangle;
            out.half_x = 0.5 * rect->size.x() * r.col(0);
            out.half_y = 0.5 * rect->size.y() * r.col(1);
            out.area = rect->size.x() * rect->size.y();
            if (!(out.area > 0.0)) continue;  // zero area: no power, nothing to hit
        } else if (const auto* disc = std::get_if<DiscLightShape>(&light.shape)) {
            out.kind = LightKind::kDisc;
            out.half_x = disc->radius * r.col(0);
            out.half_y = disc->radius * r.col(1);
            out.area = std::numbers::pi * disc->radius * disc->radius;
            if (!(out.area > 0.0)) continue;
        } else if (std::holds_alternative<PointLightShape>(light.shape)) {
            out.kind = LightKind::kPoint;
        } else if (const auto* directional = std::get_if<DirectionalLightShape>(&light.shape)) {
            out.kind = LightKind::kDirectional;
            const double norm = directional->direction.norm();
            if (!(norm > 0.0) || !std::isfinite(norm)) {
                return fail(ErrorCode::kBadInput, "light '" + light.name + "': direction must be a nonzero vector");
            }
            out.direction = directional->direction / norm;
        }
        lights.push_back(std::move(out));
    }
    return lights;
}

Result<Eigen::Vector3d> makeEnvironmentRadiance(const Scene& scene) {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    for (const Light& light : scene.lights) {
        if (!std::holds_alternative<DistantLightShape>(light.shape)) continue;
        CL_TRY(const Eigen::Vector3d emission, trueEmission(light));
        sum += emission;
    }
    return sum;
}

namespace {

// Solid-angle sampling of a rectangle seen from a point (Urena, Fajardo and King 2013, "An
// area-preserving parametrization for spherical rectangles"): the rectangle's projection on the
// unit sphere around p is sampled uniformly, density 1 / S. Far better than uniform-by-area for
// points close to a large light, where 1/d^2 and the light's cosine vary strongly over it.
struct SphericalRectangle {
    Eigen::Vector3d x, y, z;  // local frame: along the rectangle's edges, z towards the rectangle's plane's far side
    double x0 = 0, x1 = 0, y0 = 0, y1 = 0, z0 = 0;  // the rectangle in that frame, relative to p (z0 < 0)
    double b0 = 0, b1 = 0, k = 0;                   // constants of the parametrization
    double solid_angle = 0;                         // S, steradians
};

// Below this solid angle the spherical parametrization loses precision (S is a small difference
// of angles near 2 pi); such lights are far away and uniform-by-area sampling is nearly as good.
constexpr double kMinSolidAngle = 1e-5;

std::optional<SphericalRectangle> sphericalRectangle(const SimLight& light, const Eigen::Vector3d& p) {
    const Eigen::Vector3d ex = 2.0 * light.half_x;
    const Eigen::Vector3d ey = 2.0 * light.half_y;
    const double ex_len = ex.norm();
    const double ey_len = ey.norm();
    SphericalRectangle r;
    r.x = ex / ex_len;
    r.y = ey / ey_len;
    r.z = r.x.cross(r.y);
    const Eigen::Vector3d d = light.position - light.half_x - light.half_y - p;  // to the corner
    r.x0 = d.dot(r.x);
    r.y0 = d.dot(r.y);
    r.z0 = d.dot(r.z);
    if (r.z0 > 0.0) {
        r.z = -r.z;
        r.z0 = -r.z0;
    }
    // Hard case: p in (or within rounding of) the light's plane sees no solid angle.
    if (!(r.z0 < -1e-12 * std::max(1.0, d.norm()))) return std::nullopt;
    r.x1 = r.x0 + ex_len;
    r.y1 = r.y0 + ey_len;
    const Eigen::Vector3d v00(r.x0, r.y0, r.z0), v01(r.x0, r.y1, r.z0), v10(r.x1, r.y0, r.z0), v11(r.x1, r.y1, r.z0);
    // Normals of the planes through p and each edge (pointing inwards).
    const Eigen::Vector3d n0 = v00.cross(v10).normalized();
    const Eigen::Vector3d n1 = v10.cross(v11).normalized();
    const Eigen::Vector3d n2 = v11.cross(v01).normalized();
    const Eigen::Vector3d n3 = v01.cross(v00).normalized();
    const auto angle = [](const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
        return std::acos(std::clamp(-a.dot(b), -1.0, 1.0));
    };
    const double g0 = angle(n0, n1);
    const double g1 = angle(n1, n2);
    const double g2 = angle(n2, n3);
    const double g3 = angle(n3, n0);
    r.b0 = n0.z();
    r.b1 = n2.z();
    r.k = 2.0 * std::numbers::pi - g2 - g3;
    r.solid_angle = g0 + g1 - r.k;
    if (!(r.solid_angle >= kMinSolidAngle) || !std::isfinite(r.solid_angle)) return std::nullopt;
    return r;
}

// The point of the rectangle for the uniform (u, v), relative to p, in world coordinates.
std::optional<Eigen::Vector3d> sampleSphericalRectangle(const SphericalRectangle& r, const Eigen::Vector2d& u) {
    // Step 1: the x coordinate, from the area (solid angle) to the left of it: u.x * S.
    const double au = u.x() * r.solid_angle + r.k;
    const double sin_au = std::sin(au);
    // Hard case: sin(au) = 0 only at the boundary (u.x = 0 with k = pi); nudge to the limit.
    const double fu = (std::cos(au) * r.b0 - r.b1) / (std::abs(sin_au) > 1e-15 ? sin_au : 1e-15);
    double cu = std::copysign(1.0, fu) / std::sqrt(fu * fu + r.b0 * r.b0);
    cu = std::clamp(cu, -1.0 + 1e-15, 1.0 - 1e-15);
    double xu = -(cu * r.z0) / std::sqrt(1.0 - cu * cu);
    xu = std::clamp(xu, r.x0, r.x1);
    // Step 2: the y coordinate, uniform in the sine of the elevation along that column.
    const double dist = std::sqrt(xu * xu + r.z0 * r.z0);
    const double h0 = r.y0 / std::sqrt(dist * dist + r.y0 * r.y0);
    const double h1 = r.y1 / std::sqrt(dist * dist + r.y1 * r.y1);
    const double hv = h0 + u.y() * (h1 - h0);
    const double hv2 = hv * hv;
    const double yv = hv2 < 1.0 - 1e-12 ? (hv * dist) / std::sqrt(1.0 - hv2) : r.y1;
    const Eigen::Vector3d offset = xu * r.x + std::clamp(yv, r.y0, r.y1) * r.y + r.z0 * r.z;
    if (!offset.allFinite()) return std::nullopt;
    return offset;
}

}  // namespace

std::optional<LightSample> sampleLight(const SimLight& light, const Eigen::Vector3d& p,
                                       const Eigen::Vector2d& u) noexcept {
    LightSample s;
    switch (light.kind) {
        case LightKind::kPoint: {
            const Eigen::Vector3d d = light.position - p;
            const double d2 = d.squaredNorm();
            // Hard case: a shading point at the light's position (I / d^2 is infinite there).
            if (!(d2 > 1e-20)) return std::nullopt;
            s.distance = std::sqrt(d2);
            s.wi = d / s.distance;
            s.li = light.emission / d2;
            s.pdf = 1.0;
            return s;
        }
        case LightKind::kDirectional:
            s.wi = -light.direction;
            s.li = light.emission;
            s.pdf = 1.0;
            return s;
        case LightKind::kRectangle:
        case LightKind::kDisc: {
            // The light emits from its +z side only: nothing for points behind (or in) its plane.
            if ((p - light.position).dot(light.normal) <= 0.0) return std::nullopt;
            std::optional<SphericalRectangle> spherical;
            if (light.kind == LightKind::kRectangle) spherical = sphericalRectangle(light, p);
            Eigen::Vector3d d;
            if (spherical) {
                const std::optional<Eigen::Vector3d> offset = sampleSphericalRectangle(*spherical, u);
                if (!offset) return std::nullopt;
                d = *offset;
            } else if (light.kind == LightKind::kRectangle) {
                d = light.position + (2.0 * u.x() - 1.0) * light.half_x + (2.0 * u.y() - 1.0) * light.half_y - p;
            } else {
                const Eigen::Vector2d disc = concentricDisc(u);
                d = light.position + disc.x() * light.half_x + disc.y() * light.half_y - p;
            }
            const double d2 = d.squaredNorm();
            // Hard case: the shading point on the light itself.
            if (!(d2 > 1e-20)) return std::nullopt;
            s.distance = std::sqrt(d2);
            s.wi = d / s.distance;
            const double cos_light = -light.normal.dot(s.wi);
            if (cos_light <= kMinCos) return std::nullopt;
            // Solid angle: 1 / S. By area: 1 / A per m^2, i.e. d^2 / (A cos_light) per steradian.
            s.pdf = spherical ? 1.0 / spherical->solid_angle : d2 / (light.area * cos_light);
            if (!(s.pdf > kMinPdf) || !std::isfinite(s.pdf)) return std::nullopt;
            s.li = light.emission;
            return s;
        }
    }
    return std::nullopt;
}

double areaLightPdf(const SimLight& light, const Eigen::Vector3d& p, const Eigen::Vector3d& p_light,
                    const Eigen::Vector3d& wi) noexcept {
    if (light.isDelta() || !(light.area > 0.0)) return 0.0;
    const double cos_light = -light.normal.dot(wi);
    if (cos_light <= kMinCos || (p - light.position).dot(light.normal) <= 0.0) return 0.0;
    // The same choice of technique as sampleLight, which depends on p and the light only.
    if (light.kind == LightKind::kRectangle) {
        if (const std::optional<SphericalRectangle> spherical = sphericalRectangle(light, p)) {
            return 1.0 / spherical->solid_angle;
        }
    }
    const double d2 = (p_light - p).squaredNorm();
    const double pdf = d2 / (light.area * cos_light);
    return std::isfinite(pdf) ? pdf : 0.0;
}

}  // namespace commonlight::mocks::sim

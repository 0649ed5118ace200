#include "lighting/form_factor.h"

#include <algorithm>
#include <array>
#include <cassert>
#include <cmath>
#include <numbers>
#include <vector>

namespace commonlight::lighting {

namespace {

// Gauss-Legendre on [0, 1]: nodes (1 + xi) / 2, weights w_i / 2.
struct GaussTable {
    std::array<std::array<double, 8>, 9> nodes{};
    std::array<std::array<double, 8>, 9> weights{};
    GaussTable() {
        for (int n = 1; n <= 8; ++n) {
            // Newton on P_n from the Chebyshev-like initial guesses (Golub-Welsch would do too).
            for (int i = 0; i < n; ++i) {
                double x = std::cos(std::numbers::pi * (i + 0.75) / (n + 0.5));
                double dp = 1.0;
                for (int it = 0; it < 100; ++it) {
                    double p0 = 1.0, p1 = x;
                    for (int k = 2; k <= n; ++k) {
                        const double p2 = ((2.0 * k - 1.0) * x * p1 - (k - 1.0) * p0) / k;
                        p0 = p1;
                        p1 = p2;
                    }
                    dp = n * (x * p1 - p0) / (x * x - 1.0);
                    const double dx = p1 / dp;
                    x -= dx;
                    if (std::abs(dx) < 1e-15) break;
                }
                const double w = 2.0 / ((1.0 - x * x) * dp * dp);
                nodes[n][i] = 0.5 * (1.0 - x);
                weights[n][i] = 0.5 * w;
            }
        }
    }
};

const GaussTable& gauss() {
    static const GaussTable table;
    return table;
}

}  // namespace

std::span<const double> gaussNodes(int n) {
    assert(n >= 1 && n <= 8);
    return {gauss().nodes[n].data(), static_cast<std::size_t>(n)};
}

std::span<const double> gaussWeights(int n) {
    assert(n >= 1 && n <= 8);
    return {gauss().weights[n].data(), static_cast<std::size_t>(n)};
}

double pointToPolygon(const Eigen::Vector3d& x, const Eigen::Vector3d& n, std::span<const Eigen::Vector3d> polygon,
                      const Eigen::Vector3d& source_normal) {
    if (polygon.size() < 3) return 0.0;
    // A one-sided emitter seen from behind (or edge-on) sends nothing.
    if (source_normal.squaredNorm() > 0.0 && (x - polygon[0]).dot(source_normal) <= 0.0) return 0.0;
    // Step 1: clip the polygon to the receiver's upper half-space (Sutherland-Hodgman against one
    // plane). Heights are relative to x along n; a tiny negative tolerance keeps a source that
    // touches the receiver's plane (adjacent faces) whole instead of shaving it.
    // Clipping adds at most one vertex per crossing (two for a planar polygon); small polygons
    // (elements, lights) stay on the stack, larger ones go to the heap.
    const std::size_t m = polygon.size();
    std::array<Eigen::Vector3d, 40> stack_storage;
    std::vector<Eigen::Vector3d> heap_storage;
    std::span<Eigen::Vector3d> clipped_storage(stack_storage);
    if (m + 2 > stack_storage.size()) {
        heap_storage.resize(m + 2);
        clipped_storage = heap_storage;
    }
    std::size_t count = 0;
    const double scale = (polygon[0] - x).norm();
    const double tolerance = 1e-10 * std::max(scale, 1e-9);
    for (std::size_t i = 0; i < m && count + 2 <= clipped_storage.size(); ++i) {
        const Eigen::Vector3d& a = polygon[i];
        const Eigen::Vector3d& b = polygon[(i + 1) % m];
        const double ha = (a - x).dot(n), hb = (b - x).dot(n);
        const bool ina = ha >= -tolerance, inb = hb >= -tolerance;
        if (ina) clipped_storage[count++] = a;
        if (ina != inb) {
            const double t = ha / (ha - hb);
            clipped_storage[count++] = a + t * (b - a);
        }
    }
    if (count < 3) return 0.0;
    // Hard case: a polygon lying in the receiver's plane (coplanar faces) is seen edge-on.
    double top = 0.0;
    for (std::size_t i = 0; i < count; ++i) top = std::max(top, (clipped_storage[i] - x).dot(n));
    if (top <= tolerance) return 0.0;
    // Step 2: Lambert's formula over the clipped polygon's edges.
    double sum = 0.0;
    for (std::size_t i = 0; i < count; ++i) {
        Eigen::Vector3d ra = clipped_storage[i] - x;
        Eigen::Vector3d rb = clipped_storage[(i + 1) % count] - x;
        const double la = ra.norm(), lb = rb.norm();
        // Hard case: a vertex at the receiver point has no direction; its edges subtend nothing
        // measurable from there (the neighbours' edges carry the solid angle).
        if (la < 1e-300 || lb < 1e-300) continue;
        ra /= la;
        rb /= lb;
        const Eigen::Vector3d c = ra.cross(rb);
        const double cn = c.norm();
        if (cn < 1e-15) continue;  // collinear with x: an edge seen end-on subtends no angle
        const double gamma = std::atan2(cn, ra.dot(rb));
        sum += gamma * n.dot(c) / cn;
    }
    return std::clamp(std::abs(sum) / (2.0 * std::numbers::pi), 0.0, 1.0);
}

std::vector<QuadraturePoint> quadratureRule(const Eigen::Vector3d& corner, const Eigen::Vector3d& edge_s,
                                            const Eigen::Vector3d& edge_t, bool triangle, int n) {
    n = std::clamp(n, 1, 8);
    const auto nodes = gaussNodes(n);
    const auto weights = gaussWeights(n);
    std::vector<QuadraturePoint> points;
    points.reserve(static_cast<std::size_t>(n * n));
    if (!triangle) {
        for (int i = 0; i < n; ++i) {
            for (int j = 0; j < n; ++j) {
                points.push_back({corner + nodes[i] * edge_s + nodes[j] * edge_t, weights[i] * weights[j]});
            }
        }
        return points;
    }
    // Duffy: (a, b) in [0,1]^2 -> s = a (1 - b), t = b, Jacobian (1 - b); normalised by the
    // triangle's parameter area 1/2.
    for (int i = 0; i < n; ++i) {
        for (int j = 0; j < n; ++j) {
            const double a = nodes[i], b = nodes[j];
            const double s = a * (1.0 - b), t = b;
            points.push_back({corner + s * edge_s + t * edge_t, 2.0 * weights[i] * weights[j] * (1.0 - b)});
        }
    }
    return points;
}

int formFactorRule(double distance, double receiver_size, double source_size) {
    const double size = std::max(receiver_size, source_size);
    if (!(size > 0.0)) return 1;
    const double ratio = distance / size;
    if (ratio > 4.0) return 1;
    if (ratio > 2.0) return 2;
    if (ratio > 1.2) return 4;
    return 8;
}

Eigen::Vector3d samplePolygon(const Eigen::Vector3d& corner, const Eigen::Vector3d& edge_s, const Eigen::Vector3d& edge_t,
                              bool triangle, double u, double v) {
    if (!triangle) return corner + u * edge_s + v * edge_t;
    // Uniform on the triangle: fold the square's upper half onto the lower one.
    if (u + v > 1.0) {
        u = 1.0 - u;
        v = 1.0 - v;
    }
    return corner + u * edge_s + v * edge_t;
}

double pointToSphere(double distance, double radius, double cos_phi) {
    if (!(radius > 0.0) || !(distance > 0.0)) return 0.0;
    const double h = std::max(1.0, distance / radius);
    const double c = std::clamp(cos_phi, -1.0, 1.0);
    const double sin_phi = std::sqrt(std::max(0.0, 1.0 - c * c));
    const double root = std::sqrt(h * h - 1.0);
    // Wholly above the horizon (phi <= acos(1 / H)), or wholly below (phi >= pi/2 + asin(1 / H)).
    if (c * h >= 1.0) return c / (h * h);
    if (-c * h >= 1.0) return 0.0;
    constexpr double kPi = std::numbers::pi;
    const double a = std::asin(std::clamp(root / (h * sin_phi), -1.0, 1.0));
    const double b = std::acos(std::clamp(-root * c / sin_phi, -1.0, 1.0));
    return std::max(0.0, 0.5 - a / kPi + (c * b - root * std::sqrt(std::max(0.0, 1.0 - h * h * c * c))) / (kPi * h * h));
}

}  // namespace commonlight::lighting

// The hierarchical radiosity's solve (lighting/radiosity.h): the links gathered per receiver
// in single precision, pushed to the leaves, iterated (Jacobi) to the tolerance.
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numbers>

#include "lighting/radiosity.h"

namespace commonlight::lighting {

namespace {

constexpr double kPi = std::numbers::pi;

double maxComponent(const Eigen::Vector3d& v) { return v.cwiseAbs().maxCoeff(); }

// The links as the solve reads them: per receiver (CSR), each term its source and
// pi F V, in single precision (a third of a Link's bytes: the gather is memory-bound).
struct GatherTerms {
    std::vector<int> offsets;
    std::vector<std::int32_t> source;
    std::vector<float> weight;
};

GatherTerms gatherTerms(const std::vector<Link>& links, const std::vector<int>& link_offsets, std::size_t n) {
    GatherTerms t;
    t.offsets.assign(n + 1, 0);
    t.source.reserve(links.size());
    t.weight.reserve(links.size());
    for (std::size_t e = 0; e < n; ++e) {
        const int begin = e < link_offsets.size() - 1 ? link_offsets[e] : 0;
        const int end = e < link_offsets.size() - 1 ? link_offsets[e + 1] : 0;
        for (int k = begin; k < end; ++k) {
            const Link& l = links[static_cast<std::size_t>(k)];
            const float fv = l.form_factor * l.vis_real;
            if (!(fv > 0.0f)) continue;
            t.source.push_back(l.source);
            t.weight.push_back(static_cast<float>(kPi) * fv);
        }
        t.offsets[e + 1] = static_cast<int>(t.source.size());
    }
    return t;
}

// One gather (H = pi sum F V L over each element's links, in parallel over receivers), then the
// push: every leaf receives what its ancestors gathered (parents precede children).
template <typename Extra>
void gatherWith(const GatherTerms& t, const Hierarchy& hierarchy, const std::vector<Eigen::Vector3d>& radiance,
                std::vector<Eigen::Vector3d>& gathered, const Extra& extra) {
    const auto& elements = hierarchy.elements();
    const std::size_t n = elements.size();
    gathered.resize(n);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 512), [&](const tbb::blocked_range<std::size_t>& range) {
        for (std::size_t e = range.begin(); e < range.end(); ++e) {
            Eigen::Vector3d sum = Eigen::Vector3d::Zero();
            for (int k = t.offsets[e]; k < t.offsets[e + 1]; ++k) {
                sum += static_cast<double>(t.weight[static_cast<std::size_t>(k)]) * radiance[static_cast<std::size_t>(t.source[static_cast<std::size_t>(k)])];
            }
            gathered[e] = sum;
        }
    });
    extra(radiance, gathered);  // the cluster links
    for (std::size_t i = 0; i < n; ++i) {
        const Element& e = elements[i];
        for (int c = 0; c < e.child_count; ++c) gathered[static_cast<std::size_t>(e.first_child + c)] += gathered[i];
    }
    for (std::size_t i = 0; i < n; ++i) {
        if (!elements[i].leaf()) gathered[i].setZero();
    }
}

}  // namespace

std::vector<Eigen::Vector3d> Radiosity::gatherIndirect(Mode, const std::vector<Eigen::Vector3d>& radiance) const {
    std::vector<Eigen::Vector3d> gathered;
    gatherWith(gatherTerms(links_, link_offsets_, hierarchy_.elements().size()), hierarchy_, radiance, gathered,
               [this](const std::vector<Eigen::Vector3d>& l, std::vector<Eigen::Vector3d>& g) { gatherClusters(l, g); });
    return gathered;
}

Solution Radiosity::solve(Mode mode, const std::vector<Eigen::Vector3d>& rho, const std::vector<Eigen::Vector3d>& emission,
                          const std::vector<Eigen::Vector3d>& direct) const {
    const auto& elements = hierarchy_.elements();
    const std::size_t n = elements.size();
    Solution out;
    out.radiance.assign(n, Eigen::Vector3d::Zero());
    out.irradiance.assign(n, Eigen::Vector3d::Zero());
    out.indirect.assign(n, Eigen::Vector3d::Zero());
    const std::vector<int> active = leaves(mode);
    const GatherTerms terms = gatherTerms(links_, link_offsets_, n);
    // Step 1: the first estimate: emission plus reflected direct light.
    for (int e : active) {
        const auto i = static_cast<std::size_t>(e);
        out.radiance[i] = emission[i] + rho[i].cwiseProduct(direct[i]) / kPi;
    }
    pull(out.radiance);
    // Step 2: Jacobi iterations of gather + push-pull until the largest change is small.
    std::vector<Eigen::Vector3d> gathered;
    double scale = 0.0;
    for (int e : active) scale = std::max(scale, maxComponent(out.radiance[static_cast<std::size_t>(e)]));
    int iteration = 0;
    double residual = scale > 0.0 ? 1.0 : 0.0;
    while (residual > options_.residual && iteration < options_.max_iterations) {
        ++iteration;
        gatherWith(terms, hierarchy_, out.radiance, gathered,
                   [this](const std::vector<Eigen::Vector3d>& l, std::vector<Eigen::Vector3d>& g) { gatherClusters(l, g); });
        double change = 0.0;
        for (int e : active) {
            const auto i = static_cast<std::size_t>(e);
            const Eigen::Vector3d next = emission[i] + rho[i].cwiseProduct(direct[i] + gathered[i]) / kPi;
            change = std::max(change, maxComponent(next - out.radiance[i]));
            out.radiance[i] = next;
            out.indirect[i] = gathered[i];
        }
        pull(out.radiance);
        for (int e : active) scale = std::max(scale, maxComponent(out.radiance[static_cast<std::size_t>(e)]));
        residual = scale > 0.0 ? change / scale : 0.0;
    }
    for (int e : active) {
        const auto i = static_cast<std::size_t>(e);
        out.irradiance[i] = direct[i] + out.indirect[i];
    }
    out.summary.iterations = iteration;
    out.summary.residual = residual;
    out.summary.converged = residual <= options_.residual;
    out.summary.elements = static_cast<int>(active.size());
    out.summary.links = linkCount(mode);
    return out;
}

}  // namespace commonlight::lighting

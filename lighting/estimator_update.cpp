#include "lighting/estimator.h"
#include "lighting/estimator_impl.h"

#include <tbb/parallel_for.h>
#if defined(__SANITIZE_THREAD__)
#include <tbb/global_control.h>
#endif

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <map>
#include <numbers>
#include <variant>
#include <cstdio>
#include <cstdlib>

#include "core/log.h"
#include "lighting/distant.h"
#include "lighting/form_factor.h"
#include "lighting/influence.h"
#include "lighting/sampling.h"
#include "lighting/snapshot_builder.h"
#include "lighting/texel_direct.h"

namespace commonlight::lighting {

using namespace estimator_detail;

namespace {

// Unoccluded unit irradiance of a (non-cell) source at a point: for the "is this leaf in a
// shadow boundary" test.
double unoccluded(const DirectSource& s, const Eigen::Vector3d& x, const Eigen::Vector3d& n) {
    switch (s.kind) {
        case DirectSource::Kind::kPolygon:
            return kPi * pointToPolygon(x, n, s.polygon->polygon, s.polygon->normal);
        case DirectSource::Kind::kPoint: {
            const Eigen::Vector3d d = s.position - x;
            const double d2 = d.squaredNorm();
            return d2 > 1e-12 ? std::max(0.0, n.dot(d) / std::sqrt(d2)) / d2 : 0.0;
        }
        case DirectSource::Kind::kDirection:
            return std::max(0.0, n.dot(-s.direction));
        case DirectSource::Kind::kCell:
            return 0.0;
    }
    return 0.0;
}

}  // namespace

// A full update is due: nothing solved yet, one asked for, or the observations have doubled since
// the last fit (and refit_min_frames have passed).
bool Estimator::nextUpdateFull() const {
    const Impl& d = *impl_;
    const std::uint64_t frames = observations_->frames();
    const bool refit = frames > d.frames_at_fit && frames >= 2 * d.frames_at_fit &&
                       frames - d.frames_at_fit >= static_cast<std::uint64_t>(std::max(0, d.options.refit_min_frames));
    return !d.mesh_built || !d.influence->hasBase() || d.force_full || refit;
}

// The whole update; see estimator.h for the cases.
Result<LightingSnapshot> Estimator::update(const std::vector<Rigid3d>& virtual_world_from_object) {
    Impl& d = *impl_;
    // Between full updates (a new fit of lights and reflectances, B~ solved again) only what the
    // virtual objects change is updated, incrementally (lighting/influence.h).
    if (d.update_depth == 0 && !nextUpdateFull()) {
        setVirtualPoses(virtual_world_from_object);
        return incrementalUpdate();
    }
    d.force_full = false;
    if (d.update_depth == 0) d.direction_fitted = false;
    warnings_ = d.setup_warnings;
    if (d.update_depth == 0) stats_ = {};
    ++d.update_depth;
    struct DepthGuard {
        int& depth;
        ~DepthGuard() { --depth; }
    } depth_guard{d.update_depth};
    setVirtualPoses(virtual_world_from_object);
    Radiosity& rad = *radiosity_;
    Hierarchy& h = rad.hierarchy();
    const RadiosityOptions& ro = options_.radiosity;
    // The base changes (refinement, links, B~): the influence's elements go first.
    d.influence->collapseAll();
    stats_.full = true;

    // A tag's white ring anchors the scale when seen in enough pure pixels, hardly any clipped.
    const auto ringUsable = [&](const RadianceStats& white) {
        return white.pixels >= static_cast<std::uint32_t>(options_.min_ring_pixels) && uncensored(white);
    };

    // Step 1: columns of every source (real occluders) for the real leaves that lack them.
    const auto refresh_columns = [&](bool all_leaves) {
        d.column_valid.resize(h.elements().size(), 0);
        std::vector<int> todo;
        for (int e : rad.leaves(Mode::kReal)) {
            if (all_leaves || !d.column_valid[static_cast<std::size_t>(e)]) todo.push_back(e);
        }
        if (todo.empty()) return;
        ScopedMs timer(stats_.ms_columns);
        DirectOptions dopt;
        for (Source& s : d.sources) computeDirect(rad, s.direct, todo, dopt, s.column);
        for (int e : todo) d.column_valid[static_cast<std::size_t>(e)] = 1;
    };

    // Splits observed leaves where a light's direct irradiance varies: a shadow boundary across
    // the leaf (visible fraction between 5% and 95%) or a light close enough that its unoccluded
    // irradiance changes by 2x over the leaf. `dominant_only`: only the refined directions of
    // distant lights (their shadows appear once the direction is known).
    const auto refine_light = [&](bool dominant_only) {
        int total = 0;
        for (int round = 0; round < 4; ++round) {
            int split = 0;
            for (int e : rad.leaves(Mode::kReal)) {
                if (h.leafCount() + 4 >= ro.max_elements) break;
                if (!h.canSubdivide(e, options_.light_refinement_size)) continue;
                // Model only what the scene needs: where the camera has looked.
                if (!options_.refine_unobserved && observations_->aggregate(h[e]).pixels == 0) continue;
                const ElementGeometry g = rad.geometry(e);
                bool vary = false;
                for (const Source& s : d.sources) {
                    if (s.direct.kind == DirectSource::Kind::kCell || (dominant_only && !s.dominant)) continue;
                    const double open = unoccluded(s.direct, g.centroid, g.normal);
                    if (!(open > 0.0)) continue;
                    const double v = s.column.real[static_cast<std::size_t>(e)] / open;
                    if (v > 0.05 && v < 0.95) vary = true;
                    double lo = open, hi = open;
                    for (const Eigen::Vector3d& c : g.polygon()) {
                        const double f = unoccluded(s.direct, c + 0.02 * (g.centroid - c), g.normal);
                        lo = std::min(lo, f);
                        hi = std::max(hi, f);
                    }
                    if (hi > 2.0 * std::max(lo, 1e-12)) vary = true;
                    if (vary) break;
                }
                if (vary && h.subdivide(e, options_.light_refinement_size)) ++split;
            }
            rad.markBuried();
            refresh_columns(false);
            total += split;
            if (split == 0) break;
        }
        return total;
    };

    // The real scene's links, with the source oracle fed by an estimate of each leaf's radiance:
    // the fitted lights when there are some, else every light at unit emission (reflectance 0.5).
    const auto build_links = [&](const std::optional<std::vector<Eigen::Vector3d>>& emission) {
        std::vector<double> radiance(h.elements().size(), 0.0), reflectance(h.elements().size(), 0.0);
        double mean_direct = 0.0, mean_rho = 0.0, area = 0.0;
        for (int e : rad.leaves(Mode::kReal)) {
            double l = 0.0;
            for (std::size_t k = 0; k < d.sources.size(); ++k) {
                const Source& s = d.sources[k];
                const double em = emission ? luma((*emission)[k]) : (s.estimate ? 1.0 : luma(s.known));
                l += em * s.column.real[static_cast<std::size_t>(e)];
            }
            const Face& f = rad.face(h[e].face);
            const double r = f.albedo_known ? luma(f.albedo)
                             : rho_.size() > static_cast<std::size_t>(e) ? luma(rho_[static_cast<std::size_t>(e)])
                                                                        : 0.5;
            radiance[static_cast<std::size_t>(e)] = r / kPi * l;
            reflectance[static_cast<std::size_t>(e)] = r;
            const double a = h[e].area * rad.exposure(e);
            mean_direct += a * radiance[static_cast<std::size_t>(e)];
            mean_rho += a * r;
            area += a;
        }
        // Interreflection, as seed 001's ambient term: in an enclosure the surfaces' mean radiance
        // is the mean reflected direct light over (1 - mean reflectance), and each surface reflects
        // its share of it. Without it the oracles would take a ceiling lit only indirectly for black.
        if (area > 0.0) {
            mean_direct /= area;
            mean_rho = std::min(mean_rho / area, 0.9);
            // A sheltered surface (behind a cabinet) gets the unsheltered part of it.
            rad.measureShelters();
            for (int e : rad.leaves(Mode::kReal)) {
                const auto i = static_cast<std::size_t>(e);
                radiance[i] += (1.0 - rad.shelter(e).mean) * reflectance[i] * mean_direct / (1.0 - mean_rho);
            }
        }
        rad.setSourceRadiance(radiance);
        {
            ScopedMs timer(stats_.ms_links);
            rad.buildRealLinks();
        }
        rad.markBuried();
        refresh_columns(false);
        d.poses_changed = true;  // the virtual links go with the real ones
    };

    // Step 2: the mesh and the real scene's links (once); refinement where the light varies and
    // where the observations vary (when enough new frames came).
    if (!d.mesh_built) {
        double size = options_.initial_element_size;
        if (!(size > 0.0)) {
            double area = 0.0;
            for (const Face& f : d.real_faces) area += f.area;
            size = std::clamp(std::sqrt(area / std::max(1.0, ro.max_elements / 16.0)), 0.05, 1.0);
        }
        rad.subdivideTo(size, 1e9);  // virtual faces stay whole: the objects are clusters (lighting/influence.h)
        rad.markBuried();
        stats_.leaves_initial = h.leafCount();
        refresh_columns(true);
        if (options_.refine_by_light) refine_light(false);
        stats_.leaves_light = h.leafCount();
        build_links(std::nullopt);
        stats_.leaves_links = h.leafCount();
        d.mesh_built = true;
    }
    if (options_.refine_by_light && std::any_of(d.sources.begin(), d.sources.end(), [](const Source& src) { return src.dominant; })) {
        // A distant light's refined direction casts shadows the first mesh did not know of; once
        // they are resolved, the direction is searched again on the finer elements.
        if (refine_light(true) > 0) d.dominant_frames.clear();
    }
    if (options_.refine_by_observation && observations_->frames() >= std::max<std::uint64_t>(1, d.frames_at_refinement * 2)) {
        int split = 0;
        for (int e : rad.leaves(Mode::kReal)) {
            if (h.leafCount() + 4 >= ro.max_elements) break;
            if (!h.canSubdivide(e, options_.light_refinement_size)) continue;
            if (observations_->spread(h[e], 2) > 0.2 && h.subdivide(e, options_.light_refinement_size)) ++split;
        }
        d.frames_at_refinement = observations_->frames();
        stats_.leaves_observation = h.leafCount();
        if (split > 0) {
            rad.markBuried();
            refresh_columns(false);
        }
    }

    // Step 3 (Lighting I: links to the virtual objects and their shadows' refinement) is the
    // influence's now: lighting/influence.h, after B~.
    d.poses_changed = false;

    // Step 4: what was observed, per real leaf.
    const std::size_t n = h.elements().size();
    std::vector<Eigen::Vector3d> observed(n, Eigen::Vector3d::Zero());
    std::vector<double> weight(n, 0.0);
    std::vector<int> observed_leaves;
    stats_.leaves_observation = std::max(stats_.leaves_observation, h.leafCount());
    for (int e : rad.leaves(Mode::kReal)) {
        const RadianceStats stats = observations_->aggregate(h[e]);
        if (stats.pixels >= static_cast<std::uint32_t>(options_.min_pixels) && stats.weight > 0.0 && uncensored(stats)) {
            observed[static_cast<std::size_t>(e)] = stats.mean();
            weight[static_cast<std::size_t>(e)] = stats.weight;
            observed_leaves.push_back(e);
        }
    }
    stats_.observed_leaves = static_cast<int>(observed_leaves.size());
    LightingSnapshot snapshot;
    snapshot.radiance_scale = radiance_scale_;
    snapshot.radiance_scale_known = d.options.radiance_scale.has_value();
    snapshot.frames_used = observations_->frames();
    bool all_known = d.groups == 0 && !d.sources.empty();
    for (const Source& s : d.sources) all_known = all_known && !s.estimate;
    if (observed_leaves.empty() && !all_known) {
        warnings_.push_back("nothing of the real scene observed yet: no lighting change is drawn");
        snapshot.warnings = warnings_;
        return snapshot;
    }

    // Fallback radiance for leaves never seen: the object's mean observed radiance, else the scene's.
    std::map<int, std::pair<Eigen::Vector3d, double>> object_mean;
    Eigen::Vector3d scene_mean = Eigen::Vector3d::Zero();
    double scene_area = 0.0;
    for (int e : observed_leaves) {
        const int object = d.real_faces[static_cast<std::size_t>(h[e].face)].object_index;
        auto& [sum, area] = object_mean[object];
        if (area == 0.0) sum.setZero();
        sum += h[e].area * observed[static_cast<std::size_t>(e)];
        area += h[e].area;
        scene_mean += h[e].area * observed[static_cast<std::size_t>(e)];
        scene_area += h[e].area;
    }
    if (scene_area > 0.0) scene_mean /= scene_area;
    const auto fallback_radiance = [&](int e) -> Eigen::Vector3d {
        const int object = d.real_faces[static_cast<std::size_t>(h[e].face)].object_index;
        const auto it = object_mean.find(object);
        if (it != object_mean.end() && it->second.second > 0.0) return it->second.first / it->second.second;
        return scene_mean;
    };
    // Radiance of every element for inverse radiosity: observed where seen, else the last model's
    // (or the fallback), pulled up the hierarchy.
    const auto mixed_radiance = [&]() {
        std::vector<Eigen::Vector3d> l(n, Eigen::Vector3d::Zero());
        const bool have_model = without_.radiance.size() == n;
        for (int e : rad.leaves(Mode::kReal)) {
            const auto i = static_cast<std::size_t>(e);
            l[i] = weight[i] > 0.0 ? observed[i] : (have_model ? without_.radiance[i] : fallback_radiance(e));
        }
        rad.pull(l);
        return l;
    };

    // Tags: unit irradiance at their white rings (cached; real occluders only).
    const auto& tags = observations_->tags();
    d.tag_columns.resize(tags.size());
    d.tag_columns_face.resize(tags.size(), -2);
    for (std::size_t t = 0; t < tags.size(); ++t) {
        if (tags[t].face < 0 || !ringUsable(tags[t].white)) continue;
        if (d.tag_columns_face[t] == tags[t].face && d.tag_columns[t].size() == d.sources.size()) continue;
        d.tag_columns[t].assign(d.sources.size(), 0.0);
        tbb::parallel_for(std::size_t{0}, d.sources.size(), [&](std::size_t k) {
            double sum = 0.0;
            for (std::size_t p = 0; p < tags[t].ring_points.size(); ++p) {
                sum += directAtPoint(*rays_, d.sources[k].direct, tags[t].ring_points[p], tags[t].normal, 8,
                                     hashCombine(t * 7919 + p, k));
            }
            d.tag_columns[t][k] = sum / static_cast<double>(std::max<std::size_t>(1, tags[t].ring_points.size()));
        });
        d.tag_columns_face[t] = tags[t].face;
    }

    // Step 5: lights and reflectances.
    rho_.assign(n, Eigen::Vector3d::Constant(0.5));
    for (std::size_t e = 0; e < n; ++e) {
        const Face& f = rad.face(h[static_cast<int>(e)].face);
        if (f.albedo_known) rho_[e] = f.albedo;
    }
    std::vector<Eigen::Vector3d> emission_le(n, Eigen::Vector3d::Zero());  // Le per leaf (virtual emitters, case 3)
    for (int e : rad.leaves(Mode::kAll)) {
        if (rad.isVirtualElement(e)) {
            emission_le[static_cast<std::size_t>(e)] = rad.face(h[e].face).emission * radiance_scale_;
        }
    }
    std::vector<Eigen::Vector3d> source_emission(d.sources.size(), Eigen::Vector3d::Zero());
    for (std::size_t k = 0; k < d.sources.size(); ++k) {
        if (!d.sources[k].estimate) source_emission[k] = d.sources[k].known;
    }
    estimates_.clear();
    const bool nothing_known = d.sources.empty();
    std::vector<int> estimate_index;  // sources being estimated
    for (std::size_t k = 0; k < d.sources.size(); ++k) {
        if (d.sources[k].estimate) estimate_index.push_back(static_cast<int>(k));
    }
    std::array<FitResult, 3> fits{};
    const auto direct_real = [&](int e) {
        Eigen::Vector3d sum = Eigen::Vector3d::Zero();
        for (std::size_t k = 0; k < d.sources.size(); ++k) sum += source_emission[k] * d.sources[k].column.real[static_cast<std::size_t>(e)];
        return sum;
    };

    if (nothing_known) {
        // Case 3: every observed surface emits what interreflection does not explain. Reflectances
        // from the ambient heuristic (seed 000 eq. 4: rho proportional to radiance), its scale
        // taken from the tags when seen (a surface beside a white ring of known albedo has
        // rho = albedo_white * L / L_white), else a mean reflectance of mean_albedo_prior.
        double kappa = 0.0;
        double ring_weight = 0.0;
        for (const TagReference& ref : tags) {
            if (!ringUsable(ref.white)) continue;
            const double lw = luma(ref.white.mean());
            if (lw > 0.0) {
                kappa += ref.white.weight * ref.albedo_white / lw;
                ring_weight += ref.white.weight;
            }
        }
        if (ring_weight > 0.0) {
            kappa /= ring_weight;
        } else {
            kappa = options_.mean_albedo_prior / std::max(luma(scene_mean), 1e-12);
            warnings_.push_back("no light in the scene and no tag seen: reflectances assume a mean of " +
                                std::to_string(options_.mean_albedo_prior));
        }
        for (int e : rad.leaves(Mode::kReal)) {
            const auto i = static_cast<std::size_t>(e);
            const Face& f = rad.face(h[e].face);
            if (f.albedo_known) continue;
            const Eigen::Vector3d l = weight[i] > 0.0 ? observed[i] : fallback_radiance(e);
            rho_[i] = (kappa * l).cwiseMax(0.01).cwiseMin(0.98);
        }
        const std::vector<Eigen::Vector3d> l = mixed_radiance();
        const std::vector<Eigen::Vector3d> gathered = rad.gatherIndirect(Mode::kReal, l);
        for (int e : rad.leaves(Mode::kReal)) {
            const auto i = static_cast<std::size_t>(e);
            emission_le[i] = (l[i] - rho_[i].cwiseProduct(gathered[i]) / kPi).cwiseMax(0.0);
        }
        warnings_.push_back("the scene names no light: every observed surface is treated as an emitter (seed 001 sec. 4.4.2)");
    } else {
        // Cases 1 and 2: fit, reflectances, solve; twice (the indirect light of unseen elements
        // comes from the previous pass's model).
        for (int pass = 0; pass < std::max(1, options_.fit_iterations); ++pass) {
            const std::vector<Eigen::Vector3d> l = mixed_radiance();
            const std::vector<Eigen::Vector3d> gathered = rad.gatherIndirect(Mode::kReal, l);
            // A distant light's refined direction takes the place of the cell it lies in: both
            // light the observed elements alike (but for the shadows' edges), and the Tikhonov
            // term would split the sun between them (measured: the sun 10% low, its cell holding
            // the rest). The cell's share of the sky goes to its neighbours.
            for (const Source& dom : d.sources) {
                if (!dom.dominant) continue;
                const Eigen::Vector3d w = -dom.direct.direction.normalized();
                double phi = std::atan2(w.y(), w.x());
                if (phi < 0.0) phi += 2.0 * kPi;
                std::erase_if(estimate_index, [&](int k) {
                    const DirectSource& c = d.sources[static_cast<std::size_t>(k)].direct;
                    const bool inside = d.sources[static_cast<std::size_t>(k)].light == dom.light && c.kind == DirectSource::Kind::kCell &&
                                        w.z() >= c.cos0 && w.z() < c.cos1 && phi >= c.phi0 && phi < c.phi1;
                    if (inside) source_emission[static_cast<std::size_t>(k)].setZero();
                    return inside;
                });
            }
            if (!estimate_index.empty()) {
                // Distant lights with a refined direction add it as one more column.
                for (int channel = 0; channel < 3; ++channel) {
                    FitProblem problem;
                    problem.sources = static_cast<int>(estimate_index.size());
                    problem.groups = d.groups;
                    bool distant = false;
                    for (int k : estimate_index) distant = distant || d.sources[static_cast<std::size_t>(k)].direct.kind == DirectSource::Kind::kCell;
                    problem.tikhonov = distant ? options_.distant_tikhonov : options_.tikhonov;
                    problem.prior_albedo = options_.mean_albedo_prior;
                    for (const Eigen::Vector3d& g : d.group_albedo) problem.initial_group_albedo.push_back(g[channel]);
                    for (int e : observed_leaves) {
                        const auto i = static_cast<std::size_t>(e);
                        const Face& f = rad.face(h[e].face);
                        FitObservation o;
                        o.radiance = observed[i][channel];
                        o.weight = weight[i];
                        o.group = d.group_of_object[static_cast<std::size_t>(f.object_index)];
                        o.albedo = f.albedo[channel];
                        o.area = h[e].area;
                        o.constant = gathered[i][channel];
                        for (std::size_t k = 0; k < d.sources.size(); ++k) {
                            if (!d.sources[k].estimate) o.constant += d.sources[k].known[channel] * d.sources[k].column.real[i];
                        }
                        for (int k : estimate_index) o.columns.push_back(d.sources[static_cast<std::size_t>(k)].column.real[i]);
                        problem.observations.push_back(std::move(o));
                    }
                    for (std::size_t t = 0; t < tags.size(); ++t) {
                        if (tags[t].face < 0 || !ringUsable(tags[t].white) || d.tag_columns[t].size() != d.sources.size()) continue;
                        FitObservation o;
                        o.radiance = tags[t].white.mean()[channel];
                        o.weight = tags[t].white.weight;
                        o.group = -1;
                        o.albedo = tags[t].albedo_white;
                        // Indirect light at the ring: that of the leaves under its points.
                        double indirect = 0.0;
                        for (const Eigen::Vector3d& p : tags[t].ring_points) {
                            const Face& f = rad.face(tags[t].face);
                            Eigen::Matrix<double, 3, 2> b;
                            b.col(0) = f.edge_s;
                            b.col(1) = f.edge_t;
                            const Eigen::Vector2d st = (b.transpose() * b).inverse() * (b.transpose() * (p - f.origin));
                            indirect += gathered[static_cast<std::size_t>(h.leafAt(tags[t].face, st))][channel];
                        }
                        o.constant = indirect / static_cast<double>(std::max<std::size_t>(1, tags[t].ring_points.size()));
                        if (std::getenv("CL_FIT_DEBUG") && channel == 1) std::fprintf(stderr, "tag %zu indirect (relative) %.4f (scene units %.4f)\n", t, o.constant, o.constant / radiance_scale_);
                        for (std::size_t k = 0; k < d.sources.size(); ++k) {
                            if (!d.sources[k].estimate) o.constant += d.sources[k].known[channel] * d.tag_columns[t][k];
                        }
                        for (int k : estimate_index) o.columns.push_back(d.tag_columns[t][static_cast<std::size_t>(k)]);
                        problem.observations.push_back(std::move(o));
                    }
                    ScopedMs timer(stats_.ms_fit);
                    CL_TRY(fits[static_cast<std::size_t>(channel)], fitChannel(problem));
                }
                fit_residual_ = std::max({fits[0].relative_residual, fits[1].relative_residual, fits[2].relative_residual});
                for (std::size_t j = 0; j < estimate_index.size(); ++j) {
                    for (int c = 0; c < 3; ++c) {
                        source_emission[static_cast<std::size_t>(estimate_index[j])][c] = fits[static_cast<std::size_t>(c)].emission[j];
                    }
                }
                for (int g = 0; g < d.groups; ++g) {
                    for (int c = 0; c < 3; ++c) d.group_albedo[static_cast<std::size_t>(g)][c] = fits[static_cast<std::size_t>(c)].group_albedo[static_cast<std::size_t>(g)];
                }
            }
            // Reflectances per element: rho = pi L / H where observed (seed 000 eq. 4 with the
            // fitted light instead of an ambient term), else the area-weighted mean of the object's
            // observed elements, else its group's fit.
            std::map<int, std::pair<Eigen::Vector3d, double>> object_rho;
            for (int e : rad.leaves(Mode::kReal)) {
                const auto i = static_cast<std::size_t>(e);
                const Face& f = rad.face(h[e].face);
                if (f.albedo_known || !(weight[i] > 0.0)) continue;
                const Eigen::Vector3d irradiance = direct_real(e) + gathered[i];
                const int group = d.group_of_object[static_cast<std::size_t>(f.object_index)];
                Eigen::Vector3d r = d.group_albedo[static_cast<std::size_t>(group)];
                for (int c = 0; c < 3; ++c) {
                    // Hard case: no light reaches the element in the model: keep the group's value.
                    if (irradiance[c] > 1e-9 * std::max(1.0, luma(scene_mean))) r[c] = kPi * observed[i][c] / irradiance[c];
                }
                rho_[i] = r.cwiseMax(0.0).cwiseMin(0.98);
                auto& [sum, area] = object_rho[f.object_index];
                if (area == 0.0) sum.setZero();
                sum += h[e].area * rho_[i];
                area += h[e].area;
            }
            for (int e : rad.leaves(Mode::kReal)) {
                const auto i = static_cast<std::size_t>(e);
                const Face& f = rad.face(h[e].face);
                if (f.albedo_known || weight[i] > 0.0) continue;
                const auto it = object_rho.find(f.object_index);
                const int group = d.group_of_object[static_cast<std::size_t>(f.object_index)];
                rho_[i] = it != object_rho.end() && it->second.second > 0.0 ? Eigen::Vector3d(it->second.first / it->second.second)
                                                                             : d.group_albedo[static_cast<std::size_t>(group)];
            }
            // Case 2: the dominant direction of each unknown distant light, refined continuously
            // once the cells are fitted; it joins the model as one more column for the next pass.
            if (pass == 0 && options_.refine_distant) {
                for (std::size_t li = 0; li < d.scene.lights.size(); ++li) {
                    if (!std::holds_alternative<DistantLightShape>(d.scene.lights[li].shape)) continue;
                    if (!d.scene.lights[li].emission.isEstimate()) continue;
                    const auto done = d.dominant_frames.find(static_cast<int>(li));
                    if (done != d.dominant_frames.end() && observations_->frames() < 2 * done->second) continue;
                    // The dominant cell.
                    int peak = -1;
                    double peak_power = 0.0, total_power = 0.0;
                    for (std::size_t k = 0; k < d.sources.size(); ++k) {
                        const Source& src = d.sources[k];
                        if (src.light != static_cast<int>(li) || src.direct.kind != DirectSource::Kind::kCell) continue;
                        const double power = luma(source_emission[k]) * src.direct.solidAngle() * src.direct.cellCentre().z();
                        total_power += power;
                        if (power > peak_power) {
                            peak_power = power;
                            peak = static_cast<int>(k);
                        }
                    }
                    // Hard case: a sky without a dominant direction (overcast): nothing to refine.
                    if (peak < 0 || peak_power < 0.1 * total_power) continue;
                    int existing = -1;
                    for (std::size_t k = 0; k < d.sources.size(); ++k) {
                        if (d.sources[k].dominant && d.sources[k].light == static_cast<int>(li)) existing = static_cast<int>(k);
                    }
                    // What the other columns leave to explain, per row (luminance).
                    const auto model_without = [&](const std::vector<float>* col_real_of, std::size_t i_elem, bool tag, std::size_t t) {
                        Eigen::Vector3d irradiance = tag ? Eigen::Vector3d::Zero() : gathered[i_elem];
                        for (std::size_t k = 0; k < d.sources.size(); ++k) {
                            if (static_cast<int>(k) == peak || static_cast<int>(k) == existing) continue;
                            const double col = tag ? d.tag_columns[t][k] : d.sources[k].column.real[i_elem];
                            irradiance += source_emission[k] * col;
                        }
                        (void)col_real_of;
                        return irradiance;
                    };
                    DirectionRows rows;
                    for (int e : observed_leaves) {
                        const auto i = static_cast<std::size_t>(e);
                        std::vector<Eigen::Vector3d> pts;
                        for (int k = 0; k < 16; ++k) {
                            const Eigen::Vector2d u = stratified2d(hashCombine(0xd15ull, i), k, 16);
                            pts.push_back(rad.surfacePoint(e, u.x(), u.y()));
                        }
                        rows.points.push_back(std::move(pts));
                        rows.normals.push_back(rad.geometry(e).normal);
                        // The object's reflectance, not the element's: an element's rho = pi L / H
                        // has the current model's light (the cells' smooth shape) baked in, and the
                        // shadows the direction must explain would be divided out.
                        const Face& face = rad.face(h[e].face);
                        const int group = d.group_of_object[static_cast<std::size_t>(face.object_index)];
                        const Eigen::Vector3d r = face.albedo_known || group < 0 ? face.albedo : d.group_albedo[static_cast<std::size_t>(group)];
                        rows.scale.push_back(luma(r) / kPi);
                        rows.target.push_back(luma(observed[i]) - luma(r.cwiseProduct(model_without(nullptr, i, false, 0))) / kPi);
                        rows.weight.push_back(weight[i]);
                    }
                    for (std::size_t t = 0; t < tags.size(); ++t) {
                        if (tags[t].face < 0 || !ringUsable(tags[t].white) || d.tag_columns[t].size() != d.sources.size()) continue;
                        rows.points.push_back(tags[t].ring_points);
                        rows.normals.push_back(tags[t].normal);
                        rows.scale.push_back(tags[t].albedo_white / kPi);
                        rows.target.push_back(luma(tags[t].white.mean()) -
                                              tags[t].albedo_white / kPi * luma(model_without(nullptr, 0, true, t)));
                        rows.weight.push_back(tags[t].white.weight);
                    }
                    const DirectSource& cell = d.sources[static_cast<std::size_t>(peak)].direct;
                    const Eigen::Vector3d start = existing >= 0 ? Eigen::Vector3d(-d.sources[static_cast<std::size_t>(existing)].direct.direction)
                                                                : cell.cellCentre();
                    const double cell_size = std::sqrt(cell.solidAngle());
                    const DirectionFit fit = refineDirection(*rays_, rows, start, existing >= 0 ? 0.25 * cell_size : 0.5 * cell_size);
                    Source dom;
                    dom.light = static_cast<int>(li);
                    dom.estimate = true;
                    dom.dominant = true;
                    dom.direct.kind = DirectSource::Kind::kDirection;
                    dom.direct.light = static_cast<int>(li);
                    dom.direct.direction = -fit.direction;
                    {
                        ScopedMs timer(stats_.ms_columns);
                        computeDirect(rad, dom.direct, rad.leaves(Mode::kAll), DirectOptions{}, dom.column);
                    }
                    if (existing >= 0) {
                        d.sources[static_cast<std::size_t>(existing)] = std::move(dom);
                    } else {
                        d.sources.push_back(std::move(dom));
                        source_emission.emplace_back(Eigen::Vector3d::Zero());
                        estimate_index.push_back(static_cast<int>(d.sources.size()) - 1);
                    }
                    // The tags' columns gain the new source.
                    for (std::size_t t = 0; t < tags.size(); ++t) {
                        if (d.tag_columns[t].empty()) continue;
                        d.tag_columns[t].resize(d.sources.size(), 0.0);
                        const std::size_t k = existing >= 0 ? static_cast<std::size_t>(existing) : d.sources.size() - 1;
                        double sum = 0.0;
                        for (std::size_t p = 0; p < tags[t].ring_points.size(); ++p) {
                            sum += directAtPoint(*rays_, d.sources[k].direct, tags[t].ring_points[p], tags[t].normal, 1, p);
                        }
                        d.tag_columns[t][k] = sum / static_cast<double>(std::max<std::size_t>(1, tags[t].ring_points.size()));
                    }
                    d.dominant[static_cast<int>(li)] = fit.direction;
                    // Its shadows are refined, and the direction searched again on the finer
                    // elements, by the next update: a full one.
                    d.direction_fitted = true;
                    d.dominant_frames[static_cast<int>(li)] = std::max<std::uint64_t>(1, observations_->frames());
                }
            }
            std::vector<Eigen::Vector3d> dr(n, Eigen::Vector3d::Zero());
            for (int e : rad.leaves(Mode::kReal)) dr[static_cast<std::size_t>(e)] = direct_real(e);
            ScopedMs timer(stats_.ms_solve);
            without_ = rad.solve(Mode::kReal, rho_, emission_le, dr);
        }
    }

    // The first fit's lights and reflectances make a better source oracle than unit emissions:
    // rebuild the links once with them and update again.
    if (!estimate_index.empty() && !d.links_from_fit) {
        d.links_from_fit = true;
        build_links(source_emission);
        return update(virtual_world_from_object);
    }

    // Step 6: B~, and the virtual objects' influence on it from scratch (lighting/influence.h).
    {
        std::vector<Eigen::Vector3d> dr(n, Eigen::Vector3d::Zero());
        for (int e : rad.leaves(Mode::kReal)) dr[static_cast<std::size_t>(e)] = direct_real(e);
        ScopedMs timer(stats_.ms_solve);
        without_ = rad.solve(Mode::kReal, rho_, emission_le, dr);
    }
    {
        InfluenceBase base;
        for (std::size_t k = 0; k < d.sources.size(); ++k) {
            base.lights.push_back(InfluenceLight{&d.sources[k].direct, &d.sources[k].column, source_emission[k]});
        }
        base.rho = rho_;
        base.emission = emission_le;
        base.radiance = without_.radiance;
        base.indirect = without_.indirect;
        base.radiance_scale = radiance_scale_;
        ScopedMs timer(stats_.ms_base);
        CL_TRY_VOID(d.influence->setBase(std::move(base)));
        d.frames_at_fit = observations_->frames();
        d.solve_emission = emission_le;
    }

    // Step 7: the estimates and warnings, per light.
    for (std::size_t i = 0; i < d.scene.lights.size(); ++i) {
        LightEstimate est;
        est.light = static_cast<int>(i);
        est.estimated = d.scene.lights[i].emission.isEstimate();
        const std::string& name = d.scene.lights[i].name;
        std::string twin;  // another light the observations cannot tell from this one
        double column_weight = 0.0, max_column_weight = 0.0;
        for (std::size_t j = 0; j < estimate_index.size(); ++j) {
            for (int c = 0; c < 3; ++c) max_column_weight = std::max(max_column_weight, fits[static_cast<std::size_t>(c)].column_weight.empty() ? 0.0 : fits[static_cast<std::size_t>(c)].column_weight[j]);
        }
        for (std::size_t k = 0; k < d.sources.size(); ++k) {
            const Source& s = d.sources[k];
            if (s.light != static_cast<int>(i)) continue;
            const auto pos = std::find(estimate_index.begin(), estimate_index.end(), static_cast<int>(k));
            if (s.direct.kind == DirectSource::Kind::kCell) {
                est.cells.push_back(source_emission[k]);
                // A distant light's `emission`: the irradiance its cells give an unoccluded surface
                // facing up (sum of L w cos theta).
                est.emission += source_emission[k] * s.direct.solidAngle() * s.direct.cellCentre().z();
            } else if (s.dominant) {
                est.dominant_direction = -s.direct.direction;
                est.dominant_irradiance = source_emission[k];
                est.emission += source_emission[k] * std::max(0.0, -s.direct.direction.z());
            } else {
                est.emission = source_emission[k];
            }
            if (pos != estimate_index.end()) {
                const auto j = static_cast<std::size_t>(pos - estimate_index.begin());
                for (int c = 0; c < 3; ++c) {
                    est.relative_error[c] = std::max(est.relative_error[c], fits[static_cast<std::size_t>(c)].relative_error[j]);
                    column_weight = std::max(column_weight, fits[static_cast<std::size_t>(c)].column_weight[j]);
                }
                const std::vector<int>& partner = fits[1].indistinguishable_from;
                if (j < partner.size() && partner[j] >= 0) {
                    const Source& other = d.sources[static_cast<std::size_t>(estimate_index[static_cast<std::size_t>(partner[j])])];
                    if (other.light >= 0 && other.light != static_cast<int>(i)) twin = d.scene.lights[static_cast<std::size_t>(other.light)].name;
                }
                est.condition_number = fits[1].condition_number;
                est.negative_in_plain_least_squares = fits[1].negative_in_plain_least_squares;
            }
        }
        if (est.estimated && std::get_if<DistantLightShape>(&d.scene.lights[i].shape) == nullptr) {
            if (max_column_weight > 0.0 && column_weight < 1e-3 * max_column_weight) {
                est.warning = "light '" + name + "' contributes almost nothing to what was observed: its emission is regularised towards 0";
            } else if (!twin.empty()) {
                est.warning = "light '" + name + "' lights what was observed almost exactly as light '" + twin +
                              "' does: only their sum is determined, its share is regularised";
            } else if (!(est.relative_error.maxCoeff() < 0.5)) {
                est.warning = "light '" + name + "' is poorly determined by what was observed (relative error " +
                              std::to_string(est.relative_error.maxCoeff()) + "): its emission is regularised";
            }
        }
        if (!est.warning.empty()) warnings_.push_back(est.warning);
        estimates_.push_back(est);
    }
    if (!estimate_index.empty() && observed_leaves.size() + tags.size() < estimate_index.size()) {
        warnings_.push_back("fewer observed elements (" + std::to_string(observed_leaves.size()) + ") than unknown emissions (" +
                            std::to_string(estimate_index.size()) + "): the answer is regularised");
    }
    if (!estimate_index.empty() && fits[1].scale_from_prior) {
        warnings_.push_back("no surface of known albedo observed (a tag's white border, or an albedo in the scene): the "
                            "emissions' scale assumes a mean reflectance of " + std::to_string(options_.mean_albedo_prior));
    }
    d.last_emission = source_emission;
    // The illuminant's colour for the next frames' highlight test.
    {
        Eigen::Vector3d sum = Eigen::Vector3d::Zero();
        for (const Eigen::Vector3d& e : source_emission) sum += e;
        if (sum.sum() > 0.0) d.illuminant = sum;
    }

    // Step 8: the snapshot's lights and warnings (kept for the incremental updates until the next
    // full one), then the influence, the textures and the probes (finishUpdate()).
    d.probe_lights.clear();
    for (std::size_t k = 0; k < d.sources.size(); ++k) {
        ProbeLight pl;
        pl.source = d.sources[k].direct;
        pl.emission = source_emission[k];
        pl.indirect = d.sources[k].direct.kind == DirectSource::Kind::kCell;
        d.probe_lights.push_back(pl);
    }
    for (const LightEstimate& est : estimates_) {
        const Light& light = d.scene.lights[static_cast<std::size_t>(est.light)];
        EstimatedLight out;
        out.name = light.name;
        out.world_from_object = light.world_from_object;
        out.estimated = est.estimated;
        out.relative_error = est.relative_error.maxCoeff();
        out.warning = est.warning;
        out.emission = est.emission / radiance_scale_;
        if (const auto* area = std::get_if<AreaLightShape>(&light.shape)) {
            out.kind = LightKind::kArea;
            out.size = area->size;
        } else if (const auto* disc = std::get_if<DiscLightShape>(&light.shape)) {
            out.kind = LightKind::kDisc;
            out.radius = disc->radius;
        } else if (std::holds_alternative<PointLightShape>(light.shape)) {
            out.kind = LightKind::kPoint;
        } else if (const auto* dir = std::get_if<DirectionalLightShape>(&light.shape)) {
            out.kind = LightKind::kDirectional;
            out.direction = dir->direction.normalized();
        } else {
            // Distant: its dominant direction as a directional light (the rest is in the probes).
            if (!est.dominant_direction) continue;
            out.name = light.name + "#1";
            out.kind = LightKind::kDirectional;
            out.direction = -*est.dominant_direction;
            out.emission = est.dominant_irradiance / radiance_scale_;
        }
        snapshot.lights.push_back(out);
    }
    snapshot.warnings = warnings_;
    d.last = std::move(snapshot);
    if (d.direction_fitted) d.force_full = true;
    d.textures_all = true;
    return finishUpdate();
}

}  // namespace commonlight::lighting

#include "lighting/estimator.h"
#include "lighting/estimator_impl.h"

#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>
#include <tbb/parallel_reduce.h>
#include <tbb/task_group.h>
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

// The real face the camera's pixel (x, y) sees first, and the point's (s, t) on it: nullopt where
// the pixel has no ray or sees nothing real first.
struct RealHit {
    int face = -1;
    Eigen::Vector3d point = Eigen::Vector3d::Zero();
    Eigen::Vector2d st = Eigen::Vector2d::Zero();
};
std::optional<RealHit> realFaceAt(const RayScene& rays, const std::vector<Face>& faces, const CameraModel& cam,
                                  const Rigid3d& world_from_cam, const Eigen::Matrix3d& rotation, int x, int y,
                                  bool through_virtual = false) {
    const auto ray = cam.unproject(Eigen::Vector2d(x, y));
    if (!ray) return std::nullopt;
    const Eigen::Vector3d dir = rotation * ray->normalized();
    // (The real scene's rays: committed once, never changed; the virtual objects' move per update.)
    const RayHit hit = through_virtual ? rays.intersectReal(world_from_cam.translation, dir)
                                       : rays.intersectAll(world_from_cam.translation, dir);
    if (hit.kind != HitKind::kRealFace) return std::nullopt;
    const Face& f = faces[static_cast<std::size_t>(hit.index)];
    RealHit out;
    out.face = hit.index;
    out.point = world_from_cam.translation + hit.distance * dir;
    Eigen::Matrix<double, 3, 2> b;
    b.col(0) = f.edge_s;
    b.col(1) = f.edge_t;
    out.st = (b.transpose() * b).inverse() * (b.transpose() * (out.point - f.origin));
    return out;
}

}  // namespace

Result<Estimator::TexelRatio> Estimator::texelDirectRatio(const Rigid3d& cam_from_world, int pairs, const std::vector<std::uint8_t>& mask) const {
    const Impl& d = *impl_;
    if (!cam_from_world.isValid()) return fail(ErrorCode::kBadInput, "lighting: the camera pose is not finite");
    const CameraModel& cam = d.camera;
    const std::size_t pixels = static_cast<std::size_t>(cam.width) * static_cast<std::size_t>(cam.height);
    if (!mask.empty() && mask.size() != pixels) return fail(ErrorCode::kUsage, "texelDirectRatio: the mask is not width x height");
    pairs = std::clamp(pairs, 1, 4096);
    TexelRatio out;
    out.texel.assign(pixels, std::nanf(""));
    out.leaf.assign(pixels, std::nanf(""));
    out.face.assign(pixels, -1);
    const Radiosity& rad = *radiosity_;
    const Hierarchy& h = rad.hierarchy();
    const VirtualInfluence& inf = *d.influence;
    const Rigid3d world_from_cam = cam_from_world.inverse();
    const Eigen::Matrix3d rotation = world_from_cam.rotationMatrix();
    constexpr double kPi = std::numbers::pi;
    const auto luma = [](const Eigen::Vector3d& v) { return 0.2126 * v.x() + 0.7152 * v.y() + 0.0722 * v.z(); };
    std::atomic<long> rays{0};
    const auto t0 = std::chrono::steady_clock::now();
    tbb::parallel_for(0, cam.height, [&](int y) {
        for (int x = 0; x < cam.width; ++x) {
            const std::size_t i = static_cast<std::size_t>(y) * static_cast<std::size_t>(cam.width) + static_cast<std::size_t>(x);
            if (!mask.empty() && !mask[i]) continue;
            const std::optional<RealHit> hit = realFaceAt(*rays_, d.real_faces, cam, world_from_cam, rotation, x, y);
            if (!hit) continue;
            const Face& f = d.real_faces[static_cast<std::size_t>(hit->face)];
            const Eigen::Vector3d& p = hit->point;
            const int leaf = h.leafAt(hit->face, hit->st);
            if (leaf < 0 || h[leaf].buried) continue;
            int base = leaf;
            while (inf.refinedElement(base)) base = h[base].parent;
            const auto li = static_cast<std::size_t>(leaf);
            const Eigen::Vector3d rho = inf.reflectance()[li];
            const Eigen::Vector3d ind0 = static_cast<std::size_t>(base) < without_.indirect.size() ? without_.indirect[static_cast<std::size_t>(base)]
                                                                                                   : Eigen::Vector3d::Zero();
            const VirtualInfluence::LeafInfo info = inf.leafInfo(leaf);
            Eigen::Vector3d d_ind = Eigen::Vector3d::Zero();  // the change of the indirect light (and the objects' own light)
            for (int c = 0; c < 3; ++c) {
                if (rho[c] > 1e-6) d_ind[c] = kPi * inf.difference()[li][c] / rho[c] - info.direct[c];
            }
            // Direct light: at the pixel for area lights, the leaf's column for the others.
            Eigen::Vector3d d0 = Eigen::Vector3d::Zero(), dw = Eigen::Vector3d::Zero(), leaf_direct = Eigen::Vector3d::Zero();
            long local_rays = 0;
            for (std::size_t k = 0; k < d.sources.size() && k < d.probe_lights.size(); ++k) {
                const DirectSource& s = d.sources[k].direct;
                const Eigen::Vector3d& e = d.probe_lights[k].emission;
                const double col = li < d.sources[k].column.real.size() ? d.sources[k].column.real[li] : 0.0;
                leaf_direct += col * e;
                if (s.kind != DirectSource::Kind::kPolygon) {
                    d0 += col * e;
                    dw += col * e;
                    continue;
                }
                const LightGeometry& light = *s.polygon;
                const double form = pointToPolygon(p, f.normal, light.polygon, light.normal);
                if (!(form > 0.0)) continue;
                double all = 0.0, open_real = 0.0, open_both = 0.0;
                const std::uint64_t seed = hashCombine(hashCombine(0x7e8e1ull, i), k);
                for (int j = 0; j < pairs; ++j) {
                    const Eigen::Vector3d q = sampleLight(light, stratified2d(seed, j, pairs));
                    const Eigen::Vector3d dv = q - p;
                    const double d2 = dv.squaredNorm();
                    const double w = std::max(0.0, f.normal.dot(dv)) * std::max(0.0, -light.normal.dot(dv)) / (d2 * d2);
                    if (!(w > 0.0)) continue;
                    all += w;
                    ++local_rays;
                    if (rays_->occludedReal(p, f.normal, q, light.normal)) continue;
                    open_real += w;
                    ++local_rays;
                    if (!rays_->occludedVirtual(p, f.normal, q, light.normal)) open_both += w;
                }
                if (!(all > 0.0)) continue;
                d0 += kPi * form * (open_real / all) * e;
                dw += kPi * form * (open_both / all) * e;
            }
            rays += local_rays;
            const Eigen::Vector3d b0 = rho.cwiseProduct(d0 + ind0) / kPi, bw = rho.cwiseProduct(dw + ind0 + d_ind) / kPi;
            const Eigen::Vector3d l0 = rho.cwiseProduct(leaf_direct + ind0) / kPi, lw = rho.cwiseProduct(leaf_direct + info.direct + ind0 + d_ind) / kPi;
            out.face[i] = hit->face;
            if (luma(b0) > 0.0) out.texel[i] = static_cast<float>(luma(bw) / luma(b0));
            if (luma(l0) > 0.0) out.leaf[i] = static_cast<float>(luma(lw) / luma(l0));
        }
    });
    out.ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    out.rays = rays.load();
    return out;
}

Result<Image> Estimator::ratioImage(const LightingSnapshot& snapshot, const Rigid3d& cam_from_world, int stride,
                                    bool through_virtual) const {
    const Impl& d = *impl_;
    if (!cam_from_world.isValid()) return fail(ErrorCode::kBadInput, "lighting: the camera pose is not finite");
    stride = std::max(1, stride);
    const CameraModel& cam = d.camera;
    Image out(PixelFormat::kRgbF32, cam.width, cam.height);
    const float nan = std::nanf("");
    for (int y = 0; y < cam.height; ++y) {
        auto* row = reinterpret_cast<float*>(out.mutableView().row(y));
        std::fill(row, row + 3 * cam.width, nan);
    }
    const Rigid3d world_from_cam = cam_from_world.inverse();
    const Eigen::Matrix3d rotation = world_from_cam.rotationMatrix();
    tbb::parallel_for(0, (cam.height + stride - 1) / stride, [&](int jy) {
        const int y = jy * stride;
        auto* row = reinterpret_cast<float*>(out.mutableView().row(y));
        for (int x = 0; x < cam.width; x += stride) {
            const std::optional<RealHit> hit = realFaceAt(*rays_, d.real_faces, cam, world_from_cam, rotation, x, y, through_virtual);
            if (!hit) continue;
            const Face& f = d.real_faces[static_cast<std::size_t>(hit->face)];
            const FaceModulation* m = snapshot.findFace(f.object_index, f.face_index);
            if (!m || m->width < 1 || m->height < 1) {
                row[3 * x] = row[3 * x + 1] = row[3 * x + 2] = 1.0f;  // nothing changed on this face
                continue;
            }
            const Eigen::Vector2d& st = hit->st;
            // Bilinear between texel centres, clamped at the borders.
            const double u = std::clamp(st.x() * m->width - 0.5, 0.0, m->width - 1.0);
            const double v = std::clamp(st.y() * m->height - 0.5, 0.0, m->height - 1.0);
            const int i0 = static_cast<int>(u), j0 = static_cast<int>(v);
            const int i1 = std::min(i0 + 1, m->width - 1), j1 = std::min(j0 + 1, m->height - 1);
            const float fu = static_cast<float>(u - i0), fv = static_cast<float>(v - j0);
            const Rgb r = (1 - fu) * (1 - fv) * m->ratio[m->texel(i0, j0)] + fu * (1 - fv) * m->ratio[m->texel(i1, j0)] +
                          (1 - fu) * fv * m->ratio[m->texel(i0, j1)] + fu * fv * m->ratio[m->texel(i1, j1)];
            row[3 * x] = r.x();
            row[3 * x + 1] = r.y();
            row[3 * x + 2] = r.z();
        }
    });
    return out;
}

Result<LightingSnapshot> Estimator::incrementalUpdate() {
    stats_ = {};
    return finishUpdate();
}

// The virtual objects' influence brought up to date (incrementally: lighting/influence.h), then
// the snapshot: the textures of the faces that changed, the probes, the solve's summary.
Result<LightingSnapshot> Estimator::finishUpdate() {
    Impl& d = *impl_;
    Radiosity& rad = *radiosity_;
    std::vector<InfluenceObject> objects(d.poses.size());
    for (std::size_t v = 0; v < d.poses.size(); ++v) {
        objects[v].world_from_object = d.poses[v];
        objects[v].present = d.present[v];
        objects[v].emission = d.emission[v];
    }
    std::optional<InfluenceViewer> viewer;
    if (d.viewer) viewer = InfluenceViewer{d.camera, *d.viewer};
    const std::size_t faces = rad.realFaceCount();
    const bool all_faces = d.textures_all || d.face_builds.size() != faces;
    // The area lights' direct light per texel where the objects change it (lighting/texel_direct.h;
    // only when every light is an area light: the others' direct light stays the elements').
    const bool area_only = !d.sources.empty() && std::all_of(d.sources.begin(), d.sources.end(), [](const Source& s) {
        return s.direct.kind == DirectSource::Kind::kPolygon && s.direct.polygon != nullptr;
    });
    const bool texels_on = options_.texel_direct_pairs > 0 && area_only && d.probe_lights.size() == d.sources.size();
    const bool texels_kept = texels_on && !all_faces && d.texels;
    // A full update: the lights' polygons and the real faces stay, only the emissions change; the
    // cache keeps its visibility and forgets what the objects reached since its last textures.
    std::vector<TexelDirectCache::Light> lights;
    std::vector<Face> real_faces;
    if (texels_on && !texels_kept) {
        for (std::size_t k = 0; k < d.sources.size(); ++k) lights.push_back({d.sources[k].direct.polygon, d.probe_lights[k].emission});
        for (std::size_t f = 0; f < faces; ++f) real_faces.push_back(rad.face(static_cast<int>(f)));
    }
    const bool texels_renewed = texels_on && !texels_kept && d.texels && d.texels->sameGeometry(lights, real_faces);
    {
        ScopedMs timer(stats_.ms_influence);
        // Once the objects are committed at their new poses, the texels' answers a move reached go,
        // and those the last textures asked for are made again beside the influence's update (its
        // serial stretches leave a thread idle); the textures below ask for them.
        tbb::task_group ahead;
        struct WaitAhead {
            tbb::task_group& group;
            ~WaitAhead() {
                try {
                    group.wait();
                } catch (...) {  // (only when leaving by an error: the error is reported)
                }
            }
        } wait_ahead{ahead};
        const auto committed = [&] {
            if (!texels_kept && !texels_renewed) return;
            d.texels->forget(texels_kept ? d.influence->movedBalls() : d.texels->movedSinceSeen());
            ahead.run([&d] { d.texels->prefetch(); });
        };
        CL_TRY(stats_.influence, d.influence->update(objects, viewer, committed));
        ahead.wait();
    }
    const VirtualInfluence& inf = *d.influence;
    with_.radiance = inf.radiance();
    with_.summary.iterations = stats_.influence.rounds;
    with_.summary.residual = stats_.influence.residual;
    with_.summary.converged = stats_.influence.residual <= options_.influence.residual;
    with_.summary.elements = static_cast<int>(std::count_if(rad.hierarchy().elements().begin(), rad.hierarchy().elements().end(),
                                                            [](const Element& el) { return el.leaf() && !el.buried; }));
    with_.summary.links = rad.linkCount(Mode::kReal) + stats_.influence.corrections + stats_.influence.cluster_links;
    const auto snapshot_start = std::chrono::steady_clock::now();  // (stats_.ms_snapshot, ended below)
    LightingSnapshot snapshot = d.last;
    snapshot.frames_used = observations_->frames();
    // Textures: every face after a full update, then the faces the influence changed.
    std::vector<int> todo;
    if (all_faces) {
        // A full update: the hierarchy may be new, the lights too; the probes trace afresh.
        d.probe_memories.clear();
        if (d.face_builds.size() != faces) {
            d.face_builds.clear();
            d.face_builds.resize(faces);
        }
        d.textures_all = false;
        for (std::size_t f = 0; f < faces; ++f) todo.push_back(static_cast<int>(f));
    } else {
        todo = inf.changedFaces();
    }
    std::optional<TexelDirect> texel_direct;
    long traced_before = 0;  // (TexelDirectCache::traced() before this update's textures)
    std::vector<Eigen::Vector3d> area_with;
    if (texels_on) {
        if (texels_renewed) {
            d.texels->renew(std::move(lights));
        } else if (!texels_kept) {
            d.texels = std::make_unique<TexelDirectCache>(*rays_, options_.texel_direct_pairs);
            d.texels->reset(std::move(lights), std::move(real_faces));
        }
        // Per element: the lights' sum (its columns' direct light) and that plus the objects' share.
        // The sums depend on the element's number, the columns and the emissions alone, which stand
        // until the next full update (new emissions): kept, and made only for elements added since
        // (refinement appends them). In parallel (each element its own sums; the largest is a
        // maximum, the same in any order).
        const std::size_t n = rad.hierarchy().elements().size();
        std::vector<Eigen::Vector3d>& area_without = d.texel_area_without;
        std::size_t known = texels_kept ? area_without.size() : 0;
        if (known > n) known = 0;  // (elements went: every sum again)
        if (known == 0) d.texel_area_largest = 0.0;
        area_without.resize(n);
        if (known < n) {
            const double largest = tbb::parallel_reduce(
                tbb::blocked_range<std::size_t>(known, n, 1024), 0.0,
                [&](const tbb::blocked_range<std::size_t>& r, double top) {
                    for (std::size_t e = r.begin(); e < r.end(); ++e) {
                        Eigen::Vector3d sum = Eigen::Vector3d::Zero();
                        for (std::size_t k = 0; k < d.sources.size(); ++k) {
                            const auto& col = d.sources[k].column.real;
                            if (e < col.size()) sum += static_cast<double>(col[e]) * d.probe_lights[k].emission;
                        }
                        area_without[e] = sum;
                        top = std::max(top, sum.maxCoeff());
                    }
                    return top;
                },
                [](double a, double b) { return std::max(a, b); });
            d.texel_area_largest = std::max(d.texel_area_largest, largest);
        }
        const double largest = d.texel_area_largest;
        area_with.resize(n);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1024), [&](const tbb::blocked_range<std::size_t>& r) {
            for (std::size_t e = r.begin(); e < r.end(); ++e) area_with[e] = area_without[e] + inf.leafDirect(static_cast<int>(e));
        });
        TexelDirect td;
        td.without = &area_without;
        td.with = &area_with;
        td.threshold = 1e-3 * largest;
        td.oversample = options_.texel_direct_oversample;
        // With a camera, texels at its resolution: 2 / oversample pixels at each face's nearest
        // point (the elements' footprint bound is 2 pixels: they need not follow the penumbrae).
        if (d.viewer) {
            td.face_texel.resize(faces);
            for (std::size_t f = 0; f < faces; ++f) {
                td.face_texel[f] = cameraTexelSize(rad.face(static_cast<int>(f)), d.camera, *d.viewer,
                                                   2.0 / std::max(1, options_.texel_direct_oversample), options_.influence.min_size);
            }
        }
        TexelDirectCache* cache = d.texels.get();
        traced_before = cache->traced();
        td.at = [cache, &rad](int face, std::size_t texel, int w, int h, const Eigen::Vector3d& x, Eigen::Vector3d& d0, Eigen::Vector3d& d1) {
            cache->at(face, texel, w, h, x, rad.face(face).normal, d0, d1);
        };
        td.kept = [cache](int face, std::size_t texel) { return cache->kept(face, texel); };
        td.forgotten = [cache](int face, std::vector<std::uint32_t>& texels) { return cache->takeForgotten(face, texels); };
        texel_direct = std::move(td);
    } else {
        d.texels.reset();
    }
    // A texel is kept while its leaves' values move by less than 1e-3 of their B~ (a thousandth of
    // the ratio; the solver's residual bound is 1e-4 of the largest radiance) and no move reached its
    // own direct light.
    // The probes read what the textures read and write nothing the textures touch: both at once, so
    // that the probes fill the textures' serial tails (a large face's set-up runs on one thread).
    std::vector<VirtualIrradiance> probes;
    tbb::parallel_invoke(
        [&] {
            buildFaceModulations(rad, d.scene, inf.original(), inf.radiance(), inf.reflectance(), todo, d.face_builds, 1e-3,
                                 256, texel_direct ? &*texel_direct : nullptr);
        },
        [&] { probes = buildProbes(rad, d.scene, inf.radiance(), d.probe_lights, 256, &d.probe_memories); });
    if (d.texels) d.texels->seen();
    stats_.texels_built = stats_.texels = 0;
    stats_.texels_traced = d.texels ? d.texels->traced() - traced_before : 0;
    for (int f : todo) {
        const FaceBuild& b = d.face_builds[static_cast<std::size_t>(f)];
        if (!b.modulation) continue;
        stats_.texels_built += b.texels_built;
        stats_.texels += static_cast<long>(b.modulation->ratio.size());
    }
    snapshot.faces.reserve(faces);
    for (const FaceBuild& f : d.face_builds) {
        if (f.modulation) snapshot.faces.push_back(f.modulation);
    }
    snapshot.virtual_objects = std::move(probes);
    snapshot.solve = with_.summary;
    stats_.ms_observe = last_observe_ms_;
    stats_.leaves = with_.summary.elements;
    stats_.ms_snapshot += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - snapshot_start).count();
    if (std::getenv("CL_LIGHTING_DEBUG")) {
        std::fprintf(stderr, "lighting update (%s): observe %.1f columns %.1f links %.1f fit %.1f solve %.1f base %.1f influence %.1f "
                     "(candidates %.1f refine %.1f solve %.1f; hulls made %ld) snapshot %.1f ms; leaves %d; "
                     "texels traced %ld (made ahead since the last reset %ld, of them asked for %ld)\n",
                     stats_.full ? "full" : "incremental", stats_.ms_observe, stats_.ms_columns, stats_.ms_links, stats_.ms_fit,
                     stats_.ms_solve, stats_.ms_base, stats_.ms_influence, stats_.influence.ms_candidates, stats_.influence.ms_refine,
                     stats_.influence.ms_solve, stats_.influence.hulls_made, stats_.ms_snapshot, rad.hierarchy().leafCount(), stats_.texels_traced,
                     d.texels ? d.texels->prefetched() : 0L, d.texels ? d.texels->prefetchUsed() : 0L);
    }
    return snapshot;
}

}  // namespace commonlight::lighting

#include "mocks/sim/path_tracer.h"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace commonlight::mocks::sim {

namespace {

// Slots of a vertex's sampler dimensions.
constexpr int kSlotBsdf = 0;         // 2D: the BSDF sample that continues the path
constexpr int kSlotRoulette = 1;     // 1D: Russian roulette
constexpr int kSlotEnvironment = 2;  // 2D: the NEE sample of the distant environment
constexpr int kSlotFirstLight = 3;   // 2D per light: its NEE sample

// Whether a vertex with this BSDF samples the environment by NEE (then rays its BSDF sampling
// sends out do not collect it) or leaves it to BSDF sampling. Lambertian surfaces: NEE with
// uniform directions over the upper hemisphere, whose integrand is continuous (BSDF sampling
// would see the horizon as a step); GGX: its own lobe sampling, far better for glossy surfaces.
// Either way exactly one technique counts the environment at a vertex: unbiased.
bool samplesEnvironmentByNee(const Bsdf& bsdf) { return bsdf.kind == BsdfKind::kLambertian; }

// The origin of a ray leaving the surface point p on the side of unit normal n (n points to the
// side the ray leaves towards): lifted by epsilon so the ray cannot hit the surface it leaves.
Eigen::Vector3d offsetOrigin(const Eigen::Vector3d& p, const Eigen::Vector3d& n, double epsilon) {
    return p + epsilon * n;
}

}  // namespace

PathTracer::PathTracer(const SimScene& scene, const IntegratorOptions& options)
    : scene_(scene), options_(options), dims_per_vertex_(kSlotFirstLight + static_cast<int>(scene.lights().size())) {}

Eigen::Vector3d PathTracer::radiance(const Ray& ray, const PixelSampler& sampler, int sample,
                                     PrimaryHit* primary) const {
    return trace(ray, nullptr, sampler, sample, primary);
}

Eigen::Vector3d PathTracer::probeRadiance(const Eigen::Vector3d& point, const Eigen::Vector3d& normal,
                                          const PixelSampler& sampler, int sample) const {
    SurfaceHit probe;
    probe.p = point;
    probe.n = normal;
    probe.front = true;
    probe.bsdf = Bsdf::lambertian(Eigen::Vector3d::Ones());
    // The probe is "seen" along -normal, so that wo = normal.
    Ray ray;
    ray.origin = point + normal;
    ray.dir = -normal;
    return trace(ray, &probe, sampler, sample, nullptr);
}

Eigen::Vector3d PathTracer::trace(Ray ray, const SurfaceHit* first_hit, const PixelSampler& sampler, int sample,
                                  PrimaryHit* primary) const {
    const double epsilon = scene_.rayEpsilon();
    Eigen::Vector3d radiance = Eigen::Vector3d::Zero();
    Eigen::Vector3d beta = Eigen::Vector3d::Ones();  // path throughput
    // The previous scattering vertex, for the MIS weight of an area light found by BSDF sampling.
    bool after_scattering = false;
    bool environment_by_nee = false;  // the previous vertex counted the environment by NEE
    double previous_pdf = 0.0;
    Eigen::Vector3d previous_p = Eigen::Vector3d::Zero();

    for (int vertex = 1;; ++vertex) {
        std::optional<SurfaceHit> hit;
        if (vertex == 1 && first_hit != nullptr) {
            hit = *first_hit;
        } else {
            hit = scene_.intersect(ray.origin, ray.dir);
        }
        if (!hit) {
            if (!environment_by_nee) radiance += beta.cwiseProduct(scene_.escapedRadiance(ray.dir));
            break;
        }
        if (vertex == 1 && primary != nullptr) {
            primary->object = hit->object;
            primary->is_virtual = hit->is_virtual;
        }

        // Step 1: emission seen along the ray.
        if (hit->light >= 0) {
            if (hit->front) {
                double weight = 1.0;  // seen from the camera: no other technique finds it
                if (after_scattering) {
                    const double light_pdf = areaLightPdf(scene_.lights()[hit->light], previous_p, hit->p, ray.dir);
                    weight = powerHeuristic(previous_pdf, light_pdf);
                }
                radiance += weight * beta.cwiseProduct(hit->emission);
            }
            break;  // light surfaces absorb
        }
        radiance += beta.cwiseProduct(hit->emission);  // emissive virtual objects: BSDF sampling only
        if (vertex > options_.max_depth || hit->bsdf.isBlack()) break;

        // Step 2: the shading frame, normal turned towards the side the ray came from.
        const Eigen::Vector3d n = hit->front ? hit->n : Eigen::Vector3d(-hit->n);
        const ShadingFrame frame = ShadingFrame::fromNormal(n);
        const Eigen::Vector3d wo = frame.toLocal(-ray.dir);
        // Hard case: a ray exactly parallel to the surface (wo.z == 0) reflects nothing.
        if (!(wo.z() > 0.0)) break;

        // Step 3: next-event estimation.
        radiance += beta.cwiseProduct(directLight(*hit, frame, wo, sampler, sample, vertex));

        // Step 4: continue the path by sampling the BSDF.
        const std::optional<Bsdf::Sample> s = hit->bsdf.sample(wo, sampler.get2D(sample, dimension(vertex, kSlotBsdf)));
        if (!s) break;
        beta = beta.cwiseProduct(s->weight);
        after_scattering = true;
        environment_by_nee = samplesEnvironmentByNee(hit->bsdf);
        previous_pdf = s->pdf;
        previous_p = hit->p;
        ray.origin = offsetOrigin(hit->p, n, epsilon);
        ray.dir = frame.toWorld(s->wi).normalized();

        // Step 5: Russian roulette.
        if (vertex >= options_.rr_start_depth) {
            const double q = std::min(0.95, beta.maxCoeff());
            if (!(q > 0.0) || sampler.get1D(sample, dimension(vertex, kSlotRoulette)) >= q) break;
            beta /= q;  // q > 0 here
        }
    }
    return radiance;
}

Eigen::Vector3d PathTracer::directLight(const SurfaceHit& hit, const ShadingFrame& frame, const Eigen::Vector3d& wo,
                                        const PixelSampler& sampler, int sample, int vertex) const {
    const double epsilon = scene_.rayEpsilon();
    const Eigen::Vector3d origin = offsetOrigin(hit.p, frame.n, epsilon);
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    const Eigen::Vector3d& sky = scene_.environmentRadiance();
    if (sky.maxCoeff() > 0.0 && samplesEnvironmentByNee(hit.bsdf)) {
        // Uniform direction over the upper hemisphere (z uniform in [0, 1)): density 1 / (2 pi).
        const Eigen::Vector2d u = sampler.get2D(sample, dimension(vertex, kSlotEnvironment));
        const double z = u.x();
        const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
        const double phi = 2.0 * std::numbers::pi * u.y();
        const Eigen::Vector3d dir(r * std::cos(phi), r * std::sin(phi), z);
        const Eigen::Vector3d wi = frame.toLocal(dir);
        // Hard case: z = 0 is the horizon, where the sky ends: radiance 0 there (escapedRadiance).
        if (z > 0.0 && wi.z() > 0.0 && !scene_.occluded(origin, dir)) {
            sum += hit.bsdf.eval(wo, wi).cwiseProduct(sky) * (wi.z() * 2.0 * std::numbers::pi);
        }
    }
    const auto& lights = scene_.lights();
    for (std::size_t l = 0; l < lights.size(); ++l) {
        const SimLight& light = lights[l];
        const Eigen::Vector2d u = sampler.get2D(sample, dimension(vertex, kSlotFirstLight + static_cast<int>(l)));
        const std::optional<LightSample> ls = sampleLight(light, hit.p, u);
        if (!ls) continue;
        const Eigen::Vector3d wi = frame.toLocal(ls->wi);
        if (wi.z() <= 0.0) continue;  // the light is behind the surface (on the side the ray did not come from)
        const Eigen::Vector3d f = hit.bsdf.eval(wo, wi);
        if (f.maxCoeff() <= 0.0) continue;
        // Shadow ray up to just before the sampled point.
        if (light.kind == LightKind::kDirectional) {
            if (scene_.occluded(origin, ls->wi)) continue;
        } else {
            const Eigen::Vector3d target = hit.p + ls->distance * ls->wi;
            const double distance = (target - origin).norm();
            if (light.isDelta()) {
                // Hard case: a point light closer than the ray offset is treated as unoccluded.
                const double t_max = distance - epsilon;
                if (t_max > 0.0 && scene_.occluded(origin, ls->wi, t_max)) continue;
            } else {
                // Area light: the light's own surface never occludes; anything within 1e-4 of the
                // distance is taken to be at the light (a wall coplanar with a ceiling panel).
                if (scene_.occludedExceptLight(origin, ls->wi, distance * (1.0 - 1e-4), static_cast<int>(l))) {
                    continue;
                }
            }
        }
        const double weight = light.isDelta() ? 1.0 : powerHeuristic(ls->pdf, hit.bsdf.pdf(wo, wi));
        // ls->pdf > 1e-12 (sampleLight guarantees it): the division is safe.
        sum += f.cwiseProduct(ls->li) * (wi.z() * weight / ls->pdf);
    }
    return sum;
}

Eigen::Vector3d estimateIrradiance(const SimScene& scene, const Eigen::Vector3d& point, const Eigen::Vector3d& normal,
                                   int samples, std::uint64_t seed, const IntegratorOptions& options) {
    const int n = std::max(samples, 1);
    const PathTracer tracer(scene, options);
    const PixelSampler sampler(PixelSampler::pixelSeed(seed, 0, 0), n);
    const Eigen::Vector3d unit_normal = normal.normalized();
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    for (int i = 0; i < n; ++i) {
        const Eigen::Vector3d value = tracer.probeRadiance(point, unit_normal, sampler, i);
        if (value.allFinite()) sum += value;
    }
    // E = pi * L_out of a white Lambertian receiver.
    return sum * (std::numbers::pi / n);
}

}  // namespace commonlight::mocks::sim

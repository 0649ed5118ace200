#include "render/compositor.h"

#include "render/compositor_impl.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <numbers>
#include <string>
#include <utility>

#include <Eigen/Geometry>
#include <opencv2/imgproc.hpp>

#include <sys/resource.h>

#include "core/clock.h"
#include "render/ggx_albedo.h"
#include "render/gl_objects.h"
#include "render/gpu_mesh.h"
#include "render/light_samples.h"
#include "render/shaders.h"
#include "render/snapshot_textures.h"

namespace commonlight::render {

Rect Compositor::Impl::layerRect(const std::vector<std::optional<Eigen::Matrix4f>>& models, const Eigen::Matrix4d& cam_from_world,
                                double margin) const {
    Rect full{0, 0, layer_width - 1, layer_height - 1};
    double x0 = 1e30, y0 = 1e30, x1 = -1e30, y1 = -1e30;
    bool any = false;
    for (std::size_t i = 0; i < models.size(); ++i) {
        if (!models[i]) continue;
        const GpuMesh& m = virtual_meshes[i];
        const Eigen::Matrix4d model = models[i]->cast<double>();
        for (int c = 0; c < 8; ++c) {
            const Eigen::Vector4d corner((c & 1) ? m.bmax.x() : m.bmin.x(), (c & 2) ? m.bmax.y() : m.bmin.y(),
                                         (c & 4) ? m.bmax.z() : m.bmin.z(), 1.0);
            const Eigen::Vector4d p = cam_from_world * (model * corner);
            if (!(p.z() > 0.01)) return full;
            const double u = layer_camera.fx * p.x() / p.z() + layer_camera.cx;
            const double v = layer_camera.fy * p.y() / p.z() + layer_camera.cy;
            if (!std::isfinite(u) || !std::isfinite(v)) return full;
            x0 = std::min(x0, u);
            x1 = std::max(x1, u);
            y0 = std::min(y0, v);
            y1 = std::max(y1, v);
            any = true;
        }
    }
    if (!any) return Rect{};
    // Image rows (down) to GL rows (up); `margin` pixels for the antialiased edge (and a blur).
    Rect r;
    r.x0 = static_cast<int>(std::max(0.0, std::floor(x0 - margin)));
    r.x1 = static_cast<int>(std::min(layer_width - 1.0, std::ceil(x1 + margin)));
    r.y0 = static_cast<int>(std::max(0.0, std::floor(layer_height - 1.0 - y1 - margin)));
    r.y1 = static_cast<int>(std::min(layer_height - 1.0, std::ceil(layer_height - 1.0 - y0 + margin)));
    return r;
}

// The layer pixels (GL rows) that the final pass can read for the camera pixels of `pixels`
// (whole blocks): their ideal positions, and the neighbours the filtering reads, 2 pixels around.
Rect Compositor::Impl::layerRectOfCamera(const Rect& pixels) const {
    Rect r{1 << 30, 1 << 30, -1, -1};
    if (pixels.empty()) return Rect{};
    for (int by = std::max(0, pixels.y0 / kBlock); by <= std::min(blocks_y - 1, pixels.y1 / kBlock); ++by) {
        for (int bx = std::max(0, pixels.x0 / kBlock); bx <= std::min(blocks_x - 1, pixels.x1 / kBlock); ++bx) {
            const Eigen::Vector4f& b = block_bounds[static_cast<std::size_t>(by * blocks_x + bx)];
            if (b[0] > b[2]) continue;  // no pixel of the block has an ideal position
            r.x0 = std::min(r.x0, static_cast<int>(std::floor(b[0])) - 2);
            r.y0 = std::min(r.y0, static_cast<int>(std::floor(b[1])) - 2);
            r.x1 = std::max(r.x1, static_cast<int>(std::floor(b[2])) + 2);
            r.y1 = std::max(r.y1, static_cast<int>(std::floor(b[3])) + 2);
        }
    }
    if (r.x1 < 0) return Rect{};
    return Rect{std::max(0, r.x0), std::max(0, r.y0), std::min(layer_width - 1, r.x1), std::min(layer_height - 1, r.y1)};
}

// The camera pixels whose ideal positions can fall in a layer rectangle (whole blocks; output
// rows are image rows).
Rect Compositor::Impl::cameraRect(const Rect& layer) const {
    Rect r{1 << 30, 1 << 30, -1, -1};
    if (layer.empty()) return Rect{};
    const float lx0 = static_cast<float>(layer.x0), ly0 = static_cast<float>(layer.y0);
    const float lx1 = static_cast<float>(layer.x1 + 1), ly1 = static_cast<float>(layer.y1 + 1);
    for (int by = 0; by < blocks_y; ++by) {
        for (int bx = 0; bx < blocks_x; ++bx) {
            const Eigen::Vector4f& b = block_bounds[static_cast<std::size_t>(by * blocks_x + bx)];
            if (b[2] < lx0 || b[0] > lx1 || b[3] < ly0 || b[1] > ly1) continue;
            r.x0 = std::min(r.x0, bx * kBlock);
            r.y0 = std::min(r.y0, by * kBlock);
            r.x1 = std::max(r.x1, std::min(width, (bx + 1) * kBlock) - 1);
            r.y1 = std::max(r.y1, std::min(height, (by + 1) * kBlock) - 1);
        }
    }
    return r.x1 < 0 ? Rect{} : r;
}

void Compositor::Impl::renderShadowMaps(std::vector<LightSample>& samples, const std::vector<std::optional<Eigen::Matrix4f>>& models,
                                        const Eigen::Vector3d& vmin, const Eigen::Vector3d& vmax, double footprint_px) {
    fitShadowViews(samples, vmin, vmax);
    const Eigen::Vector3d centre = 0.5 * (vmin + vmax);
    const double radius = std::max(0.5 * (vmax - vmin).norm(), 1e-3);
    // The real proxies' maps: refitted when the objects leave their sphere, or have become so much
    // smaller that its texels are too coarse for them.
    if (!(real_shadow_radius > 0.0) || (centre - real_shadow_centre).norm() + radius > real_shadow_radius || radius < real_shadow_radius / 3.0) {
        real_shadow_centre = centre;
        real_shadow_radius = 1.5 * radius;
    }
    for (LightSample& s : samples) s.static_view_proj = shadowView(s, real_shadow_centre, real_shadow_radius);
    const int n = std::max(static_cast<int>(samples.size()), 1);
    const int size = std::clamp(options.shadow_map_size, 64, 4096);
    real_shadows.ensure(n, size);
    virtual_shadows.ensure(n, virtualShadowMapSize(footprint_px, virtual_shadows.size, size));
    std::vector<float> real_key, virtual_key;
    for (const LightSample& s : samples) {
        real_key.insert(real_key.end(), s.static_view_proj.data(), s.static_view_proj.data() + 16);
        virtual_key.insert(virtual_key.end(), s.view_proj.data(), s.view_proj.data() + 16);
    }
    for (const auto& m : models) {
        if (m) virtual_key.insert(virtual_key.end(), m->data(), m->data() + 16);
        virtual_key.push_back(m ? 1.0f : 0.0f);
    }
    real_key.push_back(static_cast<float>(real_shadows.size));
    virtual_key.push_back(static_cast<float>(virtual_shadows.size));
    const auto draw = [&](ShadowAtlas& atlas, bool real) {
        glUseProgram(shadow_program.id);
        glBindFramebuffer(GL_FRAMEBUFFER, atlas.fbo);
        glViewport(0, 0, atlas.cols * atlas.size, atlas.rows * atlas.size);
        glDisable(GL_SCISSOR_TEST);
        glDepthMask(GL_TRUE);
        glClear(GL_DEPTH_BUFFER_BIT);
        glEnable(GL_SCISSOR_TEST);
        glEnable(GL_DEPTH_TEST);
        glDepthFunc(GL_LESS);
        glDisable(GL_CULL_FACE);
        glEnable(GL_POLYGON_OFFSET_FILL);
        glPolygonOffset(2.0f, 4.0f);
        for (const LightSample& s : samples) {
            const int x = (s.layer % atlas.cols) * atlas.size, y = (s.layer / atlas.cols) * atlas.size;
            glViewport(x, y, atlas.size, atlas.size);
            glScissor(x, y, atlas.size, atlas.size);
            setMat4(shadow_program.view_proj, real ? s.static_view_proj : s.view_proj);
            const auto drawMesh = [&](const GpuMesh& mesh, const Eigen::Matrix4f& model) {
                setMat4(shadow_program.model, model);
                glBindVertexArray(mesh.vao);
                for (const MeshPart& part : mesh.shadow_parts.empty() ? mesh.parts : mesh.shadow_parts) drawPart(part);
            };
            if (real) {
                for (std::size_t i = 0; i < real_meshes.size(); ++i) drawMesh(real_meshes[i], real_models[i]);
            } else {
                for (std::size_t i = 0; i < virtual_meshes.size(); ++i) {
                    if (models[i]) drawMesh(virtual_meshes[i], *models[i]);
                }
            }
        }
        glBindVertexArray(0);
        glDisable(GL_POLYGON_OFFSET_FILL);
        glDisable(GL_SCISSOR_TEST);
    };
    if (real_key != real_shadows.key) {
        real_shadows.key = std::move(real_key);
        draw(real_shadows, true);
    }
    if (virtual_key != virtual_shadows.key) {
        virtual_shadows.key = std::move(virtual_key);
        draw(virtual_shadows, false);
    }
}

// The real proxies, single-sampled over the whole layer: each pixel gets the atlas coordinates of
// the modulation of the surface it sees (depth-tested among the proxies).
void Compositor::Impl::drawProxies(const Eigen::Matrix4f& view_proj, const Eigen::Vector3f& camera_centre, const Rect& rect) {
    glBindFramebuffer(GL_FRAMEBUFFER, proxy_fbo);
    glViewport(0, 0, layer_width, layer_height);
    glEnable(GL_SCISSOR_TEST);
    rect.scissor();
    const float none[4] = {1.0f, 1.0f, 1.0f, 1.0f};
    glClearBufferfv(GL_COLOR, 0, none);
    glDepthMask(GL_TRUE);
    glClear(GL_DEPTH_BUFFER_BIT);
    glEnable(GL_DEPTH_TEST);
    glDepthFunc(GL_LESS);
    glDisable(GL_CULL_FACE);
    const ProxyProgram& pp = proxy_program;
    glUseProgram(pp.id);
    setMat4(pp.view_proj, view_proj);
    for (std::size_t i = 0; i < real_meshes.size(); ++i) {
        const GpuMesh& mesh = real_meshes[i];
        setMat4(pp.model, real_models[i]);
        cullProxyBackFaces(mesh, real_models[i], camera_centre);
        glBindVertexArray(mesh.vao);
        for (const MeshPart& part : mesh.parts) {
            const FaceInAtlas* face = part.face >= 0 ? snapshot_textures.face(static_cast<int>(i), part.face) : nullptr;
            glUniform1i(pp.has_mod, face ? 1 : 0);
            if (face) {
                setVec3(pp.c0, face->c0);
                setVec3(pp.du, face->du);
                setVec3(pp.dv, face->dv);
                glUniform4fv(pp.atlas_rect, 1, face->rect.data());
                const Eigen::Vector4f& r = face->rect;
                glUniform4f(pp.clamp, 16.0f * r.x(), 16.0f * r.y(), 16.0f * (r.x() + r.z()), 16.0f * (r.y() + r.w()));
            } else {
                glUniform4f(pp.clamp, 65535.0f, 65535.0f, 65535.0f, 65535.0f);
            }
            drawPart(part);
        }
    }
    glBindVertexArray(0);
    glDisable(GL_CULL_FACE);
    glDisable(GL_DEPTH_TEST);
    glDisable(GL_SCISSOR_TEST);
}

// The proxies' depth (only) in the bound framebuffer, for real objects to hide virtual ones.
void Compositor::Impl::drawProxyDepth(const Eigen::Vector3f& camera_centre) {
    glColorMask(GL_FALSE, GL_FALSE, GL_FALSE, GL_FALSE);
    glUseProgram(shadow_program.id);
    for (std::size_t i = 0; i < real_meshes.size(); ++i) {
        setMat4(shadow_program.model, real_models[i]);
        cullProxyBackFaces(real_meshes[i], real_models[i], camera_centre);
        glBindVertexArray(real_meshes[i].vao);
        for (const MeshPart& part : real_meshes[i].parts) drawPart(part);
    }
    glDisable(GL_CULL_FACE);
    glColorMask(GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
}

// The virtual layer in `rect`. llvmpipe runs a fragment shader once per sample of a multisampled
// target (measured: the full shading cost 3.5x as much at 4 samples as at 1), so the objects are
// shaded once per pixel, at its centre, in a single-sampled target depth-tested against the
// proxies; only their geometry (normal, depth: a cheap shader) is multisampled; the composition
// gives each covered sample the colour of the best matching shaded pixel nearby (kComposeFs:
// silhouettes, creases and overlaps antialiased as with multisampled shading).
void Compositor::Impl::drawVirtualLayer(const Rect& rect, bool proxy_depth_drawn, const Eigen::Matrix4f& view_proj,
                                        const Eigen::Vector3f& camera_centre, const std::vector<LightSample>& samples,
                                        const std::vector<std::optional<Eigen::Matrix4f>>& models,
                                        const lighting::LightingSnapshot& snapshot, double eg) {
    const auto drawObjects = [&](GLint model_location) {
        for (std::size_t i = 0; i < virtual_meshes.size(); ++i) {
            if (!models[i]) continue;
            setMat4(model_location, *models[i]);
            cullBackFaces(virtual_meshes[i]);
            glBindVertexArray(virtual_meshes[i].vao);
            for (const MeshPart& part : virtual_meshes[i].parts) drawPart(part);
        }
        glDisable(GL_CULL_FACE);
    };
    const auto drawLines = [&](const SceneProgram& program, bool colour) {
        glUseProgram(program.id);
        setMat4(program.view_proj, view_proj);
        if (colour) setVec3(program.colour, Eigen::Vector3f(0.1f, 0.9f, 0.2f) / static_cast<float>(eg));
        glDisable(GL_DEPTH_TEST);
        glPolygonMode(GL_FRONT_AND_BACK, GL_LINE);
        for (std::size_t i = 0; i < real_meshes.size(); ++i) {
            setMat4(program.model, real_models[i]);
            glBindVertexArray(real_meshes[i].vao);
            for (const MeshPart& part : real_meshes[i].parts) drawPart(part);
        }
        glPolygonMode(GL_FRONT_AND_BACK, GL_FILL);
        glEnable(GL_DEPTH_TEST);
    };
    glViewport(0, 0, layer_width, layer_height);
    glEnable(GL_SCISSOR_TEST);
    rect.scissor();
    glEnable(GL_DEPTH_TEST);
    glDepthFunc(GL_LESS);
    glDepthMask(GL_TRUE);
    glDisable(GL_CULL_FACE);
    const float clear[4] = {0, 0, 0, 0};

    // Step a: shaded once per pixel, against the proxies' depth (already there when the proxies
    // were drawn for the modulation).
    glBindFramebuffer(GL_FRAMEBUFFER, shade_fbo);
    glClearBufferfv(GL_COLOR, 0, clear);
    glClearBufferfv(GL_COLOR, 1, clear);
    glUseProgram(shadow_program.id);
    setMat4(shadow_program.view_proj, view_proj);
    if (!proxy_depth_drawn) {
        glClear(GL_DEPTH_BUFFER_BIT);
        drawProxyDepth(camera_centre);
    }
    // The frame's uniforms (camera, light samples, shadow maps) in each program that draws.
    const auto setFrameUniforms = [&](const VirtualProgram& vp) {
        glUseProgram(vp.id);
        setMat4(vp.view_proj, view_proj);
        setVec3(vp.camera_centre, camera_centre);
        const int n = static_cast<int>(samples.size());
        glUniform1i(vp.samples, n);
        if (n > 0) {
            std::array<GLint, kMaxLightSamples> kinds{}, layers{};
            std::array<float, 3 * kMaxLightSamples> positions{}, axes{}, powers{};
            std::array<float, 16 * kMaxLightSamples> matrices{};
            for (int k = 0; k < n; ++k) {
                const LightSample& s = samples[static_cast<std::size_t>(k)];
                const std::size_t i = static_cast<std::size_t>(k);
                kinds[i] = s.kind;
                layers[i] = s.layer;
                for (int c = 0; c < 3; ++c) {
                    positions[3 * i + static_cast<std::size_t>(c)] = static_cast<float>(s.position[c]);
                    axes[3 * i + static_cast<std::size_t>(c)] = static_cast<float>(s.axis[c]);
                    powers[3 * i + static_cast<std::size_t>(c)] = static_cast<float>(s.power[c]);
                }
                std::copy(s.view_proj.data(), s.view_proj.data() + 16, matrices.begin() + static_cast<std::ptrdiff_t>(16 * i));
            }
            glUniform1iv(vp.kind, n, kinds.data());
            glUniform1iv(vp.shadow_layer, n, layers.data());
            glUniform3fv(vp.position, n, positions.data());
            glUniform3fv(vp.axis, n, axes.data());
            glUniform3fv(vp.power, n, powers.data());
            glUniformMatrix4fv(vp.shadow_vp, n, GL_FALSE, matrices.data());
            // The real proxies' views, and each sample's tile in each atlas (their map sizes differ).
            std::array<float, 4 * kMaxLightSamples> tiles{}, static_tiles{};
            for (int k = 0; k < n; ++k) {
                const LightSample& s = samples[static_cast<std::size_t>(k)];
                const std::size_t i = static_cast<std::size_t>(k);
                std::copy(s.static_view_proj.data(), s.static_view_proj.data() + 16, matrices.begin() + static_cast<std::ptrdiff_t>(16 * i));
                const Eigen::Vector4f t = s.layer >= 0 ? virtual_shadows.tile(s.layer) : Eigen::Vector4f::Zero();
                std::copy(t.data(), t.data() + 4, tiles.begin() + static_cast<std::ptrdiff_t>(4 * i));
                const Eigen::Vector4f st = s.layer >= 0 ? real_shadows.tile(s.layer) : Eigen::Vector4f::Zero();
                std::copy(st.data(), st.data() + 4, static_tiles.begin() + static_cast<std::ptrdiff_t>(4 * i));
            }
            glUniformMatrix4fv(vp.static_vp, n, GL_FALSE, matrices.data());
            glUniform4fv(vp.shadow_tile, n, tiles.data());
            glUniform4fv(vp.static_tile, n, static_tiles.data());
            glUniform1f(vp.shadow_inset, virtual_shadows.size > 0 ? 0.5f / static_cast<float>(virtual_shadows.size) : 0.0f);
            glUniform1f(vp.static_inset, real_shadows.size > 0 ? 0.5f / static_cast<float>(real_shadows.size) : 0.0f);
            if (vp.radius >= 0) {
                std::array<float, kMaxLightSamples> radii{};
                for (int k = 0; k < n; ++k) radii[static_cast<std::size_t>(k)] = static_cast<float>(samples[static_cast<std::size_t>(k)].radius);
                glUniform1fv(vp.radius, n, radii.data());
            }
        }
    };
    bool any_ggx = false, any_lambertian = false;
    for (std::size_t i = 0; i < virtual_meshes.size(); ++i) {
        if (!models[i]) continue;
        (scene.virtual_objects[i].material.type == MaterialType::kGgx ? any_ggx : any_lambertian) = true;
    }
    if (any_ggx) setFrameUniforms(virtual_ggx_program);
    if (any_lambertian) setFrameUniforms(virtual_program);
    glActiveTexture(GL_TEXTURE0 + kUnitGgxAlbedo);
    glBindTexture(GL_TEXTURE_2D, ggx_albedo_texture);
    glActiveTexture(GL_TEXTURE0 + kUnitStaticShadowMaps);
    glBindTexture(GL_TEXTURE_2D, real_shadows.texture);
    glActiveTexture(GL_TEXTURE0 + kUnitShadowMaps);
    glBindTexture(GL_TEXTURE_2D, virtual_shadows.texture);
    const double scale = snapshot.radiance_scale > 0.0 && std::isfinite(snapshot.radiance_scale) ? snapshot.radiance_scale : 1.0;
    for (std::size_t i = 0; i < virtual_meshes.size(); ++i) {
        if (!models[i]) continue;
        const VirtualObject& object = scene.virtual_objects[i];
        const bool ggx = object.material.type == MaterialType::kGgx;
        const VirtualProgram& vp = ggx ? virtual_ggx_program : virtual_program;
        glUseProgram(vp.id);
        if (ggx) glUniform1f(vp.roughness, static_cast<float>(object.material.roughness));
        setVec3(vp.emission, (object.emission.value_or(Eigen::Vector3d::Zero()) * scale).cast<float>());
        const ProbeGrid* grid = snapshot_textures.probes(i);
        // With nothing estimated yet (and no light to shade with), a neutral light that shows the
        // object at mid grey.
        const bool unlit = grid == nullptr && samples.empty();
        const float ambient = unlit ? static_cast<float>(std::numbers::pi * 0.18 / eg) : 0.0f;
        setVec3(vp.ambient, Eigen::Vector3f::Constant(ambient));
        glUniform1i(vp.has_sh, grid ? 1 : 0);
        if (grid) {
            glActiveTexture(GL_TEXTURE0 + kUnitSh);
            glBindTexture(GL_TEXTURE_3D, grid->texture);
            setVec3(vp.bmin, grid->bmin);
            setVec3(vp.bmax, grid->bmax);
            setVec3(vp.sh_scale, grid->scale);
            setVec3(vp.sh_offset, grid->offset);
        }
        setMat4(vp.model, *models[i]);
        cullBackFaces(virtual_meshes[i]);
        glBindVertexArray(virtual_meshes[i].vao);
        for (const MeshPart& part : virtual_meshes[i].parts) {
            // A part with the mesh file's own base colour: that, times its texture, is the albedo.
            const GpuMaterial* material = part.material >= 0 && static_cast<std::size_t>(part.material) < virtual_meshes[i].materials.size()
                                              ? &virtual_meshes[i].materials[static_cast<std::size_t>(part.material)]
                                              : nullptr;
            setVec3(vp.albedo, material ? material->colour : object.material.albedo.cast<float>());
            glUniform1i(vp.has_texture, material && material->texture != 0 ? 1 : 0);
            if (material && material->texture != 0) {
                glActiveTexture(GL_TEXTURE0 + kUnitBaseColour);
                glBindTexture(GL_TEXTURE_2D, material->texture);
                glActiveTexture(GL_TEXTURE0);
            }
            drawPart(part);
        }
    }
    glActiveTexture(GL_TEXTURE0);
    glDisable(GL_CULL_FACE);
    if (options.debug == DebugView::kProxyWireframe) drawLines(line_program, true);
    mark("virtual shading");

    if (layer_samples > 1) {
        // Step b: the geometry of every sample: the proxies' depth, then the objects.
        glBindFramebuffer(GL_FRAMEBUFFER, layer_fbo);
        glClearBufferfv(GL_COLOR, 0, clear);
        glClear(GL_DEPTH_BUFFER_BIT);
        glUseProgram(shadow_program.id);
        setMat4(shadow_program.view_proj, view_proj);
        drawProxyDepth(camera_centre);
        glUseProgram(geometry_program.id);
        setMat4(geometry_program.view_proj, view_proj);
        glUniform1i(geometry_program.line, 0);
        drawObjects(geometry_program.model);
        if (options.debug == DebugView::kProxyWireframe) {
            glUniform1i(geometry_program.line, 1);
            drawLines(geometry_program, false);
        }
        mark("virtual samples");
        // Step c: each sample's colour from the best matching shaded pixel; their mean.
        glDisable(GL_DEPTH_TEST);
        glBindFramebuffer(GL_FRAMEBUFFER, resolve_fbo);
        glUseProgram(compose_program);
        glUniform1i(compose_sample_count, layer_samples);
        glActiveTexture(GL_TEXTURE0);
        glBindTexture(GL_TEXTURE_2D, shade_texture);
        glActiveTexture(GL_TEXTURE1);
        glBindTexture(GL_TEXTURE_2D, shade_geometry);
        glActiveTexture(GL_TEXTURE2);
        glBindTexture(GL_TEXTURE_2D_MULTISAMPLE, layer_samples_texture);
        glBindVertexArray(empty_vao);
        glDrawArrays(GL_TRIANGLES, 0, 3);
        glActiveTexture(GL_TEXTURE0);
        layer_v = resolve_texture;
    } else {
        layer_v = shade_texture;  // one sample: the shaded colour, alpha 1 where an object is, is the layer
    }
    glBindVertexArray(0);
    glDisable(GL_DEPTH_TEST);
    glDisable(GL_SCISSOR_TEST);
}

// The frame's noise and blur (CPU), and the blur the virtual layer lacks.
Result<void> Compositor::Impl::measureCamera(const ImageView& image) {
    ImageView rgb = image;
    if (image.format == PixelFormat::kYuyv || image.format == PixelFormat::kNv12) {
        match_rgb.reshape(PixelFormat::kRgb8, width, height);
        const int rows = image.format == PixelFormat::kNv12 ? height + height / 2 : height;
        const cv::Mat src(rows, width, image.format == PixelFormat::kNv12 ? CV_8UC1 : CV_8UC2, const_cast<std::uint8_t*>(image.data),
                          image.stride);
        cv::Mat dst(height, width, CV_8UC3, match_rgb.data(), match_rgb.stride());
        cv::cvtColor(src, dst, image.format == PixelFormat::kNv12 ? cv::COLOR_YUV2RGB_NV12 : cv::COLOR_YUV2RGB_YUYV);
        rgb = match_rgb.view();
    }
    CameraMatch m;
    CL_TRY(m.noise, estimateNoise(rgb));
    CL_TRY(m.blur, estimateBlur(rgb, response));
    // The layer's own PSF: its square pixels (MSAA coverage, 1/12 px^2) and the bilinear read
    // through the lens warp; the frame's PSF includes its pixels' integration too.
    m.layer_sigma_px = std::sqrt(1.0 / 12.0 + warp_variance);
    const double extra = m.blur.edges > 0 ? m.blur.sigma_px * m.blur.sigma_px - m.layer_sigma_px * m.layer_sigma_px : 0.0;
    m.added_sigma_px = std::min(2.5, std::sqrt(std::max(0.0, extra)));
    m.frame = frames_drawn;
    match = m;
    return {};
}

// A separable Gaussian of `sigma` pixels over the virtual layer in `rect` (two passes), the result
// then the layer the final pass reads.
Result<void> Compositor::Impl::blurLayer(const Rect& rect, double sigma) {
    if (blur_program == 0) {
        using shaders::programSource;
        CL_TRY(blur_program, gl::newProgram("blur", programSource({}, shaders::kFinalVs), programSource({}, shaders::kBlurFs)));
        blur_direction = loc(blur_program, "u_direction");
        blur_radius = loc(blur_program, "u_radius");
        blur_weights = loc(blur_program, "u_weights");
        blur_rect = loc(blur_program, "u_rect");
        glUseProgram(blur_program);
        glUniform1i(loc(blur_program, "u_layer"), 0);
        for (int k = 0; k < 2; ++k) {
            blur_fbo[k] = gl::newFramebuffer();
            glBindFramebuffer(GL_FRAMEBUFFER, blur_fbo[k]);
            blur_texture[k] = floatTexture(layer_width, layer_height, GL_RGBA16F, GL_RGBA, nullptr, GL_LINEAR);
            glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, blur_texture[k], 0);
            if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
                return fail(ErrorCode::kDevice, "render: the GL cannot make the camera matching's blur framebuffers");
            }
        }
    }
    const int radius = std::clamp(static_cast<int>(std::ceil(3.0 * sigma)), 1, 8);
    std::array<float, 9> weights{};
    float total = 0.0f;
    for (int k = 0; k <= radius; ++k) {
        weights[static_cast<std::size_t>(k)] = static_cast<float>(std::exp(-0.5 * k * k / (sigma * sigma)));
        total += (k == 0 ? 1.0f : 2.0f) * weights[static_cast<std::size_t>(k)];
    }
    for (float& w : weights) w /= total;
    glUseProgram(blur_program);
    glUniform1i(blur_radius, radius);
    glUniform1fv(blur_weights, 9, weights.data());
    glViewport(0, 0, layer_width, layer_height);
    glEnable(GL_SCISSOR_TEST);
    rect.scissor();
    glDisable(GL_DEPTH_TEST);
    glBindVertexArray(empty_vao);
    glActiveTexture(GL_TEXTURE0);
    GLuint input = layer_v;
    for (int pass = 0; pass < 2; ++pass) {
        glBindFramebuffer(GL_FRAMEBUFFER, blur_fbo[pass]);
        glBindTexture(GL_TEXTURE_2D, input);
        glUniform2i(blur_direction, pass == 0 ? 1 : 0, pass == 0 ? 0 : 1);
        glUniform4i(blur_rect, rect.x0, rect.y0, rect.x1, rect.y1);
        glDrawArrays(GL_TRIANGLES, 0, 3);
        input = blur_texture[pass];
    }
    glBindVertexArray(0);
    glDisable(GL_SCISSOR_TEST);
    layer_v = blur_texture[1];
    return {};
}

}  // namespace commonlight::render

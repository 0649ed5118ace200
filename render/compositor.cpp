#include "render/compositor.h"

#include "render/compositor_impl.h"

namespace commonlight::render {

const char* debugViewName(DebugView view) {
    switch (view) {
        case DebugView::kNone: return "composite";
        case DebugView::kProxyWireframe: return "proxies (wireframe)";
        case DebugView::kElements: return "elements (radiosity of the real scene)";
        case DebugView::kRatio: return "ratio B/B~";
        case DebugView::kTags: return "tag detections";
    }
    return "?";
}

DebugView nextDebugView(DebugView view) {
    switch (view) {
        case DebugView::kNone: return DebugView::kProxyWireframe;
        case DebugView::kProxyWireframe: return DebugView::kElements;
        case DebugView::kElements: return DebugView::kRatio;
        case DebugView::kRatio: return DebugView::kTags;
        case DebugView::kTags: return DebugView::kNone;
    }
    return DebugView::kNone;
}

Compositor::Compositor() : impl_(std::make_unique<Impl>()) {}

Result<void> Compositor::Impl::makePrograms() {
    using shaders::programSource;
    const std::string scene_vs = programSource({}, shaders::kSceneVs);
    CL_TRY(shadow_program.id, gl::newProgram("shadow", programSource({}, shaders::kShadowVs), programSource({}, shaders::kShadowFs)));
    shadow_program.model = loc(shadow_program.id, "u_model");
    shadow_program.view_proj = loc(shadow_program.id, "u_view_proj");
    CL_TRY(line_program.id, gl::newProgram("lines", scene_vs, programSource({}, shaders::kLineFs)));
    line_program.model = loc(line_program.id, "u_model");
    line_program.view_proj = loc(line_program.id, "u_view_proj");
    line_program.colour = loc(line_program.id, "u_colour");

    CL_TRY(geometry_program.id, gl::newProgram("geometry", scene_vs, programSource({}, shaders::kGeometryFs)));
    geometry_program.model = loc(geometry_program.id, "u_model");
    geometry_program.view_proj = loc(geometry_program.id, "u_view_proj");
    geometry_program.line = loc(geometry_program.id, "u_line");
    CL_TRY(compose_program, gl::newProgram("compose", programSource({}, shaders::kFinalVs), programSource({}, shaders::kComposeFs)));
    glUseProgram(compose_program);
    glUniform1i(loc(compose_program, "u_shaded"), 0);
    glUniform1i(loc(compose_program, "u_shaded_geometry"), 1);
    glUniform1i(loc(compose_program, "u_samples"), 2);
    compose_sample_count = loc(compose_program, "u_sample_count");
    glUseProgram(0);

    CL_TRY(proxy_program.id, gl::newProgram("proxy", programSource({}, shaders::kProxyVs), programSource({}, shaders::kProxyFs)));
    ProxyProgram& pp = proxy_program;
    pp.model = loc(pp.id, "u_model");
    pp.view_proj = loc(pp.id, "u_view_proj");
    pp.has_mod = loc(pp.id, "u_has_mod");
    pp.c0 = loc(pp.id, "u_c0");
    pp.du = loc(pp.id, "u_du");
    pp.dv = loc(pp.id, "u_dv");
    pp.atlas_rect = loc(pp.id, "u_atlas_rect");
    pp.clamp = loc(pp.id, "u_clamp");

    CL_TRY_VOID(makeVirtualProgram(virtual_program, false));
    CL_TRY_VOID(makeVirtualProgram(virtual_ggx_program, true));

    // The final pass's everyday variants (RGB8 frames); the others are made when first needed.
    for (int bits : {int{kFinalTiles}, kFinalTiles | kFinalModulation, int{kFinalVirtual}, kFinalModulation | kFinalVirtual}) CL_TRY_VOID(finalProgram(bits));
    return {};
}

Result<void> Compositor::Impl::makeVirtualProgram(VirtualProgram& vp, bool ggx) {
    using shaders::programSource;
    const std::string vs = std::string(shaders::kShIrradiance) + shaders::kVirtualVs;
    const std::string fs = ggx ? std::string(shaders::kShIrradiance) + shaders::kVirtualFs : std::string(shaders::kVirtualFs);
    const std::vector<std::string> defines =
        ggx ? std::vector<std::string>{"GGX", "GGX_TABLE_SIZE " + std::to_string(kGgxTableSize) + ".0"} : std::vector<std::string>{};
    CL_TRY(vp.id, gl::newProgram(ggx ? "virtual (ggx)" : "virtual", programSource({}, vs.c_str()), programSource(defines, fs.c_str())));
    vp.model = loc(vp.id, "u_model");
    vp.view_proj = loc(vp.id, "u_view_proj");
    vp.albedo = loc(vp.id, "u_albedo");
    vp.emission = loc(vp.id, "u_emission");
    vp.ambient = loc(vp.id, "u_ambient");
    vp.camera_centre = loc(vp.id, "u_camera_centre");
    vp.samples = loc(vp.id, "u_samples");
    vp.kind = loc(vp.id, "u_kind");
    vp.position = loc(vp.id, "u_position");
    vp.axis = loc(vp.id, "u_axis");
    vp.power = loc(vp.id, "u_power");
    vp.shadow_layer = loc(vp.id, "u_shadow_layer");
    vp.shadow_vp = loc(vp.id, "u_shadow_vp");
    vp.static_vp = loc(vp.id, "u_static_vp");
    vp.shadow_tile = loc(vp.id, "u_shadow_tile");
    vp.shadow_inset = loc(vp.id, "u_shadow_inset");
    vp.static_tile = loc(vp.id, "u_static_tile");
    vp.static_inset = loc(vp.id, "u_static_inset");
    vp.has_sh = loc(vp.id, "u_has_sh");
    vp.bmin = loc(vp.id, "u_bmin");
    vp.bmax = loc(vp.id, "u_bmax");
    vp.sh_scale = loc(vp.id, "u_sh_scale");
    vp.sh_offset = loc(vp.id, "u_sh_offset");
    vp.sh_depth = loc(vp.id, "u_sh_depth");
    vp.has_texture = loc(vp.id, "u_has_texture");
    vp.roughness = loc(vp.id, "u_roughness");
    vp.radius = loc(vp.id, "u_radius");
    glUseProgram(vp.id);
    glUniform1i(loc(vp.id, "u_shadow_maps"), kUnitShadowMaps);
    glUniform1i(loc(vp.id, "u_static_maps"), kUnitStaticShadowMaps);
    glUniform1i(loc(vp.id, "u_sh"), kUnitSh);
    glUniform1i(loc(vp.id, "u_base_colour"), kUnitBaseColour);
    if (ggx) glUniform1i(loc(vp.id, "u_ggx_albedo"), kUnitGgxAlbedo);
    glUniform1f(vp.sh_depth, 1.0f / 9.0f);
    glUseProgram(0);
    return {};
}

Result<const FinalProgram*> Compositor::Impl::finalProgram(int bits) {
    if (const auto it = final_programs.find(bits); it != final_programs.end()) return &it->second;
    std::vector<std::string> defines;
    defines.push_back((bits & kFinalYuyv) ? "FRAME_YUYV" : (bits & kFinalNv12) ? "FRAME_NV12" : "FRAME_RGB8");
    if (bits & kFinalModulation) defines.push_back("MODULATION");
    if (bits & kFinalVirtual) defines.push_back("VIRTUAL");
    if (bits & kFinalElements) defines.push_back("VIEW_ELEMENTS");
    if (bits & kFinalRatio) defines.push_back("VIEW_RATIO");
    if (bits & kFinalNoise) defines.push_back("MATCH_NOISE");
    defines.push_back("MODULATION_EPSILON " + std::to_string(kModulationEpsilon));
    FinalProgram p;
    const char* vs = (bits & kFinalTiles) ? shaders::kTileVs : shaders::kFinalVs;
    CL_TRY(p.id, gl::newProgram("final", shaders::programSource({}, vs), shaders::programSource(defines, shaders::kFinalFs)));
    p.atlas_size = loc(p.id, "u_atlas_size");
    p.layer_rect = loc(p.id, "u_layer_rect");
    p.exposure_gain = loc(p.id, "u_exposure_gain");
    p.size = loc(p.id, "u_size");
    p.noise = loc(p.id, "u_noise");
    p.seed = loc(p.id, "u_seed");
    glUseProgram(p.id);
    const std::pair<const char*, int> units[] = {{"u_frame", kUnitFrame},         {"u_frame_uv", kUnitFrameUv},
                                                 {"u_undistort", kUnitUndistort}, {"u_proxy_atlas", kUnitProxyAtlas},
                                                 {"u_atlas_m", kUnitAtlasM},      {"u_atlas_d", kUnitAtlasD},
                                                 {"u_atlas_o", kUnitAtlasO},      {"u_layer_v", kUnitLayerV}};
    for (const auto& [name, unit] : units) {
        if (const GLint l = loc(p.id, name); l >= 0) glUniform1i(l, unit);
    }
    if (const GLuint block = glGetUniformBlockIndex(p.id, "ToLinear"); block != GL_INVALID_INDEX) glUniformBlockBinding(p.id, block, 0);
    if (const GLuint block = glGetUniformBlockIndex(p.id, "ToCode"); block != GL_INVALID_INDEX) glUniformBlockBinding(p.id, block, 1);
    glUniform2i(p.size, layer_width, layer_height);
    glUseProgram(0);
    return &(final_programs[bits] = p);
}

Result<void> Compositor::Impl::makeLayerTargets() {
    GLint max_samples = 0, max_texture_samples = 0, max_format_samples = 0;
    glGetIntegerv(GL_MAX_SAMPLES, &max_samples);
    glGetIntegerv(GL_MAX_COLOR_TEXTURE_SAMPLES, &max_texture_samples);
    glGetInternalformativ(GL_TEXTURE_2D_MULTISAMPLE, GL_RGBA16F, GL_SAMPLES, 1, &max_format_samples);
    max_samples = std::min(max_samples, max_texture_samples);
    if (max_format_samples > 0) max_samples = std::min(max_samples, max_format_samples);
    // More samples than the GL has: the most it has (llvmpipe: 4). One sample: no multisampled pass.
    const int samples = options.msaa_samples > 1 ? std::min(options.msaa_samples, static_cast<int>(max_samples)) : 1;
    if (samples == layer_samples) return {};
    gl::deleteTexture(layer_samples_texture);
    gl::deleteRenderbuffer(layer_depth);
    gl::deleteFramebuffer(layer_fbo);
    layer_samples = samples;
    if (samples <= 1) return {};
    layer_fbo = gl::newFramebuffer();
    glBindFramebuffer(GL_FRAMEBUFFER, layer_fbo);
    layer_samples_texture = gl::newTexture();
    glBindTexture(GL_TEXTURE_2D_MULTISAMPLE, layer_samples_texture);
    glTexImage2DMultisample(GL_TEXTURE_2D_MULTISAMPLE, samples, GL_RGBA16F, layer_width, layer_height, GL_TRUE);
    glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D_MULTISAMPLE, layer_samples_texture, 0);
    layer_depth = gl::newRenderbuffer();
    glBindRenderbuffer(GL_RENDERBUFFER, layer_depth);
    glRenderbufferStorageMultisample(GL_RENDERBUFFER, samples, GL_DEPTH_COMPONENT24, layer_width, layer_height);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, layer_depth);
    if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
        layer_samples = -1;
        return fail(ErrorCode::kDevice, "render: the GL cannot make a " + std::to_string(samples) + "x multisampled float framebuffer");
    }
    return {};
}

void Compositor::Impl::makeFrameTextures(PixelFormat format) {
    if (format == frame_format) return;
    gl::deleteTexture(frame_texture);
    gl::deleteTexture(frame_uv_texture);
    switch (format) {
        case PixelFormat::kYuyv: frame_texture = byteTexture(width / 2, height, GL_RGBA8UI, GL_RGBA_INTEGER); break;
        case PixelFormat::kNv12:
            frame_texture = byteTexture(width, height, GL_R8UI, GL_RED_INTEGER);
            frame_uv_texture = byteTexture(width / 2, height / 2, GL_RG8UI, GL_RG_INTEGER);
            break;
        default: frame_texture = byteTexture(width, height, GL_RGB8, GL_RGB); break;
    }
    frame_format = format;
}

// The frame's bytes into the pixel buffer (rows packed), then into its texture(s) as they are.
void Compositor::Impl::uploadFrame(const ImageView& image) {
    makeFrameTextures(image.format);
    const bool nv12 = image.format == PixelFormat::kNv12;
    const std::size_t row = image.format == PixelFormat::kRgb8 ? 3 * static_cast<std::size_t>(width)
                            : image.format == PixelFormat::kYuyv ? 2 * static_cast<std::size_t>(width)
                                                                 : static_cast<std::size_t>(width);
    const int rows = nv12 ? height + height / 2 : height;
    glBindBuffer(GL_PIXEL_UNPACK_BUFFER, frame_pbo);
    glBufferData(GL_PIXEL_UNPACK_BUFFER, static_cast<GLsizeiptr>(row * static_cast<std::size_t>(rows)), nullptr, GL_STREAM_DRAW);
    if (auto* dst = static_cast<std::uint8_t*>(glMapBuffer(GL_PIXEL_UNPACK_BUFFER, GL_WRITE_ONLY))) {
        for (int y = 0; y < rows; ++y) std::memcpy(dst + row * static_cast<std::size_t>(y), image.row(y), row);
        glUnmapBuffer(GL_PIXEL_UNPACK_BUFFER);
    }
    glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
    glBindTexture(GL_TEXTURE_2D, frame_texture);
    switch (image.format) {
        case PixelFormat::kYuyv: glTexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, width / 2, height, GL_RGBA_INTEGER, GL_UNSIGNED_BYTE, nullptr); break;
        case PixelFormat::kNv12: {
            glTexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, width, height, GL_RED_INTEGER, GL_UNSIGNED_BYTE, nullptr);
            glBindTexture(GL_TEXTURE_2D, frame_uv_texture);
            const std::size_t offset = row * static_cast<std::size_t>(height);
            glTexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, width / 2, height / 2, GL_RG_INTEGER, GL_UNSIGNED_BYTE,
                            reinterpret_cast<void*>(static_cast<std::uintptr_t>(offset)));
            break;
        }
        default: glTexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, width, height, GL_RGB, GL_UNSIGNED_BYTE, nullptr); break;
    }
    glBindBuffer(GL_PIXEL_UNPACK_BUFFER, 0);
}

// Every camera pixel's ideal (undistorted) position in the layer's texel coordinates (GL rows),
// and the layer that holds them all: the camera's pinhole with a margin (barrel distortion puts
// the corners' ideal positions outside the camera's own rectangle).
void Compositor::Impl::makeUndistortMap() {
    const std::size_t n = static_cast<std::size_t>(width) * static_cast<std::size_t>(height);
    std::vector<Eigen::Vector2f> ideal(n, Eigen::Vector2f::Constant(kNoIdeal));
    Eigen::Vector2d lo(0.0, 0.0), hi(width - 1.0, height - 1.0);
    // Hard case: beyond the fold of a strong barrel distortion ideal positions run far out; the
    // layer covers at most twice the camera's size around it, and pixels beyond show no layer.
    const Eigen::Vector2d limit_lo(-0.5 * width, -0.5 * height), limit_hi(1.5 * width, 1.5 * height);
    for (int y = 0; y < height; ++y) {
        for (int x = 0; x < width; ++x) {
            const std::optional<Eigen::Vector2d> p = camera.undistortPixel(Eigen::Vector2d(x, y));
            if (!p || !p->allFinite() || (p->array() < limit_lo.array()).any() || (p->array() > limit_hi.array()).any()) continue;
            ideal[static_cast<std::size_t>(y) * static_cast<std::size_t>(width) + static_cast<std::size_t>(x)] = p->cast<float>();
            lo = lo.cwiseMin(*p);
            hi = hi.cwiseMax(*p);
        }
    }
    // Two pixels of margin: bilinear reads and the rectangles' rounding.
    layer_origin = Eigen::Vector2i(static_cast<int>(std::floor(lo.x())) - 2, static_cast<int>(std::floor(lo.y())) - 2);
    layer_width = static_cast<int>(std::ceil(hi.x())) + 2 - layer_origin.x() + 1;
    layer_height = static_cast<int>(std::ceil(hi.y())) + 2 - layer_origin.y() + 1;
    layer_camera = camera;
    layer_camera.width = layer_width;
    layer_camera.height = layer_height;
    layer_camera.cx = camera.cx - layer_origin.x();
    layer_camera.cy = camera.cy - layer_origin.y();
    layer_camera.distortion = Distortion{};

    std::vector<float> map(2 * n);
    warp_variance = 0.0;
    std::size_t warp_pixels = 0;
    blocks_x = (width + kBlock - 1) / kBlock;
    blocks_y = (height + kBlock - 1) / kBlock;
    block_bounds.assign(static_cast<std::size_t>(blocks_x) * static_cast<std::size_t>(blocks_y),
                        Eigen::Vector4f(1e9f, 1e9f, -1e9f, -1e9f));
    for (int y = 0; y < height; ++y) {
        for (int x = 0; x < width; ++x) {
            const std::size_t k = static_cast<std::size_t>(y) * static_cast<std::size_t>(width) + static_cast<std::size_t>(x);
            Eigen::Vector2f t = Eigen::Vector2f::Constant(kNoIdeal);
            if (ideal[k].x() != kNoIdeal) {
                // Texel coordinates: x + 0.5 from the layer's left, rows counted from its bottom.
                t = Eigen::Vector2f(ideal[k].x() - static_cast<float>(layer_origin.x()) + 0.5f,
                                    static_cast<float>(layer_height) - (ideal[k].y() - static_cast<float>(layer_origin.y())) - 0.5f);
                const Eigen::Vector2f f = t - t.array().floor().matrix() - Eigen::Vector2f::Constant(0.5f);  // offset from the texel's centre
                const Eigen::Vector2f g = f.array().abs().matrix();
                warp_variance += 0.5 * static_cast<double>(g.x() * (1.0f - g.x()) + g.y() * (1.0f - g.y()));
                ++warp_pixels;
                Eigen::Vector4f& b = block_bounds[static_cast<std::size_t>(y / kBlock * blocks_x + x / kBlock)];
                b = Eigen::Vector4f(std::min(b[0], t.x()), std::min(b[1], t.y()), std::max(b[2], t.x()), std::max(b[3], t.y()));
            }
            map[2 * k] = t.x();
            map[2 * k + 1] = t.y();
        }
    }
    undistort_texture = floatTexture(width, height, GL_RG32F, GL_RG, map.data(), GL_NEAREST);
    warp_variance = warp_pixels > 0 ? warp_variance / static_cast<double>(warp_pixels) : 0.0;
}

// The layer pixels the virtual objects can cover: their bounding boxes' corners through the
// layer's pinhole, plus a margin. Everything when a corner is at or behind the camera's plane.
void Compositor::Impl::releaseAll() {
    snapshot_textures.release();
    gl::deleteTexture(layer_samples_texture);
    gl::deleteRenderbuffer(layer_depth);
    gl::deleteFramebuffer(layer_fbo);
    gl::deleteTexture(resolve_texture);
    gl::deleteFramebuffer(resolve_fbo);
    gl::deleteTexture(shade_texture);
    gl::deleteTexture(shade_geometry);
    gl::deleteFramebuffer(shade_fbo);
    gl::deleteTexture(proxy_atlas);
    gl::deleteRenderbuffer(proxy_depth);
    gl::deleteFramebuffer(proxy_fbo);
    gl::deleteTexture(output_texture);
    gl::deleteFramebuffer(output_fbo);
    virtual_shadows.release();
    real_shadows.release();
    for (GpuMesh& m : real_meshes) releaseMesh(m);
    for (GpuMesh& m : virtual_meshes) releaseMesh(m);
    gl::deleteVertexArray(empty_vao);
    gl::deleteVertexArray(tile_vao);
    gl::deleteBuffer(tile_vbo);
    gl::deleteTexture(frame_texture);
    gl::deleteTexture(frame_uv_texture);
    gl::deleteBuffer(frame_pbo);
    gl::deleteTexture(undistort_texture);
    gl::deleteBuffer(to_linear_ubo);
    gl::deleteBuffer(to_code_ubo);
    gl::deleteTexture(ggx_albedo_texture);
    for (GLuint* p : {&shadow_program.id, &line_program.id, &geometry_program.id, &compose_program, &proxy_program.id, &virtual_program.id,
                      &virtual_ggx_program.id}) {
        gl::deleteProgram(*p);
    }
    for (auto& [bits, p] : final_programs) gl::deleteProgram(p.id);
    gl::deleteProgram(blur_program);
    for (int k = 0; k < 2; ++k) {
        gl::deleteTexture(blur_texture[k]);
        gl::deleteFramebuffer(blur_fbo[k]);
    }
    gl::deleteProgram(world_program);
    gl::deleteProgram(warp_program);
    gl::deleteTexture(world_texture);
    gl::deleteFramebuffer(world_fbo);
    gl::deleteTexture(warp_texture);
    gl::deleteFramebuffer(warp_fbo);
    final_programs.clear();
}

Result<std::unique_ptr<Compositor>> Compositor::create(GlContext& context, const Scene& scene, const CameraModel& camera,
                                                       const ResponseCurve& response, const CompositorOptions& options) {
    if (camera.width <= 0 || camera.height <= 0) return fail(ErrorCode::kBadInput, "render: the camera has no size");
    auto compositor = std::unique_ptr<Compositor>(new Compositor());
    Impl& d = *compositor->impl_;
    d.context = &context;
    d.scene = scene;
    d.camera = camera;
    d.response = response;
    d.options = options;
    d.width = camera.width;
    d.height = camera.height;
    context.makeCurrent();
    d.makeUndistortMap();
    CL_TRY_VOID(d.makePrograms());
    d.empty_vao = gl::newVertexArray();
    d.makeTileBuffers();
    for (const RealObject& o : scene.real_objects) {
        d.real_meshes.push_back(uploadMesh(o.shape));
        d.real_models.push_back(toGl(o.world_from_object));
    }
    for (const VirtualObject& o : scene.virtual_objects) d.virtual_meshes.push_back(uploadMesh(o.shape));
    d.frame_pbo = gl::newBuffer();
    d.makeFrameTextures(PixelFormat::kRgb8);

    // The camera's response both ways, as uniform buffers (llvmpipe gathers from them several
    // times faster than it fetches texels).
    std::vector<float> lin(256 * 4, 0.0f), code(kToCodeSize * 4, 0.0f);
    for (int k = 0; k < 256; ++k) {
        for (int c = 0; c < 3; ++c) lin[static_cast<std::size_t>(4 * k + c)] = response.toLinear(c, static_cast<std::uint8_t>(k));
    }
    for (int k = 0; k < kToCodeSize; ++k) {
        const double s = static_cast<double>(k) / (kToCodeSize - 1);
        for (int c = 0; c < 3; ++c) code[static_cast<std::size_t>(4 * k + c)] = response.toEncoded(c, static_cast<float>(s * s));
    }
    d.to_linear_ubo = gl::newBuffer();
    glBindBuffer(GL_UNIFORM_BUFFER, d.to_linear_ubo);
    glBufferData(GL_UNIFORM_BUFFER, static_cast<GLsizeiptr>(lin.size() * sizeof(float)), lin.data(), GL_STATIC_DRAW);
    d.to_code_ubo = gl::newBuffer();
    glBindBuffer(GL_UNIFORM_BUFFER, d.to_code_ubo);
    glBufferData(GL_UNIFORM_BUFFER, static_cast<GLsizeiptr>(code.size() * sizeof(float)), code.data(), GL_STATIC_DRAW);
    glBindBuffer(GL_UNIFORM_BUFFER, 0);
    // The GGX lobe's directional albedo, for the indirect light on `type: ggx` objects.
    const std::vector<float> ggx_table = ggxAlbedoTable(kGgxTableSize, kGgxTableSamples);
    d.ggx_albedo_texture = floatTexture(kGgxTableSize, kGgxTableSize, GL_RG32F, GL_RG, ggx_table.data(), GL_LINEAR);

    // Targets: the proxies' atlas coordinates, the virtual layer (multisampled) and its resolve, the output.
    d.proxy_fbo = gl::newFramebuffer();
    glBindFramebuffer(GL_FRAMEBUFFER, d.proxy_fbo);
    d.proxy_atlas = byteTexture(d.layer_width, d.layer_height, GL_RGBA8, GL_RGBA);
    glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, d.proxy_atlas, 0);
    d.proxy_depth = gl::newRenderbuffer();
    glBindRenderbuffer(GL_RENDERBUFFER, d.proxy_depth);
    glRenderbufferStorage(GL_RENDERBUFFER, GL_DEPTH_COMPONENT24, d.layer_width, d.layer_height);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, d.proxy_depth);
    if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
        return fail(ErrorCode::kDevice, "render: the GL cannot make the proxies' framebuffer");
    }
    d.shade_fbo = gl::newFramebuffer();
    glBindFramebuffer(GL_FRAMEBUFFER, d.shade_fbo);
    d.shade_texture = floatTexture(d.layer_width, d.layer_height, GL_RGBA16F, GL_RGBA, nullptr, GL_LINEAR);
    glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, d.shade_texture, 0);
    d.shade_geometry = floatTexture(d.layer_width, d.layer_height, GL_RGBA16F, GL_RGBA, nullptr, GL_NEAREST);
    glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT1, GL_TEXTURE_2D, d.shade_geometry, 0);
    const GLenum shade_buffers[2] = {GL_COLOR_ATTACHMENT0, GL_COLOR_ATTACHMENT1};
    glDrawBuffers(2, shade_buffers);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, d.proxy_depth);
    if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
        return fail(ErrorCode::kDevice, "render: the GL cannot make the virtual objects' float framebuffer");
    }
    CL_TRY_VOID(d.makeLayerTargets());
    d.resolve_fbo = gl::newFramebuffer();
    glBindFramebuffer(GL_FRAMEBUFFER, d.resolve_fbo);
    d.resolve_texture = floatTexture(d.layer_width, d.layer_height, GL_RGBA16F, GL_RGBA, nullptr, GL_LINEAR);
    glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, d.resolve_texture, 0);
    if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
        return fail(ErrorCode::kDevice, "render: the GL cannot make the float resolve framebuffer");
    }
    d.output_fbo = gl::newFramebuffer();
    d.output_texture = gl::newTexture();
    glBindTexture(GL_TEXTURE_2D, d.output_texture);
    glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA8, d.width, d.height, 0, GL_RGBA, GL_UNSIGNED_BYTE, nullptr);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
    glBindFramebuffer(GL_FRAMEBUFFER, d.output_fbo);
    glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, d.output_texture, 0);
    if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
        return fail(ErrorCode::kDevice, "render: the GL cannot make the output framebuffer");
    }
    glBindFramebuffer(GL_FRAMEBUFFER, 0);
    return compositor;
}

Compositor::~Compositor() {
    if (!impl_ || impl_->context == nullptr) return;
    impl_->context->makeCurrent();
    impl_->releaseAll();
}

void Compositor::setOptions(const CompositorOptions& options) { impl_->options = options; }
const CompositorOptions& Compositor::options() const noexcept { return impl_->options; }
const std::vector<PassTime>& Compositor::passTimes() const noexcept { return impl_->pass_times; }
const FinalPassArea& Compositor::finalPassArea() const noexcept { return impl_->final_area; }
const std::optional<CameraMatch>& Compositor::cameraMatch() const noexcept { return impl_->match; }

Result<std::vector<Eigen::Vector4f>> Compositor::surfacePoints(const FrameInput& frame) {
    Impl& d = *impl_;
    d.context->makeCurrent();
    std::vector<Eigen::Vector4f> points(static_cast<std::size_t>(d.width) * static_cast<std::size_t>(d.height), Eigen::Vector4f::Zero());
    if (!frame.cam_from_world || !frame.cam_from_world->isValid()) return points;
    if (d.world_program == 0) {
        using shaders::programSource;
        CL_TRY(d.world_program, gl::newProgram("world", programSource({}, shaders::kSceneVs), programSource({}, shaders::kWorldFs)));
        d.world_model = loc(d.world_program, "u_model");
        d.world_view_proj = loc(d.world_program, "u_view_proj");
        d.world_surface = loc(d.world_program, "u_surface");
        CL_TRY(d.warp_program, gl::newProgram("warp", programSource({}, shaders::kFinalVs), programSource({}, shaders::kWarpFs)));
        glUseProgram(d.warp_program);
        glUniform1i(loc(d.warp_program, "u_undistort"), 0);
        glUniform1i(loc(d.warp_program, "u_world"), 1);
        glUniform2i(loc(d.warp_program, "u_size"), d.layer_width, d.layer_height);
        d.world_fbo = gl::newFramebuffer();
        glBindFramebuffer(GL_FRAMEBUFFER, d.world_fbo);
        d.world_texture = floatTexture(d.layer_width, d.layer_height, GL_RGBA32F, GL_RGBA, nullptr, GL_LINEAR);
        glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, d.world_texture, 0);
        glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, d.proxy_depth);
        d.warp_fbo = gl::newFramebuffer();
        glBindFramebuffer(GL_FRAMEBUFFER, d.warp_fbo);
        d.warp_texture = floatTexture(d.width, d.height, GL_RGBA32F, GL_RGBA, nullptr, GL_NEAREST);
        glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, d.warp_texture, 0);
        if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE) {
            return fail(ErrorCode::kDevice, "render: the GL cannot make the RGBA32F framebuffers of surfacePoints");
        }
    }
    // The layer: every proxy and virtual object's world position, depth-tested, with the same
    // view and projection as draw()'s.
    Eigen::Matrix4d view = Eigen::Matrix4d::Identity();
    view.topLeftCorner<3, 3>() = frame.cam_from_world->rotation.toRotationMatrix();
    view.topRightCorner<3, 1>() = frame.cam_from_world->translation;
    view.row(1) *= -1.0;
    view.row(2) *= -1.0;
    const Eigen::Matrix4f view_proj = (d.layer_camera.glProjection(0.01, 100.0) * view).cast<float>();
    glBindFramebuffer(GL_FRAMEBUFFER, d.world_fbo);
    glViewport(0, 0, d.layer_width, d.layer_height);
    const float none[4] = {0, 0, 0, 0};
    glClearBufferfv(GL_COLOR, 0, none);
    glDepthMask(GL_TRUE);
    glClear(GL_DEPTH_BUFFER_BIT);
    glEnable(GL_DEPTH_TEST);
    glDepthFunc(GL_LESS);
    glDisable(GL_CULL_FACE);
    glUseProgram(d.world_program);
    setMat4(d.world_view_proj, view_proj);
    float surface = 0.0f;
    const auto draw = [&](const GpuMesh& mesh, const Eigen::Matrix4f& model) {
        glUniform1f(d.world_surface, surface += 1.0f);
        setMat4(d.world_model, model);
        glBindVertexArray(mesh.vao);
        for (const MeshPart& part : mesh.parts) drawPart(part);
    };
    for (std::size_t i = 0; i < d.real_meshes.size(); ++i) draw(d.real_meshes[i], d.real_models[i]);
    for (std::size_t i = 0; i < d.virtual_meshes.size(); ++i) {
        std::optional<Rigid3d> pose = i < frame.virtual_poses.size() ? frame.virtual_poses[i]
                                                                      : worldFromObject(d.scene.virtual_objects[i], d.scene.tags, 0.0);
        if (pose && pose->isValid()) draw(d.virtual_meshes[i], toGl(*pose));
    }
    glDisable(GL_DEPTH_TEST);
    // The warp at every camera pixel.
    glBindFramebuffer(GL_FRAMEBUFFER, d.warp_fbo);
    glViewport(0, 0, d.width, d.height);
    glUseProgram(d.warp_program);
    glActiveTexture(GL_TEXTURE0);
    glBindTexture(GL_TEXTURE_2D, d.undistort_texture);
    glActiveTexture(GL_TEXTURE1);
    glBindTexture(GL_TEXTURE_2D, d.world_texture);
    glBindVertexArray(d.empty_vao);
    glDrawArrays(GL_TRIANGLES, 0, 3);
    glBindVertexArray(0);
    glActiveTexture(GL_TEXTURE0);
    glPixelStorei(GL_PACK_ALIGNMENT, 4);
    glReadPixels(0, 0, d.width, d.height, GL_RGBA, GL_FLOAT, points.data());
    glBindFramebuffer(GL_FRAMEBUFFER, 0);
    const GLenum error = glGetError();
    if (error != GL_NO_ERROR) return fail(ErrorCode::kInternal, "render: GL error " + std::to_string(error) + " in surfacePoints");
    return points;
}

Result<void> Compositor::draw(const FrameInput& frame, const lighting::LightingSnapshot& snapshot) {
    Impl& d = *impl_;
    const PixelFormat format = frame.image.format;
    const bool yuv = format == PixelFormat::kYuyv || format == PixelFormat::kNv12;
    if ((format != PixelFormat::kRgb8 && !yuv) || frame.image.width != d.width || frame.image.height != d.height ||
        frame.image.data == nullptr || (yuv && (d.width % 2 != 0 || (format == PixelFormat::kNv12 && d.height % 2 != 0)))) {
        return fail(ErrorCode::kBadInput, "render: the frame must be RGB8, YUYV or NV12 (even sizes) of " + std::to_string(d.width) + "x" +
                                              std::to_string(d.height) + " (got " + std::string(pixelFormatName(format)) + " " +
                                              std::to_string(frame.image.width) + "x" + std::to_string(frame.image.height) + ")");
    }
    const std::size_t min_stride = minStride(format, d.width);
    if (frame.image.stride < min_stride || frame.image.size_bytes < imageBytes(format, d.width, d.height, frame.image.stride)) {
        return fail(ErrorCode::kBadInput, "render: the frame's " + std::to_string(frame.image.size_bytes) + " bytes (stride " +
                                              std::to_string(frame.image.stride) + ") are too few for " +
                                              std::string(pixelFormatName(format)) + " " + std::to_string(d.width) + "x" +
                                              std::to_string(d.height));
    }
    if (!frame.virtual_poses.empty() && frame.virtual_poses.size() != d.scene.virtual_objects.size()) {
        return fail(ErrorCode::kBadInput, "render: " + std::to_string(frame.virtual_poses.size()) + " virtual poses for " +
                                              std::to_string(d.scene.virtual_objects.size()) + " virtual objects");
    }
    d.context->makeCurrent();
    while (glGetError() != GL_NO_ERROR) {
    }  // errors left by others (the check below is for this frame's)
    d.pass_times.clear();
    d.mark(nullptr);
    CL_TRY_VOID(d.makeLayerTargets());
    const double eg = frame.exposure_gain > 0.0 && std::isfinite(frame.exposure_gain) ? frame.exposure_gain : 1.0;
    const bool posed = frame.cam_from_world && frame.cam_from_world->isValid();

    // Step 1: the frame, through the pixel buffer, in its own format.
    d.uploadFrame(frame.image);
    d.mark("upload frame");
    if (d.options.camera_matching) {
        const std::uint64_t interval = static_cast<std::uint64_t>(std::max(1, d.options.matching_interval));
        if (!d.match || d.frames_drawn - d.match->frame >= interval) CL_TRY_VOID(d.measureCamera(frame.image));
        d.mark("camera matching");
    } else {
        d.match.reset();
    }
    const bool matching = d.options.camera_matching && d.match.has_value();
    const double added_blur = matching ? d.match->added_sigma_px : 0.0;
    d.snapshot_textures.update(snapshot, d.scene.virtual_objects.size(), d.options.lighting);
    d.mark("upload snapshot");

    // Step 2: the poses of what is drawn.
    std::vector<std::optional<Eigen::Matrix4f>> virtual_model(d.scene.virtual_objects.size());
    Eigen::Vector3d vmin = Eigen::Vector3d::Constant(1e30), vmax = Eigen::Vector3d::Constant(-1e30);
    for (std::size_t i = 0; i < virtual_model.size(); ++i) {
        std::optional<Rigid3d> pose = i < frame.virtual_poses.size() ? frame.virtual_poses[i]
                                                                      : worldFromObject(d.scene.virtual_objects[i], d.scene.tags, 0.0);
        if (!pose || !pose->isValid() || d.virtual_meshes[i].index_count == 0) continue;
        virtual_model[i] = toGl(*pose);
        const GpuMesh& m = d.virtual_meshes[i];
        for (int c = 0; c < 8; ++c) {
            const Eigen::Vector3d corner((c & 1) ? m.bmax.x() : m.bmin.x(), (c & 2) ? m.bmax.y() : m.bmin.y(), (c & 4) ? m.bmax.z() : m.bmin.z());
            const Eigen::Vector3d w = pose->rotation * corner + pose->translation;
            vmin = vmin.cwiseMin(w);
            vmax = vmax.cwiseMax(w);
        }
    }
    const bool any_virtual = vmin.x() <= vmax.x();

    // Step 3: light samples and their shadow maps (for shading the virtual objects only).
    std::vector<LightSample> samples = lightSamples(snapshot, d.options.area_light_samples);
    if (posed && any_virtual && !samples.empty()) {
        // The objects' bounding sphere across in layer pixels: their maps need no finer texels.
        const Eigen::Vector3d centre = 0.5 * (vmin + vmax);
        const double radius = 0.5 * (vmax - vmin).norm();
        const double depth = (frame.cam_from_world->rotation * centre + frame.cam_from_world->translation).z();
        const double f = std::max(d.layer_camera.fx, d.layer_camera.fy);
        const double footprint = depth > 2.0 * radius ? 2.0 * radius * f / (depth - radius) : std::numeric_limits<double>::infinity();
        d.renderShadowMaps(samples, virtual_model, vmin, vmax, footprint);
    }
    d.mark("shadow maps");

    // Step 4: the real proxies (atlas coordinates of their modulation) and the virtual layer, in
    // the undistorted image.
    const bool modulated = posed && d.snapshot_textures.modulates();
    Rect layer_rect, virtual_camera_rect;
    bool proxies_drawn = false;
    TileMask& tiles = d.modulation_tiles;
    tiles.reset(d.width, d.height, kBlock);
    if (posed) {
        // GL camera: x right, y up, looking along -z.
        Eigen::Matrix4d cam_from_world = Eigen::Matrix4d::Identity();
        cam_from_world.topLeftCorner<3, 3>() = frame.cam_from_world->rotation.toRotationMatrix();
        cam_from_world.topRightCorner<3, 1>() = frame.cam_from_world->translation;
        Eigen::Matrix4d view = cam_from_world;
        view.row(1) *= -1.0;
        view.row(2) *= -1.0;
        const Eigen::Matrix4f view_proj = (d.layer_camera.glProjection(0.01, 100.0) * view).cast<float>();
        const Eigen::Vector3f camera_centre = frame.cam_from_world->inverse().translation.cast<float>();
        const Rect full_layer{0, 0, d.layer_width - 1, d.layer_height - 1};
        layer_rect = d.options.debug == DebugView::kProxyWireframe
                         ? full_layer
                         : d.layerRect(virtual_model, cam_from_world, 2.0 + (added_blur > 0.05 ? std::ceil(3.0 * added_blur) : 0.0));
        virtual_camera_rect = d.cameraRect(layer_rect);
        // The camera tiles to modulate: where the snapshot changes something (the debug views show
        // it all); elsewhere the final pass copies the frame's codes. The proxies are drawn where
        // the final pass reads them and under the virtual objects (their depth hides them).
        if (modulated) d.markModulationTiles(cam_from_world, virtual_camera_rect);
        const Rect camera_rect = unite(virtual_camera_rect, tiles.bounds(d.width, d.height));
        const Rect proxy_rect = unite(d.layerRectOfCamera(camera_rect), layer_rect);
        proxies_drawn = modulated && !camera_rect.empty() && !proxy_rect.empty();
        if (proxies_drawn) d.drawProxies(view_proj, camera_centre, proxy_rect);
        d.mark("proxies");
        if (!layer_rect.empty()) {
            d.drawVirtualLayer(layer_rect, proxies_drawn, view_proj, camera_centre, samples, virtual_model, snapshot, eg);
            if (added_blur > 0.05) CL_TRY_VOID(d.blurLayer(layer_rect, added_blur));
        }
        d.mark("virtual layer");
    }
    if (!proxies_drawn) tiles.reset(d.width, d.height, kBlock);

    // Step 5: the final pass at each camera pixel, each program only where it is needed: in
    // `virtual_camera_rect` (the pixels that can see the virtual layer) the modulation and the
    // virtual layer; in the other marked tiles the modulation; elsewhere the frame's codes as they
    // are (converted from YUV). The tiles as quads: one draw per program.
    const int bits = format == PixelFormat::kYuyv ? kFinalYuyv : format == PixelFormat::kNv12 ? kFinalNv12 : 0;
    int modulation_bits = bits;
    if (proxies_drawn) {
        modulation_bits |= kFinalModulation;
        if (d.options.debug == DebugView::kElements) modulation_bits |= kFinalElements;
        if (d.options.debug == DebugView::kRatio) modulation_bits |= kFinalRatio;
    }
    const int virtual_bits = modulation_bits | kFinalVirtual | (matching ? kFinalNoise : 0);
    if (layer_rect.empty()) virtual_camera_rect = Rect{};
    CL_TRY(const FinalProgram* plain, d.finalProgram(bits | kFinalTiles));
    CL_TRY(const FinalProgram* modulating, d.finalProgram(modulation_bits | kFinalTiles));
    const FinalProgram* with_virtual = nullptr;
    if (!virtual_camera_rect.empty()) {
        CL_TRY(with_virtual, d.finalProgram(virtual_bits));
    }
    const auto [plain_vertices, modulated_vertices] = d.uploadTileQuads(virtual_camera_rect);
    glBindFramebuffer(GL_FRAMEBUFFER, d.output_fbo);
    const GLenum out0 = GL_COLOR_ATTACHMENT0;
    glDrawBuffers(1, &out0);
    glViewport(0, 0, d.width, d.height);
    const std::pair<int, GLuint> textures[] = {{kUnitFrame, d.frame_texture},       {kUnitFrameUv, d.frame_uv_texture},
                                               {kUnitUndistort, d.undistort_texture}, {kUnitProxyAtlas, d.proxy_atlas},
                                               {kUnitAtlasM, d.snapshot_textures.atlasM()}, {kUnitAtlasD, d.snapshot_textures.atlasD()},
                                               {kUnitAtlasO, d.snapshot_textures.atlasO()}, {kUnitLayerV, d.layer_v}};
    for (const auto& [unit, texture] : textures) {
        glActiveTexture(GL_TEXTURE0 + static_cast<GLenum>(unit));
        glBindTexture(GL_TEXTURE_2D, texture);
    }
    glBindBufferBase(GL_UNIFORM_BUFFER, 0, d.to_linear_ubo);
    glBindBufferBase(GL_UNIFORM_BUFFER, 1, d.to_code_ubo);
    const auto setUniforms = [&](const FinalProgram& p) {
        glUseProgram(p.id);
        glUniform1f(p.exposure_gain, static_cast<float>(eg));
        const Eigen::Vector2f atlas = d.snapshot_textures.atlasSize();
        glUniform2f(p.atlas_size, atlas.x(), atlas.y());
        // Texel coordinates at which a bilinear read stays inside the drawn rectangle.
        glUniform4f(p.layer_rect, static_cast<float>(layer_rect.x0) + 0.5f, static_cast<float>(layer_rect.y0) + 0.5f,
                    static_cast<float>(layer_rect.x1) + 0.5f, static_cast<float>(layer_rect.y1) + 0.5f);
        if (p.noise >= 0 && matching) {
            std::array<float, 3 * NoiseProfile::kBins> noise{};
            for (int b = 0; b < NoiseProfile::kBins; ++b) {
                for (int c = 0; c < 3; ++c) noise[static_cast<std::size_t>(3 * b + c)] = d.match->noise.sigma[static_cast<std::size_t>(b)][c];
            }
            glUniform3fv(p.noise, NoiseProfile::kBins, noise.data());
            glUniform1ui(p.seed, static_cast<GLuint>(d.frames_drawn & 0xffffffffu));
        }
    };
    if (plain_vertices > 0) {
        setUniforms(*plain);
        d.drawTileQuads(0, plain_vertices);
    }
    if (modulated_vertices > 0) {
        setUniforms(*modulating);
        d.drawTileQuads(plain_vertices, modulated_vertices);
    }
    if (with_virtual) {
        setUniforms(*with_virtual);
        d.drawVirtualRect(virtual_camera_rect);
    }
    glActiveTexture(GL_TEXTURE0);
    d.mark("final pass");

    // In a window: the composite, scaled to the window (the output's row 0 is the image's top row).
    if (d.context->kind() == ContextKind::kWindow) {
        int w = 0, h = 0;
        d.context->windowSize(w, h);
        glBindFramebuffer(GL_READ_FRAMEBUFFER, d.output_fbo);
        glReadBuffer(GL_COLOR_ATTACHMENT0);
        glBindFramebuffer(GL_DRAW_FRAMEBUFFER, 0);
        glDrawBuffer(GL_BACK);
        glBlitFramebuffer(0, 0, d.width, d.height, 0, h, w, 0, GL_COLOR_BUFFER_BIT, GL_LINEAR);
        d.mark("window");
    }
    glBindFramebuffer(GL_FRAMEBUFFER, 0);
    ++d.frames_drawn;
    const GLenum error = glGetError();
    if (error != GL_NO_ERROR) return fail(ErrorCode::kInternal, "render: GL error " + std::to_string(error) + " while compositing");
    return {};
}

Result<Image> Compositor::read() const {
    const Impl& d = *impl_;
    d.context->makeCurrent();
    d.mark(nullptr);
    Image out(PixelFormat::kRgb8, d.width, d.height);
    glBindFramebuffer(GL_READ_FRAMEBUFFER, d.output_fbo);
    glReadBuffer(GL_COLOR_ATTACHMENT0);
    glPixelStorei(GL_PACK_ALIGNMENT, 1);
    // Rows come out top row first, packed as the image is.
    glReadPixels(0, 0, d.width, d.height, GL_RGB, GL_UNSIGNED_BYTE, out.data());
    glBindFramebuffer(GL_READ_FRAMEBUFFER, 0);
    d.mark("read back");
    return out;
}

}  // namespace commonlight::render

#include "render/gl_context.h"

#define GL_GLEXT_PROTOTYPES
#include <GL/glcorearb.h>
#include <EGL/egl.h>
#include <EGL/eglext.h>
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>

#include <cstdlib>
#include <cstring>
#include <mutex>

namespace commonlight::render {

struct GlContext::Impl {
    // Offscreen.
    EGLDisplay display = EGL_NO_DISPLAY;
    EGLContext context = EGL_NO_CONTEXT;
    // Window.
    GLFWwindow* window = nullptr;
    std::vector<int> keys;
    int width = 0, height = 0;
};

namespace {

std::mutex& glfwMutex() {
    static std::mutex m;
    return m;
}
int glfw_users = 0;          // windows alive; guarded by glfwMutex()
bool glfw_initialised = false;  // once per process; guarded by glfwMutex()

void keyCallback(GLFWwindow* window, int key, int /*scancode*/, int action, int /*mods*/) {
    if (action != GLFW_PRESS && action != GLFW_REPEAT) return;
    auto* impl = static_cast<std::vector<int>*>(glfwGetWindowUserPointer(window));
    if (impl) impl->push_back(key);
}

std::string eglErrorText(const char* what) {
    char buffer[96];
    std::snprintf(buffer, sizeof buffer, "%s failed (EGL error 0x%04x)", what, static_cast<unsigned>(eglGetError()));
    return buffer;
}

}  // namespace

Result<std::unique_ptr<GlContext>> GlContext::create(const ContextOptions& options) {
    auto ctx = std::unique_ptr<GlContext>(new GlContext());
    ctx->impl_ = std::make_unique<Impl>();
    ctx->kind_ = options.kind;
    Impl& d = *ctx->impl_;
    d.width = options.width;
    d.height = options.height;
    if (options.kind == ContextKind::kWindow) {
        const char* x11 = std::getenv("DISPLAY");
        const char* wayland = std::getenv("WAYLAND_DISPLAY");
        if ((x11 == nullptr || *x11 == '\0') && (wayland == nullptr || *wayland == '\0')) {
            return fail(ErrorCode::kDevice, "no display for the window (DISPLAY is not set): run with --headless, or under xvfb-run");
        }
        std::lock_guard lock(glfwMutex());
        if (!glfw_initialised && glfwInit() != GLFW_TRUE) {
            const char* description = nullptr;
            glfwGetError(&description);
            return fail(ErrorCode::kDevice, std::string("GLFW cannot open the display '") + (x11 ? x11 : "") +
                                                "': " + (description ? description : "unknown error"));
        }
        glfw_initialised = true;
        glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, 3);
        glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, 3);
        glfwWindowHint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
        glfwWindowHint(GLFW_OPENGL_FORWARD_COMPAT, GLFW_TRUE);
        d.window = glfwCreateWindow(options.width, options.height, options.title.c_str(), nullptr, nullptr);
        if (d.window == nullptr) {
            const char* description = nullptr;
            glfwGetError(&description);
            return fail(ErrorCode::kDevice, std::string("cannot open a window with OpenGL 3.3 core: ") +
                                                (description ? description : "unknown error"));
        }
        ++glfw_users;
        glfwSetWindowUserPointer(d.window, &d.keys);
        glfwSetKeyCallback(d.window, keyCallback);
        glfwMakeContextCurrent(d.window);
        glfwSwapInterval(0);
        return ctx;
    }
    // Offscreen: EGL on Mesa's surfaceless platform, desktop OpenGL 3.3 core, no surface at all.
    const char* client_extensions = eglQueryString(EGL_NO_DISPLAY, EGL_EXTENSIONS);
    if (client_extensions == nullptr || std::strstr(client_extensions, "EGL_MESA_platform_surfaceless") == nullptr) {
        return fail(ErrorCode::kDevice, "EGL: no surfaceless platform (EGL_MESA_platform_surfaceless; install libegl-mesa0)");
    }
    d.display = eglGetPlatformDisplay(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, nullptr);
    if (d.display == EGL_NO_DISPLAY) return fail(ErrorCode::kDevice, "EGL: " + eglErrorText("eglGetPlatformDisplay(surfaceless)"));
    EGLint major = 0, minor = 0;
    if (eglInitialize(d.display, &major, &minor) != EGL_TRUE) {
        d.display = EGL_NO_DISPLAY;
        return fail(ErrorCode::kDevice, "EGL: " + eglErrorText("eglInitialize"));
    }
    if (eglBindAPI(EGL_OPENGL_API) != EGL_TRUE) return fail(ErrorCode::kDevice, "EGL: " + eglErrorText("eglBindAPI(OpenGL)"));
    // A config is optional on Mesa (EGL_KHR_no_config_context): the context renders only into
    // framebuffer objects.
    EGLConfig config = EGL_NO_CONFIG_KHR;
    const char* display_extensions = eglQueryString(d.display, EGL_EXTENSIONS);
    const bool no_config = display_extensions != nullptr && std::strstr(display_extensions, "EGL_KHR_no_config_context") != nullptr;
    if (!no_config) {
        const EGLint config_attributes[] = {EGL_SURFACE_TYPE, EGL_PBUFFER_BIT, EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT, EGL_NONE};
        EGLint configs = 0;
        if (eglChooseConfig(d.display, config_attributes, &config, 1, &configs) != EGL_TRUE || configs < 1) {
            return fail(ErrorCode::kDevice, "EGL: no config with desktop OpenGL and no EGL_KHR_no_config_context");
        }
    }
    const EGLint context_attributes[] = {EGL_CONTEXT_MAJOR_VERSION, 3, EGL_CONTEXT_MINOR_VERSION, 3,
                                         EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT, EGL_NONE};
    d.context = eglCreateContext(d.display, config, EGL_NO_CONTEXT, context_attributes);
    if (d.context == EGL_NO_CONTEXT) return fail(ErrorCode::kDevice, "EGL: no OpenGL 3.3 core context: " + eglErrorText("eglCreateContext"));
    if (eglMakeCurrent(d.display, EGL_NO_SURFACE, EGL_NO_SURFACE, d.context) != EGL_TRUE) {
        return fail(ErrorCode::kDevice, "EGL: " + eglErrorText("eglMakeCurrent without a surface"));
    }
    return ctx;
}

GlContext::~GlContext() {
    if (!impl_) return;
    Impl& d = *impl_;
    if (d.window != nullptr) {
        std::lock_guard lock(glfwMutex());
        glfwDestroyWindow(d.window);
        // GLFW stays initialised for the rest of the process (the next window reuses it):
        // glfwTerminate unloads the GL driver while blocks its JIT code allocated are referenced
        // only from there, which LeakSanitizer then reports.
        --glfw_users;
    }
    if (d.display != EGL_NO_DISPLAY) {
        eglMakeCurrent(d.display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
        if (d.context != EGL_NO_CONTEXT) eglDestroyContext(d.display, d.context);
        // The display stays initialised (EGL keeps one per process and reuses it on the next
        // eglInitialize): eglTerminate would unload Mesa's driver while blocks its JIT code
        // allocated are still referenced only from there, which LeakSanitizer then reports.
    }
}

void GlContext::makeCurrent() {
    if (impl_->window != nullptr) {
        glfwMakeContextCurrent(impl_->window);
    } else {
        eglMakeCurrent(impl_->display, EGL_NO_SURFACE, EGL_NO_SURFACE, impl_->context);
    }
}

bool GlContext::shouldClose() const { return impl_->window != nullptr && glfwWindowShouldClose(impl_->window) == GLFW_TRUE; }

void GlContext::present() {
    if (impl_->window != nullptr) glfwSwapBuffers(impl_->window);
}

std::vector<int> GlContext::pollKeys() {
    if (impl_->window == nullptr) return {};
    glfwPollEvents();
    std::vector<int> keys;
    keys.swap(impl_->keys);
    return keys;
}

void GlContext::windowSize(int& width, int& height) const {
    if (impl_->window != nullptr) {
        glfwGetFramebufferSize(impl_->window, &width, &height);
    } else {
        width = impl_->width;
        height = impl_->height;
    }
}

void GlContext::setTitle(const std::string& title) {
    if (impl_->window != nullptr) glfwSetWindowTitle(impl_->window, title.c_str());
}

Result<Image> GlContext::readWindow() const {
    if (impl_->window == nullptr) return fail(ErrorCode::kUnsupported, "render: no window to read (offscreen context)");
    int w = 0, h = 0;
    glfwGetFramebufferSize(impl_->window, &w, &h);
    std::vector<std::uint8_t> rgba(static_cast<std::size_t>(w) * static_cast<std::size_t>(h) * 4);
    glBindFramebuffer(GL_READ_FRAMEBUFFER, 0);
    glReadBuffer(GL_BACK);
    glPixelStorei(GL_PACK_ALIGNMENT, 1);
    glReadPixels(0, 0, w, h, GL_RGBA, GL_UNSIGNED_BYTE, rgba.data());
    Image out(PixelFormat::kRgb8, w, h);
    for (int y = 0; y < h; ++y) {
        const std::uint8_t* src = rgba.data() + static_cast<std::size_t>(h - 1 - y) * static_cast<std::size_t>(w) * 4;
        std::uint8_t* dst = out.mutableView().row(y);
        for (int x = 0; x < w; ++x) {
            dst[3 * x] = src[4 * x];
            dst[3 * x + 1] = src[4 * x + 1];
            dst[3 * x + 2] = src[4 * x + 2];
        }
    }
    return out;
}

std::string GlContext::renderer() const {
    const auto* text = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
    return text ? text : "";
}

}  // namespace commonlight::render

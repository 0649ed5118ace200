#include "render/gl_objects.h"

#include <atomic>
#include <vector>

#include "render/compositor.h"

namespace commonlight::render {

namespace {
std::atomic<long> textures{0}, buffers{0}, framebuffers{0}, renderbuffers{0}, programs{0}, vertex_arrays{0};
}  // namespace

GlObjectCounts liveGlObjects() {
    return {textures.load(), buffers.load(), framebuffers.load(), renderbuffers.load(), programs.load(), vertex_arrays.load()};
}

namespace gl {

GLuint newTexture() {
    GLuint name = 0;
    glGenTextures(1, &name);
    ++textures;
    return name;
}
void deleteTexture(GLuint& name) {
    if (name == 0) return;
    glDeleteTextures(1, &name);
    name = 0;
    --textures;
}
GLuint newBuffer() {
    GLuint name = 0;
    glGenBuffers(1, &name);
    ++buffers;
    return name;
}
void deleteBuffer(GLuint& name) {
    if (name == 0) return;
    glDeleteBuffers(1, &name);
    name = 0;
    --buffers;
}
GLuint newFramebuffer() {
    GLuint name = 0;
    glGenFramebuffers(1, &name);
    ++framebuffers;
    return name;
}
void deleteFramebuffer(GLuint& name) {
    if (name == 0) return;
    glDeleteFramebuffers(1, &name);
    name = 0;
    --framebuffers;
}
GLuint newRenderbuffer() {
    GLuint name = 0;
    glGenRenderbuffers(1, &name);
    ++renderbuffers;
    return name;
}
void deleteRenderbuffer(GLuint& name) {
    if (name == 0) return;
    glDeleteRenderbuffers(1, &name);
    name = 0;
    --renderbuffers;
}
GLuint newVertexArray() {
    GLuint name = 0;
    glGenVertexArrays(1, &name);
    ++vertex_arrays;
    return name;
}
void deleteVertexArray(GLuint& name) {
    if (name == 0) return;
    glDeleteVertexArrays(1, &name);
    name = 0;
    --vertex_arrays;
}

namespace {
Result<GLuint> compile(const char* name, GLenum type, const std::string& source) {
    const GLuint shader = glCreateShader(type);
    const char* text = source.c_str();
    glShaderSource(shader, 1, &text, nullptr);
    glCompileShader(shader);
    GLint ok = GL_FALSE;
    glGetShaderiv(shader, GL_COMPILE_STATUS, &ok);
    if (ok != GL_TRUE) {
        GLint length = 0;
        glGetShaderiv(shader, GL_INFO_LOG_LENGTH, &length);
        std::vector<char> log(static_cast<std::size_t>(std::max(length, 1)));
        glGetShaderInfoLog(shader, length, nullptr, log.data());
        glDeleteShader(shader);
        return fail(ErrorCode::kDevice, std::string("render: shader '") + name + "' does not compile: " + log.data());
    }
    return shader;
}
}  // namespace

Result<GLuint> newProgram(const char* name, const std::string& vertex, const std::string& fragment) {
    CL_TRY(GLuint vs, compile(name, GL_VERTEX_SHADER, vertex));
    auto fs = compile(name, GL_FRAGMENT_SHADER, fragment);
    if (!fs) {
        glDeleteShader(vs);
        return fail(fs.error().code, fs.error().message);
    }
    const GLuint program = glCreateProgram();
    glAttachShader(program, vs);
    glAttachShader(program, *fs);
    glLinkProgram(program);
    glDeleteShader(vs);
    glDeleteShader(*fs);
    GLint ok = GL_FALSE;
    glGetProgramiv(program, GL_LINK_STATUS, &ok);
    if (ok != GL_TRUE) {
        GLint length = 0;
        glGetProgramiv(program, GL_INFO_LOG_LENGTH, &length);
        std::vector<char> log(static_cast<std::size_t>(std::max(length, 1)));
        glGetProgramInfoLog(program, length, nullptr, log.data());
        glDeleteProgram(program);
        return fail(ErrorCode::kDevice, std::string("render: program '") + name + "' does not link: " + log.data());
    }
    ++programs;
    return program;
}

void deleteProgram(GLuint& name) {
    if (name == 0) return;
    glDeleteProgram(name);
    name = 0;
    --programs;
}

}  // namespace gl
}  // namespace commonlight::render

// GL object creation and deletion through one place, counted, so tests can check that the
// compositor leaks nothing (render/compositor.h: liveGlObjects()).
#pragma once

#define GL_GLEXT_PROTOTYPES
#include <GL/glcorearb.h>

#include <string>

#include "core/result.h"

namespace commonlight::render::gl {

GLuint newTexture();
void deleteTexture(GLuint& name);
GLuint newBuffer();
void deleteBuffer(GLuint& name);
GLuint newFramebuffer();
void deleteFramebuffer(GLuint& name);
GLuint newRenderbuffer();
void deleteRenderbuffer(GLuint& name);
GLuint newVertexArray();
void deleteVertexArray(GLuint& name);
// Compiles and links a program from GLSL sources; errors (kDevice) carry the GL's log and `name`.
Result<GLuint> newProgram(const char* name, const std::string& vertex, const std::string& fragment);
void deleteProgram(GLuint& name);

}  // namespace commonlight::render::gl

#include "gl/gl_objects.h"

#include <vector>

#include <fmt/format.h>

namespace penumbra::client::gl {

void DeleteBuffer(GLuint id) { glDeleteBuffers(1, &id); }
void DeleteTexture(GLuint id) { glDeleteTextures(1, &id); }
void DeleteVertexArray(GLuint id) { glDeleteVertexArrays(1, &id); }
void DeleteFramebuffer(GLuint id) { glDeleteFramebuffers(1, &id); }
void DeleteProgram(GLuint id) { glDeleteProgram(id); }

Buffer MakeBuffer() {
  GLuint id = 0;
  glGenBuffers(1, &id);
  return Buffer(id);
}
Texture MakeTexture() {
  GLuint id = 0;
  glGenTextures(1, &id);
  return Texture(id);
}
VertexArray MakeVertexArray() {
  GLuint id = 0;
  glGenVertexArrays(1, &id);
  return VertexArray(id);
}
Framebuffer MakeFramebuffer() {
  GLuint id = 0;
  glGenFramebuffers(1, &id);
  return Framebuffer(id);
}

namespace {

std::string InfoLog(GLuint object, bool isProgram) {
  GLint length = 0;
  if (isProgram)
    glGetProgramiv(object, GL_INFO_LOG_LENGTH, &length);
  else
    glGetShaderiv(object, GL_INFO_LOG_LENGTH, &length);
  std::vector<char> log(size_t(std::max(length, 1)));
  if (isProgram)
    glGetProgramInfoLog(object, GLsizei(log.size()), nullptr, log.data());
  else
    glGetShaderInfoLog(object, GLsizei(log.size()), nullptr, log.data());
  return std::string(log.data());
}

Expected<GLuint> Compile(GLenum stage, const char* source, const std::string& name) {
  const GLuint shader = glCreateShader(stage);
  glShaderSource(shader, 1, &source, nullptr);
  glCompileShader(shader);
  GLint ok = GL_FALSE;
  glGetShaderiv(shader, GL_COMPILE_STATUS, &ok);
  if (ok != GL_TRUE) {
    const std::string log = InfoLog(shader, false);
    glDeleteShader(shader);
    return Fail(fmt::format("{} {} shader: {}", name, stage == GL_VERTEX_SHADER ? "vertex" : "fragment", log));
  }
  return shader;
}

}  // namespace

Expected<Program> BuildProgram(const std::string& name, const char* vertexSource, const char* fragmentSource) {
  auto vertex = Compile(GL_VERTEX_SHADER, vertexSource, name);
  if (!vertex) return vertex.error();
  auto fragment = Compile(GL_FRAGMENT_SHADER, fragmentSource, name);
  if (!fragment) {
    glDeleteShader(*vertex);
    return fragment.error();
  }
  Program program(glCreateProgram());
  glAttachShader(program.id(), *vertex);
  glAttachShader(program.id(), *fragment);
  glLinkProgram(program.id());
  glDeleteShader(*vertex);  // flagged; freed with the program
  glDeleteShader(*fragment);
  GLint ok = GL_FALSE;
  glGetProgramiv(program.id(), GL_LINK_STATUS, &ok);
  if (ok != GL_TRUE) return Fail(fmt::format("{} program: {}", name, InfoLog(program.id(), true)));
  return program;
}

std::string TakeGlError(const char* what) {
  std::string first;
  for (GLenum e = glGetError(); e != GL_NO_ERROR; e = glGetError()) {
    if (!first.empty()) continue;
    switch (e) {
      case GL_INVALID_ENUM: first = "GL_INVALID_ENUM"; break;
      case GL_INVALID_VALUE: first = "GL_INVALID_VALUE"; break;
      case GL_INVALID_OPERATION: first = "GL_INVALID_OPERATION"; break;
      case GL_INVALID_FRAMEBUFFER_OPERATION: first = "GL_INVALID_FRAMEBUFFER_OPERATION"; break;
      case GL_OUT_OF_MEMORY: first = "GL_OUT_OF_MEMORY"; break;
      default: first = fmt::format("GL error 0x{:x}", e);
    }
    first += fmt::format(" after {}", what);
  }
  return first;
}

const char* const kFullScreenVertexShader = R"(#version 330 core
void main() {
  // One triangle covering the viewport: (-1,-1), (3,-1), (-1,3).
  vec2 corner = vec2(float((gl_VertexID & 1) << 2) - 1.0, float((gl_VertexID & 2) << 1) - 1.0);
  gl_Position = vec4(corner, 0.0, 1.0);
}
)";

}  // namespace penumbra::client::gl

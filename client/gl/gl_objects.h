#pragma once
// Owning handles for OpenGL objects and shader program building. Every
// function here must be called on the render thread with the context
// current; a handle deletes its object when destroyed, so handles must not
// outlive the context.

#include <string>
#include <utility>

#include <epoxy/gl.h>

#include "penumbra/common/expected.h"

namespace penumbra::client::gl {

/// A move-only GL object name with its deleter.
template <void (*Delete)(GLuint)>
class Handle {
 public:
  Handle() = default;
  explicit Handle(GLuint id) : id_(id) {}
  Handle(Handle&& other) noexcept : id_(std::exchange(other.id_, 0)) {}
  Handle& operator=(Handle&& other) noexcept {
    if (this != &other) {
      Reset();
      id_ = std::exchange(other.id_, 0);
    }
    return *this;
  }
  Handle(const Handle&) = delete;
  Handle& operator=(const Handle&) = delete;
  ~Handle() { Reset(); }

  GLuint id() const { return id_; }
  void Reset() {
    if (id_ != 0) Delete(id_);
    id_ = 0;
  }

 private:
  GLuint id_ = 0;
};

void DeleteBuffer(GLuint id);
void DeleteTexture(GLuint id);
void DeleteVertexArray(GLuint id);
void DeleteFramebuffer(GLuint id);
void DeleteProgram(GLuint id);

using Buffer = Handle<DeleteBuffer>;
using Texture = Handle<DeleteTexture>;
using VertexArray = Handle<DeleteVertexArray>;
using Framebuffer = Handle<DeleteFramebuffer>;
using Program = Handle<DeleteProgram>;

Buffer MakeBuffer();
Texture MakeTexture();
VertexArray MakeVertexArray();
Framebuffer MakeFramebuffer();

/// Compiles and links a program; the error carries `name` and the GL info log.
Expected<Program> BuildProgram(const std::string& name, const char* vertexSource, const char* fragmentSource);

/// Vertex shader of a full-screen pass: draw 3 vertices (glDrawArrays, no
/// attributes, an empty vertex array bound) and one triangle covers the
/// viewport; the fragment shader works from gl_FragCoord.
extern const char* const kFullScreenVertexShader;

/// The first pending GL error as text ("GL_OUT_OF_MEMORY after <what>"), or
/// empty; clears every pending error.
std::string TakeGlError(const char* what);

}  // namespace penumbra::client::gl

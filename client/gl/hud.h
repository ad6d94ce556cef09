#pragma once
// The heads-up display: lines of text in the bitmap font over a translucent
// panel at the top-left of the window.
//
// Threads: render thread, with the context current.

#include <string>
#include <vector>

#include <glm/vec2.hpp>

#include "gl/gl_objects.h"

namespace penumbra::client::gl {

class Hud {
 public:
  static Expected<Hud> Create();

  /// Draws `lines` into the bound framebuffer, whose viewport is `viewport`
  /// pixels, each font pixel `scale` x `scale` screen pixels.
  void Draw(const std::vector<std::string>& lines, glm::ivec2 viewport, int scale);

 private:
  Hud(Program program, Texture font, VertexArray vao, Buffer buffer)
      : program_(std::move(program)), font_(std::move(font)), vao_(std::move(vao)), buffer_(std::move(buffer)) {}
  Program program_;
  Texture font_;  // every glyph side by side, one texel per font pixel
  VertexArray vao_;
  Buffer buffer_;
  std::vector<float> vertices_;  // reused between frames
};

}  // namespace penumbra::client::gl

#pragma once
// The sky behind the mesh: where no triangle is drawn, the radiance pass
// shows the scene's sky in the direction of each pixel's ray, exactly as the
// renderer's primary rays see it (SkyLight::Radiance; penumbra-reference), so
// that windows and the open atrium roof are not black holes and screenshots
// compare with the path-traced reference pixel for pixel.
//
// Threads: render thread, with the context current.

#include <glm/mat4x4.hpp>

#include "gl/gl_objects.h"
#include "penumbra/common/scene.h"

namespace penumbra::client::gl {

class SkyRenderer {
 public:
  static Expected<SkyRenderer> Create();

  /// Fills the bound RGBA32F framebuffer's viewport with the sky's linear
  /// radiance (alpha 1) seen through `worldToClip`; depth is neither tested
  /// nor written, so draw it before the mesh.
  void Draw(const glm::mat4& worldToClip, const SkyLight& sky) const;

 private:
  SkyRenderer(Program program, VertexArray empty) : program_(std::move(program)), empty_(std::move(empty)) {}
  Program program_;
  VertexArray empty_;  // core profile draws need a bound vertex array
};

}  // namespace penumbra::client::gl

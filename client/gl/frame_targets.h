#pragma once
// The two offscreen images every frame is drawn into, at the view's size:
//  * radiance: RGBA32F linear radiance (alpha 0 where nothing was drawn),
//    with a 32-bit float depth texture;
//  * display: RGBA8 tone-mapped, display-encoded colour, sharing that depth
//    texture so overlays (the wireframe) are depth-tested against the mesh.
// The window shows the display image by a blit; headless runs read it (or
// the radiance) back for screenshots.
//
// Threads: render thread, with the context current.

#include <vector>

#include <glm/vec2.hpp>

#include "gl/gl_objects.h"

namespace penumbra::client::gl {

class FrameTargets {
 public:
  /// Allocates (or reallocates) for `size` pixels; no-op when unchanged.
  Status Resize(glm::ivec2 size);
  glm::ivec2 Size() const { return size_; }

  /// Binds the radiance framebuffer, sets the viewport, clears colour to 0
  /// (alpha 0: background) and depth to 1.
  void BeginRadiance();
  /// Binds the display framebuffer and sets the viewport (depth kept).
  void BeginDisplay();
  GLuint RadianceTexture() const { return radianceColour_.id(); }

  /// Linear radiance as RGB floats, row 0 at the top (for .exr); with
  /// `coverage`, also the alpha per pixel there (1 drawn, 0 background).
  std::vector<float> ReadRadiance(std::vector<float>* coverage = nullptr);
  /// The display image decoded to display-linear RGB floats, row 0 at the
  /// top; WriteImage's sRGB encoding of a .png gives back the same bytes.
  std::vector<float> ReadDisplay();
  /// Copies the display image into the default framebuffer (a window's).
  void BlitToDefault(glm::ivec2 windowFramebufferSize);

 private:
  glm::ivec2 size_{0};
  Framebuffer radianceFbo_;
  Framebuffer displayFbo_;
  Texture radianceColour_;
  Texture displayColour_;
  Texture depth_;
};

}  // namespace penumbra::client::gl

#include "gl/frame_targets.h"

#include <cstdint>

#include <fmt/format.h>

#include "penumbra/common/math.h"

namespace penumbra::client::gl {

namespace {

Texture MakeTarget(GLint internalFormat, GLenum format, GLenum type, glm::ivec2 size) {
  Texture texture = MakeTexture();
  glBindTexture(GL_TEXTURE_2D, texture.id());
  glTexImage2D(GL_TEXTURE_2D, 0, internalFormat, size.x, size.y, 0, format, type, nullptr);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
  return texture;
}

Status Attach(const Framebuffer& fbo, const Texture& colour, const Texture& depth, const char* name) {
  glBindFramebuffer(GL_FRAMEBUFFER, fbo.id());
  glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, colour.id(), 0);
  glFramebufferTexture2D(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_TEXTURE_2D, depth.id(), 0);
  const GLenum status = glCheckFramebufferStatus(GL_FRAMEBUFFER);
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
  if (status != GL_FRAMEBUFFER_COMPLETE) return Fail(fmt::format("the {} framebuffer is incomplete (0x{:x})", name, status));
  return Status::Ok();
}

}  // namespace

Status FrameTargets::Resize(glm::ivec2 size) {
  if (size == size_ && radianceFbo_.id()) return Status::Ok();
  if (size.x < 1 || size.y < 1) return Fail(fmt::format("frame size {}x{}", size.x, size.y));
  size_ = size;
  radianceColour_ = MakeTarget(GL_RGBA32F, GL_RGBA, GL_FLOAT, size);
  displayColour_ = MakeTarget(GL_RGBA8, GL_RGBA, GL_UNSIGNED_BYTE, size);
  depth_ = MakeTarget(GL_DEPTH_COMPONENT32F, GL_DEPTH_COMPONENT, GL_FLOAT, size);
  if (!radianceFbo_.id()) {
    radianceFbo_ = MakeFramebuffer();
    displayFbo_ = MakeFramebuffer();
  }
  if (auto ok = Attach(radianceFbo_, radianceColour_, depth_, "radiance"); !ok) return ok;
  if (auto ok = Attach(displayFbo_, displayColour_, depth_, "display"); !ok) return ok;
  if (auto error = TakeGlError("allocating frame targets"); !error.empty()) return Fail(error);
  return Status::Ok();
}

void FrameTargets::BeginRadiance() {
  glBindFramebuffer(GL_FRAMEBUFFER, radianceFbo_.id());
  glViewport(0, 0, size_.x, size_.y);
  glClearColor(0.0f, 0.0f, 0.0f, 0.0f);
  glClearDepth(1.0);
  glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
}

void FrameTargets::BeginDisplay() {
  glBindFramebuffer(GL_FRAMEBUFFER, displayFbo_.id());
  glViewport(0, 0, size_.x, size_.y);
}

std::vector<float> FrameTargets::ReadRadiance(std::vector<float>* coverage) {
  std::vector<float> rgba(size_t(size_.x) * size_t(size_.y) * 4);
  glBindFramebuffer(GL_READ_FRAMEBUFFER, radianceFbo_.id());
  glPixelStorei(GL_PACK_ALIGNMENT, 4);
  glReadPixels(0, 0, size_.x, size_.y, GL_RGBA, GL_FLOAT, rgba.data());
  std::vector<float> rgb(size_t(size_.x) * size_t(size_.y) * 3);
  // GL's row 0 is the bottom; images start at the top.
  for (int y = 0; y < size_.y; ++y)
    for (int x = 0; x < size_.x; ++x)
      for (int c = 0; c < 3; ++c)
        rgb[(size_t(y) * size_t(size_.x) + size_t(x)) * 3 + size_t(c)] =
            rgba[(size_t(size_.y - 1 - y) * size_t(size_.x) + size_t(x)) * 4 + size_t(c)];
  if (coverage) {
    coverage->resize(size_t(size_.x) * size_t(size_.y));
    for (int y = 0; y < size_.y; ++y)
      for (int x = 0; x < size_.x; ++x)
        (*coverage)[size_t(y) * size_t(size_.x) + size_t(x)] =
            rgba[(size_t(size_.y - 1 - y) * size_t(size_.x) + size_t(x)) * 4 + 3];
  }
  return rgb;
}

std::vector<float> FrameTargets::ReadDisplay() {
  std::vector<uint8_t> rgba(size_t(size_.x) * size_t(size_.y) * 4);
  glBindFramebuffer(GL_READ_FRAMEBUFFER, displayFbo_.id());
  glPixelStorei(GL_PACK_ALIGNMENT, 4);
  glReadPixels(0, 0, size_.x, size_.y, GL_RGBA, GL_UNSIGNED_BYTE, rgba.data());
  float decode[256];
  for (int i = 0; i < 256; ++i) decode[i] = SrgbToLinear(float(i) / 255.0f);
  std::vector<float> rgb(size_t(size_.x) * size_t(size_.y) * 3);
  for (int y = 0; y < size_.y; ++y)
    for (int x = 0; x < size_.x; ++x)
      for (int c = 0; c < 3; ++c)
        rgb[(size_t(y) * size_t(size_.x) + size_t(x)) * 3 + size_t(c)] =
            decode[rgba[(size_t(size_.y - 1 - y) * size_t(size_.x) + size_t(x)) * 4 + size_t(c)]];
  return rgb;
}

void FrameTargets::BlitToDefault(glm::ivec2 windowFramebufferSize) {
  glBindFramebuffer(GL_READ_FRAMEBUFFER, displayFbo_.id());
  glBindFramebuffer(GL_DRAW_FRAMEBUFFER, 0);
  glBlitFramebuffer(0, 0, size_.x, size_.y, 0, 0, windowFramebufferSize.x, windowFramebufferSize.y,
                    GL_COLOR_BUFFER_BIT, GL_NEAREST);
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
}

}  // namespace penumbra::client::gl

#include "gl/frame_targets.h"

#include <algorithm>
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

Texture MakeMultisampleTarget(GLenum internalFormat, glm::ivec2 size, int samples) {
  Texture texture = MakeTexture();
  glBindTexture(GL_TEXTURE_2D_MULTISAMPLE, texture.id());
  glTexImage2DMultisample(GL_TEXTURE_2D_MULTISAMPLE, samples, internalFormat, size.x, size.y, GL_TRUE);
  glBindTexture(GL_TEXTURE_2D_MULTISAMPLE, 0);
  return texture;
}

Status Attach(const Framebuffer& fbo, const Texture& colour, const Texture& depth, const char* name,
              GLenum target = GL_TEXTURE_2D) {
  glBindFramebuffer(GL_FRAMEBUFFER, fbo.id());
  glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, target, colour.id(), 0);
  glFramebufferTexture2D(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, target, depth.id(), 0);
  const GLenum status = glCheckFramebufferStatus(GL_FRAMEBUFFER);
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
  if (status != GL_FRAMEBUFFER_COMPLETE) return Fail(fmt::format("the {} framebuffer is incomplete (0x{:x})", name, status));
  return Status::Ok();
}

}  // namespace

Status FrameTargets::Resize(glm::ivec2 size, int samples) {
  if (size.x < 1 || size.y < 1) return Fail(fmt::format("frame size {}x{}", size.x, size.y));
  GLint colourLimit = 1, depthLimit = 1;
  glGetIntegerv(GL_MAX_COLOR_TEXTURE_SAMPLES, &colourLimit);
  glGetIntegerv(GL_MAX_DEPTH_TEXTURE_SAMPLES, &depthLimit);
  samples = std::clamp(samples, 1, std::max(1, std::min(colourLimit, depthLimit)));
  if (size == size_ && samples == samples_ && radianceFbo_.id()) return Status::Ok();
  size_ = size;
  samples_ = samples;
  radianceColour_ = MakeTarget(GL_RGBA32F, GL_RGBA, GL_FLOAT, size);
  displayColour_ = MakeTarget(GL_RGBA8, GL_RGBA, GL_UNSIGNED_BYTE, size);
  depth_ = MakeTarget(GL_DEPTH_COMPONENT32F, GL_DEPTH_COMPONENT, GL_FLOAT, size);
  if (!radianceFbo_.id()) {
    radianceFbo_ = MakeFramebuffer();
    displayFbo_ = MakeFramebuffer();
  }
  if (auto ok = Attach(radianceFbo_, radianceColour_, depth_, "radiance"); !ok) return ok;
  if (auto ok = Attach(displayFbo_, displayColour_, depth_, "display"); !ok) return ok;
  if (samples_ > 1) {
    if (!multisampleFbo_.id()) multisampleFbo_ = MakeFramebuffer();
    multisampleColour_ = MakeMultisampleTarget(GL_RGBA32F, size, samples_);
    multisampleDepth_ = MakeMultisampleTarget(GL_DEPTH_COMPONENT32F, size, samples_);
    if (auto ok = Attach(multisampleFbo_, multisampleColour_, multisampleDepth_, "multisampled radiance",
                         GL_TEXTURE_2D_MULTISAMPLE);
        !ok)
      return ok;
  } else {
    multisampleFbo_ = {};
    multisampleColour_ = {};
    multisampleDepth_ = {};
  }
  if (auto error = TakeGlError("allocating frame targets"); !error.empty()) return Fail(error);
  return Status::Ok();
}

void FrameTargets::BeginRadiance() {
  glBindFramebuffer(GL_FRAMEBUFFER, samples_ > 1 ? multisampleFbo_.id() : radianceFbo_.id());
  glViewport(0, 0, size_.x, size_.y);
  glClearColor(0.0f, 0.0f, 0.0f, 0.0f);
  glClearDepth(1.0);
  glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
}

void FrameTargets::EndRadiance() {
  if (samples_ <= 1) return;
  // Colour: the mean of each pixel's samples. Depth: one sample's (the
  // wireframe only needs it to tell front from back).
  glBindFramebuffer(GL_READ_FRAMEBUFFER, multisampleFbo_.id());
  glBindFramebuffer(GL_DRAW_FRAMEBUFFER, radianceFbo_.id());
  glBlitFramebuffer(0, 0, size_.x, size_.y, 0, 0, size_.x, size_.y, GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT,
                    GL_NEAREST);
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
}

void FrameTargets::BeginDisplay() {
  glBindFramebuffer(GL_FRAMEBUFFER, displayFbo_.id());
  glViewport(0, 0, size_.x, size_.y);
}

std::vector<float> FrameTargets::ReadRadiance() {
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

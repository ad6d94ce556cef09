#include "gl/sky_renderer.h"

#include <glm/gtc/type_ptr.hpp>
#include <glm/matrix.hpp>

namespace penumbra::client::gl {

namespace {

// Mirrors SkyLight::Radiance (common/src/scene.cpp); change them together.
constexpr const char* kSkyFragmentShader = R"(#version 330 core
uniform mat4 uClipToWorld;
uniform vec2 uViewportSize;
uniform vec3 uUp;
uniform vec3 uZenith;
uniform vec3 uHorizon;
uniform vec3 uGround;
layout(location = 0) out vec4 outRadiance;
void main() {
  // The pixel's ray: from its point on the near plane through its point on
  // the far plane, both unprojected to world space.
  vec2 ndc = gl_FragCoord.xy / uViewportSize * 2.0 - 1.0;
  vec4 nearPoint = uClipToWorld * vec4(ndc, -1.0, 1.0);
  vec4 farPoint = uClipToWorld * vec4(ndc, 1.0, 1.0);
  vec3 direction = normalize(farPoint.xyz / farPoint.w - nearPoint.xyz / nearPoint.w);
  float c = clamp(dot(direction, uUp), -1.0, 1.0);
  vec3 radiance = c >= 0.0 ? mix(uHorizon, uZenith, c) : mix(uHorizon, uGround, -c);
  outRadiance = vec4(radiance, 1.0);
}
)";

void SetVec3(GLuint program, const char* name, const Vec3& v) {
  glUniform3f(glGetUniformLocation(program, name), v.x, v.y, v.z);
}

}  // namespace

Expected<SkyRenderer> SkyRenderer::Create() {
  auto program = BuildProgram("sky", kFullScreenVertexShader, kSkyFragmentShader);
  if (!program) return program.error();
  return SkyRenderer(std::move(*program), MakeVertexArray());
}

void SkyRenderer::Draw(const glm::mat4& worldToClip, const SkyLight& sky) const {
  GLint viewport[4];
  glGetIntegerv(GL_VIEWPORT, viewport);
  const GLuint p = program_.id();
  glUseProgram(p);
  const glm::mat4 clipToWorld = glm::inverse(worldToClip);
  glUniformMatrix4fv(glGetUniformLocation(p, "uClipToWorld"), 1, GL_FALSE, glm::value_ptr(clipToWorld));
  glUniform2f(glGetUniformLocation(p, "uViewportSize"), float(viewport[2]), float(viewport[3]));
  SetVec3(p, "uUp", sky.up);
  SetVec3(p, "uZenith", sky.zenith);
  SetVec3(p, "uHorizon", sky.horizon);
  SetVec3(p, "uGround", sky.ground);
  glDisable(GL_DEPTH_TEST);
  glDepthMask(GL_FALSE);
  glBindVertexArray(empty_.id());
  glDrawArrays(GL_TRIANGLES, 0, 3);
  glBindVertexArray(0);
  glDepthMask(GL_TRUE);
}

}  // namespace penumbra::client::gl

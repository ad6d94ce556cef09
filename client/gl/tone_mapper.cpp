#include "gl/tone_mapper.h"

#include <cmath>

namespace penumbra::client::gl {

namespace {

constexpr float kMidGrey = 0.18f;

// Every line of DragoDisplayLuminance and ToneMapDrago (common/src/tonemap.cpp)
// and LinearToSrgb (common/math.h) has its counterpart here; change them together.
constexpr const char* kToneMapFragmentShader = R"(#version 330 core
uniform sampler2D uRadiance;
uniform int uOperator;           // 0: Drago, 1: exposure + gamma
uniform float uViewMax;          // ViewLuminance::max
uniform float uViewLogAverage;   // ViewLuminance::logAverage
uniform float uBias;             // DragoParams::bias
uniform float uMaxDisplayLuminance;
uniform float uExposure;         // Drago: DragoParams::exposure; else the radiance scale
uniform float uGamma;
uniform vec3 uBackground;
layout(location = 0) out vec4 outColour;

float Luminance(vec3 c) { return 0.2126 * c.r + 0.7152 * c.g + 0.0722 * c.b; }

float DragoDisplayLuminance(float lw) {
  if (!(lw > 0.0)) return 0.0;
  float adaptation = max(uViewLogAverage, 1e-9) / max(uExposure, 1e-9);
  float l = lw / adaptation;
  float lmax = max(uViewMax / adaptation, 1e-6);
  float biasPower = log(uBias) / log(0.5);
  float scale = uMaxDisplayLuminance * 0.01 / (log(lmax + 1.0) / log(10.0));
  float ld = scale * log(l + 1.0) / log(2.0 + 8.0 * pow(l / lmax, biasPower));
  return clamp(ld, 0.0, 1.0);
}

vec3 ToneMapDrago(vec3 radiance) {
  float lw = Luminance(radiance);
  if (!(lw > 0.0)) return vec3(0.0);
  return clamp(radiance * (DragoDisplayLuminance(lw) / lw), 0.0, 1.0);
}

float LinearToSrgb(float c) {
  c = clamp(c, 0.0, 1.0);
  return c <= 0.0031308 ? 12.92 * c : 1.055 * pow(c, 1.0 / 2.4) - 0.055;
}

void main() {
  vec4 radiance = texelFetch(uRadiance, ivec2(gl_FragCoord.xy), 0);
  if (radiance.a == 0.0) {
    outColour = vec4(uBackground, 1.0);
    return;
  }
  if (uOperator == 0) {
    vec3 display = ToneMapDrago(radiance.rgb);
    outColour = vec4(LinearToSrgb(display.r), LinearToSrgb(display.g), LinearToSrgb(display.b), 1.0);
  } else {
    vec3 display = clamp(radiance.rgb * uExposure, 0.0, 1.0);
    outColour = vec4(pow(display, vec3(1.0 / uGamma)), 1.0);
  }
}
)";

}  // namespace

Expected<ToneMapper> ToneMapper::Create() {
  auto program = BuildProgram("tone mapping", kFullScreenVertexShader, kToneMapFragmentShader);
  if (!program) return program.error();
  return ToneMapper(std::move(*program), MakeVertexArray());
}

void ToneMapper::Draw(GLuint radianceTexture, const ViewLuminance& adaptation, const DragoParams& sceneParams,
                      const ToneSettings& settings) const {
  const GLuint p = program_.id();
  glUseProgram(p);
  const float stops = std::exp2(settings.exposureStops);
  const bool drago = settings.op == ToneOperator::kDrago;
  glUniform1i(glGetUniformLocation(p, "uRadiance"), 0);
  glUniform1i(glGetUniformLocation(p, "uOperator"), drago ? 0 : 1);
  glUniform1f(glGetUniformLocation(p, "uViewMax"), adaptation.max);
  glUniform1f(glGetUniformLocation(p, "uViewLogAverage"), adaptation.logAverage);
  glUniform1f(glGetUniformLocation(p, "uBias"), sceneParams.bias);
  glUniform1f(glGetUniformLocation(p, "uMaxDisplayLuminance"), sceneParams.maxDisplayLuminance);
  glUniform1f(glGetUniformLocation(p, "uExposure"),
              drago ? sceneParams.exposure * stops : stops * kMidGrey / std::max(adaptation.logAverage, 1e-9f));
  glUniform1f(glGetUniformLocation(p, "uGamma"), std::max(settings.gamma, 0.1f));
  glUniform3fv(glGetUniformLocation(p, "uBackground"), 1, kBackgroundDisplay);
  glActiveTexture(GL_TEXTURE0);
  glBindTexture(GL_TEXTURE_2D, radianceTexture);
  glBindVertexArray(empty_.id());
  glDisable(GL_DEPTH_TEST);
  glDrawArrays(GL_TRIANGLES, 0, 3);
  glBindVertexArray(0);
}

}  // namespace penumbra::client::gl

#include "penumbra/sma/sample_cache.h"

#include <fmt/format.h>

namespace penumbra::sma {

RadianceBounds RadianceBounds::ForScene(const Scene& scene) {
  const float brightest = scene.MaxEmittedRadiance();
  RadianceBounds bounds;
  bounds.maxRadiance = kMonteCarloMargin * brightest;
  bounds.maxIrradiance = kMonteCarloMargin * kPi * brightest;
  return bounds;
}

Status RadianceBounds::Check(const ShadedSample& sample) const {
  const auto inRange = [](const Rgb& c, float limit) {
    for (int i = 0; i < 3; ++i)
      if (!(c[i] >= 0.0f && c[i] <= limit)) return false;  // also false for NaN
    return true;
  };
  if (!inRange(sample.radiance, maxRadiance))
    return Fail(fmt::format("radiance ({:g}, {:g}, {:g}) is outside [0, {:g}]", sample.radiance.r, sample.radiance.g,
                            sample.radiance.b, maxRadiance));
  if (!inRange(sample.irradiance, maxIrradiance))
    return Fail(fmt::format("irradiance ({:g}, {:g}, {:g}) is outside [0, {:g}]", sample.irradiance.r,
                            sample.irradiance.g, sample.irradiance.b, maxIrradiance));
  if (!(sample.irradianceStdErr >= 0.0f && sample.irradianceStdErr <= maxIrradiance))
    return Fail(fmt::format("standard error {:g} is outside [0, {:g}]", sample.irradianceStdErr, maxIrradiance));
  return Status::Ok();
}

void SampleCache::Reserve(size_t vertexCount) {
  if (vertexCount <= shaded_.size()) return;
  shaded_.resize(vertexCount, 0);
  radiance_.resize(vertexCount, Rgb(0.0f));
  irradiance_.resize(vertexCount, Rgb(0.0f));
  irradianceStdErr_.resize(vertexCount, 0.0f);
}

size_t SampleCache::Store(std::span<const ShadedSample> samples) {
  size_t added = 0;
  for (const ShadedSample& s : samples) {
    if (s.vertex == kNoVertex) continue;
    if (s.vertex >= shaded_.size()) Reserve(size_t(s.vertex) + 1);
    if (shaded_[s.vertex]) continue;
    shaded_[s.vertex] = 1;
    radiance_[s.vertex] = s.radiance;
    irradiance_[s.vertex] = s.irradiance;
    irradianceStdErr_[s.vertex] = s.irradianceStdErr;
    ++added;
  }
  shadedCount_ += added;
  return added;
}

}  // namespace penumbra::sma

#include "penumbra/sma/sample_cache.h"

#include <algorithm>
#include <cmath>

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
  paths_.resize(vertexCount, 0);
  rounds_.resize(vertexCount, 0);
}

float SampleCache::RelativeError(VertexId v) const {
  if (!IsShaded(v)) return 0.0f;
  const float e = penumbra::Luminance(irradiance_[v]);
  const float err = irradianceStdErr_[v];
  if (!(err > 0.0f)) return 0.0f;
  return e > 0.0f ? err / e : std::numeric_limits<float>::infinity();
}

std::vector<VertexId> SampleCache::Improve(std::span<const ShadedSample> samples) {
  std::vector<VertexId> changed;
  changed.reserve(samples.size());
  for (const ShadedSample& s : samples) {
    if (s.vertex >= shaded_.size() || !shaded_[s.vertex] || s.round != rounds_[s.vertex] + 1 || s.paths == 0)
      continue;
    const VertexId v = s.vertex;
    const double n1 = std::max<uint32_t>(1, paths_[v]), n2 = std::max<uint32_t>(1, s.paths), n = n1 + n2;
    const float w1 = float(n1 / n), w2 = float(n2 / n);
    radiance_[v] = w1 * radiance_[v] + w2 * s.radiance;
    irradiance_[v] = w1 * irradiance_[v] + w2 * s.irradiance;
    // Var(w1 X1 + w2 X2) = w1^2 Var1 + w2^2 Var2 for independent estimates.
    irradianceStdErr_[v] = std::sqrt(w1 * w1 * irradianceStdErr_[v] * irradianceStdErr_[v] +
                                     w2 * w2 * s.irradianceStdErr * s.irradianceStdErr);
    paths_[v] = uint32_t(std::min<double>(n, std::numeric_limits<uint32_t>::max()));
    rounds_[v] = s.round;
    changed.push_back(v);
  }
  changes_ += changed.size();
  return changed;
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
    paths_[s.vertex] = s.paths;
    ++added;
  }
  shadedCount_ += added;
  changes_ += added;
  return added;
}

size_t SampleCache::Restore(std::span<const ShadedSample> samples) {
  size_t added = 0;
  for (const ShadedSample& s : samples) {
    if (s.vertex == kNoVertex) continue;
    if (s.vertex >= shaded_.size()) Reserve(size_t(s.vertex) + 1);
    if (shaded_[s.vertex]) continue;
    shaded_[s.vertex] = 1;
    radiance_[s.vertex] = s.radiance;
    irradiance_[s.vertex] = s.irradiance;
    irradianceStdErr_[s.vertex] = s.irradianceStdErr;
    paths_[s.vertex] = s.paths;
    rounds_[s.vertex] = s.round;
    ++added;
  }
  shadedCount_ += added;
  changes_ += added;
  return added;
}

}  // namespace penumbra::sma

#include "penumbra/sma/sample_cache.h"

namespace penumbra::sma {

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

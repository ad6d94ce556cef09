#pragma once
// The object-space sample cache: one shading sample per hierarchy vertex,
// shared by every client (paper §2). A sample is either shaded, with its
// radiance and irradiance, or not yet. A shaded sample can be improved in
// place: a further, independent estimate (an improvement round, with a random
// stream of its own) is averaged in, weighted by the paths of each, so that
// the noise of what clients see falls as a view rests; who asked for it and whether it is on
// its way is the renderer pool's business, not the cache's.
//
// Threads: not synchronised; the SMA guards it with its state lock (readers
// shared, Store() exclusive).

#include <atomic>
#include <cstdint>
#include <limits>
#include <span>
#include <vector>

#include "penumbra/common/expected.h"
#include "penumbra/common/math.h"
#include "penumbra/sma/hierarchy.h"

namespace penumbra::sma {

struct ShadedSample {
  VertexId vertex = kNoVertex;
  Rgb radiance{0.0f};
  Rgb irradiance{0.0f};
  float irradianceStdErr = 0.0f;  // standard error of Luminance(irradiance), from the renderer
  uint32_t paths = 1;             // paths the estimate averages
  uint16_t round = 0;             // 0: the first estimate; k > 0: the k-th improvement
};

/// What a renderer's sample can physically be in one scene, so that a bad or
/// hostile renderer cannot poison the cache that every client is served from.
/// Reflected radiance is non-negative and, for albedo <= 1, at most the
/// brightest emitter's radiance L; irradiance at most pi L. One Monte Carlo
/// estimate may overshoot the physical value (a path that lands close to a
/// light), so the bounds are `kMonteCarloMargin` times wider: absurd values
/// (1e30, 3e38) fail, noisy honest ones pass.
struct RadianceBounds {
  static constexpr float kMonteCarloMargin = 1.0e4f;
  float maxRadiance = std::numeric_limits<float>::max();
  float maxIrradiance = std::numeric_limits<float>::max();

  static RadianceBounds ForScene(const Scene& scene);
  /// OK, or what is wrong with the sample (non-finite, negative, too bright).
  Status Check(const ShadedSample& sample) const;
};

class SampleCache {
 public:
  /// Grows to cover `vertexCount` vertices (new ones unshaded).
  void Reserve(size_t vertexCount);
  size_t Size() const { return shaded_.size(); }

  bool IsShaded(VertexId v) const { return v < shaded_.size() && shaded_[v] != 0; }
  const Rgb& Radiance(VertexId v) const { return radiance_[v]; }
  const Rgb& Irradiance(VertexId v) const { return irradiance_[v]; }
  float IrradianceStdErr(VertexId v) const { return irradianceStdErr_[v]; }
  /// Paths averaged into a shaded sample, and the improvement rounds so far.
  uint32_t Paths(VertexId v) const { return paths_[v]; }
  uint16_t Rounds(VertexId v) const { return rounds_[v]; }
  /// Relative standard error of a shaded sample's irradiance luminance (0
  /// for a sample that reads black with no spread: nothing to improve).
  float RelativeError(VertexId v) const;
  /// Luminance of the shaded radiance (0 when unshaded).
  float Luminance(VertexId v) const { return IsShaded(v) ? penumbra::Luminance(radiance_[v]) : 0.0f; }

  /// Stores first estimates (round 0); a vertex beyond Size() grows the
  /// cache. Storing a vertex twice keeps the first value (samples are
  /// deterministic, so a second one can only be a duplicate). Returns how
  /// many were new.
  size_t Store(std::span<const ShadedSample> samples);
  /// Averages improvements (round k > 0) into shaded samples, weighted by
  /// paths; the standard errors combine accordingly. An improvement of an
  /// unshaded vertex, or whose round is not the vertex's next, is ignored.
  /// Returns the vertices that changed.
  std::vector<VertexId> Improve(std::span<const ShadedSample> samples);

  /// Puts back samples as a snapshot saved them (CacheSnapshot), with their
  /// paths and improvement rounds, into vertices not yet shaded; a vertex
  /// beyond Size() grows the cache. Returns how many were put back.
  size_t Restore(std::span<const ShadedSample> samples);

  size_t ShadedCount() const { return shadedCount_; }
  /// Counts every sample stored, improved or restored: a snapshot is due when
  /// it moved since the last one.
  uint64_t Changes() const { return changes_; }

  /// Lookup statistics for the hit rate: a lookup of a vertex a view needed.
  /// Thread-safe (counted by readers holding the state lock shared).
  void CountLookups(uint64_t hits, uint64_t misses) const {
    hits_ += hits;
    misses_ += misses;
  }
  uint64_t Hits() const { return hits_; }
  uint64_t Misses() const { return misses_; }

 private:
  std::vector<uint8_t> shaded_;
  std::vector<Rgb> radiance_;
  std::vector<Rgb> irradiance_;
  std::vector<float> irradianceStdErr_;
  std::vector<uint32_t> paths_;
  std::vector<uint16_t> rounds_;
  size_t shadedCount_ = 0;
  uint64_t changes_ = 0;
  mutable std::atomic<uint64_t> hits_{0};
  mutable std::atomic<uint64_t> misses_{0};
};

/// Whether the corners of `node` are all shaded.
inline bool CornersShaded(const Node& node, const SampleCache& cache) {
  return cache.IsShaded(node.v[0]) && cache.IsShaded(node.v[1]) && cache.IsShaded(node.v[2]);
}

}  // namespace penumbra::sma

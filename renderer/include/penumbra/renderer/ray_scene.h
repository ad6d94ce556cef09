#pragma once
// RayScene: the scene's triangles committed to Embree once, then queried
// read-only by any number of threads. This header and ray_scene.cpp are the
// only places in the renderer that touch Embree.
//
// Rays do not move their own origins: a caller leaving a surface offsets the
// origin off it (see shading.cpp) and passes tMin = 0. Triangle hits are
// robust along shared edges (Embree's robust mode), so a ray through an edge
// of a closed mesh does not slip between its two triangles.

#include <cstddef>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <span>

#include "penumbra/common/expected.h"
#include "penumbra/common/math.h"
#include "penumbra/common/scene.h"

namespace penumbra {

/// A ray-triangle hit on a base triangle.
struct RayHit {
  uint32_t triangle = 0;  // index into Scene::triangles
  float t = 0.0f;         // distance along the (unit) direction
  float b1 = 0.0f;        // barycentrics: p = (1-b1-b2) v0 + b1 v1 + b2 v2
  float b2 = 0.0f;
  Vec3 normal{0.0f};      // geometric normal, not unit: cross(v1 - v0, v2 - v0)
};

/// A ray for batch queries: origin + t*direction, t in [0, tMax).
struct Ray {
  Vec3 origin;
  Vec3 direction;  // unit
  float tMax = std::numeric_limits<float>::infinity();
};

enum class RayQuery { kClosestHit, kOcclusion };

class RayScene {
 public:
  /// Builds the acceleration structure over every triangle of `scene` (vertex
  /// data is copied; the scene need not outlive the RayScene). Errors from
  /// Embree become an Error.
  static Expected<std::unique_ptr<RayScene>> Build(const Scene& scene);
  ~RayScene();
  RayScene(const RayScene&) = delete;
  RayScene& operator=(const RayScene&) = delete;

  /// Closest hit along origin + t*direction, t in (tMin, tMax). Both sides of
  /// every triangle are hit. Thread-safe.
  std::optional<RayHit> Intersect(const Vec3& origin, const Vec3& direction, float tMin, float tMax) const;
  /// Whether anything blocks origin + t*direction for t in (tMin, tMax).
  /// Thread-safe.
  bool Occluded(const Vec3& origin, const Vec3& direction, float tMin, float tMax) const;

  /// The benchmark baseline: traces `rays` back to back with plain
  /// rtcIntersect1 or rtcOccluded1 and does nothing else with the results.
  /// Returns how many rays hit something. Thread-safe; for measurement only.
  size_t TraceRaw(std::span<const Ray> rays, RayQuery query) const;

  struct Impl;

 private:
  explicit RayScene(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

/// Sets flush-to-zero and denormals-are-zero on the calling thread, as Embree
/// asks of every thread that traces. Call once per worker thread.
void EnableFlushToZero();

}  // namespace penumbra

#pragma once
// RayScene: the scene's triangles committed to Embree once, then queried
// read-only by any number of threads. This header and ray_scene.cpp are the
// only places in the renderer that touch Embree.

#include <cstdint>
#include <memory>
#include <optional>

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
};

class RayScene {
 public:
  /// Builds the acceleration structure (the scene must outlive nothing here:
  /// vertex data is copied). Errors from Embree become an Error.
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

  struct Impl;

 private:
  explicit RayScene(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

/// Sets flush-to-zero and denormals-are-zero on the calling thread, as Embree
/// asks of every thread that traces. Call once per worker thread.
void EnableFlushToZero();

}  // namespace penumbra

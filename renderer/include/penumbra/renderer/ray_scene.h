#pragma once
// RayScene: the scene's triangles committed to Embree once, then queried
// read-only by any number of threads. This header and ray_scene.cpp are the
// only places in the renderer that touch Embree.
//
// Rays do not move their own origins: a caller leaving a surface offsets the
// origin off it (see shading.cpp) and passes tMin = 0. Triangle hits are
// robust along shared edges (Embree's robust mode), so a ray through an edge
// of a closed mesh does not slip between its two triangles.
//
// Movable objects (issue 14). Queries run against one pose of the scene, a
// PosedRayScene: RayScene::Initial() is the scene as loaded, AtPose() places
// the movable objects elsewhere (Embree instances over the static part and
// each object, committed once: a new pose is a top-level commit of a few
// instances, not a rebuild). Hits name base triangles and carry world-space
// normals at every pose. A scene without movable objects has no instancing:
// every pose is the one static BVH, queried exactly as before.

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
  Vec3 normal{0.0f};      // world-space geometric normal, not unit: cross(v1 - v0, v2 - v0) at the pose
};

/// A ray for batch queries: origin + t*direction, t in [0, tMax).
struct Ray {
  Vec3 origin;
  Vec3 direction;  // unit
  float tMax = std::numeric_limits<float>::infinity();
};

enum class RayQuery { kClosestHit, kOcclusion };

class PosedEmbreeScene;

/// The scene with its movable objects placed by one pose. Immutable and
/// thread-safe to query; shared by every batch shaded at that pose. It keeps
/// its Embree scene alive, but the RayScene it came from must outlive it.
class PosedRayScene {
 public:
  ~PosedRayScene();
  PosedRayScene(const PosedRayScene&) = delete;
  PosedRayScene& operator=(const PosedRayScene&) = delete;

  /// The pose asked for (with its epoch).
  const ScenePose& Pose() const { return pose_; }

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

 private:
  friend class RayScene;
  PosedRayScene(std::shared_ptr<const PosedEmbreeScene> embree, ScenePose pose);
  std::shared_ptr<const PosedEmbreeScene> embree_;
  ScenePose pose_;
};

class RayScene {
 public:
  /// Builds the acceleration structures over every triangle of `scene` (the
  /// static part once, each movable object once; vertex data is copied; the
  /// scene need not outlive the RayScene). Errors from Embree become an Error.
  static Expected<std::unique_ptr<RayScene>> Build(const Scene& scene);
  ~RayScene();
  RayScene(const RayScene&) = delete;
  RayScene& operator=(const RayScene&) = delete;

  /// The scene as loaded (ScenePose::Initial). Thread-safe.
  const std::shared_ptr<const PosedRayScene>& Initial() const;
  /// The scene at `pose` (one rigid transform per movable object of the
  /// scene; its epoch is kept for Pose()). Without movable objects it is
  /// Initial()'s BVH. The last pose's Embree scene is reused when the places
  /// are the same, so a stream of batches at one pose builds it once; a new
  /// pose commits a top level of instances (microseconds for a few objects).
  /// Fails for a pose with the wrong number of transforms, or an Embree
  /// error. Thread-safe.
  Expected<std::shared_ptr<const PosedRayScene>> AtPose(const ScenePose& pose) const;
  size_t MovableObjectCount() const;

  /// At the initial pose: Initial()->Intersect and so on. Thread-safe.
  std::optional<RayHit> Intersect(const Vec3& origin, const Vec3& direction, float tMin, float tMax) const;
  bool Occluded(const Vec3& origin, const Vec3& direction, float tMin, float tMax) const;
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

#pragma once
// EmbreeScene: an Embree device and one committed scene of a Scene's
// triangles -- geometry 0, primitive id = base triangle index -- with every
// device error sent to one named logger and every failed step returned as an
// Error. Build once, then query read-only from any thread.
//
// Movable objects (issue 14): a scene with movable objects commits its static
// triangles once into one bottom-level scene and each object's triangles (in
// object space) into one of its own. A pose is then a small top-level scene
// of instances -- instance 0 the static part at identity, instance 1 + i
// object i at its transform -- built in microseconds and never modified:
// queries on an older pose finish on it while a newer one is built. A scene
// without movable objects has no instancing at all: its pose is the one
// static scene, exactly as before.
//
// Both tiers that trace rays build on it (the renderer's RayScene, the SMA's
// VisibilityTracer); each keeps its own queries and chooses its scene flags.
// Its own library (penumbra_embree) so that penumbra_common stays free of
// Embree, and this header free of Embree's headers.

#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "penumbra/common/expected.h"
#include "penumbra/common/scene.h"

typedef struct RTCDeviceTy* RTCDevice;  // NOLINT: Embree's own handle types
typedef struct RTCSceneTy* RTCScene;    // NOLINT

namespace penumbra {

struct EmbreeSceneOptions {
  std::string logger = "embree";  // named logger for device errors
  /// RTC_SCENE_FLAG_ROBUST: conservative traversal so rays do not slip
  /// through the shared edges of closed meshes (the renderer's shadow rays),
  /// at a cost in speed.
  bool robust = false;
};

/// One pose of the scene, committed for queries. Immutable; thread-safe to
/// query; keep the shared_ptr alive while any query on it runs.
class PosedEmbreeScene {
 public:
  ~PosedEmbreeScene();
  PosedEmbreeScene(const PosedEmbreeScene&) = delete;
  PosedEmbreeScene& operator=(const PosedEmbreeScene&) = delete;

  RTCScene Handle() const { return top_; }
  const ScenePose& Pose() const { return pose_; }
  /// The base triangle (index into Scene::triangles) a hit names, from the
  /// hit's instID[0] and primID.
  uint32_t Triangle(unsigned instanceId, unsigned primitiveId) const {
    if (!instanced_ || instanceId == 0) return primitiveId;
    return firstTriangleOfInstance_[instanceId] + primitiveId;
  }
  /// World-space direction of a hit's geometric normal (Embree reports it
  /// in the instanced object's space).
  Vec3 WorldNormal(unsigned instanceId, const Vec3& objectNormal) const {
    if (!instanced_ || instanceId == 0) return objectNormal;
    return pose_.objectToWorld[instanceId - 1].ApplyVector(objectNormal);
  }

 private:
  friend class EmbreeScene;
  PosedEmbreeScene() = default;
  RTCScene top_ = nullptr;
  bool instanced_ = false;  // false: top_ is the static scene itself (no movable objects)
  bool ownsTop_ = false;
  ScenePose pose_;
  std::vector<uint32_t> firstTriangleOfInstance_;  // [0] = 0 (static), [1 + i] = objects[i].firstTriangle
};

class EmbreeScene {
 public:
  static constexpr unsigned kGeometryId = 0;

  /// Copies the scene's positions and triangles into high-quality BVHs (one
  /// for the static part and one per movable object) and commits the initial
  /// pose.
  static Expected<std::unique_ptr<EmbreeScene>> Build(const Scene& scene, const EmbreeSceneOptions& options);
  ~EmbreeScene();
  EmbreeScene(const EmbreeScene&) = delete;
  EmbreeScene& operator=(const EmbreeScene&) = delete;

  /// The scene at its initial pose (ScenePose::Initial).
  const std::shared_ptr<const PosedEmbreeScene>& Initial() const { return initial_; }
  /// The scene at `pose` (one transform per movable object). Without movable
  /// objects this is Initial(). Returns the last pose built when its places
  /// are the same; otherwise builds a new top level. Thread-safe.
  Expected<std::shared_ptr<const PosedEmbreeScene>> AtPose(const ScenePose& pose) const;
  bool HasMovableObjects() const { return !objectScenes_.empty(); }

 private:
  EmbreeScene() = default;
  Expected<std::shared_ptr<const PosedEmbreeScene>> BuildPose(const ScenePose& pose) const;
  RTCDevice device_ = nullptr;
  RTCScene staticScene_ = nullptr;           // null when the static part has no triangles
  std::vector<RTCScene> objectScenes_;       // one per movable object, object space
  std::vector<uint32_t> firstTriangleOfInstance_;
  bool robust_ = false;
  std::string logger_;
  std::shared_ptr<const PosedEmbreeScene> initial_;
  mutable std::mutex poseMutex_;  // guards last_
  mutable std::shared_ptr<const PosedEmbreeScene> last_;
};

}  // namespace penumbra

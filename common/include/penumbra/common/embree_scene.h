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
// Static instances (issue 15): the copies of one mesh file placed by a scene
// file's "instances" share one bottom-level scene, committed once in the
// mesh file's own coordinates (from its first copy). Each copy is one more
// instance in the top level at its fixed place; a hit on it names the scene's
// triangle StaticInstance::firstTriangle + primID. The scene's other static
// triangles stay in the static scene. With instances the top level exists
// even without movable objects; without either, nothing changes.
//
// Instance ids in the top level: 0 the static scene, 1 + i movable object i,
// 1 + objects + k static instance k. PosedEmbreeScene::Triangle and
// WorldNormal are the one place that turns them back into the Scene's terms.
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
  /// World-space direction of a normal given in the Scene's own terms for
  /// the triangle a hit names: object space for a movable object's triangle,
  /// world space for every static one (static instances are stored in world
  /// space too).
  Vec3 WorldNormal(unsigned instanceId, const Vec3& sceneNormal) const {
    if (!instanced_ || instanceId == 0 || instanceId > objectCount_) return sceneNormal;
    return instanceToWorld_[instanceId].ApplyVector(sceneNormal);
  }
  /// World-space direction of Embree's own geometric normal of a hit (Ng),
  /// which Embree 3 reports in the instanced scene's space: a movable
  /// object's object space or an instanced mesh's own coordinates.
  Vec3 WorldHitNormal(unsigned instanceId, const Vec3& embreeNormal) const {
    if (!instanced_ || instanceId == 0) return embreeNormal;
    return instanceToWorld_[instanceId].ApplyVector(embreeNormal);
  }

 private:
  friend class EmbreeScene;
  PosedEmbreeScene() = default;
  RTCScene top_ = nullptr;
  bool instanced_ = false;  // false: top_ is the static scene itself (no movable objects, no instances)
  bool ownsTop_ = false;
  ScenePose pose_;
  std::vector<uint32_t> firstTriangleOfInstance_;  // by instance id: [0] = 0 (static), then objects, then static instances
  std::vector<RigidTransform> instanceToWorld_;    // by instance id, at this pose
  unsigned objectCount_ = 0;                       // instance ids 1..objectCount_ are movable objects
};

class EmbreeScene {
 public:
  static constexpr unsigned kGeometryId = 0;

  /// Copies the scene's positions and triangles into high-quality BVHs (one
  /// for the static part, one per movable object, one per mesh that static
  /// instances copy) and commits the initial pose.
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
  /// Whether static instances share bottom-level scenes (the scene has instances).
  bool HasStaticInstances() const { return !instances_.empty(); }

 private:
  EmbreeScene() = default;
  Expected<std::shared_ptr<const PosedEmbreeScene>> BuildPose(const ScenePose& pose) const;
  RTCDevice device_ = nullptr;
  RTCScene staticScene_ = nullptr;           // null when the static part has no triangles
  std::vector<RTCScene> objectScenes_;       // one per movable object, object space
  std::vector<uint32_t> firstTriangleOfInstance_;  // by instance id, as in PosedEmbreeScene
  struct PlacedMesh {
    RTCScene mesh;  // owned by meshScenes_
    RigidTransform meshToWorld;
  };
  std::vector<RTCScene> meshScenes_;  // one per instanced mesh, in its own coordinates
  std::vector<PlacedMesh> instances_; // one per Scene::instances
  bool robust_ = false;
  std::string logger_;
  std::shared_ptr<const PosedEmbreeScene> initial_;
  mutable std::mutex poseMutex_;  // guards last_
  mutable std::shared_ptr<const PosedEmbreeScene> last_;
};

}  // namespace penumbra

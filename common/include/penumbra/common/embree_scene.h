#pragma once
// EmbreeScene: an Embree device and one committed scene of a Scene's
// triangles -- geometry 0, primitive id = base triangle index -- with every
// device error sent to one named logger and every failed step returned as an
// Error. Build once, then query read-only from any thread.
//
// Both tiers that trace rays build on it (the renderer's RayScene, the SMA's
// VisibilityTracer); each keeps its own queries and chooses its scene flags.
// Its own library (penumbra_embree) so that penumbra_common stays free of
// Embree, and this header free of Embree's headers.

#include <memory>
#include <string>

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

class EmbreeScene {
 public:
  static constexpr unsigned kGeometryId = 0;

  /// Copies the scene's positions and triangles into a high-quality BVH.
  static Expected<std::unique_ptr<EmbreeScene>> Build(const Scene& scene, const EmbreeSceneOptions& options);
  ~EmbreeScene();
  EmbreeScene(const EmbreeScene&) = delete;
  EmbreeScene& operator=(const EmbreeScene&) = delete;

  RTCScene Handle() const { return scene_; }

 private:
  EmbreeScene() = default;
  RTCDevice device_ = nullptr;
  RTCScene scene_ = nullptr;
  std::string logger_;
};

}  // namespace penumbra

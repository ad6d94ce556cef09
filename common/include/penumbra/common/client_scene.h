#pragma once
// What a client knows of the scene it is shown: the SceneInfo of the client
// protocol (docs/protocol.md) as a plain value. The SMA makes it from its
// Scene (MakeClientScene) and sends it (wire_convert.h: ToWire); the client
// receives it validated (ClientSceneFromWire) and its renderers draw from it,
// so no code on either side reads the protobuf fields itself. No protobuf here.
//
// Threads: a plain value; any thread.

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "penumbra/common/camera.h"
#include "penumbra/common/math.h"
#include "penumbra/common/rigid_transform.h"
#include "penumbra/common/scene.h"
#include "penumbra/common/tonemap.h"

namespace penumbra {

/// A material as a client draws it: untextured radiance is
/// emission + albedo * E / pi; a textured one multiplies albedo by texture
/// `texture` (an index below ClientScene::textureCount; -1: none).
struct ClientMaterial {
  Rgb albedo{0.0f};
  Rgb emission{0.0f};
  int32_t texture = -1;

  friend bool operator==(const ClientMaterial&, const ClientMaterial&) = default;
};

/// The most movable objects a SceneInfo may announce: a client keeps a
/// transform per object (and uploads them all to the GPU), so the count a
/// wire message gives must bound that.
inline constexpr uint32_t kMaxClientSceneObjects = 4096;

/// A movable object as a client sees it (issue 14). Its id on the wire
/// (MoveObject.object, Delta.vertex_objects, moved_objects) is its index in
/// ClientScene::objects plus 1; id 0 is the static part.
struct ClientObject {
  std::string name;
  Bounds3 objectBounds;          // object space
  RigidTransform objectToWorld;  // where it is at ClientScene::sceneEpoch
  bool animated = false;         // the SMA plays its path; a MoveObject on it is refused

  /// World-space bounds at objectToWorld.
  Bounds3 WorldBounds() const { return objectToWorld.ApplyBounds(objectBounds); }
};

struct ClientScene {
  std::string name;
  /// The scene's identity (Scene::identity, the Welcome's scene_hash; not in
  /// the SceneInfo itself). 0: unknown, so never "the same scene".
  uint64_t identity = 0;
  Bounds3 bounds;
  std::vector<CameraPreset> cameras;  // named presets; the first is the default view
  std::vector<ClientMaterial> materials;  // by material index (a delta's triangle_materials)
  uint32_t textureCount = 0;  // textures a client may ask for (TextureRequest); at most kMaxSceneTextures
  std::optional<SkyLight> sky;  // drawn behind the mesh; none: black
  DragoParams toneMapping;     // the operator's defaults (the SMA's flags)
  /// Movable objects, id = index + 1 (at most kMaxClientSceneObjects). Empty:
  /// everything is static.
  std::vector<ClientObject> objects;
  /// Moves so far; `objects`' transforms are those of this epoch.
  uint64_t sceneEpoch = 0;

  /// Each material's texture index (-1: none), for MeshStore::Reset.
  std::vector<int32_t> MaterialTextures() const;
  /// The index of the preset named `name`, or -1.
  int FindCamera(std::string_view name) const;
  /// The id (index + 1) of the object called `name`, or 0 when there is none.
  uint32_t FindObject(std::string_view name) const;
};

/// What clients of `scene` are told, with the tone mapping the SMA's
/// operator chose. `scene` must be finalized (bounds, identity).
/// Movable objects are at their initial places (epoch 0).
ClientScene MakeClientScene(const Scene& scene, const DragoParams& toneMapping);
/// The same with the objects where `pose` puts them, at its epoch (the
/// SceneInfo of a client that connects after moves). `pose` has one
/// transform per Scene::objects.
ClientScene MakeClientScene(const Scene& scene, const DragoParams& toneMapping, const ScenePose& pose);

}  // namespace penumbra

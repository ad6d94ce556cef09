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

  /// Each material's texture index (-1: none), for MeshStore::Reset.
  std::vector<int32_t> MaterialTextures() const;
  /// The index of the preset named `name`, or -1.
  int FindCamera(std::string_view name) const;
};

/// What clients of `scene` are told, with the tone mapping the SMA's
/// operator chose. `scene` must be finalized (bounds, identity).
ClientScene MakeClientScene(const Scene& scene, const DragoParams& toneMapping);

}  // namespace penumbra

#include "penumbra/common/client_scene.h"

namespace penumbra {

std::vector<int32_t> ClientScene::MaterialTextures() const {
  std::vector<int32_t> textures;
  textures.reserve(materials.size());
  for (const ClientMaterial& m : materials) textures.push_back(m.texture);
  return textures;
}

int ClientScene::FindCamera(std::string_view presetName) const {
  for (size_t i = 0; i < cameras.size(); ++i)
    if (cameras[i].name == presetName) return int(i);
  return -1;
}

uint32_t ClientScene::FindObject(std::string_view objectName) const {
  for (size_t i = 0; i < objects.size(); ++i)
    if (objects[i].name == objectName) return uint32_t(i + 1);
  return 0;
}

ClientScene MakeClientScene(const Scene& scene, const DragoParams& toneMapping) {
  return MakeClientScene(scene, toneMapping, ScenePose::Initial(scene));
}

ClientScene MakeClientScene(const Scene& scene, const DragoParams& toneMapping, const ScenePose& pose) {
  ClientScene out;
  out.name = scene.name;
  out.identity = scene.identity;
  out.bounds = scene.bounds;
  out.cameras = scene.cameras;
  out.materials.reserve(scene.materials.size());
  for (const Material& m : scene.materials) out.materials.push_back(ClientMaterial{m.albedo, m.emission, m.albedoTexture});
  out.textureCount = uint32_t(scene.textures.size());
  out.sky = scene.sky;
  out.toneMapping = toneMapping;
  out.objects.reserve(scene.objects.size());
  for (size_t i = 0; i < scene.objects.size(); ++i) {
    const MovableObject& o = scene.objects[i];
    out.objects.push_back(ClientObject{o.name, o.objectBounds,
                                       i < pose.objectToWorld.size() ? pose.objectToWorld[i] : o.objectToWorld,
                                       o.animation.has_value()});
  }
  out.sceneEpoch = pose.epoch;
  return out;
}

}  // namespace penumbra

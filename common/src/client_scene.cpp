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

ClientScene MakeClientScene(const Scene& scene, const DragoParams& toneMapping) {
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
  return out;
}

}  // namespace penumbra

// The scene loader (LoadScene: assimp's glTF 2.0 reader, our reading of
// KHR_materials_emissive_strength, embedded images through OpenImageIO, then
// SceneBuilder) on a glTF or GLB file. Input: the file; it is written as
// fuzz.glb when it starts with the GLB magic "glTF", else as fuzz.gltf.

#include "fuzz_support.h"
#include "penumbra/common/scene.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace penumbra;
  static fuzz::ScratchDir dir;
  static const bool quiet = (fuzz::QuietLogs(), true);
  (void)quiet;
  const std::string_view input(reinterpret_cast<const char*>(data), size);
  const auto path = dir.Path() / (input.starts_with("glTF") ? "fuzz.glb" : "fuzz.gltf");
  fuzz::WriteFile(path, input);
  if (auto scene = LoadScene(path)) {
    PENUMBRA_CHECK(!scene->triangles.empty(), "a scene without triangles was accepted");
  }
  std::error_code ec;
  std::filesystem::remove(path, ec);
  return 0;
}

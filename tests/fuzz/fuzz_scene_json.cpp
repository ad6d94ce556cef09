// The scene description reader (ParseSceneFile: JSON, cameras, camera
// paths, lights, material overrides; docs/scenes.md) through LoadScene.
// Input: the scene file, written as fuzz.json into a private folder where
// "cornell-box/" is the shipped Cornell box mesh, so that the seeds (the
// shipped scene files, their mesh pointed there) load completely.

#include "fuzz_support.h"
#include "penumbra/common/scene.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace penumbra;
  static fuzz::ScratchDir dir;
  static const bool setUp = [] {
    fuzz::QuietLogs();
    std::filesystem::create_directory_symlink(fuzz::ScenesDir() / "cornell-box", dir.Path() / "cornell-box");
    return true;
  }();
  (void)setUp;
  fuzz::WriteFile(dir.Path() / "fuzz.json", std::string_view(reinterpret_cast<const char*>(data), size));
  (void)LoadScene(dir.Path() / "fuzz.json");
  return 0;
}

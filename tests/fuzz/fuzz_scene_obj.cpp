// The scene loader (LoadScene: assimp's OBJ reader, then SceneBuilder's
// welding, crease splitting and checks) on an OBJ file and its MTL file.
// Input: the OBJ text, optionally followed by a line "%%MTL%%" and the MTL
// text; they are written as fuzz.obj and fuzz.mtl into a private folder (the
// seeds say "mtllib fuzz.mtl").

#include "fuzz_support.h"
#include "penumbra/common/scene.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace penumbra;
  static fuzz::ScratchDir dir;
  static const bool quiet = (fuzz::QuietLogs(), true);
  (void)quiet;
  const std::string_view input(reinterpret_cast<const char*>(data), size);
  constexpr std::string_view kSeparator = "\n%%MTL%%\n";
  const size_t split = input.find(kSeparator);
  fuzz::WriteFile(dir.Path() / "fuzz.obj", input.substr(0, split));
  fuzz::WriteFile(dir.Path() / "fuzz.mtl",
                  split == std::string_view::npos ? std::string_view() : input.substr(split + kSeparator.size()));
  if (auto scene = LoadScene(dir.Path() / "fuzz.obj")) {
    PENUMBRA_CHECK(!scene->triangles.empty(), "a scene without triangles was accepted");
  }
  return 0;
}

// LoadScene: a scene file (.json) or a mesh file straight into a Scene.
//
//   scene.json --ParseSceneFile--> SceneDescription --+
//                                                     |  mesh path, overrides, quads
//   mesh file  ------------ImportMesh-----------> SceneBuilder --BuildInto--> Scene
//                                                     sun, sky, cameras, paths --^

#include <algorithm>
#include <chrono>
#include <cmath>
#include <exception>
#include <optional>

#include <fmt/format.h>

#include "io_util.h"
#include "mesh_import.h"
#include "penumbra/common/logging.h"
#include "penumbra/common/scene.h"
#include "scene_file.h"

namespace penumbra {
namespace {

namespace fs = std::filesystem;

// A view of the whole scene from its +Z side, a little above, for scenes that
// name no camera: the bounding sphere fills the vertical field of view.
CameraPreset FramingCamera(const Bounds3& bounds) {
  CameraPreset camera;
  camera.name = "default";
  camera.fovYDeg = 45.0f;
  const float radius = std::max(0.5f * glm::length(bounds.Diagonal()), 1e-3f);
  const float distance = radius / std::sin(0.5f * camera.fovYDeg * kPi / 180.0f);
  const Vec3 fromCentre = glm::normalize(Vec3(0.0f, 0.25f, 1.0f));
  camera.pose.target = bounds.Center();
  camera.pose.eye = bounds.Center() + distance * fromCentre;
  camera.pose.up = Vec3(0.0f, 1.0f, 0.0f);
  return camera;
}

Expected<Scene> Load(const fs::path& path, const SceneLoadOptions& options, size_t& degenerateTriangles,
                     size_t& duplicateTriangles) {
  std::optional<SceneDescription> description;
  fs::path meshPath = path;
  float creaseAngleDeg = options.creaseAngleDeg;
  if (io::LowerExtension(path) == ".json") {
    auto parsed = ParseSceneFile(path);
    if (!parsed) return parsed.error();
    description = std::move(*parsed);
    meshPath = description->meshPath;
    creaseAngleDeg = description->creaseAngleDeg.value_or(creaseAngleDeg);
  }

  SceneBuilder builder(creaseAngleDeg);
  if (auto ok = ImportMesh(meshPath, builder); !ok)
    return description ? Fail(fmt::format("{}: {}", path.string(), ok.error().message)) : ok.error();
  if (description) {
    if (auto ok = ApplyToBuilder(*description, builder); !ok) return ok.error();
  }

  Scene scene;
  scene.name = description ? description->name : path.stem().string();
  scene.sourcePath = path;
  if (description) {
    scene.sun = description->sun;
    scene.twoSided = description->twoSided;
    scene.sky = description->sky;
    scene.cameras = std::move(description->cameras);
    scene.paths = std::move(description->paths);
  }
  if (auto ok = builder.BuildInto(scene); !ok) return ok.error();
  if (scene.cameras.empty()) scene.cameras.push_back(FramingCamera(scene.bounds));
  degenerateTriangles = builder.DegenerateTriangles();
  duplicateTriangles = builder.DuplicateTriangles();
  return scene;
}

}  // namespace

Expected<Scene> LoadScene(const fs::path& path, const SceneLoadOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  size_t degenerateTriangles = 0;
  size_t duplicateTriangles = 0;
  Expected<Scene> scene = [&]() -> Expected<Scene> {
    // Assimp, OpenImageIO and the allocator may throw; no exception leaves here.
    try {
      return Load(path, options, degenerateTriangles, duplicateTriangles);
    } catch (const std::exception& e) {
      return Fail(fmt::format("{}: cannot load: {}", path.string(), io::OneLine(e.what())));
    } catch (...) {
      return Fail(fmt::format("{}: cannot load: unknown exception", path.string()));
    }
  }();
  if (!scene) return scene;

  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  Logger("scene")->info(
      "loaded '{}' from {}: {} triangles ({} degenerate and {} duplicate dropped), {} vertices after crease splitting, "
      "{} materials, {} textures, {} emissive triangles{}{} in {:.2f} s",
      scene->name, path.string(), scene->triangles.size(), degenerateTriangles, duplicateTriangles,
      scene->vertices.size(),
      scene->materials.size(), scene->textures.size(), scene->emissiveTriangles.size(), scene->sun ? ", sun" : "",
      scene->sky ? ", sky" : "", seconds);
  return scene;
}

}  // namespace penumbra

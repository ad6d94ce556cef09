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
#include <string>
#include <vector>

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

// The nearest hit of the ray origin + t * direction (t > 0) on any triangle,
// brute force: a handful of rays per load, so no acceleration structure.
std::optional<float> NearestHit(const Scene& scene, const Vec3& origin, const Vec3& direction) {
  std::optional<float> nearest;
  for (uint32_t t = 0; t < scene.triangles.size(); ++t) {
    const Vec3 p0 = scene.Position(t, 0);
    const Vec3 e1 = scene.Position(t, 1) - p0, e2 = scene.Position(t, 2) - p0;
    const Vec3 p = glm::cross(direction, e2);
    const float det = glm::dot(e1, p);
    if (std::abs(det) < 1e-12f) continue;
    const Vec3 s = origin - p0;
    const float u = glm::dot(s, p) / det;
    if (u < 0.0f || u > 1.0f) continue;
    const Vec3 q = glm::cross(s, e1);
    const float v = glm::dot(direction, q) / det;
    if (v < 0.0f || u + v > 1.0f) continue;
    const float distance = glm::dot(e2, q) / det;
    if (distance > 0.0f && (!nearest || distance < *nearest)) nearest = distance;
  }
  return nearest;
}

// For a scene that names no camera: when the model encloses its middle (a
// building: walls in all four horizontal directions and a floor below, seen
// from the middle at eye height), a view from inside at eye height, backed
// up towards one end and looking along the longer horizontal extent; none
// for an object seen from outside (the framing view is then the right one).
std::optional<CameraPreset> InsideCamera(const Scene& scene) {
  const Bounds3& b = scene.bounds;
  const Vec3 size = b.Diagonal();
  if (scene.triangles.empty() || size.x <= 0.0f || size.y <= 0.0f || size.z <= 0.0f) return std::nullopt;
  // Eye height: a quarter of the way up (Y is up, as in FramingCamera).
  const Vec3 middle(b.Center().x, b.min.y + 0.25f * size.y, b.Center().z);
  if (!NearestHit(scene, middle, Vec3(0, -1, 0))) return std::nullopt;  // no floor
  // Three rays each way, spread across the model, so that a block in the
  // middle of an open-fronted box does not pass for a wall.
  const Vec3 horizontal[] = {{1, 0, 0}, {-1, 0, 0}, {0, 0, 1}, {0, 0, -1}};
  for (const Vec3& d : horizontal) {
    const Vec3 across = d.x != 0.0f ? Vec3(0, 0, 0.3f * size.z) : Vec3(0.3f * size.x, 0, 0);
    for (float side : {-1.0f, 0.0f, 1.0f})
      if (!NearestHit(scene, middle + side * across, d)) return std::nullopt;  // open that way: not a building
  }
  const Vec3 forward = size.x >= size.z ? Vec3(1, 0, 0) : Vec3(0, 0, 1);
  const float halfLength = 0.5f * (size.x >= size.z ? size.x : size.z);
  // Back up towards the near end, but stay well clear of whatever is behind.
  const float behind = NearestHit(scene, middle, -forward).value_or(halfLength);
  CameraPreset camera;
  camera.name = "inside";
  camera.fovYDeg = 60.0f;
  camera.pose.eye = middle - forward * std::min(0.6f * halfLength, 0.8f * behind);
  camera.pose.target = middle + forward * (0.5f * halfLength);
  camera.pose.up = Vec3(0.0f, 1.0f, 0.0f);
  return camera;
}

double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

// Triangles per second, for progress lines ("1.23 M triangles/s").
std::string Rate(size_t triangles, double seconds) {
  return fmt::format("{:.2f} M triangles/s", seconds > 0.0 ? double(triangles) / seconds * 1e-6 : 0.0);
}

// A scene file's "instances" (issue 15): each distinct mesh file is read,
// welded and crease-split once into a scene of its own, then handed to
// `builder` with the places of all its copies. The total triangle count is
// checked before any copy is made.
Status AddInstances(const SceneDescription& description, float creaseAngleDeg, SceneBuilder& builder) {
  if (description.instances.empty()) return Status::Ok();
  const std::string file = description.sourcePath.string();
  // Meshes in order of first use; copies of one mesh named by equal paths.
  std::vector<fs::path> meshes;
  std::vector<std::vector<RigidTransform>> placements;
  for (const InstanceDescription& i : description.instances) {
    const fs::path key = i.meshPath.lexically_normal();
    const auto found = std::find(meshes.begin(), meshes.end(), key);
    if (found == meshes.end()) {
      meshes.push_back(key);
      placements.push_back({i.meshToWorld});
    } else {
      placements[size_t(found - meshes.begin())].push_back(i.meshToWorld);
    }
  }
  const auto log = Logger("scene");
  const auto start = std::chrono::steady_clock::now();
  size_t readTriangles = 0;
  for (size_t m = 0; m < meshes.size(); ++m) {
    const auto meshStart = std::chrono::steady_clock::now();
    SceneBuilder meshBuilder(creaseAngleDeg);
    if (auto ok = ImportMesh(meshes[m], meshBuilder); !ok)
      return Fail(fmt::format("{}: instances: {}", file, ok.error().message));
    Scene mesh;
    mesh.name = meshes[m].stem().string();
    mesh.sourcePath = meshes[m];
    if (auto ok = meshBuilder.BuildInto(mesh); !ok) {
      const std::string& message = ok.error().message;
      return Fail(message.find(meshes[m].string()) == std::string::npos
                      ? fmt::format("{}: instances: {}: {}", file, meshes[m].string(), message)
                      : fmt::format("{}: instances: {}", file, message));
    }
    const size_t triangles = mesh.triangles.size(), vertices = mesh.vertices.size();
    const size_t copies = placements[m].size();
    const size_t total = builder.TriangleCount() + builder.InstanceTriangleCount() + triangles * copies;
    if (total > kMaxSceneTriangles)
      return Fail(fmt::format("{}: instances: {} copies of {} ({} triangles each) would make the scene {} triangles; "
                              "at most {} are supported",
                              file, copies, meshes[m].string(), triangles, total, kMaxSceneTriangles));
    readTriangles += triangles;
    builder.AddInstances(std::move(mesh), placements[m]);
    const double seconds = SecondsSince(meshStart);
    log->info("instances: mesh {}/{} {}: {} triangles, {} vertices read in {:.2f} s ({}); {} copies; {} instance "
              "triangles so far",
              m + 1, meshes.size(), meshes[m].string(), triangles, vertices, seconds, Rate(triangles, seconds), copies,
              builder.InstanceTriangleCount());
  }
  const double seconds = SecondsSince(start);
  log->info("instances: {} copies of {} meshes, {} triangles in all; the meshes ({} triangles) read in {:.2f} s ({})",
            description.instances.size(), meshes.size(), builder.InstanceTriangleCount(), readTriangles, seconds,
            Rate(readTriangles, seconds));
  return Status::Ok();
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
  // Movable objects (issue 14): parts of the main mesh ("group") become
  // objects as it is read; then each separate mesh file is read into an
  // object of its own. So Scene::objects lists group objects first, then
  // mesh-file objects, each in file order.
  std::vector<MeshGroup> groups;
  if (description) {
    for (const ObjectDescription& o : description->objects) {
      if (o.groups.empty()) continue;
      MovableObject object;
      object.name = o.name;
      object.objectToWorld = o.placement;
      object.animation = o.animation;
      groups.push_back(MeshGroup{o.groups, o.pivot, std::move(object)});
    }
  }
  const auto readStart = std::chrono::steady_clock::now();
  if (auto ok = ImportMesh(meshPath, builder, groups); !ok)
    return description ? Fail(fmt::format("{}: {}", path.string(), ok.error().message)) : ok.error();
  const double readSeconds = SecondsSince(readStart);
  Logger("scene")->info("read {}: {} triangles in {:.2f} s ({})", meshPath.string(), builder.TriangleCount(),
                        readSeconds, Rate(builder.TriangleCount(), readSeconds));
  if (description) {
    for (const ObjectDescription& o : description->objects) {
      if (o.meshPath.empty()) continue;
      MovableObject object;
      object.name = o.name;
      object.objectToWorld = o.placement;
      object.animation = o.animation;
      builder.BeginObject(std::move(object));
      auto ok = ImportMesh(o.meshPath, builder);
      builder.EndObject();
      if (!ok) return Fail(fmt::format("{}: objects.{}: {}", path.string(), o.name, ok.error().message));
    }
    if (auto ok = AddInstances(*description, creaseAngleDeg, builder); !ok) return ok.error();
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
  const auto buildStart = std::chrono::steady_clock::now();
  if (auto ok = builder.BuildInto(scene); !ok) {
    // Some of the builder's messages (an object left without triangles)
    // do not name the file.
    const std::string& message = ok.error().message;
    return message.find(path.string()) == std::string::npos ? Fail(fmt::format("{}: {}", path.string(), message))
                                                            : ok.error();
  }
  const double buildSeconds = SecondsSince(buildStart);
  Logger("scene")->info("built {} triangles and {} vertices (welded, split at creases; {} instances copied) in {:.2f} "
                        "s ({})",
                        scene.triangles.size(), scene.vertices.size(), scene.instances.size(), buildSeconds,
                        Rate(scene.triangles.size(), buildSeconds));
  if (scene.cameras.empty()) {
    // The first preset is where a client starts.
    if (auto inside = InsideCamera(scene)) scene.cameras.push_back(*inside);
    scene.cameras.push_back(FramingCamera(scene.bounds));
  }
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
  if (!scene->HasLight())
    Logger("scene")->warn("'{}' has no light (no emissive material, sun or sky): it will render black; give it one "
                          "in a scene file (.json: \"sun\", \"sky\", \"quad_lights\" or a material with \"emission\")",
                          scene->name);

  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  Logger("scene")->info(
      "loaded '{}' from {}: {} triangles ({} degenerate and {} duplicate dropped), {} vertices after crease splitting, "
      "{} materials, {} textures, {} emissive triangles{}{}, {} movable objects, {} instances in {:.2f} s ({})",
      scene->name, path.string(), scene->triangles.size(), degenerateTriangles, duplicateTriangles,
      scene->vertices.size(),
      scene->materials.size(), scene->textures.size(), scene->emissiveTriangles.size(), scene->sun ? ", sun" : "",
      scene->sky ? ", sky" : "", scene->objects.size(), scene->instances.size(), seconds,
      Rate(scene->triangles.size(), seconds));
  const ScenePose initial = ScenePose::Initial(*scene);
  for (uint32_t i = 0; i < scene->objects.size(); ++i) {
    const MovableObject& o = scene->objects[i];
    const Bounds3 world = WorldBounds(*scene, initial, i);
    Logger("scene")->info(
        "movable object {} '{}': {} triangles, {} vertices, world bounds ({:.3g}, {:.3g}, {:.3g})..({:.3g}, {:.3g}, "
        "{:.3g}), placed at {}{}",
        i + 1, o.name, o.triangleCount, o.vertexCount, world.min.x, world.min.y, world.min.z, world.max.x,
        world.max.y, world.max.z, Describe(o.objectToWorld),
        o.animation ? fmt::format(", animated: {} keyframes over {:.3g} s, {}", o.animation->keys.size(),
                                  o.animation->DurationS(), o.animation->loop ? "looped" : "once")
                    : std::string());
  }
  return scene;
}

}  // namespace penumbra

// penumbra-scene-info: load a scene (.json) or mesh file and print a summary,
// or the error and exit code 1.

#include <chrono>
#include <cmath>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "penumbra/common/logging.h"
#include "penumbra/common/scene.h"

namespace {

using namespace penumbra;

std::string Format(const Vec3& v) { return fmt::format("({:.4g}, {:.4g}, {:.4g})", v.x, v.y, v.z); }

float Degrees(float radians) { return radians * 180.0f / kPi; }

void PrintSun(const SunLight& sun) {
  const Vec3& d = sun.directionToSun;
  // Elevation and azimuth in the +Y-up convention of docs/scenes.md.
  fmt::print("sun         toward {} (elevation {:.1f} deg, azimuth {:.1f} deg), diameter {:.3g} deg\n", Format(d),
             Degrees(std::asin(std::clamp(d.y, -1.0f, 1.0f))), Degrees(std::atan2(d.x, d.z)),
             Degrees(sun.angularDiameterRad));
  fmt::print("            radiance {}, irradiance at normal incidence {}\n", Format(sun.radiance),
             Format(sun.NormalIrradiance()));
}

void PrintMaterials(const Scene& scene) {
  std::vector<size_t> triangles(scene.materials.size(), 0);
  for (const Triangle& t : scene.triangles) ++triangles[t.material];
  for (size_t i = 0; i < scene.materials.size(); ++i) {
    const Material& m = scene.materials[i];
    std::string texture = m.albedoTexture >= 0 ? fmt::format(" x texture {}", scene.textures[size_t(m.albedoTexture)].path) : "";
    std::string emission = m.IsEmissive() ? fmt::format(", emission {}", Format(m.emission)) : "";
    fmt::print("  {:<24} {:>8} triangles, albedo {}{}{}\n", m.name, triangles[i], Format(m.albedo), texture, emission);
  }
}

void PrintSummary(const Scene& scene, double loadSeconds, bool listMaterials) {
  fmt::print("scene       {} ({})\n", scene.name, scene.sourcePath.string());
  fmt::print("identity    {:016x}\n", scene.identity);
  fmt::print("triangles   {}\n", scene.triangles.size());
  fmt::print("vertices    {} (after crease splitting)\n", scene.vertices.size());
  fmt::print("materials   {}\n", scene.materials.size());
  if (listMaterials) PrintMaterials(scene);
  fmt::print("textures    {}\n", scene.textures.size());
  fmt::print("bounds      min {} max {} size {}\n", Format(scene.bounds.min), Format(scene.bounds.max),
             Format(scene.bounds.Diagonal()));

  float emissiveArea = 0.0f;
  Rgb emittedPower(0.0f);  // a Lambertian emitter sends pi * L * A
  for (uint32_t t : scene.emissiveTriangles) {
    emissiveArea += scene.Area(t);
    emittedPower += kPi * scene.Area(t) * scene.MaterialOf(t).emission;
  }
  fmt::print("area lights {} emissive triangles, area {:.4g}, power {}\n", scene.emissiveTriangles.size(),
             emissiveArea, Format(emittedPower));
  if (scene.sun) PrintSun(*scene.sun);
  if (scene.sky)
    fmt::print("sky         zenith {}, horizon {}, ground {}, up {}\n", Format(scene.sky->zenith),
               Format(scene.sky->horizon), Format(scene.sky->ground), Format(scene.sky->up));
  for (const CameraPreset& c : scene.cameras)
    fmt::print("camera      {}: eye {} target {} up {} fov_y {:.1f} deg\n", c.name, Format(c.pose.eye),
               Format(c.pose.target), Format(c.pose.up), c.fovYDeg);
  for (const CameraPath& p : scene.paths)
    fmt::print("path        {}: {} keyframes, {:.1f} s, {}x{}, fov_y {:.1f} deg\n", p.name, p.keyframes.size(),
               p.DurationSeconds(), p.width, p.height, p.fovYDeg);
  const ScenePose initial = ScenePose::Initial(scene);
  for (uint32_t i = 0; i < scene.objects.size(); ++i) {
    const MovableObject& o = scene.objects[i];
    const Bounds3 world = WorldBounds(scene, initial, i);
    fmt::print("object      {} '{}': {} triangles, {} vertices, world bounds min {} max {}\n", i + 1, o.name,
               o.triangleCount, o.vertexCount, Format(world.min), Format(world.max));
    fmt::print("            placed at {}{}\n", Describe(o.objectToWorld),
               o.animation ? fmt::format("; animated: {} keyframes over {:.3g} s, {}", o.animation->keys.size(),
                                         o.animation->DurationS(), o.animation->loop ? "looped" : "once")
                           : std::string("; still"));
  }
  fmt::print("load time   {:.2f} s\n", loadSeconds);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "Loads a Penumbra scene file (.json, see docs/scenes.md) or a mesh file (.obj, .gltf, .glb, ...) and "
      "prints what it holds: counts, bounds, identity hash, lights, cameras, camera paths and movable objects. "
      "On any problem it prints the error and exits with code 1, so it also validates scene files.",
      "penumbra-scene-info"};
  std::string scenePath;
  float creaseAngleDeg = kDefaultCreaseAngleDeg;
  bool listMaterials = false;
  std::string logLevel = "warn";
  app.add_option("--scene", scenePath, "Scene (.json) or mesh file to load")->required();
  app.add_option("--crease-angle", creaseAngleDeg,
                 "Angle between face normals (degrees) above which a vertex is split; a scene file's "
                 "crease_angle_deg takes precedence")
      ->capture_default_str()
      ->check(CLI::Range(0.0f, 180.0f));
  app.add_flag("--materials", listMaterials, "List every material with its triangle count, albedo and emission");
  app.add_option("--log-level", logLevel, "trace, debug, info, warn, error or off")->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  if (!SetupLogging(logLevel)) {
    fmt::print(stderr, "error: unknown log level '{}'\n", logLevel);
    return 2;
  }

  SceneLoadOptions options;
  options.creaseAngleDeg = creaseAngleDeg;
  const auto start = std::chrono::steady_clock::now();
  auto scene = LoadScene(scenePath, options);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (!scene) {
    fmt::print(stderr, "error: {}\n", scene.error().message);
    return 1;
  }
  PrintSummary(*scene, seconds, listMaterials);
  return 0;
}

// Issue 15: what sharing one BVH among the copies of a mesh (Embree
// instances, EmbreeScene) saves and costs against one flat BVH over every
// triangle. One variant per process (--flat or not), so that the resident
// memory each adds is measured from the same starting point:
//
//   instancing_bench [--scene scenes/street.json] [--flat] [--robust]
//
// Loads the scene, then reports: the BVH build time; VmRSS before and after
// the build (the difference is the BVH, Embree's copy of the positions and
// indices, and the top level); and primary-ray throughput (rtcIntersect1, one
// thread, coherent rows of pixels) at every keyframe of the scene's first
// camera path, 320x240 each. bench/large_scene.sh runs both variants and
// prints their ratios. --flat clears Scene::instances, which makes the copies
// ordinary static triangles: the single-BVH path every scene without
// instances takes.

#include <embree3/rtcore.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <string>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "penumbra/common/embree_scene.h"
#include "penumbra/common/logging.h"
#include "penumbra/common/scene.h"

namespace {

using namespace penumbra;

long StatusKb(const char* field) {
  std::ifstream in("/proc/self/status");
  std::string line;
  const std::string key = std::string(field) + ":";
  while (std::getline(in, line))
    if (line.rfind(key, 0) == 0) return std::stol(line.substr(key.size()));
  return -1;
}

// Primary rays of `view` through pixel centres, traced one by one; returns
// how many hit.
size_t TraceView(const PosedEmbreeScene& posed, const CameraView& view, uint64_t& checksum) {
  const Vec3 forward = glm::normalize(view.pose.target - view.pose.eye);
  const Vec3 right = glm::normalize(glm::cross(forward, view.pose.up));
  const Vec3 up = glm::cross(right, forward);
  const float tanHalf = std::tan(0.5f * view.fovYDeg * kPi / 180.0f);
  const float aspect = float(view.width) / float(view.height);
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  size_t hits = 0;
  for (int y = 0; y < view.height; ++y)
    for (int x = 0; x < view.width; ++x) {
      const float sx = (2.0f * (x + 0.5f) / view.width - 1.0f) * tanHalf * aspect;
      const float sy = (1.0f - 2.0f * (y + 0.5f) / view.height) * tanHalf;
      const Vec3 d = glm::normalize(forward + sx * right + sy * up);
      RTCRayHit rh{};
      rh.ray.org_x = view.pose.eye.x;
      rh.ray.org_y = view.pose.eye.y;
      rh.ray.org_z = view.pose.eye.z;
      rh.ray.dir_x = d.x;
      rh.ray.dir_y = d.y;
      rh.ray.dir_z = d.z;
      rh.ray.tfar = std::numeric_limits<float>::infinity();
      rh.ray.mask = ~0u;
      rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
      rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
      rtcIntersect1(posed.Handle(), &context, &rh);
      if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) continue;
      ++hits;
      // The base triangle each variant names: equal in both (printed).
      checksum += posed.Triangle(rh.hit.instID[0], rh.hit.primID);
    }
  return hits;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Shared BVHs for static instances against one flat BVH (issue 15)"};
  std::filesystem::path scenePath = std::filesystem::path(PENUMBRA_SOURCE_DIR) / "scenes" / "street.json";
  bool flat = false, robust = false;
  app.add_option("--scene", scenePath, "Scene file")->capture_default_str();
  app.add_flag("--flat", flat, "Clear Scene::instances: one BVH over every triangle");
  app.add_flag("--robust", robust, "RTC_SCENE_FLAG_ROBUST, as the renderer builds (the SMA does not)");
  CLI11_PARSE(app, argc, argv);
  SetupLogging("warn");

  auto scene = LoadScene(scenePath);
  if (!scene) {
    std::fprintf(stderr, "instancing_bench: %s\n", scene.error().message.c_str());
    return 1;
  }
  const size_t copies = scene->instances.size();
  if (flat) {
    scene->instances.clear();
    if (auto ok = scene->Finalize(); !ok) {
      std::fprintf(stderr, "instancing_bench: %s\n", ok.error().message.c_str());
      return 1;
    }
  }
  if (scene->paths.empty()) {
    std::fprintf(stderr, "instancing_bench: %s has no camera path\n", scenePath.c_str());
    return 1;
  }
  const long rssBefore = StatusKb("VmRSS");
  const auto buildStart = std::chrono::steady_clock::now();
  auto embree = EmbreeScene::Build(*scene, EmbreeSceneOptions{.logger = "bench.embree", .robust = robust});
  const double buildSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - buildStart).count();
  if (!embree) {
    std::fprintf(stderr, "instancing_bench: %s\n", embree.error().message.c_str());
    return 1;
  }
  const long rssAfter = StatusKb("VmRSS");

  const CameraPath& path = scene->paths.front();
  size_t rays = 0, hits = 0;
  uint64_t checksum = 0;
  const auto traceStart = std::chrono::steady_clock::now();
  for (const CameraKeyframe& key : path.keyframes) {
    CameraView view = path.ViewAt(key.timeSeconds);
    view.width = 320;
    view.height = 240;
    hits += TraceView(*(*embree)->Initial(), view, checksum);
    rays += size_t(view.width) * size_t(view.height);
  }
  const double traceSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - traceStart).count();
  std::printf("variant\t%s\n", flat ? "flat" : "instanced");
  std::printf("triangles\t%zu\n", scene->triangles.size());
  std::printf("instances\t%zu\n", flat ? size_t(0) : copies);
  std::printf("build_s\t%.3f\n", buildSeconds);
  std::printf("bvh_rss_mb\t%.1f\n", double(rssAfter - rssBefore) / 1024.0);
  std::printf("rays\t%zu\n", rays);
  std::printf("hits\t%zu\n", hits);
  std::printf("triangle_checksum\t%llu\n", static_cast<unsigned long long>(checksum));
  std::printf("mrays_per_s\t%.3f\n", double(rays) / traceSeconds * 1e-6);
  return 0;
}

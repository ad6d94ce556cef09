#include "penumbra/common/embree_scene.h"

#include <embree3/rtcore.h>
#include <fmt/format.h>

#include <chrono>
#include <cstring>

#include "penumbra/common/logging.h"

namespace penumbra {

namespace {

const char* ErrorName(RTCError code) {
  switch (code) {
    case RTC_ERROR_NONE: return "no error";
    case RTC_ERROR_UNKNOWN: return "unknown error";
    case RTC_ERROR_INVALID_ARGUMENT: return "invalid argument";
    case RTC_ERROR_INVALID_OPERATION: return "invalid operation";
    case RTC_ERROR_OUT_OF_MEMORY: return "out of memory";
    case RTC_ERROR_UNSUPPORTED_CPU: return "unsupported CPU";
    case RTC_ERROR_CANCELLED: return "cancelled";
  }
  return "unrecognised error";
}

// Every device error reaches the scene's logger (its name is the user
// pointer); Build() additionally turns a failed step into an Error value.
void LogDeviceError(void* loggerName, RTCError code, const char* message) {
  Logger(*static_cast<const std::string*>(loggerName))->error("Embree: {}: {}", ErrorName(code), message ? message : "");
}

}  // namespace

Expected<std::unique_ptr<EmbreeScene>> EmbreeScene::Build(const Scene& scene, const EmbreeSceneOptions& options) {
  if (scene.triangles.empty()) return Fail("Embree: the scene has no triangles");
  std::unique_ptr<EmbreeScene> out(new EmbreeScene());
  out->logger_ = options.logger;
  out->device_ = rtcNewDevice(nullptr);
  if (!out->device_)
    return Fail(fmt::format("Embree: cannot create a device: {}", ErrorName(rtcGetDeviceError(nullptr))));
  rtcSetDeviceErrorFunction(out->device_, LogDeviceError, &out->logger_);
  auto check = [&](const char* step) -> Status {
    const RTCError code = rtcGetDeviceError(out->device_);
    if (code == RTC_ERROR_NONE) return Status::Ok();
    return Fail(fmt::format("Embree: {} failed: {}", step, ErrorName(code)));
  };

  out->scene_ = rtcNewScene(out->device_);
  if (auto ok = check("creating the scene"); !ok) return ok.error();
  if (options.robust) rtcSetSceneFlags(out->scene_, RTC_SCENE_FLAG_ROBUST);
  // Built once, traced for every sample or every view.
  rtcSetSceneBuildQuality(out->scene_, RTC_BUILD_QUALITY_HIGH);

  RTCGeometry geometry = rtcNewGeometry(out->device_, RTC_GEOMETRY_TYPE_TRIANGLE);
  if (auto ok = check("creating the triangle geometry"); !ok) return ok.error();
  rtcSetGeometryBuildQuality(geometry, RTC_BUILD_QUALITY_HIGH);
  auto* positions = static_cast<float*>(rtcSetNewGeometryBuffer(
      geometry, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), scene.vertices.size()));
  auto* indices = static_cast<uint32_t*>(rtcSetNewGeometryBuffer(
      geometry, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(uint32_t), scene.triangles.size()));
  if (!positions || !indices) {
    rtcReleaseGeometry(geometry);
    auto ok = check("allocating vertex and index buffers");
    return ok ? Fail("Embree: no vertex or index buffer") : ok.error();
  }
  for (size_t i = 0; i < scene.vertices.size(); ++i) {
    const Vec3& p = scene.vertices[i].position;
    positions[3 * i + 0] = p.x;
    positions[3 * i + 1] = p.y;
    positions[3 * i + 2] = p.z;
  }
  // Primitive id == base triangle index: hits name Scene::triangles directly.
  for (size_t t = 0; t < scene.triangles.size(); ++t)
    std::memcpy(indices + 3 * t, scene.triangles[t].v.data(), 3 * sizeof(uint32_t));
  rtcCommitGeometry(geometry);
  rtcAttachGeometryByID(out->scene_, geometry, kGeometryId);
  rtcReleaseGeometry(geometry);  // the scene holds it now
  if (auto ok = check("attaching the triangles"); !ok) return ok.error();

  Logger(options.logger)->info("building the ray-tracing BVH over {} triangles", scene.triangles.size());
  const auto buildStart = std::chrono::steady_clock::now();
  rtcCommitScene(out->scene_);
  if (auto ok = check("building the BVH"); !ok) return ok.error();
  Logger(options.logger)
      ->info("BVH over {} triangles ({} vertices) built in {:.2f} s", scene.triangles.size(), scene.vertices.size(),
             std::chrono::duration<double>(std::chrono::steady_clock::now() - buildStart).count());
  return out;
}

EmbreeScene::~EmbreeScene() {
  if (scene_) rtcReleaseScene(scene_);
  if (device_) rtcReleaseDevice(device_);
}

}  // namespace penumbra

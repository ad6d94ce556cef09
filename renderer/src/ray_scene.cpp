// The renderer's one contact with Embree: one device, one committed scene of
// all base triangles (geometry 0, primitive id = triangle index), queried
// with single rays.
//
// Single-ray queries (rtcIntersect1/rtcOccluded1) rather than packets or
// streams: the shader's rays are incoherent (cosine bounces, shadow rays to
// random light points), where Embree's packet and stream paths gain little,
// and one ray at a time keeps each path a plain loop with no batching state.

#include "penumbra/renderer/ray_scene.h"

#include <embree3/rtcore.h>
#include <fmt/format.h>
#include <pmmintrin.h>
#include <xmmintrin.h>

#include <cstring>

#include "penumbra/common/logging.h"

namespace penumbra {

namespace {

constexpr unsigned kGeometryId = 0;

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

// Every device error reaches this one logger; Build() additionally turns a
// failed step into an Error value for its caller.
void LogDeviceError(void* /*userPtr*/, RTCError code, const char* message) {
  Logger("renderer.embree")->error("{}: {}", ErrorName(code), message ? message : "");
}

RTCRay MakeRay(const Vec3& origin, const Vec3& direction, float tMin, float tMax) {
  RTCRay ray;
  ray.org_x = origin.x;
  ray.org_y = origin.y;
  ray.org_z = origin.z;
  ray.tnear = tMin;
  ray.dir_x = direction.x;
  ray.dir_y = direction.y;
  ray.dir_z = direction.z;
  ray.time = 0.0f;
  ray.tfar = tMax;
  ray.mask = ~0u;
  ray.id = 0;
  ray.flags = 0;
  return ray;
}

RTCRayHit MakeRayHit(const Vec3& origin, const Vec3& direction, float tMin, float tMax) {
  RTCRayHit rayHit;
  rayHit.ray = MakeRay(origin, direction, tMin, tMax);
  rayHit.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rayHit.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  return rayHit;
}

}  // namespace

struct RayScene::Impl {
  RTCDevice device = nullptr;
  RTCScene scene = nullptr;

  Impl() = default;
  Impl(const Impl&) = delete;
  Impl& operator=(const Impl&) = delete;
  ~Impl() {
    if (scene) rtcReleaseScene(scene);
    if (device) rtcReleaseDevice(device);
  }

  // The error left by the last device call, if any, as an Error naming `step`.
  std::optional<Error> Check(const char* step) const {
    const RTCError code = rtcGetDeviceError(device);
    if (code == RTC_ERROR_NONE) return std::nullopt;
    return Fail(fmt::format("Embree: {} failed: {}", step, ErrorName(code)));
  }
};

Expected<std::unique_ptr<RayScene>> RayScene::Build(const Scene& scene) {
  auto impl = std::make_unique<Impl>();
  impl->device = rtcNewDevice(nullptr);
  if (!impl->device)
    return Fail(fmt::format("Embree: cannot create a device: {}", ErrorName(rtcGetDeviceError(nullptr))));
  rtcSetDeviceErrorFunction(impl->device, LogDeviceError, nullptr);

  impl->scene = rtcNewScene(impl->device);
  if (auto error = impl->Check("creating the scene")) return *error;
  // Robust mode: conservative traversal and watertight-leaning arithmetic,
  // so that shadow rays do not leak through the shared edges of closed
  // meshes. It costs some speed; the benchmark measures against the same
  // scene, so its ratios are unaffected.
  rtcSetSceneFlags(impl->scene, RTC_SCENE_FLAG_ROBUST);
  // The scene is built once and traced billions of times.
  rtcSetSceneBuildQuality(impl->scene, RTC_BUILD_QUALITY_HIGH);

  RTCGeometry geometry = rtcNewGeometry(impl->device, RTC_GEOMETRY_TYPE_TRIANGLE);
  if (auto error = impl->Check("creating the triangle geometry")) return *error;
  auto* positions = static_cast<float*>(rtcSetNewGeometryBuffer(
      geometry, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), scene.vertices.size()));
  auto* indices = static_cast<uint32_t*>(rtcSetNewGeometryBuffer(
      geometry, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(uint32_t), scene.triangles.size()));
  if (!positions || !indices) {
    rtcReleaseGeometry(geometry);
    return impl->Check("allocating vertex and index buffers").value_or(Fail("Embree: no buffers"));
  }
  for (size_t i = 0; i < scene.vertices.size(); ++i) {
    const Vec3& p = scene.vertices[i].position;
    positions[3 * i + 0] = p.x;
    positions[3 * i + 1] = p.y;
    positions[3 * i + 2] = p.z;
  }
  for (size_t t = 0; t < scene.triangles.size(); ++t)
    std::memcpy(indices + 3 * t, scene.triangles[t].v.data(), 3 * sizeof(uint32_t));
  rtcCommitGeometry(geometry);
  rtcAttachGeometryByID(impl->scene, geometry, kGeometryId);
  rtcReleaseGeometry(geometry);  // the scene holds it now
  if (auto error = impl->Check("attaching the triangles")) return *error;

  rtcCommitScene(impl->scene);
  if (auto error = impl->Check("building the BVH")) return *error;
  Logger("renderer.embree")
      ->debug("BVH over {} triangles ({} vertices) built", scene.triangles.size(), scene.vertices.size());
  return std::unique_ptr<RayScene>(new RayScene(std::move(impl)));
}

RayScene::RayScene(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
RayScene::~RayScene() = default;

std::optional<RayHit> RayScene::Intersect(const Vec3& origin, const Vec3& direction, float tMin,
                                          float tMax) const {
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  RTCRayHit rayHit = MakeRayHit(origin, direction, tMin, tMax);
  rtcIntersect1(impl_->scene, &context, &rayHit);
  if (rayHit.hit.geomID == RTC_INVALID_GEOMETRY_ID) return std::nullopt;
  return RayHit{rayHit.hit.primID, rayHit.ray.tfar, rayHit.hit.u, rayHit.hit.v,
                Vec3(rayHit.hit.Ng_x, rayHit.hit.Ng_y, rayHit.hit.Ng_z)};
}

bool RayScene::Occluded(const Vec3& origin, const Vec3& direction, float tMin, float tMax) const {
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  RTCRay ray = MakeRay(origin, direction, tMin, tMax);
  rtcOccluded1(impl_->scene, &context, &ray);
  // Embree marks an occluded ray by setting tfar to -infinity.
  return ray.tfar < 0.0f;
}

size_t RayScene::TraceRaw(std::span<const Ray> rays, RayQuery query) const {
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  size_t hits = 0;
  if (query == RayQuery::kClosestHit) {
    for (const Ray& r : rays) {
      RTCRayHit rayHit = MakeRayHit(r.origin, r.direction, 0.0f, r.tMax);
      rtcIntersect1(impl_->scene, &context, &rayHit);
      hits += rayHit.hit.geomID != RTC_INVALID_GEOMETRY_ID;
    }
  } else {
    for (const Ray& r : rays) {
      RTCRay ray = MakeRay(r.origin, r.direction, 0.0f, r.tMax);
      rtcOccluded1(impl_->scene, &context, &ray);
      hits += ray.tfar < 0.0f;
    }
  }
  return hits;
}

void EnableFlushToZero() {
  _MM_SET_FLUSH_ZERO_MODE(_MM_FLUSH_ZERO_ON);
  _MM_SET_DENORMALS_ZERO_MODE(_MM_DENORMALS_ZERO_ON);
}

}  // namespace penumbra

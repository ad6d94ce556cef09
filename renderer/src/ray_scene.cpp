// The renderer's one contact with Embree's queries: the scene of all base
// triangles (EmbreeScene: geometry 0, primitive id = triangle index; with
// movable objects, a top level of instances per pose), queried with single
// rays.
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

#include "penumbra/common/embree_scene.h"

namespace penumbra {

namespace {

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
  std::unique_ptr<EmbreeScene> embree;
  std::shared_ptr<const PosedRayScene> initial;
  size_t objectCount = 0;
};

Expected<std::unique_ptr<RayScene>> RayScene::Build(const Scene& scene) {
  // Robust mode: conservative traversal and watertight-leaning arithmetic,
  // so that shadow rays do not leak through the shared edges of closed
  // meshes. It costs some speed; the benchmark measures against the same
  // scene, so its ratios are unaffected.
  auto embree = EmbreeScene::Build(scene, EmbreeSceneOptions{.logger = "renderer.embree", .robust = true});
  if (!embree) return embree.error();
  auto impl = std::make_unique<Impl>();
  impl->embree = std::move(*embree);
  impl->objectCount = scene.objects.size();
  impl->initial =
      std::shared_ptr<const PosedRayScene>(new PosedRayScene(impl->embree->Initial(), ScenePose::Initial(scene)));
  return std::unique_ptr<RayScene>(new RayScene(std::move(impl)));
}

RayScene::RayScene(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
RayScene::~RayScene() = default;

const std::shared_ptr<const PosedRayScene>& RayScene::Initial() const { return impl_->initial; }

size_t RayScene::MovableObjectCount() const { return impl_->objectCount; }

Expected<std::shared_ptr<const PosedRayScene>> RayScene::AtPose(const ScenePose& pose) const {
  if (!impl_->embree->HasMovableObjects()) {
    if (!pose.objectToWorld.empty())
      return Fail(fmt::format("a pose of {} objects for a scene without movable objects", pose.objectToWorld.size()));
    if (pose.epoch == impl_->initial->Pose().epoch) return impl_->initial;
    // Same BVH; only the epoch the caller reads back differs.
    return std::shared_ptr<const PosedRayScene>(new PosedRayScene(impl_->embree->Initial(), pose));
  }
  auto embree = impl_->embree->AtPose(pose);
  if (!embree) return embree.error();
  return std::shared_ptr<const PosedRayScene>(new PosedRayScene(std::move(*embree), pose));
}

std::optional<RayHit> RayScene::Intersect(const Vec3& origin, const Vec3& direction, float tMin, float tMax) const {
  return impl_->initial->Intersect(origin, direction, tMin, tMax);
}

bool RayScene::Occluded(const Vec3& origin, const Vec3& direction, float tMin, float tMax) const {
  return impl_->initial->Occluded(origin, direction, tMin, tMax);
}

size_t RayScene::TraceRaw(std::span<const Ray> rays, RayQuery query) const {
  return impl_->initial->TraceRaw(rays, query);
}

PosedRayScene::PosedRayScene(std::shared_ptr<const PosedEmbreeScene> embree, ScenePose pose)
    : embree_(std::move(embree)), pose_(std::move(pose)) {}
PosedRayScene::~PosedRayScene() = default;

std::optional<RayHit> PosedRayScene::Intersect(const Vec3& origin, const Vec3& direction, float tMin,
                                               float tMax) const {
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  RTCRayHit rayHit = MakeRayHit(origin, direction, tMin, tMax);
  rtcIntersect1(embree_->Handle(), &context, &rayHit);
  if (rayHit.hit.geomID == RTC_INVALID_GEOMETRY_ID) return std::nullopt;
  RayHit hit{rayHit.hit.primID, rayHit.ray.tfar, rayHit.hit.u, rayHit.hit.v,
             Vec3(rayHit.hit.Ng_x, rayHit.hit.Ng_y, rayHit.hit.Ng_z)};
  // Through an instance (a scene with movable objects or static instances):
  // the primitive id counts within the instanced part, and Embree 3 reports
  // Ng in that part's own space.
  if (const unsigned instance = rayHit.hit.instID[0]; instance != RTC_INVALID_GEOMETRY_ID) {
    hit.triangle = embree_->Triangle(instance, rayHit.hit.primID);
    hit.normal = embree_->WorldHitNormal(instance, hit.normal);
  }
  return hit;
}

bool PosedRayScene::Occluded(const Vec3& origin, const Vec3& direction, float tMin, float tMax) const {
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  RTCRay ray = MakeRay(origin, direction, tMin, tMax);
  rtcOccluded1(embree_->Handle(), &context, &ray);
  // Embree marks an occluded ray by setting tfar to -infinity.
  return ray.tfar < 0.0f;
}

size_t PosedRayScene::TraceRaw(std::span<const Ray> rays, RayQuery query) const {
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  const RTCScene handle = embree_->Handle();
  size_t hits = 0;
  if (query == RayQuery::kClosestHit) {
    for (const Ray& r : rays) {
      RTCRayHit rayHit = MakeRayHit(r.origin, r.direction, 0.0f, r.tMax);
      rtcIntersect1(handle, &context, &rayHit);
      hits += rayHit.hit.geomID != RTC_INVALID_GEOMETRY_ID;
    }
  } else {
    for (const Ray& r : rays) {
      RTCRay ray = MakeRay(r.origin, r.direction, 0.0f, r.tMax);
      rtcOccluded1(handle, &context, &ray);
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

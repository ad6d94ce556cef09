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

namespace {

// Commits triangles [firstTriangle, firstTriangle + count) of `scene` (their
// vertices [firstVertex, firstVertex + vertexCount), in object space) as
// geometry 0 of a new scene; primitive id = triangle - firstTriangle.
// `toObject` takes the stored positions to the space the scene is built in
// (a static instance's mesh coordinates; identity otherwise).
Expected<RTCScene> CommitTriangles(RTCDevice device, const Scene& scene, uint32_t firstTriangle, uint32_t count,
                                   uint32_t firstVertex, uint32_t vertexCount, bool robust,
                                   const RigidTransform& toObject = RigidTransform::Identity()) {
  auto check = [&](const char* step) -> Status {
    const RTCError code = rtcGetDeviceError(device);
    if (code == RTC_ERROR_NONE) return Status::Ok();
    return Fail(fmt::format("Embree: {} failed: {}", step, ErrorName(code)));
  };
  RTCScene out = rtcNewScene(device);
  if (auto ok = check("creating the scene"); !ok) return ok.error();
  if (robust) rtcSetSceneFlags(out, RTC_SCENE_FLAG_ROBUST);
  // Built once, traced for every sample or every view.
  rtcSetSceneBuildQuality(out, RTC_BUILD_QUALITY_HIGH);

  RTCGeometry geometry = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
  if (auto ok = check("creating the triangle geometry"); !ok) {
    rtcReleaseScene(out);
    return ok.error();
  }
  rtcSetGeometryBuildQuality(geometry, RTC_BUILD_QUALITY_HIGH);
  auto* positions = static_cast<float*>(rtcSetNewGeometryBuffer(geometry, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                                3 * sizeof(float), vertexCount));
  auto* indices = static_cast<uint32_t*>(
      rtcSetNewGeometryBuffer(geometry, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(uint32_t), count));
  if (!positions || !indices) {
    rtcReleaseGeometry(geometry);
    rtcReleaseScene(out);
    auto ok = check("allocating vertex and index buffers");
    return ok ? Fail("Embree: no vertex or index buffer") : ok.error();
  }
  for (uint32_t i = 0; i < vertexCount; ++i) {
    const Vec3 p = toObject.ApplyPoint(scene.vertices[firstVertex + i].position);
    positions[3 * i + 0] = p.x;
    positions[3 * i + 1] = p.y;
    positions[3 * i + 2] = p.z;
  }
  // Primitive id == base triangle index - firstTriangle: hits name
  // Scene::triangles directly (PosedEmbreeScene::Triangle adds the offset).
  for (uint32_t t = 0; t < count; ++t)
    for (int c = 0; c < 3; ++c) indices[3 * t + c] = scene.triangles[firstTriangle + t].v[c] - firstVertex;
  rtcCommitGeometry(geometry);
  rtcAttachGeometryByID(out, geometry, EmbreeScene::kGeometryId);
  rtcReleaseGeometry(geometry);  // the scene holds it now
  if (auto ok = check("attaching the triangles"); !ok) {
    rtcReleaseScene(out);
    return ok.error();
  }
  rtcCommitScene(out);
  if (auto ok = check("building the BVH"); !ok) {
    rtcReleaseScene(out);
    return ok.error();
  }
  return out;
}

}  // namespace

Expected<std::unique_ptr<EmbreeScene>> EmbreeScene::Build(const Scene& scene, const EmbreeSceneOptions& options) {
  if (scene.triangles.empty()) return Fail("Embree: the scene has no triangles");
  std::unique_ptr<EmbreeScene> out(new EmbreeScene());
  out->logger_ = options.logger;
  out->robust_ = options.robust;
  out->device_ = rtcNewDevice(nullptr);
  if (!out->device_)
    return Fail(fmt::format("Embree: cannot create a device: {}", ErrorName(rtcGetDeviceError(nullptr))));
  rtcSetDeviceErrorFunction(out->device_, LogDeviceError, &out->logger_);

  Logger(options.logger)->info("building the ray-tracing BVH over {} triangles", scene.triangles.size());
  const auto buildStart = std::chrono::steady_clock::now();
  // The static scene holds the static triangles that are no instance's.
  uint32_t staticTriangles = scene.objects.empty() ? uint32_t(scene.triangles.size()) : scene.staticTriangleCount;
  uint32_t staticVertices = scene.objects.empty() ? uint32_t(scene.vertices.size()) : scene.staticVertexCount;
  if (!scene.instances.empty()) {
    staticTriangles = scene.instances.front().firstTriangle;
    staticVertices = scene.instances.front().firstVertex;
  }
  if (staticTriangles > 0) {
    auto committed = CommitTriangles(out->device_, scene, 0, staticTriangles, 0, staticVertices, options.robust);
    if (!committed) return committed.error();
    out->staticScene_ = *committed;
  }
  out->firstTriangleOfInstance_.push_back(0);
  for (const MovableObject& o : scene.objects) {
    auto committed = CommitTriangles(out->device_, scene, o.firstTriangle, o.triangleCount, o.firstVertex,
                                     o.vertexCount, options.robust);
    if (!committed) return committed.error();
    out->objectScenes_.push_back(*committed);
    out->firstTriangleOfInstance_.push_back(o.firstTriangle);
  }
  // One bottom-level scene per instanced mesh, from its first copy brought
  // back to the mesh's own coordinates; every copy is an instance of it.
  std::vector<size_t> meshOfPrototype(scene.instances.size(), 0);
  for (size_t k = 0; k < scene.instances.size(); ++k) {
    const StaticInstance& i = scene.instances[k];
    if (i.prototype == k) {
      auto committed = CommitTriangles(out->device_, scene, i.firstTriangle, i.triangleCount, i.firstVertex,
                                       i.vertexCount, options.robust, i.meshToWorld.Inverse());
      if (!committed) return committed.error();
      meshOfPrototype[k] = out->meshScenes_.size();
      out->meshScenes_.push_back(*committed);
    }
    out->instances_.push_back(PlacedMesh{out->meshScenes_[meshOfPrototype[i.prototype]], i.meshToWorld});
    out->firstTriangleOfInstance_.push_back(i.firstTriangle);
  }
  auto initial = out->BuildPose(ScenePose::Initial(scene));
  if (!initial) return initial.error();
  out->initial_ = *initial;
  out->last_ = out->initial_;
  Logger(options.logger)
      ->info("BVH over {} triangles ({} vertices, {} movable objects, {} static instances of {} meshes sharing their "
             "BVHs: {} triangles in bottom-level BVHs) built in {:.2f} s",
             scene.triangles.size(), scene.vertices.size(), scene.objects.size(), scene.instances.size(),
             out->meshScenes_.size(), [&] {
               size_t inBvhs = staticTriangles;
               for (const MovableObject& o : scene.objects) inBvhs += o.triangleCount;
               for (size_t k = 0; k < scene.instances.size(); ++k)
                 if (scene.instances[k].prototype == k) inBvhs += scene.instances[k].triangleCount;
               return inBvhs;
             }(),
             std::chrono::duration<double>(std::chrono::steady_clock::now() - buildStart).count());
  return out;
}

Expected<std::shared_ptr<const PosedEmbreeScene>> EmbreeScene::BuildPose(const ScenePose& pose) const {
  std::shared_ptr<PosedEmbreeScene> posed(new PosedEmbreeScene());
  posed->pose_ = pose;
  if (objectScenes_.empty() && instances_.empty()) {
    posed->top_ = staticScene_;  // owned by this EmbreeScene
    return std::shared_ptr<const PosedEmbreeScene>(std::move(posed));
  }
  if (pose.objectToWorld.size() != objectScenes_.size())
    return Fail(fmt::format("Embree: a pose of {} objects for a scene of {}", pose.objectToWorld.size(),
                            objectScenes_.size()));
  posed->instanced_ = true;
  posed->firstTriangleOfInstance_ = firstTriangleOfInstance_;
  posed->objectCount_ = unsigned(objectScenes_.size());
  posed->instanceToWorld_.reserve(firstTriangleOfInstance_.size());
  posed->instanceToWorld_.push_back(RigidTransform::Identity());
  for (const RigidTransform& t : pose.objectToWorld) posed->instanceToWorld_.push_back(t);
  for (const PlacedMesh& m : instances_) posed->instanceToWorld_.push_back(m.meshToWorld);
  posed->top_ = rtcNewScene(device_);
  posed->ownsTop_ = true;
  if (robust_) rtcSetSceneFlags(posed->top_, RTC_SCENE_FLAG_ROBUST);
  auto attach = [&](RTCScene instanced, const RigidTransform& objectToWorld, unsigned id) {
    RTCGeometry instance = rtcNewGeometry(device_, RTC_GEOMETRY_TYPE_INSTANCE);
    rtcSetGeometryInstancedScene(instance, instanced);
    float m[12];  // RTC_FORMAT_FLOAT3X4_COLUMN_MAJOR: 3 rows per column, 4 columns
    for (int c = 0; c < 3; ++c)
      for (int r = 0; r < 3; ++r) m[3 * c + r] = objectToWorld.rotation[c][r];
    for (int r = 0; r < 3; ++r) m[9 + r] = objectToWorld.translation[r];
    rtcSetGeometryTransform(instance, 0, RTC_FORMAT_FLOAT3X4_COLUMN_MAJOR, m);
    rtcCommitGeometry(instance);
    rtcAttachGeometryByID(posed->top_, instance, id);
    rtcReleaseGeometry(instance);
  };
  if (staticScene_) attach(staticScene_, RigidTransform::Identity(), 0);
  for (size_t i = 0; i < objectScenes_.size(); ++i) attach(objectScenes_[i], pose.objectToWorld[i], unsigned(i + 1));
  const unsigned firstStaticInstanceId = unsigned(1 + objectScenes_.size());
  for (size_t k = 0; k < instances_.size(); ++k)
    attach(instances_[k].mesh, instances_[k].meshToWorld, unsigned(firstStaticInstanceId + k));
  rtcCommitScene(posed->top_);
  if (const RTCError code = rtcGetDeviceError(device_); code != RTC_ERROR_NONE)
    return Fail(fmt::format("Embree: building the instances of a pose failed: {}", ErrorName(code)));
  return std::shared_ptr<const PosedEmbreeScene>(std::move(posed));
}

Expected<std::shared_ptr<const PosedEmbreeScene>> EmbreeScene::AtPose(const ScenePose& pose) const {
  if (objectScenes_.empty()) return initial_;
  {
    std::lock_guard lock(poseMutex_);
    if (last_ && last_->Pose().SamePlaces(pose)) return last_;
  }
  auto built = BuildPose(pose);
  if (!built) return built.error();
  std::lock_guard lock(poseMutex_);
  last_ = *built;
  return *built;
}

PosedEmbreeScene::~PosedEmbreeScene() {
  if (ownsTop_ && top_) rtcReleaseScene(top_);
}

EmbreeScene::~EmbreeScene() {
  initial_.reset();
  last_.reset();
  for (RTCScene s : objectScenes_) rtcReleaseScene(s);
  for (RTCScene s : meshScenes_) rtcReleaseScene(s);
  if (staticScene_) rtcReleaseScene(staticScene_);
  if (device_) rtcReleaseDevice(device_);
}

}  // namespace penumbra

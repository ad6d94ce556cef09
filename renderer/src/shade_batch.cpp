#include "penumbra/renderer/shade_batch.h"

#include <fmt/format.h>

#include <span>

namespace penumbra {

Expected<ScenePose> DecodeShadePose(const wire::ShadeRequest& request, const Scene& scene) {
  const uint64_t id = request.batch_id();
  const size_t objects = scene.objects.size();
  const size_t values = size_t(request.object_transforms_size());
  ScenePose pose;
  pose.epoch = request.scene_epoch();
  if (values == 0) {
    if (objects > 0 && pose.epoch != 0)
      return Fail(fmt::format("batch {}: scene_epoch {} without object_transforms (the initial pose is epoch 0 only; "
                              "a later epoch sends 12 values per movable object)",
                              id, pose.epoch));
    pose.objectToWorld = ScenePose::Initial(scene).objectToWorld;
    return pose;
  }
  if (values != 12 * objects)
    return Fail(fmt::format("batch {}: object_transforms has {} values, expected {} (12 per movable object for {} "
                            "objects) or none",
                            id, values, 12 * objects, objects));
  pose.objectToWorld.reserve(objects);
  const float* data = request.object_transforms().data();
  for (size_t o = 0; o < objects; ++o) {
    auto transform = RigidTransform::FromRowMajor(std::span<const float>(data + 12 * o, 12));
    if (!transform)
      return Fail(fmt::format("batch {}: object_transforms of object {} ('{}'): {}", id, o + 1,
                              scene.objects[o].name, transform.error().message));
    pose.objectToWorld.push_back(*transform);
  }
  return pose;
}

Expected<std::vector<ShadeInput>> DecodeShadeRequest(const wire::ShadeRequest& request, const Scene& scene,
                                                     const ShadeLimits& limits) {
  auto pose = DecodeShadePose(request, scene);
  if (!pose) return pose.error();
  return DecodeShadeRequest(request, scene, *pose, limits);
}

Expected<std::vector<ShadeInput>> DecodeShadeRequest(const wire::ShadeRequest& request, const Scene& scene,
                                                     const ScenePose& pose, const ShadeLimits& limits) {
  const uint64_t id = request.batch_id();
  const size_t n = size_t(request.sample_ids_size());
  if (n == 0) return Fail(fmt::format("batch {}: no samples", id));
  if (n > limits.maxBatchSamples)
    return Fail(fmt::format("batch {}: {} samples exceed the limit of {}", id, n, limits.maxBatchSamples));
  auto expectSize = [&](const char* field, size_t actual, size_t perSample) -> Status {
    if (actual != n * perSample)
      return Fail(fmt::format("batch {}: {} has {} values, expected {} ({} per sample for {} samples)", id, field,
                              actual, n * perSample, perSample, n));
    return Status::Ok();
  };
  if (auto s = expectSize("positions", size_t(request.positions_size()), 3); !s) return s.error();
  if (auto s = expectSize("normals", size_t(request.normals_size()), 3); !s) return s.error();
  if (auto s = expectSize("triangle_ids", size_t(request.triangle_ids_size()), 1); !s) return s.error();
  if (auto s = expectSize("barycentrics", size_t(request.barycentrics_size()), 2); !s) return s.error();
  if (request.paths_per_sample() > limits.maxPathsPerSample)
    return Fail(fmt::format("batch {}: paths_per_sample {} exceeds the limit of {}", id, request.paths_per_sample(),
                            limits.maxPathsPerSample));

  std::vector<ShadeInput> inputs(n);
  for (size_t i = 0; i < n; ++i) {
    ShadeInput& in = inputs[i];
    in.sampleId = request.sample_ids(int(i));
    in.position = Vec3(request.positions(int(3 * i)), request.positions(int(3 * i + 1)),
                       request.positions(int(3 * i + 2)));
    in.normal = Vec3(request.normals(int(3 * i)), request.normals(int(3 * i + 1)), request.normals(int(3 * i + 2)));
    in.triangle = request.triangle_ids(int(i));
    in.b1 = request.barycentrics(int(2 * i));
    in.b2 = request.barycentrics(int(2 * i + 1));
    if (auto valid = ValidateShadeInput(scene, pose, in); !valid)
      return Fail(fmt::format("batch {}: sample {} (id {}): {}", id, i, in.sampleId, valid.error().message));
  }
  return inputs;
}

void FillShadeReply(uint64_t batchId, std::span<const ShadeInput> inputs, std::span<const ShadeOutput> outputs,
                    uint32_t remaining, const ShadeCounters& counters, wire::ShadeReply* reply) {
  reply->set_batch_id(batchId);
  reply->set_remaining(remaining);
  reply->set_paths_traced(counters.paths);
  reply->set_rays_traced(counters.rays);
  const int n = int(inputs.size());
  reply->mutable_sample_ids()->Reserve(n);
  reply->mutable_radiance()->Reserve(3 * n);
  reply->mutable_irradiance()->Reserve(3 * n);
  reply->mutable_irradiance_stderr()->Reserve(n);
  reply->mutable_sample_paths()->Reserve(n);
  for (int i = 0; i < n; ++i) {
    reply->add_sample_ids(inputs[size_t(i)].sampleId);
    const ShadeOutput& out = outputs[size_t(i)];
    for (int c = 0; c < 3; ++c) reply->add_radiance(out.radiance[c]);
    for (int c = 0; c < 3; ++c) reply->add_irradiance(out.irradiance[c]);
    reply->add_irradiance_stderr(out.irradianceStdErr);
    reply->add_sample_paths(out.paths);
  }
}

}  // namespace penumbra

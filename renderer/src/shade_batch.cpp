#include "penumbra/renderer/shade_batch.h"

#include <fmt/format.h>

#include <span>

namespace penumbra {

namespace {

// A pose from its epoch and its transforms field (`epochField` and
// `transformsField` name them in messages).
Expected<ScenePose> DecodePose(uint64_t id, uint64_t epoch, std::span<const float> transforms, const Scene& scene,
                               const char* epochField, const char* transformsField) {
  const size_t objects = scene.objects.size();
  const size_t values = transforms.size();
  ScenePose pose;
  pose.epoch = epoch;
  if (values == 0) {
    if (objects > 0 && pose.epoch != 0)
      return Fail(fmt::format("batch {}: {} {} without {} (the initial pose is epoch 0 only; "
                              "a later epoch sends 12 values per movable object)",
                              id, epochField, pose.epoch, transformsField));
    pose.objectToWorld = ScenePose::Initial(scene).objectToWorld;
    return pose;
  }
  if (values != 12 * objects)
    return Fail(fmt::format("batch {}: {} has {} values, expected {} (12 per movable object for {} objects) or none",
                            id, transformsField, values, 12 * objects, objects));
  pose.objectToWorld.reserve(objects);
  for (size_t o = 0; o < objects; ++o) {
    auto transform = RigidTransform::FromRowMajor(transforms.subspan(12 * o, 12));
    if (!transform)
      return Fail(fmt::format("batch {}: {} of object {} ('{}'): {}", id, transformsField, o + 1,
                              scene.objects[o].name, transform.error().message));
    pose.objectToWorld.push_back(*transform);
  }
  return pose;
}

}  // namespace

Expected<ScenePose> DecodeShadePose(const wire::ShadeRequest& request, const Scene& scene) {
  return DecodePose(request.batch_id(), request.scene_epoch(),
                    std::span<const float>(request.object_transforms().data(), size_t(request.object_transforms_size())),
                    scene, "scene_epoch", "object_transforms");
}

Expected<VerificationRequest> DecodeVerifyChange(const wire::ShadeRequest& request, const Scene& scene,
                                                 std::span<const ShadeInput> inputs) {
  const uint64_t id = request.batch_id();
  const wire::VerifyChange& verify = request.verify_change();
  VerificationRequest out;
  auto baseline = DecodePose(
      id, verify.baseline_epoch(),
      std::span<const float>(verify.baseline_object_transforms().data(), size_t(verify.baseline_object_transforms_size())),
      scene, "verify_change.baseline_epoch", "verify_change.baseline_object_transforms");
  if (!baseline) return baseline.error();
  out.baseline = std::move(*baseline);
  const size_t values = size_t(verify.region_boxes_size());
  if (values == 0 || values % 6 != 0 || values > 6 * kMaxVerificationBoxes)
    return Fail(fmt::format("batch {}: verify_change.region_boxes has {} values, expected 6 per box for 1 to {} boxes",
                            id, values, kMaxVerificationBoxes));
  for (size_t b = 0; b < values / 6; ++b) {
    const float* v = verify.region_boxes().data() + 6 * b;
    Bounds3 box;
    box.min = Vec3(v[0], v[1], v[2]);
    box.max = Vec3(v[3], v[4], v[5]);
    if (!IsFinite(box.min) || !IsFinite(box.max))
      return Fail(fmt::format("batch {}: verify_change.region_boxes box {} is not finite", id, b));
    if (box.min.x > box.max.x || box.min.y > box.max.y || box.min.z > box.max.z)
      return Fail(fmt::format("batch {}: verify_change.region_boxes box {} has a min above its max", id, b));
    out.region.push_back(box);
  }
  for (size_t i = 0; i < inputs.size(); ++i) {
    const uint32_t object = scene.ObjectOfTriangle(inputs[i].triangle);
    if (object != kStaticObject)
      return Fail(fmt::format("batch {}: sample {} (id {}) lies on movable object '{}', which moves: only static "
                              "samples can be verified",
                              id, i, inputs[i].sampleId, scene.objects[object].name));
  }
  return out;
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

namespace {

// What every reply part carries: the batch, its progress, the work done and
// the sample ids. Returns the number of samples.
int FillReplyPart(uint64_t batchId, std::span<const ShadeInput> inputs, uint32_t remaining,
                  const ShadeCounters& counters, wire::ShadeReply* reply) {
  reply->set_batch_id(batchId);
  reply->set_remaining(remaining);
  reply->set_paths_traced(counters.paths);
  reply->set_rays_traced(counters.rays);
  const int n = int(inputs.size());
  reply->mutable_sample_ids()->Reserve(n);
  for (const ShadeInput& in : inputs) reply->add_sample_ids(in.sampleId);
  return n;
}

}  // namespace

void FillShadeReply(uint64_t batchId, std::span<const ShadeInput> inputs, std::span<const ShadeOutput> outputs,
                    uint32_t remaining, const ShadeCounters& counters, wire::ShadeReply* reply) {
  const int n = FillReplyPart(batchId, inputs, remaining, counters, reply);
  reply->mutable_radiance()->Reserve(3 * n);
  reply->mutable_irradiance()->Reserve(3 * n);
  reply->mutable_irradiance_stderr()->Reserve(n);
  reply->mutable_sample_paths()->Reserve(n);
  for (int i = 0; i < n; ++i) {
    const ShadeOutput& out = outputs[size_t(i)];
    for (int c = 0; c < 3; ++c) reply->add_radiance(out.radiance[c]);
    for (int c = 0; c < 3; ++c) reply->add_irradiance(out.irradiance[c]);
    reply->add_irradiance_stderr(out.irradianceStdErr);
    reply->add_sample_paths(out.paths);
  }
}

void FillChangeReply(uint64_t batchId, std::span<const ShadeInput> inputs, std::span<const ChangeEstimate> changes,
                     uint32_t remaining, const ShadeCounters& counters, wire::ShadeReply* reply) {
  const int n = FillReplyPart(batchId, inputs, remaining, counters, reply);
  reply->mutable_irradiance_change()->Reserve(n);
  reply->mutable_irradiance_change_stderr()->Reserve(n);
  for (int i = 0; i < n; ++i) {
    reply->add_irradiance_change(changes[size_t(i)].irradianceChange);
    reply->add_irradiance_change_stderr(changes[size_t(i)].standardError);
  }
}

}  // namespace penumbra

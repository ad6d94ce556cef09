#include "penumbra/sma/shade_codec.h"

#include <array>
#include <unordered_set>

#include <fmt/format.h>

#include "penumbra/common/messages.h"

namespace penumbra::sma {

SampleRequest MakeSampleRequest(const Hierarchy& hierarchy, VertexId v) {
  const SampleVertex& sv = hierarchy.GetVertex(v);
  return SampleRequest{v, sv.position, sv.normal, sv.baseTriangle, sv.bary, 0,
                       hierarchy.GetScene().ObjectOfTriangle(sv.baseTriangle)};
}

void FillShadeRequestPose(const ScenePose* pose, wire::ShadeRequest* request) {
  if (!pose) return;
  request->set_scene_epoch(pose->epoch);
  request->mutable_object_transforms()->Reserve(int(12 * pose->objectToWorld.size()));
  for (const RigidTransform& t : pose->objectToWorld) {
    const std::array<float, 12> m = t.ToRowMajor();
    request->mutable_object_transforms()->Add(m.begin(), m.end());
  }
}

void FillShadeRequest(uint64_t batchId, uint32_t pathsPerSample, std::span<const SampleRequest> samples,
                      wire::ShadeRequest* request, const ScenePose* pose) {
  FillShadeRequestPose(pose, request);
  request->set_batch_id(batchId);
  request->set_paths_per_sample(pathsPerSample);
  const int n = int(samples.size());
  request->mutable_sample_ids()->Reserve(n);
  request->mutable_positions()->Reserve(3 * n);
  request->mutable_normals()->Reserve(3 * n);
  request->mutable_triangle_ids()->Reserve(n);
  request->mutable_barycentrics()->Reserve(2 * n);
  for (const SampleRequest& r : samples) {
    request->add_sample_ids(WireSampleId(r.vertex, r.round));
    Vec3 position = r.position, normal = r.normal;
    if (pose && r.object != kStaticObject && r.object < pose->objectToWorld.size()) {
      const RigidTransform& t = pose->objectToWorld[r.object];
      position = t.ApplyPoint(position);
      normal = t.ApplyVector(normal);
    }
    for (int k = 0; k < 3; ++k) request->add_positions(position[k]);
    for (int k = 0; k < 3; ++k) request->add_normals(normal[k]);
    request->add_triangle_ids(r.triangle);
    request->add_barycentrics(r.bary.x);
    request->add_barycentrics(r.bary.y);
  }
}

std::shared_ptr<const std::string> EncodeShadeRequestFrame(uint64_t batchId, uint32_t pathsPerSample,
                                                           std::span<const SampleRequest> samples,
                                                           const ScenePose* pose, bool urgent, bool soon) {
  wire::Envelope envelope;
  FillShadeRequest(batchId, pathsPerSample, samples, envelope.mutable_shade_request(), pose);
  envelope.mutable_shade_request()->set_urgent(urgent);
  envelope.mutable_shade_request()->set_soon(soon);
  return std::make_shared<const std::string>(EncodeEnvelopeFrame(envelope));
}

std::optional<std::vector<Bounds3>> VerifyRegionBoxes(const Scene& scene, const ScenePose& baseline,
                                                      const ScenePose& target) {
  std::vector<Bounds3> boxes;
  // A pose that does not place every object cannot say where they are.
  if (baseline.objectToWorld.size() < scene.objects.size() || target.objectToWorld.size() < scene.objects.size())
    return std::nullopt;
  for (uint32_t o = 0; o < scene.objects.size(); ++o) {
    if (baseline.objectToWorld[o] == target.objectToWorld[o]) continue;
    // Two boxes, not their union: the estimator samples each box's
    // silhouette, and a long thin move's union would be mostly empty.
    boxes.push_back(WorldBounds(scene, baseline, o));
    boxes.push_back(WorldBounds(scene, target, o));
    if (boxes.size() > kMaxVerifyBoxes) return std::nullopt;
  }
  if (boxes.empty()) return std::nullopt;
  return boxes;
}

void FillVerifyRequest(uint64_t batchId, uint32_t pathsPerSample, std::span<const SampleRequest> samples,
                       const VerifyContext& context, wire::ShadeRequest* request) {
  FillShadeRequest(batchId, pathsPerSample, samples, request, context.target.get());
  wire::VerifyChange& verify = *request->mutable_verify_change();
  if (context.baseline) {
    verify.set_baseline_epoch(context.baseline->epoch);
    for (const RigidTransform& t : context.baseline->objectToWorld) {
      const std::array<float, 12> m = t.ToRowMajor();
      verify.mutable_baseline_object_transforms()->Add(m.begin(), m.end());
    }
  }
  for (const Bounds3& box : context.regionBoxes)
    for (float value : {box.min.x, box.min.y, box.min.z, box.max.x, box.max.y, box.max.z}) verify.add_region_boxes(value);
}

std::shared_ptr<const std::string> EncodeVerifyRequestFrame(uint64_t batchId, uint32_t pathsPerSample,
                                                            std::span<const SampleRequest> samples,
                                                            const VerifyContext& context) {
  wire::Envelope envelope;
  FillVerifyRequest(batchId, pathsPerSample, samples, context, envelope.mutable_shade_request());
  return std::make_shared<const std::string>(EncodeEnvelopeFrame(envelope));
}

Expected<std::vector<VerifiedSample>> DecodeVerifyReply(const wire::ShadeReply& reply, std::vector<uint16_t>* rounds) {
  const int n = reply.sample_ids_size();
  if (reply.irradiance_change_size() != n || reply.irradiance_change_stderr_size() != n || reply.radiance_size() != 0 ||
      reply.irradiance_size() != 0)
    return Fail(fmt::format("inconsistent verification arrays ({} ids, {} changes, {} stderr, {} radiance, {} "
                            "irradiance values)",
                            n, reply.irradiance_change_size(), reply.irradiance_change_stderr_size(),
                            reply.radiance_size(), reply.irradiance_size()));
  std::vector<VerifiedSample> out;
  out.reserve(size_t(n));  // bounded by the frame the part came in
  std::unordered_set<uint64_t> seen;
  seen.reserve(size_t(n));
  for (int i = 0; i < n; ++i) {
    const uint64_t id = reply.sample_ids(i);
    if (!seen.insert(id).second) return Fail(fmt::format("sample {} is answered twice", id));
    if (RoundOfWireId(id) > 0xffffu) return Fail(fmt::format("sample id {} names no round this SMA asks for", id));
    const float change = reply.irradiance_change(i), sigma = reply.irradiance_change_stderr(i);
    if (!std::isfinite(change) || !std::isfinite(sigma) || sigma < 0.0f)
      return Fail(fmt::format("sample {}: change {} with standard error {} is impossible", id, change, sigma));
    VerifiedSample v;
    v.vertex = VertexOfWireId(id);
    v.change = change;
    v.changeStdErr = sigma;
    out.push_back(v);
    if (rounds) rounds->push_back(uint16_t(RoundOfWireId(id)));
  }
  return out;
}

Status CheckShadeReplyShape(const wire::ShadeReply& reply) {
  const int n = reply.sample_ids_size();
  if (reply.radiance_size() != 3 * n || reply.irradiance_size() != 3 * n || reply.irradiance_stderr_size() != n ||
      (reply.sample_paths_size() != 0 && reply.sample_paths_size() != n))
    return Fail(fmt::format("inconsistent arrays ({} ids, {} radiance, {} irradiance, {} stderr, {} path values)", n,
                            reply.radiance_size(), reply.irradiance_size(), reply.irradiance_stderr_size(),
                            reply.sample_paths_size()));
  return Status::Ok();
}

Expected<ShadedSample> DecodeReplySample(const wire::ShadeReply& reply, int i, uint32_t batchPaths) {
  const uint64_t id = reply.sample_ids(i);
  const uint32_t paths = reply.sample_paths_size() == reply.sample_ids_size() ? reply.sample_paths(i) : batchPaths;
  if (paths == 0 || paths > (1u << 24)) return Fail(fmt::format("sample {} averages {} paths", id, paths));
  if (RoundOfWireId(id) > 0xffffu) return Fail(fmt::format("sample id {} names no round this SMA asks for", id));
  return ShadedSample{VertexOfWireId(id),
                      Rgb(reply.radiance(3 * i), reply.radiance(3 * i + 1), reply.radiance(3 * i + 2)),
                      Rgb(reply.irradiance(3 * i), reply.irradiance(3 * i + 1), reply.irradiance(3 * i + 2)),
                      reply.irradiance_stderr(i), paths, uint16_t(RoundOfWireId(id))};
}

Expected<std::vector<ShadedSample>> DecodeShadeReply(const wire::ShadeReply& reply, uint32_t batchPaths) {
  if (auto ok = CheckShadeReplyShape(reply); !ok) return ok.error();
  const int n = reply.sample_ids_size();
  std::vector<ShadedSample> samples;
  samples.reserve(size_t(n));  // bounded by the frame the part came in
  std::unordered_set<uint64_t> seen;
  seen.reserve(size_t(n));
  for (int i = 0; i < n; ++i) {
    if (!seen.insert(reply.sample_ids(i)).second)
      return Fail(fmt::format("sample {} is answered twice", reply.sample_ids(i)));
    auto sample = DecodeReplySample(reply, i, batchPaths);
    if (!sample) return sample.error();
    samples.push_back(*sample);
  }
  return samples;
}

}  // namespace penumbra::sma

#pragma once
// Translation between wire ShadeRequest/ShadeReply messages and the shader's
// ShadeInput/ShadeOutput, with every field checked. Plain code, no sockets.

#include <cstdint>
#include <span>
#include <vector>

#include "penumbra/common/expected.h"
#include "penumbra/renderer/shading.h"
#include "penumbra/wire.pb.h"

namespace penumbra {

struct ShadeLimits {
  uint32_t maxBatchSamples = 16384;
  uint32_t maxPathsPerSample = 65536;
};

/// The pose a request is to be shaded at (issue 14): epoch scene_epoch, and
/// object_transforms, 12 floats per movable object of the scene in scene
/// order, each a rigid object-to-world transform (RigidTransform::
/// FromRowMajor). An empty object_transforms means the scene's initial pose;
/// a scene with movable objects accepts that only at scene_epoch 0 (a later
/// epoch without its transforms is a peer's mistake, not a pose). Fails,
/// naming the batch, the object and the problem, for any other count or a
/// transform that is not finite and rigid; the count is checked before
/// anything is allocated.
Expected<ScenePose> DecodeShadePose(const wire::ShadeRequest& request, const Scene& scene);

/// Decodes a request into shader inputs at `pose`. Fails, naming the field
/// and the sample index, when the parallel arrays disagree in length, the
/// batch is empty or over the limit, the path count is over the limit, or
/// any sample fails ValidateShadeInput at `pose`.
Expected<std::vector<ShadeInput>> DecodeShadeRequest(const wire::ShadeRequest& request, const Scene& scene,
                                                     const ScenePose& pose, const ShadeLimits& limits);
/// DecodeShadePose, then the samples at that pose.
Expected<std::vector<ShadeInput>> DecodeShadeRequest(const wire::ShadeRequest& request, const Scene& scene,
                                                     const ShadeLimits& limits);

/// What a verification batch (ShadeRequest::verify_change) measures: the
/// change from `baseline` to the request's pose through `region`.
struct VerificationRequest {
  ScenePose baseline;
  std::vector<Bounds3> region;
};
inline constexpr size_t kMaxVerificationBoxes = 16;

/// Decodes verify_change for the decoded `inputs`: the baseline pose (as
/// DecodeShadePose checks a pose) and 1 to kMaxVerificationBoxes boxes, each
/// finite with min <= max. Fails, naming the batch and the field, for any
/// other, and for a sample on a movable object (it moves: only static
/// samples can be verified).
Expected<VerificationRequest> DecodeVerifyChange(const wire::ShadeRequest& request, const Scene& scene,
                                                 std::span<const ShadeInput> inputs);

/// Fills one reply part of a verification batch: sample_ids,
/// irradiance_change and irradiance_change_stderr (the caller sets
/// scene_epoch).
void FillChangeReply(uint64_t batchId, std::span<const ShadeInput> inputs, std::span<const ChangeEstimate> changes,
                     uint32_t remaining, const ShadeCounters& counters, wire::ShadeReply* reply);

/// Fills one reply part: results for `inputs[i]` are `outputs[i]` (the
/// caller sets scene_epoch).
void FillShadeReply(uint64_t batchId, std::span<const ShadeInput> inputs, std::span<const ShadeOutput> outputs,
                    uint32_t remaining, const ShadeCounters& counters, wire::ShadeReply* reply);

}  // namespace penumbra

#pragma once
// The SMA's half of the shade protocol, the mirror of the renderer's
// renderer/src/shade_batch.cpp: ShadeRequest batches built from sample
// requests, and ShadeReply parts checked and decoded into shaded samples.
// Plain functions of messages and bytes: no socket, no pool state, so they
// are tested with bytes against the renderer's own codec
// (tests/shade_codec_test.cpp) and fuzzed (tests/fuzz/fuzz_sma_shade_reply.cpp).
//
// Threads: none of their own; any thread may call them.

#include <cstdint>
#include <cmath>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "penumbra/common/expected.h"
#include "penumbra/sma/hierarchy.h"
#include "penumbra/sma/sample_cache.h"
#include "penumbra/wire.pb.h"

namespace penumbra::sma {

/// Everything a renderer needs to shade one vertex. Position and normal are
/// in the space of the vertex's object (world space for the static part):
/// they are placed in the world when the batch is encoded, at the pose it
/// is sent at, so that a request queued before a move is shaded where the
/// object is when it leaves.
struct SampleRequest {
  VertexId vertex = kNoVertex;
  Vec3 position;  // object space
  Vec3 normal;    // object space, unit
  uint32_t triangle = 0;
  Vec2 bary{0.0f};
  uint16_t round = 0;  // 0: first shading; k > 0: the k-th improvement (Priority::kImprove)
  uint32_t object = kStaticObject;  // Scene::objects index of the base triangle's object
};

/// Builds the request for vertex `v` of `hierarchy`.
SampleRequest MakeSampleRequest(const Hierarchy& hierarchy, VertexId v);

/// The pose a batch is shaded at: ShadeRequest.scene_epoch and, for a scene
/// with movable objects, their transforms. Null means epoch 0 with no
/// objects (a static scene).
void FillShadeRequestPose(const ScenePose* pose, wire::ShadeRequest* request);

/// Wire sample ids: the vertex in the low 32 bits, the improvement round
/// above, so that each round has a random stream of its own.
constexpr uint64_t WireSampleId(VertexId v, uint16_t round) { return uint64_t(v) | (uint64_t(round) << 32); }
constexpr VertexId VertexOfWireId(uint64_t id) { return VertexId(id & 0xffffffffu); }
constexpr uint64_t RoundOfWireId(uint64_t id) { return id >> 32; }

/// Fills `request` with one batch: `pathsPerSample` 0 leaves the count to
/// the renderer's default. Positions and normals go in world space at
/// `pose` (object samples transformed by their object's transform), with
/// the pose itself (FillShadeRequestPose); null `pose`: a static scene.
void FillShadeRequest(uint64_t batchId, uint32_t pathsPerSample, std::span<const SampleRequest> samples,
                      wire::ShadeRequest* request, const ScenePose* pose = nullptr);
/// The same batch as a whole frame, ready for net::Connection::SendFrame:
/// built by the caller outside any lock. `urgent`: a client waits for it
/// (ShadeRequest::urgent; AssignedBatch::urgent); `soon`: one is expected to
/// (ShadeRequest::soon; AssignedBatch::soon).
std::shared_ptr<const std::string> EncodeShadeRequestFrame(uint64_t batchId, uint32_t pathsPerSample,
                                                           std::span<const SampleRequest> samples,
                                                           const ScenePose* pose = nullptr, bool urgent = false,
                                                           bool soon = false);

// --- Verification batches (issue 14, docs/moving-objects.md "A test instead
// of a bound") ----------------------------------------------------------------

/// A move's test as a verification batch carries it: the change of static
/// samples' irradiance from `baseline` (the pose they were shaded at) to
/// `target` (the pose the batch is shaded at), measured through
/// `regionBoxes` (world space), the boxes that hold every object placed
/// differently at the two poses. Shared by all the samples it tests.
struct VerifyContext {
  std::shared_ptr<const ScenePose> baseline;
  std::shared_ptr<const ScenePose> target;
  std::vector<Bounds3> regionBoxes;  // 1 .. kMaxVerifyBoxes
  /// Paired samples per test; 0: the scheduler's verifyPaths. (A retest of
  /// a test its own noise failed asks for more: a context of its own.)
  uint32_t paths = 0;
};
/// The renderer's limit on region boxes (renderer/shade_batch.h).
inline constexpr size_t kMaxVerifyBoxes = 16;

/// The test of one static sample: the vertex (request.round is set by the
/// scheduler: each target epoch draws its own random stream), the cache
/// generation its suspect sample has (SampleCache::Suspect), and the change
/// it may have and still be kept (luminance of irradiance).
struct VerifyRequest {
  SampleRequest request;
  std::shared_ptr<const VerifyContext> context;
  uint32_t generation = 0;
  float tolerance = 0.0f;
};

/// A renderer's answer to one test.
struct VerifiedSample {
  VertexId vertex = kNoVertex;
  float change = 0.0f;        // Luminance(E(target)) - Luminance(E(baseline)), first order
  float changeStdErr = 0.0f;  // its standard error
  // From the request:
  uint32_t generation = 0;
  float tolerance = 0.0f;
  uint64_t targetEpoch = 0;
  SampleRequest request;  // round 0: to ask for a reshade when the test fails
  uint16_t testRound = 0;  // the round the test was asked under (VerifyRound)
  std::shared_ptr<const VerifyContext> context;  // what it was tested against
  /// Kept when the change, z standard errors beyond it, is within the
  /// tolerance: |change| + z sigma <= tolerance (z = 3: a sample that truly
  /// changes by more than its tolerance passes less than 0.14 % of the time).
  bool Passes(float z = 3.0f) const {
    return std::isfinite(change) && std::isfinite(changeStdErr) && std::abs(change) + z * changeStdErr <= tolerance;
  }
};

/// The round a test of a move to scene epoch `targetEpoch` asks under (its
/// wire id's high bits, WireSampleId): above every improvement round, and
/// different for consecutive epochs so that testing a vertex again after the
/// next move draws other random numbers.
constexpr uint16_t VerifyRound(uint64_t targetEpoch) { return uint16_t(0x8000u | (targetEpoch & 0x7fffu)); }
constexpr bool IsVerifyRound(uint16_t round) { return (round & 0x8000u) != 0; }
/// The round of a retest (more paths, after a test its noise failed): other
/// random numbers than the first test's.
constexpr uint16_t VerifyRetestRound(uint64_t targetEpoch) { return uint16_t(VerifyRound(targetEpoch) ^ 0x4000u); }

/// The boxes that hold every object placed differently at `baseline` and
/// `target` (WorldBounds at each), for VerifyContext::regionBoxes; nothing
/// when no object moved, more than kMaxVerifyBoxes boxes would be needed,
/// or a pose does not place every object of the scene.
std::optional<std::vector<Bounds3>> VerifyRegionBoxes(const Scene& scene, const ScenePose& baseline,
                                                      const ScenePose& target);

/// Fills `request` with one verification batch: the samples at the
/// context's target pose (FillShadeRequest) and its verify_change.
void FillVerifyRequest(uint64_t batchId, uint32_t pathsPerSample, std::span<const SampleRequest> samples,
                       const VerifyContext& context, wire::ShadeRequest* request);
std::shared_ptr<const std::string> EncodeVerifyRequestFrame(uint64_t batchId, uint32_t pathsPerSample,
                                                            std::span<const SampleRequest> samples,
                                                            const VerifyContext& context);
/// A verification reply part: one id, change and standard error per sample
/// (no radiance), each id once, values finite with a non-negative error.
/// `vertex`, `change` and `changeStdErr` are filled, with the round of each
/// id in `rounds` (parallel); the rest is the scheduler's.
Expected<std::vector<VerifiedSample>> DecodeVerifyReply(const wire::ShadeReply& reply, std::vector<uint16_t>* rounds);

/// OK when a reply part's arrays agree: per sample one id, three radiance,
/// three irradiance and one standard-error value, and no path counts or one
/// each.
Status CheckShadeReplyShape(const wire::ShadeReply& reply);
/// Sample `i` of a part that passed CheckShadeReplyShape: vertex and round
/// from its id, its path count, else `batchPaths`. An error when that count
/// is 0 or above 2^24. Values are not checked here (RadianceBounds::Check).
Expected<ShadedSample> DecodeReplySample(const wire::ShadeReply& reply, int i, uint32_t batchPaths);
/// A whole part: its shape, every sample (DecodeReplySample), and no sample
/// id twice in it. Whether the batch asked for these ids, and whether their
/// values are possible, is the scheduler's to check.
Expected<std::vector<ShadedSample>> DecodeShadeReply(const wire::ShadeReply& reply, uint32_t batchPaths);

}  // namespace penumbra::sma

#pragma once
// Moving objects in the SMA (issue 14), as plain code without sockets:
// checking a client's MoveObject, coalescing the moves that arrive while one
// is being applied, the next pose, and which vertices a move invalidates.
// The server (server.cpp) carries these out on a job thread: see
// sma/README.md, "Moving objects".
//
// Threads: MoveCoalescer is thread-safe; the rest are functions of their
// arguments (PlanInvalidation reads the hierarchy: the caller holds the
// state lock shared).

#include <cstdint>
#include <deque>
#include <map>
#include <mutex>
#include <optional>
#include <memory>
#include <span>
#include <vector>

#include "penumbra/common/expected.h"
#include "penumbra/common/rigid_transform.h"
#include "penumbra/common/scene.h"
#include "penumbra/sma/hierarchy.h"
#include "penumbra/sma/sample_cache.h"
#include "penumbra/wire.pb.h"

namespace penumbra::sma {

/// One object's new place: `object` indexes Scene::objects (the wire id
/// minus 1).
struct ObjectMove {
  uint32_t object = 0;
  RigidTransform objectToWorld;
};

/// The wire id of Scene::objects[index] (MovableObjectInfo.object,
/// Delta.vertex_objects, moved_objects): index + 1; 0 is the static part.
inline uint32_t WireObjectId(uint32_t index) { return index == kStaticObject ? 0 : index + 1; }

/// The SceneInfo's movable objects (id, name, object-space bounds, where
/// `pose` puts them, animated) and scene_epoch, replacing any objects
/// already there.
void FillSceneInfoObjects(const Scene& scene, const ScenePose& pose, wire::SceneInfo* info);
/// A MOVED delta's body: kind, scene_epoch and, for each of `objects`
/// (indices into Scene::objects), its id and its transform at `pose`.
void FillMovedDelta(const ScenePose& pose, std::span<const uint32_t> objects, wire::Delta* delta);

/// A client's MoveObject checked against the scene: an object id that names
/// a movable object (1 .. objects.size()), not one the SMA animates, and 12
/// finite numbers forming a rigid transform (RigidTransform::FromRowMajor).
/// The error message names the problem.
Expected<ObjectMove> CheckMoveObject(const wire::MoveObject& move, const Scene& scene);

/// `current` with `moves` applied (later moves of one object win) at epoch
/// current.epoch + 1; nothing when no object changes place (a transform
/// within 1e-6 of the current one -- the same 12 numbers sent back -- is
/// no change).
std::optional<ScenePose> NextPose(const ScenePose& current, std::span<const ObjectMove> moves);

/// Whether two poses put every object at the same place, within the 1e-6
/// NextPose treats as no change (epochs aside).
bool SamePlacesWithin(const ScenePose& a, const ScenePose& b);

/// Moves waiting to be applied, at most one per object: a move arriving
/// while earlier ones wait (or are being applied) replaces the waiting move
/// of its object, so a client dragging at 30 moves/s costs at most one
/// application at a time. One job applies them: Add says when to post it,
/// and the job calls Take until it returns nothing. Thread-safe.
class MoveCoalescer {
 public:
  /// Queues a move. True when no job is posted or running: the caller posts one.
  bool Add(const ObjectMove& move);
  /// The moves waiting now (in object order), or nothing -- then the job is
  /// over and the next Add posts a new one.
  std::vector<ObjectMove> Take();
  /// Moves replaced by a later one before they were applied.
  uint64_t Coalesced() const;

 private:
  mutable std::mutex mutex_;
  std::map<uint32_t, RigidTransform> pending_;
  bool jobActive_ = false;
  uint64_t coalesced_ = 0;
};

/// A cached sample a move might change, as the invalidation test sees it:
/// in world space at the pose before the move (its object did not move, so
/// also after it).
struct InvalidationCandidate {
  VertexId vertex = kNoVertex;
  Vec3 position;  // world space
  Vec3 normal;    // world space, unit: the side its sample shades
  Rgb radiance{0.0f};
  Rgb irradiance{0.0f};
  float irradianceStdErr = 0.0f;  // the sample's own noise
  Rgb albedo{0.0f};
  bool emissive = false;  // on an emitting surface (its radiance includes emission)
};

/// The vertices, among `candidates` (every cached vertex not of a moved
/// object: static ones and those of objects that stayed), whose radiance moving the
/// objects `movedObjects` (indices into scene.objects) from their places in
/// `oldPose` to their places in `newPose` may change by more than their
/// noise. All the objects of one epoch are judged together: their changes
/// add up at a vertex. Called with at least one candidate.
///
/// The motion-volume test (motion_volume.h): one MotionVolumes per moved
/// object from WorldBounds at both poses, one MoveInvalidator over them
/// (exact shafts for direct light, a solid-angle bound for indirect light
/// with twice the brightest cached reflected radiance), asked about the
/// candidates against each sample's own noise.
///
/// Two classes, each ascending: `direct`, where the exact shaft tests alone
/// (area lights, the sun) exceed the tolerance -- a shadow or a lit patch
/// moves there, what a viewer sees first -- and `indirectOnly`, invalidated
/// by the solid-angle bound of indirect light and the sky, usually far
/// above the real change. The SMA re-shades held vertices of the first
/// class at visible priority and of the second at background priority.
struct InvalidatedStatic {
  std::vector<VertexId> direct;
  std::vector<VertexId> indirectOnly;
  /// Parallel to indirectOnly: each one's tolerance tau (luminance of
  /// irradiance), for a test of its actual change (VerifyRequest).
  std::vector<float> indirectOnlyTolerance;
  std::vector<float> directTolerance;  // parallel to direct
};
/// `brightestReflected`: the brightest reflected radiance (luminance) of
/// every cached sample, which bounds what the volume can block or reflect;
/// < 0: taken over `candidates`.
InvalidatedStatic InvalidatedStaticVertices(const Scene& scene, const ScenePose& oldPose, const ScenePose& newPose,
                                            std::span<const uint32_t> movedObjects,
                                            std::span<const InvalidationCandidate> candidates,
                                            float brightestReflected = -1.0f);
/// Luminance of a candidate's reflected radiance, albedo/pi E.
inline float ReflectedLuminance(const InvalidationCandidate& c) { return Luminance(c.albedo * c.irradiance) * kInvPi; }

/// A cached static sample a move is to be tested at instead of invalidated
/// (InvalidationRule::kTestIndirect): the epoch it was shaded at and its
/// tolerance.
struct TestedVertex {
  VertexId vertex = kNoVertex;
  uint64_t baselineEpoch = 0;
  float tolerance = 0.0f;
  bool direct = false;  // of the direct class (InvalidationRule::kTestAll)
};

/// What a move from `oldPose` to `newPose` invalidates.
struct Invalidation {
  std::vector<VertexId> vertices;  // sorted, each once: the moved objects' vertices and those the test chose
  size_t objectVertices = 0;       // of which the moved objects' own
  /// Sorted: the moved objects' vertices and the test's `direct` class (all
  /// of `vertices` under InvalidationRule::kEverything): what a viewer
  /// sees change first, re-shaded at visible priority.
  std::vector<VertexId> urgent;
  /// Under InvalidationRule::kTestIndirect: the indirect-only class, not in
  /// `vertices`, sorted by baseline epoch then vertex: a renderer measures
  /// their change (docs/moving-objects.md "A test instead of a bound").
  /// Under kTestAll the direct class too (first in each epoch), and not in
  /// `urgent`.
  std::vector<TestedVertex> tested;
};

/// How much a move invalidates: what the test chooses, or everything cached
/// (a full recomputation: the benchmarks' baseline, and a check that needs
/// every sample shaded at the final pose; --invalidate-all-on-move).
/// kTestIndirect: as kTest, but the vertices invalidated only by the
/// indirect-light bound are to be tested (Invalidation::tested) rather
/// than invalidated. kTestAll: the direct class too (the shaft tests say
/// where light may change; the test measures whether it did -- in an
/// umbra at both places it did not).
enum class InvalidationRule { kTest, kTestIndirect, kTestAll, kEverything };

/// The poses of recent scene epochs, so that each cached sample can be
/// judged against the pose it was shaded at (PlanInvalidation). Bounded
/// (issue 15): at most `maxBytes` of poses are kept, the oldest forgotten
/// first. A sample shaded at a forgotten epoch is invalidated outright --
/// safe, it can only cost a reshade. The default, 16 MiB, keeps ~130 k epochs
/// of a one-object scene (3.6 h of a 10 Hz animation) and ~5 k of a
/// 64-object one.
///
/// Threads: not synchronised; the SMA's move job owns it.
class PoseHistory {
 public:
  static constexpr size_t kDefaultMaxBytes = size_t(16) << 20;
  explicit PoseHistory(size_t maxBytes = kDefaultMaxBytes) : maxBytes_(maxBytes) {}

  /// Records the pose of an epoch later than every recorded one (a pose of
  /// the last recorded epoch again is ignored; an earlier one is refused).
  /// Forgets the oldest poses beyond the byte budget, never the newest.
  void Record(std::shared_ptr<const ScenePose> pose);
  /// The pose recorded for `epoch`, or null (never recorded, or forgotten).
  const ScenePose* At(uint64_t epoch) const { return Shared(epoch).get(); }
  /// The same, shared (a test's VerifyContext keeps its baseline alive).
  std::shared_ptr<const ScenePose> Shared(uint64_t epoch) const;
  size_t Size() const { return poses_.size(); }
  size_t Bytes() const { return bytes_; }
  /// The newest recorded epoch; nothing when empty.
  std::optional<uint64_t> Newest() const {
    return poses_.empty() ? std::nullopt : std::optional<uint64_t>(poses_.back()->epoch);
  }

  /// What one pose costs to keep (the objects' transforms and the record).
  static size_t BytesOf(const ScenePose& pose);

 private:
  size_t maxBytes_;
  size_t bytes_ = 0;
  std::deque<std::shared_ptr<const ScenePose>> poses_;  // epochs strictly increasing
};

/// Every vertex of a moved object (its world place changed) whose id's chunk
/// the cache has (SampleCache::HasChunk), every vertex
/// with no sample that awaits a reshade (urgent: a client holding it wants
/// it), and the cached vertices InvalidatedStaticVertices chooses among the
/// others, for all the moved objects together. The other vertices with no
/// sample are not listed: the caller calls the cache's
/// InvalidateUnshaded(newPose.epoch) first, which refuses a sample of any of
/// them shaded at the old pose and perhaps on its way. The caller holds
/// the state lock shared (the hierarchy is read; the cache is read as it is).
///
/// Each cached sample is judged against the pose it was shaded at
/// (CachedSample::epoch, looked up in `history`), not only against
/// `oldPose`: a sample kept through many small moves, each below the
/// tolerance, would otherwise drift by the sum of them. A sample whose pose
/// the history does not have (forgotten, PoseHistory) is invalidated
/// outright, urgently. Without a history (tests) every sample is judged
/// against `oldPose`.
Invalidation PlanInvalidation(const Hierarchy& hierarchy, const SampleCache& cache, const ScenePose& oldPose,
                              const ScenePose& newPose, InvalidationRule rule = InvalidationRule::kTest,
                              const PoseHistory* history = nullptr);

}  // namespace penumbra::sma

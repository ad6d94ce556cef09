#include "penumbra/sma/scene_moves.h"

#include "penumbra/sma/motion_volume.h"

#include <algorithm>
#include <array>
#include <map>
#include <cmath>

#include <fmt/format.h>

namespace penumbra::sma {

namespace {

void AddTransform(const RigidTransform& t, google::protobuf::RepeatedField<float>* out) {
  const std::array<float, 12> m = t.ToRowMajor();
  out->Add(m.begin(), m.end());
}

void SetVec3(const Vec3& v, wire::Vec3* out) {
  out->set_x(v.x);
  out->set_y(v.y);
  out->set_z(v.z);
}

}  // namespace

void FillSceneInfoObjects(const Scene& scene, const ScenePose& pose, wire::SceneInfo* info) {
  info->clear_objects();
  for (uint32_t i = 0; i < scene.objects.size(); ++i) {
    const MovableObject& o = scene.objects[i];
    wire::MovableObjectInfo* out = info->add_objects();
    out->set_object(WireObjectId(i));
    out->set_name(o.name);
    SetVec3(o.objectBounds.min, out->mutable_bounds_min());
    SetVec3(o.objectBounds.max, out->mutable_bounds_max());
    AddTransform(i < pose.objectToWorld.size() ? pose.objectToWorld[i] : o.objectToWorld,
                 out->mutable_object_to_world());
    out->set_animated(o.animation.has_value());
  }
  info->set_scene_epoch(pose.epoch);
}

void FillMovedDelta(const ScenePose& pose, std::span<const uint32_t> objects, wire::Delta* delta) {
  delta->set_kind(wire::DELTA_KIND_MOVED);
  delta->set_scene_epoch(pose.epoch);
  for (uint32_t o : objects) {
    if (o >= pose.objectToWorld.size()) continue;
    delta->add_moved_objects(WireObjectId(o));
    AddTransform(pose.objectToWorld[o], delta->mutable_moved_object_transforms());
  }
}

Expected<ObjectMove> CheckMoveObject(const wire::MoveObject& move, const Scene& scene) {
  const uint32_t id = move.object();
  if (scene.objects.empty())
    return Fail(fmt::format("move_object: object {}: scene '{}' has no movable objects", id, scene.name));
  if (id == 0 || id > scene.objects.size())
    return Fail(fmt::format("move_object: unknown object id {} (the scene's movable objects are 1 .. {}; 0 is the "
                            "static part)",
                            id, scene.objects.size()));
  const MovableObject& object = scene.objects[id - 1];
  if (object.animation)
    return Fail(fmt::format("move_object: object {} ('{}') is animated: the SMA plays its path, it cannot be moved",
                            id, object.name));
  if (move.object_to_world_size() != 12)
    return Fail(fmt::format("move_object: object {} ('{}'): object_to_world has {} numbers, not 12 (3x4 row-major)", id,
                            object.name, move.object_to_world_size()));
  auto transform = RigidTransform::FromRowMajor(
      std::span<const float>(move.object_to_world().data(), size_t(move.object_to_world_size())));
  if (!transform)
    return Fail(fmt::format("move_object: object {} ('{}'): {}", id, object.name, transform.error().message));
  return ObjectMove{id - 1, *transform};
}

namespace {

// A transform sent back as the 12 floats it was announced with comes back
// re-orthonormalised (RigidTransform::FromRowMajor), a few ulps off: that
// is the same place, not a move.
bool SamePlace(const RigidTransform& a, const RigidTransform& b) {
  const std::array<float, 12> x = a.ToRowMajor(), y = b.ToRowMajor();
  for (size_t i = 0; i < 12; ++i) {
    const float scale = (i % 4 == 3) ? std::max(1.0f, std::abs(x[i])) : 1.0f;  // translations: relative
    if (!(std::abs(x[i] - y[i]) <= 1e-6f * scale)) return false;
  }
  return true;
}

}  // namespace

bool SamePlacesWithin(const ScenePose& a, const ScenePose& b) {
  if (a.objectToWorld.size() != b.objectToWorld.size()) return false;
  for (size_t o = 0; o < a.objectToWorld.size(); ++o)
    if (!SamePlace(a.objectToWorld[o], b.objectToWorld[o])) return false;
  return true;
}

std::optional<ScenePose> NextPose(const ScenePose& current, std::span<const ObjectMove> moves) {
  ScenePose next = current;
  bool changed = false;
  for (const ObjectMove& m : moves) {
    if (m.object >= next.objectToWorld.size() || SamePlace(next.objectToWorld[m.object], m.objectToWorld)) continue;
    next.objectToWorld[m.object] = m.objectToWorld;
    changed = true;
  }
  if (!changed) return std::nullopt;
  next.epoch = current.epoch + 1;
  return next;
}

bool MoveCoalescer::Add(const ObjectMove& move) {
  std::lock_guard lock(mutex_);
  auto [it, inserted] = pending_.insert_or_assign(move.object, move.objectToWorld);
  if (!inserted) ++coalesced_;
  if (jobActive_) return false;
  jobActive_ = true;
  return true;
}

std::vector<ObjectMove> MoveCoalescer::Take() {
  std::lock_guard lock(mutex_);
  std::vector<ObjectMove> moves;
  moves.reserve(pending_.size());
  for (const auto& [object, transform] : pending_) moves.push_back(ObjectMove{object, transform});
  pending_.clear();
  if (moves.empty()) jobActive_ = false;
  return moves;
}

uint64_t MoveCoalescer::Coalesced() const {
  std::lock_guard lock(mutex_);
  return coalesced_;
}

InvalidatedStatic InvalidatedStaticVertices(const Scene& scene, const ScenePose& oldPose, const ScenePose& newPose,
                                            std::span<const uint32_t> movedObjects,
                                            std::span<const InvalidationCandidate> candidates,
                                            float brightestReflected) {
  // The motion volume of each moved object (motion_volume.h): where it was
  // and where it is now, one box or two. All of an epoch's volumes are
  // judged together: two separate tests could each keep a vertex whose
  // combined change exceeds the tolerance.
  std::vector<MotionVolume> volumes;
  for (uint32_t o : movedObjects)
    volumes.push_back(MotionVolumes(WorldBounds(scene, oldPose, o), WorldBounds(scene, newPose, o)));
  // What the volume can block or reflect towards a vertex: reflected
  // radiance (albedo/pi E, an emitter's own emission excluded -- light is
  // handled by the exact shaft tests) no brighter than twice the brightest
  // cached. The moving object is lit by the same lights as what is cached
  // around it; the margin covers surfaces no client has seen yet being
  // brighter than those seen. With nothing cached the scene's brightest
  // light bounds it (always safe).
  float brightest = 0.0f;
  std::vector<Vec3> positions(candidates.size()), normals(candidates.size());
  std::vector<float> irradiance(candidates.size()), stdErr(candidates.size());
  for (size_t i = 0; i < candidates.size(); ++i) {
    const InvalidationCandidate& c = candidates[i];
    positions[i] = c.position;
    normals[i] = c.normal;
    irradiance[i] = Luminance(c.irradiance);
    stdErr[i] = c.irradianceStdErr;
    brightest = std::max(brightest, ReflectedLuminance(c));
  }
  if (brightestReflected >= 0.0f) brightest = brightestReflected;
  InvalidationParams params;
  params.indirectRadiance = brightest > 0.0f ? 2.0f * brightest : -1.0f;
  const MoveInvalidator invalidator(scene, std::span<const MotionVolume>(volumes), params);
  auto chosen = invalidator.ClassifyInvalidated(VertexSpans{positions, normals, irradiance, stdErr});
  InvalidatedStatic out;
  if (!chosen) {
    // Spans of equal length by construction; should it ever fail, the safe
    // answer is every candidate, urgently.
    out.direct.reserve(candidates.size());
    for (const InvalidationCandidate& c : candidates) out.direct.push_back(c.vertex);
    return out;
  }
  out.direct.reserve(chosen->direct.size());
  out.directTolerance.reserve(chosen->direct.size());
  for (uint32_t i : chosen->direct) {
    out.direct.push_back(candidates[i].vertex);
    out.directTolerance.push_back(params.Tolerance(irradiance[i], stdErr[i]));
  }
  out.indirectOnly.reserve(chosen->indirectOnly.size());
  out.indirectOnlyTolerance.reserve(chosen->indirectOnly.size());
  for (uint32_t i : chosen->indirectOnly) {
    out.indirectOnly.push_back(candidates[i].vertex);
    out.indirectOnlyTolerance.push_back(params.Tolerance(irradiance[i], stdErr[i]));
  }
  return out;
}

void PoseHistory::Record(std::shared_ptr<const ScenePose> pose) {
  if (!pose) return;
  if (!poses_.empty() && pose->epoch <= poses_.back()->epoch) return;  // known, or out of order
  bytes_ += BytesOf(*pose);
  poses_.push_back(std::move(pose));
  while (poses_.size() > 1 && bytes_ > maxBytes_) {
    bytes_ -= BytesOf(*poses_.front());
    poses_.pop_front();
  }
}

std::shared_ptr<const ScenePose> PoseHistory::Shared(uint64_t epoch) const {
  const auto it = std::lower_bound(poses_.begin(), poses_.end(), epoch,
                                   [](const std::shared_ptr<const ScenePose>& p, uint64_t e) { return p->epoch < e; });
  return it != poses_.end() && (*it)->epoch == epoch ? *it : nullptr;
}

size_t PoseHistory::BytesOf(const ScenePose& pose) {
  // The pose, its control block (make_shared), its transforms, the deque's slot.
  return sizeof(ScenePose) + 32 + pose.objectToWorld.capacity() * sizeof(RigidTransform) +
         sizeof(std::shared_ptr<const ScenePose>);
}

Invalidation PlanInvalidation(const Hierarchy& hierarchy, const SampleCache& cache, const ScenePose& oldPose,
                              const ScenePose& newPose, InvalidationRule rule,
                              const PoseHistory* history) {
  const Scene& scene = hierarchy.GetScene();
  // Objects whose place differs between `from` and the new pose.
  const auto movedSince = [&](const ScenePose& from) {
    std::vector<uint32_t> out;
    for (uint32_t o = 0; o < scene.objects.size(); ++o)
      if (!(o < from.objectToWorld.size() && o < newPose.objectToWorld.size() &&
            from.objectToWorld[o] == newPose.objectToWorld[o]))
        out.push_back(o);
    return out;
  };
  const std::vector<uint32_t> movedObjects = movedSince(oldPose);
  std::vector<bool> moved(scene.objects.size(), false);
  for (uint32_t o : movedObjects) moved[o] = true;
  Invalidation out;
  if (movedObjects.empty()) return out;
  // Cached candidates grouped by the pose their sample was shaded at.
  std::map<uint64_t, std::vector<InvalidationCandidate>> candidatesByEpoch;
  std::vector<VertexId> everythingElse;
  const size_t vertexCount = hierarchy.VertexCount();
  constexpr VertexId kChunk = VertexId(SampleCache::kChunkVertices);
  for (VertexId v = 0; v < vertexCount; ++v) {
    // A chunk of ids the cache never wrote holds no sample, suspect or
    // awaited reshade: nothing to judge or evict, and the caller's
    // InvalidateUnshaded already refuses old samples of it. Most of a
    // large scene's ids are in such chunks until they are seen.
    if (v % kChunk == 0 && !cache.HasChunk(v)) {
      v += kChunk - 1;
      continue;
    }
    const SampleVertex& sv = hierarchy.GetVertex(v);
    const uint32_t object = scene.ObjectOfTriangle(sv.baseTriangle);
    if (object != kStaticObject && moved[object]) {
      out.vertices.push_back(v);
      continue;
    }
    // A sample held back for an earlier move's test (SampleCache::Suspect)
    // is judged again like a stored one: tested again, invalidated, or left
    // to its pending test.
    std::optional<CachedSample> sample = cache.Read(v);
    if (!sample) sample = cache.ReadSuspect(v);
    // Nothing cached: the caller's SampleCache::InvalidateUnshaded refuses
    // a sample of it shaded at the old pose that may be on its way, and
    // there is nothing to evict -- unless it awaits a reshade, which a
    // client holding it wants urgently (listed). Most of a refined
    // hierarchy's vertices are not cached: 287 k of 299 k in the
    // breakfast room seen once.
    if (!sample) {
      if (cache.AwaitingReshade(v)) everythingElse.push_back(v);
      continue;
    }
    if (rule == InvalidationRule::kEverything) {
      everythingElse.push_back(v);
      continue;
    }
    InvalidationCandidate c;
    c.vertex = v;
    // The vertex's object did not move in this step, so its place is the
    // same at the old and the new pose.
    const RigidTransform place = oldPose.Of(object);
    c.position = place.ApplyPoint(sv.position);
    c.normal = place.ApplyVector(sv.normal);
    c.radiance = sample->radiance;
    c.irradiance = sample->irradiance;
    c.irradianceStdErr = sample->irradianceStdErr;
    c.albedo = scene.AlbedoAt(sv.baseTriangle, sv.bary.x, sv.bary.y);
    c.emissive = scene.MaterialOf(sv.baseTriangle).IsEmissive();
    uint64_t epoch = oldPose.epoch;
    if (history && sample->epoch != oldPose.epoch) {
      if (!history->At(sample->epoch)) {
        // Its pose was forgotten: it cannot be judged, so it goes.
        everythingElse.push_back(v);
        continue;
      }
      epoch = sample->epoch;
    }
    candidatesByEpoch[epoch].push_back(c);
  }
  out.objectVertices = out.vertices.size();
  // Urgent: the objects' own vertices, whatever had nothing cached (a held
  // one of those awaits an earlier move's reshade) or was shaded at a
  // forgotten pose, and the direct class.
  out.vertices.insert(out.vertices.end(), everythingElse.begin(), everythingElse.end());
  out.urgent = out.vertices;
  // One bound on reflected radiance for every group: the brightest of all.
  float brightest = 0.0f;
  for (const auto& [epoch, candidates] : candidatesByEpoch)
    for (const InvalidationCandidate& c : candidates) brightest = std::max(brightest, ReflectedLuminance(c));
  for (const auto& [epoch, candidates] : candidatesByEpoch) {
    const ScenePose& shadedAt = epoch == oldPose.epoch ? oldPose : *history->At(epoch);
    const std::vector<uint32_t> objects = &shadedAt == &oldPose ? movedObjects : movedSince(shadedAt);
    if (objects.empty()) continue;  // every object is back where it was when these were shaded
    const InvalidatedStatic chosen =
        InvalidatedStaticVertices(scene, shadedAt, newPose, objects, candidates, brightest);
    const size_t testedBefore = out.tested.size();
    if (rule == InvalidationRule::kTestIndirect || rule == InvalidationRule::kTestAll) {
      for (size_t i = 0; i < chosen.indirectOnly.size(); ++i)
        out.tested.push_back(TestedVertex{chosen.indirectOnly[i], epoch, chosen.indirectOnlyTolerance[i], false});
    } else {
      out.vertices.insert(out.vertices.end(), chosen.indirectOnly.begin(), chosen.indirectOnly.end());
    }
    if (rule == InvalidationRule::kTestAll) {
      for (size_t i = 0; i < chosen.direct.size(); ++i)
        out.tested.push_back(TestedVertex{chosen.direct[i], epoch, chosen.directTolerance[i], true});
      // One epoch's tests: the direct class first (a shadow that moved is
      // what a viewer sees first), each in vertex order.
      std::sort(out.tested.begin() + std::ptrdiff_t(testedBefore), out.tested.end(),
                [](const TestedVertex& a, const TestedVertex& b) {
                  return a.direct != b.direct ? a.direct : a.vertex < b.vertex;
                });
    } else {
      out.vertices.insert(out.vertices.end(), chosen.direct.begin(), chosen.direct.end());
      out.urgent.insert(out.urgent.end(), chosen.direct.begin(), chosen.direct.end());
    }
  }
  for (std::vector<VertexId>* list : {&out.vertices, &out.urgent}) {
    std::sort(list->begin(), list->end());
    list->erase(std::unique(list->begin(), list->end()), list->end());
  }
  return out;
}

}  // namespace penumbra::sma

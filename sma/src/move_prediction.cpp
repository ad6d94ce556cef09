#include "penumbra/sma/move_prediction.h"

#include <algorithm>
#include <utility>

#include "penumbra/common/check.h"

namespace penumbra::sma {

// --- MovePredictor --------------------------------------------------------------

MovePredictor::MovePredictor(const Scene& scene, double animationHz) : scene_(scene), hz_(animationHz) {}

ScenePose MovePredictor::AtStep(const ScenePose& pose, uint64_t step) const {
  ScenePose out = pose;
  for (uint32_t o = 0; o < scene_.objects.size() && o < out.objectToWorld.size(); ++o)
    if (const auto& animation = scene_.objects[o].animation) out.objectToWorld[o] = animation->At(double(step) / hz_);
  return out;
}

void MovePredictor::Applied(const ScenePose& before, uint64_t epoch, std::span<const ObjectMove> sent,
                            Clock::time_point at) {
  for (const ObjectMove& move : sent) {
    const uint32_t o = move.object;
    if (o >= scene_.objects.size() || o >= before.objectToWorld.size() || scene_.objects[o].animation) continue;
    Drag& drag = drags_[o];
    const bool continues = !drag.places.empty() && at - drag.at <= kDragGap;
    if (!continues) {
      drag.places = {before.objectToWorld[o]};  // a new drag, from where the object rested
      drag.secondOrder = false;
    } else {
      // Which guess would have been right this time: the next one is made
      // the same way (a straight drag: first order; a turn: second).
      const Bounds3& bounds = scene_.objects[o].objectBounds;
      const float firstMiss = LargestDisplacement(ExtrapolatePlace(drag.places, false), move.objectToWorld, bounds);
      drag.secondOrder = drag.places.size() >= 3 &&
                         LargestDisplacement(ExtrapolatePlace(drag.places, true), move.objectToWorld, bounds) < firstMiss;
    }
    drag.places.push_back(move.objectToWorld);
    if (drag.places.size() > 3) drag.places.erase(drag.places.begin());
    drag.epoch = epoch;
    drag.at = at;
  }
}

std::optional<ScenePose> MovePredictor::Predict(const ScenePose& current, uint64_t latestStep) const {
  if (current.objectToWorld.size() != scene_.objects.size()) return std::nullopt;
  bool animated = false;
  for (const MovableObject& o : scene_.objects) animated |= o.animation.has_value();
  ScenePose next = current;
  if (animated && hz_ > 0.0) {
    bool shown = false;
    for (uint64_t step : {latestStep, latestStep - 1}) {
      if (step == ~uint64_t(0) || !AtStep(current, step).SamePlaces(current)) continue;
      next = AtStep(current, step + 1);
      shown = true;
      break;
    }
    if (!shown) return std::nullopt;
  }
  for (const auto& [object, drag] : drags_) {
    if (drag.epoch != current.epoch || drag.places.size() < 2) continue;  // not dragged in the latest epoch: it rests
    next.objectToWorld[object] = ExtrapolatePlace(drag.places, drag.secondOrder);
  }
  next.epoch = current.epoch + 1;
  // A path resting between keyframes does not move: no epoch comes.
  if (SamePlacesWithin(next, current)) return std::nullopt;
  return next;
}

RigidTransform ExtrapolatePlace(std::span<const RigidTransform> places, bool secondOrder) {
  PENUMBRA_CHECK(places.size() >= 2, "a place to continue needs two before it");
  const RigidTransform& last = places[places.size() - 1];
  const RigidTransform& previous = places[places.size() - 2];
  RigidTransform change = last.Compose(previous.Inverse());  // world frame: last = change * previous
  if (secondOrder && places.size() >= 3) {
    const RigidTransform before = previous.Compose(places[places.size() - 3].Inverse());
    change = change.Compose(before.Inverse()).Compose(change);
  }
  const RigidTransform next = change.Compose(last);
  // Re-orthonormalised like a client's move (a few float compositions stay
  // well within kRigidTolerance).
  if (auto clean = RigidTransform::FromRowMajor(next.ToRowMajor())) return *clean;
  return last;
}

float LargestDisplacement(const RigidTransform& a, const RigidTransform& b, const Bounds3& objectBounds) {
  float largest = 0.0f;
  for (int corner = 0; corner < 8; ++corner) {
    const Vec3 p((corner & 1) ? objectBounds.max.x : objectBounds.min.x, (corner & 2) ? objectBounds.max.y : objectBounds.min.y,
                 (corner & 4) ? objectBounds.max.z : objectBounds.min.z);
    largest = std::max(largest, glm::length(a.ApplyPoint(p) - b.ApplyPoint(p)));
  }
  return largest;
}

std::optional<ObjectMove> SnapToPrediction(const ObjectMove& move, const ScenePose& current,
                                           const ScenePose& predicted, const Scene& scene, float tolerance) {
  const uint32_t o = move.object;
  if (!(tolerance > 0.0f) || o >= scene.objects.size() || o >= predicted.objectToWorld.size() ||
      o >= current.objectToWorld.size() || scene.objects[o].animation)
    return std::nullopt;
  const RigidTransform& place = predicted.objectToWorld[o];
  if (place == current.objectToWorld[o]) return std::nullopt;  // predicted to rest: never snapped back
  if (!NearlyEqual(move.objectToWorld, place, tolerance)) return std::nullopt;
  if (!(LargestDisplacement(move.objectToWorld, place, scene.objects[o].objectBounds) <= tolerance))
    return std::nullopt;
  return ObjectMove{o, place};
}

// --- MovePreparation ------------------------------------------------------------

bool MovePreparation::Begin(std::shared_ptr<const ScenePose> predicted, uint64_t generation) {
  std::lock_guard lock(mutex_);
  if (!predicted || predicted->epoch <= appliedEpoch_) return false;
  if (predicted_) {
    // The move prepared for before never came (or is this one again).
    counters_.samplesDropped += kept_.size();
    kept_.clear();
  }
  predicted_ = std::move(predicted);
  generation_ = generation;
  ++counters_.predictions;
  return true;
}

std::vector<ShadedSample> MovePreparation::Arrived(std::vector<ShadedSample> samples) {
  std::lock_guard lock(mutex_);
  std::vector<ShadedSample> release;
  for (ShadedSample& s : samples) {
    ++counters_.samplesArrived;
    if (predicted_ && s.epoch == predicted_->epoch) {
      kept_.push_back(s);
    } else if (releasing_ != 0 && s.epoch == releasing_) {
      ++counters_.samplesReleased;
      release.push_back(s);
    } else {
      ++counters_.samplesDropped;
    }
  }
  return release;
}

MovePreparation::AppliedOutcome MovePreparation::Applied(const ScenePose& applied, uint64_t generation) {
  std::lock_guard lock(mutex_);
  appliedEpoch_ = std::max(appliedEpoch_, applied.epoch);
  releasing_ = 0;
  AppliedOutcome out;
  if (!predicted_) return out;
  if (predicted_->epoch > applied.epoch) return out;  // still ahead
  out.preparedEpoch = predicted_->epoch;
  out.hit = predicted_->epoch == applied.epoch && generation == generation_ && predicted_->SamePlaces(applied);
  if (out.hit) {
    ++counters_.hits;
    counters_.samplesReleased += kept_.size();
    out.samples = std::move(kept_);
    releasing_ = applied.epoch;
  } else {
    ++counters_.misses;
    counters_.samplesDropped += kept_.size();
  }
  kept_.clear();
  predicted_.reset();
  return out;
}

std::shared_ptr<const ScenePose> MovePreparation::Predicted() const {
  std::lock_guard lock(mutex_);
  return predicted_;
}

MovePreparationCounters MovePreparation::Counters() const {
  std::lock_guard lock(mutex_);
  return counters_;
}

}  // namespace penumbra::sma

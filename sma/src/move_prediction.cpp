#include "penumbra/sma/move_prediction.h"

#include <utility>

namespace penumbra::sma {

// --- MovePredictor --------------------------------------------------------------

MovePredictor::MovePredictor(const Scene& scene, double animationHz) : scene_(scene), hz_(animationHz) {}

ScenePose MovePredictor::AtStep(const ScenePose& pose, uint64_t step) const {
  ScenePose out = pose;
  for (uint32_t o = 0; o < scene_.objects.size() && o < out.objectToWorld.size(); ++o)
    if (const auto& animation = scene_.objects[o].animation) out.objectToWorld[o] = animation->At(double(step) / hz_);
  return out;
}

std::optional<ScenePose> MovePredictor::Predict(const ScenePose& current, uint64_t latestStep) const {
  if (!(hz_ > 0.0) || current.objectToWorld.size() != scene_.objects.size()) return std::nullopt;
  for (uint64_t step : {latestStep, latestStep - 1}) {
    if (step == ~uint64_t(0) || !AtStep(current, step).SamePlaces(current)) continue;
    ScenePose next = AtStep(current, step + 1);
    next.epoch = current.epoch + 1;
    // A path resting between keyframes does not move: no epoch comes.
    if (SamePlacesWithin(next, current)) return std::nullopt;
    return next;
  }
  return std::nullopt;
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

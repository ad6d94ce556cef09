#pragma once
// Movement prediction for moving objects (issue 15, the paper's prediction
// applied to issue 14's moves): guess the scene's next pose, shade ahead at
// it what the move will invalidate and a viewer sees, and hand those samples
// to the cache the moment the move happens -- if it happens where predicted.
//
//  * MovePredictor: the next pose.
//    - An animated object's place is known: the SMA plays its path on a
//      fixed step clock (step k places it at the path's time k /
//      animationHz), so the next step's place is its path at the next
//      step's time.
//    - An object a client drags steadily (the paper's linear extrapolation
//      of the transform): its next place continues its last applied places
//      -- the same change again (first order), or the change changing as it
//      last did (second order: a steady turn, a circle), whichever would
//      have predicted its latest place better. Only while the drag goes on
//      (its places applied at most kDragGap apart, in the latest epoch).
//  * Snapping (SnapToPrediction): a client's next move never repeats a
//    prediction to the last bit (its 12 floats are re-orthonormalised; a
//    steady drag lands within ~1e-6 of the first-order guess, a circle
//    within r*theta^3 of the second-order one), and a prepared sample is
//    used only at exactly the pose it was shaded at -- accepting samples
//    shaded *near* their pose would need a bound on how much such a
//    difference changes them, and issue 14's indirect-light bound is far too
//    coarse for that (docs/moving-objects.md). So a move that lands within
//    a tolerance of the prediction (no point of the object's bounds more
//    than it away, and every entry of the transform within it) is applied
//    at the predicted place: the object is shown at most that far from where
//    the client put it (a millimetre by default, kMoveConfirmTolerance: the
//    client still confirms its move by value), and the samples prepared for
//    it are exactly right.
//  * MovePreparation: the prepared samples' state. Samples shaded at the
//    predicted pose are kept until the move; when the pose applied is the
//    predicted one (every object exactly where predicted) and the
//    hierarchy's structure did not change meanwhile (no collection reused a
//    vertex id), they are the new epoch's first estimates and go to the
//    cache at once; answers still on their way go there as they arrive.
//    Otherwise they are dropped: a sample shaded at a pose that never
//    happened is never stored.
//
// Threads: MovePredictor is not synchronised (the move job owns it: the
// job applying moves calls Applied, then Predict);
// MovePreparation is thread-safe (the move job, a job thread preparing, and
// the I/O thread the renderer pool answers on).

#include <chrono>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <vector>

#include "penumbra/common/rigid_transform.h"
#include "penumbra/common/scene.h"
#include "penumbra/sma/sample_cache.h"
#include "penumbra/sma/scene_moves.h"

namespace penumbra::sma {

class MovePredictor {
 public:
  using Clock = std::chrono::steady_clock;
  /// Places of a dragged object applied further apart than this end its
  /// drag: the next place starts a new one (a pause, a new grab).
  static constexpr Clock::duration kDragGap = std::chrono::milliseconds(500);

  MovePredictor(const Scene& scene, double animationHz);

  /// Moves were applied as epoch `epoch` (the one after `before`'s) at
  /// `at`; `sent` are the places the clients sent (before any snapping: a
  /// snapped place, off by up to the tolerance, would feed its error into
  /// the next guesses -- at second order three times over). Each object a
  /// client moves (one without a path) continues its drag, or starts one
  /// from where `before` has it.
  void Applied(const ScenePose& before, uint64_t epoch, std::span<const ObjectMove> sent, Clock::time_point at);
  /// The pose expected at epoch current.epoch + 1: each animated object at
  /// its path's place at the step after the one `current` shows -- found
  /// among `latestStep` (the clock's last) and the step before it, since the
  /// clock may play a step while the previous one is applied --, each object
  /// dragged in `current`'s epoch (Applied) at its extrapolated place, every
  /// other object where it is. Nothing when no object would move, or the
  /// scene is animated and `current` shows neither step.
  std::optional<ScenePose> Predict(const ScenePose& current, uint64_t latestStep) const;
  /// Where the animated objects are at `step` in `pose` (the others kept).
  ScenePose AtStep(const ScenePose& pose, uint64_t step) const;
 private:
  struct Drag {
    std::vector<RigidTransform> places;  // as sent, the latest last; at most 3
    uint64_t epoch = 0;                  // the epoch that applied the latest
    Clock::time_point at;
    bool secondOrder = false;  // the second-order guess was the closer for the latest place
  };
  const Scene& scene_;
  double hz_;
  std::map<uint32_t, Drag> drags_;  // by object index
};

/// The place after `places` (oldest first, 2 or 3 of them) continuing the
/// latest change (first order) or, with 3 places and `secondOrder`, that
/// change changed as it last did. World-frame changes: D = T_k T_(k-1)^-1,
/// next = D T_k, or (D_k D_(k-1)^-1 D_k) T_k.
RigidTransform ExtrapolatePlace(std::span<const RigidTransform> places, bool secondOrder);

/// The farthest any corner of `objectBounds` (object space) lies at `a`
/// from where it lies at `b`.
float LargestDisplacement(const RigidTransform& a, const RigidTransform& b, const Bounds3& objectBounds);

/// `move` placed at `predicted`'s place of its object when it lands within
/// `tolerance` of it -- no corner of the object's bounds more than
/// `tolerance` away and every transform entry within it (NearlyEqual) --,
/// the prediction moves the object (from its place in `current`: a slow
/// drag's small moves are never snapped back to where it rests) and it is
/// not animated; else nothing. `predicted` is the pose prepared for the
/// epoch after `current`, the one `move` will be applied at.
std::optional<ObjectMove> SnapToPrediction(const ObjectMove& move, const ScenePose& current,
                                           const ScenePose& predicted, const Scene& scene, float tolerance);

/// Counters of MovePreparation (and the SMA's prepared-shading metrics).
struct MovePreparationCounters {
  uint64_t predictions = 0;       // preparations begun
  uint64_t hits = 0;              // moves applied where a preparation predicted
  uint64_t misses = 0;            // preparations whose move went elsewhere (or a collection intervened)
  uint64_t samplesArrived = 0;    // prepared samples answered
  uint64_t samplesReleased = 0;   // handed to the cache (Applied, or Arrived after it)
  uint64_t samplesDropped = 0;    // answered for a pose that did not happen
};

class MovePreparation {
 public:
  /// Starts preparing for `predicted` (whose epoch is the current epoch + 1)
  /// while the hierarchy's structure is `generation`; the preparation
  /// before, if its move has not happened, is dropped. Refused (false) for
  /// an epoch already applied.
  bool Begin(std::shared_ptr<const ScenePose> predicted, uint64_t generation);
  /// Answers to prepared batches (ShadedSample::epoch: the epoch they were
  /// prepared for). Returns those for the cache now: their move happened
  /// where predicted. Those for the move still ahead are kept; the rest are
  /// dropped.
  std::vector<ShadedSample> Arrived(std::vector<ShadedSample> samples);
  /// What a move's application found prepared.
  struct AppliedOutcome {
    uint64_t preparedEpoch = 0;  // the epoch a preparation ended for (0: none did)
    bool hit = false;            // the move landed where it predicted, the structure unchanged
    std::vector<ShadedSample> samples;  // prepared for it and answered: for the cache (hit only)
  };
  /// `applied` is the current pose now, with the hierarchy at `generation`.
  /// On a hit -- it is the predicted pose and the structure did not change
  /// since Begin -- the samples prepared for it are returned (later answers
  /// for it then come out of Arrived); otherwise they are dropped.
  AppliedOutcome Applied(const ScenePose& applied, uint64_t generation);
  /// The pose being prepared for; null when none is ahead.
  std::shared_ptr<const ScenePose> Predicted() const;
  MovePreparationCounters Counters() const;

 private:
  mutable std::mutex mutex_;
  std::shared_ptr<const ScenePose> predicted_;  // ahead: its move not applied yet
  uint64_t generation_ = 0;
  std::vector<ShadedSample> kept_;
  uint64_t appliedEpoch_ = 0;   // the newest epoch applied
  uint64_t releasing_ = 0;      // epoch whose late answers go to the cache (0: none)
  MovePreparationCounters counters_;
};

}  // namespace penumbra::sma

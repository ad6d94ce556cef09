#pragma once
// The refinement of one client's view, step by step (issue 13): the Refiner
// of the current view, whether a step runs, which of its splits still await
// samples, the per-view sample cap, and the rules that keep refinement alive
// -- that some event always starts the next step until the criterion has
// nothing left. They lived in the SMA's network session; an NLD_IS stall was
// once fixed there alone. They live beside Refiner now, without sockets.
//
// A step (RunStep) runs on a job thread: Select under the state lock held
// shared, then split and ask for the new vertices under it held exclusive.
// Everything else is called on the owning session's strand (one thread at a
// time); the driver knows nothing of the session: the session's view state
// (view_session.h) owns it and passes in what the rules need.

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <shared_mutex>
#include <span>
#include <unordered_set>
#include <vector>

#include "penumbra/common/tonemap.h"
#include "penumbra/sma/hierarchy.h"
#include "penumbra/sma/refinement.h"
#include "penumbra/sma/sample_cache.h"
#include "penumbra/sma/visibility.h"

namespace penumbra::sma {

/// What a step needs of the SMA's shared state.
struct RefinementStepContext {
  std::shared_mutex& stateMutex;  // guards hierarchy and cache
  Hierarchy& hierarchy;
  SampleCache& cache;
  DragoParams toneMapping;
  const std::atomic<bool>* stop = nullptr;  // set: give up between splits (shutdown)
  /// Asks for the vertices a step created; called with the state lock held
  /// exclusive (RendererPool: "requested once").
  std::function<void(std::span<const VertexId> created)> request;
};

/// What one step did, handed back to the session's strand.
struct RefinementStep {
  std::shared_ptr<Refiner> refiner;  // the Refiner it ran (stale if the view changed meanwhile)
  size_t chosen = 0;                 // leaves split
  std::vector<VertexId> created;     // vertices the splits made
  bool exhausted = false;            // the criterion has nothing more for this view
  /// The visibility it chose from was mapped before a collection (its node
  /// ids may be freed or reused): nothing was split; the view must be
  /// re-mapped first (hierarchy.h, "Collection").
  bool staleMapping = false;
  size_t remadeVertices = 0;  // of `created`, made again after a collection (RefineResult)
  double exclusiveMs = 0.0;   // the state lock held exclusive (splits and requests): every reader waits
};

class RefinementDriver {
 public:
  /// `maxSamplesPerView`: new vertices one view's refinement may create
  /// (--client-max-refinement-samples).
  RefinementDriver(RefinementParams params, uint64_t maxSamplesPerView);

  const RefinementParams& Params() const { return params_; }
  /// New options: takes effect through Restart().
  void SetParams(const RefinementParams& params) { params_ = params; }
  bool Enabled() const { return params_.criterion != Criterion::kNone; }

  /// A new view (or new options): a new Refiner, nothing pending. A step
  /// still running keeps the old Refiner, and OnStepDone recognises it.
  void Restart();
  /// The same view, lit anew (a move): a new Refiner as Restart, but the
  /// samples this view's refinement asked for so far still count against
  /// its cap -- an animation's every step would otherwise give the view a
  /// fresh budget, and its refinement could grow without bound.
  void RestartSameView();

  enum class Start {
    kNothing,     // off, running, finished, or not allowed now
    kStep,        // a step is marked running: run RunStep(CurrentRefiner(), ...)
    kCapReached,  // the sample cap ended this view's refinement just now
  };
  /// Whether to start a step. `stage1Done`: the view's own samples are all
  /// shaded (refinement waits for stage 1). The cap is checked here.
  Start StartStep(bool stage1Done);
  /// StartStep would not answer kNothing (it may still find the cap reached).
  bool WantsStep(bool stage1Done) const { return Enabled() && !running_ && !done_ && stage1Done; }
  std::shared_ptr<Refiner> CurrentRefiner() const { return refiner_; }
  /// For the step's Select: earlier splits still await samples, or a re-map
  /// that would show them is due (`remapDue`), so an empty choice is not final.
  bool Outstanding(bool remapDue) const { return !pending_.empty() || remapDue; }

  /// The step itself, on a job thread: chooses leaves (shared lock), splits
  /// them and asks for the new vertices (exclusive lock). Leaves split
  /// meanwhile by another client are skipped.
  static RefinementStep RunStep(std::shared_ptr<Refiner> refiner, const HitBuffer& hits, const VisibleSet& visible,
                                bool outstanding, const RefinementStepContext& context);

  enum class After {
    kStale,      // the step ran for a Refiner since replaced: ask StartStep again
    kStepAgain,  // it split something: give the strand a turn (a new view), then StartStep
    kFinished,   // the criterion is exhausted: refinement of this view is over
    kStepNow,    // nothing to split, and nothing outstanding will wake it: StartStep now
    kWait,       // nothing to split now; an arriving sample or a re-map wakes it
  };
  /// The step's result, on the strand. `cache` is read for which created
  /// vertices are already shaded (caller holds the state lock shared).
  /// `remapPending`: a re-map is due, armed or running, and its completion
  /// will call StartStep. This is the liveness rule: a step that found
  /// nothing while everything it waited for happened meanwhile must look
  /// again at once (kStepNow), or nothing would ever wake it.
  After OnStepDone(RefinementStep step, const SampleCache& cache, bool remapPending);

  /// A sample arrived; true if it was one of this view's splits.
  bool OnSampleArrived(VertexId v);

  /// Off, or the criterion exhausted (or the cap reached) with no step
  /// running and every split shaded. A re-map still owed is the caller's to add.
  bool Finished() const { return !Enabled() || (done_ && pending_.empty() && !running_); }
  bool Running() const { return running_; }

  size_t PendingSamples() const { return pending_.size(); }
  size_t SamplesTotal() const { return total_; }     // this view's, for Delta fields 22-23
  size_t SamplesDone() const { return std::min(doneCount_, total_); }
  uint64_t Splits() const { return splits_; }        // every view's, for statistics
  uint64_t Samples() const { return samples_; }
  /// Samples this view's refinement asked for (across RestartSameView), as
  /// its steps reported them (OnStepDone).
  size_t Requested() const { return requestedThisView_; }

 private:
  RefinementParams params_;
  uint64_t maxSamplesPerView_;
  std::shared_ptr<Refiner> refiner_;
  // The cap's count, kept on the strand (a running step's Refiner is its
  // job thread's until OnStepDone): every step of this view, including
  // those of Refiners RestartSameView replaced.
  size_t requestedThisView_ = 0;
  uint64_t viewSerial_ = 0;  // bumped by Restart (a new view), not by RestartSameView
  uint64_t stepSerial_ = 0;  // viewSerial_ when the running step started
  bool running_ = false;
  bool done_ = false;
  std::unordered_set<VertexId> pending_;  // split vertices not yet shaded
  size_t total_ = 0;
  size_t doneCount_ = 0;
  uint64_t splits_ = 0;
  uint64_t samples_ = 0;
};

}  // namespace penumbra::sma

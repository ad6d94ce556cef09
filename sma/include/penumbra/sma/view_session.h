#pragma once
// What one client's session is doing with its view, and what it should do
// next (issue 13) -- without sockets, locks on the network or timers, so it
// is tested as a plain object. The network session (server.cpp) moves bytes,
// runs jobs and timers, and asks this class at every event.
//
// The phase of the view, in order (Phase()):
//
//   AwaitingHello -> NoView -> Tracing -> Shading -> Refining -> Converged
//                                ^__________________________________|  a new view
//
//  * Tracing: the latest view's visibility is not applied yet (a trace and
//    mapping run, or wait for the client's queue to drain).
//  * Shading (stage 1, paper §5): applied; some of its initially visible
//    triangles wait for samples.
//  * Refining (stage 2): every initially visible triangle shaded; the
//    refinement driver splits, improvement asks for better samples.
//  * Converged: the criterion has nothing left, every split is shaded and
//    re-mapped, nothing shown needs improving.
//
// Beside the phase, three orthogonal parts:
//  * the view job (none, new view, refresh) -- at most one runs;
//  * the re-map of the applied view (none, due, timer armed, or a timer
//    armed for a re-map that another path already made), throttled to one
//    per refresh interval;
//  * waiting for the client's queue to drain: while it is over the soft
//    limit no work is started for the client; on drain one refresh sends
//    the difference that built up.
//
// Threads: one at a time -- the session's strand.

#include <chrono>
#include <cstdint>
#include <optional>
#include <span>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "penumbra/common/camera.h"
#include "penumbra/sma/hierarchy.h"
#include "penumbra/sma/refinement_driver.h"
#include "penumbra/sma/sample_cache.h"
#include "penumbra/sma/visibility.h"
#include "penumbra/wire.pb.h"

namespace penumbra::sma {

/// What an improvement lap walks: the view's visible nodes as the lap
/// begins, those covering the most pixels first (ties in node order). A lap
/// is often cut short -- the camera moves on, or other clients' work fills
/// the renderers -- and the image's error is per pixel: improving first what
/// fills most of the screen lowers it soonest (bench/walkthrough,
/// docs/refinement.md).
std::vector<NodeId> ImprovementLap(const VisibleSet& visible);

class ViewSession {
 public:
  using Clock = std::chrono::steady_clock;

  enum class Phase { kAwaitingHello, kNoView, kTracing, kShading, kRefining, kConverged };
  enum class Job { kNone, kNewView, kRefresh };
  enum class Remap { kNone, kDue, kArmed, kArmedIdle };

  /// `improvementOn`: the SMA improves shown samples (--improve-paths > 0).
  ViewSession(RefinementParams params, uint64_t maxRefinementSamplesPerView, bool improvementOn);

  Phase CurrentPhase() const;
  Job RunningJob() const { return job_; }
  Remap RemapState() const { return remap_; }
  bool AwaitingDrain() const { return awaitingDrain_; }

  // --- Handshake ------------------------------------------------------------
  /// False: a second hello.
  bool OnHello();
  bool Handshook() const { return handshook_; }

  // --- Views and their jobs -------------------------------------------------
  /// View ids must increase.
  bool Accepts(uint64_t viewId) const { return !hasView_ || viewId > viewId_; }
  /// A new view supersedes the old: its refinement and improvement restart;
  /// a running job's result will be dropped (OnJobDone).
  void OnNewView(uint64_t viewId, const CameraView& view, Clock::time_point now);
  bool HasView() const { return hasView_; }
  uint64_t ViewId() const { return viewId_; }
  const CameraView& View() const { return view_; }
  uint64_t AppliedViewId() const { return appliedViewId_; }
  bool HasVisible() const { return hasVisible_; }
  Clock::time_point ViewReceived() const { return viewReceived_; }

  enum class JobStart { kNothing, kWaitForDrain, kNewView, kRefresh };
  /// Which job to start now, if any (no change of state). `blocked`: the
  /// client's queue is over its soft limit.
  JobStart NextJob(bool blocked) const;
  /// The job chosen by NextJob was posted: a refresh is no longer due.
  void OnJobStarted(JobStart job, Clock::time_point now);
  /// A job is posted but the latest view is not what it traces: when no job
  /// thread has taken it yet, the caller may make it trace the latest view
  /// instead (OnJobRetargeted) -- rather than let it run, drop its result,
  /// and only then queue the view's own job behind everyone else's.
  bool LatestViewWaitsForJob() const { return job_ != Job::kNone && (!hasVisible_ || appliedViewId_ != viewId_); }
  /// The posted job, not yet taken, now traces the latest view.
  void OnJobRetargeted() { job_ = Job::kNewView; }

  enum class JobOutcome {
    kDrop,        // superseded: drop the result, start the next job
    kApply,       // apply it
    kApplyStale,  // superseded, but applied (too many dropped in a row); start the next job after
  };
  struct JobDone {
    JobOutcome outcome;
    bool firstForView;  // the first visibility applied for this view (latency is recorded)
  };
  /// A job's result reached the strand. A client sending views faster than
  /// they are traced would otherwise never receive one: after
  /// kMaxNewViewsDroppedInARow new views dropped, a slightly older one is applied.
  JobDone OnJobDone(uint64_t viewId, bool newView);
  static constexpr int kMaxNewViewsDroppedInARow = 3;

  // --- Stage 1: the view's own samples --------------------------------------
  /// The applied visibility's plan: `pending` nodes wait for their unshaded
  /// corners. Caller holds the state lock (shared). Returns the pending
  /// nodes whose corners were all stored since the plan was made (samples
  /// are stored without the state lock): the caller sends them as cached.
  std::vector<NodeId> BeginShading(std::span<const NodeId> pending, const Hierarchy& hierarchy,
                                   const SampleCache& cache, bool newView);
  struct Arrived {
    std::vector<NodeId> candidates;  // pending nodes one of whose corners arrived
    bool remapWanted = false;        // a midpoint arrived that may complete shown nodes' children
    /// An improvement this session waited for was answered by a first
    /// estimate: the wait is over, and only a new improvement look can
    /// ask again or find the lap done (no IMPROVED answer will call one).
    bool improveLookWanted = false;
  };
  /// Samples were stored. `baseVertices`: vertex ids below are base vertices.
  Arrived OnSamplesArrived(std::span<const VertexId> vertices, size_t baseVertices);
  /// Of `candidates`, the pending nodes now complete, removed from pending,
  /// sorted. Caller holds the state lock (shared).
  ///
  /// A candidate still incomplete waits again for each corner that is not
  /// shaded and not waited for: a corner that had arrived can have been
  /// invalidated or held back for a test by a move since (moves come at
  /// 10/s), and a re-map that finds the view unchanged plans nothing, so
  /// without this the node would wait for no sample, forever. Those corners
  /// are appended to `newlyAwaited` (when given) for the caller to ask for
  /// (a request for a vertex under test or already alive costs nothing).
  std::vector<NodeId> TakeReady(const std::vector<NodeId>& candidates, const Hierarchy& hierarchy,
                                const SampleCache& cache, std::vector<VertexId>* newlyAwaited = nullptr);
  bool Stage1Done() const {
    return hasVisible_ && appliedViewId_ == viewId_ && job_ == Job::kNone && waiting_.empty() && pending_.empty();
  }
  /// Stage 1 was reached just now: its time since the view (once per view).
  std::optional<double> NoteStage1(Clock::time_point now);

  // --- Re-maps (refresh of the applied view) --------------------------------
  /// A re-map is wanted (a split's samples arrived, or the client caught up).
  void WantRemap();
  bool RemapWanted() const { return remap_ == Remap::kDue || remap_ == Remap::kArmed; }
  enum class RemapAction { kNothing, kStartNow, kArmTimer };
  /// Throttled to one per `interval`: start now, or arm the timer for
  /// `*due` (then RemapState() is kArmed).
  RemapAction ScheduleRemap(Clock::time_point now, Clock::duration interval, Clock::time_point* due);
  enum class TimerAction { kNothing, kReschedule, kStartJob };
  /// The re-map timer fired (or was cancelled).
  TimerAction OnRemapTimer(bool cancelled);

  // --- Waiting for the client to read ---------------------------------------
  /// The applied mapping was planned but its changes were held back: the
  /// client is behind, and the refresh after its queue drains sends them.
  /// Until then the client does not hold the view, so it is not converged,
  /// whatever the samples say -- a status sent between the drain and that
  /// (throttled) refresh once told a client "converged" over an empty mesh.
  void OnPlanHeldBack() { planOwed_ = true; }
  /// The applied mapping's changes were queued for the client.
  void OnPlanQueued() { planOwed_ = false; }
  bool PlanOwed() const { return planOwed_; }
  /// True when the caller should ask the connection for a drain callback
  /// (false: already waiting).
  bool BeginDrainWait();
  /// The queue drained at `now`: what built up goes. A new view held back
  /// starts at once (kStartNow); a refresh keeps its throttle, one per
  /// `interval` since the last (kStartNow, or kArmTimer for `*due`) -- a
  /// client that reads in bursts would otherwise get a re-map per burst.
  RemapAction OnDrained(Clock::time_point now, Clock::duration interval, Clock::time_point* due);

  // --- Refinement (stage 2) -------------------------------------------------
  RefinementDriver& Refinement() { return driver_; }
  const RefinementDriver& Refinement() const { return driver_; }
  /// New options: refinement (and improvement) restart on the current view.
  void SetRefinementParams(const RefinementParams& params);
  enum class RefineStart { kNothing, kWaitForDrain, kStep, kCapReached };
  RefineStart NextRefinement(bool blocked);
  /// The Select of a step starting now may not conclude the view is done:
  /// splits await samples or a re-map is due.
  bool RefinementOutstanding() const { return driver_.Outstanding(remap_ != Remap::kNone); }
  /// A step's result; see RefinementDriver::OnStepDone. Caller holds the
  /// state lock (shared).
  RefinementDriver::After OnRefineStepDone(RefinementStep step, const SampleCache& cache);

  // --- Improvement (stage 2) ------------------------------------------------
  enum class ImproveStart { kNothing, kWaitForDrain, kLook };
  /// `batch`: improvements kept in flight; more are looked for once half came back.
  ImproveStart NextImprovement(bool blocked, size_t batch) const;
  bool ImprovementPending(VertexId v) const { return improvePending_.contains(v); }
  size_t ImprovementsPending() const { return improvePending_.size(); }
  /// Where the next look starts in the view's visible-node list. Looks
  /// walk the list in laps, each going on from where the last stopped, so
  /// the looks that follow improved batches share one walk of the list
  /// instead of making one each (a whole walk per batch had starved a
  /// client's strand with two I/O threads: docs/performance.md).
  size_t ImproveScanPosition() const { return improveScanPosition_; }
  /// What comes after an improvement look (OnImprovementsAsked).
  enum class AfterLook {
    /// end < count: the next look goes on from `end` (the caller knows
    /// whether it stopped at its walk's bound or at a full batch).
    kLapGoesOn,
    /// The lap is over and answers are out: each that comes back calls for a look.
    kAwaitAnswers,
    /// The lap is over, it asked something, and all of it is back already:
    /// nothing else will call for the next lap, so the caller looks now.
    kLookAgain,
    /// A whole lap asked nothing and nothing is pending: improvement of this
    /// view is done (the status changed).
    kDone,
  };
  /// The look asked `asked`, having walked the visible nodes up to `end` of
  /// `count` (`end == count`: the lap is over, the next look starts at the
  /// first node).
  AfterLook OnImprovementsAsked(std::span<const VertexId> asked, size_t end, size_t count);
  void OnImprovementsAnswered(std::span<const VertexId> answered);
  /// What is displayed changed: look for improvements again, from the first node.
  void DisplayChanged() { RestartImprovementScan(); }

  // --- Moves (issue 14) -----------------------------------------------------
  /// The scene moved: `reshades` -- vertices the client holds whose samples
  /// the move invalidated, asked for again -- are awaited (the view is not
  /// converged until they arrived or the client let them go), and
  /// refinement and improvement look at the view again.
  void OnSceneMoved(std::span<const VertexId> reshades);
  /// Forgets awaited reshades of vertices `stillHeld` says the client no
  /// longer holds.
  template <class StillHeld>
  void PruneReshades(StillHeld stillHeld) {
    std::erase_if(reshadesAwaited_, [&](VertexId v) { return !stillHeld(v); });
  }
  size_t ReshadesAwaited() const { return reshadesAwaited_.size(); }

  // --- Status ---------------------------------------------------------------
  bool RefinementDone() const { return driver_.Finished() && !RemapWanted(); }
  bool ImprovementDone() const { return !improvementOn_ || (improvementDone_ && improvePending_.empty()); }
  bool Converged() const {
    return Stage1Done() && RefinementDone() && ImprovementDone() && reshadesAwaited_.empty() && !planOwed_;
  }
  bool RefiningNow() const { return Stage1Done() && !Converged() && (driver_.Enabled() || improvementOn_); }
  /// Fills a delta's status fields (view id, pending, converged, refining,
  /// progress). `last`: no delta of this event follows, so it may say
  /// converged. Returns the view's time to convergence the first time it does.
  std::optional<double> FillStatus(wire::Delta& delta, bool last, size_t renderers, Clock::time_point now);
  /// The client's last word on this view (converged, refining) is out of date.
  bool StatusOutdated() const {
    return hasVisible_ && (Converged() != sentConverged_ || RefiningNow() != sentRefining_);
  }
  /// The client was told another renderer count.
  bool RenderersOutdated(size_t renderers) const { return hasVisible_ && renderers != sentRenderers_; }

  size_t PendingNodes() const { return pending_.size(); }
  size_t WaitingSamples() const { return waiting_.size(); }
  double Stage1Ms() const { return stage1Ms_; }
  double Stage2Ms() const { return stage2Ms_; }

 private:
  // `sameView`: a move lit it anew; its refinement keeps counting against its cap.
  void RestartRefinement(bool sameView = false);

  bool handshook_ = false;
  bool hasView_ = false;
  bool hasVisible_ = false;       // some view's visibility is applied
  uint64_t viewId_ = 0;           // newest view received
  uint64_t appliedViewId_ = 0;    // view whose visibility is applied
  CameraView view_;
  Clock::time_point viewReceived_;
  Job job_ = Job::kNone;
  Remap remap_ = Remap::kNone;
  Clock::time_point lastRemap_;
  bool awaitingDrain_ = false;
  bool planOwed_ = false;  // OnPlanHeldBack
  int newViewsDroppedInARow_ = 0;

  std::unordered_set<NodeId> pending_;                         // visible, waiting for samples
  std::unordered_map<VertexId, std::vector<NodeId>> waiting_;  // missing vertex -> pending nodes
  size_t stage1Total_ = 0;
  size_t stage1Done_ = 0;
  double stage1Ms_ = -1.0;  // view received -> stage 1 done
  double stage2Ms_ = -1.0;  // view received -> converged

  RefinementDriver driver_;
  bool improvementOn_;
  bool improvementDone_ = false;
  std::unordered_set<VertexId> improvePending_;  // asked for, not answered
  size_t improveScanPosition_ = 0;  // in the visible-node list
  size_t improveLapAsked_ = 0;      // asked since the lap began
  void RestartImprovementScan() {
    improvementDone_ = false;
    improveScanPosition_ = 0;
    improveLapAsked_ = 0;
  }
  std::unordered_set<VertexId> reshadesAwaited_;  // held, invalidated by a move, asked again

  bool sentConverged_ = false;  // as the last delta sent said
  bool sentRefining_ = false;
  size_t sentRenderers_ = 0;
};

}  // namespace penumbra::sma

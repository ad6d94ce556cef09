#include "penumbra/sma/view_session.h"

#include <algorithm>

#include "penumbra/common/check.h"
#include "penumbra/common/duration.h"

namespace penumbra::sma {

ViewSession::ViewSession(RefinementParams params, uint64_t maxRefinementSamplesPerView, bool improvementOn)
    : driver_(params, maxRefinementSamplesPerView), improvementOn_(improvementOn) {}

ViewSession::Phase ViewSession::CurrentPhase() const {
  if (!handshook_) return Phase::kAwaitingHello;
  if (!hasView_) return Phase::kNoView;
  if (!hasVisible_ || appliedViewId_ != viewId_) return Phase::kTracing;
  if (!Stage1Done()) return Phase::kShading;
  return Converged() ? Phase::kConverged : Phase::kRefining;
}

bool ViewSession::OnHello() {
  if (handshook_) return false;
  handshook_ = true;
  return true;
}

void ViewSession::OnNewView(uint64_t viewId, const CameraView& view, Clock::time_point now) {
  hasView_ = true;
  viewId_ = viewId;
  view_ = view;
  viewReceived_ = now;
  stage1Ms_ = stage2Ms_ = -1.0;
  RestartRefinement();
}

void ViewSession::RestartRefinement(bool sameView) {
  if (sameView) driver_.RestartSameView();
  else driver_.Restart();
  RestartImprovementScan();
  improvePending_.clear();
}

ViewSession::JobStart ViewSession::NextJob(bool blocked) const {
  if (job_ != Job::kNone || !hasView_) return JobStart::kNothing;
  const bool newView = !hasVisible_ || appliedViewId_ != viewId_;
  if (!newView && !RemapWanted()) return JobStart::kNothing;
  // No work for a client that cannot take its results (four clients that
  // never read once cost 1.8 cores): its latest view is traced, or the
  // refresh made, once its queue drains.
  if (blocked) return JobStart::kWaitForDrain;
  return newView ? JobStart::kNewView : JobStart::kRefresh;
}

void ViewSession::OnJobStarted(JobStart job, Clock::time_point now) {
  job_ = job == JobStart::kNewView ? Job::kNewView : Job::kRefresh;
  // The job re-maps: a re-map that was due is made by it (an armed timer
  // will find nothing to do).
  if (remap_ == Remap::kDue) remap_ = Remap::kNone;
  if (remap_ == Remap::kArmed) remap_ = Remap::kArmedIdle;
  lastRemap_ = now;
}

ViewSession::JobDone ViewSession::OnJobDone(uint64_t viewId, bool newView) {
  job_ = Job::kNone;
  // Superseded while it ran: dropped, and the latest view traced -- unless
  // the last few new views were dropped too. A client sending views faster
  // than they are traced would otherwise never receive one, and one that
  // never reads would cost a trace per view without its queue ever backing
  // up (issue 12).
  const bool stale = viewId != viewId_;
  if (stale && (!newView || ++newViewsDroppedInARow_ < kMaxNewViewsDroppedInARow))
    return {JobOutcome::kDrop, false};
  if (newView) newViewsDroppedInARow_ = 0;
  const bool first = (appliedViewId_ != viewId || !hasVisible_) && !stale;
  appliedViewId_ = viewId;
  hasVisible_ = true;
  return {stale ? JobOutcome::kApplyStale : JobOutcome::kApply, first};
}

std::vector<NodeId> ViewSession::BeginShading(std::span<const NodeId> pending, const Hierarchy& hierarchy,
                                              const SampleCache& cache, bool newView) {
  RestartImprovementScan();  // what is displayed changed: look again
  pending_.clear();
  waiting_.clear();
  std::vector<NodeId> complete;
  for (NodeId id : pending) {
    bool waits = false;
    for (VertexId v : hierarchy.GetNode(id).v) {
      if (cache.IsShaded(v)) continue;
      waiting_[v].push_back(id);
      waits = true;
    }
    // Samples are stored without the state lock: a node's corners may have
    // arrived since PlanView, their notice already queued behind us and
    // looking for waiters it will not find. The caller sends it now instead.
    if (waits) pending_.insert(id);
    else complete.push_back(id);
  }
  if (newView) stage1Done_ = 0;
  stage1Total_ = stage1Done_ + waiting_.size();
  return complete;
}

ViewSession::Arrived ViewSession::OnSamplesArrived(std::span<const VertexId> vertices, size_t baseVertices) {
  Arrived out;
  std::unordered_set<NodeId> candidates;
  for (VertexId v : vertices) {
    driver_.OnSampleArrived(v);
    reshadesAwaited_.erase(v);
    // A new sample of a vertex whose improvement this session asked for
    // ends the wait as an improvement would: the pool keeps one request per
    // vertex, so an improvement asked while a first estimate was alive (a
    // reshade, a prepared sample stored before its visible request came
    // back) is answered by that estimate, never as IMPROVED -- and the view
    // would never converge. The next lap asks again if it is still noisy --
    // and that lap must be looked for now: no IMPROVED answer will ask for
    // it, and with nothing else pending the session would wait forever
    // (seen with sessions and the I/O thread on different threads, where a
    // look can find a vertex stored but not yet completed in the pool).
    if (improvePending_.erase(v) > 0) out.improveLookWanted = true;
    auto it = waiting_.find(v);
    if (it == waiting_.end()) {
      // A midpoint this client was not waiting for may complete the children
      // of a node it shows: re-map (throttled) to pick them up.
      out.remapWanted |= v >= baseVertices;
      continue;
    }
    candidates.insert(it->second.begin(), it->second.end());
    waiting_.erase(it);
    ++stage1Done_;
  }
  out.candidates.assign(candidates.begin(), candidates.end());
  return out;
}

std::vector<NodeId> ViewSession::TakeReady(const std::vector<NodeId>& candidates, const Hierarchy& hierarchy,
                                           const SampleCache& cache, std::vector<VertexId>* newlyAwaited) {
  std::vector<NodeId> ready;
  for (NodeId id : candidates) {
    if (!pending_.contains(id)) continue;
    const Node& node = hierarchy.GetNode(id);
    if (CornersShaded(node, cache)) {
      ready.push_back(id);
      continue;
    }
    for (VertexId v : node.v) {
      if (cache.IsShaded(v)) continue;
      std::vector<NodeId>& waiters = waiting_[v];
      if (std::find(waiters.begin(), waiters.end(), id) != waiters.end()) continue;
      if (waiters.empty()) {
        ++stage1Total_;
        if (newlyAwaited) newlyAwaited->push_back(v);
      }
      waiters.push_back(id);
    }
  }
  std::sort(ready.begin(), ready.end());
  for (NodeId id : ready) pending_.erase(id);
  return ready;
}

std::optional<double> ViewSession::NoteStage1(Clock::time_point now) {
  if (stage1Ms_ >= 0.0 || !Stage1Done()) return std::nullopt;
  stage1Ms_ = Milliseconds(now - viewReceived_);
  return stage1Ms_;
}

void ViewSession::WantRemap() {
  if (remap_ == Remap::kNone) remap_ = Remap::kDue;
  if (remap_ == Remap::kArmedIdle) remap_ = Remap::kArmed;
}

ViewSession::RemapAction ViewSession::ScheduleRemap(Clock::time_point now, Clock::duration interval,
                                                    Clock::time_point* due) {
  if (remap_ != Remap::kDue) return RemapAction::kNothing;  // nothing wanted, or a timer is armed
  *due = lastRemap_ + interval;
  if (now >= *due && job_ == Job::kNone) return RemapAction::kStartNow;
  remap_ = Remap::kArmed;
  return RemapAction::kArmTimer;
}

ViewSession::TimerAction ViewSession::OnRemapTimer(bool cancelled) {
  if (remap_ == Remap::kArmed) remap_ = Remap::kDue;
  if (remap_ == Remap::kArmedIdle) remap_ = Remap::kNone;
  if (cancelled) return TimerAction::kNothing;
  if (job_ != Job::kNone) return TimerAction::kReschedule;  // try again after the running job
  return TimerAction::kStartJob;
}

bool ViewSession::BeginDrainWait() {
  if (awaitingDrain_) return false;
  awaitingDrain_ = true;
  return true;
}

ViewSession::RemapAction ViewSession::OnDrained(Clock::time_point now, Clock::duration interval,
                                                Clock::time_point* due) {
  awaitingDrain_ = false;
  WantRemap();
  if (NextJob(/*blocked=*/false) == JobStart::kNewView) return RemapAction::kStartNow;
  return ScheduleRemap(now, interval, due);
}

void ViewSession::OnSceneMoved(std::span<const VertexId> reshades) {
  reshadesAwaited_.insert(reshades.begin(), reshades.end());
  // Lighting changed: what was converged may now be worth splitting (the
  // criteria split where it changed) or improving -- within what is left
  // of this view's sample cap.
  if (hasVisible_) RestartRefinement(/*sameView=*/true);
}

void ViewSession::SetRefinementParams(const RefinementParams& params) {
  driver_.SetParams(params);
  RestartRefinement();
}

ViewSession::RefineStart ViewSession::NextRefinement(bool blocked) {
  if (!driver_.WantsStep(Stage1Done())) return RefineStart::kNothing;
  if (blocked) return RefineStart::kWaitForDrain;  // resumed by the refresh on drain
  switch (driver_.StartStep(Stage1Done())) {
    case RefinementDriver::Start::kStep:
      return RefineStart::kStep;
    case RefinementDriver::Start::kCapReached:
      return RefineStart::kCapReached;
    case RefinementDriver::Start::kNothing:
      break;
  }
  return RefineStart::kNothing;
}

RefinementDriver::After ViewSession::OnRefineStepDone(RefinementStep step, const SampleCache& cache) {
  // A re-map due, armed or running will call for the next step when it ends.
  return driver_.OnStepDone(std::move(step), cache, remap_ != Remap::kNone || job_ != Job::kNone);
}

ViewSession::ImproveStart ViewSession::NextImprovement(bool blocked, size_t batch) const {
  if (!improvementOn_ || improvementDone_ || !Stage1Done()) return ImproveStart::kNothing;
  if (blocked) return ImproveStart::kWaitForDrain;  // resumed by the refresh on drain
  // Keep about a batch in flight: look for more once half of it is back.
  if (improvePending_.size() > batch / 2) return ImproveStart::kNothing;
  return ImproveStart::kLook;
}

ViewSession::AfterLook ViewSession::OnImprovementsAsked(std::span<const VertexId> asked, size_t end, size_t count) {
  PENUMBRA_CHECK(end <= count, "an improvement look walked past the visible nodes");
  improvePending_.insert(asked.begin(), asked.end());
  improveLapAsked_ += asked.size();
  improveScanPosition_ = end;
  if (end < count) return AfterLook::kLapGoesOn;
  // The lap is over. Done only when all of it asked nothing and nothing is
  // out: an answer still pending may come back noisy and be asked again.
  const bool askedSome = improveLapAsked_ > 0;
  improveScanPosition_ = 0;
  improveLapAsked_ = 0;
  if (!improvePending_.empty()) return AfterLook::kAwaitAnswers;
  // Everything this lap asked came back before it ended (a lap of several
  // looks, answers on other threads): no answer is left to call for the
  // next lap, which must start now or the view never converges.
  if (askedSome) return AfterLook::kLookAgain;
  improvementDone_ = true;
  return AfterLook::kDone;
}

void ViewSession::OnImprovementsAnswered(std::span<const VertexId> answered) {
  for (VertexId v : answered) improvePending_.erase(v);
}

std::optional<double> ViewSession::FillStatus(wire::Delta& delta, bool last, size_t renderers,
                                              Clock::time_point now) {
  delta.set_view_id(appliedViewId_);
  delta.set_pending_samples(uint32_t(waiting_.size() + driver_.PendingSamples() + reshadesAwaited_.size()));
  const bool converged = last && Converged();
  delta.set_converged(converged);
  delta.set_refining(!converged && RefiningNow());
  // Progress for the people waiting (issue 16).
  sentRenderers_ = renderers;
  delta.set_renderers_connected(uint32_t(renderers));
  delta.set_stage1_samples_total(uint32_t(stage1Total_));
  delta.set_stage1_samples_done(uint32_t(std::min(stage1Done_, stage1Total_)));
  delta.set_refinement_samples_total(uint32_t(driver_.SamplesTotal()));
  delta.set_refinement_samples_done(uint32_t(driver_.SamplesDone()));
  sentConverged_ = converged;
  sentRefining_ = delta.refining();
  if (!converged || stage2Ms_ >= 0.0) return std::nullopt;
  stage2Ms_ = Milliseconds(now - viewReceived_);
  return stage2Ms_;
}

std::vector<NodeId> ImprovementLap(const VisibleSet& visible) {
  PENUMBRA_CHECK(visible.coverage.size() == visible.nodes.size(),
                 "ImprovementLap: the visible set's coverage must be parallel to its nodes");
  std::vector<uint32_t> order(visible.nodes.size());
  for (uint32_t i = 0; i < order.size(); ++i) order[i] = i;
  // Stable: equal coverage keeps node order (the nodes are sorted).
  std::stable_sort(order.begin(), order.end(),
                   [&](uint32_t a, uint32_t b) { return visible.coverage[a] > visible.coverage[b]; });
  std::vector<NodeId> lap;
  lap.reserve(order.size());
  for (uint32_t i : order) lap.push_back(visible.nodes[i]);
  return lap;
}

}  // namespace penumbra::sma

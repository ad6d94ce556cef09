// The view session's state machine (view_session.h) without sockets: what a
// client's session does next at each event.

#include "penumbra/sma/view_session.h"

#include <algorithm>

#include <gtest/gtest.h>

namespace penumbra::sma {
namespace {

using Phase = ViewSession::Phase;
using JobStart = ViewSession::JobStart;
using Clock = ViewSession::Clock;
using namespace std::chrono_literals;

Scene QuadScene() {
  SceneBuilder b;
  Material m;
  m.albedo = Rgb(0.5f);
  b.AddQuad(Vec3(0, 0, 0), Vec3(0, 0, 1), Vec3(1, 0, 0), b.AddMaterial(m));
  Scene s;
  s.twoSided = false;
  EXPECT_TRUE(b.BuildInto(s).ok());
  return s;
}

struct SessionFixture {
  Scene scene = QuadScene();
  Hierarchy hierarchy{scene};
  SampleCache cache;
  Clock::time_point now = Clock::now();
  CameraView view;

  SessionFixture() {
    cache.Reserve(hierarchy.VertexCount());
    view.width = view.height = 8;
  }
  std::vector<NodeId> Roots() const {
    std::vector<NodeId> roots;
    for (NodeId r = 0; r < hierarchy.RootCount(); ++r) roots.push_back(r);
    return roots;
  }
  std::vector<VertexId> Shade() {
    std::vector<ShadedSample> samples;
    std::vector<VertexId> vertices;
    for (VertexId v = 0; v < hierarchy.VertexCount(); ++v)
      if (!cache.IsShaded(v)) {
        samples.push_back(ShadedSample{v, Rgb(0.1f), Rgb(1.0f)});
        vertices.push_back(v);
      }
    cache.Store(samples);
    return vertices;
  }
  // Hello, a view, its job run and applied with every root pending.
  void ToShading(ViewSession& s, uint64_t viewId = 1) {
    if (!s.Handshook()) s.OnHello();
    s.OnNewView(viewId, view, now);
    ASSERT_EQ(s.NextJob(false), JobStart::kNewView);
    s.OnJobStarted(JobStart::kNewView, now);
    ASSERT_EQ(s.OnJobDone(viewId, true).outcome, ViewSession::JobOutcome::kApply);
    s.BeginShading(Roots(), hierarchy, cache, true);
  }
  // The view's samples arrive: its nodes are ready.
  void ToStage2(ViewSession& s) {
    const auto arrived = s.OnSamplesArrived(Shade(), hierarchy.BaseVertexCount());
    EXPECT_FALSE(arrived.remapWanted);  // base vertices only
    EXPECT_EQ(s.TakeReady(arrived.candidates, hierarchy, cache), Roots());
  }
};

RefinementParams NoRefinement() {
  RefinementParams p;
  p.criterion = Criterion::kNone;
  return p;
}

TEST(ViewSessionTest, GoesThroughItsPhasesToConvergence) {
  SessionFixture f;
  ViewSession s(NoRefinement(), 1000, /*improvementOn=*/false);
  EXPECT_EQ(s.CurrentPhase(), Phase::kAwaitingHello);
  EXPECT_TRUE(s.OnHello());
  EXPECT_FALSE(s.OnHello());  // a second hello
  EXPECT_EQ(s.CurrentPhase(), Phase::kNoView);
  EXPECT_EQ(s.NextJob(false), JobStart::kNothing);
  EXPECT_TRUE(s.Accepts(0));
  s.OnNewView(4, f.view, f.now);
  EXPECT_FALSE(s.Accepts(4));  // ids must increase
  EXPECT_TRUE(s.Accepts(5));
  EXPECT_EQ(s.CurrentPhase(), Phase::kTracing);
  EXPECT_EQ(s.NextJob(/*blocked=*/true), JobStart::kWaitForDrain);
  EXPECT_EQ(s.NextJob(false), JobStart::kNewView);
  s.OnJobStarted(JobStart::kNewView, f.now);
  EXPECT_EQ(s.RunningJob(), ViewSession::Job::kNewView);
  EXPECT_EQ(s.NextJob(false), JobStart::kNothing);  // one job at a time
  const auto done = s.OnJobDone(4, true);
  EXPECT_EQ(done.outcome, ViewSession::JobOutcome::kApply);
  EXPECT_TRUE(done.firstForView);
  s.BeginShading(f.Roots(), f.hierarchy, f.cache, true);
  EXPECT_EQ(s.CurrentPhase(), Phase::kShading);
  EXPECT_FALSE(s.Stage1Done());
  EXPECT_EQ(s.WaitingSamples(), f.hierarchy.BaseVertexCount());  // the quad's corners
  EXPECT_FALSE(s.NoteStage1(f.now));

  f.ToStage2(s);
  EXPECT_TRUE(s.Stage1Done());
  EXPECT_TRUE(s.NoteStage1(f.now + 30ms).has_value());
  EXPECT_FALSE(s.NoteStage1(f.now + 40ms));  // once per view
  EXPECT_DOUBLE_EQ(s.Stage1Ms(), 30.0);
  // No refinement, no improvement: converged as soon as stage 1 is done.
  EXPECT_EQ(s.CurrentPhase(), Phase::kConverged);
  EXPECT_TRUE(s.StatusOutdated());
  wire::Delta delta;
  const auto converged = s.FillStatus(delta, /*last=*/true, 2, f.now + 50ms);
  ASSERT_TRUE(converged.has_value());
  EXPECT_DOUBLE_EQ(*converged, 50.0);
  EXPECT_TRUE(delta.converged());
  EXPECT_FALSE(delta.refining());
  EXPECT_EQ(delta.view_id(), 4u);
  EXPECT_EQ(delta.stage1_samples_total(), f.hierarchy.BaseVertexCount());
  EXPECT_EQ(delta.stage1_samples_done(), f.hierarchy.BaseVertexCount());
  EXPECT_EQ(delta.renderers_connected(), 2u);
  EXPECT_FALSE(s.StatusOutdated());
  EXPECT_FALSE(s.RenderersOutdated(2));
  EXPECT_TRUE(s.RenderersOutdated(1));
  EXPECT_EQ(s.NextJob(false), JobStart::kNothing);

  // A new view starts over.
  s.OnNewView(5, f.view, f.now);
  EXPECT_EQ(s.CurrentPhase(), Phase::kTracing);
  EXPECT_EQ(s.NextJob(false), JobStart::kNewView);
}

// A move invalidates (or holds back for a test) a corner that had already
// arrived, then the node's last corner arrives: the node must wait for the
// first corner again -- nothing else would ever complete it, since a re-map
// that finds the same view plans nothing (a view stalled short of stage 1
// with no sample awaited, seen in bench/move_bench's 10 moves/s phase).
TEST(ViewSessionTest, ACornerAMoveTookBackIsAwaitedAgain) {
  SessionFixture f;
  ViewSession s(NoRefinement(), 1000, /*improvementOn=*/false);
  s.OnHello();
  s.OnNewView(1, f.view, f.now);
  ASSERT_EQ(s.NextJob(false), JobStart::kNewView);
  s.OnJobStarted(JobStart::kNewView, f.now);
  ASSERT_EQ(s.OnJobDone(1, true).outcome, ViewSession::JobOutcome::kApply);
  const std::vector<NodeId> roots = f.Roots();
  s.BeginShading(roots, f.hierarchy, f.cache, true);
  const Node& root = f.hierarchy.GetNode(roots[0]);
  // Every corner of the scene but root's third arrives.
  std::vector<ShadedSample> first;
  std::vector<VertexId> firstIds;
  for (VertexId v = 0; v < f.hierarchy.VertexCount(); ++v)
    if (v != root.v[2]) {
      first.push_back(ShadedSample{v, Rgb(0.1f), Rgb(1.0f)});
      firstIds.push_back(v);
    }
  f.cache.Store(first);
  auto arrived = s.OnSamplesArrived(firstIds, f.hierarchy.BaseVertexCount());
  std::vector<VertexId> again;
  auto ready = s.TakeReady(arrived.candidates, f.hierarchy, f.cache, &again);
  EXPECT_TRUE(std::find(ready.begin(), ready.end(), roots[0]) == ready.end());
  EXPECT_TRUE(again.empty()) << "only the third corner is missing, and it is awaited already";
  // A move takes the first corner back; then the third corner arrives.
  ASSERT_TRUE(f.cache.Invalidate(root.v[0], 1));
  f.cache.Store(std::vector<ShadedSample>{ShadedSample{root.v[2], Rgb(0.1f), Rgb(1.0f), 0.0f, 1, 0, 1}});
  arrived = s.OnSamplesArrived(std::vector<VertexId>{root.v[2]}, f.hierarchy.BaseVertexCount());
  ready = s.TakeReady(arrived.candidates, f.hierarchy, f.cache, &again);
  EXPECT_TRUE(std::find(ready.begin(), ready.end(), roots[0]) == ready.end());
  EXPECT_EQ(again, std::vector<VertexId>{root.v[0]}) << "the corner taken back is asked for again";
  EXPECT_FALSE(s.Stage1Done());
  EXPECT_GE(s.WaitingSamples(), 1u) << "the node waits for a sample, not for nothing";
  // Its reshade arrives: the node is ready and stage 1 ends.
  f.cache.Store(std::vector<ShadedSample>{ShadedSample{root.v[0], Rgb(0.1f), Rgb(1.0f), 0.0f, 1, 0, 1}});
  arrived = s.OnSamplesArrived(std::vector<VertexId>{root.v[0]}, f.hierarchy.BaseVertexCount());
  again.clear();
  ready = s.TakeReady(arrived.candidates, f.hierarchy, f.cache, &again);
  EXPECT_TRUE(std::find(ready.begin(), ready.end(), roots[0]) != ready.end());
  EXPECT_TRUE(again.empty());
}

TEST(ViewSessionTest, AStatusThatWasNotTheLastDeltaNeverSaysConverged) {
  SessionFixture f;
  ViewSession s(NoRefinement(), 1000, false);
  f.ToShading(s);
  f.ToStage2(s);
  wire::Delta delta;
  EXPECT_FALSE(s.FillStatus(delta, /*last=*/false, 1, f.now));
  EXPECT_FALSE(delta.converged());
  EXPECT_TRUE(s.StatusOutdated());  // so a STATUS follows
}

// A client behind on reading: the view's plan is made but held back until
// its queue drains. Its samples may all be in meanwhile (another client's
// view shaded them): the client holds nothing of the view yet, so no
// status may say converged -- one sent between the drain and the throttled
// refresh did, over an empty mesh (SmaSlowClientTest, once in CI).
TEST(ViewSessionTest, APlanHeldBackHoldsConvergenceUntilItIsQueued) {
  SessionFixture f;
  ViewSession s(NoRefinement(), 1000, false);
  f.ToShading(s);
  s.OnPlanHeldBack();
  f.ToStage2(s);
  EXPECT_TRUE(s.Stage1Done());
  EXPECT_TRUE(s.PlanOwed());
  EXPECT_FALSE(s.Converged());
  EXPECT_NE(s.CurrentPhase(), Phase::kConverged);
  wire::Delta early;
  s.FillStatus(early, /*last=*/true, 1, f.now);
  EXPECT_FALSE(early.converged());
  EXPECT_FALSE(s.StatusOutdated());
  s.OnPlanQueued();  // the refresh after the drain sends the plan
  EXPECT_TRUE(s.Converged());
  EXPECT_TRUE(s.StatusOutdated());  // so its last delta, or a STATUS, says so
  wire::Delta sent;
  s.FillStatus(sent, /*last=*/true, 1, f.now);
  EXPECT_TRUE(sent.converged());
}

TEST(ViewSessionTest, AQueuedJobRetargetedToTheLatestViewAppliesIt) {
  SessionFixture f;
  ViewSession s(NoRefinement(), 1000, false);
  s.OnHello();
  s.OnNewView(1, f.view, f.now);
  EXPECT_FALSE(s.LatestViewWaitsForJob());  // no job yet: NextJob starts one
  s.OnJobStarted(JobStart::kNewView, f.now);
  EXPECT_TRUE(s.LatestViewWaitsForJob());  // the view is not applied yet: the job is for it
  ASSERT_EQ(s.OnJobDone(1, true).outcome, ViewSession::JobOutcome::kApply);
  s.BeginShading({}, f.hierarchy, f.cache, true);
  EXPECT_FALSE(s.LatestViewWaitsForJob());
  // A refresh is queued; the client sends a new view before a job thread
  // takes it: the refresh traces the new view instead.
  s.WantRemap();
  ASSERT_EQ(s.NextJob(false), JobStart::kRefresh);
  s.OnJobStarted(JobStart::kRefresh, f.now);
  EXPECT_FALSE(s.LatestViewWaitsForJob());
  s.OnNewView(2, f.view, f.now);
  EXPECT_TRUE(s.LatestViewWaitsForJob());
  EXPECT_EQ(s.NextJob(false), JobStart::kNothing);  // still one job at a time
  s.OnJobRetargeted();
  EXPECT_EQ(s.RunningJob(), ViewSession::Job::kNewView);
  const auto done = s.OnJobDone(2, true);
  EXPECT_EQ(done.outcome, ViewSession::JobOutcome::kApply);
  EXPECT_TRUE(done.firstForView);
  EXPECT_EQ(s.AppliedViewId(), 2u);
  EXPECT_FALSE(s.LatestViewWaitsForJob());
  EXPECT_EQ(s.NextJob(false), JobStart::kNothing);  // nothing superseded to trace again
}

TEST(ViewSessionTest, ASupersededResultIsDroppedUntilThreeInARow) {
  SessionFixture f;
  ViewSession s(NoRefinement(), 1000, false);
  s.OnHello();
  uint64_t id = 1;
  s.OnNewView(id, f.view, f.now);
  for (int dropped = 1; dropped < ViewSession::kMaxNewViewsDroppedInARow; ++dropped) {
    ASSERT_EQ(s.NextJob(false), JobStart::kNewView);
    s.OnJobStarted(JobStart::kNewView, f.now);
    s.OnNewView(++id, f.view, f.now);  // the client moved while it was traced
    EXPECT_EQ(s.OnJobDone(id - 1, true).outcome, ViewSession::JobOutcome::kDrop) << dropped;
    EXPECT_EQ(s.CurrentPhase(), Phase::kTracing);
  }
  ASSERT_EQ(s.NextJob(false), JobStart::kNewView);
  s.OnJobStarted(JobStart::kNewView, f.now);
  s.OnNewView(++id, f.view, f.now);
  // The third in a row is applied (a client sending views faster than they
  // are traced still gets some), and the latest is traced next.
  const auto done = s.OnJobDone(id - 1, true);
  EXPECT_EQ(done.outcome, ViewSession::JobOutcome::kApplyStale);
  EXPECT_FALSE(done.firstForView);
  EXPECT_EQ(s.AppliedViewId(), id - 1);
  EXPECT_EQ(s.NextJob(false), JobStart::kNewView);
  // A superseded refresh is simply dropped.
  s.OnJobStarted(JobStart::kNewView, f.now);
  EXPECT_EQ(s.OnJobDone(id, true).outcome, ViewSession::JobOutcome::kApply);
  s.WantRemap();
  ASSERT_EQ(s.NextJob(false), JobStart::kRefresh);
  s.OnJobStarted(JobStart::kRefresh, f.now);
  s.OnNewView(++id, f.view, f.now);
  EXPECT_EQ(s.OnJobDone(id - 1, false).outcome, ViewSession::JobOutcome::kDrop);
}

TEST(ViewSessionTest, RemapsAreThrottledAndATimerThatFindsItDoneDoesNothing) {
  SessionFixture f;
  ViewSession s(NoRefinement(), 1000, false);
  f.ToShading(s);
  f.ToStage2(s);
  const auto interval = 100ms;
  Clock::time_point due;
  EXPECT_EQ(s.ScheduleRemap(f.now, interval, &due), ViewSession::RemapAction::kNothing);  // none wanted
  s.WantRemap();
  EXPECT_TRUE(s.RemapWanted());
  EXPECT_FALSE(s.RefinementDone());  // a re-map owed may show more
  // The last job started at f.now: the re-map waits for the interval.
  EXPECT_EQ(s.ScheduleRemap(f.now + 10ms, interval, &due), ViewSession::RemapAction::kArmTimer);
  EXPECT_EQ(due, f.now + interval);
  EXPECT_EQ(s.RemapState(), ViewSession::Remap::kArmed);
  EXPECT_EQ(s.ScheduleRemap(f.now + 20ms, interval, &due), ViewSession::RemapAction::kNothing);  // armed already
  // Another path (the client caught up) runs the refresh before the timer.
  ASSERT_EQ(s.NextJob(false), JobStart::kRefresh);
  s.OnJobStarted(JobStart::kRefresh, f.now + 30ms);
  EXPECT_EQ(s.RemapState(), ViewSession::Remap::kArmedIdle);
  EXPECT_FALSE(s.RemapWanted());
  // The timer fires while that job runs: try again after it...
  EXPECT_EQ(s.OnRemapTimer(false), ViewSession::TimerAction::kReschedule);
  EXPECT_EQ(s.ScheduleRemap(f.now + 100ms, interval, &due), ViewSession::RemapAction::kNothing);  // nothing owed
  EXPECT_EQ(s.OnJobDone(1, false).outcome, ViewSession::JobOutcome::kApply);
  // ...and past the interval a wanted re-map starts at once.
  s.WantRemap();
  EXPECT_EQ(s.ScheduleRemap(f.now + 200ms, interval, &due), ViewSession::RemapAction::kStartNow);
  // A cancelled timer (the session closed) does nothing.
  s.OnJobStarted(JobStart::kRefresh, f.now + 200ms);
  s.WantRemap();
  EXPECT_EQ(s.ScheduleRemap(f.now + 210ms, interval, &due), ViewSession::RemapAction::kArmTimer);
  EXPECT_EQ(s.OnRemapTimer(/*cancelled=*/true), ViewSession::TimerAction::kNothing);
}

TEST(ViewSessionTest, ABlockedClientGetsNoWorkAndOneRefreshOnDrain) {
  SessionFixture f;
  RefinementParams p;  // NLD_OS
  ViewSession s(p, 1000, /*improvementOn=*/true);
  f.ToShading(s);
  f.ToStage2(s);
  EXPECT_EQ(s.CurrentPhase(), Phase::kRefining);
  EXPECT_EQ(s.NextRefinement(/*blocked=*/true), ViewSession::RefineStart::kWaitForDrain);
  EXPECT_EQ(s.NextImprovement(/*blocked=*/true, 64), ViewSession::ImproveStart::kWaitForDrain);
  EXPECT_TRUE(s.BeginDrainWait());
  EXPECT_FALSE(s.BeginDrainWait());  // one callback at a time
  EXPECT_TRUE(s.AwaitingDrain());
  // The last re-map (the view's job) was long enough ago: the refresh goes now.
  Clock::time_point due;
  EXPECT_EQ(s.OnDrained(f.now + 1s, 100ms, &due), ViewSession::RemapAction::kStartNow);
  EXPECT_FALSE(s.AwaitingDrain());
  EXPECT_TRUE(s.RemapWanted());
  EXPECT_EQ(s.NextJob(false), JobStart::kRefresh);
}

TEST(ViewSessionTest, ADrainKeepsTheRefreshThrottleButNotANewView) {
  SessionFixture f;
  ViewSession s(NoRefinement(), 1000, false);
  f.ToShading(s);  // its job re-mapped at f.now
  f.ToStage2(s);
  const auto interval = 100ms;
  Clock::time_point due;
  // A client reading in bursts drains 10 ms after the last re-map: the
  // refresh waits for the throttle's timer, it does not start at once.
  ASSERT_TRUE(s.BeginDrainWait());
  EXPECT_EQ(s.OnDrained(f.now + 10ms, interval, &due), ViewSession::RemapAction::kArmTimer);
  EXPECT_EQ(due, f.now + interval);
  EXPECT_EQ(s.RemapState(), ViewSession::Remap::kArmed);
  // A second drain while the timer is armed adds nothing.
  ASSERT_TRUE(s.BeginDrainWait());
  EXPECT_EQ(s.OnDrained(f.now + 20ms, interval, &due), ViewSession::RemapAction::kNothing);
  EXPECT_EQ(s.OnRemapTimer(false), ViewSession::TimerAction::kStartJob);
  EXPECT_EQ(s.NextJob(false), JobStart::kRefresh);
  s.OnJobStarted(JobStart::kRefresh, f.now + interval);
  ASSERT_EQ(s.OnJobDone(1, false).outcome, ViewSession::JobOutcome::kApply);
  // A new view held back by the full queue starts on the drain, throttle or not.
  s.OnNewView(2, f.view, f.now + interval + 1ms);
  ASSERT_TRUE(s.BeginDrainWait());
  EXPECT_EQ(s.OnDrained(f.now + interval + 2ms, interval, &due), ViewSession::RemapAction::kStartNow);
  EXPECT_EQ(s.NextJob(false), JobStart::kNewView);
}

TEST(ViewSessionTest, RefinementWaitsForStage1AndARunningJob) {
  SessionFixture f;
  RefinementParams p;
  ViewSession s(p, 1000, false);
  f.ToShading(s);
  EXPECT_EQ(s.NextRefinement(false), ViewSession::RefineStart::kNothing);  // stage 1 first
  f.ToStage2(s);
  EXPECT_TRUE(s.RefiningNow());
  EXPECT_EQ(s.CurrentPhase(), Phase::kRefining);
  s.WantRemap();
  ASSERT_EQ(s.NextJob(false), JobStart::kRefresh);
  s.OnJobStarted(JobStart::kRefresh, f.now);
  EXPECT_FALSE(s.Stage1Done());  // a re-map runs
  EXPECT_EQ(s.NextRefinement(false), ViewSession::RefineStart::kNothing);
  EXPECT_EQ(s.OnJobDone(1, false).outcome, ViewSession::JobOutcome::kApply);
  ASSERT_EQ(s.NextRefinement(false), ViewSession::RefineStart::kStep);
  EXPECT_EQ(s.NextRefinement(false), ViewSession::RefineStart::kNothing);  // one step at a time
  // The step found nothing, nothing is outstanding: it is over.
  EXPECT_FALSE(s.RefinementOutstanding());
  RefinementStep step{s.Refinement().CurrentRefiner(), 0, {}, /*exhausted=*/true};
  EXPECT_EQ(s.OnRefineStepDone(std::move(step), f.cache), RefinementDriver::After::kFinished);
  EXPECT_TRUE(s.RefinementDone());
  EXPECT_EQ(s.CurrentPhase(), Phase::kConverged);
  // New options restart refinement on the same view.
  s.SetRefinementParams(p);
  EXPECT_EQ(s.CurrentPhase(), Phase::kRefining);
  EXPECT_EQ(s.NextRefinement(false), ViewSession::RefineStart::kStep);
}

TEST(ViewSessionTest, AStepThatFoundNothingWaitsOnlyIfSomethingWillWakeIt) {
  SessionFixture f;
  ViewSession s(RefinementParams{}, 1000, false);
  f.ToShading(s);
  f.ToStage2(s);
  ASSERT_EQ(s.NextRefinement(false), ViewSession::RefineStart::kStep);
  s.WantRemap();  // a split's samples arrived during the step: its re-map will wake refinement
  EXPECT_TRUE(s.RefinementOutstanding());
  EXPECT_EQ(s.OnRefineStepDone(RefinementStep{s.Refinement().CurrentRefiner(), 0, {}, false}, f.cache),
            RefinementDriver::After::kWait);
  // The re-map ran meanwhile and is done: nothing will wake it but itself.
  ASSERT_EQ(s.NextJob(false), JobStart::kRefresh);
  s.OnJobStarted(JobStart::kRefresh, f.now);
  s.OnJobDone(1, false);
  ASSERT_EQ(s.NextRefinement(false), ViewSession::RefineStart::kStep);
  EXPECT_EQ(s.OnRefineStepDone(RefinementStep{s.Refinement().CurrentRefiner(), 0, {}, false}, f.cache),
            RefinementDriver::After::kStepNow);
}

TEST(ViewSessionTest, ImprovementKeepsABatchInFlightAndEnds) {
  SessionFixture f;
  ViewSession s(NoRefinement(), 1000, /*improvementOn=*/true);
  f.ToShading(s);
  EXPECT_EQ(s.NextImprovement(false, 4), ViewSession::ImproveStart::kNothing);  // stage 1 first
  f.ToStage2(s);
  EXPECT_EQ(s.CurrentPhase(), Phase::kRefining);  // improving
  ASSERT_EQ(s.NextImprovement(false, 4), ViewSession::ImproveStart::kLook);
  const std::vector<VertexId> asked = {0, 1, 2};
  EXPECT_EQ(s.OnImprovementsAsked(asked, 10, 10), ViewSession::AfterLook::kAwaitAnswers);  // a whole lap of 10 visible nodes
  EXPECT_EQ(s.NextImprovement(false, 4), ViewSession::ImproveStart::kNothing);  // 3 > 4 / 2 in flight
  s.OnImprovementsAnswered(std::vector<VertexId>{0, 1});
  ASSERT_EQ(s.NextImprovement(false, 4), ViewSession::ImproveStart::kLook);
  EXPECT_EQ(s.ImproveScanPosition(), 0u);  // a new lap
  EXPECT_EQ(s.OnImprovementsAsked({}, 10, 10), ViewSession::AfterLook::kAwaitAnswers);  // vertex 2 still out
  s.OnImprovementsAnswered(std::vector<VertexId>{2});
  EXPECT_FALSE(s.ImprovementDone());
  ASSERT_EQ(s.NextImprovement(false, 4), ViewSession::ImproveStart::kLook);
  EXPECT_EQ(s.OnImprovementsAsked({}, 10, 10), ViewSession::AfterLook::kDone);  // nothing needs more
  EXPECT_TRUE(s.ImprovementDone());
  EXPECT_EQ(s.CurrentPhase(), Phase::kConverged);
  s.DisplayChanged();
  EXPECT_EQ(s.CurrentPhase(), Phase::kRefining);
}

// The pool keeps one request per vertex: an improvement asked while a first
// estimate of the vertex was alive comes back as that estimate (an arrival),
// which must end the wait too and call for a look, or the view never
// converges (SmaSlowClientTest stalled so with session threads).
TEST(ViewSessionTest, AnArrivalEndsAnImprovementsWait) {
  SessionFixture f;
  ViewSession s(NoRefinement(), 1000, /*improvementOn=*/true);
  f.ToShading(s);
  f.ToStage2(s);
  ASSERT_EQ(s.NextImprovement(false, 4), ViewSession::ImproveStart::kLook);
  EXPECT_EQ(s.OnImprovementsAsked(std::vector<VertexId>{5}, 10, 10), ViewSession::AfterLook::kAwaitAnswers);
  EXPECT_TRUE(s.ImprovementPending(5));
  // The arrival is the last thing this session waited for: it must ask
  // for the next look itself, since no IMPROVED answer will.
  EXPECT_TRUE(s.OnSamplesArrived(std::vector<VertexId>{5}, 1000).improveLookWanted);
  EXPECT_FALSE(s.ImprovementPending(5));
  EXPECT_FALSE(s.OnSamplesArrived(std::vector<VertexId>{5}, 1000).improveLookWanted);  // not waited for now
  ASSERT_EQ(s.NextImprovement(false, 4), ViewSession::ImproveStart::kLook);
  EXPECT_EQ(s.OnImprovementsAsked({}, 10, 10), ViewSession::AfterLook::kDone);
  EXPECT_EQ(s.CurrentPhase(), Phase::kConverged);
}

TEST(ViewSessionTest, ArrivingMidpointsAskForARemap) {
  SessionFixture f;
  ViewSession s(RefinementParams{}, 1000, false);
  f.ToShading(s);
  f.ToStage2(s);
  const RefineResult split = f.hierarchy.Refine(0, ToRefineOptions(RefinementParams{}));
  ASSERT_FALSE(split.newVertices.empty());
  f.cache.Reserve(f.hierarchy.VertexCount());
  f.Shade();
  const auto arrived = s.OnSamplesArrived(split.newVertices, f.hierarchy.BaseVertexCount());
  EXPECT_TRUE(arrived.remapWanted);
  EXPECT_TRUE(arrived.candidates.empty());
}


// Moving objects: after a move, the held vertices whose samples it
// invalidated are awaited -- the view is not converged until their
// reshades arrived, or the client let them go.
TEST(ViewSessionTest, AMoveHoldsConvergenceUntilTheReshadesArrive) {
  SessionFixture f;
  ViewSession s(NoRefinement(), 1000, /*improvementOn=*/false);
  f.ToShading(s);
  f.ToStage2(s);
  ASSERT_TRUE(s.Converged());
  wire::Delta told;
  s.FillStatus(told, true, 1, f.now);
  ASSERT_TRUE(told.converged());

  s.OnSceneMoved(std::vector<VertexId>{0, 1, 2});
  EXPECT_FALSE(s.Converged());
  EXPECT_EQ(s.ReshadesAwaited(), 3u);
  EXPECT_TRUE(s.StatusOutdated());
  wire::Delta moved;
  s.FillStatus(moved, true, 1, f.now);
  EXPECT_FALSE(moved.converged());
  EXPECT_EQ(moved.pending_samples(), 3u);

  s.OnSamplesArrived(std::vector<VertexId>{0, 1}, f.hierarchy.BaseVertexCount());
  EXPECT_EQ(s.ReshadesAwaited(), 1u);
  s.PruneReshades([](VertexId v) { return v != 2; });  // the client let vertex 2 go
  EXPECT_EQ(s.ReshadesAwaited(), 0u);
  EXPECT_TRUE(s.Converged());
}

// A lap improves first what covers the most pixels: cut short, it has
// lowered the image's error the most. Equal coverage keeps node order.
TEST(ImprovementLapTest, TheNodesCoveringTheMostPixelsComeFirst) {
  VisibleSet visible;
  visible.nodes = {3, 5, 8, 13, 21};
  visible.coverage = {10, 4000, 10, 1, 250};
  EXPECT_EQ(ImprovementLap(visible), (std::vector<NodeId>{5, 21, 3, 8, 13}));
  EXPECT_TRUE(ImprovementLap(VisibleSet{}).empty());
}

TEST(ViewSessionTest, ImprovementLooksWalkTheVisibleNodesInLaps) {
  SessionFixture f;
  ViewSession s(NoRefinement(), 1000, /*improvementOn=*/true);
  f.ToShading(s);
  f.ToStage2(s);
  // A lap over 10 000 nodes in three looks: each goes on where the last stopped.
  EXPECT_EQ(s.ImproveScanPosition(), 0u);
  EXPECT_EQ(s.OnImprovementsAsked({}, 4096, 10000), ViewSession::AfterLook::kLapGoesOn);
  EXPECT_EQ(s.ImproveScanPosition(), 4096u);
  EXPECT_EQ(s.OnImprovementsAsked(std::vector<VertexId>{7}, 8192, 10000), ViewSession::AfterLook::kLapGoesOn);
  EXPECT_EQ(s.ImproveScanPosition(), 8192u);
  // The lap ends having asked vertex 7, answered since: not done, and since
  // no answer is out to call for it, the next lap must be looked for now
  // (a session waited forever here: SmaSlowClientTest with session threads).
  s.OnImprovementsAnswered(std::vector<VertexId>{7});
  EXPECT_EQ(s.OnImprovementsAsked({}, 10000, 10000), ViewSession::AfterLook::kLookAgain);
  EXPECT_FALSE(s.ImprovementDone());
  EXPECT_EQ(s.ImproveScanPosition(), 0u);
  // A lap that asks nothing part-way is not done until its end.
  EXPECT_EQ(s.OnImprovementsAsked({}, 5000, 10000), ViewSession::AfterLook::kLapGoesOn);
  EXPECT_FALSE(s.ImprovementDone());
  // What is displayed changed: the lap starts over (the list is another).
  s.DisplayChanged();
  EXPECT_EQ(s.ImproveScanPosition(), 0u);
  EXPECT_EQ(s.OnImprovementsAsked({}, 4096, 10000), ViewSession::AfterLook::kLapGoesOn);
  EXPECT_EQ(s.OnImprovementsAsked({}, 10000, 10000), ViewSession::AfterLook::kDone);
  EXPECT_TRUE(s.ImprovementDone());
}

}  // namespace
}  // namespace penumbra::sma

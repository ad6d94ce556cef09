// The sample scheduler with a fake clock and no socket: requeue on loss,
// never two requests for a vertex, priorities and interest, credits, a
// renderer's timeout moving its work, quarantine after a bad reply, and the
// tests of a move's change (Verify), kept apart from shading.

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <memory>
#include <set>
#include <string>
#include <tuple>
#include <vector>

#include "penumbra/sma/sample_scheduler.h"

namespace penumbra::sma {
namespace {

using namespace std::chrono_literals;
using Clock = SampleScheduler::Clock;

struct FakeClock {
  Clock::time_point now{};
  SampleScheduler::Now Function() {
    return [this] { return now; };
  }
};

std::vector<SampleRequest> Requests(VertexId first, VertexId count, uint16_t round = 0) {
  std::vector<SampleRequest> out;
  for (VertexId v = first; v < first + count; ++v) {
    SampleRequest r;
    r.vertex = v;
    r.round = round;
    out.push_back(r);
  }
  return out;
}

// The renderer's answer to a batch: every sample, radiance 0.5.
wire::ShadeReply Answer(const AssignedBatch& batch, uint32_t remaining = 0) {
  wire::ShadeReply r;
  r.set_batch_id(batch.id);
  r.set_remaining(remaining);
  for (const SampleRequest& s : batch.samples) {
    r.add_sample_ids(WireSampleId(s.vertex, s.round));
    for (int k = 0; k < 3; ++k) r.add_radiance(0.5f);
    for (int k = 0; k < 3; ++k) r.add_irradiance(1.0f);
    r.add_irradiance_stderr(0.01f);
    r.add_sample_paths(16);
  }
  return r;
}

std::set<VertexId> VerticesOf(const std::vector<AssignedBatch>& batches) {
  std::set<VertexId> out;
  for (const auto& b : batches)
    for (const auto& s : b.samples) out.insert(s.vertex);
  return out;
}

SampleSchedulerOptions Options() {
  SampleSchedulerOptions o;
  o.pathsPerSample = 100;
  o.firstPaths = 16;
  o.improvePaths = 64;
  o.creditsPerRenderer = 4;
  o.minBatchSamples = 8;  // and 32 per batch until a rate is measured
  o.maxBatchSamples = 1000;
  o.batchTimeout = 10s;
  o.quarantine = 30s;
  o.radianceBounds.maxRadiance = 10.0f;
  o.radianceBounds.maxIrradiance = 40.0f;
  return o;
}

constexpr RendererCapacity kOneCredit{1, 1000, 32};

TEST(SampleScheduler, AVertexIsNeverRequestedTwiceWhileAlive) {
  FakeClock clock;
  SampleScheduler s(Options(), clock.Function());
  EXPECT_EQ(s.Request(Requests(0, 10), Priority::kVisible), 10u);
  EXPECT_EQ(s.Request(Requests(5, 10), Priority::kBackground), 5u);  // 5..9 are alive already
  EXPECT_EQ(s.Outstanding(), 15u);
  s.RendererReady(1, RendererCapacity{4, 1000, 32});
  auto batches = s.Assemble();
  ASSERT_FALSE(batches.empty());
  EXPECT_EQ(VerticesOf(batches).size(), 15u);
  EXPECT_EQ(s.Request(Requests(0, 15), Priority::kVisible), 0u) << "in flight";

  // Answered, not yet stored: still alive (the cache does not have them).
  std::vector<ShadedSample> results;
  for (const auto& b : batches) {
    auto outcome = s.OnReply(1, Answer(b));
    ASSERT_FALSE(outcome.badReply) << *outcome.badReply;
    EXPECT_TRUE(outcome.batchDone);
    results.insert(results.end(), outcome.results.begin(), outcome.results.end());
  }
  EXPECT_EQ(results.size(), 15u);
  EXPECT_EQ(s.Request(Requests(0, 15), Priority::kVisible), 0u) << "answered, not stored";
  s.Complete(results);
  EXPECT_EQ(s.Outstanding(), 0u);
  // Stored: a request now is the caller's decision (it asks only for what
  // the cache lacks), and it is taken.
  EXPECT_EQ(s.Request(Requests(0, 1), Priority::kVisible), 1u);
  EXPECT_EQ(s.Counters().shaded, 15u);
}

TEST(SampleScheduler, VisibleBeforeBackgroundBeforeImprovementOnePriorityPerBatch) {
  FakeClock clock;
  SampleScheduler s(Options(), clock.Function());
  s.Request(Requests(100, 3, 2), Priority::kImprove);
  s.Request(Requests(0, 3), Priority::kBackground);
  s.Request(Requests(10, 3), Priority::kVisible);
  s.RendererReady(1, kOneCredit);
  std::vector<std::pair<VertexId, uint32_t>> order;  // first vertex and paths of each batch
  for (int i = 0; i < 3; ++i) {
    auto batches = s.Assemble();
    ASSERT_EQ(batches.size(), 1u) << "one credit";
    EXPECT_TRUE(s.Assemble().empty()) << "no credit left";
    const AssignedBatch& b = batches[0];
    ASSERT_EQ(b.samples.size(), 3u);
    for (const auto& sample : b.samples) EXPECT_EQ(sample.vertex / 10, b.samples[0].vertex / 10);
    order.emplace_back(b.samples[0].vertex, b.pathsPerSample);
    auto outcome = s.OnReply(1, Answer(b));
    ASSERT_FALSE(outcome.badReply) << *outcome.badReply;
    s.Complete(outcome.results);
  }
  EXPECT_EQ(order[0], std::make_pair(VertexId(10), 16u));   // visible: first paths
  EXPECT_EQ(order[1], std::make_pair(VertexId(0), 100u));   // background
  EXPECT_EQ(order[2], std::make_pair(VertexId(100), 64u));  // improvement
  EXPECT_EQ(s.Outstanding(), 0u);
}

TEST(SampleScheduler, InterestReleasedDemotesAndANewViewPromotes) {
  FakeClock clock;
  SampleScheduler s(Options(), clock.Function());
  std::vector<InterestTicket> released;
  s.Request(Requests(0, 4), Priority::kVisible, &released);  // a view that moves on
  EXPECT_EQ(released.size(), 4u);
  s.Request(Requests(10, 4), Priority::kBackground);
  s.Request(Requests(10, 2), Priority::kVisible);   // 10, 11 now wanted by a view
  s.ReleaseInterest(released);
  s.RendererReady(1, kOneCredit);
  auto first = s.Assemble();
  ASSERT_EQ(first.size(), 1u);
  EXPECT_EQ(VerticesOf(first), (std::set<VertexId>{10, 11}));
  EXPECT_EQ(first[0].pathsPerSample, 16u);
  s.Complete(s.OnReply(1, Answer(first[0])).results);
  auto second = s.Assemble();
  ASSERT_EQ(second.size(), 1u);
  // 12, 13 and the demoted 0..3 at background priority, each once.
  EXPECT_EQ(VerticesOf(second), (std::set<VertexId>{0, 1, 2, 3, 12, 13}));
  EXPECT_EQ(second[0].samples.size(), 6u);
  EXPECT_EQ(second[0].pathsPerSample, 100u);
}

// Interest is taken back from the request it was given to, never from a
// later request of the same vertex id: once a sample is stored its request
// ends, the collector may free the vertex and a split reuse the id (issue
// 15). Before tickets, the first view's release demoted the second view's
// request of the reused id to background, behind the refinement queued.
TEST(SampleScheduler, ReleasedInterestNeverReachesALaterRequestOfTheSameVertexId) {
  FakeClock clock;
  SampleScheduler s(Options(), clock.Function());
  std::vector<InterestTicket> firstView, secondView, background;
  s.Request(Requests(0, 2), Priority::kVisible, &firstView);
  s.Request(Requests(0, 2), Priority::kBackground, &background);
  EXPECT_TRUE(background.empty()) << "only visible requests take interest";
  s.RendererReady(1, kOneCredit);
  auto batch = s.Assemble();
  ASSERT_EQ(batch.size(), 1u);
  s.Complete(s.OnReply(1, Answer(batch[0])).results);  // stored: both requests end
  EXPECT_EQ(s.Outstanding(), 0u);
  // Vertex ids 0 and 1 now name new vertices, wanted by another view, with
  // refinement queued behind them.
  s.Request(Requests(0, 2), Priority::kVisible, &secondView);
  s.Request(Requests(50, 4), Priority::kBackground);
  ASSERT_EQ(secondView.size(), 2u);
  EXPECT_NE(secondView[0], firstView[0]) << "a new request, a new ticket";
  s.ReleaseInterest(firstView);  // the first view moves on, late
  auto next = s.Assemble();
  ASSERT_EQ(next.size(), 1u);
  EXPECT_EQ(VerticesOf(next), (std::set<VertexId>{0, 1})) << "still visible: before the refinement";
  EXPECT_EQ(next[0].pathsPerSample, 16u) << "a visible batch";
  // Released by their own view, they would have been background work.
  s.RendererLost(1);
  s.ReleaseInterest(secondView);
  s.RendererReady(1, kOneCredit);
  auto demoted = s.Assemble();
  ASSERT_EQ(demoted.size(), 1u);
  EXPECT_EQ(demoted[0].pathsPerSample, 100u) << "background once their view moved on";
}

// Movement prediction (issue 15): what a predicted view needs goes after
// what current views need and before refinement and improvement.
TEST(SampleScheduler, PredictedBetweenVisibleAndBackground) {
  FakeClock clock;
  SampleScheduler s(Options(), clock.Function());
  s.Request(Requests(100, 3, 2), Priority::kImprove);
  s.Request(Requests(0, 3), Priority::kBackground);
  EXPECT_EQ(s.Request(Requests(20, 3), Priority::kPredicted), 3u);
  s.Request(Requests(10, 3), Priority::kVisible);
  EXPECT_EQ(s.Counters().queuedVisible, 3u);
  EXPECT_EQ(s.Counters().queuedPredicted, 3u);
  EXPECT_EQ(s.Counters().queuedBackground, 3u);
  EXPECT_EQ(s.Counters().queuedImprove, 3u);
  s.RendererReady(1, kOneCredit);
  std::vector<std::pair<VertexId, uint32_t>> order;  // first vertex and paths of each batch
  for (int i = 0; i < 4; ++i) {
    auto batches = s.Assemble();
    ASSERT_EQ(batches.size(), 1u) << "one credit";
    const AssignedBatch& b = batches[0];
    ASSERT_EQ(b.samples.size(), 3u);
    for (const auto& sample : b.samples) EXPECT_EQ(sample.vertex / 10, b.samples[0].vertex / 10);
    order.emplace_back(b.samples[0].vertex, b.pathsPerSample);
    auto outcome = s.OnReply(1, Answer(b));
    ASSERT_FALSE(outcome.badReply) << *outcome.badReply;
    s.Complete(outcome.results);
  }
  EXPECT_EQ(order[0], std::make_pair(VertexId(10), 16u));   // visible: first paths
  EXPECT_EQ(order[1], std::make_pair(VertexId(20), 16u));   // predicted: first estimates too
  EXPECT_EQ(order[2], std::make_pair(VertexId(0), 100u));   // background
  EXPECT_EQ(order[3], std::make_pair(VertexId(100), 64u));  // improvement
  EXPECT_EQ(s.Outstanding(), 0u);
}

TEST(SampleScheduler, PredictionPromotesBackgroundAndAViewPromotesAPrediction) {
  FakeClock clock;
  SampleScheduler s(Options(), clock.Function());
  s.Request(Requests(0, 4), Priority::kBackground);  // refinement: 0..3
  EXPECT_EQ(s.Request(Requests(2, 4), Priority::kPredicted), 2u) << "2, 3 alive already, 4, 5 new";
  EXPECT_EQ(s.Request(Requests(5, 1), Priority::kVisible), 0u) << "5 promoted, not asked twice";
  EXPECT_EQ(s.Request(Requests(0, 1), Priority::kBackground), 0u);
  EXPECT_EQ(s.Counters().queuedVisible, 1u);
  EXPECT_EQ(s.Counters().queuedPredicted, 3u);  // 2, 3, 4
  EXPECT_EQ(s.Counters().queuedBackground, 2u);  // 0, 1
  s.RendererReady(1, kOneCredit);
  std::vector<std::set<VertexId>> batches;
  for (int i = 0; i < 3; ++i) {
    auto assigned = s.Assemble();
    ASSERT_EQ(assigned.size(), 1u);
    batches.push_back(VerticesOf(assigned));
    s.Complete(s.OnReply(1, Answer(assigned[0])).results);
  }
  EXPECT_EQ(batches[0], (std::set<VertexId>{5}));        // the view's
  EXPECT_EQ(batches[1], (std::set<VertexId>{2, 3, 4}));  // the prediction's, each once
  EXPECT_EQ(batches[2], (std::set<VertexId>{0, 1}));     // refinement's
  EXPECT_EQ(s.Counters().requested, 6u);
  EXPECT_EQ(s.Outstanding(), 0u);
}

TEST(SampleScheduler, AViewThatMovesOnDemotesToPredictedIfPredictedAndRequeueKeepsThePlace) {
  FakeClock clock;
  SampleScheduler s(Options(), clock.Function());
  std::vector<InterestTicket> released;
  s.Request(Requests(0, 2), Priority::kVisible, &released);
  s.Request(Requests(1, 1), Priority::kPredicted);  // 1: wanted by the view and predicted
  s.Request(Requests(10, 1), Priority::kBackground);
  s.ReleaseInterest(released);
  s.RendererReady(1, kOneCredit);
  auto first = s.Assemble();
  ASSERT_EQ(first.size(), 1u);
  EXPECT_EQ(VerticesOf(first), (std::set<VertexId>{1})) << "demoted to predicted, before background";
  // The renderer is lost: its sample goes back to the front of the predicted queue.
  EXPECT_EQ(s.RendererLost(1), 1u);
  EXPECT_EQ(s.Counters().queuedPredicted, 1u);
  s.RendererReady(1, kOneCredit);
  auto again = s.Assemble();
  ASSERT_EQ(again.size(), 1u);
  EXPECT_EQ(VerticesOf(again), (std::set<VertexId>{1}));
  s.Complete(s.OnReply(1, Answer(again[0])).results);
  auto rest = s.Assemble();
  ASSERT_EQ(rest.size(), 1u);
  EXPECT_EQ(VerticesOf(rest), (std::set<VertexId>{0, 10}));  // both background now
  EXPECT_EQ(s.Counters().queuedPredicted, 0u);
}

// Batches of 1 to 5 samples: credits, not sizes, decide how many go out.
SampleSchedulerOptions SmallBatchOptions() {
  SampleSchedulerOptions o = Options();
  o.minBatchSamples = 1;
  o.maxBatchSamples = 5;
  return o;
}

TEST(SampleScheduler, CreditsBoundBatchesInFlight) {
  FakeClock clock;
  const SampleSchedulerOptions o = SmallBatchOptions();
  SampleScheduler s(o, clock.Function());
  s.Request(Requests(0, 100), Priority::kVisible);
  s.RendererReady(1, RendererCapacity{2, 1000, 32});  // its own limit: 2 batches
  auto batches = s.Assemble();
  EXPECT_EQ(batches.size(), 2u);
  for (const auto& b : batches) EXPECT_LE(b.samples.size(), 5u);
  EXPECT_EQ(s.Load(1).batchesInFlight, 2u);
  EXPECT_TRUE(s.Assemble().empty());
  s.Complete(s.OnReply(1, Answer(batches[0])).results);
  EXPECT_EQ(s.Assemble().size(), 1u) << "a credit back, a batch out";
}

// The last free credit of a renderer is kept for what a client waits for:
// background work (tests, prefetch and refinement alike) never takes it, so
// a visible request finds a credit at once and goes as an urgent batch.
TEST(SampleScheduler, TheLastCreditWaitsForVisibleSamples) {
  FakeClock clock;
  const SampleSchedulerOptions o = SmallBatchOptions();
  SampleScheduler s(o, clock.Function());
  s.Request(Requests(0, 100), Priority::kBackground);
  s.RendererReady(1, RendererCapacity{3, 1000, 32});
  auto background = s.Assemble();
  EXPECT_EQ(background.size(), 2u) << "two of three credits";
  for (const auto& b : background) EXPECT_FALSE(b.urgent || b.soon);
  EXPECT_TRUE(s.Assemble().empty()) << "the last one is kept";
  s.Request(Requests(500, 3), Priority::kVisible);
  auto visible = s.Assemble();
  ASSERT_EQ(visible.size(), 1u);
  EXPECT_TRUE(visible[0].urgent);
  EXPECT_FALSE(visible[0].soon);
  EXPECT_EQ(VerticesOf(visible), (std::set<VertexId>{500, 501, 502}));
  EXPECT_TRUE(s.Assemble().empty()) << "every credit in flight";
  s.Complete(s.OnReply(1, Answer(visible[0])).results);
  EXPECT_TRUE(s.Assemble().empty()) << "its credit is the kept one again";
  s.Complete(s.OnReply(1, Answer(background[0])).results);
  EXPECT_EQ(s.Assemble().size(), 1u) << "a background credit back, a background batch out";

  // A renderer with one credit keeps none.
  SampleScheduler single(o, clock.Function());
  single.Request(Requests(0, 10), Priority::kBackground);
  single.RendererReady(1, kOneCredit);
  EXPECT_EQ(single.Assemble().size(), 1u);
}

TEST(SampleScheduler, ALostRenderersWorkGoesToTheOthersFirst) {
  FakeClock clock;
  SampleScheduler s(Options(), clock.Function());
  s.Request(Requests(0, 6), Priority::kVisible);
  s.RendererReady(1, kOneCredit);
  auto lost = s.Assemble();
  ASSERT_EQ(lost.size(), 1u);
  const std::set<VertexId> carried = VerticesOf(lost);
  s.Request(Requests(50, 3), Priority::kVisible);  // queued behind
  EXPECT_EQ(s.RendererLost(1), carried.size());
  EXPECT_EQ(s.Counters().requeued, carried.size());
  EXPECT_EQ(s.Load(1).failures, 1u);
  EXPECT_EQ(s.Request(Requests(0, 6), Priority::kVisible), 0u) << "requeued, still alive";
  s.RendererReady(2, kOneCredit);
  auto again = s.Assemble();
  ASSERT_EQ(again.size(), 1u);
  EXPECT_EQ(again[0].renderer, 2u);
  // The requeued samples lead, in their order; the later ones follow.
  ASSERT_GE(again[0].samples.size(), carried.size());
  for (size_t i = 0; i < lost[0].samples.size(); ++i) EXPECT_EQ(again[0].samples[i].vertex, lost[0].samples[i].vertex);
  EXPECT_EQ(VerticesOf(again).size(), again[0].samples.size()) << "each vertex once";
}

TEST(SampleScheduler, ATimedOutRenderersWorkMovesAndItsLateReplyIsIgnored) {
  FakeClock clock;
  SampleScheduler s(Options(), clock.Function());
  s.Request(Requests(0, 4), Priority::kVisible);
  s.RendererReady(1, kOneCredit);
  auto slow = s.Assemble();
  ASSERT_EQ(slow.size(), 1u);
  s.RendererReady(2, kOneCredit);
  clock.now += 9s;
  EXPECT_TRUE(s.ExpireTimedOut().empty());
  clock.now += 2s;  // 11 s > batchTimeout
  auto expired = s.ExpireTimedOut();
  ASSERT_EQ(expired.size(), 1u);
  EXPECT_EQ(expired[0].first, 1u);
  EXPECT_NE(expired[0].second.find("unanswered"), std::string::npos);
  auto moved = s.Assemble();
  ASSERT_EQ(moved.size(), 1u);
  EXPECT_EQ(moved[0].renderer, 2u);
  EXPECT_EQ(VerticesOf(moved), VerticesOf(slow));
  // The slow renderer's answer arrives after all: not taken (it would be a
  // second answer), not held against it either.
  auto late = s.OnReply(1, Answer(slow[0]));
  EXPECT_TRUE(late.results.empty());
  EXPECT_FALSE(late.badReply);
  auto good = s.OnReply(2, Answer(moved[0]));
  EXPECT_EQ(good.results.size(), 4u);
}

TEST(SampleScheduler, ABadReplyRequeuesEverythingAndQuarantines) {
  FakeClock clock;
  SampleScheduler s(Options(), clock.Function());
  s.Request(Requests(0, 4), Priority::kVisible);
  s.RendererReady(1, kOneCredit);
  auto batches = s.Assemble();
  ASSERT_EQ(batches.size(), 1u);
  wire::ShadeReply bad = Answer(batches[0]);
  bad.set_radiance(4, 1e30f);  // the second sample: impossible radiance, after a good one
  auto outcome = s.OnReply(1, bad);
  ASSERT_TRUE(outcome.badReply);
  EXPECT_TRUE(outcome.results.empty()) << "nothing of a bad part is taken";
  EXPECT_EQ(s.Counters().rejected, 1u);
  EXPECT_EQ(s.Load(1).badReplies, 1u);
  EXPECT_TRUE(s.Quarantined(1));
  EXPECT_EQ(s.QuarantineLeft(1), 30s);

  // It comes back at once (its link reconnected): no work while quarantined.
  s.RendererReady(1, kOneCredit);
  EXPECT_TRUE(s.Assemble().empty());
  clock.now += 29s;
  EXPECT_TRUE(s.Assemble().empty());
  clock.now += 1s;
  EXPECT_FALSE(s.Quarantined(1));
  auto retried = s.Assemble();
  ASSERT_EQ(retried.size(), 1u);
  EXPECT_EQ(VerticesOf(retried), VerticesOf(batches));
}

TEST(SampleScheduler, RepliesNamingWhatWasNotAskedAreBad) {
  FakeClock clock;
  SampleSchedulerOptions o = Options();
  o.minBatchSamples = 1;
  SampleScheduler s(o, clock.Function());
  s.Request(Requests(0, 2), Priority::kVisible);
  s.RendererReady(1, RendererCapacity{4, 1, 32});  // one sample per batch
  auto batches = s.Assemble();
  ASSERT_EQ(batches.size(), 2u);
  // Batch 0 answered with batch 1's sample.
  wire::ShadeReply swapped = Answer(batches[1]);
  swapped.set_batch_id(batches[0].id);
  auto outcome = s.OnReply(1, swapped);
  ASSERT_TRUE(outcome.badReply);
  EXPECT_NE(outcome.badReply->find("not asked for"), std::string::npos) << *outcome.badReply;
  EXPECT_EQ(s.Counters().requeued, 2u) << "both batches back";

  clock.now += 31s;
  s.RendererReady(1, kOneCredit);
  auto again = s.Assemble();
  ASSERT_EQ(again.size(), 1u);
  wire::ShadeReply unknown = Answer(again[0]);
  unknown.set_batch_id(999);
  EXPECT_TRUE(s.OnReply(1, unknown).badReply);
  clock.now += 31s;
  s.RendererReady(1, kOneCredit);
  again = s.Assemble();
  ASSERT_EQ(again.size(), 1u);
  wire::ShadeReply shortAnswer = Answer(again[0]);  // ends the batch one sample short
  shortAnswer.mutable_sample_ids()->RemoveLast();
  shortAnswer.mutable_radiance()->Truncate(shortAnswer.radiance_size() - 3);
  shortAnswer.mutable_irradiance()->Truncate(shortAnswer.irradiance_size() - 3);
  shortAnswer.mutable_irradiance_stderr()->RemoveLast();
  shortAnswer.mutable_sample_paths()->RemoveLast();
  auto ended = s.OnReply(1, shortAnswer);
  ASSERT_TRUE(ended.badReply);
  EXPECT_NE(ended.badReply->find("ended with 1 of 2"), std::string::npos) << *ended.badReply;
}

TEST(SampleScheduler, ABatchInPartsAndARefusedOneGivenUpAfterThreeInvalids) {
  FakeClock clock;
  SampleScheduler s(Options(), clock.Function());
  s.Request(Requests(0, 2), Priority::kVisible);
  s.RendererReady(1, kOneCredit);
  auto batches = s.Assemble();
  ASSERT_EQ(batches.size(), 1u);
  AssignedBatch firstHalf = batches[0], secondHalf = batches[0];
  firstHalf.samples.resize(1);
  secondHalf.samples.erase(secondHalf.samples.begin());
  auto part = s.OnReply(1, Answer(firstHalf, 1));
  EXPECT_EQ(part.results.size(), 1u);
  EXPECT_FALSE(part.batchDone);
  auto rest = s.OnReply(1, Answer(secondHalf, 0));
  EXPECT_EQ(rest.results.size(), 1u);
  EXPECT_TRUE(rest.batchDone);
  s.Complete(part.results);
  s.Complete(rest.results);

  s.Request(Requests(7, 1), Priority::kVisible);
  for (int attempt = 1; attempt <= 3; ++attempt) {
    auto b = s.Assemble();
    ASSERT_EQ(b.size(), 1u) << attempt;
    auto givenUp = s.OnBatchRefused(1, b[0].id, /*invalid=*/true);
    ASSERT_TRUE(givenUp.has_value());
    if (attempt < 3) {
      EXPECT_TRUE(givenUp->empty());
    } else {
      ASSERT_EQ(givenUp->size(), 1u);
      EXPECT_EQ((*givenUp)[0].vertex, 7u);
      EXPECT_EQ((*givenUp)[0].paths, 0u);
      EXPECT_EQ((*givenUp)[0].radiance, Rgb(0.0f));
    }
  }
  EXPECT_EQ(s.Counters().failed, 1u);
  EXPECT_TRUE(s.Assemble().empty());
  EXPECT_FALSE(s.OnBatchRefused(1, 12345, true).has_value()) << "unknown batch";
}

TEST(SampleScheduler, ADrainingRendererGetsNoNewBatches) {
  FakeClock clock;
  SampleScheduler s(Options(), clock.Function());
  s.RendererReady(1, kOneCredit);
  s.RendererDraining(1);
  s.Request(Requests(0, 2), Priority::kVisible);
  EXPECT_TRUE(s.Assemble().empty());
  s.RendererReady(2, kOneCredit);
  auto b = s.Assemble();
  ASSERT_EQ(b.size(), 1u);
  EXPECT_EQ(b[0].renderer, 2u);
}

// A vertex promoted from background to visible, shaded, and then asked to
// be improved: the stale background copy must not send the improvement at
// background priority (or twice).
TEST(SampleScheduler, AStaleQueueCopyDoesNotSendAnImprovementEarly) {
  FakeClock clock;
  SampleScheduler s(Options(), clock.Function());
  s.Request(Requests(0, 1), Priority::kBackground);
  s.Request(Requests(0, 1), Priority::kVisible);  // promoted; its background copy stays in that queue
  s.RendererReady(1, kOneCredit);
  auto b = s.Assemble();
  ASSERT_EQ(b.size(), 1u);
  s.Complete(s.OnReply(1, Answer(b[0])).results);
  s.Request(Requests(0, 1, 1), Priority::kImprove);
  auto improve = s.Assemble();
  ASSERT_EQ(improve.size(), 1u);
  EXPECT_EQ(improve[0].pathsPerSample, 64u);
  EXPECT_EQ(improve[0].samples.size(), 1u);
  EXPECT_EQ(s.Counters().queuedImprove, 0u);
}


// Moving objects (issue 14): a batch is shaded at the epoch it was sent at;
// the reply must say so, and its samples carry it to the cache.
TEST(SampleScheduler, BatchesCarryTheirEpochAndRepliesMustMatchIt) {
  FakeClock clock;
  SampleScheduler s(Options(), clock.Function());
  s.RendererReady(1, kOneCredit);
  s.SetEpoch(3);
  s.Request(Requests(0, 4), Priority::kVisible);
  auto batches = s.Assemble();
  ASSERT_EQ(batches.size(), 1u);
  EXPECT_EQ(batches[0].epoch, 3u);
  s.SetEpoch(4);  // a move after it left: the batch keeps epoch 3
  wire::ShadeReply reply = Answer(batches[0]);
  reply.set_scene_epoch(3);
  auto outcome = s.OnReply(1, reply);
  ASSERT_FALSE(outcome.badReply) << *outcome.badReply;
  ASSERT_EQ(outcome.results.size(), 4u);
  for (const ShadedSample& r : outcome.results) EXPECT_EQ(r.epoch, 3u);

  // A renderer that shades at another pose (one that ignores movable
  // objects answers epoch 0) answered nonsense.
  s.RendererReady(2, kOneCredit);
  s.Request(Requests(10, 4), Priority::kVisible);
  batches = s.Assemble();
  ASSERT_EQ(batches.size(), 1u);
  EXPECT_EQ(batches[0].epoch, 4u);
  outcome = s.OnReply(batches[0].renderer, Answer(batches[0]));  // scene_epoch 0
  ASSERT_TRUE(outcome.badReply);
  EXPECT_NE(outcome.badReply->find("epoch"), std::string::npos) << *outcome.badReply;
  EXPECT_EQ(s.Queued(), 4u) << "its samples went back to the queue";
}

// A sample the cache refused as stale is asked again as a first estimate,
// visible while a view wants it; an improvement becomes a first estimate.
TEST(SampleScheduler, RetryRequeuesAnsweredSamplesAsFirstEstimates) {
  FakeClock clock;
  SampleScheduler s(Options(), clock.Function());
  s.RendererReady(1, RendererCapacity{4, 1000, 32});
  s.Request(Requests(0, 2), Priority::kVisible);
  s.Request(Requests(5, 1, /*round=*/2), Priority::kImprove);
  auto batches = s.Assemble();
  std::vector<ShadedSample> results;
  for (const auto& b : batches) {
    auto outcome = s.OnReply(1, Answer(b));
    ASSERT_FALSE(outcome.badReply) << *outcome.badReply;
    results.insert(results.end(), outcome.results.begin(), outcome.results.end());
  }
  ASSERT_EQ(results.size(), 3u);
  s.Retry(std::vector<VertexId>{0, 5, 7});  // 7 was never asked: ignored
  s.Complete(results);                       // the retried ones stay alive
  EXPECT_EQ(s.Outstanding(), 2u);
  EXPECT_EQ(s.Counters().retried, 2u);
  EXPECT_EQ(s.Counters().queuedVisible, 1u);     // 0: its view still wants it
  EXPECT_EQ(s.Counters().queuedBackground, 1u);  // 5: nobody's interest
  EXPECT_EQ(s.Request(Requests(0, 1), Priority::kVisible), 0u) << "alive: asked once";
  batches = s.Assemble();
  std::set<std::pair<VertexId, uint16_t>> asked;
  for (const auto& b : batches)
    for (const auto& r : b.samples) asked.insert({r.vertex, r.round});
  EXPECT_EQ(asked, (std::set<std::pair<VertexId, uint16_t>>{{0, 0}, {5, 0}}));
}


// After a move, a vertex whose improvement is alive is asked for a first
// estimate: a queued improvement becomes one, keeping the view's interest.
TEST(SampleScheduler, AFirstEstimateReplacesAQueuedImprovement) {
  FakeClock clock;
  SampleScheduler s(Options(), clock.Function());
  s.Request(Requests(3, 1, /*round=*/2), Priority::kImprove);
  EXPECT_EQ(s.Counters().queuedImprove, 1u);
  EXPECT_EQ(s.Request(Requests(3, 1), Priority::kVisible), 0u) << "alive: not a new entry";
  EXPECT_EQ(s.Counters().queuedImprove, 0u);
  EXPECT_EQ(s.Counters().queuedVisible, 1u);
  s.RendererReady(1, kOneCredit);
  auto batches = s.Assemble();
  ASSERT_EQ(batches.size(), 1u);
  ASSERT_EQ(batches[0].samples.size(), 1u);
  EXPECT_EQ(batches[0].samples[0].round, 0u);
  EXPECT_EQ(batches[0].pathsPerSample, 16u) << "visible: stage 1 paths";
  EXPECT_EQ(s.Queued(), 0u) << "the improvement's queue copy is gone with it";
}

// Prepared shading (a predicted move's): after visible and predicted
// samples, before background ones; batches at the predicted epoch; answers
// apart from the results; a vertex may be alive both ways.
TEST(SampleScheduler, PreparedSamplesGoAfterPredictedBeforeBackgroundAtTheirEpochAndComeBackApart) {
  FakeClock clock;
  SampleScheduler s(Options(), clock.Function());
  s.SetEpoch(5);
  s.Request(Requests(0, 4), Priority::kBackground);
  EXPECT_EQ(s.Prepare(Requests(2, 4), 6), 4u) << "vertices 2 and 3 are also requested: both stay alive";
  s.Request(Requests(100, 4), Priority::kPredicted);
  EXPECT_TRUE(s.AnyQueued());
  EXPECT_EQ(s.Outstanding(), 8u) << "prepared samples are nobody's outstanding work";
  EXPECT_TRUE(s.AnyAlive(std::vector<VertexId>{5}));
  s.RendererReady(1, kOneCredit);
  auto first = s.Assemble();
  ASSERT_EQ(first.size(), 1u);
  EXPECT_FALSE(first[0].prepared);
  EXPECT_EQ(VerticesOf(first), (std::set<VertexId>{100, 101, 102, 103}));
  ASSERT_FALSE(s.OnReply(1, [&] { auto r = Answer(first[0]); r.set_scene_epoch(5); return r; }()).badReply);

  auto second = s.Assemble();
  ASSERT_EQ(second.size(), 1u);
  EXPECT_TRUE(second[0].prepared);
  EXPECT_EQ(second[0].epoch, 6u) << "shaded at the predicted pose";
  EXPECT_EQ(second[0].pathsPerSample, 16u) << "first estimates: stage-1 paths";
  EXPECT_EQ(VerticesOf(second), (std::set<VertexId>{2, 3, 4, 5}));
  wire::ShadeReply reply = Answer(second[0]);
  reply.set_scene_epoch(5);  // not the epoch it was asked at
  {
    // Checked like any batch: the wrong epoch is a bad reply, and the
    // renderer's prepared work goes back to the prepared queue.
    auto outcome = s.OnReply(1, reply);
    ASSERT_TRUE(outcome.badReply);
  }
  s.RendererReady(2, kOneCredit);
  auto again = s.Assemble();
  ASSERT_EQ(again.size(), 1u);
  EXPECT_TRUE(again[0].prepared);
  EXPECT_EQ(VerticesOf(again), (std::set<VertexId>{2, 3, 4, 5}));
  reply = Answer(again[0]);
  reply.set_scene_epoch(6);
  auto outcome = s.OnReply(2, reply);
  ASSERT_FALSE(outcome.badReply) << *outcome.badReply;
  EXPECT_TRUE(outcome.results.empty());
  ASSERT_EQ(outcome.prepared.size(), 4u);
  for (const ShadedSample& r : outcome.prepared) EXPECT_EQ(r.epoch, 6u);
  EXPECT_TRUE(s.AnyAlive(std::vector<VertexId>{5})) << "answered, not yet kept";
  s.CompletePrepared(outcome.prepared);
  EXPECT_FALSE(s.AnyAlive(std::vector<VertexId>{5}));
  EXPECT_TRUE(s.AnyAlive(std::vector<VertexId>{2})) << "still requested at the current pose";

  auto background = s.Assemble();
  ASSERT_EQ(background.size(), 1u);
  EXPECT_FALSE(background[0].prepared);
  EXPECT_EQ(background[0].epoch, 5u);
  EXPECT_EQ(VerticesOf(background), (std::set<VertexId>{0, 1, 2, 3}));
  const SchedulerCounters c = s.Counters();
  EXPECT_EQ(c.preparedRequested, 4u);
  EXPECT_EQ(c.preparedShaded, 4u);
}

// A newer preparation replaces the queued part of the one before; what is
// in flight is answered and a renderer lost with it does not requeue it.
TEST(SampleScheduler, ANewPreparationDropsTheQueuedPartOfTheOldOne) {
  FakeClock clock;
  SampleSchedulerOptions options = Options();
  options.minBatchSamples = 2;
  SampleScheduler s(options, clock.Function());
  s.Prepare(Requests(0, 4), 7);
  s.RendererReady(1, RendererCapacity{1, 2, 32});
  auto batches = s.Assemble();
  ASSERT_EQ(batches.size(), 1u);
  ASSERT_EQ(batches[0].samples.size(), 2u);
  const std::set<VertexId> sent = VerticesOf(batches);
  EXPECT_EQ(s.Prepare(Requests(0, 8), 8), 6u) << "the two in flight for epoch 7 are skipped";
  EXPECT_EQ(s.Counters().preparedDropped, 2u);
  EXPECT_EQ(s.Counters().queuedPrepared, 6u);
  // The renderer is lost: epoch 7's samples are not asked again.
  s.RendererLost(1);
  EXPECT_EQ(s.Counters().queuedPrepared, 6u);
  for (VertexId v : sent) EXPECT_FALSE(s.AnyAlive(std::vector<VertexId>{v}));
  s.RendererReady(2, RendererCapacity{4, 100, 32});
  batches = s.Assemble();
  std::set<VertexId> all = VerticesOf(batches);
  EXPECT_EQ(all.size(), 6u);
  for (const AssignedBatch& b : batches) {
    EXPECT_TRUE(b.prepared);
    EXPECT_EQ(b.epoch, 8u);
  }
  EXPECT_FALSE(s.AnyQueued());
}

// The move prepared for lands where predicted: what is still queued is
// wanted at the (now current) pose as ordinary requests; after a miss it
// is dropped. Answers in flight come back as prepared either way.
TEST(SampleScheduler, EndingAPreparationTurnsItsQueuedSamplesIntoRequestsOrDropsThem) {
  FakeClock clock;
  SampleSchedulerOptions options = Options();
  options.minBatchSamples = 2;
  SampleScheduler s(options, clock.Function());
  s.SetEpoch(5);
  s.Prepare(Requests(0, 6), 6);
  s.RendererReady(1, RendererCapacity{1, 2, 32});
  auto inFlight = s.Assemble();
  ASSERT_EQ(inFlight.size(), 1u);
  ASSERT_TRUE(inFlight[0].prepared);
  EXPECT_EQ(s.EndPreparation(5, true), 0u) << "not the epoch prepared for";
  s.SetEpoch(6);  // the move, applied where predicted
  const std::set<VertexId> sent = VerticesOf(inFlight);
  const VertexId storedMeanwhile = *std::set<VertexId>{2, 3, 4, 5}.begin();
  EXPECT_EQ(s.EndPreparation(6, true, [&](VertexId v) { return v == storedMeanwhile; }), 3u);
  EXPECT_EQ(s.Counters().queuedPrepared, 0u);
  EXPECT_EQ(s.Counters().queuedPredicted, 3u);
  EXPECT_EQ(s.Outstanding(), 3u);
  wire::ShadeReply reply = Answer(inFlight[0]);
  reply.set_scene_epoch(6);
  auto outcome = s.OnReply(1, reply);
  ASSERT_FALSE(outcome.badReply) << *outcome.badReply;
  EXPECT_EQ(outcome.prepared.size(), 2u) << "answered as prepared";
  s.CompletePrepared(outcome.prepared);
  auto batches = s.Assemble();
  ASSERT_EQ(batches.size(), 1u);
  EXPECT_FALSE(batches[0].prepared);
  EXPECT_EQ(batches[0].epoch, 6u);
  for (const auto& r : batches[0].samples) {
    EXPECT_FALSE(sent.contains(r.vertex));
    EXPECT_NE(r.vertex, storedMeanwhile);
  }

  // A miss: the queued part is dropped.
  s.Prepare(Requests(10, 4), 7);
  EXPECT_EQ(s.EndPreparation(7, false), 0u);
  EXPECT_FALSE(s.AnyAlive(std::vector<VertexId>{10}));
  EXPECT_EQ(s.Counters().queuedPrepared, 0u);
  EXPECT_EQ(s.Counters().preparedDropped, 4u);
}

// --- Tests of a move's change (Verify) ------------------------------------------

// A move's test as the server makes it: from the pose of epoch `baseline` to
// the pose of epoch `target`, through one box.
std::shared_ptr<const VerifyContext> MoveTest(uint64_t baseline, uint64_t target) {
  auto from = std::make_shared<ScenePose>();
  from->epoch = baseline;
  auto to = std::make_shared<ScenePose>();
  to->epoch = target;
  Bounds3 box;
  box.Extend(Vec3(0.0f));
  box.Extend(Vec3(1.0f));
  return std::make_shared<const VerifyContext>(VerifyContext{from, to, {box}});
}

// Tests of vertices first .. first + count - 1 under `context`, asked under
// the round of its target epoch as the server asks them; each carries a
// generation and a tolerance of its own (`generation` + v, 0.25 (v + 1)).
std::vector<VerifyRequest> Tests(VertexId first, VertexId count, const std::shared_ptr<const VerifyContext>& context,
                                 uint32_t generation = 100) {
  std::vector<VerifyRequest> out;
  for (VertexId v = first; v < first + count; ++v) {
    VerifyRequest t;
    t.request.vertex = v;
    t.request.position = Vec3(float(v), 1.0f, 2.0f);
    t.request.triangle = v + 7;
    t.request.round = VerifyRound(context->target->epoch);
    t.context = context;
    t.generation = generation + v;
    t.tolerance = 0.25f * float(v + 1);
    out.push_back(t);
  }
  return out;
}

// The renderer's answer to a verification batch, at the batch's pose: every
// sample changed by `change`, with standard error 0.01.
wire::ShadeReply ChangeAnswer(const AssignedBatch& batch, float change = 0.1f, uint32_t remaining = 0) {
  wire::ShadeReply r;
  r.set_batch_id(batch.id);
  r.set_remaining(remaining);
  r.set_scene_epoch(batch.epoch);
  for (const SampleRequest& s : batch.samples) {
    r.add_sample_ids(WireSampleId(s.vertex, s.round));
    r.add_irradiance_change(change);
    r.add_irradiance_change_stderr(0.01f);
  }
  return r;
}

// Shading answers at the batch's pose.
wire::ShadeReply AnswerAtItsEpoch(const AssignedBatch& batch) {
  wire::ShadeReply r = Answer(batch);
  r.set_scene_epoch(batch.epoch);
  return r;
}

// Tests decide whether a vertex a client holds must be shaded again, so they
// go after what views need now or soon and the next move's prepared shading
// (a few hundred first estimates, which thousands of tests queued ahead
// would leave undone until that move came) and before refinement; a batch
// tests against one move's context only, at its target pose, with the
// test's paths.
TEST(SampleScheduler, TestsGoAfterPredictedAndPreparedBeforeBackgroundOneContextPerBatch) {
  FakeClock clock;
  SampleSchedulerOptions o = Options();
  o.verifyPaths = 24;
  SampleScheduler s(o, clock.Function());
  s.SetEpoch(7);
  const auto first = MoveTest(5, 6), second = MoveTest(4, 7);
  s.Request(Requests(0, 4), Priority::kBackground);
  EXPECT_EQ(s.Verify(Tests(10, 3, first)), 3u);
  EXPECT_EQ(s.Verify(Tests(20, 2, second)), 2u);
  EXPECT_EQ(s.Prepare(Requests(30, 2), 8), 2u);
  s.Request(Requests(100, 4), Priority::kPredicted);
  s.Request(Requests(200, 2), Priority::kVisible);
  EXPECT_EQ(s.Counters().queuedVerify, 5u);
  EXPECT_EQ(s.Counters().verifyRequested, 5u);
  EXPECT_EQ(s.Outstanding(), 4u + 5u + 4u + 2u) << "tests are outstanding work, prepared samples are not";
  EXPECT_TRUE(s.AnyAlive(std::vector<VertexId>{21}));
  EXPECT_FALSE(s.AnyAlive(std::vector<VertexId>{22}));
  s.RendererReady(1, kOneCredit);

  std::vector<AssignedBatch> order;
  for (int i = 0; i < 6; ++i) {
    auto batches = s.Assemble();
    ASSERT_EQ(batches.size(), 1u) << "one credit";
    const AssignedBatch& b = batches[0];
    order.push_back(b);
    auto outcome = s.OnReply(1, b.verify ? ChangeAnswer(b) : AnswerAtItsEpoch(b));
    ASSERT_FALSE(outcome.badReply) << *outcome.badReply;
    if (b.verify) {
      EXPECT_TRUE(outcome.results.empty());
      EXPECT_TRUE(outcome.prepared.empty());
      EXPECT_EQ(outcome.verified.size(), b.samples.size());
      s.CompleteVerified(outcome.verified);
    } else {
      EXPECT_TRUE(outcome.verified.empty());
      s.Complete(outcome.results);
      s.CompletePrepared(outcome.prepared);
    }
  }
  EXPECT_TRUE(s.Assemble().empty());
  EXPECT_EQ(VerticesOf({order[0]}), (std::set<VertexId>{200, 201})) << "visible";
  EXPECT_EQ(VerticesOf({order[1]}), (std::set<VertexId>{100, 101, 102, 103})) << "predicted";
  EXPECT_EQ(VerticesOf({order[2]}), (std::set<VertexId>{30, 31})) << "prepared";
  EXPECT_EQ(VerticesOf({order[3]}), (std::set<VertexId>{10, 11, 12})) << "the first move's tests";
  EXPECT_EQ(VerticesOf({order[4]}), (std::set<VertexId>{20, 21})) << "the second move's, in a batch of their own";
  EXPECT_EQ(VerticesOf({order[5]}), (std::set<VertexId>{0, 1, 2, 3})) << "background";
  for (int i : {0, 1, 2, 5}) EXPECT_EQ(order[size_t(i)].verify, nullptr) << i;
  // What a client waits for overtakes the renderer's queue; what one is
  // expected to want (predicted, prepared) overtakes tests and background.
  for (int i = 0; i < 6; ++i) EXPECT_EQ(order[size_t(i)].urgent, i == 0) << i;
  for (int i = 0; i < 6; ++i) EXPECT_EQ(order[size_t(i)].soon, i == 1 || i == 2) << i;
  EXPECT_EQ(order[3].verify, first);
  EXPECT_EQ(order[4].verify, second);
  EXPECT_EQ(order[3].epoch, 6u) << "the context's target pose, not the current epoch";
  EXPECT_EQ(order[4].epoch, 7u);
  for (int i : {3, 4}) {
    const AssignedBatch& b = order[size_t(i)];
    ASSERT_NE(b.verify, nullptr) << i;
    EXPECT_FALSE(b.prepared);
    EXPECT_EQ(b.pathsPerSample, 24u) << "the test's paths";
    for (const SampleRequest& r : b.samples) EXPECT_EQ(r.round, VerifyRound(b.verify->target->epoch));
  }
  EXPECT_TRUE(order[2].prepared);
  EXPECT_EQ(order[2].epoch, 8u);
  EXPECT_EQ(order[5].epoch, 7u);
  EXPECT_EQ(order[5].pathsPerSample, 100u);
  EXPECT_EQ(s.Counters().verified, 5u);
  EXPECT_EQ(s.Counters().queuedVerify, 0u);
  EXPECT_EQ(s.Outstanding(), 0u);
  EXPECT_FALSE(s.AnyAlive(std::vector<VertexId>{10, 11, 12, 20, 21}));
}

// An answer carries the change and its standard error from the renderer and
// the rest from its request: the cache generation to confirm or fail, the
// tolerance, the pose it was tested at, and the request to shade again (as
// a first estimate) when it fails. A batch may come back in parts.
TEST(SampleScheduler, AnsweredTestsComeBackApartWithWhatTheirRequestsCarried) {
  FakeClock clock;
  SampleScheduler s(Options(), clock.Function());
  s.SetEpoch(6);
  const auto move = MoveTest(5, 6);
  s.Verify(Tests(10, 3, move));
  s.RendererReady(1, kOneCredit);
  auto batches = s.Assemble();
  ASSERT_EQ(batches.size(), 1u);
  ASSERT_EQ(batches[0].samples.size(), 3u);
  EXPECT_EQ(s.Outstanding(), 3u) << "in flight";
  EXPECT_EQ(s.Request(Requests(10, 1), Priority::kVisible), 1u) << "a test and a request are apart";
  s.RendererReady(2, kOneCredit);
  auto shading = s.Assemble();
  ASSERT_EQ(shading.size(), 1u);
  ASSERT_EQ(shading[0].verify, nullptr);

  AssignedBatch firstPart = batches[0], rest = batches[0];
  firstPart.samples.resize(1);
  rest.samples.erase(rest.samples.begin());
  wire::ShadeReply part = ChangeAnswer(firstPart, -0.2f, /*remaining=*/2);
  part.set_irradiance_change_stderr(0, 0.05f);
  auto outcome = s.OnReply(1, part);
  ASSERT_FALSE(outcome.badReply) << *outcome.badReply;
  EXPECT_FALSE(outcome.batchDone);
  EXPECT_TRUE(outcome.results.empty());
  ASSERT_EQ(outcome.verified.size(), 1u);
  std::vector<VerifiedSample> verified = outcome.verified;
  outcome = s.OnReply(1, ChangeAnswer(rest, 0.3f));
  ASSERT_FALSE(outcome.badReply) << *outcome.badReply;
  EXPECT_TRUE(outcome.batchDone);
  ASSERT_EQ(outcome.verified.size(), 2u);
  verified.insert(verified.end(), outcome.verified.begin(), outcome.verified.end());

  const std::vector<VerifyRequest> asked = Tests(10, 3, move);
  for (size_t i = 0; i < verified.size(); ++i) {
    const VerifiedSample& v = verified[i];
    const VerifyRequest& a = asked[v.vertex - 10];
    SCOPED_TRACE(v.vertex);
    EXPECT_EQ(v.vertex, batches[0].samples[i].vertex);
    EXPECT_EQ(v.change, i == 0 ? -0.2f : 0.3f);
    EXPECT_EQ(v.changeStdErr, i == 0 ? 0.05f : 0.01f);
    EXPECT_EQ(v.generation, a.generation);
    EXPECT_EQ(v.tolerance, a.tolerance);
    EXPECT_EQ(v.targetEpoch, 6u);
    EXPECT_EQ(v.request.vertex, v.vertex);
    EXPECT_EQ(v.request.position, a.request.position);
    EXPECT_EQ(v.request.triangle, a.request.triangle);
    EXPECT_EQ(v.request.round, 0u) << "shaded again as a first estimate";
  }
  // Answered, not yet acted on: still alive, no longer outstanding.
  EXPECT_EQ(s.Outstanding(), 1u) << "the shading request only";
  EXPECT_TRUE(s.AnyAlive(std::vector<VertexId>{11}));
  EXPECT_EQ(s.Counters().verified, 3u);
  EXPECT_EQ(s.Load(1).samplesShaded, 3u);
  EXPECT_EQ(s.Load(1).samplesInFlight, 0u);
  s.CompleteVerified(verified);
  EXPECT_FALSE(s.AnyAlive(std::vector<VertexId>{11}));
  EXPECT_TRUE(s.AnyAlive(std::vector<VertexId>{10})) << "its shading request is still alive";
  auto shaded = s.OnReply(2, AnswerAtItsEpoch(shading[0]));
  ASSERT_FALSE(shaded.badReply) << *shaded.badReply;
  EXPECT_EQ(shaded.results.size(), 1u);
  EXPECT_TRUE(shaded.verified.empty());
}

// A test's answer is checked like a shading answer: anything not asked, a
// value that is not a number or more than the scene's brightest irradiance,
// or a shading answer, is a bad reply -- the renderer is quarantined and
// every test it had goes back to the queue, none lost.
TEST(SampleScheduler, BadTestRepliesQuarantineTheRendererAndRequeueTheTests) {
  FakeClock clock;
  SampleScheduler s(Options(), clock.Function());  // maxIrradiance 40
  s.SetEpoch(6);
  const auto move = MoveTest(5, 6);
  s.Verify(Tests(10, 3, move));
  using Spoil = std::function<void(wire::ShadeReply&, const AssignedBatch&)>;
  const std::vector<std::tuple<std::string, Spoil, std::string>> spoilers{
      {"another round",
       [](wire::ShadeReply& r, const AssignedBatch& b) {
         r.set_sample_ids(1, WireSampleId(b.samples[1].vertex, VerifyRound(7)));
       },
       "not asked to test"},
      {"a vertex not tested",
       [](wire::ShadeReply& r, const AssignedBatch& b) { r.set_sample_ids(1, WireSampleId(99, b.samples[1].round)); },
       "not asked to test"},
      {"a first estimate's id",
       [](wire::ShadeReply& r, const AssignedBatch& b) { r.set_sample_ids(1, WireSampleId(b.samples[1].vertex, 0)); },
       "not asked to test"},
      {"not a number", [](wire::ShadeReply& r, const AssignedBatch&) { r.set_irradiance_change(1, std::nanf("")); },
       "impossible"},
      {"an infinite change",
       [](wire::ShadeReply& r, const AssignedBatch&) {
         r.set_irradiance_change(2, -std::numeric_limits<float>::infinity());
       },
       "impossible"},
      {"a negative error", [](wire::ShadeReply& r, const AssignedBatch&) { r.set_irradiance_change_stderr(1, -0.5f); },
       "impossible"},
      {"brighter than the brightest", [](wire::ShadeReply& r, const AssignedBatch&) { r.set_irradiance_change(1, 41.0f); },
       "exceeds the scene's brightest irradiance"},
      {"darker than the darkest",
       [](wire::ShadeReply& r, const AssignedBatch&) { r.set_irradiance_change(1, -41.0f); },
       "exceeds the scene's brightest irradiance"},
      {"an error beyond it",
       [](wire::ShadeReply& r, const AssignedBatch&) { r.set_irradiance_change_stderr(2, 41.0f); },
       "exceeds the scene's brightest irradiance"},
      {"a shading answer", [](wire::ShadeReply& r, const AssignedBatch& b) { r = AnswerAtItsEpoch(b); },
       "inconsistent verification arrays"},
      {"another pose", [](wire::ShadeReply& r, const AssignedBatch&) { r.set_scene_epoch(5); }, "scene epoch 5"},
      {"one short",
       [](wire::ShadeReply& r, const AssignedBatch&) {
         r.mutable_sample_ids()->RemoveLast();
         r.mutable_irradiance_change()->RemoveLast();
         r.mutable_irradiance_change_stderr()->RemoveLast();
       },
       "ended with 2 of 3"},
  };
  RendererId renderer = 0;
  uint64_t requeued = 0, rejected = 0;
  for (const auto& [name, spoil, mention] : spoilers) {
    SCOPED_TRACE(name);
    s.RendererReady(++renderer, kOneCredit);  // the ones before are quarantined
    auto batches = s.Assemble();
    ASSERT_EQ(batches.size(), 1u);
    ASSERT_EQ(batches[0].renderer, renderer);
    ASSERT_EQ(batches[0].verify, move);
    ASSERT_EQ(VerticesOf(batches), (std::set<VertexId>{10, 11, 12})) << "every test back, none lost";
    wire::ShadeReply reply = ChangeAnswer(batches[0]);
    spoil(reply, batches[0]);
    auto outcome = s.OnReply(renderer, reply);
    ASSERT_TRUE(outcome.badReply);
    EXPECT_NE(outcome.badReply->find(mention), std::string::npos) << *outcome.badReply;
    EXPECT_TRUE(outcome.verified.empty()) << "nothing of a bad part is taken";
    EXPECT_TRUE(s.Quarantined(renderer));
    EXPECT_EQ(s.Load(renderer).badReplies, 1u);
    EXPECT_EQ(s.Counters().requeued, requeued += 3);
    if (mention.starts_with("exceeds")) ++rejected;
    EXPECT_EQ(s.Counters().rejected, rejected);
    EXPECT_EQ(s.Counters().queuedVerify, 3u);
    EXPECT_EQ(s.Counters().verified, 0u);
    EXPECT_EQ(s.Outstanding(), 3u);
  }
  s.RendererReady(++renderer, kOneCredit);
  auto batches = s.Assemble();
  ASSERT_EQ(batches.size(), 1u);
  auto outcome = s.OnReply(renderer, ChangeAnswer(batches[0]));
  ASSERT_FALSE(outcome.badReply) << *outcome.badReply;
  EXPECT_EQ(outcome.verified.size(), 3u);
}

// A renderer lost, or a batch refused for a passing reason, puts its tests
// back; a batch refused as invalid gives them up as failing (an infinite
// change), so that their vertices are shaded again rather than waited for.
TEST(SampleScheduler, ALostRendererRequeuesItsTestsAndAnInvalidRefusalGivesThemUpAsFailing) {
  FakeClock clock;
  SampleScheduler s(Options(), clock.Function());
  const auto move = MoveTest(5, 6);
  s.Verify(Tests(10, 3, move));
  s.RendererReady(1, kOneCredit);
  auto batches = s.Assemble();
  ASSERT_EQ(batches.size(), 1u);
  EXPECT_EQ(s.Counters().queuedVerify, 0u);
  EXPECT_EQ(s.RendererLost(1), 3u);
  EXPECT_EQ(s.Counters().requeued, 3u);
  EXPECT_EQ(s.Counters().queuedVerify, 3u);
  EXPECT_EQ(s.Outstanding(), 3u);
  EXPECT_EQ(s.Load(1).failures, 1u);

  s.RendererReady(2, kOneCredit);
  batches = s.Assemble();
  ASSERT_EQ(batches.size(), 1u);
  EXPECT_EQ(batches[0].renderer, 2u);
  EXPECT_EQ(batches[0].verify, move);
  EXPECT_EQ(VerticesOf(batches), (std::set<VertexId>{10, 11, 12}));
  auto refused = s.OnBatchRefused(2, batches[0].id, /*invalid=*/false);
  ASSERT_TRUE(refused.has_value());
  EXPECT_TRUE(refused->empty());
  EXPECT_TRUE(s.TakeVerifyGivenUp().empty()) << "requeued, not given up";
  EXPECT_EQ(s.Counters().requeued, 6u);
  EXPECT_EQ(s.Outstanding(), 3u);

  batches = s.Assemble();
  ASSERT_EQ(batches.size(), 1u);
  EXPECT_EQ(VerticesOf(batches), (std::set<VertexId>{10, 11, 12}));
  refused = s.OnBatchRefused(2, batches[0].id, /*invalid=*/true);
  ASSERT_TRUE(refused.has_value());
  EXPECT_TRUE(refused->empty()) << "no black sample stored for a test";
  EXPECT_EQ(s.Counters().failed, 0u);
  EXPECT_EQ(s.Outstanding(), 0u);
  EXPECT_FALSE(s.AnyQueued());
  EXPECT_TRUE(s.Assemble().empty());
  const std::vector<VerifiedSample> givenUp = s.TakeVerifyGivenUp();
  ASSERT_EQ(givenUp.size(), 3u);
  EXPECT_TRUE(s.TakeVerifyGivenUp().empty()) << "taken once";
  const std::vector<VerifyRequest> asked = Tests(10, 3, move);
  std::set<VertexId> vertices;
  for (const VerifiedSample& v : givenUp) {
    SCOPED_TRACE(v.vertex);
    vertices.insert(v.vertex);
    const VerifyRequest& a = asked[v.vertex - 10];
    EXPECT_TRUE(std::isinf(v.change));
    EXPECT_FALSE(v.Passes());
    EXPECT_FALSE(v.Passes(0.0f));
    EXPECT_EQ(v.generation, a.generation);
    EXPECT_EQ(v.tolerance, a.tolerance);
    EXPECT_EQ(v.targetEpoch, 6u);
    EXPECT_EQ(v.request.vertex, v.vertex);
    EXPECT_EQ(v.request.position, a.request.position);
    EXPECT_EQ(v.request.round, 0u);
  }
  EXPECT_EQ(vertices, (std::set<VertexId>{10, 11, 12}));
  EXPECT_TRUE(s.AnyAlive(std::vector<VertexId>{10})) << "until acted on";
  s.CompleteVerified(givenUp);
  EXPECT_FALSE(s.AnyAlive(std::vector<VertexId>{10, 11, 12}));
  EXPECT_FALSE(s.OnBatchRefused(2, batches[0].id, true).has_value()) << "not in flight any more";
}

// One test per vertex at a time: a newer move's test of a queued vertex
// takes the old one's place; one of a vertex whose test is in flight (or
// answered, not yet acted on) waits for CompleteVerified.
TEST(SampleScheduler, ATestAskedAgainReplacesAQueuedOneAndWaitsForOneInFlight) {
  FakeClock clock;
  SampleScheduler s(Options(), clock.Function());
  const auto moveA = MoveTest(1, 2), moveB = MoveTest(2, 3), moveC = MoveTest(3, 4), moveD = MoveTest(4, 5);
  EXPECT_EQ(s.Verify(Tests(0, 1, moveA, 100)), 1u);
  EXPECT_EQ(s.Verify(Tests(0, 1, moveB, 200)), 0u) << "replaces the queued test";
  EXPECT_EQ(s.Verify(std::vector<VerifyRequest>{VerifyRequest{}}), 0u) << "no context: nothing to test";
  EXPECT_EQ(s.Counters().queuedVerify, 1u);
  EXPECT_EQ(s.Counters().verifyRequested, 1u);
  EXPECT_EQ(s.Outstanding(), 1u);
  s.RendererReady(1, RendererCapacity{4, 1000, 32});
  auto batches = s.Assemble();
  ASSERT_EQ(batches.size(), 1u);
  ASSERT_EQ(batches[0].samples.size(), 1u);
  EXPECT_EQ(batches[0].verify, moveB);
  EXPECT_EQ(batches[0].epoch, 3u);
  EXPECT_EQ(batches[0].samples[0].round, VerifyRound(3));

  EXPECT_EQ(s.Verify(Tests(0, 1, moveC, 300)), 0u);
  EXPECT_FALSE(s.AnyQueued()) << "not tested twice at once";
  EXPECT_TRUE(s.Assemble().empty());
  auto outcome = s.OnReply(1, ChangeAnswer(batches[0]));
  ASSERT_FALSE(outcome.badReply) << *outcome.badReply;
  ASSERT_EQ(outcome.verified.size(), 1u);
  EXPECT_EQ(outcome.verified[0].generation, 200u);
  EXPECT_EQ(outcome.verified[0].targetEpoch, 3u);
  EXPECT_TRUE(s.Assemble().empty()) << "answered, not yet acted on";
  s.CompleteVerified(outcome.verified);
  EXPECT_EQ(s.Counters().queuedVerify, 1u);
  EXPECT_EQ(s.Outstanding(), 1u);
  batches = s.Assemble();
  ASSERT_EQ(batches.size(), 1u);
  EXPECT_EQ(batches[0].verify, moveC);
  EXPECT_EQ(batches[0].epoch, 4u);
  EXPECT_EQ(batches[0].samples[0].round, VerifyRound(4));

  // Answered, and asked again before it is acted on.
  outcome = s.OnReply(1, ChangeAnswer(batches[0]));
  ASSERT_EQ(outcome.verified.size(), 1u);
  EXPECT_EQ(outcome.verified[0].generation, 300u);
  EXPECT_EQ(s.Verify(Tests(0, 1, moveD, 400)), 0u);
  EXPECT_TRUE(s.Assemble().empty());
  s.CompleteVerified(outcome.verified);
  batches = s.Assemble();
  ASSERT_EQ(batches.size(), 1u);
  EXPECT_EQ(batches[0].verify, moveD);
  outcome = s.OnReply(1, ChangeAnswer(batches[0]));
  ASSERT_EQ(outcome.verified.size(), 1u);
  EXPECT_EQ(outcome.verified[0].generation, 400u);
  s.CompleteVerified(outcome.verified);
  EXPECT_FALSE(s.AnyAlive(std::vector<VertexId>{0}));
  EXPECT_FALSE(s.AnyQueued());
  EXPECT_EQ(s.Outstanding(), 0u);
  // A stale completion (of a vertex no longer tested) changes nothing.
  s.CompleteVerified(outcome.verified);
  EXPECT_FALSE(s.AnyQueued());
}

// A test requeued (its renderer lost) while a newer move's test of the same
// vertex waited for it is sent as the newer one: the older would only be
// answered for a cache generation that is gone.
TEST(SampleScheduler, ARequeuedTestIsSentAsTheNewerTestThatWaitedForIt) {
  FakeClock clock;
  SampleScheduler s(Options(), clock.Function());
  const auto moveA = MoveTest(1, 2), moveB = MoveTest(2, 3);
  s.Verify(Tests(0, 1, moveA, 100));
  s.RendererReady(1, kOneCredit);
  auto batches = s.Assemble();
  ASSERT_EQ(batches.size(), 1u);
  EXPECT_EQ(batches[0].verify, moveA);
  EXPECT_EQ(s.Verify(Tests(0, 1, moveB, 200)), 0u);
  EXPECT_EQ(s.RendererLost(1), 1u);
  s.RendererReady(2, kOneCredit);
  batches = s.Assemble();
  ASSERT_EQ(batches.size(), 1u);
  EXPECT_EQ(batches[0].verify, moveB);
  EXPECT_EQ(batches[0].epoch, 3u);
  EXPECT_EQ(batches[0].samples[0].round, VerifyRound(3));
  auto outcome = s.OnReply(2, ChangeAnswer(batches[0]));
  ASSERT_FALSE(outcome.badReply) << *outcome.badReply;
  ASSERT_EQ(outcome.verified.size(), 1u);
  EXPECT_EQ(outcome.verified[0].generation, 200u);
  s.CompleteVerified(outcome.verified);
  EXPECT_FALSE(s.AnyQueued()) << "the older test is not sent after it";
  EXPECT_FALSE(s.AnyAlive(std::vector<VertexId>{0}));
}

}  // namespace
}  // namespace penumbra::sma

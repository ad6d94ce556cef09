#include "penumbra/sma/sample_scheduler.h"

#include <algorithm>
#include <limits>

#include <fmt/format.h>

#include "penumbra/common/check.h"

namespace penumbra::sma {

SampleScheduler::SampleScheduler(SampleSchedulerOptions options, Now now)
    : options_(std::move(options)), now_(std::move(now)) {}

// --- Requests -----------------------------------------------------------------

size_t SampleScheduler::Request(std::span<const SampleRequest> samples, Priority priority,
                                std::vector<InterestTicket>* interest) {
  size_t added = 0;
  const bool visible = priority == Priority::kVisible;
  if (priority == Priority::kImprove) {
    for (const SampleRequest& s : samples) {
      auto [it, inserted] = entries_.try_emplace(s.vertex);
      if (!inserted) continue;  // alive already (being shaded or improved): one request at a time
      Entry& e = it->second;
      e.request = s;
      e.serial = ++lastRequestSerial_;
      e.improve = true;
      ++queuedTotal_;
      ++queuedImprove_;
      ++added;
      improveQueue_.push_back(s.vertex);
    }
    return added;
  }
  // One unit of interest for the request of `e`, and its ticket.
  auto addInterest = [&](VertexId v, Entry& e) {
    ++e.interest;
    if (interest) interest->push_back(InterestTicket{v, e.serial});
  };
  for (const SampleRequest& s : samples) {
    auto [it, inserted] = entries_.try_emplace(s.vertex);
    Entry& e = it->second;
    if (inserted) e.serial = ++lastRequestSerial_;
    if (e.improve) {
      // A first estimate of a vertex whose improvement is alive: its sample
      // was invalidated by a move since (the pool asks only for vertices
      // the cache lacks). One in flight will be refused by the cache and
      // retried (Retry) with this interest; one still queued becomes the
      // first estimate now (its copy in the improvement queue is skipped).
      if (visible) addInterest(s.vertex, e);
      if (e.state != EntryState::kQueued) continue;
      e.improve = false;
      e.request = s;
      --queuedImprove_;
      if (priority == Priority::kPredicted) e.predicted = true;
      if (visible) {
        e.inVisibleQueue = true;
        ++queuedVisible_;
        visibleQueue_.push_back(s.vertex);
      } else {
        QueueBelowVisible(s.vertex, e, /*front=*/false);
      }
      continue;
    }
    if (visible) addInterest(s.vertex, e);
    if (inserted) {
      e.request = s;
      e.predicted = priority == Priority::kPredicted;
      ++requested_;
      ++queuedTotal_;
      ++added;
      if (visible) {
        e.inVisibleQueue = true;
        ++queuedVisible_;
        visibleQueue_.push_back(s.vertex);
      } else {
        QueueBelowVisible(s.vertex, e, /*front=*/false);
      }
    } else if (visible && e.state == EntryState::kQueued && !e.inVisibleQueue) {
      // Queued for refinement, a prediction or a past view, now wanted by a
      // view: promote. Its copy in the lower queue is skipped when met.
      if (e.predicted) --queuedPredicted_;
      e.inVisibleQueue = true;
      ++queuedVisible_;
      visibleQueue_.push_back(s.vertex);
    } else if (priority == Priority::kPredicted && !e.predicted) {
      // Queued for refinement (or a past view): a prediction wants it
      // sooner. Where a view wants it too, the visible queue keeps it.
      e.predicted = true;
      if (e.state == EntryState::kQueued && !e.inVisibleQueue) QueueBelowVisible(s.vertex, e, /*front=*/false);
    }
  }
  return added;
}

void SampleScheduler::ReleaseInterest(std::span<const InterestTicket> tickets) {
  for (const InterestTicket& t : tickets) {
    auto it = entries_.find(t.vertex);
    if (it == entries_.end() || it->second.serial != t.request) continue;  // that request has ended
    PENUMBRA_CHECK(it->second.interest > 0, "a live ticket's request has no interest left");
    --it->second.interest;
  }
}

void SampleScheduler::Complete(std::span<const ShadedSample> samples) {
  for (const ShadedSample& s : samples) {
    auto it = entries_.find(s.vertex);
    if (it != entries_.end() && it->second.state == EntryState::kAnswered) entries_.erase(it);
  }
}

void SampleScheduler::Retry(std::span<const VertexId> vertices) {
  for (VertexId v : vertices) {
    auto it = entries_.find(v);
    if (it == entries_.end() || it->second.state != EntryState::kAnswered) continue;
    Entry& e = it->second;
    e.state = EntryState::kQueued;
    e.improve = false;
    e.request.round = 0;
    e.invalidReplies = 0;
    ++queuedTotal_;
    ++retried_;
    if (e.interest > 0) {
      e.inVisibleQueue = true;
      ++queuedVisible_;
      visibleQueue_.push_front(v);
    } else {
      e.inVisibleQueue = false;
      QueueBelowVisible(v, e, /*front=*/true);
    }
  }
}

// --- Prepared shading -----------------------------------------------------------

size_t SampleScheduler::Prepare(std::span<const SampleRequest> samples, uint64_t epoch) {
  // The earlier preparation's samples not sent yet are of no use now.
  preparedDropped_ += TakeQueuedPrepared().size();
  preparedEpoch_ = epoch;
  size_t added = 0;
  for (const SampleRequest& s : samples) {
    auto [it, inserted] = prepared_.try_emplace(s.vertex);
    if (!inserted) continue;  // listed twice, or an earlier preparation's still in flight
    it->second.request = s;
    it->second.request.round = 0;  // a first estimate at the predicted pose
    it->second.epoch = epoch;
    preparedQueue_.push_back(s.vertex);
    ++queuedPrepared_;
    ++added;
  }
  preparedRequested_ += added;
  return added;
}

void SampleScheduler::CompletePrepared(std::span<const ShadedSample> samples) {
  for (const ShadedSample& s : samples) {
    auto it = prepared_.find(s.vertex);
    if (it != prepared_.end() && it->second.state == EntryState::kAnswered) prepared_.erase(it);
  }
}

size_t SampleScheduler::EndPreparation(uint64_t epoch, bool hit, const std::function<bool(VertexId)>& stored) {
  if (epoch != preparedEpoch_) return 0;
  std::vector<SampleRequest> queued = TakeQueuedPrepared();
  if (!hit) {
    preparedDropped_ += queued.size();
    return 0;
  }
  if (stored) std::erase_if(queued, [&](const SampleRequest& r) { return stored(r.vertex); });
  return queued.empty() ? 0 : Request(queued, Priority::kPredicted);
}

std::vector<SampleRequest> SampleScheduler::TakeQueuedPrepared() {
  std::vector<SampleRequest> queued;
  for (auto it = prepared_.begin(); it != prepared_.end();) {
    if (it->second.state == EntryState::kQueued) {
      queued.push_back(it->second.request);
      it = prepared_.erase(it);
    } else {
      ++it;
    }
  }
  preparedQueue_.clear();
  queuedPrepared_ = 0;
  return queued;
}

// --- Tests of a move's change ------------------------------------------------------

namespace {
// Cache slot generations only rise (modulo 2^32).
bool NotOlder(uint32_t a, uint32_t b) { return int32_t(a - b) >= 0; }
}  // namespace

size_t SampleScheduler::Verify(std::span<const VerifyRequest> requests) {
  size_t added = 0;
  for (const VerifyRequest& r : requests) {
    if (!r.context) continue;
    auto [it, inserted] = verify_.try_emplace(r.request.vertex);
    VerifyEntry& e = it->second;
    if (inserted) {
      e.request = r;
      verifyQueue_.push_back(r.request.vertex);
      ++queuedVerify_;
      ++added;
    } else if (e.state == EntryState::kQueued) {
      // A newer move's test replaces the one not sent yet, in its place.
      if (NotOlder(r.generation, e.request.generation)) e.request = r;
    } else if (NotOlder(r.generation, e.request.generation) && (!e.next || NotOlder(r.generation, e.next->generation))) {
      // Tested once the one in flight is answered. A request for an older
      // generation than one already asked for (a retest of a sample a later
      // move has suspected again, racing that move) is of no use: its answer
      // would find the slot changed.
      e.next = r;
    }
  }
  verifyRequested_ += added;
  return added;
}

void SampleScheduler::CompleteVerified(std::span<const VerifiedSample> samples) {
  for (const VerifiedSample& s : samples) {
    auto it = verify_.find(s.vertex);
    if (it == verify_.end() || it->second.state != EntryState::kAnswered) continue;
    VerifyEntry& e = it->second;
    if (!e.next) {
      verify_.erase(it);
      continue;
    }
    e.request = *e.next;
    e.next.reset();
    e.state = EntryState::kQueued;
    verifyQueue_.push_back(s.vertex);
    ++queuedVerify_;
  }
}

bool SampleScheduler::TakeNextVerify(const VerifyContext* context, VertexId& out) {
  while (!verifyQueue_.empty()) {
    const VertexId v = verifyQueue_.front();
    auto it = verify_.find(v);
    if (it == verify_.end() || it->second.state != EntryState::kQueued) {
      verifyQueue_.pop_front();
      continue;
    }
    // One context per batch: a run of the queue. Tests of one move are
    // queued together, so runs are long.
    if (context && it->second.request.context.get() != context) return false;
    verifyQueue_.pop_front();
    --queuedVerify_;
    out = v;
    return true;
  }
  return false;
}

// --- Renderers ------------------------------------------------------------------

void SampleScheduler::RendererReady(RendererId renderer, const RendererCapacity& capacity) {
  Renderer& r = renderers_[renderer];
  r.ready = true;
  r.draining = false;
  r.capacity.maxBatchesInFlight = std::max(1u, std::min(options_.creditsPerRenderer, capacity.maxBatchesInFlight));
  r.capacity.maxBatchSamples = std::max(1u, std::min(options_.maxBatchSamples, capacity.maxBatchSamples));
  r.capacity.defaultPaths = std::max(1u, capacity.defaultPaths);
  r.lastCompletion = now_();
}

void SampleScheduler::RendererDraining(RendererId renderer) {
  if (auto it = renderers_.find(renderer); it != renderers_.end()) it->second.draining = true;
}

size_t SampleScheduler::RendererLost(RendererId renderer) {
  auto it = renderers_.find(renderer);
  if (it == renderers_.end()) return 0;
  Renderer& r = it->second;
  if (r.ready || !r.batches.empty()) ++r.failures;
  r.ready = false;
  r.draining = false;
  const uint64_t before = requeued_;
  RequeueAll(r);
  return size_t(requeued_ - before);
}

void SampleScheduler::RemoveRenderer(RendererId renderer) {
  RendererLost(renderer);
  renderers_.erase(renderer);
}

void SampleScheduler::RequeueAll(Renderer& renderer) {
  // Newest batch first, each to the front: the oldest ends up first in line.
  for (auto it = renderer.batches.rbegin(); it != renderer.batches.rend(); ++it) Requeue(it->first, it->second, nullptr);
  renderer.batches.clear();
  renderer.samplesInFlight = 0;
}

void SampleScheduler::Requeue(uint64_t batchId, const Batch& batch, std::vector<ShadedSample>* givenUpIfInvalid) {
  if (batch.verify) {
    // Back to the front of the test queue; refused as invalid, given up as
    // failing (the vertex is then shaded again, never waited for).
    for (auto v = batch.vertices.rbegin(); v != batch.vertices.rend(); ++v) {
      auto e = verify_.find(*v);
      if (e == verify_.end() || e->second.state != EntryState::kInFlight || e->second.batch != batchId) continue;
      --verifyInFlight_;
      if (givenUpIfInvalid) {
        e->second.state = EntryState::kAnswered;
        VerifiedSample failed;
        failed.vertex = *v;
        failed.change = std::numeric_limits<float>::infinity();
        failed.generation = e->second.request.generation;
        failed.tolerance = e->second.request.tolerance;
        failed.targetEpoch = batch.epoch;
        failed.request = e->second.request.request;
        failed.request.round = 0;
        failed.testRound = e->second.request.request.round;
        failed.context = e->second.request.context;
        verifyGivenUp_.push_back(failed);
        continue;
      }
      e->second.state = EntryState::kQueued;
      // A newer move's test arrived while this one was in flight: send that
      // one (the older one's cache generation is gone), and only that one.
      if (e->second.next) {
        e->second.request = std::move(*e->second.next);
        e->second.next.reset();
      }
      ++queuedVerify_;
      ++requeued_;
      verifyQueue_.push_front(*v);
    }
    return;
  }
  if (batch.prepared) {
    // Back to the front of the prepared queue while their preparation is
    // the current one; else (or refused as invalid: nobody waits for a
    // prepared sample) forgotten.
    for (auto v = batch.vertices.rbegin(); v != batch.vertices.rend(); ++v) {
      auto e = prepared_.find(*v);
      if (e == prepared_.end() || e->second.state != EntryState::kInFlight || e->second.batch != batchId) continue;
      --preparedInFlight_;
      if (givenUpIfInvalid || e->second.epoch != preparedEpoch_) {
        prepared_.erase(e);
        continue;
      }
      e->second.state = EntryState::kQueued;
      ++queuedPrepared_;
      preparedQueue_.push_front(*v);
    }
    return;
  }
  // Back to the front of their queues, in their order: they have waited longest.
  for (auto v = batch.vertices.rbegin(); v != batch.vertices.rend(); ++v) {
    auto e = entries_.find(*v);
    if (e == entries_.end() || e->second.state != EntryState::kInFlight || e->second.batch != batchId) continue;
    Entry& entry = e->second;
    --inFlight_;
    if (givenUpIfInvalid && ++entry.invalidReplies >= 3) {
      // Refused as invalid three times: given up on, stored black with no
      // path (so an improvement of it changes nothing) and nobody waits.
      entry.state = EntryState::kAnswered;
      ++failed_;
      givenUpIfInvalid->push_back(ShadedSample{*v, Rgb(0.0f), Rgb(0.0f), 0.0f, 0, entry.request.round});
      continue;
    }
    entry.state = EntryState::kQueued;
    ++requeued_;
    ++queuedTotal_;
    if (entry.improve) {
      ++queuedImprove_;
      improveQueue_.push_front(*v);
    } else if (entry.interest > 0) {
      entry.inVisibleQueue = true;
      ++queuedVisible_;
      visibleQueue_.push_front(*v);
    } else {
      QueueBelowVisible(*v, entry, /*front=*/true);
    }
  }
}

ReplyOutcome SampleScheduler::Reject(Renderer& renderer, RendererId id, std::string reason) {
  ++renderer.badReplies;
  renderer.quarantinedUntil = now_() + options_.quarantine;
  RendererLost(id);
  ReplyOutcome outcome;
  outcome.badReply = std::move(reason);
  return outcome;
}

ReplyOutcome SampleScheduler::OnReply(RendererId id, const wire::ShadeReply& reply) {
  auto found = renderers_.find(id);
  // A renderer forgotten or lost (its connection closing after a timeout):
  // its work went elsewhere, and a late reply is not its fault.
  if (found == renderers_.end() || !found->second.ready) return {};
  Renderer& renderer = found->second;
  auto it = renderer.batches.find(reply.batch_id());
  if (it == renderer.batches.end())
    return Reject(renderer, id, fmt::format("reply for unknown batch {}", reply.batch_id()));
  const uint64_t batchId = it->first;
  Batch& batch = it->second;
  // The whole part is checked before any of it is taken: a bad sample after
  // good ones drops the renderer, and every sample of the batch (the good
  // ones too) must then still be in flight so that it is requeued, not lost.
  if (reply.scene_epoch() != batch.epoch)
    return Reject(renderer, id,
                  fmt::format("reply for batch {} was shaded at scene epoch {}, but the batch asked for epoch {} "
                              "(a renderer without movable-object support?)",
                              batchId, reply.scene_epoch(), batch.epoch));
  if (batch.verify) return OnVerifyReply(renderer, id, it, reply);
  auto decoded = DecodeShadeReply(reply, batch.paths);
  if (!decoded) return Reject(renderer, id, fmt::format("reply for batch {}: {}", batchId, decoded.error().message));
  for (ShadedSample& sample : *decoded) sample.epoch = batch.epoch;
  // The entry that asked for a sample, in flight in this batch.
  const auto askedHere = [&](const ShadedSample& sample) {
    if (batch.prepared) {
      auto p = prepared_.find(sample.vertex);
      return p != prepared_.end() && p->second.state == EntryState::kInFlight && p->second.batch == batchId &&
             sample.round == 0;
    }
    auto e = entries_.find(sample.vertex);
    return e != entries_.end() && e->second.state == EntryState::kInFlight && e->second.batch == batchId &&
           e->second.request.round == sample.round;
  };
  for (const ShadedSample& sample : *decoded) {
    if (!askedHere(sample))
      return Reject(renderer, id,
                    fmt::format("reply for batch {} names sample {}, which it was not asked for", batchId,
                                WireSampleId(sample.vertex, sample.round)));
    if (auto ok = options_.radianceBounds.Check(sample); !ok) {
      ++rejected_;
      return Reject(renderer, id,
                    fmt::format("reply for batch {}: sample {}: {}", batchId, WireSampleId(sample.vertex, sample.round),
                                ok.error().message));
    }
  }
  const size_t n = decoded->size();
  if (reply.remaining() == 0 && batch.answered + n != batch.vertices.size())
    return Reject(renderer, id,
                  fmt::format("batch {} ended with {} of {} samples", batchId, batch.answered + n, batch.vertices.size()));
  if (batch.prepared) {
    for (const ShadedSample& sample : *decoded) prepared_.at(sample.vertex).state = EntryState::kAnswered;
    preparedInFlight_ -= n;
    preparedShaded_ += n;
  } else {
    for (const ShadedSample& sample : *decoded) entries_.at(sample.vertex).state = EntryState::kAnswered;
    inFlight_ -= n;
    shaded_ += n;
  }
  batch.answered += n;
  renderer.samplesInFlight -= n;
  renderer.shaded += n;
  const bool prepared = batch.prepared;
  ReplyOutcome outcome;
  if (reply.remaining() == 0) {
    EndBatch(renderer, it);
    outcome.batchDone = true;
  }
  (prepared ? outcome.prepared : outcome.results) = std::move(*decoded);
  return outcome;
}

void SampleScheduler::EndBatch(Renderer& renderer, std::map<uint64_t, Batch>::iterator it) {
  const Batch& batch = it->second;
  // Service rate: pipelined batches overlap, so time a batch from the
  // later of its sending and the previous completion. (A test costs about
  // as much per sample as a first estimate: paired paths, fewer bounces.)
  const auto now = now_();
  const double seconds = std::chrono::duration<double>(now - std::max(batch.sentAt, renderer.lastCompletion)).count();
  if (seconds > 0.0) {
    const double rate = double(batch.vertices.size()) / seconds;
    renderer.rate = renderer.rate > 0.0 ? 0.7 * renderer.rate + 0.3 * rate : rate;
  }
  renderer.lastCompletion = now;
  renderer.batches.erase(it);
}

ReplyOutcome SampleScheduler::OnVerifyReply(Renderer& renderer, RendererId id, std::map<uint64_t, Batch>::iterator it,
                                            const wire::ShadeReply& reply) {
  const uint64_t batchId = it->first;
  Batch& batch = it->second;
  std::vector<uint16_t> rounds;
  auto decoded = DecodeVerifyReply(reply, &rounds);
  if (!decoded) return Reject(renderer, id, fmt::format("reply for batch {}: {}", batchId, decoded.error().message));
  for (size_t i = 0; i < decoded->size(); ++i) {
    VerifiedSample& answer = (*decoded)[i];
    auto e = verify_.find(answer.vertex);
    if (e == verify_.end() || e->second.state != EntryState::kInFlight || e->second.batch != batchId ||
        e->second.request.request.round != rounds[i])
      return Reject(renderer, id,
                    fmt::format("reply for batch {} names sample {}, which it was not asked to test", batchId,
                                WireSampleId(answer.vertex, rounds[i])));
    // What the change may physically be: at most the brightest irradiance.
    if (std::abs(answer.change) > options_.radianceBounds.maxIrradiance ||
        answer.changeStdErr > options_.radianceBounds.maxIrradiance) {
      ++rejected_;
      return Reject(renderer, id,
                    fmt::format("reply for batch {}: sample {}: change {} (standard error {}) exceeds the scene's "
                                "brightest irradiance {}",
                                batchId, WireSampleId(answer.vertex, rounds[i]), answer.change, answer.changeStdErr,
                                options_.radianceBounds.maxIrradiance));
    }
    const VerifyRequest& asked = e->second.request;
    answer.generation = asked.generation;
    answer.tolerance = asked.tolerance;
    answer.targetEpoch = batch.epoch;
    answer.request = asked.request;
    answer.request.round = 0;
    answer.testRound = asked.request.round;
    answer.context = asked.context;
  }
  const size_t n = decoded->size();
  if (reply.remaining() == 0 && batch.answered + n != batch.vertices.size())
    return Reject(renderer, id,
                  fmt::format("batch {} ended with {} of {} samples", batchId, batch.answered + n, batch.vertices.size()));
  for (const VerifiedSample& answer : *decoded) verify_.at(answer.vertex).state = EntryState::kAnswered;
  verifyInFlight_ -= n;
  verified_ += n;
  batch.answered += n;
  renderer.samplesInFlight -= n;
  renderer.shaded += n;
  ReplyOutcome outcome;
  if (reply.remaining() == 0) {
    EndBatch(renderer, it);
    outcome.batchDone = true;
  }
  outcome.verified = std::move(*decoded);
  return outcome;
}

std::optional<std::vector<ShadedSample>> SampleScheduler::OnBatchRefused(RendererId id, uint64_t batchId,
                                                                         bool invalid) {
  auto found = renderers_.find(id);
  if (found == renderers_.end()) return std::nullopt;
  Renderer& renderer = found->second;
  auto it = renderer.batches.find(batchId);
  if (it == renderer.batches.end()) return std::nullopt;
  std::vector<ShadedSample> givenUp;
  const Batch batch = std::move(it->second);
  renderer.batches.erase(it);
  renderer.samplesInFlight -= batch.vertices.size() - batch.answered;
  Requeue(batchId, batch, invalid ? &givenUp : nullptr);
  return givenUp;
}

std::vector<std::pair<RendererId, std::string>> SampleScheduler::ExpireTimedOut() {
  std::vector<std::pair<RendererId, std::string>> expired;
  const auto now = now_();
  for (auto& [id, renderer] : renderers_) {
    for (const auto& [batchId, batch] : renderer.batches) {
      if (now - batch.sentAt <= options_.batchTimeout) continue;
      expired.emplace_back(id, fmt::format("batch {} unanswered for {} ms", batchId,
                                           std::chrono::duration_cast<std::chrono::milliseconds>(now - batch.sentAt).count()));
      break;
    }
  }
  for (const auto& e : expired) RendererLost(e.first);
  return expired;
}

// --- Assembly -------------------------------------------------------------------

uint32_t SampleScheduler::Reserved(const Renderer& r) const {
  // A renderer's last free credit waits for samples a client waits for
  // (when it has more than one): those would otherwise queue behind every
  // test, prefetch and refinement batch the renderer already holds.
  const bool last = r.capacity.maxBatchesInFlight > 1 && r.batches.size() + 1 == r.capacity.maxBatchesInFlight;
  return last && queuedVisible_ == 0 ? 1 : 0;
}

bool SampleScheduler::Accepts(const Renderer& r, Clock::time_point now) const {
  return r.ready && !r.draining && r.batches.size() < r.capacity.maxBatchesInFlight && now >= r.quarantinedUntil;
}

void SampleScheduler::QueueBelowVisible(VertexId v, Entry& e, bool front) {
  std::deque<VertexId>& queue = e.predicted ? predictedQueue_ : backgroundQueue_;
  if (e.predicted) ++queuedPredicted_;
  if (front) queue.push_front(v);
  else queue.push_back(v);
}

bool SampleScheduler::TakeNext(Priority priority, VertexId& out) {
  if (priority == Priority::kImprove) {
    while (!improveQueue_.empty()) {
      const VertexId v = improveQueue_.front();
      improveQueue_.pop_front();
      auto it = entries_.find(v);
      if (it == entries_.end() || it->second.state != EntryState::kQueued || !it->second.improve) continue;
      --queuedImprove_;
      out = v;
      return true;
    }
    return false;
  }
  while (priority == Priority::kVisible && !visibleQueue_.empty()) {
    const VertexId v = visibleQueue_.front();
    visibleQueue_.pop_front();
    auto it = entries_.find(v);
    if (it == entries_.end() || it->second.state != EntryState::kQueued || !it->second.inVisibleQueue) continue;
    it->second.inVisibleQueue = false;
    --queuedVisible_;
    if (it->second.interest == 0) {  // every view that wanted it has moved on
      QueueBelowVisible(v, it->second, /*front=*/false);
      continue;
    }
    out = v;
    return true;
  }
  while (priority == Priority::kPredicted && !predictedQueue_.empty()) {
    const VertexId v = predictedQueue_.front();
    predictedQueue_.pop_front();
    auto it = entries_.find(v);
    // A copy also in the visible queue is taken from there.
    if (it == entries_.end() || it->second.state != EntryState::kQueued || it->second.inVisibleQueue ||
        it->second.improve || !it->second.predicted)
      continue;
    --queuedPredicted_;
    out = v;
    return true;
  }
  while (priority == Priority::kBackground && !backgroundQueue_.empty()) {
    const VertexId v = backgroundQueue_.front();
    backgroundQueue_.pop_front();
    auto it = entries_.find(v);
    // A copy also in the visible or predicted queue is taken from there.
    if (it == entries_.end() || it->second.state != EntryState::kQueued || it->second.inVisibleQueue ||
        it->second.improve || it->second.predicted)
      continue;
    out = v;
    return true;
  }
  return false;
}

bool SampleScheduler::TakeNextPrepared(VertexId& out) {
  while (!preparedQueue_.empty()) {
    const VertexId v = preparedQueue_.front();
    preparedQueue_.pop_front();
    auto it = prepared_.find(v);
    if (it == prepared_.end() || it->second.state != EntryState::kQueued) continue;
    --queuedPrepared_;
    out = v;
    return true;
  }
  return false;
}

std::vector<AssignedBatch> SampleScheduler::Assemble() {
  std::vector<AssignedBatch> out;
  const auto now = now_();
  while (AnyQueued()) {
    uint32_t freeCredits = 0;
    for (const auto& [id, r] : renderers_)
      if (Accepts(r, now)) freeCredits += r.capacity.maxBatchesInFlight - uint32_t(r.batches.size()) - Reserved(r);
    if (freeCredits == 0) return out;
    for (auto& [id, r] : renderers_) {
      if (!Accepts(r, now) || r.batches.size() + Reserved(r) >= r.capacity.maxBatchesInFlight) continue;
      // Size by the renderer's measured rate, but when little is queued share
      // it among every free credit so that all renderers work on it.
      const double byRate = r.rate > 0.0 ? r.rate * std::chrono::duration<double>(options_.targetBatchTime).count()
                                         : double(options_.minBatchSamples * 4);
      const size_t fairShare = size_t((queuedTotal_ + queuedPrepared_ + queuedVerify_ + freeCredits - 1) / freeCredits);
      const size_t size = std::clamp<size_t>(std::min<size_t>(size_t(byRate), fairShare), options_.minBatchSamples,
                                             std::max(options_.minBatchSamples, r.capacity.maxBatchSamples));
      // One priority per batch, the most urgent one queued: visible and
      // predicted samples, then prepared ones (the next move's urgent class:
      // a few hundred first estimates that show its shadow the moment it
      // lands), then tests (the current move's held-back indirect class,
      // thousands at a time, which would otherwise keep a renderer busy
      // until the next move came and leave nothing prepared).
      VertexId v = kNoVertex;
      Priority priority = Priority::kVisible;
      bool prepared = false;
      std::shared_ptr<const VerifyContext> verify;
      const auto takeFirst = [&](std::initializer_list<Priority> priorities) {
        for (Priority p : priorities) {
          if (TakeNext(p, v)) {
            priority = p;
            return true;
          }
        }
        return false;
      };
      if (!takeFirst({Priority::kVisible, Priority::kPredicted})) {
        prepared = TakeNextPrepared(v);
        if (!prepared) {
          if (TakeNextVerify(nullptr, v))
            verify = verify_.at(v).request.context;
          else
            takeFirst({Priority::kBackground, Priority::kImprove});
        }
      }
      // Every queued entry sits in one of the queues.
      PENUMBRA_CHECK(v != kNoVertex, fmt::format("{} samples counted as queued but none found",
                                                 queuedTotal_ + queuedPrepared_ + queuedVerify_));
      // Predicted and prepared samples are the first estimates a coming view
      // or move will show.
      const bool firstEstimate = prepared || priority == Priority::kVisible || priority == Priority::kPredicted;
      const uint32_t paths = verify                                           ? (verify->paths > 0 ? verify->paths
                                                                                                   : options_.verifyPaths)
                             : priority == Priority::kImprove                  ? options_.improvePaths
                             : firstEstimate && options_.firstPaths > 0 ? options_.firstPaths
                                                                        : options_.pathsPerSample;
      const uint64_t epoch = verify ? (verify->target ? verify->target->epoch : 0) : prepared ? preparedEpoch_ : epoch_;
      const bool urgent = !verify && !prepared && priority == Priority::kVisible;
      const bool soon = prepared || (!verify && priority == Priority::kPredicted);
      AssignedBatch assigned{id, nextBatchId_++, epoch, paths, prepared, urgent, soon, {}, verify};
      Batch batch;
      batch.prepared = prepared;
      batch.verify = verify;
      batch.paths = paths > 0 ? paths : r.capacity.defaultPaths;
      batch.epoch = epoch;
      batch.sentAt = now;
      const auto takeMore = [&] {
        return verify ? TakeNextVerify(verify.get(), v) : prepared ? TakeNextPrepared(v) : TakeNext(priority, v);
      };
      for (bool first = true; first || (batch.vertices.size() < size && takeMore()); first = false) {
        if (verify) {
          VerifyEntry& e = verify_.at(v);
          e.state = EntryState::kInFlight;
          e.batch = assigned.id;
          ++verifyInFlight_;
          assigned.samples.push_back(e.request.request);
        } else if (prepared) {
          PreparedEntry& e = prepared_.at(v);
          e.state = EntryState::kInFlight;
          e.batch = assigned.id;
          ++preparedInFlight_;
          assigned.samples.push_back(e.request);
        } else {
          Entry& e = entries_.at(v);
          e.state = EntryState::kInFlight;
          e.batch = assigned.id;
          --queuedTotal_;
          ++inFlight_;
          assigned.samples.push_back(e.request);
        }
        batch.vertices.push_back(v);
      }
      r.samplesInFlight += batch.vertices.size();
      r.batches.emplace(assigned.id, std::move(batch));
      out.push_back(std::move(assigned));
      if (!AnyQueued()) return out;
    }
  }
  return out;
}

// --- Observation ----------------------------------------------------------------

bool SampleScheduler::Quarantined(RendererId renderer) const { return QuarantineLeft(renderer).count() > 0; }

std::chrono::milliseconds SampleScheduler::QuarantineLeft(RendererId renderer) const {
  auto it = renderers_.find(renderer);
  if (it == renderers_.end()) return std::chrono::milliseconds(0);
  const auto left = it->second.quarantinedUntil - now_();
  return left.count() > 0 ? std::chrono::ceil<std::chrono::milliseconds>(left) : std::chrono::milliseconds(0);
}

SchedulerCounters SampleScheduler::Counters() const {
  SchedulerCounters c;
  c.queuedVisible = queuedVisible_;
  c.queuedImprove = queuedImprove_;
  c.queuedPredicted = queuedPredicted_;
  const uint64_t above = queuedVisible_ + queuedPredicted_ + queuedImprove_;
  c.queuedBackground = queuedTotal_ >= above ? queuedTotal_ - above : 0;
  c.inFlight = inFlight_;
  c.requested = requested_;
  c.shaded = shaded_;
  c.requeued = requeued_;
  c.failed = failed_;
  c.rejected = rejected_;
  c.retried = retried_;
  c.queuedPrepared = queuedPrepared_;
  c.preparedRequested = preparedRequested_;
  c.preparedShaded = preparedShaded_;
  c.preparedDropped = preparedDropped_;
  c.queuedVerify = queuedVerify_;
  c.verifyRequested = verifyRequested_;
  c.verified = verified_;
  return c;
}

RendererLoad SampleScheduler::Load(RendererId renderer) const {
  RendererLoad load;
  auto it = renderers_.find(renderer);
  if (it == renderers_.end()) return load;
  const Renderer& r = it->second;
  load.ready = r.ready;
  load.batchesInFlight = uint32_t(r.batches.size());
  load.samplesInFlight = r.samplesInFlight;
  load.samplesShaded = r.shaded;
  load.samplesPerSecond = r.rate;
  load.failures = r.failures;
  load.badReplies = r.badReplies;
  return load;
}

}  // namespace penumbra::sma

#include "penumbra/sma/renderer_pool.h"

#include <algorithm>
#include <map>

#include <fmt/format.h>

#include "penumbra/common/logging.h"
#include "penumbra/common/messages.h"
#include "renderer_link.h"

namespace penumbra::sma {

namespace {
using boost::system::error_code;

}  // namespace

std::shared_ptr<RendererPool> RendererPool::Create(asio::io_context& io, RendererPoolOptions options,
                                                   ResultHandler onResults, StoredCheck isStored) {
  return std::shared_ptr<RendererPool>(
      new RendererPool(io, std::move(options), std::move(onResults), std::move(isStored)));
}

RendererPool::RendererPool(asio::io_context& io, RendererPoolOptions options, ResultHandler onResults,
                           StoredCheck isStored)
    : io_(io),
      options_(std::move(options)),
      onResults_(std::move(onResults)),
      isStored_(std::move(isStored)),
      resolveTimer_(io),
      timeoutTimer_(io),
      resolver_(io),
      scheduler_(static_cast<const SampleSchedulerOptions&>(options_)),
      resolved_(options_.renderers.size()) {}

RendererPool::~RendererPool() = default;

void RendererPool::Start() {
  asio::post(io_, [self = shared_from_this()] {
    self->Resolve();
    self->CheckTimeouts();
  });
}

void RendererPool::Stop() {
  std::vector<std::shared_ptr<RendererLink>> links;
  {
    std::lock_guard lock(mutex_);
    stopped_ = true;
    links = links_;
  }
  for (auto& link : links) link->Remove("SMA stopping");
  asio::post(io_, [self = shared_from_this()] {
    self->resolveTimer_.cancel();
    self->timeoutTimer_.cancel();
    self->resolver_.cancel();
  });
}

std::shared_ptr<RendererLink> RendererPool::FindLinkLocked(uint32_t index) const {
  for (const auto& link : links_)
    if (link->Index() == index) return link;
  return nullptr;
}

// --- Resolution -----------------------------------------------------------------

void RendererPool::Resolve() {
  {
    std::lock_guard lock(mutex_);
    if (stopped_) return;
  }
  for (size_t i = 0; i < options_.renderers.size(); ++i) {
    const HostPort& r = options_.renderers[i];
    resolver_.async_resolve(r.host, std::to_string(r.port),
                            [self = shared_from_this(), i](const error_code& ec, tcp::resolver::results_type results) {
                              std::vector<tcp::endpoint> endpoints;
                              for (const auto& entry : results) endpoints.push_back(entry.endpoint());
                              self->OnResolved(i, ec, endpoints);
                            });
  }
  resolveTimer_.expires_after(options_.resolveInterval);
  resolveTimer_.async_wait([self = shared_from_this()](const error_code& ec) {
    if (!ec) self->Resolve();
  });
}

void RendererPool::OnResolved(size_t configured, const error_code& ec, const std::vector<tcp::endpoint>& endpoints) {
  auto log = Logger("sma.renderers");
  std::vector<std::shared_ptr<RendererLink>> removed, added;
  {
    std::lock_guard lock(mutex_);
    if (stopped_) return;
    if (ec || endpoints.empty()) {
      // Keep what we have: a DNS hiccup must not drop working renderers.
      log->warn("cannot resolve renderer {}: {}", options_.renderers[configured].ToString(),
                ec ? ec.message() : std::string("no address"));
      return;
    }
    resolved_[configured] = endpoints;
    std::map<tcp::endpoint, std::string> wanted;  // address -> the configured name it came from
    for (size_t i = 0; i < resolved_.size(); ++i)
      for (const auto& endpoint : resolved_[i]) wanted.emplace(endpoint, options_.renderers[i].host);

    // Renderers that left the name are closed; their work goes to the others.
    for (const auto& link : links_) {
      if (wanted.contains(link->Endpoint())) continue;
      log->info("renderer {} no longer resolves from the configured names; closing", link->Label());
      scheduler_.RemoveRenderer(link->Index());
      removed.push_back(link);
    }
    std::erase_if(links_, [&](const auto& l) { return !wanted.contains(l->Endpoint()); });
    for (const auto& entry : wanted) {
      // Not a structured binding: clang 14 (the fuzz build) cannot capture one in a lambda.
      const tcp::endpoint& endpoint = entry.first;
      const bool known =
          std::any_of(links_.begin(), links_.end(), [&](const auto& l) { return l->Endpoint() == endpoint; });
      if (known) continue;
      std::weak_ptr<RendererPool> weak = shared_from_this();
      RendererLink::Events events{
          [weak](RendererLink& link, const wire::Welcome& w) {
            if (auto self = weak.lock()) self->OnLinkReady(link, w);
          },
          [weak](RendererLink& link, wire::Envelope&& e) {
            if (auto self = weak.lock()) self->OnLinkMessage(link, std::move(e));
          },
          [weak](RendererLink& link, const std::string& reason, bool wasReady) {
            if (auto self = weak.lock()) self->OnLinkClosed(link, reason, wasReady);
          }};
      auto link = RendererLink::Create(io_, options_, endpoint, entry.second, nextLinkIndex_++, std::move(events));
      links_.push_back(link);
      added.push_back(link);
      log->info("renderer endpoint {} added as renderer.{}", link->Label(), link->Index());
    }
  }
  for (auto& link : removed) link->Remove("renderer removed from DNS");
  for (auto& link : added) link->Start();
  Dispatch();
}

// --- Link events ----------------------------------------------------------------

void RendererPool::OnLinkReady(RendererLink& link, const wire::Welcome& w) {
  {
    std::lock_guard lock(mutex_);
    if (stopped_ || !FindLinkLocked(link.Index())) return;
    scheduler_.RendererReady(link.Index(), RendererCapacity{w.max_batches_in_flight(), w.max_batch_samples(),
                                                            w.paths_per_sample()});
  }
  Dispatch();
}

void RendererPool::OnLinkClosed(RendererLink& link, const std::string& reason, bool wasReady) {
  size_t requeued = 0;
  {
    std::lock_guard lock(mutex_);
    requeued = scheduler_.RendererLost(link.Index());
  }
  if (wasReady || requeued > 0)
    Logger("sma.renderers")->warn("renderer {} lost ({}); {} sample(s) go to the others", link.Label(), reason, requeued);
  Dispatch();
}

void RendererPool::OnLinkMessage(RendererLink& link, wire::Envelope&& envelope) {
  auto log = Logger("sma.renderers");
  switch (envelope.body_case()) {
    case wire::Envelope::kShadeReply:
      return OnReply(link, envelope.shade_reply());
    case wire::Envelope::kError: {
      const auto& error = envelope.error();
      const bool invalid = error.code() == wire::ERROR_CODE_INVALID_REQUEST;
      std::optional<std::vector<ShadedSample>> givenUp;
      std::vector<VerifiedSample> testsGivenUp;
      {
        std::lock_guard lock(mutex_);
        if (error.code() == wire::ERROR_CODE_SHUTTING_DOWN) scheduler_.RendererDraining(link.Index());
        // A refused batch: its samples go back to the queue, except those
        // refused as invalid three times, which are given up on (and tests
        // refused as invalid, at once: they fail, and are shaded instead).
        givenUp = scheduler_.OnBatchRefused(link.Index(), error.request_id(), invalid);
        testsGivenUp = scheduler_.TakeVerifyGivenUp();
      }
      if (!testsGivenUp.empty()) FinishVerified(std::move(testsGivenUp));
      if (givenUp && invalid)
        log->error("renderer {} refused batch {}: {}", link.Label(), error.request_id(), error.message());
      else if (!givenUp)
        log->warn("renderer {}: {}: {}", link.Label(), wire::ErrorCode_Name(error.code()), error.message());
      if (givenUp && !givenUp->empty()) onResults_(std::move(*givenUp));
      Dispatch();
      return;
    }
    default:
      return;  // stats replies and the like: nothing to do
  }
}

void RendererPool::OnReply(RendererLink& link, const wire::ShadeReply& reply) {
  ReplyOutcome outcome;
  {
    std::lock_guard lock(mutex_);
    outcome = scheduler_.OnReply(link.Index(), reply);
  }
  if (outcome.badReply) {
    // Quarantine: a renderer that answered nonsense is not retried at once,
    // and its Welcome does not shorten the wait (only a good batch does).
    link.BackOffAtLeast(options_.quarantine);
    Logger("sma.renderers")
        ->warn("renderer {}: bad reply ({}); quarantined for at least {} ms; dropping it", link.Label(),
               *outcome.badReply, link.BackOff().count());
    link.Drop(*outcome.badReply);
  } else if (outcome.batchDone) {
    link.ResetBackOff();  // only a whole batch answered well earns a quick reconnection next time
  }
  Dispatch();
  if (!outcome.results.empty()) onResults_(std::move(outcome.results));
  if (!outcome.prepared.empty()) {
    if (onPrepared_) onPrepared_(std::vector<ShadedSample>(outcome.prepared));
    std::lock_guard lock(mutex_);
    scheduler_.CompletePrepared(outcome.prepared);
  }
  if (!outcome.verified.empty()) FinishVerified(std::move(outcome.verified));
}

void RendererPool::FinishVerified(std::vector<VerifiedSample>&& verified) {
  // Acted on (the cache written, reshades requested) before they are
  // forgotten: a tested vertex is always suspect in the cache, stored, or
  // alive in the pool.
  if (onVerified_) onVerified_(verified);
  {
    std::lock_guard lock(mutex_);
    scheduler_.CompleteVerified(verified);
  }
  PostDispatch();
}

size_t RendererPool::Verify(std::span<const VerifyRequest> requests) {
  size_t added = 0;
  {
    std::lock_guard lock(mutex_);
    added = scheduler_.Verify(requests);
  }
  PostDispatch();
  return added;
}

void RendererPool::CheckTimeouts() {
  std::vector<std::pair<std::shared_ptr<RendererLink>, std::string>> expired;
  {
    std::lock_guard lock(mutex_);
    if (stopped_) return;
    for (auto& [index, reason] : scheduler_.ExpireTimedOut())
      if (auto link = FindLinkLocked(index)) expired.emplace_back(std::move(link), std::move(reason));
  }
  for (auto& [link, reason] : expired) {
    Logger("sma.renderers")->warn("renderer {}: {}; dropping it", link->Label(), reason);
    link->Drop(reason);
  }
  Dispatch();
  timeoutTimer_.expires_after(std::chrono::milliseconds(500));
  timeoutTimer_.async_wait([self = shared_from_this()](const error_code& ec) {
    if (!ec) self->CheckTimeouts();
  });
}

// --- Requests and dispatch --------------------------------------------------------

size_t RendererPool::Request(std::span<const SampleRequest> samples, Priority priority,
                             std::vector<InterestTicket>* interest) {
  size_t added = 0;
  {
    std::lock_guard lock(mutex_);
    if (isStored_ && priority != Priority::kImprove) {
      // Under the lock: a result is stored before it is completed (the
      // pool's lock), so a vertex is here either still alive or seen stored.
      std::vector<SampleRequest> unstored;
      unstored.reserve(samples.size());
      for (const SampleRequest& r : samples)
        if (!isStored_(r.vertex)) unstored.push_back(r);
      added = scheduler_.Request(unstored, priority, interest);
    } else {
      added = scheduler_.Request(samples, priority, interest);
    }
  }
  PostDispatch();
  return added;
}

void RendererPool::PostDispatch() {
  if (dispatchPosted_.exchange(true)) return;
  asio::post(io_, [self = shared_from_this()] {
    self->dispatchPosted_.store(false);
    self->Dispatch();
  });
}

void RendererPool::ReleaseInterest(std::span<const InterestTicket> tickets) {
  std::lock_guard lock(mutex_);
  scheduler_.ReleaseInterest(tickets);
}

bool RendererPool::AnyAlive(std::span<const VertexId> vertices) {
  std::lock_guard lock(mutex_);
  return scheduler_.AnyAlive(vertices);
}

void RendererPool::Complete(std::span<const ShadedSample> samples) {
  std::lock_guard lock(mutex_);
  scheduler_.Complete(samples);
}

void RendererPool::Retry(std::span<const VertexId> vertices) {
  {
    std::lock_guard lock(mutex_);
    scheduler_.Retry(vertices);
  }
  PostDispatch();
}

void RendererPool::SetPose(std::shared_ptr<const ScenePose> pose) {
  std::lock_guard lock(mutex_);
  scheduler_.SetEpoch(pose ? pose->epoch : 0);
  pose_ = std::move(pose);
}

void RendererPool::Prepare(std::span<const SampleRequest> samples, std::shared_ptr<const ScenePose> predicted) {
  if (!predicted) return;
  {
    std::lock_guard lock(mutex_);
    // Under one lock with the scheduler's epoch: a prepared batch is always
    // encoded at the pose its epoch names.
    scheduler_.Prepare(samples, predicted->epoch);
    preparedPose_ = std::move(predicted);
  }
  PostDispatch();
}

void RendererPool::EndPreparation(uint64_t epoch, bool hit) {
  size_t moved = 0;
  {
    std::lock_guard lock(mutex_);
    // As Request: a vertex stored meanwhile is not asked again.
    moved = scheduler_.EndPreparation(epoch, hit, isStored_);
  }
  if (moved > 0) PostDispatch();
}

void RendererPool::Dispatch() {
  std::vector<std::pair<std::shared_ptr<RendererLink>, AssignedBatch>> batches;
  std::shared_ptr<const ScenePose> pose, preparedPose;
  {
    std::lock_guard lock(mutex_);
    if (stopped_ || !scheduler_.AnyQueued()) return;
    // The poses and the batches' epochs are read under one lock: a batch is
    // encoded at the epoch the scheduler expects in its reply.
    pose = pose_;
    preparedPose = preparedPose_;
    for (AssignedBatch& batch : scheduler_.Assemble()) batches.emplace_back(FindLinkLocked(batch.renderer), std::move(batch));
  }
  // Encoded and sent without the pool's lock: a large batch's encoding must
  // not hold up replies, requests and statistics.
  for (auto& [link, batch] : batches) {
    if (!link) continue;  // cannot happen: a renderer leaves the scheduler when its link goes
    const ScenePose* at = batch.prepared ? preparedPose.get() : pose.get();
    auto frame = batch.verify ? EncodeVerifyRequestFrame(batch.id, batch.pathsPerSample, batch.samples, *batch.verify)
                              : EncodeShadeRequestFrame(batch.id, batch.pathsPerSample, batch.samples, at, batch.urgent,
                                                                        batch.soon);
    if (!link->Send(std::move(frame)))
      link->Drop("cannot queue a batch");  // closing requeues it (OnLinkClosed)
  }
}

// --- Observation ----------------------------------------------------------------

size_t RendererPool::Outstanding() const {
  std::lock_guard lock(mutex_);
  return scheduler_.Outstanding();
}

bool RendererPool::AnyRendererReady() const { return ReadyRenderers() > 0; }

size_t RendererPool::ReadyRenderers() const {
  std::lock_guard lock(mutex_);
  return size_t(std::count_if(links_.begin(), links_.end(), [](const auto& l) { return l->Ready(); }));
}

RendererPoolStats RendererPool::Stats() const {
  std::lock_guard lock(mutex_);
  RendererPoolStats s;
  const SchedulerCounters c = scheduler_.Counters();
  s.queuedVisible = c.queuedVisible;
  s.queuedPredicted = c.queuedPredicted;
  s.queuedBackground = c.queuedBackground;
  s.queuedImprove = c.queuedImprove;
  s.inFlight = c.inFlight;
  s.requested = c.requested;
  s.shaded = c.shaded;
  s.requeued = c.requeued;
  s.failed = c.failed;
  s.rejected = c.rejected;
  s.retried = c.retried;
  s.queuedPrepared = c.queuedPrepared;
  s.preparedRequested = c.preparedRequested;
  s.preparedShaded = c.preparedShaded;
  s.preparedDropped = c.preparedDropped;
  s.queuedVerify = c.queuedVerify;
  s.verifyRequested = c.verifyRequested;
  s.verified = c.verified;
  for (const auto& link : links_) {
    const RendererLoad load = scheduler_.Load(link->Index());
    RendererStatus r;
    r.index = link->Index();
    r.endpoint = link->Label();
    r.name = link->PeerName();
    r.connected = link->Ready();
    r.batchesInFlight = load.batchesInFlight;
    r.samplesInFlight = load.samplesInFlight;
    r.samplesShaded = load.samplesShaded;
    r.samplesPerSecond = load.samplesPerSecond;
    r.failures = load.failures;
    r.badReplies = load.badReplies;
    s.renderers.push_back(std::move(r));
  }
  return s;
}

}  // namespace penumbra::sma

#include "penumbra/sma/renderer_pool.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <set>

#include <fmt/format.h>

#include "penumbra/common/check.h"
#include "penumbra/common/logging.h"
#include "penumbra/common/messages.h"

namespace penumbra::sma {

namespace {
using Clock = std::chrono::steady_clock;
using boost::system::error_code;

std::string EndpointLabel(const tcp::endpoint& e) {
  return e.address().is_v6() ? fmt::format("[{}]:{}", e.address().to_string(), e.port())
                             : fmt::format("{}:{}", e.address().to_string(), e.port());
}
}  // namespace

SampleRequest MakeSampleRequest(const Hierarchy& hierarchy, VertexId v) {
  const SampleVertex& sv = hierarchy.GetVertex(v);
  return SampleRequest{v, sv.position, sv.normal, sv.baseTriangle, sv.bary};
}

struct RendererPool::Batch {
  uint64_t id = 0;
  std::vector<VertexId> vertices;
  size_t answered = 0;
  uint32_t paths = 0;  // paths per sample asked for (the renderer's default when the request said 0)
  Clock::time_point sentAt;
};

namespace {
// Wire sample ids: the vertex in the low 32 bits, the improvement round above.
uint64_t WireSampleId(VertexId v, uint16_t round) { return uint64_t(v) | (uint64_t(round) << 32); }
}  // namespace

struct RendererPool::Link {
  Link(asio::io_context& io, tcp::endpoint e, std::string host)
      : endpoint(std::move(e)), host(std::move(host)), label(EndpointLabel(endpoint)), timer(io) {}

  enum class State { kWaiting, kConnecting, kHandshaking, kReady, kRemoved };

  tcp::endpoint endpoint;
  std::string host;  // the configured name it came from: TLS checks the certificate against it
  std::string label;
  uint32_t index = 0;  // RendererStatus::index
  std::shared_ptr<net::Connection> connection;
  State state = State::kWaiting;
  std::chrono::milliseconds backoff{0};
  asio::steady_timer timer;
  std::string peerName;
  uint32_t credits = 0;   // batches in flight allowed
  uint32_t maxBatch = 0;  // samples per batch allowed
  uint32_t defaultPaths = 0;  // its --spp, from its Welcome
  bool draining = false;  // the renderer is shutting down: no new batches
  std::unordered_map<uint64_t, Batch> batches;
  uint64_t samplesInFlight = 0;
  double rate = 0.0;  // samples per second, moving average
  Clock::time_point lastCompletion;
  uint64_t shaded = 0;
  uint32_t failures = 0;
  uint32_t badReplies = 0;
  uint32_t connectFailures = 0;  // in a row; 0 once connected
};

std::shared_ptr<RendererPool> RendererPool::Create(asio::io_context& io, RendererPoolOptions options,
                                                   ResultHandler onResults) {
  return std::shared_ptr<RendererPool>(new RendererPool(io, std::move(options), std::move(onResults)));
}

RendererPool::RendererPool(asio::io_context& io, RendererPoolOptions options, ResultHandler onResults)
    : io_(io),
      options_(std::move(options)),
      onResults_(std::move(onResults)),
      resolveTimer_(io),
      timeoutTimer_(io),
      resolver_(io),
      resolved_(options_.renderers.size()) {}

RendererPool::~RendererPool() = default;

void RendererPool::Start() {
  asio::post(io_, [self = shared_from_this()] {
    self->Resolve();
    self->CheckTimeouts();
  });
}

void RendererPool::Stop() {
  std::vector<std::shared_ptr<net::Connection>> connections;
  {
    std::lock_guard lock(mutex_);
    stopped_ = true;
    for (auto& link : links_) {
      link->state = Link::State::kRemoved;
      if (link->connection) connections.push_back(link->connection);
    }
  }
  for (auto& c : connections) c->Close("SMA stopping");
  asio::post(io_, [self = shared_from_this()] {
    self->resolveTimer_.cancel();
    self->timeoutTimer_.cancel();
    self->resolver_.cancel();
    std::lock_guard lock(self->mutex_);
    for (auto& link : self->links_) link->timer.cancel();
  });
}

// --- Resolution and connections ---------------------------------------------

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
  std::lock_guard lock(mutex_);
  if (stopped_) return;
  auto log = Logger("sma.renderers");
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
  for (auto& link : links_) {
    if (wanted.contains(link->endpoint) || link->state == Link::State::kRemoved) continue;
    log->info("renderer {} no longer resolves from the configured names; closing", link->label);
    link->state = Link::State::kRemoved;
    link->timer.cancel();
    RequeueLocked(*link);
    if (link->connection) link->connection->Close("renderer removed from DNS");
  }
  std::erase_if(links_, [](const auto& l) { return l->state == Link::State::kRemoved; });
  for (const auto& entry : wanted) {
    // Not a structured binding: clang 14 (the fuzz build) cannot capture one in a lambda.
    const tcp::endpoint& endpoint = entry.first;
    const std::string& host = entry.second;
    const bool known = std::any_of(links_.begin(), links_.end(), [&](const auto& l) { return l->endpoint == endpoint; });
    if (known) continue;
    auto link = std::make_shared<Link>(io_, endpoint, host);
    link->index = nextLinkIndex_++;
    link->backoff = options_.reconnectMin;
    links_.push_back(link);
    log->info("renderer endpoint {} added as renderer.{}", link->label, link->index);
    asio::post(io_, [self = shared_from_this(), link] { self->Connect(link); });
  }
  DispatchLocked();
}

void RendererPool::Connect(const std::shared_ptr<Link>& link) {
  {
    std::lock_guard lock(mutex_);
    if (stopped_ || link->state == Link::State::kRemoved) return;
    link->state = Link::State::kConnecting;
  }
  net::AsyncConnectStream(io_, link->endpoint, net::TlsClientTarget{options_.tls, link->host}, options_.connectTimeout,
                    [self = shared_from_this(), link](Expected<net::Stream> stream) {
                      if (!stream) {
                        std::lock_guard lock(self->mutex_);
                        // Said at warning level the first time and then about every reconnectMax, so that an
                        // operator (and the log) hears of a renderer that cannot be reached without a flood.
                        const bool say = link->connectFailures++ == 0 || link->backoff >= self->options_.reconnectMax;
                        Logger("sma.renderers")
                            ->log(say ? spdlog::level::warn : spdlog::level::debug,
                                  "renderer {}: cannot connect ({}); {} sample(s) waiting", link->label, stream.error().message,
                                  self->queuedTotal_);
                        self->ScheduleReconnect(link);
                        return;
                      }
                      self->OnConnected(link, std::move(*stream));
                    });
}

void RendererPool::OnConnected(const std::shared_ptr<Link>& link, net::Stream stream) {
  auto connection = net::Connection::Create(std::move(stream), options_.connection, "renderer " + link->label);
  {
    std::lock_guard lock(mutex_);
    if (stopped_ || link->state == Link::State::kRemoved) {
      connection->Close("SMA stopping");
      return;
    }
    link->connection = connection;
    link->state = Link::State::kHandshaking;
    link->draining = false;
  }
  auto self = shared_from_this();
  connection->Start([self, link](wire::Envelope&& e) { self->OnMessage(link, std::move(e)); },
                    [self, link](const std::string& reason) { self->OnClosed(link, reason); });
  connection->Send(MakeHello(wire::ROLE_SMA, options_.name, options_.sceneHash, options_.authToken));
}

void RendererPool::ScheduleReconnect(const std::shared_ptr<Link>& link) {
  if (stopped_ || link->state == Link::State::kRemoved) return;
  link->state = Link::State::kWaiting;
  link->timer.expires_after(link->backoff);
  link->backoff = std::min(options_.reconnectMax, std::max(options_.reconnectMin, link->backoff * 2));
  link->timer.async_wait([self = shared_from_this(), link](const error_code& ec) {
    if (!ec) self->Connect(link);
  });
}

void RendererPool::OnClosed(const std::shared_ptr<Link>& link, const std::string& reason) {
  std::lock_guard lock(mutex_);
  const bool wasReady = link->state == Link::State::kReady;
  if (!link->batches.empty() || wasReady) {
    ++link->failures;
    Logger("sma.renderers")->warn("renderer {} lost ({}); {} sample(s) go to the others", link->label, reason,
                                  link->samplesInFlight);
  }
  RequeueLocked(*link);
  link->connection.reset();
  if (link->state != Link::State::kRemoved) ScheduleReconnect(link);
  DispatchLocked();
}

void RendererPool::FailLinkLocked(Link& link, const std::string& reason) {
  Logger("sma.renderers")->warn("renderer {}: {}; dropping it", link.label, reason);
  RequeueLocked(link);
  if (link.connection) link.connection->Close(reason);
}

void RendererPool::RequeueLocked(Link& link) {
  for (auto& [id, batch] : link.batches) {
    // Back to the front of the queue: these have waited longest.
    for (auto it = batch.vertices.rbegin(); it != batch.vertices.rend(); ++it) {
      auto e = entries_.find(*it);
      if (e == entries_.end() || e->second.state != EntryState::kInFlight || e->second.batch != id) continue;
      RequeueEntryLocked(*it, e->second);
    }
  }
  link.batches.clear();
  link.samplesInFlight = 0;
}

void RendererPool::RequeueEntryLocked(VertexId v, Entry& entry) {
  // Back to the front of its queue: it has waited longest.
  entry.state = EntryState::kQueued;
  ++requeued_;
  --inFlight_;
  ++queuedTotal_;
  if (entry.improve) {
    ++queuedImprove_;
    improveQueue_.push_front(v);
  } else if (entry.interest > 0) {
    entry.inVisibleQueue = true;
    ++queuedVisible_;
    visibleQueue_.push_front(v);
  } else {
    backgroundQueue_.push_front(v);
  }
}

void RendererPool::CheckTimeouts() {
  {
    std::lock_guard lock(mutex_);
    if (stopped_) return;
    const auto now = Clock::now();
    for (auto& link : links_) {
      for (const auto& [id, batch] : link->batches) {
        if (now - batch.sentAt > options_.batchTimeout) {
          ++link->failures;
          FailLinkLocked(*link, fmt::format("batch {} unanswered for {} ms", id,
                                            std::chrono::duration_cast<std::chrono::milliseconds>(now - batch.sentAt).count()));
          break;
        }
      }
    }
    DispatchLocked();
  }
  timeoutTimer_.expires_after(std::chrono::milliseconds(500));
  timeoutTimer_.async_wait([self = shared_from_this()](const error_code& ec) {
    if (!ec) self->CheckTimeouts();
  });
}

// --- Messages from renderers ------------------------------------------------

Status CheckShadeReplyArrays(const wire::ShadeReply& reply) {
  const int n = reply.sample_ids_size();
  if (reply.radiance_size() != 3 * n || reply.irradiance_size() != 3 * n || reply.irradiance_stderr_size() != n ||
      (reply.sample_paths_size() != 0 && reply.sample_paths_size() != n))
    return Fail(fmt::format("inconsistent arrays ({} ids, {} radiance, {} irradiance, {} stderr, {} path values)", n,
                            reply.radiance_size(), reply.irradiance_size(), reply.irradiance_stderr_size(),
                            reply.sample_paths_size()));
  return Status::Ok();
}

Expected<ShadedSample> ShadedSampleFromReply(const wire::ShadeReply& reply, int i, uint32_t batchPaths) {
  const uint64_t id = reply.sample_ids(i);
  const uint32_t paths = reply.sample_paths_size() == reply.sample_ids_size() ? reply.sample_paths(i) : batchPaths;
  if (paths == 0 || paths > (1u << 24)) return Fail(fmt::format("sample {} averages {} paths", id, paths));
  return ShadedSample{VertexId(id & 0xffffffffu),
                      Rgb(reply.radiance(3 * i), reply.radiance(3 * i + 1), reply.radiance(3 * i + 2)),
                      Rgb(reply.irradiance(3 * i), reply.irradiance(3 * i + 1), reply.irradiance(3 * i + 2)),
                      reply.irradiance_stderr(i), paths, uint16_t(id >> 32)};
}

void RendererPool::OnMessage(const std::shared_ptr<Link>& link, wire::Envelope&& envelope) {
  auto log = Logger("sma.renderers");
  switch (envelope.body_case()) {
    case wire::Envelope::kWelcome: {
      std::lock_guard lock(mutex_);
      const auto& w = envelope.welcome();
      wire::ErrorCode code = wire::ERROR_CODE_UNSPECIFIED;
      if (auto ok = ValidateWelcome(w, wire::ROLE_RENDERER, options_.sceneHash, &code); !ok) {
        log->error("renderer {} refused: {}", link->label, ok.error().message);
        link->backoff = options_.reconnectMax;  // a misconfigured renderer: retry slowly
        if (link->connection) link->connection->Close(ok.error().message);
        return;
      }
      link->state = Link::State::kReady;
      link->connectFailures = 0;
      link->peerName = Printable(w.server_name());
      link->credits = std::max(1u, std::min(options_.creditsPerRenderer, w.max_batches_in_flight()));
      link->maxBatch = std::max(1u, std::min(options_.maxBatchSamples, w.max_batch_samples()));
      link->defaultPaths = std::max(1u, w.paths_per_sample());
      link->lastCompletion = Clock::now();
      log->info("renderer {} ('{}', {} threads) ready", link->label, link->peerName, w.worker_threads());
      DispatchLocked();
      return;
    }
    case wire::Envelope::kShadeReply:
      return OnReply(link, envelope.shade_reply());
    case wire::Envelope::kError: {
      const auto& error = envelope.error();
      std::vector<ShadedSample> failedSamples;
      {
        std::lock_guard lock(mutex_);
        auto it = link->batches.find(error.request_id());
        if (error.code() == wire::ERROR_CODE_SHUTTING_DOWN) link->draining = true;
        if (error.code() == wire::ERROR_CODE_AUTH_FAILED) {
          // Permanent until an operator changes a token or TLS flag: said
          // at error level, retried only every reconnectMax.
          log->error("renderer {} refused this SMA (AUTH_FAILED): {} (check --renderer-auth-token-file and the renderer's "
                     "--auth-token-file); retrying every {} ms",
                     link->label, Printable(error.message(), 256), options_.reconnectMax.count());
          link->backoff = options_.reconnectMax;
          return;
        }
        if (it == link->batches.end()) {
          log->warn("renderer {}: {}: {}", link->label, wire::ErrorCode_Name(error.code()), error.message());
          return;
        }
        // The batch was refused: its samples go back to the queue, except
        // those refused as invalid three times, which are given up on.
        Batch batch = std::move(it->second);
        link->batches.erase(it);
        link->samplesInFlight -= batch.vertices.size() - batch.answered;
        const bool invalid = error.code() == wire::ERROR_CODE_INVALID_REQUEST;
        if (invalid) log->error("renderer {} refused batch {}: {}", link->label, batch.id, error.message());
        for (VertexId v : batch.vertices) {
          auto e = entries_.find(v);
          if (e == entries_.end() || e->second.state != EntryState::kInFlight || e->second.batch != batch.id) continue;
          Entry& entry = e->second;
          if (invalid && ++entry.invalidReplies >= 3) {
            entry.state = EntryState::kAnswered;
            --inFlight_;
            ++failed_;
            // Paths 0: no estimate (an improvement of it changes nothing).
            failedSamples.push_back(ShadedSample{v, Rgb(0.0f), Rgb(0.0f), 0.0f, 0, entry.request.round});
          } else {
            RequeueEntryLocked(v, entry);
          }
        }
        DispatchLocked();
      }
      if (!failedSamples.empty()) onResults_(std::move(failedSamples));
      return;
    }
    default:
      return;  // stats replies and the like: nothing to do
  }
}

void RendererPool::OnReply(const std::shared_ptr<Link>& link, const wire::ShadeReply& reply) {
  std::vector<ShadedSample> results;
  {
    std::lock_guard lock(mutex_);
    auto it = link->batches.find(reply.batch_id());
    if (it == link->batches.end())
      return RejectReplyLocked(*link, fmt::format("reply for unknown batch {}", reply.batch_id()));
    Batch& batch = it->second;
    const int n = reply.sample_ids_size();
    if (auto ok = CheckShadeReplyArrays(reply); !ok)
      return RejectReplyLocked(*link, fmt::format("reply for batch {}: {}", batch.id, ok.error().message));
    // The whole part is checked before any of it is taken: a bad sample after
    // good ones drops the link, and every sample of the batch (the good ones
    // too) must then still be in flight so that it is requeued, not lost.
    results.reserve(size_t(n));
    std::set<uint64_t> seen;
    for (int i = 0; i < n; ++i) {
      const uint64_t id = reply.sample_ids(i);
      const VertexId vertex = VertexId(id & 0xffffffffu);
      const uint64_t round = id >> 32;
      auto e = vertex != kNoVertex ? entries_.find(vertex) : entries_.end();
      if (e == entries_.end() || e->second.state != EntryState::kInFlight || e->second.batch != batch.id ||
          e->second.request.round != round || !seen.insert(id).second)
        return RejectReplyLocked(*link, fmt::format("reply for batch {} names sample {}, which it was not asked for",
                                                    batch.id, id));
      auto decoded = ShadedSampleFromReply(reply, i, batch.paths);
      if (!decoded)
        return RejectReplyLocked(*link, fmt::format("reply for batch {}: {}", batch.id, decoded.error().message));
      const ShadedSample sample = *decoded;
      if (auto ok = options_.radianceBounds.Check(sample); !ok) {
        ++rejectedSamples_;
        return RejectReplyLocked(*link, fmt::format("reply for batch {}: sample {}: {}", batch.id, id,
                                                    ok.error().message));
      }
      results.push_back(sample);
    }
    if (reply.remaining() == 0 && batch.answered + size_t(n) != batch.vertices.size())
      return RejectReplyLocked(*link, fmt::format("batch {} ended with {} of {} samples", batch.id,
                                                  batch.answered + size_t(n), batch.vertices.size()));
    for (const ShadedSample& sample : results) entries_[sample.vertex].state = EntryState::kAnswered;
    batch.answered += size_t(n);
    link->samplesInFlight -= size_t(n);
    link->shaded += size_t(n);
    inFlight_ -= size_t(n);
    shaded_ += size_t(n);
    if (reply.remaining() == 0) {
      // Service rate: pipelined batches overlap, so time a batch from the
      // later of its sending and the previous completion.
      const auto now = Clock::now();
      const double seconds = std::chrono::duration<double>(now - std::max(batch.sentAt, link->lastCompletion)).count();
      if (seconds > 0.0) {
        const double rate = double(batch.vertices.size()) / seconds;
        link->rate = link->rate > 0.0 ? 0.7 * link->rate + 0.3 * rate : rate;
      }
      link->lastCompletion = now;
      // Only a whole batch answered well earns a quick reconnection next time.
      link->backoff = options_.reconnectMin;
      link->batches.erase(it);
    }
    DispatchLocked();
  }
  if (!results.empty()) onResults_(std::move(results));
}

void RendererPool::RejectReplyLocked(Link& link, const std::string& reason) {
  ++link.failures;
  ++link.badReplies;
  // Quarantine: a renderer that answered nonsense is not retried at once,
  // and its Welcome does not shorten the wait (only a good batch does).
  link.backoff = std::max(link.backoff, options_.quarantine);
  Logger("sma.renderers")
      ->warn("renderer {}: bad reply ({}); quarantined for at least {} ms", link.label, reason,
             link.backoff.count());
  FailLinkLocked(link, reason);
}

// --- Requests and scheduling ------------------------------------------------

size_t RendererPool::Request(std::span<const SampleRequest> samples, Priority priority) {
  std::lock_guard lock(mutex_);
  size_t added = 0;
  const bool visible = priority == Priority::kVisible;
  if (priority == Priority::kImprove) {
    for (const SampleRequest& s : samples) {
      auto [it, inserted] = entries_.try_emplace(s.vertex);
      if (!inserted) continue;  // alive already (being shaded or improved): one request at a time
      Entry& e = it->second;
      e.request = s;
      e.improve = true;
      ++queuedTotal_;
      ++queuedImprove_;
      ++added;
      improveQueue_.push_back(s.vertex);
    }
    DispatchLocked();
    return added;
  }
  for (const SampleRequest& s : samples) {
    auto [it, inserted] = entries_.try_emplace(s.vertex);
    Entry& e = it->second;
    if (e.improve) continue;  // its improvement is on the way; a shaded vertex is not asked for again
    if (visible) ++e.interest;
    if (inserted) {
      e.request = s;
      ++requested_;
      ++queuedTotal_;
      ++added;
      if (visible) {
        e.inVisibleQueue = true;
        ++queuedVisible_;
        visibleQueue_.push_back(s.vertex);
      } else {
        backgroundQueue_.push_back(s.vertex);
      }
    } else if (visible && e.state == EntryState::kQueued && !e.inVisibleQueue) {
      // Queued for refinement or a past view, now wanted by a view: promote.
      e.inVisibleQueue = true;
      ++queuedVisible_;
      visibleQueue_.push_back(s.vertex);
    }
  }
  DispatchLocked();
  return added;
}

void RendererPool::ReleaseInterest(std::span<const VertexId> vertices) {
  std::lock_guard lock(mutex_);
  for (VertexId v : vertices) {
    auto it = entries_.find(v);
    if (it != entries_.end() && it->second.interest > 0) --it->second.interest;
  }
}

void RendererPool::Complete(std::span<const ShadedSample> samples) {
  std::lock_guard lock(mutex_);
  for (const ShadedSample& s : samples) {
    auto it = entries_.find(s.vertex);
    if (it != entries_.end() && it->second.state == EntryState::kAnswered) entries_.erase(it);
  }
}

bool RendererPool::TakeNextLocked(Priority priority, VertexId& out) {
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
      backgroundQueue_.push_back(v);
      continue;
    }
    out = v;
    return true;
  }
  while (priority == Priority::kBackground && !backgroundQueue_.empty()) {
    const VertexId v = backgroundQueue_.front();
    backgroundQueue_.pop_front();
    auto it = entries_.find(v);
    // A copy also in the visible queue is taken from there.
    if (it == entries_.end() || it->second.state != EntryState::kQueued || it->second.inVisibleQueue) continue;
    out = v;
    return true;
  }
  return false;
}

void RendererPool::DispatchLocked() {
  if (stopped_) return;
  while (queuedTotal_ > 0) {
    uint32_t freeCredits = 0;
    for (const auto& link : links_)
      if (link->state == Link::State::kReady && !link->draining) freeCredits += link->credits - uint32_t(std::min<size_t>(link->credits, link->batches.size()));
    if (freeCredits == 0) return;
    bool sent = false;
    for (auto& link : links_) {
      if (link->state != Link::State::kReady || link->draining || link->batches.size() >= link->credits) continue;
      // Size by the renderer's measured rate, but when little is queued share
      // it among every free credit so that all renderers work on it.
      const double byRate = link->rate > 0.0 ? link->rate * std::chrono::duration<double>(options_.targetBatchTime).count()
                                              : double(options_.minBatchSamples * 4);
      const size_t fairShare = size_t((queuedTotal_ + freeCredits - 1) / freeCredits);
      const size_t size = std::clamp<size_t>(std::min<size_t>(size_t(byRate), fairShare), options_.minBatchSamples,
                                             std::max(options_.minBatchSamples, link->maxBatch));
      // One priority per batch, the most urgent one queued.
      VertexId v = kNoVertex;
      Priority priority = Priority::kVisible;
      for (Priority p : {Priority::kVisible, Priority::kBackground, Priority::kImprove}) {
        if (TakeNextLocked(p, v)) {
          priority = p;
          break;
        }
      }
      // Every queued entry sits in one of the queues.
      PENUMBRA_CHECK(v != kNoVertex, fmt::format("{} samples counted as queued but none found", queuedTotal_));
      const uint32_t paths = priority == Priority::kImprove ? options_.improvePaths
                             : priority == Priority::kVisible && options_.firstPaths > 0 ? options_.firstPaths
                                                                                       : options_.pathsPerSample;
      Batch batch;
      batch.id = nextBatchId_++;
      batch.paths = paths > 0 ? paths : link->defaultPaths;
      wire::Envelope envelope;
      auto* request = envelope.mutable_shade_request();
      request->set_batch_id(batch.id);
      request->set_paths_per_sample(paths);
      for (bool first = true; first || (batch.vertices.size() < size && TakeNextLocked(priority, v)); first = false) {
        Entry& e = entries_.at(v);
        e.state = EntryState::kInFlight;
        e.batch = batch.id;
        --queuedTotal_;
        ++inFlight_;
        batch.vertices.push_back(v);
        const SampleRequest& r = e.request;
        request->add_sample_ids(WireSampleId(v, r.round));
        for (int k = 0; k < 3; ++k) request->add_positions(r.position[k]);
        for (int k = 0; k < 3; ++k) request->add_normals(r.normal[k]);
        request->add_triangle_ids(r.triangle);
        request->add_barycentrics(r.bary.x);
        request->add_barycentrics(r.bary.y);
      }
      batch.sentAt = Clock::now();
      link->samplesInFlight += batch.vertices.size();
      const uint64_t id = batch.id;
      link->batches.emplace(id, std::move(batch));
      link->connection->Send(envelope);
      sent = true;
      if (queuedTotal_ == 0) return;
    }
    if (!sent) return;
  }
}

// --- Observation ------------------------------------------------------------

size_t RendererPool::Outstanding() const {
  std::lock_guard lock(mutex_);
  return size_t(queuedTotal_ + inFlight_);
}

bool RendererPool::AnyRendererReady() const {
  std::lock_guard lock(mutex_);
  return std::any_of(links_.begin(), links_.end(), [](const auto& l) { return l->state == Link::State::kReady; });
}

size_t RendererPool::ReadyRenderers() const {
  std::lock_guard lock(mutex_);
  return size_t(std::count_if(links_.begin(), links_.end(), [](const auto& l) { return l->state == Link::State::kReady; }));
}

RendererPoolStats RendererPool::Stats() const {
  std::lock_guard lock(mutex_);
  RendererPoolStats s;
  s.queuedVisible = queuedVisible_;
  s.queuedImprove = queuedImprove_;
  s.queuedBackground = queuedTotal_ >= queuedVisible_ + queuedImprove_ ? queuedTotal_ - queuedVisible_ - queuedImprove_ : 0;
  s.inFlight = inFlight_;
  s.requested = requested_;
  s.shaded = shaded_;
  s.requeued = requeued_;
  s.failed = failed_;
  s.rejected = rejectedSamples_;
  for (const auto& link : links_) {
    RendererStatus r;
    r.index = link->index;
    r.endpoint = link->label;
    r.name = link->peerName;
    r.connected = link->state == Link::State::kReady;
    r.batchesInFlight = uint32_t(link->batches.size());
    r.samplesInFlight = link->samplesInFlight;
    r.samplesShaded = link->shaded;
    r.samplesPerSecond = link->rate;
    r.failures = link->failures;
    r.badReplies = link->badReplies;
    s.renderers.push_back(std::move(r));
  }
  return s;
}

}  // namespace penumbra::sma

#pragma once
// The SMA's side of the renderer tier: one RendererLink per renderer address
// (a name that resolves to several addresses gives one link each,
// re-resolved periodically so renderers can come and go), a SampleScheduler
// that decides which samples go where (sample_scheduler.h: at most one
// request per vertex alive, priorities, interest, credits, one requeue path,
// timeouts, quarantine), and the shade codec (shade_codec.h) that turns its
// batches into frames. The pool glues them: link events go to the scheduler,
// the scheduler's batches are encoded and handed to links.
//
// Failure: when a renderer disconnects, times out, or answers nonsense, its
// unanswered samples go back to the front of the queue for the others, and
// it is reconnected with exponential back-off (after a quarantine when it
// answered nonsense).
//
// Threads: every public function is thread-safe. The pool's mutex guards the
// scheduler and the list of links; frames are encoded and sent after it is
// released. The ResultHandler runs on an I/O thread without the pool's lock
// held; the receiver stores the results in the sample cache and *then* calls
// Complete() with them, so that at every moment a vertex is in the cache or
// in the pool (never neither), which is what makes the "requested once" rule
// race-free.

#include <atomic>
#include <chrono>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <unordered_map>
#include <vector>

#include "penumbra/common/connection.h"
#include "penumbra/common/endpoint.h"
#include "penumbra/common/expected.h"
#include "penumbra/sma/hierarchy.h"
#include "penumbra/sma/sample_cache.h"
#include "penumbra/sma/sample_scheduler.h"
#include "penumbra/sma/shade_codec.h"

namespace penumbra::sma {

class RendererLink;

// The scheduling options (paths, credits, batch sizes, timeouts, quarantine,
// radiance bounds) are the scheduler's own; the pool adds the connections'.
struct RendererPoolOptions : SampleSchedulerOptions {
  std::vector<HostPort> renderers;
  uint64_t sceneHash = 0;
  std::string name = "penumbra-sma";
  std::chrono::milliseconds reconnectMin{100};
  std::chrono::milliseconds reconnectMax{5000};
  std::chrono::milliseconds resolveInterval{10000};
  std::chrono::milliseconds connectTimeout{3000};
  net::ConnectionOptions connection;
  /// Sent in every Hello to renderers (their --auth-token-file); empty: none.
  std::string authToken;
  /// TLS to renderers: verify them against this context's CA and the name
  /// each was configured by; null: plain TCP.
  std::shared_ptr<net::ssl::context> tls;
};

struct RendererStatus {
  /// Names the endpoint where clients may look (their counters): 1, 2, ...
  /// in the order endpoints were added, never reused. The log line
  /// "renderer endpoint ADDRESS added as renderer.N" pairs it with its address.
  uint32_t index = 0;
  std::string endpoint;  // its address: for operators (logs), never for clients
  std::string name;  // from its Welcome
  bool connected = false;
  uint32_t batchesInFlight = 0;
  uint64_t samplesInFlight = 0;
  uint64_t samplesShaded = 0;
  double samplesPerSecond = 0.0;  // measured rate (moving average)
  uint32_t failures = 0;          // disconnects, timeouts and bad replies so far
  uint32_t badReplies = 0;        // replies rejected (malformed or impossible radiance)
};

struct RendererPoolStats {
  uint64_t queuedVisible = 0;
  uint64_t queuedPredicted = 0;
  uint64_t queuedBackground = 0;
  uint64_t queuedImprove = 0;
  uint64_t inFlight = 0;
  uint64_t requested = 0;    // distinct samples queued since start
  uint64_t shaded = 0;       // samples answered since start
  uint64_t requeued = 0;     // samples sent again after a renderer failed
  uint64_t failed = 0;       // samples a renderer refused as invalid (stored black)
  uint64_t rejected = 0;     // samples whose radiance was impossible (their renderer was quarantined)
  uint64_t retried = 0;      // samples shaded at a pose a move had changed, asked again
  uint64_t queuedPrepared = 0;     // shading ahead of a predicted move (Prepare), waiting
  uint64_t preparedRequested = 0;  // prepared samples queued since start
  uint64_t preparedShaded = 0;     // prepared samples answered since start
  uint64_t preparedDropped = 0;    // queued prepared samples a newer preparation replaced
  uint64_t queuedVerify = 0;       // tests of a move's change waiting (Verify)
  uint64_t verifyRequested = 0;    // tests queued since start
  uint64_t verified = 0;           // tests answered since start
  std::vector<RendererStatus> renderers;
};

class RendererPool : public std::enable_shared_from_this<RendererPool> {
 public:
  using ResultHandler = std::function<void(std::vector<ShadedSample>&& samples)>;
  /// Whether a vertex's first estimate is stored (SampleCache::IsShaded).
  using StoredCheck = std::function<bool(VertexId)>;

  /// `isStored`: asked under the pool's lock for each first-estimate request,
  /// so that a vertex stored and completed between a caller's look at the
  /// cache and its Request is not asked for again (the cache is written
  /// without the state lock, so that lock no longer orders the two).
  static std::shared_ptr<RendererPool> Create(asio::io_context& io, RendererPoolOptions options,
                                              ResultHandler onResults, StoredCheck isStored = {});
  ~RendererPool();

  /// Resolves the renderer names and connects; returns at once.
  void Start();
  /// Closes every connection; queued work stays queued.
  void Stop();

  /// Queues the samples that are neither alive in the pool nor stored.
  /// Visible requests add one unit of interest to every listed vertex,
  /// queued now or before. Returns the number newly queued. Batches are
  /// assembled and sent on an I/O thread, not the caller's (which may hold
  /// the state lock).
  /// With `interest`, a visible request appends its tickets
  /// (SampleScheduler::Request) for ReleaseInterest.
  size_t Request(std::span<const SampleRequest> samples, Priority priority,
                 std::vector<InterestTicket>* interest = nullptr);
  /// Takes back units of interest (a view moved on; SampleScheduler::ReleaseInterest).
  void ReleaseInterest(std::span<const InterestTicket> tickets);
  /// SampleScheduler::AnyAlive, under the pool's lock.
  bool AnyAlive(std::span<const VertexId> vertices);
  /// The results have been stored: forget these vertices.
  void Complete(std::span<const ShadedSample> samples);
  /// The cache refused these answered vertices (shaded before a move that
  /// invalidated them): ask again as first estimates (SampleScheduler::Retry).
  void Retry(std::span<const VertexId> vertices);
  /// Batches dispatched from now on are shaded at `pose` (its epoch and
  /// transforms; null: a static scene). Thread-safe; a batch assembled
  /// before the call keeps the pose it was assembled with.
  void SetPose(std::shared_ptr<const ScenePose> pose);

  /// Shading ahead of a predicted move (issue 15; SampleScheduler::Prepare):
  /// first estimates of `samples` at `predicted`, a pose that is not current
  /// yet, sent when no visible or predicted sample waits. Replaces the
  /// preparation before. Their answers go to the prepared handler, never to
  /// the result handler. Thread-safe.
  void Prepare(std::span<const SampleRequest> samples, std::shared_ptr<const ScenePose> predicted);
  /// Receives the answers to prepared batches (an I/O thread), each with the
  /// predicted epoch it was shaded at; the pool forgets them after it
  /// returns. Set before Start().
  void SetPreparedHandler(ResultHandler onPrepared) { onPrepared_ = std::move(onPrepared); }
  /// SampleScheduler::EndPreparation (call after SetPose to the pose applied).
  void EndPreparation(uint64_t epoch, bool hit);

  /// Tests of a move's change at samples held back in the cache
  /// (SampleScheduler::Verify). Thread-safe.
  size_t Verify(std::span<const VerifyRequest> requests);
  /// Receives the answers (an I/O thread), with what each request carried;
  /// the pool forgets them after it returns, so it must leave each vertex
  /// stored, suspect, or requested again. Tests a renderer refused as
  /// invalid arrive as failing. Set before Start().
  using VerifiedHandler = std::function<void(const std::vector<VerifiedSample>& verified)>;
  void SetVerifiedHandler(VerifiedHandler onVerified) { onVerified_ = std::move(onVerified); }

  /// Samples queued or in flight.
  size_t Outstanding() const;
  bool AnyRendererReady() const;
  /// Renderers connected and past their handshake (ready for work).
  size_t ReadyRenderers() const;
  RendererPoolStats Stats() const;

 private:
  RendererPool(asio::io_context& io, RendererPoolOptions options, ResultHandler onResults, StoredCheck isStored);

  void Resolve();
  void OnResolved(size_t configured, const boost::system::error_code& ec, const std::vector<tcp::endpoint>& endpoints);
  void OnLinkReady(RendererLink& link, const wire::Welcome& welcome);
  void OnLinkMessage(RendererLink& link, wire::Envelope&& envelope);
  void OnLinkClosed(RendererLink& link, const std::string& reason, bool wasReady);
  void OnReply(RendererLink& link, const wire::ShadeReply& reply);
  void CheckTimeouts();
  // Assembles batches under the lock, then encodes and sends them without it.
  void Dispatch();
  void PostDispatch();  // Dispatch on an I/O thread, once however often asked before it runs
  void FinishVerified(std::vector<VerifiedSample>&& verified);  // the handler, then CompleteVerified
  std::shared_ptr<RendererLink> FindLinkLocked(uint32_t index) const;

  asio::io_context& io_;
  const RendererPoolOptions options_;
  ResultHandler onResults_;
  ResultHandler onPrepared_;
  VerifiedHandler onVerified_;
  StoredCheck isStored_;
  std::atomic<bool> dispatchPosted_{false};
  asio::steady_timer resolveTimer_;
  asio::steady_timer timeoutTimer_;
  tcp::resolver resolver_;

  mutable std::mutex mutex_;
  bool stopped_ = false;
  SampleScheduler scheduler_;
  std::shared_ptr<const ScenePose> pose_;  // batches are encoded at it (null: static scene)
  std::shared_ptr<const ScenePose> preparedPose_;  // prepared batches are encoded at it (Prepare)
  std::vector<std::shared_ptr<RendererLink>> links_;
  uint32_t nextLinkIndex_ = 1;  // RendererStatus::index, and the scheduler's RendererId
  std::vector<std::vector<tcp::endpoint>> resolved_;  // per configured renderer
};

}  // namespace penumbra::sma

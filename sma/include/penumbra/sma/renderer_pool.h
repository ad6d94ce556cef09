#pragma once
// The SMA's side of the renderer tier: one connection per renderer endpoint
// (a name that resolves to several addresses gives one connection each,
// re-resolved periodically so renderers can come and go), and a scheduler
// that turns sample requests into ShadeRequest batches.
//
// Scheduling:
//  * Every vertex is requested at most once while its request is alive:
//    queued, in flight, or answered but not yet stored. Asking again for such
//    a vertex only raises its interest.
//  * Three priorities. Visible requests (a client's view needs the vertex)
//    go before background ones (refinement, or views since superseded), and
//    both before improvements (a further estimate of a shaded vertex, to be
//    averaged into it; SampleCache::Improve). A batch holds one priority
//    only, and asks for that priority's paths per sample: few for visible
//    samples (a first complete image soon), the default for refinement,
//    `improvePaths` for an improvement. An improvement round k of vertex v
//    is the wire sample id v + k * 2^32: its own random stream. A
//    visible request carries one unit of *interest* per asking view; when
//    every view that asked has moved on (ReleaseInterest), it is demoted to
//    background the next time the scheduler meets it.
//  * Credits: each renderer has a bounded number of batches in flight. A
//    renderer that answers faster gets its credits back sooner and so gets
//    more work; batch sizes follow each renderer's measured rate so a batch
//    takes about `targetBatchTime`.
//  * Failure: when a renderer disconnects, times out, or answers nonsense,
//    its unanswered samples go back to the front of the queue for the
//    others, and it is reconnected with exponential back-off.
//
// Threads: every public function is thread-safe. The ResultHandler runs on
// an I/O thread without the pool's lock held; the receiver stores the
// results in the sample cache and *then* calls Complete() with them, so that
// at every moment a vertex is in the cache or in the pool (never neither),
// which is what makes the "requested once" rule race-free.

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

namespace penumbra::sma {

/// The checks on a renderer's ShadeReply part that need no pool state, as
/// plain functions so that they are fuzzed with bytes (tests/fuzz).
/// OK when the part's arrays agree: per sample one id, three radiance, three
/// irradiance and one standard-error value, and no path counts or one each.
Status CheckShadeReplyArrays(const wire::ShadeReply& reply);
/// Sample `i` of a part that passed CheckShadeReplyArrays: vertex (the id's
/// low 32 bits) and round (the rest) from its id, its path count, else
/// `batchPaths`. An error when that count is 0 or above 2^24. Values are not
/// checked here (RadianceBounds::Check).
Expected<ShadedSample> ShadedSampleFromReply(const wire::ShadeReply& reply, int i, uint32_t batchPaths);

/// Everything a renderer needs to shade one vertex.
struct SampleRequest {
  VertexId vertex = kNoVertex;
  Vec3 position;
  Vec3 normal;
  uint32_t triangle = 0;
  Vec2 bary{0.0f};
  uint16_t round = 0;  // 0: first shading; k > 0: the k-th improvement (Priority::kImprove)
};

/// Builds the request for vertex `v` of `hierarchy`.
SampleRequest MakeSampleRequest(const Hierarchy& hierarchy, VertexId v);

enum class Priority : uint8_t { kVisible, kBackground, kImprove };

struct RendererPoolOptions {
  std::vector<HostPort> renderers;
  uint64_t sceneHash = 0;
  std::string name = "penumbra-sma";
  uint32_t pathsPerSample = 0;           // background samples (refinement); 0: each renderer's default
  uint32_t firstPaths = 16;              // visible samples (stage 1); 0: as pathsPerSample
  uint32_t improvePaths = 64;            // each improvement round
  uint32_t creditsPerRenderer = 4;       // batches in flight per renderer (and at most its own limit)
  uint32_t minBatchSamples = 8;
  uint32_t maxBatchSamples = 2048;       // and at most the renderer's own limit
  std::chrono::milliseconds targetBatchTime{150};
  std::chrono::milliseconds batchTimeout{60000};  // a batch unanswered this long drops its renderer
  std::chrono::milliseconds reconnectMin{100};
  std::chrono::milliseconds reconnectMax{5000};
  /// A renderer that sent a bad reply (malformed, or radiance outside
  /// `radianceBounds`) waits at least this long before it is reconnected.
  std::chrono::milliseconds quarantine{30000};
  /// What a sample's radiance may physically be in this scene.
  RadianceBounds radianceBounds;
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
  uint64_t queuedBackground = 0;
  uint64_t queuedImprove = 0;
  uint64_t inFlight = 0;
  uint64_t requested = 0;    // distinct samples queued since start
  uint64_t shaded = 0;       // samples answered since start
  uint64_t requeued = 0;     // samples sent again after a renderer failed
  uint64_t failed = 0;       // samples a renderer refused as invalid (stored black)
  uint64_t rejected = 0;     // samples whose radiance was impossible (their renderer was quarantined)
  std::vector<RendererStatus> renderers;
};

class RendererPool : public std::enable_shared_from_this<RendererPool> {
 public:
  using ResultHandler = std::function<void(std::vector<ShadedSample>&& samples)>;

  static std::shared_ptr<RendererPool> Create(asio::io_context& io, RendererPoolOptions options,
                                              ResultHandler onResults);
  ~RendererPool();

  /// Resolves the renderer names and connects; returns at once.
  void Start();
  /// Closes every connection; queued work stays queued.
  void Stop();

  /// Queues the samples that are not already alive in the pool. Visible
  /// requests add one unit of interest to every listed vertex, queued now
  /// or before. Returns the number newly queued.
  size_t Request(std::span<const SampleRequest> samples, Priority priority);
  /// Removes one unit of interest from each vertex (a view moved on).
  void ReleaseInterest(std::span<const VertexId> vertices);
  /// The results have been stored: forget these vertices.
  void Complete(std::span<const ShadedSample> samples);

  /// Samples queued or in flight.
  size_t Outstanding() const;
  bool AnyRendererReady() const;
  /// Renderers connected and past their handshake (ready for work).
  size_t ReadyRenderers() const;
  RendererPoolStats Stats() const;

  struct Link;
  struct Batch;

 private:
  RendererPool(asio::io_context& io, RendererPoolOptions options, ResultHandler onResults);

  void Resolve();
  void OnResolved(size_t configured, const boost::system::error_code& ec, const std::vector<tcp::endpoint>& endpoints);
  void Connect(const std::shared_ptr<Link>& link);
  void OnConnected(const std::shared_ptr<Link>& link, net::Stream stream);
  void OnMessage(const std::shared_ptr<Link>& link, wire::Envelope&& envelope);
  void OnReply(const std::shared_ptr<Link>& link, const wire::ShadeReply& reply);
  void OnClosed(const std::shared_ptr<Link>& link, const std::string& reason);
  void ScheduleReconnect(const std::shared_ptr<Link>& link);
  void CheckTimeouts();
  void FailLinkLocked(Link& link, const std::string& reason);
  void RequeueLocked(Link& link);
  void RejectReplyLocked(Link& link, const std::string& reason);
  void DispatchLocked();
  bool TakeNextLocked(Priority priority, VertexId& out);
  struct Entry;
  void RequeueEntryLocked(VertexId v, Entry& entry);

  enum class EntryState : uint8_t { kQueued, kInFlight, kAnswered };
  struct Entry {
    SampleRequest request;
    uint32_t interest = 0;
    EntryState state = EntryState::kQueued;
    bool inVisibleQueue = false;
    bool improve = false;  // an improvement (request.round > 0), in the improvement queue
    uint8_t invalidReplies = 0;
    uint64_t batch = 0;  // while in flight: the batch carrying it
  };

  asio::io_context& io_;
  RendererPoolOptions options_;
  ResultHandler onResults_;
  asio::steady_timer resolveTimer_;
  asio::steady_timer timeoutTimer_;
  tcp::resolver resolver_;

  mutable std::mutex mutex_;
  bool stopped_ = false;
  std::unordered_map<VertexId, Entry> entries_;
  std::deque<VertexId> visibleQueue_;
  std::deque<VertexId> backgroundQueue_;
  std::deque<VertexId> improveQueue_;
  std::vector<std::shared_ptr<Link>> links_;
  uint32_t nextLinkIndex_ = 1;  // RendererStatus::index
  std::vector<std::vector<tcp::endpoint>> resolved_;  // per configured renderer
  uint64_t nextBatchId_ = 1;
  uint64_t queuedVisible_ = 0;  // entries queued and in the visible deque
  uint64_t queuedImprove_ = 0;  // entries queued in the improvement deque
  uint64_t queuedTotal_ = 0;
  uint64_t inFlight_ = 0;
  uint64_t requested_ = 0;
  uint64_t shaded_ = 0;
  uint64_t requeued_ = 0;
  uint64_t failed_ = 0;
  uint64_t rejectedSamples_ = 0;
};

}  // namespace penumbra::sma

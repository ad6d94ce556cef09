#pragma once
// Which samples go to which renderer, and when: the renderer pool's
// scheduling without its sockets (renderer_pool.h moves the bytes). Tested
// with a fake clock (sma/tests/sample_scheduler_test.cpp).
//
//  * Every vertex is requested at most once while its request is alive:
//    queued, in flight, or answered but not yet stored (Complete). Asking
//    again for such a vertex only raises its interest.
//  * Four priorities. Visible requests (a client's view needs the vertex)
//    go before predicted ones (a view the client is expected to send soon
//    will need it; camera_prediction.h), which go before background ones
//    (refinement, or views since superseded), and all three before
//    improvements (a further estimate of a shaded vertex;
//    SampleCache::Improve). A batch holds one priority only, and asks for
//    that priority's paths per sample (predicted samples are first
//    estimates like visible ones: stage-1 paths). A visible request carries
//    one unit of *interest* per asking view; when every view that asked has
//    moved on (ReleaseInterest), it is demoted -- to predicted if a
//    prediction also asked for it, else to background -- the next time the
//    scheduler meets it. A predicted request never demotes: a prediction
//    that was wrong has asked for little, and what it asked for is shaded
//    before refinement, which is what the paper's background process does.
//  * Credits: each renderer has a bounded number of batches in flight, so a
//    faster renderer gets its credits back sooner and gets more work; batch
//    sizes follow each renderer's measured rate so a batch takes about
//    `targetBatchTime`, shared among free credits when little is queued.
//    A renderer's last free credit (of two or more) is kept for visible
//    samples, which go as urgent batches (AssignedBatch::urgent) that the
//    renderer shades ahead of what it has queued: a view's samples wait for
//    at most the chunks being shaded, not for every batch in flight.
//    Predicted and prepared batches go as *soon* (AssignedBatch::soon): after
//    the renderer's queued urgent batches, ahead of the rest -- a view that
//    needs a vertex already in flight in one waits for that batch.
//  * One requeue path (Requeue): whatever takes samples back from a renderer
//    -- loss, timeout, bad reply, a refused batch -- puts them back at the
//    front of their queue.
//  * Quarantine: a renderer that answered nonsense gets no work until
//    `quarantine` has passed on the scheduler's clock.
//  * Prepared shading (issue 15, moving objects): first estimates at a
//    *predicted* scene pose, one not current yet (Prepare), kept apart from
//    the requests above -- a vertex may be alive in both -- and assembled
//    after visible and predicted samples, before tests and background ones
//    (the next move's urgent class, a few hundred first estimates: behind
//    a move's thousands of tests they would not be done before it came). Their
//    batches carry the predicted epoch and their results come back apart
//    (ReplyOutcome::prepared): nothing about them reaches the cache unless
//    the move they were prepared for happens as predicted (move_prediction.h).
//  * Tests (issue 14, docs/moving-objects.md "A test instead of a bound"):
//    verification requests (Verify) ask a renderer for the change a move
//    made to static samples held back in the cache (SampleCache::Suspect),
//    kept apart like prepared shading -- a vertex may be alive in both --
//    and assembled after visible, predicted and prepared samples, before
//    background ones (a test decides whether a vertex a client holds must
//    be shaded again, and costs a fraction of shading it). A batch tests
//    against one VerifyContext only. Their answers come back apart
//    (ReplyOutcome::verified). A renderer lost puts them back in the queue; a
//    batch refused as invalid gives them up as failed (TakeVerifyGivenUp),
//    so that the vertex is shaded again rather than waited for.
//
// Threads: not synchronised; the pool calls it under its own mutex.

#include <chrono>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <optional>
#include <span>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "penumbra/sma/sample_cache.h"
#include "penumbra/sma/shade_codec.h"
#include "penumbra/wire.pb.h"

namespace penumbra::sma {

enum class Priority : uint8_t { kVisible, kPredicted, kBackground, kImprove };

/// One unit of interest a visible request gave a vertex's request, as
/// ReleaseInterest takes it back: the vertex and the serial of the request
/// it went to. A request ends when its sample is stored (Complete); the
/// collector may then free the vertex and a split reuse its id for a new
/// vertex, whose request must not lose interest that was never its own.
struct InterestTicket {
  VertexId vertex = kNoVertex;
  uint64_t request = 0;
  friend bool operator==(const InterestTicket&, const InterestTicket&) = default;
};

struct SampleSchedulerOptions {
  uint32_t pathsPerSample = 0;      // background samples (refinement); 0: each renderer's default
  // Visible samples (stage 1); 0: as pathsPerSample. 8 puts a new Sponza view's
  // first complete image under 300 ms on two cores (docs/refinement.md); the
  // improvement rounds average their paths in, so nothing shaded is wasted.
  uint32_t firstPaths = 8;
  uint32_t improvePaths = 64;       // each improvement round
  uint32_t verifyPaths = 64;        // paired samples of each move's test (Verify)
  uint32_t creditsPerRenderer = 4;  // batches in flight per renderer (and at most its own limit)
  uint32_t minBatchSamples = 8;
  uint32_t maxBatchSamples = 2048;  // and at most the renderer's own limit
  std::chrono::milliseconds targetBatchTime{150};
  std::chrono::milliseconds batchTimeout{60000};  // a batch unanswered this long drops its renderer
  std::chrono::milliseconds quarantine{30000};    // no work for a renderer after a bad reply
  /// What a sample's radiance may physically be in this scene.
  RadianceBounds radianceBounds;
};

/// A renderer's limits, from its Welcome.
struct RendererCapacity {
  uint32_t maxBatchesInFlight = 1;
  uint32_t maxBatchSamples = 1;
  uint32_t defaultPaths = 1;  // its --spp: what a request for 0 paths gets
};

/// Identifies a renderer to the scheduler (the pool uses RendererStatus::index).
using RendererId = uint32_t;

/// A batch assigned to a renderer, for its link to encode and send.
struct AssignedBatch {
  RendererId renderer = 0;
  uint64_t id = 0;
  uint64_t epoch = 0;           // the scene epoch (pose) it is to be shaded at (SetEpoch)
  uint32_t pathsPerSample = 0;  // as sent (0: the renderer's default)
  bool prepared = false;        // shading ahead of a predicted move (Prepare): `epoch` is the predicted pose's
  /// Visible priority: a client waits for it, so the renderer shades it
  /// ahead of the batches it has queued (ShadeRequest::urgent).
  bool urgent = false;
  /// Predicted or prepared first estimates: a client is expected to want
  /// them soon, so the renderer shades them after its queued urgent batches,
  /// ahead of the rest (ShadeRequest::soon). A view that needs a vertex
  /// already in flight waits for that batch, so it must not sit behind
  /// refinement.
  bool soon = false;
  std::vector<SampleRequest> samples;
  /// Set: a verification batch (Verify) testing `samples` against it;
  /// `epoch` is its target pose's.
  std::shared_ptr<const VerifyContext> verify;
};

/// What a reply part came to.
struct ReplyOutcome {
  std::vector<ShadedSample> results;  // to store, then Complete()
  /// Answers to a prepared batch (Prepare): shaded at its predicted epoch
  /// (ShadedSample::epoch), for the caller to keep, then CompletePrepared().
  std::vector<ShadedSample> prepared;
  /// Answers to a verification batch (Verify), with what their requests
  /// carried, for the caller to act on, then CompleteVerified().
  std::vector<VerifiedSample> verified;
  /// Set when the reply was nonsense: the renderer's batches were requeued
  /// and it is quarantined; its link should be dropped.
  std::optional<std::string> badReply;
  bool batchDone = false;  // the part ended a batch answered well
};

/// One renderer as the scheduler sees it (for statistics).
struct RendererLoad {
  bool ready = false;
  uint32_t batchesInFlight = 0;
  uint64_t samplesInFlight = 0;
  uint64_t samplesShaded = 0;
  double samplesPerSecond = 0.0;  // moving average
  uint32_t failures = 0;          // losses, timeouts and bad replies
  uint32_t badReplies = 0;
};

struct SchedulerCounters {
  uint64_t queuedVisible = 0;
  uint64_t queuedPredicted = 0;
  uint64_t queuedBackground = 0;
  uint64_t queuedImprove = 0;
  uint64_t inFlight = 0;
  uint64_t requested = 0;  // distinct samples queued since start
  uint64_t shaded = 0;     // samples answered since start
  uint64_t requeued = 0;   // samples sent again after a renderer failed
  uint64_t failed = 0;     // samples a renderer refused as invalid three times (stored black)
  uint64_t rejected = 0;   // samples whose radiance was impossible (their renderer was quarantined)
  uint64_t retried = 0;    // samples shaded at a pose a move had changed, asked again (Retry)
  uint64_t queuedPrepared = 0;    // prepared samples (Prepare) waiting
  uint64_t preparedRequested = 0;  // prepared samples queued since start
  uint64_t preparedShaded = 0;     // prepared samples answered since start
  uint64_t preparedDropped = 0;    // queued prepared samples a newer preparation replaced
  uint64_t queuedVerify = 0;       // tests (Verify) waiting
  uint64_t verifyRequested = 0;    // tests queued since start
  uint64_t verified = 0;           // tests answered since start
};

class SampleScheduler {
 public:
  using Clock = std::chrono::steady_clock;
  /// The clock every time is read from; tests give a fake one.
  using Now = std::function<Clock::time_point()>;

  explicit SampleScheduler(SampleSchedulerOptions options, Now now = &Clock::now);

  // --- Requests (any client's work) ---
  /// Queues the samples that are not already alive. Visible requests add one
  /// unit of interest to every listed vertex, queued now or before, and
  /// append a ticket for each to `interest` when given. Returns the number
  /// newly queued.
  size_t Request(std::span<const SampleRequest> samples, Priority priority,
                 std::vector<InterestTicket>* interest = nullptr);
  /// Takes back the units of interest of `tickets` (a view moved on). A
  /// ticket whose request has ended since is ignored, also when its vertex id
  /// has a new request now.
  void ReleaseInterest(std::span<const InterestTicket> tickets);
  /// Whether any of `vertices` is alive: queued, in flight or answered and
  /// not yet completed (the collector never frees such a vertex: its reply
  /// would land in a reused slot).
  bool AnyAlive(std::span<const VertexId> vertices) const {
    for (VertexId v : vertices)
      if (entries_.contains(v) || prepared_.contains(v) || verify_.contains(v)) return true;
    return false;
  }
  /// The results have been stored: forget these vertices.
  void Complete(std::span<const ShadedSample> samples);
  /// These answered vertices were refused by the cache (shaded at a pose a
  /// move has since changed; SampleCache::Store): ask again, as first
  /// estimates (an improvement becomes one), at the front of their queue --
  /// visible while a view is interested. Vertices not answered are ignored.
  void Retry(std::span<const VertexId> vertices);
  /// Batches assembled from now on are shaded at `epoch` (the scene pose
  /// the pool encodes them with). A reply must name its batch's epoch.
  void SetEpoch(uint64_t epoch) { epoch_ = epoch; }
  uint64_t Epoch() const { return epoch_; }

  // --- Prepared shading (a predicted move's; see the file comment) ---
  /// Queues first estimates of `samples` at scene epoch `epoch`, a pose
  /// predicted for a coming move (the pool encodes these batches with it).
  /// Replaces the preparation before: its samples still queued are dropped;
  /// those in flight are answered as usual. A vertex whose earlier prepared
  /// sample is still in flight is skipped. Returns the number queued.
  size_t Prepare(std::span<const SampleRequest> samples, uint64_t epoch);
  /// The prepared answers have been kept or stored: forget these vertices.
  void CompletePrepared(std::span<const ShadedSample> samples);
  /// The move prepared for at `epoch` has been applied. `hit`: where
  /// predicted, so the epoch's prepared samples still queued are wanted at
  /// the current pose: they become ordinary requests at predicted priority
  /// (a view's visible request then promotes them as usual). Otherwise they
  /// are dropped. Those in flight are answered either way. `stored` (when
  /// given) names vertices whose sample is in the cache already: not asked
  /// again. Returns the number of requests made.
  size_t EndPreparation(uint64_t epoch, bool hit, const std::function<bool(VertexId)>& stored = {});
  uint64_t PreparedEpoch() const { return preparedEpoch_; }

  // --- Tests of a move's change (see the file comment) ---
  /// Queues tests. A vertex already queued for a test takes the new request
  /// (a newer move's: it replaces the old in place); one in flight is
  /// tested again with it once answered (CompleteVerified), or with it
  /// instead when the old test goes back to the queue (a renderer lost). A
  /// request for an older cache generation than the vertex's queued, in
  /// flight or waiting one is ignored (its answer could only be stale).
  /// Returns the number newly queued.
  size_t Verify(std::span<const VerifyRequest> requests);
  /// The answers have been acted on: forget these vertices (or queue the
  /// request that arrived while they were in flight).
  void CompleteVerified(std::span<const VerifiedSample> samples);
  /// Tests given up because a renderer refused their batch as invalid,
  /// answered as failing (an infinite change): the caller acts on them as
  /// on any failed test, then CompleteVerified().
  std::vector<VerifiedSample> TakeVerifyGivenUp() { return std::exchange(verifyGivenUp_, {}); }

  // --- Renderers (events from their links) ---
  /// Connected and past its handshake: it may get work (unless quarantined).
  void RendererReady(RendererId renderer, const RendererCapacity& capacity);
  /// It is shutting down: no new batches, its batches in flight may still end.
  void RendererDraining(RendererId renderer);
  /// It is gone (closed, removed from DNS, dropped): its unanswered samples
  /// go back to the front of their queues. A renderer that was ready or had
  /// work counts a failure. Returns the samples requeued.
  size_t RendererLost(RendererId renderer);
  /// Forgets a renderer that will not come back (after RendererLost).
  void RemoveRenderer(RendererId renderer);

  /// A reply part: checked against what the batch asked for (ids, rounds,
  /// counts, RadianceBounds, the scene epoch it was sent at -- a renderer
  /// that shaded at another pose, e.g. one that ignores movable objects,
  /// answered nonsense) as a whole before any sample is taken, so a bad
  /// part requeues every sample of the renderer. A renderer that is not
  /// ready (lost, timed out: its work already requeued) is not listened to.
  ReplyOutcome OnReply(RendererId renderer, const wire::ShadeReply& reply);
  /// The renderer refused a batch (an Error naming it). Its samples are
  /// requeued, except those refused as invalid three times: they are given
  /// up on and returned as black samples of no path, to be stored so that
  /// nobody waits for them. Nothing for a batch it does not have in flight.
  std::optional<std::vector<ShadedSample>> OnBatchRefused(RendererId renderer, uint64_t batchId, bool invalid);

  /// Renderers with a batch unanswered for longer than `batchTimeout`, each
  /// with the reason; their work is already requeued (RendererLost), the
  /// caller drops their links.
  std::vector<std::pair<RendererId, std::string>> ExpireTimedOut();

  /// Assigns queued samples to renderers with free credits, most urgent
  /// priority first. Encoding and sending is the caller's (outside its lock).
  std::vector<AssignedBatch> Assemble();

  // --- Observation ---
  /// Requested samples queued or in flight (prepared ones not included:
  /// nobody waits for them).
  size_t Outstanding() const { return size_t(queuedTotal_ + inFlight_ + queuedVerify_ + verifyInFlight_); }
  size_t Queued() const { return size_t(queuedTotal_); }
  /// Anything to assemble: requested or prepared samples queued.
  bool AnyQueued() const { return queuedTotal_ + queuedPrepared_ + queuedVerify_ > 0; }
  bool Quarantined(RendererId renderer) const;
  /// How long a renderer must still wait before it may be reconnected.
  std::chrono::milliseconds QuarantineLeft(RendererId renderer) const;
  SchedulerCounters Counters() const;
  RendererLoad Load(RendererId renderer) const;

 private:
  enum class EntryState : uint8_t { kQueued, kInFlight, kAnswered };
  struct Entry {
    SampleRequest request;
    uint64_t serial = 0;  // this request's, unique over the scheduler's life (InterestTicket)
    uint32_t interest = 0;
    EntryState state = EntryState::kQueued;
    bool inVisibleQueue = false;
    // A prediction asked for it: when not in the visible queue, its place is
    // the predicted queue (not the background one).
    bool predicted = false;
    bool improve = false;  // an improvement (request.round > 0), in the improvement queue
    uint8_t invalidReplies = 0;
    uint64_t batch = 0;  // while in flight: the batch carrying it
  };
  struct PreparedEntry {
    SampleRequest request;
    uint64_t epoch = 0;
    EntryState state = EntryState::kQueued;
    uint64_t batch = 0;
  };
  struct VerifyEntry {
    VerifyRequest request;
    EntryState state = EntryState::kQueued;
    uint64_t batch = 0;
    std::optional<VerifyRequest> next;  // arrived while in flight: tested after
  };
  struct Batch {
    bool prepared = false;  // its vertices are in prepared_, not entries_
    std::shared_ptr<const VerifyContext> verify;  // set: its vertices are in verify_
    std::vector<VertexId> vertices;
    size_t answered = 0;
    uint32_t paths = 0;  // paths per sample asked for (the renderer's default when the request said 0)
    uint64_t epoch = 0;  // the scene epoch it was sent at
    Clock::time_point sentAt;
  };
  struct Renderer {
    bool ready = false;
    bool draining = false;
    RendererCapacity capacity;
    std::map<uint64_t, Batch> batches;  // by id: oldest first
    uint64_t samplesInFlight = 0;
    double rate = 0.0;
    Clock::time_point lastCompletion;
    Clock::time_point quarantinedUntil;
    uint64_t shaded = 0;
    uint32_t failures = 0;
    uint32_t badReplies = 0;
  };

  bool Accepts(const Renderer& r, Clock::time_point now) const;
  /// Credits of `r` kept free for visible samples now (0 or 1).
  uint32_t Reserved(const Renderer& r) const;
  bool TakeNext(Priority priority, VertexId& out);
  bool TakeNextPrepared(VertexId& out);
  // The next queued test; with `context`, only one of that context.
  bool TakeNextVerify(const VerifyContext* context, VertexId& out);
  // Removes every prepared sample not sent yet; returns their requests.
  std::vector<SampleRequest> TakeQueuedPrepared();
  // A queued first estimate not wanted by a view: to the predicted queue if
  // a prediction asked for it, else to the background queue.
  void QueueBelowVisible(VertexId v, Entry& e, bool front);
  // The one requeue path: a batch's unanswered samples back to the front of
  // their queues, oldest first.
  // `givenUpIfInvalid`: the batch was refused as invalid; entries refused
  // so three times are given up on (appended there) instead.
  void Requeue(uint64_t batchId, const Batch& batch, std::vector<ShadedSample>* givenUpIfInvalid);
  void RequeueAll(Renderer& renderer);
  ReplyOutcome Reject(Renderer& renderer, RendererId id, std::string reason);
  ReplyOutcome OnVerifyReply(Renderer& renderer, RendererId id, std::map<uint64_t, Batch>::iterator batch,
                             const wire::ShadeReply& reply);
  // The batch's last part arrived: its renderer's rate, and it is forgotten.
  void EndBatch(Renderer& renderer, std::map<uint64_t, Batch>::iterator batch);

  SampleSchedulerOptions options_;
  Now now_;
  std::unordered_map<VertexId, Entry> entries_;
  std::deque<VertexId> visibleQueue_;
  std::deque<VertexId> predictedQueue_;
  std::deque<VertexId> backgroundQueue_;
  std::deque<VertexId> improveQueue_;
  std::unordered_map<VertexId, PreparedEntry> prepared_;
  std::deque<VertexId> preparedQueue_;
  uint64_t preparedEpoch_ = 0;
  uint64_t queuedPrepared_ = 0;
  uint64_t preparedInFlight_ = 0;
  uint64_t preparedRequested_ = 0;
  uint64_t preparedShaded_ = 0;
  uint64_t preparedDropped_ = 0;
  std::unordered_map<VertexId, VerifyEntry> verify_;
  std::deque<VertexId> verifyQueue_;
  uint64_t queuedVerify_ = 0;
  uint64_t verifyInFlight_ = 0;
  uint64_t verifyRequested_ = 0;
  uint64_t verified_ = 0;
  std::vector<VerifiedSample> verifyGivenUp_;
  std::map<RendererId, Renderer> renderers_;  // by id: dispatch order is stable
  uint64_t nextBatchId_ = 1;
  uint64_t lastRequestSerial_ = 0;
  uint64_t queuedVisible_ = 0;
  uint64_t queuedPredicted_ = 0;
  uint64_t queuedImprove_ = 0;
  uint64_t queuedTotal_ = 0;
  uint64_t inFlight_ = 0;
  uint64_t requested_ = 0;
  uint64_t shaded_ = 0;
  uint64_t requeued_ = 0;
  uint64_t failed_ = 0;
  uint64_t rejected_ = 0;
  uint64_t retried_ = 0;
  uint64_t epoch_ = 0;
};

}  // namespace penumbra::sma

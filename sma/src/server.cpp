#include "penumbra/sma/server.h"

#include <malloc.h>

#include <array>
#include <map>
#include <mutex>
#include <numeric>
#include <shared_mutex>
#include <unordered_map>
#include <unordered_set>

#include <fmt/format.h>

#include "penumbra/common/auth.h"
#include "penumbra/common/duration.h"
#include "penumbra/common/embree_scene.h"
#include "penumbra/common/logging.h"
#include "penumbra/common/metrics.h"
#include "penumbra/common/messages.h"
#include "penumbra/common/server_skeleton.h"
#include "penumbra/common/wire_convert.h"
#include "penumbra/sma/cache_snapshot.h"
#include "penumbra/sma/client_requests.h"
#include "penumbra/sma/collector.h"
#include "penumbra/sma/delta.h"
#include "penumbra/sma/hierarchy.h"
#include "penumbra/sma/job_scheduler.h"
#include "penumbra/sma/memory_usage.h"
#include "penumbra/sma/refinement.h"
#include "penumbra/sma/sample_cache.h"
#include "penumbra/sma/refinement_driver.h"
#include "penumbra/sma/scene_moves.h"
#include "penumbra/sma/move_prediction.h"
#include "penumbra/sma/texture_frames.h"
#include "penumbra/sma/view_session.h"
#include "penumbra/sma/visibility.h"
#include "sma_metrics.h"

namespace penumbra::sma {

namespace {

using Clock = std::chrono::steady_clock;
using boost::system::error_code;


// Descend into a node's children once every vertex its split added is
// shaded: a parent is replaced by its children only when they can be drawn.
// A midpoint whose sample a move invalidated still counts (its reshade is
// on its way): clients keep the children they hold, with the old radiance,
// until the RESHADED update, instead of losing them to a coarser parent.
bool ChildrenShaded(const Node& node, const void* context) {
  const auto& cache = *static_cast<const SampleCache*>(context);
  for (VertexId m : node.mid)
    if (m != kNoVertex && !cache.IsShaded(m) && !cache.AwaitingReshade(m)) return false;
  return true;
}

// What every session hears about one applied move (posted to its strand).
struct MoveNotice {
  std::shared_ptr<const ScenePose> pose;  // the new pose
  std::vector<uint32_t> movedObjects;     // indices into Scene::objects whose place changed
  /// Invalidation::urgent, sorted: held vertices in it are re-shaded at
  /// visible priority (a shadow moved there), the others at background.
  std::shared_ptr<const std::vector<VertexId>> urgent;
  /// Prepared samples the move stored (move prediction): shaded at the new
  /// pose already; sessions are told of them (as arrived) after the move.
  std::shared_ptr<const std::vector<VertexId>> prepared;
};

// A job of its own in the JobSchedulers' round-robin (not a client's).
constexpr uint64_t kMoveJobSession = ~uint64_t(0);
constexpr uint64_t kCollectorSession = ~uint64_t(0) - 1;
// The collector's clock (Hierarchy::SetTick): ticks of 100 ms; a collection
// is considered every kCollectCheckTicks.
constexpr auto kTick = std::chrono::milliseconds(100);
constexpr uint32_t kCollectCheckTicks = 5;

CollectorOptions CollectorOptionsOf(const SmaOptions& o) {
  CollectorOptions c;
  c.budgetBytes = o.memoryBudgetBytes;
  c.startFraction = o.memoryCollectStart;
  c.stopFraction = o.memoryCollectStop;
  c.minAgeTicks = uint32_t(std::ceil(o.memoryMinAgeSeconds * 1000.0 / double(kTick.count())));
  return c;
}

}  // namespace

class SmaServer::Impl {
 public:
  class Session;

  Impl(const Scene& scene, SmaOptions options, std::unique_ptr<VisibilityTracer> tracer,
       std::unique_ptr<CacheSnapshotter> snapshots, std::optional<RestoredCache> restored)
      : scene_(scene),
        options_(std::move(options)),
        sessionThreads_(size_t(std::max(1, options_.sessionThreads))),
        hierarchy_(restored ? std::move(restored->hierarchy) : Hierarchy(scene)),
        tracer_(std::move(tracer)),
        jobs_(options_.viewThreads),
        visibilityBudget_(options_.visibilityBudgetPixels),
        textures_(scene, options_.clientConnection.maxFrameBytes / 2,
                  [this](std::function<void()> job) { backgroundJobs_.Post(0, JobClass::kNewView, std::move(job)); }),
        backgroundJobs_(1),
        log_(Logger("sma")),
        collector_(CollectorOptionsOf(options_)),
        skeleton_(io_,
                  // Descriptors beside the clients' for renderer links and files.
                  net::ServerSkeletonOptions::For(options_, options_.clientConnection,
                                                  {.service = "SMA", .peer = "client", .peers = "clients",
                                                   .logger = "sma", .reservedDescriptors = 256}),
                  net::ServerHooks{.logStats = [this] { LogStats(); }, .beginShutdown = [this] { StopWork(); }},
                  [this](std::shared_ptr<net::Connection> connection, uint64_t id) {
                    return std::make_shared<Session>(*this, std::move(connection), id);
                  }),
        snapshots_(std::move(snapshots)) {
    cache_.Reserve(hierarchy_.VertexCount());
    if (restored) cache_.Restore(restored->samples);
    // Every texture is encoded once, on the background thread, from now on:
    // clients' requests find them ready (or wait for their encoding).
    textures_.PrepareAll();
    options_.pool.sceneHash = scene.identity;
    options_.pool.name = options_.name;
    options_.pool.radianceBounds = RadianceBounds::ForScene(scene);
    pool_ = RendererPool::Create(
        io_, options_.pool, [this](std::vector<ShadedSample>&& samples) { OnResults(std::move(samples)); },
        // A sample held back for a move's test is stored as far as requests
        // go: the test's answer confirms it or asks for it (OnVerified).
        [this](VertexId v) { return cache_.IsShaded(v) || cache_.IsSuspect(v); });
    pool_->SetVerifiedHandler([this](const std::vector<VerifiedSample>& verified) { OnVerified(verified); });
    pose_ = std::make_shared<const ScenePose>(ScenePose::Initial(scene));
    posed_ = tracer_->Initial();
    pool_->SetPose(pose_);
    pool_->SetPreparedHandler([this](std::vector<ShadedSample>&& samples) { OnPreparedResults(std::move(samples)); });
    if (restored) {
      std::vector<SampleRequest> requests;
      for (VertexId v : UnshadedMidpoints(hierarchy_, cache_)) requests.push_back(MakeSampleRequest(hierarchy_, v));
      pool_->Request(requests, Priority::kBackground);
      log_->info("cache: {} restored midpoints were still unshaded: asked for", requests.size());
    }
  }

  Expected<tcp::endpoint> Listen() { return skeleton_.Listen(); }

  void Run() {
    pool_->Start();
    if (snapshots_) snapshots_->Start(stateMutex_, hierarchy_, cache_);
    ArmRendererWatch();
    StartAnimation();
    collectorStart_ = Clock::now();
    ArmCollectorClock();
    skeleton_.RunIo(options_.ioThreads);
    // Every client is told and closed (or the drain gave up). The jobs
    // still running (a trace or a step giving up) post their results to
    // sessions' strands: they end first. Then what is queued for the
    // sessions runs and finds the server shutting down (nothing re-posts
    // itself then), so that no handler holding a session -- and with it a
    // socket of io_ -- outlives io_.
    jobs_.Join();
    backgroundJobs_.Join();
    sessionThreads_.join();
    if (snapshots_) snapshots_->Stop();  // the final snapshot
    log_->info("{}: stopped", options_.name);
  }

  void Shutdown() { skeleton_.Shutdown(); }

  // Called by the renderer pool (I/O thread) with shaded samples.
  void OnResults(std::vector<ShadedSample>&& samples) {
    // First estimates and improvements come in separate batches (one
    // priority per batch), but need not: sort them.
    std::vector<ShadedSample> improvements;
    for (auto it = samples.begin(); it != samples.end();) {
      if (it->round == 0) {
        ++it;
        continue;
      }
      improvements.push_back(*it);
      it = samples.erase(it);
    }
    // No state lock: the cache is safe to write while views read it
    // (sample_cache.h), so this I/O thread never waits on a view's mapping.
    // Stored before Complete: a vertex is always in the cache or in the pool.
    // A sample shaded at a pose a move has since changed (its epoch is
    // before its vertex's invalidation) is refused by the cache and asked
    // again -- before Complete, so the vertex stays alive in the pool.
    std::vector<VertexId> changed, stale;
    if (!samples.empty()) cache_.Store(samples, &stale);
    if (!improvements.empty()) changed = cache_.Improve(improvements, &stale);
    if (!stale.empty()) {
      pool_->Retry(stale);
      samplesStale_ += stale.size();
      std::sort(stale.begin(), stale.end());
    }
    pool_->Complete(samples);
    pool_->Complete(improvements);
    samplesImproved_ += changed.size();
    if (!samples.empty()) {
      auto vertices = std::make_shared<std::vector<VertexId>>();
      vertices->reserve(samples.size());
      for (const ShadedSample& s : samples)
        if (!std::binary_search(stale.begin(), stale.end(), s.vertex)) vertices->push_back(s.vertex);
      if (!vertices->empty())
        for (auto& session : Sessions()) NotifyArrived(session, vertices);
    }
    if (!improvements.empty()) {
      auto answered = std::make_shared<std::vector<VertexId>>();
      answered->reserve(improvements.size());
      for (const ShadedSample& s : improvements) answered->push_back(s.vertex);
      auto improved = std::make_shared<std::vector<VertexId>>(std::move(changed));
      for (auto& session : Sessions()) NotifyImproved(session, answered, improved);
    }
  }

  // Called by the renderer pool (I/O thread) with the answers of a move's
  // tests: each suspect sample is kept (Confirm; sessions are told as of an
  // arrival, and a held one goes out as RESHADED with the value the client
  // already shows) or dropped and asked again at background priority, like
  // the indirect class without a test. A sample whose slot was written
  // since (a newer move's test or invalidation, a reshade) is left to
  // whoever wrote it.
  void OnVerified(const std::vector<VerifiedSample>& verified) {
    auto confirmed = std::make_shared<std::vector<VertexId>>();
    std::vector<SampleRequest> reshade;
    std::vector<VerifyRequest> retests;
    std::map<const VerifyContext*, std::shared_ptr<const VerifyContext>> retestContexts;
    for (const VerifiedSample& v : verified) {
      if (v.Passes(options_.moveTestZ)) {
        if (cache_.Confirm(v.vertex, v.generation)) confirmed->push_back(v.vertex);
        continue;
      }
      // The estimate within tau, its noise beyond: a first test is asked
      // again with kRetestFactor times the paths (half the noise at 4x),
      // other random numbers, and only the retest's answer counts (the
      // first's is the one that looked ambiguous). The sample stays suspect.
      const bool byNoise = std::isfinite(v.change) && std::abs(v.change) <= v.tolerance;
      if (byNoise && v.context && v.testRound == VerifyRound(v.targetEpoch) &&
          cache_.IsSuspect(v.vertex) && cache_.Generation(v.vertex) == v.generation) {
        std::shared_ptr<const VerifyContext>& retest = retestContexts[v.context.get()];
        if (!retest) {
          VerifyContext more = *v.context;
          more.paths = kRetestFactor * std::max(1u, options_.pool.verifyPaths);
          retest = std::make_shared<const VerifyContext>(std::move(more));
        }
        VerifyRequest again{v.request, retest, v.generation, v.tolerance};
        again.request.round = VerifyRetestRound(v.targetEpoch);
        retests.push_back(std::move(again));
        continue;
      }
      if (cache_.FailSuspect(v.vertex, v.generation)) {
        reshade.push_back(v.request);
        if (byNoise) ++testsFailedByNoise_;
      }
    }
    // Queued behind the tests in flight (the pool forgets the answered
    // ones after this returns, then queues these).
    if (!retests.empty()) {
      testsRetested_ += retests.size();
      pool_->Verify(retests);
    }
    // Asked for before the pool forgets the tests: the vertex stays alive.
    if (!reshade.empty()) pool_->Request(reshade, Priority::kBackground);
    if (!confirmed->empty())
      for (auto& session : Sessions()) NotifyArrived(session, confirmed, /*kept=*/true);
  }

  std::vector<std::shared_ptr<Session>> Sessions() { return skeleton_.Sessions(); }
  void RemoveSession(uint64_t id) { skeleton_.Remove(id); }
  // `kept`: samples a move's test kept (Confirm), whose values a client
  // that holds them already shows.
  void NotifyArrived(const std::shared_ptr<Session>& session, std::shared_ptr<const std::vector<VertexId>> vertices,
                     bool kept = false);
  // `answered`: improvements that came back (some may have changed nothing);
  // `improved`: the vertices whose cached estimate changed.
  void NotifyImproved(const std::shared_ptr<Session>& session, std::shared_ptr<const std::vector<VertexId>> answered,
                      std::shared_ptr<const std::vector<VertexId>> improved);
  std::atomic<uint64_t> samplesImproved_{0};
  std::atomic<uint64_t> samplesStale_{0};  // refused as shaded before their vertex's invalidation
  // Camera movement prediction (issue 15): predicted views traced and the
  // samples they asked for; and, with prediction on or off alike, the
  // triangles new views newly displayed and how many of those had their
  // corners shaded already when the view's visibility was applied.
  std::atomic<uint64_t> predictedViews_{0};
  std::atomic<uint64_t> samplesPredicted_{0};
  std::atomic<uint64_t> viewTrianglesNew_{0};
  std::atomic<uint64_t> viewTrianglesNewShaded_{0};

  // --- Moving objects (issue 14; scene_moves.h) ---
  /// The current pose and the visibility scene at it. Thread-safe copies.
  std::shared_ptr<const ScenePose> CurrentPose() {
    std::lock_guard lock(poseMutex_);
    return pose_;
  }
  std::shared_ptr<const PosedEmbreeScene> CurrentPosed() {
    std::lock_guard lock(poseMutex_);
    return posed_;
  }
  /// Any thread: queues a checked move; the job that applies moves (one at a
  /// time, coalescing those that arrive meanwhile) is posted if none is.
  void SubmitMove(const ObjectMove& move) {
    if (shuttingDown_) return;
    if (moveQueue_.Add(move)) jobs_.Post(kMoveJobSession, JobClass::kNewView, [this] { ApplyMoves(); });
  }
  std::atomic<uint64_t> movesRefused_{0};

  void AddGlobalCounters(wire::StatsReply* reply);
  // What the cache, the hierarchy and the clients' mirrors occupy (issue 15):
  // takes the state lock shared, briefly. Any thread but an I/O thread's
  // hot path (stats, metrics).
  MemoryUsage Memory();
  // Timings of the views answered since the last stats line (any session).
  void RecordView(double traceMs, double mapMs, double firstDeltaMs) {
    latencies_.toFirstDelta.Observe(firstDeltaMs / 1000.0);
    std::lock_guard lock(viewTimesMutex_);
    viewTimes_.push_back({traceMs, mapMs, firstDeltaMs});
  }
  // Operator endpoint (--http; issue 16): histograms are lock-free.
  ViewLatencyHistograms latencies_;
  void WriteMetrics(metrics::ExpositionWriter& out);
  std::string NotReadyReason();
  DragoParams DragoForClients() const {
    return options_.toneMapping;
  }

  const Scene& scene_;
  SmaOptions options_;
  // Where the client sessions' handlers run (each session a strand of it):
  // planning and encoding deltas, off the I/O thread. Declared before io_,
  // so that it outlives io_: sessions and connections that io_'s abandoned
  // handlers release on its destruction hold strands of it. Its own queue
  // is run empty (joined) in Run(), while io_ lives, for the converse.
  asio::thread_pool sessionThreads_;
  asio::io_context io_;
  std::shared_mutex stateMutex_;  // guards hierarchy_ and cache_
  Hierarchy hierarchy_;
  SampleCache cache_;
  std::unique_ptr<VisibilityTracer> tracer_;
  std::shared_ptr<RendererPool> pool_;
  // View jobs and refinement steps of every client: new views first, then
  // re-maps, then refinement steps, clients taking turns (job_scheduler.h).
  JobScheduler jobs_;
  // Resource limits per client (issue 12). Views above largeViewPixels and
  // texture encoding run on backgroundJobs_, one job at a time (in the same
  // order), so they never hold up ordinary views; textures_ posts its
  // encodings there and is declared first, so that the thread is joined
  // before it goes.
  VisibilityBudget visibilityBudget_;
  std::atomic<uint64_t> viewTraces_{0};  // visibility traces made, for every client
  std::atomic<uint64_t> viewJobsRetargeted_{0};  // queued view jobs a newer view took over
  TextureFrames textures_;
  JobScheduler backgroundJobs_;
  std::shared_ptr<spdlog::logger> log_;

 private:
  void LogStats();
  // Job thread: applies the waiting moves until none is left.
  void ApplyMoves();
  void ApplyMoveStep(std::span<const ObjectMove> moves);
  // The animation clock: every 1/animationHz, each animated object's place
  // on its path is submitted as a move.
  void StartAnimation();
  void ArmAnimation();
  asio::steady_timer animationTimer_{io_};
  Clock::time_point animationStart_;
  // The step the animation clock played last: step k places each animated
  // object at its path's time k / animationHz (so the next step's places
  // are known ahead: move prediction).
  std::atomic<uint64_t> animationStep_{0};
  // --- Movement prediction for moving objects (issue 15; move_prediction.h) ---
  // After each move: predict the next pose and post PrepareMove.
  void PredictNextMove(const ScenePose& applied);
  // Job thread: what the predicted move will invalidate and someone holds
  // (or awaits), shaded ahead at the predicted pose.
  void PrepareMove(std::shared_ptr<const ScenePose> predicted);
  // Prepared answers (an I/O thread, from the pool).
  void OnPreparedResults(std::vector<ShadedSample>&& samples);
  // Stores prepared samples released for the current epoch into vertices
  // that lack a sample; returns the vertices stored.
  std::vector<VertexId> StorePrepared(std::span<const ShadedSample> samples);
  MovePredictor movePredictor_{scene_, options_.animationHz};
  // What clients held and a move invalidated, at the latest epoch any
  // session reported (each session's OnMoved, on its strand): what the next
  // step will most likely ask again. Guarded by heldReshadeMutex_ (a leaf).
  void NoteHeldReshade(uint64_t epoch, const std::vector<VertexId>& sortedVertices);
  std::mutex heldReshadeMutex_;
  uint64_t heldReshadeEpoch_ = 0;
  std::vector<VertexId> heldReshade_;  // sorted
  MovePreparation preparation_;
  std::atomic<uint64_t> preparedStored_{0};  // prepared samples that became the new epoch's first estimates
  std::atomic<double> lastPrepareMs_{0.0};
  // Shutdown, on an I/O thread: abandon the work (a running trace or
  // refinement step stops at its next tile or split; it took 7 s to finish
  // them): nobody will see it.
  void StopWork();

  // Clients are told when the number of connected renderers differs from
  // what their last delta said (a view waiting on no renderer says so):
  // polled, as the pool has no callback, and compared per session, as a
  // renderer may come and go between two polls.
  void ArmRendererWatch();
  asio::steady_timer rendererWatchTimer_{io_};
  std::atomic<bool> shuttingDown_{false};  // also tells running jobs to give up
  RendererPoolStats lastStats_;
  std::mutex viewTimesMutex_;
  std::vector<std::array<double, 3>> viewTimes_;  // trace, map, view -> first delta (ms)
  // Pose: replaced (never changed in place) by the move job; readers copy
  // the pointers under poseMutex_ (a leaf: nothing else is taken under it).
  std::mutex poseMutex_;
  std::shared_ptr<const ScenePose> pose_;
  std::shared_ptr<const PosedEmbreeScene> posed_;
  MoveCoalescer moveQueue_;
  std::atomic<uint64_t> moves_{0};             // moves applied (scene epochs after 0)
  std::atomic<uint64_t> movesSnapped_{0};      // clients' moves placed at their prediction (SnapToPrediction)
  std::atomic<uint64_t> samplesInvalidated_{0};  // cached samples evicted by moves
  std::atomic<uint64_t> samplesInvalidatedOfObjects_{0};  // of which on movable objects
  std::atomic<uint64_t> samplesTested_{0};
  std::atomic<uint64_t> testsFailedByNoise_{0};  // failed with |change| <= tau, after a retest
  std::atomic<uint64_t> testsRetested_{0};       // tests asked again with more paths (OnVerified)
  // A retest's paths, as a multiple of --move-test-paths.
  static constexpr uint32_t kRetestFactor = 4;       // cached samples held back for a move's test
  std::atomic<uint64_t> lastMoveTested_{0};
  std::atomic<uint64_t> lastMoveInvalidated_{0};
  std::atomic<uint64_t> samplesInvalidatedUrgent_{0};
  /// Recent poses by epoch, bounded (PoseHistory). Only the move job reads
  /// and writes it.
  PoseHistory poseHistory_;
  std::atomic<uint64_t> lastMoveInvalidatedUrgent_{0};
  std::atomic<uint64_t> lastMoveCached_{0};    // samples cached just before the last move
  std::atomic<uint64_t> lastMoveReshadedBase_{0};  // cache_.Reshaded() when the last move was applied
  std::atomic<double> lastMoveApplyMs_{0.0};
  // --- The age-based collector (issue 15; collector.h) ---
  /// The data in use the collector steers by. Caller holds the state lock.
  size_t DataInUse();
  std::atomic<uint64_t> samplesRemade_{0};  // made again by splits of collapsed nodes
  std::atomic<uint64_t> remapsAfterCollection_{0};  // mappings found older than a collection
  std::atomic<uint64_t> viewRemaps_{0};  // refreshes: re-maps of a view's hits from its applied mapping
  std::atomic<uint64_t> viewRemapsUnchanged_{0};  // ... that found every pixel on its node: nothing planned

  // The clock: every kTick the hierarchy's tick advances (no lock); every
  // kCollectCheckTicks a collection job is posted if none is running.
  void ArmCollectorClock();
  // Job thread, one at a time: measures, scans (shared lock), collapses one
  // bounded step (exclusive lock), and posts itself again until the data is
  // down to the stop level or nothing old enough is left.
  void Collect(bool fresh);
  // A view displayed, or a prediction asked for, `node`: it and the cache
  // chunks of its corners are young again (the collector's ages). State
  // lock shared or exclusive; atomics only.
  void TouchForCollector(NodeId node) {
    hierarchy_.Touch(node);
    for (VertexId v : hierarchy_.GetNode(node).v) cache_.Touch(v);
  }
  asio::steady_timer collectorTimer_{io_};
  Clock::time_point collectorStart_;
  MemoryCollector collector_;  // only the running collection job touches it
  std::atomic<bool> collecting_{false};
  Clock::time_point lastStuckWarning_{};  // the collection job's
  bool collectedSinceScan_ = false;    // the collection job's
  bool releasedThisCollection_ = false;  // the collection job's: scene records released in this one
  std::atomic<uint64_t> recordsReleasedBytes_{0};
  // What a collection freed since the last malloc_trim (the collection
  // job's), and what the trims handed back: resident bytes before less after.
  size_t freedSinceTrim_ = 0;
  std::atomic<uint64_t> trims_{0};
  std::atomic<uint64_t> trimmedBytes_{0};
  // Job thread, at the end of a collection that freed something: hands the
  // heap pages it left free back to the system (malloc_trim).
  void TrimFreedHeap();
  std::atomic<uint64_t> collections_{0};        // collections started (over the start level)
  std::atomic<uint64_t> collectedGroups_{0};
  std::atomic<uint64_t> collectedNodes_{0};
  std::atomic<uint64_t> collectedVertices_{0};
  std::atomic<uint64_t> samplesEvicted_{0};     // freed vertices that had a sample, and dropped chunks' samples
  std::atomic<uint64_t> sampleChunksDropped_{0};  // cache chunks of base-vertex samples dropped
  std::atomic<uint64_t> collectKept_{0};        // groups kept: held by a client or being shaded
  std::atomic<uint64_t> collectOverBudgetStuck_{0};  // collections that ended above the stop level
  std::atomic<size_t> memoryInUse_{0};          // as of the last check
  net::ServerSkeleton<Session> skeleton_;  // listener, sessions, signals, stats timer, drain
  // Last member: stopped (its thread joined) before the state it reads goes.
  std::unique_ptr<CacheSnapshotter> snapshots_;

};

// One client connection: moves bytes and runs jobs and timers. What to do
// next is decided by its ViewSession (view_session.h), which owns the view's
// state and its RefinementDriver. Everything here runs on the connection's
// strand, except the bodies of posted jobs (JobScheduler threads).
class SmaServer::Impl::Session : public std::enable_shared_from_this<Session> {
 public:
  Session(Impl& server, std::shared_ptr<net::Connection> connection, uint64_t id)
      : server_(server),
        connection_(std::move(connection)),
        id_(id),
        log_(Logger("sma.client")),
        strand_(server.options_.sessionThreads > 0
                    ? asio::strand<asio::any_io_executor>(asio::make_strand(server.sessionThreads_.get_executor()))
                    : connection_->Strand()),
        refreshTimer_(server.io_),
        params_(server.options_.refinement),
        state_(params_, server.options_.clientRefinement.maxSamplesPerView, server.options_.pool.improvePaths > 0) {}

  void Start() {
    auto self = shared_from_this();
    auto onMessage = [self](wire::Envelope&& e) { self->OnMessage(std::move(e)); };
    auto onClose = [self](const std::string& reason) { self->OnClosed(reason); };
    if (server_.options_.sessionThreads > 0)
      connection_->StartOn(strand_, kMaxInbox, std::move(onMessage), std::move(onClose));
    else  // the connection's own strand, on the I/O thread (SmaOptions::sessionThreads)
      connection_->Start(std::move(onMessage), std::move(onClose));
  }

  net::Connection& Connection() { return *connection_; }
  /// Where every handler of this session runs (on the session threads).
  const asio::strand<asio::any_io_executor>& Strand() const { return strand_; }
  /// Whether the client holds a node or a vertex `group` would free. Any
  /// thread holding the state lock exclusively: the mirror changes only
  /// under it shared (QueueChanges).
  bool HoldsAnyOf(const Hierarchy::CollapseGroup& group) const {
    for (NodeId n : group.freedNodes)
      if (mirror_.Holds(n)) return true;
    for (VertexId v : group.freedVertices)
      if (mirror_.HoldsVertex(v)) return true;
    return false;
  }
  /// Whether the client holds a vertex in [first, end) (a cache chunk the
  /// collector would drop). Same threads as HoldsAnyOf.
  bool HoldsAnyVertexIn(VertexId first, VertexId end) const {
    for (VertexId v = first; v < end; ++v)
      if (mirror_.HoldsVertex(v)) return true;
    return false;
  }
  /// The client's mirror's bytes as of its last change (any thread).
  size_t MirrorBytes() const { return mirrorBytes_.load(std::memory_order_relaxed); }

  // Strand: samples were stored in the cache (`kept`: kept by a move's
  // test, the values a client holding them shows).
  void OnSamplesArrived(const std::vector<VertexId>& vertices, bool kept = false);
  // Strand: improvements came back; `improved` changed the cache.
  void OnSamplesImproved(const std::vector<VertexId>& answered, const std::vector<VertexId>& improved);
  /// Strand: a move was applied: MOVED to the client, held vertices it
  /// invalidated asked again, the view re-traced at the new pose.
  void OnMoved(const MoveNotice& notice);
  /// Strand: `renderers` are connected now; tell the client if it was told otherwise.
  void OnRendererCount(size_t renderers) {
    if (state_.RenderersOutdated(renderers)) SendStatus();
  }

 private:
  using JobStart = ViewSession::JobStart;
  struct JobTimings {
    double beforePostMs = 0.0;  // the view's arrival -> its job posted (the session's previous job, a drain)
    double queuedMs = 0.0;  // posted -> a job thread took it
    double traceMs = 0.0;
    double mapMs = 0.0;
    Clock::time_point done{};  // the job posted its result to the strand
  };

  void OnMessage(wire::Envelope&& envelope);
  void OnHello(const wire::Hello& hello);
  void OnView(const wire::View& view);
  void OnStatsRequest(const wire::StatsRequest& request);
  void OnTextureRequest(const wire::TextureRequest& request);
  void OnSessionOptions(const wire::SessionOptions& options);
  void OnMoveObject(const wire::MoveObject& move);
  void OnClosed(const std::string& reason);
  void Fatal(wire::ErrorCode code, const std::string& message) {
    log_->warn("{}: {} (closing)", connection_->Id(), message);
    connection_->FailAndClose(MakeError(0, code, message, true), message);
  }

  // A view job: what it traces and maps. The session's strand fills it in
  // and posts it; the job thread that runs it first marks it taken (under
  // its mutex). Until then the strand may retarget the job to a newer view:
  // it marks this one taken (its queued copy then runs nothing) and posts a
  // new view's job in its place.
  struct ViewJob {
    std::mutex mutex;
    bool taken = false;
    CameraView view;
    uint64_t viewId = 0;
    bool newView = false;
    std::shared_ptr<HitBuffer> hits;            // a refresh's: the applied view's hits
    std::shared_ptr<const VisibleSet> previous;  // a refresh's: their applied mapping
    Clock::time_point posted{};
    double beforePostMs = 0.0;
  };
  void StartJob();
  // The latest view's job (a new view's trace, or a refresh), its pixels
  // counted as the running job's.
  std::shared_ptr<ViewJob> MakeViewJob(bool newView);
  void PostViewJob(std::shared_ptr<ViewJob> job);
  void RetargetQueuedJob();
  void RunViewJob(ViewJob& job);  // job thread
  // Views above --large-view-pixels work on the background thread.
  JobScheduler& JobsFor(const CameraView& view) {
    return uint64_t(view.width) * uint64_t(view.height) > server_.options_.largeViewPixels ? server_.backgroundJobs_
                                                                                         : server_.jobs_;
  }
  /// This client's reservation in the visibility budget: the largest of its
  /// latest view, the trace running for it and the buffers it holds. Never
  /// more than OnView reserved, so it only shrinks.
  void UpdateReservation() {
    const auto pixels = [](const CameraView& v) { return uint64_t(v.width) * uint64_t(v.height); };
    server_.visibilityBudget_.Resize(reservedPixels_, std::max({pixels(state_.View()), runningJobPixels_,
                                                                hits_ ? pixels(hits_->view) : 0}));
  }
  void OnTextureReady(uint32_t texture, TextureFrames::Frame frame);
  void SendTextures();
  void OnJobDone(uint64_t viewId, bool newView, std::shared_ptr<HitBuffer> hits, std::shared_ptr<VisibleSet> visible,
                 JobTimings timings);
  void ApplyVisibility(bool newView);
  void ScheduleRefresh();
  bool Blocked() const { return connection_->QueuedBytes() > server_.options_.clientSoftQueueBytes; }
  /// Asks the connection to call back once the client's queue is under the
  /// soft limit; then one refresh sends what built up.
  void WaitUntilUnblocked();
  /// The throttled refresh's timer, armed for `due` (the state says kArmed).
  void ArmRefreshTimer(Clock::time_point due);
  void OnRefreshTimer(const boost::system::error_code& ec);  // strand
  /// Builds removals and additions into as many deltas as the size limit
  /// asks, into the outbox (caller holds the state lock shared; Flush sends
  /// them after it is released). `last`: no other delta for this event
  /// follows, so the final one may report convergence; `alwaysSend`: send
  /// even when nothing changed.
  void QueueChanges(wire::DeltaKind kind, std::span<const NodeId> removals, std::span<const NodeId> additions,
                    bool alwaysSend, bool last);
  /// Encodes and sends the outbox -- never under the state lock.
  void Flush();
  void FillStatus(wire::Delta& delta, bool last) {
    delta.set_scene_epoch(epochSent_);  // the epoch of the transforms the client was last told
    if (auto ms = state_.FillStatus(delta, last, server_.pool_->ReadyRenderers(), Clock::now()))
      server_.latencies_.toConverged.Observe(*ms / 1000.0);
  }
  void NoteStage1();
  /// Camera movement prediction: once a view reached stage 1 (its own
  /// samples are in), a job behind every new view and re-map traces where
  /// the camera is expected next and asks for what that view lacks at
  /// kPredicted, which the pool serves only after kVisible
  /// (SmaOptions::predictionOn). Once per view; the next view cancels it.
  void MaybePredict();
  // Improvement of the view's samples (SmaOptions::improveTargetError).
  void MaybeImprove();
  void QueueImproveLook();  // a MaybeImprove posted to the strand, at most one queued
  static constexpr size_t kImproveNodesPerLook = 4096;
  void SendUpdates();
  void MaybeRefine();
  void OnRefineStepDone(RefinementStep step);
  void SendStatus();
  /// Sends a STATUS delta if the client's last word on this view (converged,
  /// refining) is out of date -- e.g. after a coalesced refresh that changed
  /// no triangle, or when stage 1 ends without a delta of its own.
  void SyncStatus() {
    if (state_.StatusOutdated()) SendStatus();
  }

  // Client messages received and not yet handled: beyond this the
  // connection stops reading (a client's views are superseded by the next
  // anyway; its stats requests are answered in order).
  static constexpr size_t kMaxInbox = 64;

  Impl& server_;
  std::shared_ptr<net::Connection> connection_;
  uint64_t id_;
  std::shared_ptr<spdlog::logger> log_;
  // The session's own strand on the session threads (SmaOptions::
  // sessionThreads): its handlers plan and encode deltas there, so the I/O
  // thread only moves bytes (issue 13).
  asio::strand<asio::any_io_executor> strand_;
  asio::steady_timer refreshTimer_;
  RefinementParams params_;  // the client's refinement options, as last accepted
  ViewSession state_;

  std::shared_ptr<ViewJob> postedJob_;     // the last view job posted (taken by now, or still queued)
  std::shared_ptr<HitBuffer> hits_;        // base hits of the applied view
  std::shared_ptr<VisibleSet> visible_;    // latest mapping of hits_
  // visible_ was planned and its changes queued for the client (not held
  // back by a full queue, not found older than a collection): a refresh
  // whose mapping is the same has nothing to plan.
  bool visibleApplied_ = false;
  bool improveScanQueued_ = false;  // a MaybeImprove is posted to the strand (OnSamplesImproved coalesces)
  std::vector<NodeId> improveLap_;  // ImprovementLap of visible_ when the lap began
  ClientMirror mirror_;
  std::atomic<size_t> mirrorBytes_{0};     // mirror_.MemoryBytes() as of its last change (memory accounting)
  std::vector<InterestTicket> interest_;   // the interest our views' visible requests gave (released with the next plan)
  std::vector<wire::Envelope> outbox_;     // built under the state lock, sent by Flush after it
  uint64_t sequence_ = 0;
  uint64_t deltasSent_ = 0;
  // Hierarchy::StructureGeneration() of the mapping the pending nodes
  // (ViewSession's waiting set) came from: their ids are valid while it is
  // the hierarchy's.
  uint64_t shadingGeneration_ = 0;
  uint64_t trianglesSent_ = 0;
  uint64_t viewsReceived_ = 0;
  JobTimings lastTimings_;
  double lastFirstDeltaMs_ = 0.0;

  // Improvement: updates owed to the client (held vertices whose estimate
  // improved), sent when its queue allows.
  std::unordered_set<VertexId> updatesOwed_;
  uint64_t updatesSent_ = 0;
  // Moves (issue 14): the scene epoch whose transforms the client has
  // (SceneInfo, then each MOVED), and the held vertices whose reshade
  // arrived and is owed as RESHADED.
  uint64_t epochSent_ = 0;
  std::unordered_set<VertexId> reshadesOwed_;
  uint64_t reshadesSent_ = 0;
  uint64_t keptHeld_ = 0;  // held vertices a move's test kept: not re-sent
  uint64_t movesSent_ = 0;
  uint64_t improvementsAsked_ = 0;

  // Resource limits (issue 12). Visibility: this client's reservation in
  // the server's budget -- the largest of its latest view, the trace running
  // for it and the buffers it holds (one view's buffers at a time: a new
  // view drops the old one's).
  uint64_t reservedPixels_ = 0;
  uint64_t runningJobPixels_ = 0;
  // Textures asked for and not yet queued: null while being encoded.
  std::map<uint32_t, TextureFrames::Frame> texturesOutstanding_;
  uint64_t textureRequestsRefused_ = 0;

  // Camera movement prediction (issue 15): the client's recent views, the
  // view last predicted from, and the flag that abandons its job when a
  // newer view arrives.
  CameraPredictor predictor_{server_.options_.prediction};
  uint64_t predictedForView_ = 0;
  std::shared_ptr<std::atomic<bool>> predictionCancel_;
};

void SmaServer::Impl::NotifyArrived(const std::shared_ptr<Session>& session,
                                    std::shared_ptr<const std::vector<VertexId>> vertices, bool kept) {
  asio::post(session->Strand(),
             [session, vertices = std::move(vertices), kept] { session->OnSamplesArrived(*vertices, kept); });
}

void SmaServer::Impl::NotifyImproved(const std::shared_ptr<Session>& session,
                                     std::shared_ptr<const std::vector<VertexId>> answered,
                                     std::shared_ptr<const std::vector<VertexId>> improved) {
  asio::post(session->Strand(),
             [session, answered = std::move(answered), improved = std::move(improved)] {
               session->OnSamplesImproved(*answered, *improved);
             });
}

void SmaServer::Impl::Session::OnMessage(wire::Envelope&& envelope) {
  if (envelope.has_hello()) return OnHello(envelope.hello());
  if (!state_.Handshook()) {
    return Fatal(wire::ERROR_CODE_HANDSHAKE_REQUIRED,
                 fmt::format("expected hello as the first message, got {}", BodyName(envelope)));
  }
  switch (envelope.body_case()) {
    case wire::Envelope::kView:
      return OnView(envelope.view());
    case wire::Envelope::kStatsRequest:
      return OnStatsRequest(envelope.stats_request());
    case wire::Envelope::kTextureRequest:
      return OnTextureRequest(envelope.texture_request());
    case wire::Envelope::kSessionOptions:
      return OnSessionOptions(envelope.session_options());
    case wire::Envelope::kMoveObject:
      return OnMoveObject(envelope.move_object());
    case wire::Envelope::kError:
      log_->warn("{}: client reports {}: {}", connection_->Id(), wire::ErrorCode_Name(envelope.error().code()),
                 envelope.error().message());
      return;
    default:
      return Fatal(wire::ERROR_CODE_UNEXPECTED_MESSAGE,
                   fmt::format("an SMA does not take {} messages from clients", BodyName(envelope)));
  }
}

void SmaServer::Impl::Session::OnHello(const wire::Hello& hello) {
  if (state_.Handshook()) return Fatal(wire::ERROR_CODE_UNEXPECTED_MESSAGE, "second hello on one connection");
  wire::ErrorCode code = wire::ERROR_CODE_UNSPECIFIED;
  const Scene& scene = server_.scene_;
  // The token first: a peer without it learns nothing else.
  if (auto ok = CheckHelloToken(hello, server_.options_.authToken, &code); !ok) return Fatal(code, ok.error().message);
  if (auto ok = ValidateHello(hello, wire::ROLE_CLIENT, scene.identity, &code); !ok) return Fatal(code, ok.error().message);
  state_.OnHello();
  wire::Envelope welcome;
  auto* w = welcome.mutable_welcome();
  w->set_protocol_version(kProtocolVersion);
  w->set_role(wire::ROLE_SMA);
  w->set_server_name(server_.options_.name);
  w->set_scene_hash(scene.identity);
  w->set_max_frame_bytes(server_.options_.clientConnection.maxFrameBytes);
  connection_->Send(welcome);

  wire::Envelope infoEnvelope;
  ToWire(MakeClientScene(scene, server_.options_.toneMapping), infoEnvelope.mutable_scene_info());
  // The objects where they are now: moves after this one come as MOVED.
  const std::shared_ptr<const ScenePose> pose = server_.CurrentPose();
  FillSceneInfoObjects(scene, *pose, infoEnvelope.mutable_scene_info());
  epochSent_ = pose->epoch;
  connection_->Send(infoEnvelope);
  connection_->MarkHandshakeDone();
  log_->info("{}: client '{}' joined", connection_->Id(), Printable(hello.peer_name()));
}

void SmaServer::Impl::Session::OnView(const wire::View& v) {
  ++viewsReceived_;
  auto checked = ViewFromWire(v, server_.options_.maxViewPixels);
  if (!checked) return Fatal(wire::ERROR_CODE_INVALID_REQUEST, checked.error().message);
  const CameraView view = *checked;
  if (!state_.Accepts(v.view_id())) {
    connection_->Send(MakeError(v.view_id(), wire::ERROR_CODE_INVALID_REQUEST,
                                fmt::format("view id {} does not increase (last {}); ignored", v.view_id(),
                                            state_.ViewId()),
                                false));
    return;
  }
  // Visibility memory across clients: the new view must fit in the budget
  // (with the superseded trace still running for this client, if larger).
  const uint64_t pixels = uint64_t(view.width) * uint64_t(view.height);
  if (!server_.visibilityBudget_.Resize(reservedPixels_, std::max(pixels, runningJobPixels_))) {
    const uint64_t others = server_.visibilityBudget_.Used() - reservedPixels_;
    log_->info("{}: view {} ({}x{}) refused: visibility budget ({} of {} pixels held by other views)", connection_->Id(),
               v.view_id(), view.width, view.height, others, server_.visibilityBudget_.Capacity());
    connection_->Send(MakeError(v.view_id(), wire::ERROR_CODE_LIMIT_EXCEEDED,
                                fmt::format("view {}: {}x{} = {} pixels do not fit in this SMA's visibility budget now "
                                            "({} of {} pixels are held by other clients' views, "
                                            "--visibility-budget-pixels); ignored: send a smaller view or retry later",
                                            v.view_id(), view.width, view.height, pixels, others,
                                            server_.visibilityBudget_.Capacity()),
                                false));
    return;
  }
  // The old view's buffers are not used once a new view is taken (its
  // refinement and improvement wait for the new view's stage 1).
  hits_.reset();
  visible_.reset();
  visibleApplied_ = false;
  // A prediction made from the old view is abandoned: a real view is here.
  if (predictionCancel_) *predictionCancel_ = true;
  predictor_.Observe(view, Clock::now());
  // A new view supersedes whatever this client was waiting for: a running
  // job's result is dropped when it lands, and StartJob picks this view.
  state_.OnNewView(v.view_id(), view, Clock::now());
  StartJob();
}

void SmaServer::Impl::Session::StartJob() {
  if (!connection_->IsOpen()) return;
  if (state_.LatestViewWaitsForJob()) {
    RetargetQueuedJob();
    return;
  }
  const JobStart next = state_.NextJob(Blocked());
  if (next == JobStart::kNothing) return;
  if (next == JobStart::kWaitForDrain) {
    WaitUntilUnblocked();
    return;
  }
  const bool newView = next == JobStart::kNewView;
  std::shared_ptr<ViewJob> job = MakeViewJob(newView);
  if (newView) {  // one view's buffers at a time
    hits_.reset();
    visible_.reset();
  } else {
    // A refresh starts from the applied mapping of the same hits.
    job->hits = hits_;
    job->previous = visible_;
  }
  UpdateReservation();
  state_.OnJobStarted(next, Clock::now());
  PostViewJob(std::move(job));
}

std::shared_ptr<SmaServer::Impl::Session::ViewJob> SmaServer::Impl::Session::MakeViewJob(bool newView) {
  auto job = std::make_shared<ViewJob>();
  job->view = state_.View();
  job->viewId = state_.ViewId();
  job->newView = newView;
  // The trace about to run holds its pixels in the visibility budget.
  runningJobPixels_ = uint64_t(job->view.width) * uint64_t(job->view.height);
  return job;
}

void SmaServer::Impl::Session::PostViewJob(std::shared_ptr<ViewJob> job) {
  job->posted = Clock::now();
  job->beforePostMs = Milliseconds(job->posted - state_.ViewReceived());
  postedJob_ = job;
  JobsFor(job->view).Post(id_, job->newView ? JobClass::kNewView : JobClass::kRefresh,
                          [self = shared_from_this(), job] { self->RunViewJob(*job); });
}

void SmaServer::Impl::Session::RetargetQueuedJob() {
  // With 32 clients refining, a session's refresh waits in the queue for
  // 100-300 ms; a new view arriving meanwhile would wait for it to run, be
  // dropped, and only then queue its own trace (docs/performance.md, issue
  // 13). While no job thread has taken it, the job traces the new view.
  if (!postedJob_ || Blocked()) return;
  {
    std::lock_guard lock(postedJob_->mutex);
    if (postedJob_->taken || (postedJob_->newView && postedJob_->viewId == state_.ViewId())) return;
    postedJob_->taken = true;  // the copy queued runs nothing
  }
  std::shared_ptr<ViewJob> job = MakeViewJob(/*newView=*/true);
  UpdateReservation();
  state_.OnJobRetargeted();
  ++server_.viewJobsRetargeted_;
  // A new view's class: it goes ahead of the refreshes it was queued among.
  PostViewJob(std::move(job));
}

void SmaServer::Impl::Session::RunViewJob(ViewJob& job) {
  {
    std::lock_guard lock(job.mutex);
    if (job.taken) return;  // retargeted: its replacement runs
    job.taken = true;
  }
  Impl& server = server_;
  auto self = shared_from_this();
  const CameraView& view = job.view;
  const uint64_t id = job.viewId;
  const bool newView = job.newView;
  std::shared_ptr<HitBuffer> hits = std::move(job.hits);
  std::shared_ptr<const VisibleSet> previous = std::move(job.previous);
  JobTimings t;
  auto t0 = Clock::now();
  t.beforePostMs = job.beforePostMs;
  t.queuedMs = Milliseconds(t0 - job.posted);
  // A re-map of hits traced before a move traces again: the object may
  // now hide or reveal triangles.
  const std::shared_ptr<const PosedEmbreeScene> posed = server.CurrentPosed();
  if (!hits || hits->epoch != posed->Pose().epoch) {
    hits = std::make_shared<HitBuffer>();
    server.tracer_->Trace(view, *hits, &server.shuttingDown_, posed.get());
    ++server.viewTraces_;
    previous.reset();  // mapped from the hits just replaced
  }
  auto t1 = Clock::now();
  auto visible = std::make_shared<VisibleSet>();
  if (server.shuttingDown_) return;  // the result would be dropped anyway
  {
    std::shared_lock lock(server.stateMutex_);
    // Between collections ChildrenShaded only turns true (samples are
    // added; a move's invalidated ones still count), so a refresh looks
    // at each pixel's node instead of descending from its root.
    if (previous) {
      RemapHitsToNodes(server.hierarchy_, *hits, &ChildrenShaded, &server.cache_, *previous, *visible,
                       &server.shuttingDown_);
      ++server.viewRemaps_;
    } else {
      MapHitsToNodes(server.hierarchy_, *hits, &ChildrenShaded, &server.cache_, *visible, &server.shuttingDown_);
    }
    for (NodeId node : visible->nodes) server.TouchForCollector(node);
  }
  if (server.shuttingDown_) return;
  auto t2 = Clock::now();
  t.traceMs = newView ? Milliseconds(t1 - t0) : 0.0;
  t.mapMs = Milliseconds(t2 - t1);
  t.done = Clock::now();
  asio::post(strand_, [self, id, newView, hits, visible, t] { self->OnJobDone(id, newView, hits, visible, t); });
}

void SmaServer::Impl::Session::OnJobDone(uint64_t viewId, bool newView, std::shared_ptr<HitBuffer> hits,
                                         std::shared_ptr<VisibleSet> visible, JobTimings timings) {
  const ViewSession::JobDone done = state_.OnJobDone(viewId, newView);
  if (!connection_->IsOpen()) return;
  runningJobPixels_ = 0;
  if (done.outcome == ViewSession::JobOutcome::kDrop) {  // superseded: trace the latest view
    UpdateReservation();
    StartJob();
    return;
  }
  hits_ = std::move(hits);
  visible_ = std::move(visible);
  // The counters report the last new view's visibility; refreshes of the
  // same view (no trace, a re-map) would overwrite its trace time with 0.
  if (newView) lastTimings_ = timings;
  const auto planStart = Clock::now();
  const double strandWaitMs = Milliseconds(planStart - timings.done);
  ApplyVisibility(newView);
  if (done.firstForView) {
    lastFirstDeltaMs_ = Milliseconds(Clock::now() - state_.ViewReceived());
    server_.RecordView(timings.traceMs, timings.mapMs, lastFirstDeltaMs_);
    // Where a view's first delta waited: for a job thread (queued), for the
    // session's strand on the I/O thread (strand wait), or worked.
    log_->debug("{}: view {}: before its job {:.1f} ms, queued {:.1f} ms, trace {:.1f} ms, map {:.1f} ms, strand wait {:.1f} ms, "
                "plan+send {:.1f} ms, view->first delta {:.1f} ms; {} visible, {} held, {} pending ({} samples)",
                connection_->Id(), viewId, timings.beforePostMs, timings.queuedMs, timings.traceMs, timings.mapMs, strandWaitMs,
                Milliseconds(Clock::now() - planStart), lastFirstDeltaMs_, visible_->nodes.size(), mirror_.TriangleCount(), state_.PendingNodes(),
                state_.WaitingSamples());
  }
  UpdateReservation();
  if (done.outcome == ViewSession::JobOutcome::kApplyStale) {  // applied, but the latest view is traced next
    StartJob();
    return;
  }
  // Traced at a pose a move has since replaced: re-map (and re-trace) soon.
  if (hits_->epoch != server_.CurrentPose()->epoch) state_.WantRemap();
  if (state_.RemapWanted()) ScheduleRefresh();
  NoteStage1();
  MaybeRefine();
  MaybeImprove();
  SyncStatus();
}

void SmaServer::Impl::Session::ApplyVisibility(bool newView) {
  Impl& server = server_;
  std::shared_lock lock(server.stateMutex_);
  if (visible_->structureGeneration != server.hierarchy_.StructureGeneration()) {
    // Mapped before a collection: its node ids may be freed or reused. Map
    // again (no trace: the hits are still right); OnJobDone schedules it.
    state_.WantRemap();
    ++server.remapsAfterCollection_;
    return;
  }
  // A refresh that found every pixel on the node it had: what the client was
  // sent already matches it, and arrivals since have been sent as they
  // completed nodes (OnSamplesArrived). Only what was held back is owed.
  // Most refreshes with many clients are this: each re-maps whenever any
  // client's splits arrive, and PlanView was the I/O thread's largest cost.
  if (!newView && visible_->sameAsPrevious && visibleApplied_) {
    ++server.viewRemapsUnchanged_;
    lock.unlock();
    if (Blocked()) {
      WaitUntilUnblocked();
      return;
    }
    Flush();
    SendUpdates();
    return;
  }
  visibleApplied_ = false;
  ViewPlan plan = PlanView(*visible_, mirror_, server.hierarchy_, server.cache_, server.options_.clientLingerTriangles);

  // Ask for what is missing before letting go of the old interest, so a
  // vertex both views need is never demoted in between. Requests are made
  // under the state lock: see RendererPool's note on "requested once".
  std::vector<SampleRequest> requests;
  requests.reserve(plan.missing.size());
  for (VertexId v : plan.missing) requests.push_back(MakeSampleRequest(server.hierarchy_, v));
  std::vector<InterestTicket> interest;
  server.pool_->Request(requests, Priority::kVisible, &interest);
  server.pool_->ReleaseInterest(interest_);
  interest_ = std::move(interest);
  if (newView) {  // the prediction hit rate, counted with prediction on or off
    server.viewTrianglesNew_ += plan.addCached.size() + plan.pending.size();
    server.viewTrianglesNewShaded_ += plan.addCached.size();
  }
  for (NodeId id : state_.BeginShading(plan.pending, server.hierarchy_, server.cache_, newView))
    plan.addCached.push_back(id);
  shadingGeneration_ = visible_->structureGeneration;  // the pending nodes' ids are valid while it lasts

  if (Blocked()) {
    // The client is behind: send nothing now; once its queue drains, one
    // refresh sends the difference that has built up (coalescing).
    state_.OnPlanHeldBack();
    lock.unlock();
    WaitUntilUnblocked();
    return;
  }
  state_.OnPlanQueued();  // before its deltas' status: the last may say converged
  if (newView) {
    // The paper's order: what the cache already has, then what is gone;
    // what must be rendered follows as it arrives.
    const bool removalsFollow = !plan.removeGone.empty();
    QueueChanges(wire::DELTA_KIND_CACHED, plan.removeReplaced, plan.addCached, /*alwaysSend=*/true, !removalsFollow);
    QueueChanges(wire::DELTA_KIND_REMOVED, plan.removeGone, {}, /*alwaysSend=*/false, /*last=*/true);
  } else {
    std::vector<NodeId> removals = plan.removeReplaced;
    removals.insert(removals.end(), plan.removeGone.begin(), plan.removeGone.end());
    QueueChanges(wire::DELTA_KIND_REFINED, removals, plan.addCached, /*alwaysSend=*/false, /*last=*/true);
  }
  mirror_.SetLingering(plan.linger);
  visibleApplied_ = true;
  lock.unlock();
  // Reshades of vertices the client no longer holds are not awaited.
  state_.PruneReshades([this](VertexId v) { return mirror_.HoldsVertex(v); });
  Flush();
  SendUpdates();
}

void SmaServer::Impl::Session::QueueChanges(wire::DeltaKind kind, std::span<const NodeId> removals,
                                            std::span<const NodeId> additions, bool alwaysSend, bool last) {
  // Caller holds the state lock (shared).
  const size_t chunk = std::max<size_t>(1, server_.options_.maxTrianglesPerDelta);
  size_t offset = 0;
  bool first = true;
  while (first || offset < additions.size()) {
    const size_t count = std::min(chunk, additions.size() - offset);
    wire::Envelope envelope;
    wire::Delta& delta = *envelope.mutable_delta();
    delta.set_kind(kind);
    trianglesSent_ += mirror_.AppendChanges(first ? removals : std::span<const NodeId>{},
                                            additions.subspan(offset, count), server_.hierarchy_, server_.cache_, delta);
    offset += count;
    first = false;
    const bool empty = delta.removed_triangles_size() == 0 && delta.triangle_ids_size() == 0;
    if (empty && !alwaysSend) continue;
    delta.set_sequence(++sequence_);
    FillStatus(delta, last && offset >= additions.size());
    outbox_.push_back(std::move(envelope));
  }
  mirrorBytes_.store(mirror_.MemoryBytes(), std::memory_order_relaxed);  // read by the stats (any thread)
}

void SmaServer::Impl::Session::Flush() {
  std::vector<wire::Envelope> out;
  out.swap(outbox_);
  for (const wire::Envelope& envelope : out) {
    if (!connection_->Send(envelope)) {
      // Over the hard queue limit: this client is not reading at all.
      connection_->Close("client send queue overflow");
      return;
    }
    ++deltasSent_;
  }
}

void SmaServer::Impl::Session::OnSamplesArrived(const std::vector<VertexId>& vertices, bool kept) {
  if (!state_.HasVisible() || !connection_->IsOpen()) return;
  const ViewSession::Arrived arrived = state_.OnSamplesArrived(vertices, server_.hierarchy_.BaseVertexCount());
  if (arrived.improveLookWanted) QueueImproveLook();
  // A first estimate of a vertex the client already holds, which a move
  // invalidated (ValidFrom > 0), is its reshade: it goes as RESHADED. (A
  // vertex never invalidated can also arrive while held -- a duplicate
  // answer after a requeue -- and is no news.) A sample a test kept is the
  // value the client kept showing: no news either, unless an update of it
  // was owed and held back while it was suspect (SendUpdates).
  bool reshaded = false;
  for (VertexId v : vertices) {
    if (!mirror_.HoldsVertex(v)) continue;
    if (kept) {
      ++keptHeld_;
      if (reshadesOwed_.contains(v) || updatesOwed_.contains(v)) reshaded = true;
      continue;
    }
    if (server_.cache_.ValidFrom(v) == 0) continue;
    reshadesOwed_.insert(v);
    updatesOwed_.erase(v);
    reshaded = true;
  }
  if (arrived.remapWanted) {
    state_.WantRemap();
    ScheduleRefresh();
  }
  if (arrived.candidates.empty()) {
    if (reshaded) {
      SendUpdates();
      SyncStatus();
      MaybeImprove();
    }
    return;
  }
  std::shared_lock lock(server_.stateMutex_);
  if (shadingGeneration_ != server_.hierarchy_.StructureGeneration()) {
    // The nodes waiting for these samples were mapped before a collection.
    lock.unlock();
    state_.WantRemap();
    ++server_.remapsAfterCollection_;
    ScheduleRefresh();
    return;
  }
  std::vector<VertexId> awaitedAgain;
  const std::vector<NodeId> ready =
      state_.TakeReady(arrived.candidates, server_.hierarchy_, server_.cache_, &awaitedAgain);
  if (!awaitedAgain.empty()) {
    // Corners a move took back after they had arrived: asked again for
    // this view (under the shared lock, like the view's own requests).
    std::vector<SampleRequest> again;
    again.reserve(awaitedAgain.size());
    for (VertexId v : awaitedAgain) again.push_back(MakeSampleRequest(server_.hierarchy_, v));
    server_.pool_->Request(again, Priority::kVisible, &interest_);
  }
  if (Blocked()) {
    lock.unlock();
    WaitUntilUnblocked();
    return;
  }
  QueueChanges(wire::DELTA_KIND_SHADED, {}, ready, /*alwaysSend=*/state_.Converged(), /*last=*/true);
  lock.unlock();
  Flush();
  if (reshaded) SendUpdates();
  NoteStage1();
  MaybeRefine();
  MaybeImprove();
}

void SmaServer::Impl::Session::MaybeImprove() {
  if (!connection_->IsOpen()) return;
  const SmaOptions& o = server_.options_;
  switch (state_.NextImprovement(Blocked(), o.improveBatch)) {
    case ViewSession::ImproveStart::kNothing:
      return;
    case ViewSession::ImproveStart::kWaitForDrain:  // no work for a client that cannot take it
      WaitUntilUnblocked();
      return;
    case ViewSession::ImproveStart::kLook:
      break;
  }
  // A look goes on from where the last stopped and walks at most
  // kImproveNodesPerLook nodes, so the strand's other handlers (the
  // connection's reads, writes and heartbeat) never wait behind a walk of
  // the whole visible set.
  // A lap walks the visible nodes as they were when it began, the most
  // pixels first (ImprovementLap); nodes that have left the view since are
  // skipped, and new ones (refined children) wait for the next lap.
  const std::vector<NodeId>& visibleNodes = visible_->nodes;
  if (state_.ImproveScanPosition() == 0) improveLap_ = ImprovementLap(*visible_);
  const std::vector<NodeId>& nodes = improveLap_;
  const size_t begin = std::min(state_.ImproveScanPosition(), nodes.size());
  const size_t stop = std::min(nodes.size(), begin + kImproveNodesPerLook);
  size_t end = begin;
  std::vector<SampleRequest> requests;
  {
    std::shared_lock lock(server_.stateMutex_);
    const Hierarchy& hierarchy = server_.hierarchy_;
    const SampleCache& cache = server_.cache_;
    std::unordered_set<VertexId> seen;
    for (; end < stop; ++end) {
      if (requests.size() + state_.ImprovementsPending() >= o.improveBatch) break;
      const NodeId id = nodes[end];
      // Only what the client shows (held and in view: not what lingers).
      if (!mirror_.Holds(id) || !std::binary_search(visibleNodes.begin(), visibleNodes.end(), id)) continue;
      for (VertexId v : hierarchy.GetNode(id).v) {
        if (!seen.insert(v).second || state_.ImprovementPending(v) || !cache.IsShaded(v)) continue;
        if (cache.Paths(v) >= o.improveMaxPaths || !(cache.RelativeError(v) > o.improveTargetError)) continue;
        SampleRequest r = MakeSampleRequest(hierarchy, v);
        r.round = uint16_t(cache.Rounds(v) + 1);
        if (r.round == 0) continue;  // 65535 rounds: enough
        requests.push_back(r);
      }
    }
    // Under the state lock, like every request (RendererPool: "requested once").
    if (!requests.empty()) server_.pool_->Request(requests, Priority::kImprove);
  }
  std::vector<VertexId> asked;
  asked.reserve(requests.size());
  for (const SampleRequest& r : requests) asked.push_back(r.vertex);
  improvementsAsked_ += requests.size();
  switch (state_.OnImprovementsAsked(asked, end, nodes.size())) {
    case ViewSession::AfterLook::kDone:
      SyncStatus();
      return;
    case ViewSession::AfterLook::kLapGoesOn:
      // Stopped by the walk's bound with room in the batch: go on after
      // whatever else waits on the strand. (Stopped by a full batch: the
      // answers call for the next look.)
      if (end == stop) QueueImproveLook();
      return;
    case ViewSession::AfterLook::kLookAgain:
      QueueImproveLook();
      return;
    case ViewSession::AfterLook::kAwaitAnswers:
      return;
  }
}

void SmaServer::Impl::Session::QueueImproveLook() {
  if (improveScanQueued_) return;
  improveScanQueued_ = true;
  asio::post(strand_, [self = shared_from_this()] {
    self->improveScanQueued_ = false;
    if (self->server_.shuttingDown_) return;
    self->MaybeImprove();
  });
}

void SmaServer::Impl::Session::OnSamplesImproved(const std::vector<VertexId>& answered,
                                                 const std::vector<VertexId>& improved) {
  state_.OnImprovementsAnswered(answered);
  if (!state_.HasVisible() || !connection_->IsOpen()) return;
  for (VertexId v : improved)
    if (mirror_.HoldsVertex(v) && !reshadesOwed_.contains(v)) updatesOwed_.insert(v);
  SendUpdates();
  // One improvement look for all the notices queued now, not one per
  // notice: with two I/O threads the pool's links posted them faster than
  // this strand ran a look each, and the connection's own handlers starved
  // behind them (docs/performance.md).
  QueueImproveLook();
}

void SmaServer::Impl::Session::SendUpdates() {
  if (updatesOwed_.empty() && reshadesOwed_.empty()) return;
  if (Blocked()) {
    WaitUntilUnblocked();  // its refresh sends them
    return;
  }
  // RESHADED (a move changed them) and IMPROVED (better estimates) carry
  // the same fields; a client may treat them alike, but they are told apart.
  const auto queue = [this](std::unordered_set<VertexId>& owedSet, wire::DeltaKind kind, bool lastKind,
                            uint64_t& sent) {
    std::vector<VertexId> owed(owedSet.begin(), owedSet.end());
    owedSet.clear();
    std::sort(owed.begin(), owed.end());
    // Held back for a move's test: still owed (sent once the test keeps
    // them; a failed one's reshade is owed again when it arrives).
    std::vector<VertexId> stillOwed;
    const size_t chunk = std::max<size_t>(1, server_.options_.maxTrianglesPerDelta);
    for (size_t offset = 0; offset < owed.size(); offset += chunk) {
      wire::Envelope envelope;
      wire::Delta& delta = *envelope.mutable_delta();
      delta.set_kind(kind);
      const size_t n = mirror_.AppendUpdates(std::span(owed).subspan(offset, std::min(chunk, owed.size() - offset)),
                                             server_.cache_, delta, &stillOwed);
      if (n == 0) continue;
      delta.set_sequence(++sequence_);
      FillStatus(delta, /*last=*/lastKind && offset + chunk >= owed.size());
      outbox_.push_back(std::move(envelope));
      sent += n;
    }
    owedSet.insert(stillOwed.begin(), stillOwed.end());
  };
  {
    std::shared_lock lock(server_.stateMutex_);
    const bool improvedFollow = !updatesOwed_.empty();
    queue(reshadesOwed_, wire::DELTA_KIND_RESHADED, !improvedFollow, reshadesSent_);
    queue(updatesOwed_, wire::DELTA_KIND_IMPROVED, true, updatesSent_);
  }
  Flush();
}

void SmaServer::Impl::Session::NoteStage1() {
  if (const std::optional<double> ms = state_.NoteStage1(Clock::now())) {
    server_.latencies_.toShaded.Observe(*ms / 1000.0);
    log_->debug("{}: view {}: stage 1 in {:.0f} ms, {} triangles", connection_->Id(), state_.AppliedViewId(), *ms,
                mirror_.TriangleCount());
    // Tell the client at once that stage 2 (refinement) has begun.
    SyncStatus();
    // The view's own needs are met: predict now (the issue's order: after
    // the current view's needs, before refinement). Predicting as soon as
    // a view was applied took CPU from its own stage 1 (about 5 ms of ~45
    // at the median on 2 cores, docs/performance.md "Movement prediction").
    MaybePredict();
  }
}

void SmaServer::Impl::Session::MaybePredict() {
  const SmaOptions& o = server_.options_;
  // Not gated on Blocked() either: predicted samples go to the cache, not to
  // this client's send queue.
  if (!o.predictionOn || !connection_->IsOpen()) return;
  const uint64_t viewId = state_.ViewId();
  if (predictedForView_ == viewId) return;
  predictedForView_ = viewId;
  const std::optional<PredictedView> predicted = predictor_.Predict(Clock::now());
  if (!predicted || predicted->atRest) return;  // nothing to prepare
  CameraView view = predicted->view;
  view.width = std::max(1, int(double(view.width) * o.predictionResolution));
  view.height = std::max(1, int(double(view.height) * o.predictionResolution));
  auto cancel = std::make_shared<std::atomic<bool>>(false);
  predictionCancel_ = cancel;
  // Behind every new view and re-map of any client (JobClass order), and
  // abandoned when this client's next view arrives; the buffers are the
  // job's own (a fraction of the view's pixels) and go with it.
  JobsFor(state_.View()).Post(id_, JobClass::kPrediction, [self = shared_from_this(), view, cancel] {
    Impl& server = self->server_;
    if (*cancel || server.shuttingDown_) return;
    HitBuffer hits;
    const std::shared_ptr<const PosedEmbreeScene> posed = server.CurrentPosed();
    server.tracer_->Trace(view, hits, cancel.get(), posed.get());
    if (*cancel || server.shuttingDown_) return;
    VisibleSet visible;
    std::shared_lock lock(server.stateMutex_);
    MapHitsToNodes(server.hierarchy_, hits, &ChildrenShaded, &server.cache_, visible, cancel.get());
    if (*cancel || server.shuttingDown_) return;
    for (NodeId id : visible.nodes) server.TouchForCollector(id);  // what a coming view needs ages from now
    // The corners a view there would wait for; the pool skips those alive
    // or stored. Requested under the state lock like every request.
    std::vector<SampleRequest> requests;
    std::unordered_set<VertexId> seen;
    for (NodeId id : visible.nodes)
      for (VertexId v : server.hierarchy_.GetNode(id).v)
        if (seen.insert(v).second && !server.cache_.IsShaded(v))
          requests.push_back(MakeSampleRequest(server.hierarchy_, v));
    const size_t added = requests.empty() ? 0 : server.pool_->Request(requests, Priority::kPredicted);
    lock.unlock();
    ++server.predictedViews_;
    server.samplesPredicted_ += added;
    self->log_->debug("{}: predicted view {}x{}: {} nodes, {} corners unshaded, {} samples asked",
                      self->connection_->Id(), view.width, view.height, visible.nodes.size(), requests.size(), added);
  });
}

void SmaServer::Impl::Session::MaybeRefine() {
  if (!connection_->IsOpen()) return;
  switch (state_.NextRefinement(Blocked())) {
    case ViewSession::RefineStart::kNothing:
      return;
    case ViewSession::RefineStart::kWaitForDrain:  // no work for a client that cannot take it
      WaitUntilUnblocked();
      return;
    case ViewSession::RefineStart::kCapReached:
      log_->info("{}: view {}: refinement stopped at {} new samples (--client-max-refinement-samples {})",
                 connection_->Id(), state_.AppliedViewId(), state_.Refinement().Requested(),
                 server_.options_.clientRefinement.maxSamplesPerView);
      SyncStatus();
      return;
    case ViewSession::RefineStart::kStep:
      break;
  }
  auto self = shared_from_this();
  auto refiner = state_.Refinement().CurrentRefiner();
  auto hits = hits_;
  auto visible = visible_;
  const bool outstanding = state_.RefinementOutstanding();
  JobsFor(hits->view).Post(id_, JobClass::kRefinement, [self, refiner, hits, visible, outstanding] {
    Impl& server = self->server_;
    const RefinementStepContext context{
        server.stateMutex_, server.hierarchy_, server.cache_, server.DragoForClients(), &server.shuttingDown_,
        [&server](std::span<const VertexId> created) {
          std::vector<SampleRequest> requests;
          requests.reserve(created.size());
          for (VertexId v : created) requests.push_back(MakeSampleRequest(server.hierarchy_, v));
          server.pool_->Request(requests, Priority::kBackground);
        }};
    RefinementStep step = RefinementDriver::RunStep(refiner, *hits, *visible, outstanding, context);
    asio::post(self->strand_,
               [self, step = std::move(step)]() mutable { self->OnRefineStepDone(std::move(step)); });
  });
}

void SmaServer::Impl::Session::OnRefineStepDone(RefinementStep step) {
  const size_t chosen = step.chosen, created = step.created.size();
  const double exclusiveMs = step.exclusiveMs;
  const bool exhausted = step.exhausted;
  server_.samplesRemade_ += step.remadeVertices;
  if (step.staleMapping) {
    // Chose from a mapping older than a collection: map again; the re-map's
    // completion asks for the next step (a re-map due makes the driver wait).
    state_.WantRemap();
    ++server_.remapsAfterCollection_;
    ScheduleRefresh();
  }
  RefinementDriver::After after;
  {
    std::shared_lock lock(server_.stateMutex_);
    after = state_.OnRefineStepDone(std::move(step), server_.cache_);
  }
  log_->debug("{}: refinement step: {} split, {} new vertices, exclusive {:.1f} ms, exhausted {}; pending {}, next {}",
              connection_->Id(), chosen, created, exclusiveMs, exhausted, state_.Refinement().PendingSamples(), int(after));
  switch (after) {
    case RefinementDriver::After::kStale:    // the view changed meanwhile: its refinement may start
    case RefinementDriver::After::kStepNow:  // nothing outstanding will wake it: look again now
      MaybeRefine();
      return;
    case RefinementDriver::After::kStepAgain:
      // Bounded batches (the paper's R): give the strand's queue -- a new view
      // above all -- a turn before the next step.
      asio::post(strand_, [self = shared_from_this()] {
        if (!self->server_.shuttingDown_) self->MaybeRefine();
      });
      return;
    case RefinementDriver::After::kFinished:
      SyncStatus();
      return;
    case RefinementDriver::After::kWait:  // an arriving sample or a re-map starts the next step
      return;
  }
}

void SmaServer::Impl::Session::SendStatus() {
  if (Blocked()) {
    WaitUntilUnblocked();
    return;
  }
  wire::Envelope envelope;
  wire::Delta& delta = *envelope.mutable_delta();
  delta.set_kind(wire::DELTA_KIND_STATUS);
  delta.set_sequence(++sequence_);
  FillStatus(delta, /*last=*/true);
  outbox_.push_back(std::move(envelope));
  Flush();
}

void SmaServer::Impl::Session::OnMoveObject(const wire::MoveObject& move) {
  // Checked here (cheap); applied on a job thread, never on this I/O thread.
  auto checked = CheckMoveObject(move, server_.scene_);
  if (!checked) {
    ++server_.movesRefused_;
    log_->info("{}: {} (refused)", connection_->Id(), checked.error().message);
    connection_->Send(MakeError(move.request_id(), wire::ERROR_CODE_INVALID_REQUEST, checked.error().message, false));
    return;
  }
  server_.SubmitMove(*checked);
}

void SmaServer::Impl::Session::OnMoved(const MoveNotice& notice) {
  if (!state_.Handshook() || !connection_->IsOpen()) return;
  const uint64_t epoch = notice.pose->epoch;
  // What lingers goes first: its light may have changed, and reshading what
  // the client does not see would take the renderers from what it does.
  if (mirror_.LingeringCount() > 0) {
    const std::vector<NodeId> lingering = mirror_.LingeringNodes();
    std::shared_lock lock(server_.stateMutex_);
    QueueChanges(wire::DELTA_KIND_REMOVED, lingering, {}, /*alwaysSend=*/false, /*last=*/true);
  }
  // Held vertices the move invalidated (a held vertex was shaded when it
  // was sent, so an unshaded one now was invalidated): asked again with
  // this view's interest and awaited -- where a shadow or lit patch moved
  // (the urgent class) at visible priority, the rest (invalidated only by
  // the indirect-light bound) at background priority, so the shadow
  // follows the object first.
  std::vector<VertexId> reshade;
  mirror_.ForEachVertex([&](VertexId v) {
    if (!server_.cache_.IsShaded(v)) reshade.push_back(v);
  });
  // Prepared samples the move stored are shaded already, and held: the
  // next step will want them again too.
  std::vector<VertexId> heldChanged = reshade;
  if (notice.prepared)
    for (VertexId v : *notice.prepared)
      if (mirror_.HoldsVertex(v)) heldChanged.push_back(v);
  std::sort(heldChanged.begin(), heldChanged.end());
  heldChanged.erase(std::unique(heldChanged.begin(), heldChanged.end()), heldChanged.end());
  server_.NoteHeldReshade(epoch, heldChanged);
  if (!reshade.empty()) {
    std::sort(reshade.begin(), reshade.end());
    std::vector<SampleRequest> urgent, later;
    {
      std::shared_lock lock(server_.stateMutex_);
      for (VertexId v : reshade) {
        const bool isUrgent =
            !notice.urgent || std::binary_search(notice.urgent->begin(), notice.urgent->end(), v);
        (isUrgent ? urgent : later).push_back(MakeSampleRequest(server_.hierarchy_, v));
      }
      // The urgent ones' interest is released with the view's next plan;
      // background requests take none.
      if (!urgent.empty()) server_.pool_->Request(urgent, Priority::kVisible, &interest_);
      if (!later.empty()) server_.pool_->Request(later, Priority::kBackground);
    }
  }
  state_.OnSceneMoved(reshade);
  if (epoch > epochSent_) {
    epochSent_ = epoch;
    wire::Envelope envelope;
    wire::Delta& delta = *envelope.mutable_delta();
    FillMovedDelta(*notice.pose, notice.movedObjects, &delta);
    delta.set_sequence(++sequence_);
    FillStatus(delta, /*last=*/true);
    // Sent even to a client that is behind: it is small, and later deltas'
    // places depend on it.
    outbox_.push_back(std::move(envelope));
    Flush();
    ++movesSent_;
  }
  if (!state_.HasVisible()) return;
  // The object may now hide or reveal triangles: re-trace at the new pose.
  state_.WantRemap();
  ScheduleRefresh();
}

void SmaServer::Impl::Session::OnSessionOptions(const wire::SessionOptions& o) {
  auto checked = ApplySessionOptions(params_, o);
  if (!checked) {
    connection_->Send(MakeError(0, wire::ERROR_CODE_INVALID_REQUEST, checked.error().message, false));
    return;
  }
  const RefinementParams p = *checked;
  if (auto ok = CheckClientRefinement(p, params_, server_.options_.clientRefinement); !ok) {
    connection_->Send(MakeError(0, wire::ERROR_CODE_INVALID_REQUEST, "session options: " + ok.error().message, false));
    return;
  }
  params_ = p;
  log_->info("{}: refinement {} (S_req {}, noise z {}, R {}, min {} px)", connection_->Id(), CriterionName(p.criterion),
             p.sReq, p.noiseZ, p.batch, p.minPixels);
  state_.SetRefinementParams(p);
  MaybeRefine();
  SyncStatus();
}

void SmaServer::Impl::Session::ScheduleRefresh() {
  Clock::time_point due;
  switch (state_.ScheduleRemap(Clock::now(), server_.options_.refreshInterval, &due)) {
    case ViewSession::RemapAction::kNothing:
      return;
    case ViewSession::RemapAction::kStartNow:
      StartJob();
      return;
    case ViewSession::RemapAction::kArmTimer:
      ArmRefreshTimer(due);
      return;
  }
}

void SmaServer::Impl::Session::ArmRefreshTimer(Clock::time_point due) {
  refreshTimer_.expires_at(std::max(due, Clock::now() + std::chrono::milliseconds(1)));
  // The wait completes on an I/O thread and hands over to the strand: a
  // pending wait bound to the strand would count as the session threads'
  // work, and Run()'s join of them would wait for a timer that the stopped
  // io_context never fires.
  refreshTimer_.async_wait([self = shared_from_this()](const error_code& ec) {
    asio::post(self->strand_, [self, ec] { self->OnRefreshTimer(ec); });
  });
}

void SmaServer::Impl::Session::OnRefreshTimer(const error_code& ec) {
  switch (state_.OnRemapTimer(bool(ec))) {
    case ViewSession::TimerAction::kNothing:
      return;
    case ViewSession::TimerAction::kReschedule:  // try again after the running job
      ScheduleRefresh();
      return;
    case ViewSession::TimerAction::kStartJob:
      break;
  }
  StartJob();
  // Another path (a new view, a client that caught up) may have run the
  // refresh while this timer waited, leaving nothing to start. A refinement
  // step that found nothing to split was waiting for this timer to wake it:
  // wake it here, or it would wait forever (seen on the breakfast room).
  if (state_.RunningJob() == ViewSession::Job::kNone) MaybeRefine();
}

void SmaServer::Impl::Session::WaitUntilUnblocked() {
  if (!state_.BeginDrainWait()) return;
  // The connection calls back on this strand once the client has read down
  // to the soft limit: no polling.
  std::weak_ptr<Session> weak = shared_from_this();
  connection_->NotifyWhenQueuedAtMost(server_.options_.clientSoftQueueBytes, [weak] {
    auto self = weak.lock();
    if (!self) return;
    Clock::time_point due;
    const ViewSession::RemapAction action =
        self->state_.OnDrained(Clock::now(), self->server_.options_.refreshInterval, &due);
    if (!self->connection_->IsOpen()) return;
    self->SendTextures();
    // A held-back new view starts now; the refresh keeps its throttle.
    switch (action) {
      case ViewSession::RemapAction::kNothing:
        return;
      case ViewSession::RemapAction::kStartNow:
        self->StartJob();
        return;
      case ViewSession::RemapAction::kArmTimer:
        self->ArmRefreshTimer(due);
        return;
    }
  });
}

void SmaServer::Impl::Session::OnStatsRequest(const wire::StatsRequest& request) {
  wire::Envelope envelope;
  auto* reply = envelope.mutable_stats_reply();
  reply->set_request_id(request.request_id());
  server_.AddGlobalCounters(reply);
  AddCounter(reply, "client_view_id", double(state_.AppliedViewId()));
  AddCounter(reply, "client_views_received", double(viewsReceived_));
  AddCounter(reply, "client_triangles_held", double(mirror_.TriangleCount()));
  AddCounter(reply, "client_vertices_held", double(mirror_.VertexCount()));
  AddCounter(reply, "client_pending_triangles", double(state_.PendingNodes()));
  AddCounter(reply, "client_pending_samples", double(state_.WaitingSamples()));
  AddCounter(reply, "client_converged", state_.Converged() ? 1.0 : 0.0);
  // What convergence waits for (ViewSession::Converged), for a stall report.
  AddCounter(reply, "client_stage1_done", state_.Stage1Done() ? 1.0 : 0.0);
  AddCounter(reply, "client_refinement_done", state_.RefinementDone() ? 1.0 : 0.0);
  AddCounter(reply, "client_improvement_done", state_.ImprovementDone() ? 1.0 : 0.0);
  AddCounter(reply, "client_remap_wanted", state_.RemapWanted() ? 1.0 : 0.0);
  AddCounter(reply, "client_plan_owed", state_.PlanOwed() ? 1.0 : 0.0);
  AddCounter(reply, "client_deltas_sent", double(deltasSent_));
  AddCounter(reply, "client_improvements_pending", double(state_.ImprovementsPending()));
  AddCounter(reply, "client_improvements_asked", double(improvementsAsked_));
  AddCounter(reply, "client_vertex_updates_sent", double(updatesSent_));
  AddCounter(reply, "client_reshades_sent", double(reshadesSent_));
  AddCounter(reply, "client_kept_held", double(keptHeld_));
  AddCounter(reply, "client_reshades_awaited", double(state_.ReshadesAwaited()));
  AddCounter(reply, "client_moves_sent", double(movesSent_));
  AddCounter(reply, "client_scene_epoch", double(epochSent_));
  AddCounter(reply, "client_bytes_sent", double(connection_->BytesSent()));
  AddCounter(reply, "client_bytes_received", double(connection_->BytesReceived()));
  AddCounter(reply, "client_last_trace_ms", lastTimings_.traceMs);
  AddCounter(reply, "client_last_map_ms", lastTimings_.mapMs);
  AddCounter(reply, "client_last_view_to_first_delta_ms", lastFirstDeltaMs_);
  AddCounter(reply, "client_triangles_sent", double(trianglesSent_));
  AddCounter(reply, "client_stage1_ms", state_.Stage1Ms());
  AddCounter(reply, "client_stage2_ms", state_.Stage2Ms());
  AddCounter(reply, "client_refinement_splits", double(state_.Refinement().Splits()));
  AddCounter(reply, "client_refinement_samples", double(state_.Refinement().Samples()));
  AddCounter(reply, "client_refinement_pending", double(state_.Refinement().PendingSamples()));
  AddCounter(reply, "client_visibility_pixels_reserved", double(reservedPixels_));
  AddCounter(reply, "client_texture_requests_outstanding", double(texturesOutstanding_.size()));
  AddCounter(reply, "client_texture_requests_refused", double(textureRequestsRefused_));
  AddCounter(reply, "visibility_pixels_reserved", double(server_.visibilityBudget_.Used()));
  AddCounter(reply, "textures_encoded", double(server_.textures_.EncodedCount()));
  AddCounter(reply, "visibility_traces", double(server_.viewTraces_.load()));
  AddCounter(reply, "view_jobs_retargeted", double(server_.viewJobsRetargeted_.load()));
  size_t backedUp = 0;
  for (const auto& s : server_.Sessions())
    backedUp += s->Connection().QueuedBytes() > server_.options_.clientSoftQueueBytes;
  AddCounter(reply, "clients_backed_up", double(backedUp));
  connection_->Send(envelope);
}

void SmaServer::Impl::Session::OnTextureRequest(const wire::TextureRequest& request) {
  const Scene& scene = server_.scene_;
  const uint32_t texture = request.texture();
  if (auto ok = CheckTextureRequest(request, scene.textures.size()); !ok) {
    connection_->Send(MakeError(texture, wire::ERROR_CODE_INVALID_REQUEST, ok.error().message, false));
    return;
  }
  // A repeat of a request not yet answered: the one answer serves both.
  if (texturesOutstanding_.contains(texture)) return;
  const size_t limit = server_.options_.maxTextureRequests;
  if (!TextureRequestAllowed(texturesOutstanding_.size(), limit)) {
    if (textureRequestsRefused_++ == 0)
      log_->info("{}: texture requests over the limit of {} outstanding refused", connection_->Id(), limit);
    connection_->Send(MakeError(texture, wire::ERROR_CODE_LIMIT_EXCEEDED,
                                fmt::format("texture {}: {} texture requests are outstanding, at most {} "
                                            "(--max-texture-requests); ignored: ask again when they have arrived",
                                            texture, texturesOutstanding_.size(), limit),
                                false));
    return;
  }
  // Encoded once for every client, off the I/O threads; sent when this
  // client's queue has room.
  std::weak_ptr<Session> weak = shared_from_this();
  auto frame = server_.textures_.Get(texture, [weak, texture](TextureFrames::Frame ready) {
    if (auto self = weak.lock())
      asio::post(self->strand_, [self, texture, ready] { self->OnTextureReady(texture, ready); });
  });
  texturesOutstanding_.emplace(texture, frame);
  if (frame) SendTextures();
}

void SmaServer::Impl::Session::OnTextureReady(uint32_t texture, TextureFrames::Frame frame) {
  auto it = texturesOutstanding_.find(texture);
  if (it == texturesOutstanding_.end()) return;
  it->second = std::move(frame);
  SendTextures();
}

void SmaServer::Impl::Session::SendTextures() {
  if (!connection_->IsOpen()) return;
  for (auto it = texturesOutstanding_.begin(); it != texturesOutstanding_.end();) {
    if (!it->second) {
      ++it;
      continue;
    }
    if (Blocked()) {
      WaitUntilUnblocked();  // sends the rest
      return;
    }
    if (!connection_->SendFrame(it->second)) {
      connection_->Close("client send queue overflow");
      return;
    }
    it = texturesOutstanding_.erase(it);
  }
}

void SmaServer::Impl::Session::OnClosed(const std::string& reason) {
  refreshTimer_.cancel();
  if (predictionCancel_) *predictionCancel_ = true;  // nobody will walk there (also at shutdown)
  server_.pool_->ReleaseInterest(interest_);
  interest_.clear();
  server_.visibilityBudget_.Resize(reservedPixels_, 0);
  runningJobPixels_ = 0;
  texturesOutstanding_.clear();
  log_->info("{}: closed ({}); sent {} deltas, {} bytes", connection_->Id(), reason, deltasSent_,
             connection_->BytesSent());
  server_.RemoveSession(id_);
}

// --- Server -----------------------------------------------------------------

MemoryUsage SmaServer::Impl::Memory() {
  MemoryUsage usage;
  {
    std::shared_lock lock(stateMutex_);
    usage.hierarchy = hierarchy_.MemoryBytes();
  }
  usage.cache = cache_.MemoryBytes();
  for (const auto& s : Sessions()) usage.clients += s->MirrorBytes();
  return usage;
}

void SmaServer::Impl::AddGlobalCounters(wire::StatsReply* reply) {
  size_t nodes, vertices, shaded;
  uint64_t hits, misses;
  {
    std::shared_lock lock(stateMutex_);
    nodes = hierarchy_.NodeCount();
    vertices = hierarchy_.VertexCount();
    shaded = cache_.ShadedCount();
    hits = cache_.Hits();
    misses = cache_.Misses();
  }
  const RendererPoolStats pool = pool_->Stats();
  AddCounter(reply, "clients", double(Sessions().size()));
  AddCounter(reply, "hierarchy_nodes", double(nodes));
  AddCounter(reply, "hierarchy_vertices", double(vertices));
  AddCounter(reply, "cache_shaded", double(shaded));
  AddCounter(reply, "samples_improved", double(samplesImproved_.load()));
  AddCounter(reply, "scene_epoch", double(CurrentPose()->epoch));
  AddCounter(reply, "moves", double(moves_.load()));
  AddCounter(reply, "moves_refused", double(movesRefused_.load()));
  AddCounter(reply, "moves_coalesced", double(moveQueue_.Coalesced()));
  AddCounter(reply, "samples_invalidated", double(samplesInvalidated_.load()));
  AddCounter(reply, "samples_invalidated_of_objects", double(samplesInvalidatedOfObjects_.load()));
  AddCounter(reply, "samples_tested", double(samplesTested_.load()));
  AddCounter(reply, "last_move_tested", double(lastMoveTested_.load()));
  AddCounter(reply, "tests_kept", double(cache_.Confirmed()));
  AddCounter(reply, "tests_failed", double(cache_.FailedTests()));
  AddCounter(reply, "tests_failed_by_noise", double(testsFailedByNoise_.load()));
  AddCounter(reply, "tests_retested", double(testsRetested_.load()));
  AddCounter(reply, "samples_reshaded_after_move", double(cache_.Reshaded()));
  AddCounter(reply, "samples_stale_refused", double(samplesStale_.load()));
  AddCounter(reply, "last_move_invalidated", double(lastMoveInvalidated_.load()));
  AddCounter(reply, "samples_invalidated_urgent", double(samplesInvalidatedUrgent_.load()));
  AddCounter(reply, "last_move_invalidated_urgent", double(lastMoveInvalidatedUrgent_.load()));
  {
    const MovePreparationCounters p = preparation_.Counters();
    AddCounter(reply, "move_predictions", double(p.predictions));
    AddCounter(reply, "move_predictions_hit", double(p.hits));
    AddCounter(reply, "move_predictions_missed", double(p.misses));
    AddCounter(reply, "moves_snapped", double(movesSnapped_.load()));
    AddCounter(reply, "samples_prepared_arrived", double(p.samplesArrived));
    AddCounter(reply, "samples_prepared_dropped", double(p.samplesDropped));
    AddCounter(reply, "samples_prepared_stored", double(preparedStored_.load()));
    AddCounter(reply, "last_prepare_ms", lastPrepareMs_.load());
  }
  AddCounter(reply, "last_move_cached", double(lastMoveCached_.load()));
  AddCounter(reply, "last_move_reshaded", double(cache_.Reshaded() - lastMoveReshadedBase_.load()));
  AddCounter(reply, "last_move_apply_ms", lastMoveApplyMs_.load());
  AddCounter(reply, "cache_hits", double(hits));
  AddCounter(reply, "cache_misses", double(misses));
  AddCounter(reply, "cache_hit_rate", hits + misses > 0 ? double(hits) / double(hits + misses) : 0.0);
  const MemoryUsage memory = Memory();
  AddCounter(reply, "memory_bytes", double(memory.Total()));
  AddCounter(reply, "memory_cache_bytes", double(memory.cache));
  AddCounter(reply, "memory_hierarchy_bytes", double(memory.hierarchy));
  AddCounter(reply, "memory_clients_bytes", double(memory.clients));
  AddCounter(reply, "memory_budget_bytes", double(options_.memoryBudgetBytes));
  {
    std::shared_lock lock(stateMutex_);
    AddCounter(reply, "memory_in_use_bytes", double(DataInUse()));
    AddCounter(reply, "hierarchy_nodes_live", double(hierarchy_.LiveNodeCount()));
    AddCounter(reply, "hierarchy_vertices_live", double(hierarchy_.LiveVertexCount()));
  }
  AddCounter(reply, "memory_collections", double(collections_.load()));
  AddCounter(reply, "memory_collections_stuck", double(collectOverBudgetStuck_.load()));
  AddCounter(reply, "collected_groups", double(collectedGroups_.load()));
  AddCounter(reply, "collected_nodes", double(collectedNodes_.load()));
  AddCounter(reply, "collected_vertices", double(collectedVertices_.load()));
  AddCounter(reply, "collect_kept_groups", double(collectKept_.load()));
  AddCounter(reply, "samples_evicted", double(samplesEvicted_.load()));
  AddCounter(reply, "sample_chunks_dropped", double(sampleChunksDropped_.load()));
  AddCounter(reply, "scene_records_released_bytes", double(recordsReleasedBytes_.load()));
  AddCounter(reply, "memory_trims", double(trims_.load()));
  AddCounter(reply, "memory_trimmed_bytes", double(trimmedBytes_.load()));
  AddCounter(reply, "samples_reshaded_after_eviction", double(samplesRemade_.load() + cache_.ReshadedAfterDrop()));
  AddCounter(reply, "remaps_after_collection", double(remapsAfterCollection_.load()));
  AddCounter(reply, "view_remaps", double(viewRemaps_.load()));
  AddCounter(reply, "view_remaps_unchanged", double(viewRemapsUnchanged_.load()));
  if (const auto rss = metrics::ResidentMemoryBytes()) AddCounter(reply, "process_resident_bytes", double(*rss));
  AddCounter(reply, "samples_requested", double(pool.requested));
  AddCounter(reply, "samples_shaded", double(pool.shaded));
  AddCounter(reply, "samples_requeued", double(pool.requeued));
  AddCounter(reply, "samples_failed", double(pool.failed));
  AddCounter(reply, "samples_rejected", double(pool.rejected));
  AddCounter(reply, "samples_queued_visible", double(pool.queuedVisible));
  AddCounter(reply, "samples_queued_predicted", double(pool.queuedPredicted));
  AddCounter(reply, "samples_queued_background", double(pool.queuedBackground));
  AddCounter(reply, "samples_queued_improve", double(pool.queuedImprove));
  AddCounter(reply, "samples_in_flight", double(pool.inFlight));
  AddCounter(reply, "samples_prepared", double(pool.preparedRequested));
  AddCounter(reply, "samples_prepared_shaded", double(pool.preparedShaded));
  AddCounter(reply, "samples_queued_prepared", double(pool.queuedPrepared));
  AddCounter(reply, "tests_queued", double(pool.queuedVerify));
  AddCounter(reply, "tests_answered", double(pool.verified));
  AddCounter(reply, "predicted_views", double(predictedViews_.load()));
  AddCounter(reply, "samples_requested_predicted", double(samplesPredicted_.load()));
  const uint64_t newTriangles = viewTrianglesNew_.load(), newShaded = viewTrianglesNewShaded_.load();
  AddCounter(reply, "view_triangles_new", double(newTriangles));
  AddCounter(reply, "view_triangles_new_shaded", double(newShaded));
  AddCounter(reply, "prediction_hit_rate", newTriangles > 0 ? double(newShaded) / double(newTriangles) : 0.0);
  size_t connected = 0;
  for (const RendererStatus& r : pool.renderers) {
    connected += r.connected;
    // By index, never by address: clients must not learn where the renderers
    // are (operators find the pairing in the log).
    const std::string prefix = fmt::format("renderer.{}.", r.index);
    AddCounter(reply, prefix + "connected", r.connected ? 1.0 : 0.0);
    AddCounter(reply, prefix + "samples_in_flight", double(r.samplesInFlight));
    AddCounter(reply, prefix + "samples_shaded", double(r.samplesShaded));
    AddCounter(reply, prefix + "samples_per_second", r.samplesPerSecond);
    AddCounter(reply, prefix + "failures", double(r.failures));
    AddCounter(reply, prefix + "bad_replies", double(r.badReplies));
  }
  AddCounter(reply, "renderers", double(pool.renderers.size()));
  AddCounter(reply, "renderers_connected", double(connected));
  if (snapshots_) {
    const CacheSnapshotStats disk = snapshots_->Stats();
    AddCounter(reply, "cache_snapshots_written", double(disk.written));
    AddCounter(reply, "cache_snapshot_samples", double(disk.lastSamples));
    AddCounter(reply, "cache_snapshot_bytes", double(disk.lastBytes));
    AddCounter(reply, "cache_restored_samples", double(disk.restoredSamples));
  }
}

// HTTP thread (never an I/O thread): the same counters as StatsReply.
void SmaServer::Impl::WriteMetrics(metrics::ExpositionWriter& out) {
  wire::StatsReply counters;
  AddGlobalCounters(&counters);
  WriteSmaMetrics(out, counters, latencies_);
  // The endpoint is the operators': it may say where each renderer is (the
  // counters name them by index only, as clients see them).
  out.Family("penumbra_sma_renderer_info", "gauge", "1 per renderer endpoint: its index (the renderer label) and address");
  for (const RendererStatus& r : pool_->Stats().renderers)
    out.Sample("penumbra_sma_renderer_info", 1.0, {{"renderer", std::to_string(r.index)}, {"address", r.endpoint}});
}

std::string SmaServer::Impl::NotReadyReason() {
  if (shuttingDown_) return "shutting down";
  const RendererPoolStats pool = pool_->Stats();
  size_t connected = 0;
  for (const RendererStatus& r : pool.renderers) connected += r.connected;
  if (connected == 0)
    return fmt::format("no renderer connected ({} address(es) known); views would wait for shading",
                       pool.renderers.size());
  return {};
}

void SmaServer::Impl::LogStats() {
  const RendererPoolStats now = pool_->Stats();
  const double seconds = std::chrono::duration<double>(options_.statsInterval).count();
  size_t shaded;
  uint64_t hits, misses;
  {
    std::shared_lock lock(stateMutex_);
    shaded = cache_.ShadedCount();
    hits = cache_.Hits();
    misses = cache_.Misses();
  }
  std::string renderers;
  for (const RendererStatus& r : now.renderers)
    renderers += fmt::format(" {}{}:{} in flight", r.endpoint, r.connected ? "" : "(down)", r.samplesInFlight);
  std::string clients;
  for (auto& s : Sessions()) clients += fmt::format(" {}:{}B", s->Connection().Id(), s->Connection().BytesSent());
  std::string views = "none";
  {
    std::lock_guard lock(viewTimesMutex_);
    if (!viewTimes_.empty()) {
      auto percentile = [&](int column, double p) {
        std::vector<double> v;
        for (const auto& t : viewTimes_) v.push_back(t[size_t(column)]);
        std::sort(v.begin(), v.end());
        return v[std::min(v.size() - 1, size_t(p * double(v.size() - 1) + 0.5))];
      };
      views = fmt::format("{} (trace p50 {:.1f} ms, map p50 {:.1f} ms, view->first delta p50 {:.1f} / p99 {:.1f} ms)",
                          viewTimes_.size(), percentile(0, 0.5), percentile(1, 0.5), percentile(2, 0.5),
                          percentile(2, 0.99));
      viewTimes_.clear();
    }
  }
  std::string moves;
  if (!scene_.objects.empty())
    moves = fmt::format("; scene epoch {}, {} moves, {} samples invalidated, {} re-shaded, {} stale replies refused",
                        CurrentPose()->epoch, moves_.load(), samplesInvalidated_.load(), cache_.Reshaded(),
                        samplesStale_.load());
  const MemoryUsage memory = Memory();
  constexpr double kMiB = 1024.0 * 1024.0;
  std::string budget;
  if (options_.memoryBudgetBytes > 0)
    budget = fmt::format(" ({:.1f} in use) of a {:.0f} MiB budget{}; {} collections, {} nodes and {} samples collected, "
                         "{} re-made",
                         double(memoryInUse_.load()) / kMiB, double(options_.memoryBudgetBytes) / kMiB,
                         memoryInUse_.load() > options_.memoryBudgetBytes ? " (OVER)" : "", collections_.load(),
                         collectedNodes_.load(), samplesEvicted_.load(), samplesRemade_.load() + cache_.ReshadedAfterDrop());
  log_->info("stats: cache {} shaded, hit rate {:.1f}%; memory {:.1f} MiB{} (cache {:.1f}, hierarchy {:.1f}, "
             "clients {:.1f}; resident {:.1f}); {:.0f} requested/s, {:.0f} shaded/s, {} queued; "
             "renderers:{}; clients:{}; views: {}{}",
             shaded, hits + misses > 0 ? 100.0 * double(hits) / double(hits + misses) : 0.0,
             double(memory.Total()) / kMiB, budget, double(memory.cache) / kMiB, double(memory.hierarchy) / kMiB,
             double(memory.clients) / kMiB, double(metrics::ResidentMemoryBytes().value_or(0)) / kMiB,
             double(now.requested - lastStats_.requested) / seconds, double(now.shaded - lastStats_.shaded) / seconds,
             now.queuedVisible + now.queuedPredicted + now.queuedBackground, renderers.empty() ? " none" : renderers,
             clients.empty() ? " none" : clients, views, moves);
  lastStats_ = now;
}

size_t SmaServer::Impl::DataInUse() {
  size_t clients = 0;
  for (const auto& session : Sessions()) clients += session->MirrorBytes();
  return MemoryCollector::DataInUse(hierarchy_, cache_, clients);
}

void SmaServer::Impl::ArmCollectorClock() {
  collectorTimer_.expires_after(kTick);
  collectorTimer_.async_wait(asio::bind_executor(skeleton_.Control(), [this](const error_code& ec) {
    if (ec || shuttingDown_) return;
    const auto ticks = uint32_t((Clock::now() - collectorStart_) / kTick);
    hierarchy_.SetTick(ticks);  // atomics: no lock
    cache_.SetTick(ticks);
    if (collector_.Enabled() && ticks % kCollectCheckTicks == 0 && !collecting_.exchange(true))
      jobs_.Post(kCollectorSession, JobClass::kRefinement, [this] { Collect(/*fresh=*/true); });
    ArmCollectorClock();
  }));
}

void SmaServer::Impl::Collect(bool fresh) {
  // Runs after every waiting new view, re-map and prediction, taking turns
  // with the sessions' refinement steps (JobClass::kRefinement); it posts
  // itself again after each bounded step.
  // finish() ends the collection when this job returns: the trim (tens of
  // ms) runs after the state lock below is released, so it holds up no
  // split, and before collecting_ lets the next collection job in.
  struct EndOfCollection {
    Impl* impl;
    bool finished = false;
    ~EndOfCollection() {
      if (!finished) return;
      impl->TrimFreedHeap();
      impl->collecting_ = false;
    }
  } end{this};
  const auto finish = [&end] { end.finished = true; };
  if (shuttingDown_) return finish();
  size_t inUse = 0;
  {
    std::shared_lock lock(stateMutex_);
    inUse = DataInUse();
    memoryInUse_ = inUse;
    if (fresh && !collector_.ShouldStart(inUse)) return finish();
    if (inUse <= collector_.StopBytes()) return finish();
    if (fresh) {
      ++collections_;
      releasedThisCollection_ = false;
    }
    // A new scan once the last one's candidates are used up -- unless they
    // freed nothing: then what is left is held, young or entangled with
    // what is held, and the next check (kCollectCheckTicks) looks again.
    if (!collector_.HasCandidates() && (fresh || collectedSinceScan_)) {
      collector_.Scan(hierarchy_, cache_);  // O(nodes), views go on meanwhile
      collectedSinceScan_ = false;
    }
  }
  if (!collector_.HasCandidates()) {
    // Nothing refined is left to collect. The records of unsplit roots and
    // of base vertices are the scene's, made again on first use: free them
    // all (the views in progress make theirs again, a few ms), once per
    // collection, and look again.
    if (!releasedThisCollection_) {
      releasedThisCollection_ = true;
      {
        std::unique_lock lock(stateMutex_);
        const size_t released = hierarchy_.ReleaseSceneRecords();
        recordsReleasedBytes_ += released;
        freedSinceTrim_ += released;
        inUse = DataInUse();
      }
      memoryInUse_ = inUse;
      if (inUse <= collector_.StopBytes()) return finish();
    }
    // Everything refined was used within --memory-min-age, or is held: the
    // working set is larger than the budget. Look again at the next check.
    ++collectOverBudgetStuck_;
    // Once a minute at most: a walk whose working set is over the stop
    // level meets this at every check.
    const auto now = Clock::now();
    if (now - lastStuckWarning_ >= std::chrono::minutes(1)) {
      lastStuckWarning_ = now;
      log_->warn("memory: {:.1f} MiB in use, over the collector's stop level ({:.1f} MiB of a {:.1f} MiB budget), "
                 "and nothing left that no client holds and nobody used in the last {:.1f} s",
                 double(inUse) / 1048576.0, double(collector_.StopBytes()) / 1048576.0,
                 double(options_.memoryBudgetBytes) / 1048576.0, options_.memoryMinAgeSeconds);
    }
    return finish();
  }
  CollectStep step;
  {
    std::unique_lock lock(stateMutex_);
    const auto sessions = Sessions();
    step = collector_.Step(hierarchy_, cache_, inUse - collector_.StopBytes(),
                           [&](const Hierarchy::CollapseGroup& group) {
                             for (const auto& session : sessions)
                               if (session->HoldsAnyOf(group)) return true;
                             return pool_->AnyAlive(group.freedVertices);  // lock order: state, then pool
                           },
                           [&](VertexId first, VertexId stop) {
                             for (const auto& session : sessions)
                               if (session->HoldsAnyVertexIn(first, stop)) return true;
                             std::vector<VertexId> vertices(stop - first);
                             std::iota(vertices.begin(), vertices.end(), first);
                             return pool_->AnyAlive(vertices);
                           });
  }
  collectedSinceScan_ = collectedSinceScan_ || step.groups > 0 || step.chunksDropped > 0;
  // A dropped chunk's pages went back already (madvise): no trim for them.
  freedSinceTrim_ += step.bytesFreed - step.chunksDropped * SampleCache::ChunkBytes();
  collectedGroups_ += step.groups;
  collectedNodes_ += step.nodesFreed;
  collectedVertices_ += step.verticesFreed;
  samplesEvicted_ += step.samplesDropped;
  sampleChunksDropped_ += step.chunksDropped;
  collectKept_ += step.kept;
  log_->debug("memory: collected {} groups ({} nodes, {} vertices) and {} chunks of base-vertex samples "
              "({} samples in all; {} kept, {} young), {:.1f} MiB",
              step.groups, step.nodesFreed, step.verticesFreed, step.chunksDropped, step.samplesDropped, step.kept,
              step.young,
              double(step.bytesFreed) / 1048576.0);
  jobs_.Post(kCollectorSession, JobClass::kRefinement, [this] { Collect(/*fresh=*/false); });
}

void SmaServer::Impl::TrimFreedHeap() {
  // glibc keeps the pages of freed chunks resident (in the middle of a heap,
  // and in every thread's arena) and reuses them only for allocations that
  // fit: what a collection frees -- collapsed subtrees' vectors, released
  // scene records' chunks, dropped cache chunks -- stayed resident after it,
  // so resident memory went on growing past the data in use
  // (docs/performance.md "Memory over a long walk"). malloc_trim(0) walks
  // all arenas and madvises their free pages away: 20-70 ms on the street,
  // so on the collection job's thread, never an I/O thread, after the state
  // lock is released, once per collection.
  constexpr size_t kTrimAfterFreedBytes = size_t(1) << 20;
  if (freedSinceTrim_ < kTrimAfterFreedBytes) return;
  freedSinceTrim_ = 0;
  const auto before = metrics::ResidentMemoryBytes();
  const auto start = Clock::now();
  malloc_trim(0);
  const double ms = Milliseconds(Clock::now() - start);
  const auto after = metrics::ResidentMemoryBytes();
  ++trims_;
  if (before && after && *after < *before) trimmedBytes_ += *before - *after;
  // Logged when it mattered: a walk under a small budget collects every few
  // seconds.
  const bool notable = (before && after && *before >= *after + (size_t(4) << 20)) || ms >= 20.0;
  log_->log(notable ? spdlog::level::info : spdlog::level::debug,
            "memory: malloc_trim after a collection: resident {:.1f} -> {:.1f} MiB in {:.1f} ms",
            double(before.value_or(0)) / 1048576.0, double(after.value_or(0)) / 1048576.0, ms);
}

void SmaServer::Impl::ArmRendererWatch() {
  rendererWatchTimer_.expires_after(std::chrono::milliseconds(500));
  rendererWatchTimer_.async_wait(asio::bind_executor(skeleton_.Control(), [this](const error_code& ec) {
    if (ec || shuttingDown_) return;
    const size_t renderers = pool_->ReadyRenderers();
    for (auto& session : Sessions())
      asio::post(session->Strand(), [session, renderers] { session->OnRendererCount(renderers); });
    ArmRendererWatch();
  }));
}

void SmaServer::Impl::ApplyMoves() {
  for (std::vector<ObjectMove> moves = moveQueue_.Take(); !moves.empty(); moves = moveQueue_.Take())
    if (!shuttingDown_) ApplyMoveStep(moves);
}

void SmaServer::Impl::ApplyMoveStep(std::span<const ObjectMove> moves) {
  const auto start = Clock::now();
  const std::shared_ptr<const ScenePose> oldPose = CurrentPose();  // only this job replaces it
  // A client's move that lands within --move-snap of the place prepared for
  // it is applied there (move_prediction.h, "Snapping"): the samples shaded
  // ahead at that place are then exactly right.
  std::vector<ObjectMove> placed(moves.begin(), moves.end());
  if (options_.movePrediction && options_.moveSnap > 0.0f) {
    const std::shared_ptr<const ScenePose> predicted = preparation_.Predicted();
    if (predicted && predicted->epoch == oldPose->epoch + 1) {
      for (ObjectMove& move : placed) {
        if (auto snapped = SnapToPrediction(move, *oldPose, *predicted, scene_, options_.moveSnap)) {
          movesSnapped_ += !(snapped->objectToWorld == move.objectToWorld);
          move = *snapped;
        } else if (move.object < scene_.objects.size() &&
                   !(predicted->objectToWorld[move.object] == oldPose->objectToWorld[move.object])) {
          // A drag's guess missed (it turned, sped up, or was not steady).
          log_->debug("move of object {} lands {:.3f} mm from its predicted place: not snapped", move.object,
                      1e3 * LargestDisplacement(move.objectToWorld, predicted->objectToWorld[move.object],
                                                scene_.objects[move.object].objectBounds));
        }
      }
    }
  }
  std::optional<ScenePose> next = NextPose(*oldPose, placed);
  if (!next) return;  // nothing changes place: no new epoch
  auto newPose = std::make_shared<const ScenePose>(std::move(*next));
  const auto posing = Clock::now();
  auto posed = tracer_->AtPose(*newPose);
  if (!posed) {
    log_->error("move to scene epoch {} not applied: {}", newPose->epoch, posed.error().message);
    return;
  }
  // 1. Publish: batches dispatched from now on are shaded at the new pose,
  //    views traced from now on see it.
  pool_->SetPose(newPose);
  {
    std::lock_guard lock(poseMutex_);
    pose_ = newPose;
    posed_ = *posed;
  }
  // 2. What the move invalidates (reads the hierarchy and the cache).
  Invalidation invalidation;
  const size_t cachedBefore = cache_.ShadedCount();
  const auto planning = Clock::now();
  {
    std::shared_lock lock(stateMutex_);
    // Every pose so far, by epoch: each cached sample is judged against the
    // pose it was shaded at. Only this job touches the history.
    poseHistory_.Record(oldPose);
    // Before the plan reads which vertices have samples (SampleCache: a
    // first estimate of one with none, shaded at the old pose, is refused
    // from here on; one stored before is read by the plan and judged).
    cache_.InvalidateUnshaded(newPose->epoch);
    const InvalidationRule rule = options_.invalidateEverythingOnMove ? InvalidationRule::kEverything
                                  : options_.pool.verifyPaths == 0     ? InvalidationRule::kTest
                                  : options_.moveTestDirect            ? InvalidationRule::kTestAll
                                                                       : InvalidationRule::kTestIndirect;
    invalidation = PlanInvalidation(hierarchy_, cache_, *oldPose, *newPose, rule, &poseHistory_);
    poseHistory_.Record(newPose);
  }
  const auto invalidating = Clock::now();
  // 3. Invalidate under the exclusive lock: a delta is planned and built
  //    under the shared lock, so it sees each sample either before (then
  //    the client gets it and, holding it, its reshade) or after (then the
  //    vertex is unshaded and the node waits) -- never a sample evicted
  //    between the plan and the delta. Samples shaded before the new epoch
  //    that arrive later are refused by the cache (validFrom).
  size_t evicted = 0;
  size_t evictedUrgent = 0;  // of which urgent: the moved objects' own and where direct light changed
  size_t evictedOfObjects = 0;  // of which on movable objects (the moved ones' own)
  std::vector<VertexId> prepared;  // first estimates shaded ahead at this pose (move prediction), now stored
  std::vector<VerifyRequest> tests;  // samples held back for a test of this move
  MovePreparation::AppliedOutcome preparedFor;
  {
    std::unique_lock lock(stateMutex_);
    for (VertexId v : invalidation.vertices) {
      const bool was = cache_.Invalidate(v, newPose->epoch);
      evicted += was;
      if (was && scene_.ObjectOfTriangle(hierarchy_.GetVertex(v).baseTriangle) != kStaticObject) ++evictedOfObjects;
      if (was && std::binary_search(invalidation.urgent.begin(), invalidation.urgent.end(), v)) ++evictedUrgent;
    }
    // The indirect class: held back and tested (one context per baseline
    // pose: `tested` is grouped by it), or -- when the region is more than
    // a test can take -- invalidated like the rest.
    std::shared_ptr<const VerifyContext> context;
    for (const TestedVertex& t : invalidation.tested) {
      if (!context || context->baseline->epoch != t.baselineEpoch) {
        context.reset();
        std::shared_ptr<const ScenePose> baseline =
            t.baselineEpoch == oldPose->epoch ? oldPose : poseHistory_.Shared(t.baselineEpoch);
        if (baseline) {
          if (auto boxes = VerifyRegionBoxes(scene_, *baseline, *newPose))
            context = std::make_shared<const VerifyContext>(VerifyContext{baseline, newPose, std::move(*boxes)});
        }
      }
      if (!context) {
        evicted += cache_.Invalidate(t.vertex, newPose->epoch);
        continue;
      }
      const std::optional<uint32_t> generation = cache_.Suspect(t.vertex, newPose->epoch);
      if (!generation) continue;  // shaded at the new pose already: valid
      VerifyRequest request{MakeSampleRequest(hierarchy_, t.vertex), context, *generation, t.tolerance};
      request.request.round = VerifyRound(newPose->epoch);
      tests.push_back(std::move(request));
    }
    // Under the same lock: a view mapped after the invalidation finds them
    // stored, and sessions told of the move below do not ask for them.
    preparedFor = preparation_.Applied(*newPose, hierarchy_.StructureGeneration());
    prepared = StorePrepared(preparedFor.samples);
  }
  // The preparation's samples not sent yet: asked for at the new pose after
  // a hit (sessions' requests below then find them alive), dropped after a
  // miss.
  if (preparedFor.preparedEpoch != 0) pool_->EndPreparation(preparedFor.preparedEpoch, preparedFor.hit);
  // Suspect in the cache, so alive (stored, as requests see it) until
  // the pool has them.
  if (!tests.empty()) pool_->Verify(tests);
  samplesTested_ += tests.size();
  lastMoveTested_ = tests.size();
  ++moves_;
  samplesInvalidated_ += evicted;
  lastMoveInvalidated_ = evicted;
  samplesInvalidatedUrgent_ += evictedUrgent;
  samplesInvalidatedOfObjects_ += evictedOfObjects;
  lastMoveInvalidatedUrgent_ = evictedUrgent;
  lastMoveCached_ = cachedBefore;
  lastMoveReshadedBase_ = cache_.Reshaded();
  const double ms = Milliseconds(Clock::now() - start);
  lastMoveApplyMs_ = ms;
  // 4. Tell every session: MOVED, held vertices asked again, views re-traced.
  auto notice = std::make_shared<MoveNotice>();
  notice->pose = newPose;
  notice->urgent = std::make_shared<const std::vector<VertexId>>(std::move(invalidation.urgent));
  for (uint32_t o = 0; o < newPose->objectToWorld.size(); ++o)
    if (!(oldPose->objectToWorld[o] == newPose->objectToWorld[o])) notice->movedObjects.push_back(o);
  auto arrived = std::make_shared<const std::vector<VertexId>>(std::move(prepared));
  notice->prepared = arrived;
  for (auto& session : Sessions()) {
    asio::post(session->Strand(), [session, notice] { session->OnMoved(*notice); });
    // After MOVED on the session's strand: held ones go out as RESHADED.
    if (!arrived->empty()) NotifyArrived(session, arrived);
  }
  log_->debug("scene epoch {}: {} object(s) moved; {} vertices invalidated ({} of the objects'), {} of {} cached "
              "samples evicted, {} held back for a test, {} prepared samples stored; applied in {:.1f} ms "
              "(posing {:.1f}, planning {:.1f}, invalidating {:.1f})",
              newPose->epoch, notice->movedObjects.size(), invalidation.vertices.size(),
              invalidation.objectVertices, evicted, cachedBefore, tests.size(), arrived->size(), ms,
              Milliseconds(planning - posing), Milliseconds(invalidating - planning), ms - Milliseconds(invalidating - start));
  if (options_.movePrediction) {
    movePredictor_.Applied(*oldPose, newPose->epoch, moves, Clock::now());
    PredictNextMove(*newPose);
  }
}

void SmaServer::Impl::PredictNextMove(const ScenePose& applied) {
  std::optional<ScenePose> predicted = movePredictor_.Predict(applied, animationStep_.load());
  if (!predicted) return;
  auto pose = std::make_shared<const ScenePose>(std::move(*predicted));
  // After views and predicted views, like the samples it asks for.
  jobs_.Post(kMoveJobSession, JobClass::kPrediction, [this, pose] { PrepareMove(pose); });
}

void SmaServer::Impl::PrepareMove(std::shared_ptr<const ScenePose> predicted) {
  if (shuttingDown_) return;
  const auto start = Clock::now();
  const std::shared_ptr<const ScenePose> current = CurrentPose();
  if (current->epoch + 1 != predicted->epoch) return;  // another move came first
  // At most this many samples per preparation: a step's urgent class of a
  // large refined view, not a whole scene.
  constexpr size_t kMaxPrepared = size_t(1) << 16;
  // What clients held that the last move made them ask again: the next
  // step's displayed changes are most likely among them (a client's view
  // and the object move little in a step).
  std::vector<VertexId> held;
  {
    std::lock_guard lock(heldReshadeMutex_);
    held = heldReshade_;
  }
  if (held.empty()) return;
  std::vector<SampleRequest> requests;
  uint64_t generation = 0;
  {
    std::shared_lock lock(stateMutex_);
    generation = hierarchy_.StructureGeneration();
    // What the move would invalidate urgently (the objects' own vertices
    // and where direct light changes), of what clients hold: what a viewer
    // sees change first. Judged against the current pose only: a guess
    // about work, never about correctness (the move itself is judged as
    // ever, ApplyMoveStep).
    const Invalidation plan = PlanInvalidation(hierarchy_, cache_, *current, *predicted);
    std::vector<VertexId> wanted;
    std::set_intersection(plan.urgent.begin(), plan.urgent.end(), held.begin(), held.end(),
                          std::back_inserter(wanted));
    for (VertexId v : wanted) {
      if (v >= hierarchy_.VertexCount() || !hierarchy_.VertexAlive(v)) continue;  // collected since it was held
      requests.push_back(MakeSampleRequest(hierarchy_, v));
      if (requests.size() >= kMaxPrepared) break;
    }
  }
  if (!preparation_.Begin(predicted, generation)) return;
  pool_->Prepare(requests, predicted);
  lastPrepareMs_ = Milliseconds(Clock::now() - start);
  log_->debug("scene epoch {} predicted: {} samples prepared in {:.1f} ms", predicted->epoch, requests.size(),
              lastPrepareMs_.load());
}

void SmaServer::Impl::NoteHeldReshade(uint64_t epoch, const std::vector<VertexId>& sortedVertices) {
  std::lock_guard lock(heldReshadeMutex_);
  if (epoch < heldReshadeEpoch_) return;
  if (epoch > heldReshadeEpoch_) {
    heldReshadeEpoch_ = epoch;
    heldReshade_ = sortedVertices;
    return;
  }
  std::vector<VertexId> both;
  both.reserve(heldReshade_.size() + sortedVertices.size());
  std::set_union(heldReshade_.begin(), heldReshade_.end(), sortedVertices.begin(), sortedVertices.end(),
                 std::back_inserter(both));
  heldReshade_ = std::move(both);
}

void SmaServer::Impl::OnPreparedResults(std::vector<ShadedSample>&& samples) {
  const std::vector<ShadedSample> release = preparation_.Arrived(std::move(samples));
  if (release.empty()) return;
  // Their move has happened where predicted: first estimates of this epoch.
  auto stored = std::make_shared<const std::vector<VertexId>>(StorePrepared(release));
  if (stored->empty()) return;
  for (auto& session : Sessions()) NotifyArrived(session, stored);
}

std::vector<VertexId> SmaServer::Impl::StorePrepared(std::span<const ShadedSample> samples) {
  // Only where the move left no sample: one that was kept (not invalidated)
  // or already re-shaded stays.
  std::vector<ShadedSample> missing;
  for (const ShadedSample& s : samples)
    if (!cache_.IsShaded(s.vertex)) missing.push_back(s);
  if (missing.empty()) return {};
  std::vector<VertexId> stale;
  cache_.Store(missing, &stale);  // none stale: shaded at the current epoch
  std::sort(stale.begin(), stale.end());
  std::vector<VertexId> stored;
  for (const ShadedSample& s : missing)
    if (!std::binary_search(stale.begin(), stale.end(), s.vertex)) stored.push_back(s.vertex);
  preparedStored_ += stored.size();
  return stored;
}

void SmaServer::Impl::StartAnimation() {
  bool animated = false;
  for (const MovableObject& o : scene_.objects) animated |= o.animation.has_value();
  if (!animated || !(options_.animationHz > 0.0)) return;
  animationStart_ = Clock::now();
  log_->info("animating the scene's paths at {} Hz", options_.animationHz);
  ArmAnimation();
}

void SmaServer::Impl::ArmAnimation() {
  // Step k at animationStart_ + k periods, placing the objects at the
  // path's time k / animationHz: the next step's places are known ahead
  // (move prediction), whatever the timer's jitter.
  const double hz = options_.animationHz;
  const auto stepTime = [this, hz](uint64_t step) {
    return animationStart_ + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(double(step) / hz));
  };
  animationTimer_.expires_at(stepTime(animationStep_.load() + 1));
  animationTimer_.async_wait(asio::bind_executor(skeleton_.Control(), [this, hz](const error_code& ec) {
    if (ec || shuttingDown_) return;
    // A timer that fired more than a step late plays where the path is now,
    // not the steps it missed.
    const double elapsed = std::chrono::duration<double>(Clock::now() - animationStart_).count();
    const uint64_t step = std::max(animationStep_.load() + 1, uint64_t(std::max(0.0, std::floor(elapsed * hz))));
    animationStep_ = step;
    const double t = double(step) / hz;
    // Cheap here (a few interpolations); the move itself is a job.
    for (uint32_t i = 0; i < scene_.objects.size(); ++i)
      if (const auto& animation = scene_.objects[i].animation) SubmitMove(ObjectMove{i, animation->At(t)});
    ArmAnimation();
  }));
}

// On the skeleton's control strand, like the timers' handlers: cancelling
// them here never races one re-arming itself on another I/O thread.
void SmaServer::Impl::StopWork() {
  shuttingDown_ = true;
  rendererWatchTimer_.cancel();
  animationTimer_.cancel();
  collectorTimer_.cancel();
  jobs_.Stop();
  backgroundJobs_.Stop();
  pool_->Stop();
  log_->info("shutting down: telling {} client(s)", skeleton_.SessionCount());
}

// --- Public wrapper ---------------------------------------------------------

Expected<std::unique_ptr<SmaServer>> SmaServer::Create(const Scene& scene, SmaOptions options) {
  if (options.memoryBudgetBytes > 0 && !options.cacheDir.empty())
    return Fail("--memory-budget cannot be combined with --cache-dir yet: a snapshot replays splits by their ids, "
                "which the collector frees and reuses");
  if (!(options.memoryCollectStop < options.memoryCollectStart))
    return Fail(fmt::format("--memory-collect-stop ({}) must be below --memory-collect-start ({})",
                            options.memoryCollectStop, options.memoryCollectStart));
  auto tracer = VisibilityTracer::Build(scene);
  if (!tracer) return tracer.error();
  std::unique_ptr<CacheSnapshotter> snapshots;
  if (!options.cacheDir.empty()) {
    auto opened = CacheSnapshotter::Open(options.cacheDir, options.cacheSnapshotInterval);
    if (!opened) return opened.error();
    snapshots = std::move(*opened);
  }
  std::optional<RestoredCache> restored =
      snapshots ? snapshots->Restore(scene, RadianceBounds::ForScene(scene)) : std::optional<RestoredCache>();
  auto server = std::unique_ptr<SmaServer>(new SmaServer(std::make_unique<Impl>(
      scene, std::move(options), std::move(*tracer), std::move(snapshots), std::move(restored))));
  // Issue 15: loading the scene and building Embree's and the hierarchy's
  // structures peak above what stays; glibc keeps the freed heap pages
  // resident (and the SMA's memory budget is compared with what is left), so
  // hand them back once, here.
  malloc_trim(0);
  return server;
}

SmaServer::SmaServer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
SmaServer::~SmaServer() = default;
Expected<tcp::endpoint> SmaServer::Listen() { return impl_->Listen(); }
void SmaServer::Run() { impl_->Run(); }
void SmaServer::Shutdown() { impl_->Shutdown(); }
void SmaServer::WriteMetrics(metrics::ExpositionWriter& out) { impl_->WriteMetrics(out); }
std::string SmaServer::NotReadyReason() { return impl_->NotReadyReason(); }

}  // namespace penumbra::sma

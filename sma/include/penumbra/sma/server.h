#pragma once
// SmaServer: the shading management agent as a network service. It owns the
// subdivision hierarchy and the sample cache (shared by every client), the
// renderer pool, and one session per client; see sma/README.md for the data
// flow and who owns what.
//
// Threads:
//  * I/O threads run the io_context: every client and renderer connection
//    on its own strand (reading, decoding, writing frames), the renderer
//    links' handling of replies (storing samples), timers, signal handling.
//  * Session threads (sessionThreads, 2, an asio::thread_pool; 0: on the
//    I/O thread): each client
//    session's handlers on the session's own strand -- its views, the
//    planning of what to send (PlanView) and the encoding of its deltas, its
//    refinement driving. A connection hands a session at most 64 unhandled
//    messages before it stops reading (net::Connection::StartOn).
//  * View workers (viewThreads, a JobScheduler) trace visibility, map it
//    onto the hierarchy and run refinement steps for every client: new
//    views first, then re-maps, then refinement steps, clients taking turns
//    within each. A client's new view waits for the jobs already running
//    (any client's), never for another client's queued refinement.
//  * One background worker takes the jobs of views above largeViewPixels
//    and encodes every texture once, right after start (for every client),
//    so that neither delays ordinary views nor runs on an I/O thread.
//  * State lock (shared_mutex): the hierarchy and the cache. Visibility
//    mapping, delta planning and refinement choices hold it shared (a
//    mapping on a refined scene for tens of milliseconds); splitting holds
//    it exclusively. Samples are stored and improved without it (the
//    SampleCache synchronises itself), so the I/O thread that receives a
//    renderer's reply never waits for a mapping. Frames are encoded after
//    the lock is released. Lock order: state lock before the renderer
//    pool's lock; never the other way round.

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "penumbra/common/connection.h"
#include "penumbra/common/endpoint.h"
#include "penumbra/common/expected.h"
#include "penumbra/common/metrics.h"
#include "penumbra/common/rigid_transform.h"
#include "penumbra/common/scene.h"
#include "penumbra/sma/camera_prediction.h"
#include "penumbra/sma/client_limits.h"
#include "penumbra/sma/refinement.h"
#include "penumbra/sma/renderer_pool.h"

namespace penumbra::sma {

struct SmaOptions {
  HostPort listen{"127.0.0.1", 7200};
  std::string name = "penumbra-sma";
  RendererPoolOptions pool;            // renderers, scene hash (filled in), credits, timeouts
  RefinementParams refinement;         // each session starts with these; clients may change theirs
  net::ConnectionOptions clientConnection{.handshakeTimeout = std::chrono::milliseconds(10000),
                                          .maxFrameBytesBeforeHandshake = 64 * 1024};
  /// Required of every client's Hello (constant-time comparison, never
  /// logged); empty: none required. What the SMA presents to renderers is
  /// another secret: pool.authToken.
  std::string authToken;
  /// TLS for client connections (net::MakeTlsServerContext); null: plain
  /// TCP. The handshake must complete within clientConnection.handshakeTimeout.
  std::shared_ptr<net::ssl::context> tls;
  /// Threads running the client sessions' strands: what a view, a shaded
  /// sample or a refinement step changes for a client is planned and encoded
  /// there (PlanView, the deltas), never on an I/O thread. 32 clients:
  /// cached view -> first delta p99 776-851 -> 129-203 ms with 2
  /// (docs/performance.md; one thread: 809 ms, its planning the queue). 0:
  /// each session on its connection's strand, on an I/O thread, as before
  /// this option (kept for comparison). A session beside the I/O thread
  /// once stalled short of convergence (an improvement lap whose answers
  /// had all come back before it ended waited for one more; sma/README.md):
  /// fixed, and the suite runs with 2 under ThreadSanitizer.
  int sessionThreads = 2;
  /// Threads running the connections' strands and the pool's links: they
  /// read, decode and write frames, and store arriving samples. Two took
  /// the tail off many clients' latencies (docs/performance.md, "Two I/O
  /// threads": 32-client new-view p99 332 -> 197 ms, stats p99 73 -> 30 ms),
  /// and the strand starvation they had exposed is fixed (improvement
  /// notices coalesce, each look walks a bounded part of the view). One stays
  /// the default for now: the one CI run with two found a test that assumed
  /// one connection's close is handled before another's next request
  /// (fixed); the suite has not yet run clean with two often enough to
  /// trust it has no other such assumption.
  int ioThreads = 1;
  int viewThreads = 2;                 // visibility jobs in parallel (each also uses TBB inside)
  size_t clientSoftQueueBytes = size_t(4) << 20;  // beyond this, a client's deltas are coalesced
  uint32_t maxTrianglesPerDelta = 16384;          // larger changes go in several deltas
  /// Triangles a client keeps after they leave its view (delta.h,
  /// "Lingering"), so that turning back shows them at once; 0: removed as
  /// they leave (the paper). A move removes them (their light may change).
  /// 65536: a few MB a client (theirs and the mirror's), several views of
  /// the bathroom; docs/refinement.md, "Walkthrough", has what it bought.
  size_t clientLingerTriangles = 65536;
  uint64_t maxViewPixels = uint64_t(8192) * 4608;  // larger views are refused (visibility's time and memory)
  /// Client connections (counting those yet to say Hello) served at once;
  /// more are refused with TOO_MANY_CONNECTIONS and closed at once.
  size_t maxConnections = 256;
  std::chrono::milliseconds refreshInterval{100}; // min time between re-mapping a view after new samples
  std::chrono::milliseconds statsInterval{10000};
  DragoParams toneMapping;  // what clients are told to apply (SceneInfo), and the criteria's luminance
  /// Improvement (SampleCache::Improve): once a view is shaded, its visible
  /// samples whose irradiance has a relative standard error above
  /// `improveTargetError` get further rounds of `pool.improvePaths` paths,
  /// averaged in and re-sent to every client holding them, until they reach
  /// it or `improveMaxPaths`; the view converges only then. 0 paths: off.
  float improveTargetError = 0.02f;
  uint32_t improveMaxPaths = 1024;
  uint32_t improveBatch = 4096;  // improvements in flight per session
  /// Cache on disk (cache_snapshot.h): empty for none; else the cache is
  /// restored from this directory at start and snapshotted to it every
  /// interval (when it changed) and at shutdown.
  std::string cacheDir;
  std::chrono::milliseconds cacheSnapshotInterval{30000};
  /// Resource limits per client (issue 12). Visibility buffers of every
  /// client's view together (kVisibilityBytesPerPixel each): a view that
  /// does not fit is refused with LIMIT_EXCEEDED. Views above
  /// `largeViewPixels` are traced, mapped and refined on the background job
  /// thread (one at a time, with texture encoding), never holding up the
  /// view threads that answer ordinary views.
  uint64_t visibilityBudgetPixels = uint64_t(64) << 20;
  uint64_t largeViewPixels = uint64_t(4) << 20;
  ClientRefinementLimits clientRefinement;  // what SessionOptions may ask
  uint32_t maxTextureRequests = 1024;       // unanswered TextureRequests per client
  /// Moving objects (issue 14): the SMA plays the scene's animation paths on
  /// its own clock, one move per animated object every 1/animationHz
  /// seconds (coalesced with other moves like a client's). 0: not played.
  double animationHz = 10.0;
  /// Every cached sample is invalidated by every move (a full
  /// recomputation), not only what the invalidation test chooses: the
  /// baseline benchmarks compare with, and what tests that need every
  /// sample shaded at the final pose ask for.
  bool invalidateEverythingOnMove = false;
  /// Cached samples a move's indirect-light bound would invalidate are
  /// tested instead (docs/moving-objects.md "A test instead of a bound"):
  /// held back in the cache (SampleCache::Suspect) while a renderer
  /// measures their change with `pool.verifyPaths` paired samples, kept when
  /// |change| + moveTestZ sigma <= tau, shaded again otherwise.
  /// pool.verifyPaths 0: no test, the bound invalidates them.
  float moveTestZ = 3.0f;
  /// The direct class (where the exact shaft tests say an area light's or
  /// the sun's light may change) is tested too, before the indirect class,
  /// instead of re-shaded at once.
  bool moveTestDirect = false;
  /// Movement prediction for moving objects (issue 15; move_prediction.h):
  /// after each move, the next pose is predicted (the animated objects at
  /// their paths' next step, dragged ones extrapolated) and what it will
  /// invalidate and someone needs is shaded at it ahead of time (after
  /// views' and predicted samples, before refinement's); used if the move
  /// lands exactly there.
  bool movePrediction = true;
  /// A client's move within this (scene units) of its predicted place is
  /// applied there (SnapToPrediction); 0: never. At most
  /// kMoveConfirmTolerance, within which the client confirms its move.
  float moveSnap = kMoveConfirmTolerance;
  /// Camera movement prediction (issue 15; camera_prediction.h). Once a
  /// client's new view is applied (its visibility), the view its camera is expected to
  /// show `prediction.horizon` later (widened by `prediction.widen`) is
  /// traced at `predictionResolution` times the view's width and height, and
  /// what it would display unshaded is asked for at predicted priority
  /// (after every view's samples, before refinement's). Nothing is sent.
  bool predictionOn = true;
  CameraPredictionOptions prediction;
  double predictionResolution = 0.5;
  /// Memory budget (issue 15) for the SMA's data -- sample cache, hierarchy,
  /// clients' mirrors (memory_usage.h) -- in bytes; 0: unbounded. The
  /// age-based collector (collector.h) keeps the data in use within it:
  /// it starts above `memoryCollectStart` of the budget and collapses the
  /// refined subtrees used longest ago until the data is down to
  /// `memoryCollectStop`, never what a client holds, a renderer is shading,
  /// or anything used in the last `memoryMinAgeSeconds`. Cannot be combined
  /// with `cacheDir` (snapshots replay splits by id).
  uint64_t memoryBudgetBytes = 0;
  double memoryCollectStart = 0.9;
  double memoryCollectStop = 0.75;
  double memoryMinAgeSeconds = 2.0;
};

class SmaServer {
 public:
  /// `scene` must outlive the server. Builds the hierarchy and visibility
  /// structure; fails (with a message) only if Embree cannot build.
  static Expected<std::unique_ptr<SmaServer>> Create(const Scene& scene, SmaOptions options);
  ~SmaServer();
  SmaServer(const SmaServer&) = delete;
  SmaServer& operator=(const SmaServer&) = delete;

  /// Binds the client listener; returns the bound address.
  Expected<tcp::endpoint> Listen();
  /// Serves until SIGINT/SIGTERM or Shutdown(); returns after closing.
  void Run();
  /// Stops within about a second: queued visibility and refinement jobs are
  /// dropped and running ones stop early, every client is sent a fatal
  /// SHUTTING_DOWN and closed. Thread-safe.
  void Shutdown();

  /// Writes the SMA's metric families (docs/metrics.md): StatsReply's server
  /// counters and the view latency histograms. Thread-safe; takes the state
  /// lock shared, briefly, so it is called off the I/O threads (by the --http
  /// endpoint's own thread).
  void WriteMetrics(metrics::ExpositionWriter& out);
  /// Empty when ready (not shutting down, at least one renderer connected),
  /// else the reason. Thread-safe.
  std::string NotReadyReason();

  class Impl;

 private:
  explicit SmaServer(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace penumbra::sma

#include "penumbra/sma/server.h"

#include <array>
#include <map>
#include <csignal>
#include <mutex>
#include <shared_mutex>
#include <unordered_map>
#include <unordered_set>

#include <fmt/format.h>

#include "job_queue.h"
#include "penumbra/common/auth.h"
#include "penumbra/common/logging.h"
#include "penumbra/common/messages.h"
#include "penumbra/sma/cache_snapshot.h"
#include "penumbra/sma/client_requests.h"
#include "penumbra/sma/delta.h"
#include "penumbra/sma/hierarchy.h"
#include "penumbra/sma/refinement.h"
#include "penumbra/sma/sample_cache.h"
#include "penumbra/sma/texture_frames.h"
#include "penumbra/sma/visibility.h"
#include "sma_metrics.h"

namespace penumbra::sma {

namespace {

using Clock = std::chrono::steady_clock;
using boost::system::error_code;

double Ms(Clock::duration d) { return std::chrono::duration<double, std::milli>(d).count(); }

void AddCounter(wire::StatsReply* reply, const std::string& name, double value) {
  auto* c = reply->add_counters();
  c->set_name(name);
  c->set_value(value);
}

void ToWire(const Vec3& v, wire::Vec3* out) {
  out->set_x(v.x);
  out->set_y(v.y);
  out->set_z(v.z);
}

// Descend into a node's children once every vertex its split added is
// shaded: a parent is replaced by its children only when they can be drawn.
bool ChildrenShaded(const Node& node, const void* context) {
  const auto& cache = *static_cast<const SampleCache*>(context);
  for (VertexId m : node.mid)
    if (m != kNoVertex && !cache.IsShaded(m)) return false;
  return true;
}

}  // namespace

class SmaServer::Impl {
 public:
  class Session;

  Impl(const Scene& scene, SmaOptions options, std::unique_ptr<VisibilityTracer> tracer,
       std::unique_ptr<CacheSnapshotter> snapshots, std::optional<RestoredCache> restored)
      : scene_(scene),
        options_(std::move(options)),
        hierarchy_(restored ? std::move(restored->hierarchy) : Hierarchy(scene)),
        tracer_(std::move(tracer)),
        jobs_(options_.viewThreads),
        visibilityBudget_(options_.visibilityBudgetPixels),
        textures_(scene, options_.clientConnection.maxFrameBytes / 2,
                  [this](std::function<void()> job) { backgroundJobs_.Post(std::move(job)); }),
        backgroundJobs_(1),
        log_(Logger("sma")),
        signals_(io_, SIGINT, SIGTERM),
        statsTimer_(io_),
        shutdownTimer_(io_),
        snapshots_(std::move(snapshots)) {
    cache_.Reserve(hierarchy_.VertexCount());
    if (restored) cache_.Restore(restored->samples);
    options_.pool.sceneHash = scene.identity;
    options_.pool.name = options_.name;
    options_.pool.radianceBounds = RadianceBounds::ForScene(scene);
    pool_ = RendererPool::Create(
        io_, options_.pool, [this](std::vector<ShadedSample>&& samples) { OnResults(std::move(samples)); },
        [this](VertexId v) { return cache_.IsShaded(v); });
    if (restored) {
      std::vector<SampleRequest> requests;
      for (VertexId v : UnshadedMidpoints(hierarchy_, cache_)) requests.push_back(MakeSampleRequest(hierarchy_, v));
      pool_->Request(requests, Priority::kBackground);
      log_->info("cache: {} restored midpoints were still unshaded: asked for", requests.size());
    }
  }

  Expected<tcp::endpoint> Listen() {
    // Descriptors for every client allowed, and room for renderer links and files.
    const size_t fit = net::FitConnectionsToDescriptorLimit(options_.maxConnections, 256);
    if (fit < options_.maxConnections) {
      log_->warn("the descriptor limit (ulimit -n) allows only {} client connections; --max-connections {} lowered "
                 "to that", fit, options_.maxConnections);
      options_.maxConnections = fit;
    }
    listener_ = net::Listener::Create(io_, [this](net::Stream stream) { Accept(std::move(stream)); });
    if (options_.tls) listener_->SetTls(options_.tls, options_.clientConnection.handshakeTimeout);
    auto bound = listener_->Listen(options_.listen);
    if (bound)
      log_->info("{}: listening for clients on {}:{} ({}{})", options_.name, bound->address().to_string(),
                 bound->port(), options_.tls ? "TLS" : "plain TCP", options_.authToken.empty() ? "" : ", token required");
    return bound;
  }

  void Run() {
    signals_.async_wait([this](const error_code& ec, int signal) {
      if (ec) return;
      log_->info("signal {} received: shutting down", signal);
      Shutdown();
    });
    pool_->Start();
    if (listener_) listener_->Start();
    ArmStats();
    if (snapshots_) snapshots_->Start(stateMutex_, hierarchy_, cache_);
    ArmRendererWatch();
    std::vector<std::thread> extra;
    for (int i = 1; i < options_.ioThreads; ++i) extra.emplace_back([this] { io_.run(); });
    io_.run();
    for (auto& t : extra) t.join();
    if (snapshots_) snapshots_->Stop();  // the final snapshot
    log_->info("{}: stopped", options_.name);
  }

  void Shutdown();

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
    std::vector<VertexId> changed;
    if (!samples.empty()) cache_.Store(samples);
    if (!improvements.empty()) changed = cache_.Improve(improvements);
    pool_->Complete(samples);
    pool_->Complete(improvements);
    samplesImproved_ += changed.size();
    if (!samples.empty()) {
      auto vertices = std::make_shared<std::vector<VertexId>>();
      vertices->reserve(samples.size());
      for (const ShadedSample& s : samples) vertices->push_back(s.vertex);
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

  std::vector<std::shared_ptr<Session>> Sessions() {
    std::lock_guard lock(sessionsMutex_);
    std::vector<std::shared_ptr<Session>> out;
    out.reserve(sessions_.size());
    for (auto& [id, s] : sessions_) out.push_back(s);
    return out;
  }
  void RemoveSession(uint64_t id) {
    std::lock_guard lock(sessionsMutex_);
    sessions_.erase(id);
  }
  void NotifyArrived(const std::shared_ptr<Session>& session, std::shared_ptr<const std::vector<VertexId>> vertices);
  // `answered`: improvements that came back (some may have changed nothing);
  // `improved`: the vertices whose cached estimate changed.
  void NotifyImproved(const std::shared_ptr<Session>& session, std::shared_ptr<const std::vector<VertexId>> answered,
                      std::shared_ptr<const std::vector<VertexId>> improved);
  std::atomic<uint64_t> samplesImproved_{0};

  void AddGlobalCounters(wire::StatsReply* reply);
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
    return DragoParams{options_.toneMapping.bias, options_.toneMapping.maxDisplayLuminance, options_.toneMapping.exposure};
  }

  const Scene& scene_;
  SmaOptions options_;
  asio::io_context io_;
  std::shared_mutex stateMutex_;  // guards hierarchy_ and cache_
  Hierarchy hierarchy_;
  SampleCache cache_;
  std::unique_ptr<VisibilityTracer> tracer_;
  std::shared_ptr<RendererPool> pool_;
  JobQueue jobs_;
  // Resource limits per client (issue 12). Views above largeViewPixels and
  // texture encoding run on backgroundJobs_, one job at a time, so they
  // never hold up ordinary views; textures_ posts its encodings there and
  // is declared first, so that the thread is joined before it goes.
  VisibilityBudget visibilityBudget_;
  std::atomic<uint64_t> viewTraces_{0};  // visibility traces made, for every client
  TextureFrames textures_;
  JobQueue backgroundJobs_;
  std::shared_ptr<spdlog::logger> log_;

 private:
  void Accept(net::Stream stream);
  void ArmStats();
  void PollShutdown();

  std::shared_ptr<net::Listener> listener_;
  asio::signal_set signals_;
  asio::steady_timer statsTimer_;
  asio::steady_timer shutdownTimer_;
  // Clients are told when the number of connected renderers differs from
  // what their last delta said (a view waiting on no renderer says so):
  // polled, as the pool has no callback, and compared per session, as a
  // renderer may come and go between two polls.
  void ArmRendererWatch();
  asio::steady_timer rendererWatchTimer_{io_};
  std::atomic<bool> shuttingDown_{false};  // also tells running jobs to give up
  Clock::time_point shutdownDeadline_;
  net::LogThrottle refusals_{std::chrono::seconds(10)};
  RendererPoolStats lastStats_;
  std::mutex viewTimesMutex_;
  std::vector<std::array<double, 3>> viewTimes_;  // trace, map, view -> first delta (ms)
  std::mutex sessionsMutex_;
  std::unordered_map<uint64_t, std::shared_ptr<Session>> sessions_;
  uint64_t nextSessionId_ = 1;
  // Last member: stopped (its thread joined) before the state it reads goes.
  std::unique_ptr<CacheSnapshotter> snapshots_;
};

// One client connection. Everything here runs on the connection's strand.
class SmaServer::Impl::Session : public std::enable_shared_from_this<Session> {
 public:
  Session(Impl& server, std::shared_ptr<net::Connection> connection, uint64_t id)
      : server_(server),
        connection_(std::move(connection)),
        id_(id),
        log_(Logger("sma.client")),
        refreshTimer_(connection_->Strand()),
        unblockTimer_(connection_->Strand()),
        params_(server.options_.refinement),
        refiner_(std::make_shared<Refiner>(params_)) {}

  void Start() {
    auto self = shared_from_this();
    connection_->Start([self](wire::Envelope&& e) { self->OnMessage(std::move(e)); },
                       [self](const std::string& reason) { self->OnClosed(reason); });
  }

  net::Connection& Connection() { return *connection_; }

  // Strand: samples were stored in the cache.
  void OnSamplesArrived(const std::vector<VertexId>& vertices);
  // Strand: improvements came back; `improved` changed the cache.
  void OnSamplesImproved(const std::vector<VertexId>& answered, const std::vector<VertexId>& improved);

 private:
  struct JobTimings {
    double traceMs = 0.0;
    double mapMs = 0.0;
  };

  void OnMessage(wire::Envelope&& envelope);
  void OnHello(const wire::Hello& hello);
  void OnView(const wire::View& view);
  void OnStatsRequest(const wire::StatsRequest& request);
  void OnTextureRequest(const wire::TextureRequest& request);
  void OnSessionOptions(const wire::SessionOptions& options);
  void OnClosed(const std::string& reason);
  void Fatal(wire::ErrorCode code, const std::string& message) {
    log_->warn("{}: {} (closing)", connection_->Id(), message);
    connection_->FailAndClose(MakeError(0, code, message, true), message);
  }

  void StartJob();
  // Views above --large-view-pixels work on the background thread.
  JobQueue& JobsFor(const CameraView& view) {
    return uint64_t(view.width) * uint64_t(view.height) > server_.options_.largeViewPixels ? server_.backgroundJobs_
                                                                                         : server_.jobs_;
  }
  /// This client's reservation in the visibility budget: the largest of its
  /// latest view, the trace running for it and the buffers it holds. Never
  /// more than OnView reserved, so it only shrinks.
  void UpdateReservation() {
    const auto pixels = [](const CameraView& v) { return uint64_t(v.width) * uint64_t(v.height); };
    server_.visibilityBudget_.Resize(reservedPixels_,
                                     std::max({pixels(view_), runningJobPixels_, hits_ ? pixels(hits_->view) : 0}));
  }
  void OnTextureReady(uint32_t texture, TextureFrames::Frame frame);
  void SendTextures();
  void OnJobDone(uint64_t viewId, bool newView, std::shared_ptr<HitBuffer> hits, std::shared_ptr<VisibleSet> visible,
                 JobTimings timings, Clock::time_point started);
  void ApplyVisibility(bool newView);
  void ScheduleRefresh();
  bool Blocked() const { return connection_->QueuedBytes() > server_.options_.clientSoftQueueBytes; }
  void WaitUntilUnblocked();
  /// Sends removals and additions in as many deltas as the size limit asks.
  /// `last`: no other delta for this event follows, so the final one may
  /// report convergence; `alwaysSend`: send even when nothing changed.
  void SendChanges(wire::DeltaKind kind, std::span<const NodeId> removals, std::span<const NodeId> additions,
                   bool alwaysSend, bool last);
  // Stage 2: the view is shaded, and refinement or improvement goes on.
  bool RefiningNow() const {
    return Stage1Done() && !Converged() && (params_.criterion != Criterion::kNone || ImprovementOn());
  }
  void FillStatus(wire::Delta& delta, bool last) {
    delta.set_view_id(appliedViewId_);
    delta.set_pending_samples(uint32_t(waiting_.size() + refinementPending_.size()));
    const bool converged = last && Converged();
    delta.set_converged(converged);
    delta.set_refining(!converged && RefiningNow());
    // Progress for the people waiting (issue 16).
    sentRenderers_ = server_.pool_->ReadyRenderers();
    delta.set_renderers_connected(uint32_t(sentRenderers_));
    delta.set_stage1_samples_total(uint32_t(stage1Total_));
    delta.set_stage1_samples_done(uint32_t(std::min(stage1Done_, stage1Total_)));
    delta.set_refinement_samples_total(uint32_t(refineTotal_));
    delta.set_refinement_samples_done(uint32_t(std::min(refineDone_, refineTotal_)));
    sentConverged_ = converged;
    sentRefining_ = delta.refining();
    if (converged && stage2Ms_ < 0.0) {
      stage2Ms_ = Ms(Clock::now() - viewReceived_);
      server_.latencies_.toConverged.Observe(stage2Ms_ / 1000.0);
    }
  }
  // Stage 1 (paper §5): every initially visible triangle of the view shaded.
  bool Stage1Done() const {
    return hasVisible_ && appliedViewId_ == viewId_ && !jobRunning_ && waiting_.empty() && pending_.empty();
  }
  bool RefinementDone() const {
    return params_.criterion == Criterion::kNone ||
           (refinementDone_ && refinementPending_.empty() && !refineRunning_ && !refreshWanted_);
  }
  bool ImprovementDone() const { return !ImprovementOn() || (improvementDone_ && improvePending_.empty()); }
  bool ImprovementOn() const { return server_.options_.pool.improvePaths > 0; }
  bool Converged() const { return Stage1Done() && RefinementDone() && ImprovementDone(); }
  void NoteStage1();
  // Improvement of the view's samples (SmaOptions::improveTargetError).
  void MaybeImprove();
  void SendUpdates();
  void MaybeRefine();
  void OnRefineStepDone(const std::shared_ptr<Refiner>& refiner, size_t chosen, std::vector<VertexId> newVertices,
                        bool exhausted);
  void SendStatus();
  /// Sends a STATUS delta if the client's last word on this view (converged,
  /// refining) is out of date -- e.g. after a coalesced refresh that changed
  /// no triangle, or when stage 1 ends without a delta of its own.
  void SyncStatus() {
    if (hasVisible_ && (Converged() != sentConverged_ || RefiningNow() != sentRefining_)) SendStatus();
  }

 public:
  /// Strand: `renderers` are connected now; tell the client if it was told otherwise.
  void OnRendererCount(size_t renderers) {
    if (hasVisible_ && renderers != sentRenderers_) SendStatus();
  }

 private:
  void RestartRefinement();

  Impl& server_;
  std::shared_ptr<net::Connection> connection_;
  uint64_t id_;
  std::shared_ptr<spdlog::logger> log_;
  asio::steady_timer refreshTimer_;
  asio::steady_timer unblockTimer_;

  bool handshook_ = false;
  bool hasView_ = false;
  bool hasVisible_ = false;
  uint64_t viewId_ = 0;          // newest view received
  uint64_t appliedViewId_ = 0;   // view whose visibility is applied
  CameraView view_;
  bool jobRunning_ = false;
  bool refreshWanted_ = false;
  bool refreshArmed_ = false;
  bool unblockArmed_ = false;
  Clock::time_point lastRefresh_;
  Clock::time_point viewReceived_;
  std::shared_ptr<HitBuffer> hits_;        // base hits of the applied view
  std::shared_ptr<VisibleSet> visible_;    // latest mapping of hits_

  ClientMirror mirror_;
  std::unordered_set<NodeId> pending_;                           // visible, waiting for samples
  std::unordered_map<VertexId, std::vector<NodeId>> waiting_;    // missing vertex -> pending nodes
  std::vector<VertexId> interest_;                               // vertices we asked the pool for
  uint64_t sequence_ = 0;
  uint64_t deltasSent_ = 0;
  uint64_t trianglesSent_ = 0;
  uint64_t viewsReceived_ = 0;
  JobTimings lastTimings_;
  double lastFirstDeltaMs_ = 0.0;

  // Refinement of the current view (paper §4): one Refiner per view; its
  // steps run on job threads one at a time.
  RefinementParams params_;
  std::shared_ptr<Refiner> refiner_;
  bool refineRunning_ = false;
  bool refinementDone_ = false;
  // Improvement of the view's samples: asked for and not yet answered; done
  // when nothing visible needs more; updates owed to the client (held
  // vertices whose estimate improved), sent when its queue allows.
  std::unordered_set<VertexId> improvePending_;
  bool improvementDone_ = false;
  std::unordered_set<VertexId> updatesOwed_;
  uint64_t updatesSent_ = 0;
  uint64_t improvementsAsked_ = 0;
  std::unordered_set<VertexId> refinementPending_;  // split vertices not yet shaded
  uint64_t refinementSplits_ = 0;
  uint64_t refinementSamples_ = 0;
  double stage1Ms_ = -1.0;  // view received -> stage 1 done
  double stage2Ms_ = -1.0;  // view received -> converged
  bool sentConverged_ = false;  // as the last delta sent said
  bool sentRefining_ = false;

  // Resource limits (issue 12). Visibility: this client's reservation in
  // the server's budget -- the largest of its latest view, the trace running
  // for it and the buffers it holds (one view's buffers at a time: a new
  // view drops the old one's). Views traced in a row whose results were
  // dropped as superseded (see OnJobDone).
  uint64_t reservedPixels_ = 0;
  uint64_t runningJobPixels_ = 0;
  static constexpr int kMaxNewViewsDroppedInARow = 3;
  int newViewsDroppedInARow_ = 0;
  // Textures asked for and not yet queued: null while being encoded.
  std::map<uint32_t, TextureFrames::Frame> texturesOutstanding_;
  uint64_t textureRequestsRefused_ = 0;
  size_t sentRenderers_ = 0;
  // Progress of the applied view (Delta fields 20-23).
  size_t stage1Total_ = 0;
  size_t stage1Done_ = 0;
  size_t refineTotal_ = 0;
  size_t refineDone_ = 0;
};

void SmaServer::Impl::NotifyArrived(const std::shared_ptr<Session>& session,
                                    std::shared_ptr<const std::vector<VertexId>> vertices) {
  asio::post(session->Connection().Strand(),
             [session, vertices = std::move(vertices)] { session->OnSamplesArrived(*vertices); });
}

void SmaServer::Impl::NotifyImproved(const std::shared_ptr<Session>& session,
                                     std::shared_ptr<const std::vector<VertexId>> answered,
                                     std::shared_ptr<const std::vector<VertexId>> improved) {
  asio::post(session->Connection().Strand(),
             [session, answered = std::move(answered), improved = std::move(improved)] {
               session->OnSamplesImproved(*answered, *improved);
             });
}

void SmaServer::Impl::Session::OnMessage(wire::Envelope&& envelope) {
  if (envelope.has_hello()) return OnHello(envelope.hello());
  if (!handshook_) {
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
  if (handshook_) return Fatal(wire::ERROR_CODE_UNEXPECTED_MESSAGE, "second hello on one connection");
  wire::ErrorCode code = wire::ERROR_CODE_UNSPECIFIED;
  const Scene& scene = server_.scene_;
  // The token first: a peer without it learns nothing else.
  if (auto ok = CheckHelloToken(hello, server_.options_.authToken, &code); !ok) return Fatal(code, ok.error().message);
  if (auto ok = ValidateHello(hello, wire::ROLE_CLIENT, scene.identity, &code); !ok) return Fatal(code, ok.error().message);
  handshook_ = true;
  wire::Envelope welcome;
  auto* w = welcome.mutable_welcome();
  w->set_protocol_version(kProtocolVersion);
  w->set_role(wire::ROLE_SMA);
  w->set_server_name(server_.options_.name);
  w->set_scene_hash(scene.identity);
  w->set_max_frame_bytes(server_.options_.clientConnection.maxFrameBytes);
  connection_->Send(welcome);

  wire::Envelope infoEnvelope;
  auto* info = infoEnvelope.mutable_scene_info();
  info->set_name(scene.name);
  ToWire(scene.bounds.min, info->mutable_bounds_min());
  ToWire(scene.bounds.max, info->mutable_bounds_max());
  for (const CameraPreset& c : scene.cameras) {
    auto* p = info->add_cameras();
    p->set_name(c.name);
    ToWire(c.pose.eye, p->mutable_eye());
    ToWire(c.pose.target, p->mutable_target());
    ToWire(c.pose.up, p->mutable_up());
    p->set_fov_y_deg(c.fovYDeg);
  }
  for (const Material& m : scene.materials) {
    auto* mi = info->add_materials();
    ToWire(m.albedo, mi->mutable_albedo());
    ToWire(m.emission, mi->mutable_emission());
    mi->set_texture(m.albedoTexture);
  }
  const auto& tm = server_.options_.toneMapping;
  info->mutable_tone_mapping()->set_bias(tm.bias);
  info->mutable_tone_mapping()->set_exposure(tm.exposure);
  info->mutable_tone_mapping()->set_max_display_luminance(tm.maxDisplayLuminance);
  info->set_texture_count(uint32_t(scene.textures.size()));
  if (scene.sky) {
    auto* sky = info->mutable_sky();
    ToWire(scene.sky->up, sky->mutable_up());
    ToWire(scene.sky->zenith, sky->mutable_zenith());
    ToWire(scene.sky->horizon, sky->mutable_horizon());
    ToWire(scene.sky->ground, sky->mutable_ground());
  }
  connection_->Send(infoEnvelope);
  connection_->MarkHandshakeDone();
  log_->info("{}: client '{}' joined", connection_->Id(), Printable(hello.peer_name()));
}

void SmaServer::Impl::Session::OnView(const wire::View& v) {
  ++viewsReceived_;
  auto checked = ViewFromWire(v, server_.options_.maxViewPixels);
  if (!checked) return Fatal(wire::ERROR_CODE_INVALID_REQUEST, checked.error().message);
  const CameraView view = *checked;
  if (hasView_ && v.view_id() <= viewId_) {
    connection_->Send(MakeError(v.view_id(), wire::ERROR_CODE_INVALID_REQUEST,
                                fmt::format("view id {} does not increase (last {}); ignored", v.view_id(), viewId_),
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
  hasView_ = true;
  viewId_ = v.view_id();
  view_ = view;
  viewReceived_ = Clock::now();
  stage1Ms_ = stage2Ms_ = -1.0;
  RestartRefinement();
  // A new view supersedes whatever this client was waiting for: a running
  // job's result is dropped when it lands, and StartJob picks this view.
  StartJob();
}

void SmaServer::Impl::Session::StartJob() {
  if (jobRunning_ || !hasView_ || connection_->IsOpen() == false) return;
  const bool newView = !hits_ || appliedViewId_ != viewId_;
  if (!newView && !refreshWanted_) return;
  // No work for a client that cannot take its results (four clients that
  // never read once cost 1.8 cores): its latest view is traced, or the
  // refresh made, once its queue drains.
  if (Blocked()) {
    WaitUntilUnblocked();
    return;
  }
  jobRunning_ = true;
  runningJobPixels_ = uint64_t(view_.width) * uint64_t(view_.height);
  if (newView) {  // one view's buffers at a time
    hits_.reset();
    visible_.reset();
  }
  UpdateReservation();
  refreshWanted_ = false;
  lastRefresh_ = Clock::now();
  auto self = shared_from_this();
  const CameraView view = view_;
  const uint64_t id = viewId_;
  std::shared_ptr<HitBuffer> hits = newView ? nullptr : hits_;
  const auto started = Clock::now();
  JobsFor(view).Post([self, view, id, hits, newView, started]() mutable {
    Impl& server = self->server_;
    JobTimings t;
    auto t0 = Clock::now();
    if (!hits) {
      hits = std::make_shared<HitBuffer>();
      server.tracer_->Trace(view, *hits, &server.shuttingDown_);
      ++server.viewTraces_;
    }
    auto t1 = Clock::now();
    auto visible = std::make_shared<VisibleSet>();
    if (server.shuttingDown_) return;  // the result would be dropped anyway
    {
      std::shared_lock lock(server.stateMutex_);
      MapHitsToNodes(server.hierarchy_, *hits, &ChildrenShaded, &server.cache_, *visible, &server.shuttingDown_);
    }
    if (server.shuttingDown_) return;
    auto t2 = Clock::now();
    t.traceMs = newView ? Ms(t1 - t0) : 0.0;
    t.mapMs = Ms(t2 - t1);
    asio::post(self->connection_->Strand(), [self, id, newView, hits, visible, t, started] {
      self->OnJobDone(id, newView, hits, visible, t, started);
    });
  });
}

void SmaServer::Impl::Session::OnJobDone(uint64_t viewId, bool newView, std::shared_ptr<HitBuffer> hits,
                                         std::shared_ptr<VisibleSet> visible, JobTimings timings,
                                         Clock::time_point started) {
  jobRunning_ = false;
  if (!connection_->IsOpen()) return;
  runningJobPixels_ = 0;
  // Superseded while it ran: the result is dropped and the latest view
  // traced -- unless the last few new views were dropped too. A client
  // sending views faster than they are traced would otherwise never receive
  // one, and one that never reads would cost a trace per view without its
  // queue ever backing up (issue 12). Then this slightly older view is
  // applied, and the latest one traced next.
  const bool stale = viewId != viewId_;
  if (stale && (!newView || ++newViewsDroppedInARow_ < kMaxNewViewsDroppedInARow)) {
    UpdateReservation();
    StartJob();
    return;
  }
  if (newView) newViewsDroppedInARow_ = 0;
  const bool firstForView = (appliedViewId_ != viewId || !hasVisible_) && !stale;
  hits_ = std::move(hits);
  visible_ = std::move(visible);
  appliedViewId_ = viewId;
  hasVisible_ = true;
  // The counters report the last new view's visibility; refreshes of the
  // same view (no trace, a re-map) would overwrite its trace time with 0.
  if (newView) lastTimings_ = timings;
  const auto planStart = Clock::now();
  ApplyVisibility(newView);
  if (firstForView) {
    lastFirstDeltaMs_ = Ms(Clock::now() - viewReceived_);
    server_.RecordView(timings.traceMs, timings.mapMs, lastFirstDeltaMs_);
    log_->debug("{}: view {}: trace {:.1f} ms, map {:.1f} ms, plan+send {:.1f} ms, view->first delta {:.1f} ms; "
                "{} visible, {} held, {} pending ({} samples)",
                connection_->Id(), viewId, timings.traceMs, timings.mapMs, Ms(Clock::now() - planStart),
                lastFirstDeltaMs_, visible_->nodes.size(), mirror_.TriangleCount(), pending_.size(), waiting_.size());
  }
  (void)started;
  UpdateReservation();
  if (stale) {
    StartJob();
    return;
  }
  if (refreshWanted_) ScheduleRefresh();
  NoteStage1();
  MaybeRefine();
  MaybeImprove();
  SyncStatus();
}

void SmaServer::Impl::Session::ApplyVisibility(bool newView) {
  Impl& server = server_;
  improvementDone_ = false;  // what is displayed changed: look again
  std::shared_lock lock(server.stateMutex_);
  ViewPlan plan = PlanView(*visible_, mirror_, server.hierarchy_, server.cache_);

  // Ask for what is missing before letting go of the old interest, so a
  // vertex both views need is never demoted in between. Requests are made
  // under the state lock: see RendererPool's note on "requested once".
  std::vector<SampleRequest> requests;
  requests.reserve(plan.missing.size());
  for (VertexId v : plan.missing) requests.push_back(MakeSampleRequest(server.hierarchy_, v));
  server.pool_->Request(requests, Priority::kVisible);
  server.pool_->ReleaseInterest(interest_);
  interest_ = plan.missing;

  pending_.clear();
  waiting_.clear();
  for (NodeId id : plan.pending) {
    bool waits = false;
    for (VertexId v : server.hierarchy_.GetNode(id).v) {
      if (server.cache_.IsShaded(v)) continue;
      waiting_[v].push_back(id);
      waits = true;
    }
    // Samples are stored without the state lock: its corners may have
    // arrived since PlanView, their notice already queued behind us and
    // looking for waiters it will not find. Sent now instead.
    if (waits) pending_.insert(id);
    else plan.addCached.push_back(id);
  }
  if (newView) stage1Done_ = 0;
  stage1Total_ = stage1Done_ + waiting_.size();

  if (Blocked()) {
    // The client is behind: send nothing now; once its queue drains, one
    // refresh sends the difference that has built up (coalescing).
    WaitUntilUnblocked();
    return;
  }
  if (newView) {
    // The paper's order: what the cache already has, then what is gone;
    // what must be rendered follows as it arrives.
    const bool removalsFollow = !plan.removeGone.empty();
    SendChanges(wire::DELTA_KIND_CACHED, plan.removeReplaced, plan.addCached, /*alwaysSend=*/true, !removalsFollow);
    SendChanges(wire::DELTA_KIND_REMOVED, plan.removeGone, {}, /*alwaysSend=*/false, /*last=*/true);
  } else {
    std::vector<NodeId> removals = plan.removeReplaced;
    removals.insert(removals.end(), plan.removeGone.begin(), plan.removeGone.end());
    SendChanges(wire::DELTA_KIND_REFINED, removals, plan.addCached, /*alwaysSend=*/false, /*last=*/true);
  }
  lock.unlock();
  SendUpdates();
}

void SmaServer::Impl::Session::SendChanges(wire::DeltaKind kind, std::span<const NodeId> removals,
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
    if (!connection_->Send(envelope)) {
      // Over the hard queue limit: this client is not reading at all.
      connection_->Close("client send queue overflow");
      return;
    }
    ++deltasSent_;
  }
}

void SmaServer::Impl::Session::OnSamplesArrived(const std::vector<VertexId>& vertices) {
  if (!hasVisible_ || !connection_->IsOpen()) return;
  std::unordered_set<NodeId> candidates;
  bool refinement = false;
  const size_t baseVertices = server_.hierarchy_.BaseVertexCount();
  for (VertexId v : vertices) {
    refineDone_ += refinementPending_.erase(v);
    auto it = waiting_.find(v);
    if (it == waiting_.end()) {
      // A midpoint this client was not waiting for may complete the children
      // of a node it shows: re-map (throttled) to pick them up.
      refinement |= v >= baseVertices;
      continue;
    }
    candidates.insert(it->second.begin(), it->second.end());
    waiting_.erase(it);
    ++stage1Done_;
  }
  if (refinement) {
    refreshWanted_ = true;
    ScheduleRefresh();
  }
  if (candidates.empty()) return;
  std::shared_lock lock(server_.stateMutex_);
  std::vector<NodeId> ready;
  for (NodeId id : candidates)
    if (pending_.contains(id) && CornersShaded(server_.hierarchy_.GetNode(id), server_.cache_)) ready.push_back(id);
  std::sort(ready.begin(), ready.end());
  for (NodeId id : ready) pending_.erase(id);
  if (Blocked()) {
    WaitUntilUnblocked();
    return;
  }
  SendChanges(wire::DELTA_KIND_SHADED, {}, ready, /*alwaysSend=*/Converged(), /*last=*/true);
  lock.unlock();
  NoteStage1();
  MaybeRefine();
  MaybeImprove();
}

void SmaServer::Impl::Session::MaybeImprove() {
  if (!ImprovementOn() || improvementDone_ || !Stage1Done() || !connection_->IsOpen()) return;
  if (Blocked()) {  // no work for a client that cannot take it; resumed by the refresh on drain
    WaitUntilUnblocked();
    return;
  }
  const SmaOptions& o = server_.options_;
  // Keep about a batch in flight: look for more once half of it is back.
  if (improvePending_.size() > o.improveBatch / 2) return;
  std::vector<SampleRequest> requests;
  {
    std::shared_lock lock(server_.stateMutex_);
    const Hierarchy& hierarchy = server_.hierarchy_;
    const SampleCache& cache = server_.cache_;
    std::unordered_set<VertexId> seen;
    for (NodeId id : visible_->nodes) {
      if (requests.size() + improvePending_.size() >= o.improveBatch) break;
      if (!mirror_.Holds(id)) continue;  // only what the client shows
      for (VertexId v : hierarchy.GetNode(id).v) {
        if (!seen.insert(v).second || improvePending_.contains(v) || !cache.IsShaded(v)) continue;
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
  for (const SampleRequest& r : requests) improvePending_.insert(r.vertex);
  improvementsAsked_ += requests.size();
  if (requests.empty() && improvePending_.empty()) {
    improvementDone_ = true;
    SyncStatus();
  }
}

void SmaServer::Impl::Session::OnSamplesImproved(const std::vector<VertexId>& answered,
                                                 const std::vector<VertexId>& improved) {
  for (VertexId v : answered) improvePending_.erase(v);
  if (!hasVisible_ || !connection_->IsOpen()) return;
  for (VertexId v : improved)
    if (mirror_.HoldsVertex(v)) updatesOwed_.insert(v);
  SendUpdates();
  MaybeImprove();
}

void SmaServer::Impl::Session::SendUpdates() {
  if (updatesOwed_.empty()) return;
  if (Blocked()) {
    WaitUntilUnblocked();  // its refresh sends them
    return;
  }
  std::vector<VertexId> owed(updatesOwed_.begin(), updatesOwed_.end());
  updatesOwed_.clear();
  std::sort(owed.begin(), owed.end());
  std::shared_lock lock(server_.stateMutex_);
  const size_t chunk = std::max<size_t>(1, server_.options_.maxTrianglesPerDelta);
  for (size_t offset = 0; offset < owed.size(); offset += chunk) {
    wire::Envelope envelope;
    wire::Delta& delta = *envelope.mutable_delta();
    delta.set_kind(wire::DELTA_KIND_IMPROVED);
    const size_t n = mirror_.AppendUpdates(std::span(owed).subspan(offset, std::min(chunk, owed.size() - offset)),
                                           server_.cache_, delta);
    if (n == 0) continue;
    delta.set_sequence(++sequence_);
    FillStatus(delta, /*last=*/offset + chunk >= owed.size());
    if (!connection_->Send(envelope)) {
      connection_->Close("client send queue overflow");
      return;
    }
    ++deltasSent_;
    updatesSent_ += n;
  }
}

void SmaServer::Impl::Session::NoteStage1() {
  if (stage1Ms_ < 0.0 && Stage1Done()) {
    stage1Ms_ = Ms(Clock::now() - viewReceived_);
    server_.latencies_.toShaded.Observe(stage1Ms_ / 1000.0);
    log_->debug("{}: view {}: stage 1 in {:.0f} ms, {} triangles", connection_->Id(), appliedViewId_, stage1Ms_,
                mirror_.TriangleCount());
    // Tell the client at once that stage 2 (refinement) has begun.
    SyncStatus();
  }
}

void SmaServer::Impl::Session::RestartRefinement() {
  // A running step keeps the old Refiner; its result is recognised as stale.
  refiner_ = std::make_shared<Refiner>(params_);
  refinementDone_ = false;
  refinementPending_.clear();
  refineTotal_ = refineDone_ = 0;
  improvementDone_ = false;
  improvePending_.clear();
}

void SmaServer::Impl::Session::MaybeRefine() {
  if (params_.criterion == Criterion::kNone || refineRunning_ || refinementDone_ || !Stage1Done() ||
      !connection_->IsOpen())
    return;
  if (Blocked()) {  // no work for a client that cannot take it; resumed by the refresh on drain
    WaitUntilUnblocked();
    return;
  }
  // The samples one client's refinement may create for one view are capped
  // (fuzzed options once grew the SMA by 17 MiB/s, for good).
  if (const uint64_t cap = server_.options_.clientRefinement.maxSamplesPerView; refiner_->Requested() >= cap) {
    log_->info("{}: view {}: refinement stopped at {} new samples (--client-max-refinement-samples {})",
               connection_->Id(), appliedViewId_, refiner_->Requested(), cap);
    refinementDone_ = true;
    SyncStatus();
    return;
  }
  refineRunning_ = true;
  auto self = shared_from_this();
  auto refiner = refiner_;
  auto hits = hits_;
  auto visible = visible_;
  // Splits still waiting for samples, or shaded but not yet re-mapped: an
  // empty choice now would not mean NLD_OS is done.
  const bool outstanding = !refinementPending_.empty() || refreshWanted_ || refreshArmed_;
  JobsFor(hits->view).Post([self, refiner, hits, visible, outstanding] {
    Impl& server = self->server_;
    std::vector<NodeId> chosen;
    {
      std::shared_lock lock(server.stateMutex_);
      chosen = refiner->Select(server.hierarchy_, server.cache_, *hits, *visible, server.DragoForClients(), outstanding);
    }
    std::vector<VertexId> created;
    if (!chosen.empty()) {
      std::unique_lock lock(server.stateMutex_);
      const RefineOptions options = refiner->Params().ToRefineOptions();
      for (NodeId id : chosen) {
        if (server.shuttingDown_.load(std::memory_order_relaxed)) break;  // a step of 10^5 splits takes long
        if (!server.hierarchy_.GetNode(id).IsLeaf()) continue;  // split meanwhile, by another client
        RefineResult r = server.hierarchy_.Refine(id, options);
        created.insert(created.end(), r.newVertices.begin(), r.newVertices.end());
      }
      server.cache_.Reserve(server.hierarchy_.VertexCount());
      std::vector<SampleRequest> requests;
      requests.reserve(created.size());
      for (VertexId v : created) requests.push_back(MakeSampleRequest(server.hierarchy_, v));
      server.pool_->Request(requests, Priority::kBackground);
    }
    refiner->CountRequested(created.size());
    const bool exhausted = refiner->Exhausted();
    asio::post(self->connection_->Strand(), [self, refiner, n = chosen.size(), created = std::move(created), exhausted]() mutable {
      self->OnRefineStepDone(refiner, n, std::move(created), exhausted);
    });
  });
}

void SmaServer::Impl::Session::OnRefineStepDone(const std::shared_ptr<Refiner>& refiner, size_t chosen,
                                                std::vector<VertexId> newVertices, bool exhausted) {
  refineRunning_ = false;
  if (refiner != refiner_ || !connection_->IsOpen()) {  // the view changed meanwhile
    MaybeRefine();
    return;
  }
  refinementSplits_ += chosen;
  refinementSamples_ += newVertices.size();
  const size_t pendingBefore = refinementPending_.size();
  log_->trace("{}: refinement step: {} split, {} new vertices, exhausted {}; pending {}, refresh wanted {} armed {}, "
              "job running {}",
              connection_->Id(), chosen, newVertices.size(), exhausted, refinementPending_.size(), refreshWanted_,
              refreshArmed_, jobRunning_);
  {
    // Results may have landed before this step's report: only wait for
    // what is still unshaded.
    std::shared_lock lock(server_.stateMutex_);
    for (VertexId v : newVertices)
      if (!server_.cache_.IsShaded(v)) refinementPending_.insert(v);
  }
  refineTotal_ += newVertices.size();
  refineDone_ += newVertices.size() - std::min(newVertices.size(), refinementPending_.size() - pendingBefore);
  if (chosen > 0) {
    // Bounded batches (the paper's R): give the strand's queue -- a new view
    // above all -- a turn before the next step.
    asio::post(connection_->Strand(), [self = shared_from_this()] { self->MaybeRefine(); });
    return;
  }
  if (exhausted) {
    refinementDone_ = true;
    SyncStatus();
    return;
  }
  // Nothing to split now. If samples are still on their way, or a re-map is
  // due or running, its completion starts the next step. If all of that
  // happened while this step ran (its trigger found a step running), look
  // again now, or refinement would never be woken.
  if (refinementPending_.empty() && !refreshWanted_ && !refreshArmed_ && !jobRunning_) MaybeRefine();
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
  if (connection_->Send(envelope)) ++deltasSent_;
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
  RestartRefinement();
  MaybeRefine();
  SyncStatus();
}

void SmaServer::Impl::Session::ScheduleRefresh() {
  if (refreshArmed_ || !refreshWanted_) return;
  const auto due = lastRefresh_ + server_.options_.refreshInterval;
  if (Clock::now() >= due && !jobRunning_) {
    StartJob();
    return;
  }
  refreshArmed_ = true;
  refreshTimer_.expires_at(std::max(due, Clock::now() + std::chrono::milliseconds(1)));
  refreshTimer_.async_wait([self = shared_from_this()](const error_code& ec) {
    self->refreshArmed_ = false;
    if (ec) return;
    if (self->jobRunning_) {
      self->ScheduleRefresh();  // try again after the running job
      return;
    }
    self->StartJob();
    // Another path (a new view, a client that caught up) may have run the
    // refresh while this timer waited, leaving nothing to start. A refinement
    // step that found nothing to split was waiting for this timer to wake it:
    // wake it here, or it would wait forever (seen on the breakfast room).
    if (!self->jobRunning_) self->MaybeRefine();
  });
}

void SmaServer::Impl::Session::WaitUntilUnblocked() {
  if (unblockArmed_) return;
  unblockArmed_ = true;
  unblockTimer_.expires_after(std::chrono::milliseconds(10));
  unblockTimer_.async_wait([self = shared_from_this()](const error_code& ec) {
    self->unblockArmed_ = false;
    if (ec || !self->connection_->IsOpen()) return;
    if (self->Blocked()) {
      self->WaitUntilUnblocked();
      return;
    }
    self->SendTextures();
    self->refreshWanted_ = true;
    self->StartJob();
  });
}

void SmaServer::Impl::Session::OnStatsRequest(const wire::StatsRequest& request) {
  wire::Envelope envelope;
  auto* reply = envelope.mutable_stats_reply();
  reply->set_request_id(request.request_id());
  server_.AddGlobalCounters(reply);
  AddCounter(reply, "client_view_id", double(appliedViewId_));
  AddCounter(reply, "client_views_received", double(viewsReceived_));
  AddCounter(reply, "client_triangles_held", double(mirror_.TriangleCount()));
  AddCounter(reply, "client_vertices_held", double(mirror_.VertexCount()));
  AddCounter(reply, "client_pending_triangles", double(pending_.size()));
  AddCounter(reply, "client_pending_samples", double(waiting_.size()));
  AddCounter(reply, "client_converged", Converged() ? 1.0 : 0.0);
  AddCounter(reply, "client_deltas_sent", double(deltasSent_));
  AddCounter(reply, "client_improvements_pending", double(improvePending_.size()));
  AddCounter(reply, "client_improvements_asked", double(improvementsAsked_));
  AddCounter(reply, "client_vertex_updates_sent", double(updatesSent_));
  AddCounter(reply, "client_bytes_sent", double(connection_->BytesSent()));
  AddCounter(reply, "client_bytes_received", double(connection_->BytesReceived()));
  AddCounter(reply, "client_last_trace_ms", lastTimings_.traceMs);
  AddCounter(reply, "client_last_map_ms", lastTimings_.mapMs);
  AddCounter(reply, "client_last_view_to_first_delta_ms", lastFirstDeltaMs_);
  AddCounter(reply, "client_triangles_sent", double(trianglesSent_));
  AddCounter(reply, "client_stage1_ms", stage1Ms_);
  AddCounter(reply, "client_stage2_ms", stage2Ms_);
  AddCounter(reply, "client_refinement_splits", double(refinementSplits_));
  AddCounter(reply, "client_refinement_samples", double(refinementSamples_));
  AddCounter(reply, "client_refinement_pending", double(refinementPending_.size()));
  AddCounter(reply, "client_visibility_pixels_reserved", double(reservedPixels_));
  AddCounter(reply, "client_texture_requests_outstanding", double(texturesOutstanding_.size()));
  AddCounter(reply, "client_texture_requests_refused", double(textureRequestsRefused_));
  AddCounter(reply, "visibility_pixels_reserved", double(server_.visibilityBudget_.Used()));
  AddCounter(reply, "textures_encoded", double(server_.textures_.EncodedCount()));
  AddCounter(reply, "visibility_traces", double(server_.viewTraces_.load()));
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
      asio::post(self->connection_->Strand(), [self, texture, ready] { self->OnTextureReady(texture, ready); });
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
  unblockTimer_.cancel();
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

void SmaServer::Impl::Accept(net::Stream stream) {
  if (shuttingDown_) {
    net::RefuseConnection(std::move(stream), MakeError(0, wire::ERROR_CODE_SHUTTING_DOWN, "SMA is shutting down", true));
    return;
  }
  const std::string peer = net::PeerAddress(stream);
  std::shared_ptr<Session> session;
  {
    std::lock_guard lock(sessionsMutex_);
    if (sessions_.size() >= options_.maxConnections) {
      // Refused at once: idle or anonymous peers cannot exhaust descriptors,
      // and the clients already connected are served as before.
      if (const uint64_t n = refusals_.Note())
        log_->warn("{} client connection(s) refused, latest from {}: at the cap of {} connections (--max-connections)",
                   n, peer, options_.maxConnections);
      net::RefuseConnection(std::move(stream),
                            MakeError(0, wire::ERROR_CODE_TOO_MANY_CONNECTIONS,
                                      fmt::format("this SMA serves at most {} connections at once; try again later",
                                                  options_.maxConnections),
                                      true));
      return;
    }
    const uint64_t id = nextSessionId_++;
    auto connection =
        net::Connection::Create(std::move(stream), options_.clientConnection, fmt::format("client#{} {}", id, peer));
    log_->info("{}: connected", connection->Id());
    session = std::make_shared<Session>(*this, std::move(connection), id);
    sessions_.emplace(id, session);
  }
  session->Start();
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
  AddCounter(reply, "cache_hits", double(hits));
  AddCounter(reply, "cache_misses", double(misses));
  AddCounter(reply, "cache_hit_rate", hits + misses > 0 ? double(hits) / double(hits + misses) : 0.0);
  AddCounter(reply, "samples_requested", double(pool.requested));
  AddCounter(reply, "samples_shaded", double(pool.shaded));
  AddCounter(reply, "samples_requeued", double(pool.requeued));
  AddCounter(reply, "samples_failed", double(pool.failed));
  AddCounter(reply, "samples_rejected", double(pool.rejected));
  AddCounter(reply, "samples_queued_visible", double(pool.queuedVisible));
  AddCounter(reply, "samples_queued_background", double(pool.queuedBackground));
  AddCounter(reply, "samples_queued_improve", double(pool.queuedImprove));
  AddCounter(reply, "samples_in_flight", double(pool.inFlight));
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

void SmaServer::Impl::ArmStats() {
  statsTimer_.expires_after(options_.statsInterval);
  statsTimer_.async_wait([this](const error_code& ec) {
    if (ec) return;
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
    log_->info("stats: cache {} shaded, hit rate {:.1f}%; {:.0f} requested/s, {:.0f} shaded/s, {} queued; "
               "renderers:{}; clients:{}; views: {}",
               shaded, hits + misses > 0 ? 100.0 * double(hits) / double(hits + misses) : 0.0,
               double(now.requested - lastStats_.requested) / seconds, double(now.shaded - lastStats_.shaded) / seconds,
               now.queuedVisible + now.queuedBackground, renderers.empty() ? " none" : renderers,
               clients.empty() ? " none" : clients, views);
    lastStats_ = now;
    ArmStats();
  });
}

void SmaServer::Impl::ArmRendererWatch() {
  rendererWatchTimer_.expires_after(std::chrono::milliseconds(500));
  rendererWatchTimer_.async_wait([this](const error_code& ec) {
    if (ec || shuttingDown_) return;
    const size_t renderers = pool_->ReadyRenderers();
    for (auto& session : Sessions())
      asio::post(session->Connection().Strand(), [session, renderers] { session->OnRendererCount(renderers); });
    ArmRendererWatch();
  });
}

void SmaServer::Impl::Shutdown() {
  asio::post(io_, [this] {
    if (shuttingDown_.exchange(true)) return;
    if (listener_) listener_->Stop();
    signals_.cancel();
    statsTimer_.cancel();
    rendererWatchTimer_.cancel();
    // Abandon the work (a running trace or refinement step stops at its next
    // tile or split; it took 7 s to finish them): nobody will see it.
    jobs_.Stop();
    backgroundJobs_.Stop();
    pool_->Stop();
    const auto sessions = Sessions();
    log_->info("shutting down: telling {} client(s)", sessions.size());
    for (auto& s : sessions)
      s->Connection().FailAndClose(MakeError(0, wire::ERROR_CODE_SHUTTING_DOWN, "SMA is shutting down", true),
                                   "SMA shutting down");
    // Stop when every client has been told and closed, or after a second
    // whatever a client that does not read does.
    shutdownDeadline_ = Clock::now() + std::chrono::seconds(1);
    PollShutdown();
  });
}

void SmaServer::Impl::PollShutdown() {
  if (Sessions().empty() || Clock::now() >= shutdownDeadline_) {
    io_.stop();
    return;
  }
  shutdownTimer_.expires_after(std::chrono::milliseconds(20));
  shutdownTimer_.async_wait([this](const error_code& ec) {
    if (!ec) PollShutdown();
  });
}

// --- Public wrapper ---------------------------------------------------------

Expected<std::unique_ptr<SmaServer>> SmaServer::Create(const Scene& scene, SmaOptions options) {
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
  return std::unique_ptr<SmaServer>(new SmaServer(std::make_unique<Impl>(
      scene, std::move(options), std::move(*tracer), std::move(snapshots), std::move(restored))));
}

SmaServer::SmaServer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
SmaServer::~SmaServer() = default;
Expected<tcp::endpoint> SmaServer::Listen() { return impl_->Listen(); }
void SmaServer::Run() { impl_->Run(); }
void SmaServer::Shutdown() { impl_->Shutdown(); }
void SmaServer::WriteMetrics(metrics::ExpositionWriter& out) { impl_->WriteMetrics(out); }
std::string SmaServer::NotReadyReason() { return impl_->NotReadyReason(); }

}  // namespace penumbra::sma

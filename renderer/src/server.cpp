#include "penumbra/renderer/server.h"

#include <mutex>
#include <optional>
#include <thread>
#include <unordered_set>

#include <fmt/format.h>

#include "penumbra/common/auth.h"
#include "penumbra/common/logging.h"
#include "penumbra/common/messages.h"
#include "penumbra/common/server_skeleton.h"
#include "penumbra/renderer/ray_scene.h"
#include "penumbra/renderer/shading_pool.h"
#include "renderer_metrics.h"

namespace penumbra {

namespace {
using Clock = std::chrono::steady_clock;
}  // namespace

class RendererServer::Impl {
 public:
  class Session;

  Impl(const Shader& shader, RendererServerOptions options)
      : shader_(shader),
        options_(std::move(options)),
        pool_(shader, options_.workerThreads > 0 ? options_.workerThreads
                                                 : int(std::max(1u, std::thread::hardware_concurrency()))),
        log_(Logger("renderer")),
        skeleton_(io_,
                  net::ServerSkeletonOptions::For(options_, options_.connection,
                                                  {.service = "renderer", .peer = "sma", .peers = "SMAs",
                                                   .logger = "renderer", .reservedDescriptors = 64}),
                  net::ServerHooks{.logStats = [this] { LogStats(); }, .beginShutdown = [this] { AbandonAll(); }},
                  [this](std::shared_ptr<net::Connection> connection, uint64_t id) {
                    return std::make_shared<Session>(*this, std::move(connection), id);
                  }) {}

  Expected<tcp::endpoint> Listen() { return skeleton_.Listen(); }

  void Run() {
    skeleton_.RunIo();
    log_->info("{}: stopped", options_.name);
  }

  void Shutdown() { skeleton_.Shutdown(); }

  bool Draining() const { return skeleton_.Draining(); }
  const Shader& GetShader() const { return shader_; }
  const RendererServerOptions& Options() const { return options_; }
  ShadingPool& Pool() { return pool_; }
  Clock::time_point Started() const { return started_; }
  // The counters of every StatsReply and of /metrics (renderer_metrics.cpp).
  // Any thread: the pool's totals and the session count, each under its
  // own brief lock.
  void AddServerCounters(wire::StatsReply* reply) const {
    const auto totals = pool_.GetTotals();
    AddCounter(reply, "samples_shaded", double(totals.samplesShaded));
    AddCounter(reply, "samples_cancelled", double(totals.samplesCancelled));
    AddCounter(reply, "samples_queued", double(totals.samplesQueued));
    AddCounter(reply, "paths_traced", double(totals.paths));
    AddCounter(reply, "rays_traced", double(totals.rays));
    AddCounter(reply, "samples_buried", double(totals.buriedSamples));
    AddCounter(reply, "worker_threads", double(pool_.Threads()));
    AddCounter(reply, "connections", double(skeleton_.SessionCount()));
    AddCounter(reply, "uptime_seconds", std::chrono::duration<double>(Clock::now() - started_).count());
  }
  void RemoveSession(uint64_t id) { skeleton_.Remove(id); }

 private:
  // Shutdown, on the I/O thread: abandon the work rather than finish it (a
  // deep queue once took 19 s): the SMAs send the samples to other renderers.
  void AbandonAll();

  void LogStats() {
    const auto totals = pool_.GetTotals();
    const double seconds = std::chrono::duration<double>(options_.statsInterval).count();
    log_->info("stats: {} connection(s), {:.0f} samples/s, {:.2f} Mrays/s, {} queued, {} shaded, {} cancelled",
               skeleton_.SessionCount(), double(totals.samplesShaded - lastTotals_.samplesShaded) / seconds,
               double(totals.rays - lastTotals_.rays) / seconds * 1e-6, totals.samplesQueued,
               totals.samplesShaded, totals.samplesCancelled);
    lastTotals_ = totals;
  }

  const Shader& shader_;
  RendererServerOptions options_;
  asio::io_context io_;
  ShadingPool pool_;
  std::shared_ptr<spdlog::logger> log_;
  Clock::time_point started_ = Clock::now();
  ShadingPool::Totals lastTotals_;
  net::ServerSkeleton<Session> skeleton_;
};

// One SMA connection. All members are touched on the connection's strand
// only, except inFlightCount_ (an atomic copy of the count, for other threads).
class RendererServer::Impl::Session : public std::enable_shared_from_this<Session> {
 public:
  Session(Impl& server, std::shared_ptr<net::Connection> connection, uint64_t id)
      : server_(server),
        connection_(std::move(connection)),
        id_(id),
        source_(server.Pool().AddSource()),
        log_(Logger("renderer")) {}

  void Start() {
    auto self = shared_from_this();
    connection_->Start([self](wire::Envelope&& e) { self->OnMessage(std::move(e)); },
                       [self](const std::string& reason) { self->OnClosed(reason); });
  }

  size_t InFlight() const { return inFlightCount_.load(); }
  /// Drops this connection's queued work and stops its running samples.
  /// Thread-safe. Returns the queued samples dropped.
  size_t AbandonWork() { return server_.Pool().Cancel(source_); }
  net::Connection& Connection() { return *connection_; }

 private:
  void OnMessage(wire::Envelope&& envelope) {
    if (envelope.has_hello()) return OnHello(envelope.hello());
    if (!handshook_) {
      return Fatal(wire::ERROR_CODE_HANDSHAKE_REQUIRED,
                   fmt::format("expected hello as the first message, got {}", BodyName(envelope)));
    }
    switch (envelope.body_case()) {
      case wire::Envelope::kShadeRequest:
        return OnShadeRequest(*envelope.mutable_shade_request());
      case wire::Envelope::kStatsRequest:
        return OnStatsRequest(envelope.stats_request());
      case wire::Envelope::kError:
        log_->warn("{}: peer reports error {}: {}", connection_->Id(), wire::ErrorCode_Name(envelope.error().code()),
                   envelope.error().message());
        return;
      default:
        Reject(0, wire::ERROR_CODE_UNEXPECTED_MESSAGE,
               fmt::format("a renderer does not take {} messages", BodyName(envelope)));
    }
  }

  void OnHello(const wire::Hello& hello) {
    if (handshook_) {
      return Reject(0, wire::ERROR_CODE_UNEXPECTED_MESSAGE, "hello after the handshake is ignored");
    }
    const Scene& scene = server_.GetShader().GetScene();
    wire::ErrorCode code = wire::ERROR_CODE_UNSPECIFIED;
    // The token first: a peer without it learns nothing else.
    if (auto ok = CheckHelloToken(hello, server_.Options().authToken, &code); !ok) {
      return Fatal(code, ok.error().message);
    }
    if (auto ok = ValidateHello(hello, wire::ROLE_SMA, scene.identity, &code); !ok) {
      return Fatal(code, ok.error().message);
    }
    handshook_ = true;
    const auto& options = server_.Options();
    wire::Envelope envelope;
    auto* w = envelope.mutable_welcome();
    w->set_protocol_version(kProtocolVersion);
    w->set_role(wire::ROLE_RENDERER);
    w->set_server_name(options.name);
    w->set_scene_hash(scene.identity);
    w->set_max_frame_bytes(options.connection.maxFrameBytes);
    w->set_max_batch_samples(options.limits.maxBatchSamples);
    w->set_worker_threads(uint32_t(server_.Pool().Threads()));
    w->set_paths_per_sample(uint32_t(server_.GetShader().Settings().pathsPerSample));
    w->set_max_batches_in_flight(options.maxBatchesInFlight);
    connection_->Send(envelope);
    connection_->MarkHandshakeDone();
    log_->info("{}: handshake with '{}' done", connection_->Id(), Printable(hello.peer_name()));
  }

  void OnShadeRequest(wire::ShadeRequest& request) {
    const uint64_t batchId = request.batch_id();
    if (server_.Draining()) return Reject(batchId, wire::ERROR_CODE_SHUTTING_DOWN, "renderer is shutting down");
    if (inFlight_.size() >= server_.Options().maxBatchesInFlight) {
      return Reject(batchId, wire::ERROR_CODE_OVERLOADED,
                    fmt::format("batch {}: {} batches already in flight (limit {})", batchId, inFlight_.size(),
                                server_.Options().maxBatchesInFlight));
    }
    if (inFlight_.contains(batchId)) {
      return Reject(batchId, wire::ERROR_CODE_INVALID_REQUEST,
                    fmt::format("batch {}: a batch with this id is already in flight", batchId));
    }
    const Scene& scene = server_.GetShader().GetScene();
    auto pose = DecodeShadePose(request, scene);
    if (!pose) return Reject(batchId, wire::ERROR_CODE_INVALID_REQUEST, pose.error().message);
    auto inputs = DecodeShadeRequest(request, scene, *pose, server_.Options().limits);
    if (!inputs) return Reject(batchId, wire::ERROR_CODE_INVALID_REQUEST, inputs.error().message);
    std::optional<VerificationRequest> verification;
    if (request.has_verify_change()) {
      auto decoded = DecodeVerifyChange(request, scene, *inputs);
      if (!decoded) return Reject(batchId, wire::ERROR_CODE_INVALID_REQUEST, decoded.error().message);
      verification = std::move(*decoded);
    }
    // The posed scene: the last one again while the SMAs stay at one pose,
    // else a top-level commit of a few instances -- microseconds, as cheap
    // as the validation above, so it is done here rather than on a worker.
    auto posed = server_.GetShader().GetRays().AtPose(*pose);
    if (!posed) {
      // Not the request's fault (Embree out of memory): the SMA sends it again.
      return Reject(batchId, wire::ERROR_CODE_OVERLOADED,
                    fmt::format("batch {}: cannot place the objects: {}", batchId, posed.error().message));
    }

    auto job = std::make_shared<ShadeJob>();
    if (verification) {
      auto baseline = server_.GetShader().GetRays().AtPose(verification->baseline);
      if (!baseline)
        return Reject(batchId, wire::ERROR_CODE_OVERLOADED,
                      fmt::format("batch {}: cannot place the objects: {}", batchId, baseline.error().message));
      job->baseline = std::move(*baseline);
      job->region = std::move(verification->region);
    }
    job->batchId = batchId;
    job->urgent = request.urgent();
    job->soon = request.soon();
    job->paths = int(request.paths_per_sample());
    job->pose = std::move(*posed);
    job->inputs = std::move(*inputs);
    std::weak_ptr<Session> weak = weak_from_this();
    job->onPart = [weak, connection = connection_](const ShadeJob& j, size_t begin, size_t end,
                                                     const ShadeCounters& counters, size_t remaining) {
      wire::Envelope reply;
      if (j.baseline)
        FillChangeReply(j.batchId, std::span(j.inputs).subspan(begin, end - begin),
                        std::span(j.changes).subspan(begin, end - begin), uint32_t(remaining), counters,
                        reply.mutable_shade_reply());
      else
        FillShadeReply(j.batchId, std::span(j.inputs).subspan(begin, end - begin),
                       std::span(j.outputs).subspan(begin, end - begin), uint32_t(remaining), counters,
                       reply.mutable_shade_reply());
      reply.mutable_shade_reply()->set_scene_epoch(j.pose->Pose().epoch);
      if (!connection->Send(reply) && connection->IsOpen()) {
        // Never drop a result silently: closing makes the SMA re-send the batch elsewhere.
        connection->Close(fmt::format("send queue full while answering batch {}", j.batchId));
      }
      if (remaining == 0) {
        asio::post(connection->Strand(), [weak, id = j.batchId] {
          if (auto self = weak.lock()) self->Finished(id);
        });
      }
    };
    inFlight_.insert(batchId);
    inFlightCount_ = inFlight_.size();
    ++batchesReceived_;
    samplesReceived_ += job->inputs.size();
    server_.Pool().Submit(source_, std::move(job));
  }

  void Finished(uint64_t batchId) {
    inFlight_.erase(batchId);
    inFlightCount_ = inFlight_.size();
  }

  void OnStatsRequest(const wire::StatsRequest& request) {
    wire::Envelope envelope;
    auto* reply = envelope.mutable_stats_reply();
    reply->set_request_id(request.request_id());
    server_.AddServerCounters(reply);
    AddCounter(reply, "connection_batches_in_flight", double(inFlight_.size()));
    AddCounter(reply, "connection_batches_received", double(batchesReceived_));
    AddCounter(reply, "connection_samples_received", double(samplesReceived_));
    AddCounter(reply, "connection_bytes_received", double(connection_->BytesReceived()));
    AddCounter(reply, "connection_bytes_sent", double(connection_->BytesSent()));
    connection_->Send(envelope);
  }

  void Reject(uint64_t requestId, wire::ErrorCode code, const std::string& message) {
    log_->warn("{}: {}", connection_->Id(), message);
    connection_->Send(MakeError(requestId, code, message, /*fatal=*/false));
  }

  void Fatal(wire::ErrorCode code, const std::string& message) {
    log_->warn("{}: {} (closing)", connection_->Id(), message);
    connection_->FailAndClose(MakeError(0, code, message, /*fatal=*/true), message);
  }

  void OnClosed(const std::string& reason) {
    const size_t dropped = server_.Pool().Cancel(source_);
    inFlight_.clear();
    inFlightCount_ = 0;
    log_->info("{}: closed ({}); {} queued sample(s) cancelled", connection_->Id(), reason, dropped);
    server_.RemoveSession(id_);
  }

  Impl& server_;
  std::shared_ptr<net::Connection> connection_;
  uint64_t id_;
  std::shared_ptr<ShadingPool::Source> source_;
  std::shared_ptr<spdlog::logger> log_;
  bool handshook_ = false;
  std::unordered_set<uint64_t> inFlight_;
  std::atomic<size_t> inFlightCount_{0};
  uint64_t batchesReceived_ = 0;
  uint64_t samplesReceived_ = 0;
};

void RendererServer::Impl::AbandonAll() {
  size_t abandoned = 0;
  const auto sessions = skeleton_.Sessions();
  for (auto& s : sessions) abandoned += s->AbandonWork();
  log_->info("shutting down: {} connection(s), {} queued sample(s) abandoned", sessions.size(), abandoned);
}

RendererServer::RendererServer(const Shader& shader, RendererServerOptions options)
    : impl_(std::make_unique<Impl>(shader, std::move(options))) {}
RendererServer::~RendererServer() = default;
Expected<tcp::endpoint> RendererServer::Listen() { return impl_->Listen(); }
void RendererServer::Run() { impl_->Run(); }
void RendererServer::Shutdown() { impl_->Shutdown(); }

void RendererServer::WriteMetrics(metrics::ExpositionWriter& out) const {
  wire::StatsReply counters;
  impl_->AddServerCounters(&counters);
  WriteRendererMetrics(out, counters);
}

std::string RendererServer::NotReadyReason() const {
  return impl_->Draining() ? "draining (shutting down)" : std::string();
}

}  // namespace penumbra

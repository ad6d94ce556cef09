#include "penumbra/client/session.h"

#include <atomic>
#include <cmath>
#include <mutex>
#include <thread>
#include <utility>

#include <fmt/format.h>

#include "penumbra/common/connection.h"
#include "penumbra/common/duration.h"
#include "penumbra/common/logging.h"
#include "penumbra/common/messages.h"
#include "penumbra/common/scene.h"
#include "penumbra/common/wire_convert.h"
#include "penumbra/wire.pb.h"

namespace penumbra::client {

namespace {

using Clock = std::chrono::steady_clock;
using boost::system::error_code;

/// Rough size of an event, for the read-pause threshold.
size_t EventBytes(const SessionEvent& event) {
  if (const auto* d = std::get_if<DeltaReceived>(&event)) return d->delta->ByteSizeLong();
  if (const auto* t = std::get_if<TextureReceived>(&event)) return t->rgb8.size();
  return 256;
}

}  // namespace

const char* ToString(ConnectionState state) {
  switch (state) {
    case ConnectionState::kConnecting: return "connecting";
    case ConnectionState::kConnected: return "connected";
    case ConnectionState::kWaiting: return "waiting";
    case ConnectionState::kStopped: return "stopped";
  }
  return "?";
}

// Everything below the public methods runs on the network thread.
class SmaSession::Impl : public std::enable_shared_from_this<Impl> {
 public:
  explicit Impl(SmaSessionOptions options)
      : options_(std::move(options)),
        work_(asio::make_work_guard(io_)),
        resolver_(io_),
        retryTimer_(io_),
        countersTimer_(io_),
        log_(Logger("client.session")),
        address_(options_.sma.ToString()),
        backoff_(options_.reconnectMin) {
    status_.disconnectedSince = Clock::now();
  }

  void Start() {
    asio::post(io_, [self = shared_from_this()] { self->Attempt(); });
    thread_ = std::thread([this] { io_.run(); });
  }

  void Stop() {
    if (!thread_.joinable()) return;
    asio::post(io_, [self = shared_from_this()] {
      self->stopping_ = true;
      self->retryTimer_.cancel();
      self->countersTimer_.cancel();
      self->resolver_.cancel();
      if (self->connection_) self->connection_->Close("client stopping");
      self->work_.reset();
    });
    thread_.join();
    std::lock_guard lock(mutex_);
    status_.state = ConnectionState::kStopped;
  }

  uint64_t SetView(const CameraView& view) {
    const uint64_t serial = ++lastSerial_;
    asio::post(io_, [self = shared_from_this(), view, serial] {
      self->view_ = view;
      self->viewSerial_ = serial;
      if (self->ready_) self->SendView();
    });
    return serial;
  }

  void SetSessionOptions(const RefinementRequest& request) {
    wire::SessionOptions options;
    ToWire(request, &options);
    asio::post(io_, [self = shared_from_this(), options] {
      self->sessionOptions_ = options;
      if (self->ready_) self->SendSessionOptions();
    });
  }

  uint64_t MoveObject(uint32_t object, const RigidTransform& objectToWorld) {
    const uint64_t requestId = kMoveRequestBit | ++lastMoveSerial_;
    wire::Envelope e;
    auto* move = e.mutable_move_object();
    move->set_request_id(requestId);
    move->set_object(object);
    ToWire(objectToWorld, move->mutable_object_to_world());
    asio::post(io_, [self = shared_from_this(), e = std::move(e), requestId, object] {
      if (self->ready_ && self->connection_->Send(e)) return;
      const std::string text = fmt::format("move of object {} not sent: no connection to SMA {}", object,
                                           self->address_);
      self->log_->warn("{}", text);
      self->Push(SmaErrorReceived{0, requestId, true, text});
    });
    return requestId;
  }

  std::vector<SessionEvent> TakeEvents() {
    std::vector<SessionEvent> taken;
    bool resume = false;
    {
      std::lock_guard lock(mutex_);
      taken.swap(events_);
      pendingEventBytes_ = 0;
      resume = std::exchange(readPaused_, false);
    }
    if (resume) {
      asio::post(io_, [self = shared_from_this()] {
        if (self->connection_) self->connection_->SetReadPaused(false);
      });
    }
    return taken;
  }

  SessionStatus Status() const {
    std::lock_guard lock(mutex_);
    SessionStatus s = status_;
    if (statusConnection_) s.bytesReceived += statusConnection_->BytesReceived();
    return s;
  }

  void RequestTexture(uint64_t connection, uint32_t texture) {
    asio::post(io_, [self = shared_from_this(), connection, texture] {
      if (!self->ready_ || connection != self->connectionNumber_) return;
      wire::Envelope e;
      e.mutable_texture_request()->set_texture(texture);
      self->connection_->Send(e);
    });
  }

  void AbandonConnection(uint64_t connection, const std::string& reason) {
    asio::post(io_, [self = shared_from_this(), connection, reason] {
      if (!self->ready_ || connection != self->connectionNumber_) return;
      self->log_->debug("abandoning connection {} to SMA {}: {}", connection, self->address_, reason);
      self->connection_->FailAndClose(MakeError(0, wire::ERROR_CODE_INVALID_REQUEST, reason, true), reason);
    });
  }

 private:
  // --- Connecting ------------------------------------------------------------

  void Attempt() {
    if (stopping_) return;
    SetState(ConnectionState::kConnecting);
    resolver_.async_resolve(options_.sma.host, std::to_string(options_.sma.port),
                            [self = shared_from_this()](const error_code& ec, tcp::resolver::results_type results) {
                              if (self->stopping_) return;
                              if (ec || results.empty())
                                return self->AttemptFailed(Fail(fmt::format("cannot resolve: {}", ec.message())));
                              std::vector<tcp::endpoint> endpoints;
                              for (const auto& r : results) endpoints.push_back(r.endpoint());
                              self->TryEndpoint(std::move(endpoints), 0, Error{});
                            });
  }

  // Tries the addresses a name resolves to in turn; the first that accepts
  // wins. A refused certificate at any of them is what the user is told
  // (and it ends the session): it is a configuration error, not a network one.
  void TryEndpoint(std::vector<tcp::endpoint> endpoints, size_t index, Error failure) {
    if (stopping_) return;
    if (index >= endpoints.size()) return AttemptFailed(std::move(failure));
    const tcp::endpoint endpoint = endpoints[index];
    net::AsyncConnectStream(
        io_, endpoint, net::TlsClientTarget{options_.tls, options_.sma.host}, options_.connectTimeout,
        [self = shared_from_this(), endpoints = std::move(endpoints), index,
         failure = std::move(failure)](Expected<net::Stream> stream) mutable {
          // AsyncConnectStream's handler runs on the socket's strand; hop to the session.
          asio::post(self->io_, [self, stream = std::move(stream), endpoints = std::move(endpoints), index,
                                 failure = std::move(failure)]() mutable {
            if (self->stopping_) return;
            if (!stream) {
              if (!failure.permanent) failure = stream.error();
              return self->TryEndpoint(std::move(endpoints), index + 1, std::move(failure));
            }
            self->OnSocket(std::move(*stream));
          });
        });
  }

  void OnSocket(net::Stream stream) {
    auto connection = net::Connection::Create(std::move(stream), options_.connection, "sma " + address_);
    connection_ = connection;
    welcomed_ = false;
    ready_ = false;
    closeReason_.clear();
    {
      std::lock_guard lock(mutex_);
      statusConnection_ = connection;
    }
    std::weak_ptr<Impl> weak = weak_from_this();
    // The connection's handlers run on its strand; both hop to the session's
    // thread of control so that session state has a single owner.
    connection->Start(
        [weak, connection](wire::Envelope&& envelope) {
          if (auto self = weak.lock())
            asio::post(self->io_, [self, connection, envelope = std::move(envelope)]() mutable {
              if (connection == self->connection_) self->OnMessage(std::move(envelope));
            });
        },
        [weak, connection](const std::string& reason) {
          if (auto self = weak.lock())
            asio::post(self->io_, [self, connection, reason] {
              if (connection == self->connection_) self->OnClosed(reason);
            });
        });
    // Scene 0: a client takes whatever scene the SMA serves.
    connection->Send(MakeHello(wire::ROLE_CLIENT, options_.clientName, 0, options_.authToken));
  }

  void AttemptFailed(Error failure) {
    RecordError(failure.message);
    if (failure.permanent) {
      permanentError_ = fmt::format("{} (check --tls-ca and the SMA's --tls-cert)", failure.message);
      return GiveUp();
    }
    log_->info("cannot connect to SMA {}: {}; retrying in {} ms", address_, failure.message, ScheduleRetry().count());
  }

  // Retrying cannot help (permanentError_ says why): stop, and let the
  // application say why.
  void GiveUp() {
    log_->error("giving up on SMA {}: {}; not retrying", address_, permanentError_);
    std::lock_guard lock(mutex_);
    status_.state = ConnectionState::kStopped;
    status_.permanentError = permanentError_;
  }

  /// Arms the reconnection timer and returns its delay; the delay doubles
  /// with each failure up to reconnectMax and resets on a handshake.
  std::chrono::milliseconds ScheduleRetry() {
    const auto delay = backoff_;
    if (stopping_) return delay;
    SetState(ConnectionState::kWaiting);
    retryTimer_.expires_after(delay);
    backoff_ = std::min(options_.reconnectMax, backoff_ * 2);
    retryTimer_.async_wait([self = shared_from_this()](const error_code& ec) {
      if (!ec) self->Attempt();
    });
    return delay;
  }

  void OnClosed(const std::string& reason) {
    {
      std::lock_guard lock(mutex_);
      status_.bytesReceived += connection_->BytesReceived();
      statusConnection_.reset();
      status_.disconnectedSince = Clock::now();
    }
    connection_.reset();
    countersTimer_.cancel();
    // The server's own word (a fatal error it sent, as "SMA ... is shutting
    // down") says more than the socket's ("peer closed the connection").
    const std::string why = closeReason_.empty() ? reason : std::exchange(closeReason_, std::string());
    RecordError(why);
    const bool wasReady = std::exchange(ready_, false);
    if (wasReady) Push(Disconnected{connectionNumber_, why});
    if (stopping_) return;
    if (!permanentError_.empty()) return GiveUp();
    const auto delay = ScheduleRetry();
    if (wasReady)
      log_->warn("lost connection {} to SMA {}: {}; reconnecting in {} ms", connectionNumber_, address_, why,
                 delay.count());
    else
      log_->info("SMA {} closed the connection during the handshake: {}; retrying in {} ms", address_, why,
                 delay.count());
  }

  // --- Messages ----------------------------------------------------------------

  void OnMessage(wire::Envelope&& envelope) {
    if (envelope.has_error()) return OnErrorReply(envelope.error());
    if (!welcomed_) {
      if (!envelope.has_welcome())
        return Refuse(wire::ERROR_CODE_HANDSHAKE_REQUIRED,
                      fmt::format("expected welcome, got {}", BodyName(envelope)));
      wire::ErrorCode code = wire::ERROR_CODE_UNSPECIFIED;
      if (auto ok = ValidateWelcome(envelope.welcome(), wire::ROLE_SMA, 0, &code); !ok) {
        if (IsPermanent(code)) permanentError_ = fmt::format("{} is not a usable SMA: {}", address_, ok.error().message);
        return Refuse(code, ok.error().message);
      }
      welcome_ = envelope.welcome();
      welcomed_ = true;
      return;
    }
    if (!ready_) {
      if (!envelope.has_scene_info())
        return Refuse(wire::ERROR_CODE_UNEXPECTED_MESSAGE,
                      fmt::format("expected scene_info after welcome, got {}", BodyName(envelope)));
      auto scene = ClientSceneFromWire(envelope.scene_info(), welcome_.scene_hash());
      if (!scene) return Refuse(wire::ERROR_CODE_INVALID_REQUEST, scene.error().message);
      return OnReady(std::move(*scene));
    }
    switch (envelope.body_case()) {
      case wire::Envelope::kDelta:
        return OnDelta(std::move(*envelope.mutable_delta()));
      case wire::Envelope::kTextureData:
      {
        wire::TextureData& t = *envelope.mutable_texture_data();
        return Push(TextureReceived{connectionNumber_, t.texture(), t.width(), t.height(), std::move(*t.mutable_rgb8())});
      }
      case wire::Envelope::kStatsReply: {
        SmaCountersReceived counters{connectionNumber_, {}};
        for (const auto& c : envelope.stats_reply().counters()) counters.counters[c.name()] = c.value();
        return Push(std::move(counters));
      }
      default:
        return Refuse(wire::ERROR_CODE_UNEXPECTED_MESSAGE,
                      fmt::format("a client does not take {} messages", BodyName(envelope)));
    }
  }

  void OnErrorReply(const wire::ErrorReply& error) {
    if (error.fatal() && error.code() == wire::ERROR_CODE_SHUTTING_DOWN) {
      // Not a fault: the server is going away (a restart, say); reconnecting
      // takes it from here.
      closeReason_ = fmt::format("SMA {} is shutting down", address_);
      log_->warn("{}", closeReason_);
      RecordError(closeReason_);
      return;
    }
    const std::string text = fmt::format("SMA {} reports {}: {}", address_, wire::ErrorCode_Name(error.code()),
                                         Printable(error.message(), 512));
    if (error.code() == wire::ERROR_CODE_AUTH_FAILED) {
      // Retrying cannot help until an operator changes a token or a TLS flag.
      permanentError_ = text + " (check --auth-token-file and --tls-ca against the SMA's flags)";
      log_->error("{}; not retrying", permanentError_);
      closeReason_ = text;
      RecordError(text);
    } else if (error.fatal()) {
      log_->error("{} (it closes the connection)", text);
      closeReason_ = text;
      RecordError(text);
      // Refused during the handshake for what we are (role, protocol
      // version, scene): the same answer would come on every attempt.
      if (!ready_ && IsPermanent(error.code())) {
        permanentError_ = fmt::format("{} refused this client: {}", address_, Printable(error.message()));
        if (error.message().find("expected sma") != std::string::npos)
          permanentError_ += " (that port belongs to a renderer: point --connect at the SMA's client port)";
      }
    } else {
      log_->warn("{}", text);
      // The render thread shows it (a refused move snaps the object back).
      if (ready_)
        Push(SmaErrorReceived{connectionNumber_, error.request_id(), (error.request_id() & kMoveRequestBit) != 0, text});
    }
  }

  static bool IsPermanent(wire::ErrorCode code) {
    // A role mismatch is reported as UNEXPECTED_MESSAGE (common/messages.cpp).
    return code == wire::ERROR_CODE_VERSION_MISMATCH || code == wire::ERROR_CODE_SCENE_MISMATCH ||
           code == wire::ERROR_CODE_UNEXPECTED_MESSAGE;
  }

  void Refuse(wire::ErrorCode code, const std::string& reason) {
    log_->error("SMA {}: {}; dropping the connection", address_, reason);
    connection_->FailAndClose(MakeError(0, code, reason, true), reason);
  }

  void OnReady(ClientScene scene) {
    ready_ = true;
    ++connectionNumber_;
    nextViewId_ = 1;
    lastSentViewId_ = 0;
    backoff_ = options_.reconnectMin;
    SetState(ConnectionState::kConnected, /*connected=*/true);
    log_->info("connected to SMA {} ('{}'), scene '{}' (connection {})", address_, Printable(welcome_.server_name()),
               Printable(scene.name), connectionNumber_);
    Push(Connected{connectionNumber_, std::move(scene)});
    if (sessionOptions_) SendSessionOptions();
    if (view_) SendView();
    ArmCountersTimer();
  }

  void SendSessionOptions() {
    wire::Envelope e;
    *e.mutable_session_options() = *sessionOptions_;
    connection_->Send(e);  // if closing, the next connection sends it
  }

  void SendView() {
    wire::Envelope e;
    auto* v = e.mutable_view();
    v->set_view_id(nextViewId_);
    ToWire(view_->pose.eye, v->mutable_eye());
    ToWire(view_->pose.target, v->mutable_target());
    ToWire(view_->pose.up, v->mutable_up());
    v->set_fov_y_deg(view_->fovYDeg);
    v->set_width(uint32_t(view_->width));
    v->set_height(uint32_t(view_->height));
    if (!connection_->Send(e)) return;  // closing; the next connection sends it
    lastSentViewId_ = nextViewId_++;
    lastSentSerial_ = viewSerial_;
    lastViewSentAt_ = Clock::now();
    awaitingFirstDelta_ = true;
  }

  void OnDelta(wire::Delta delta) {
    // A MOVED delta tells where objects are, not what a view shows: the SMA
    // may send one before this connection's first view has reached it
    // (another client's move, an animation), with view id 0.
    const bool viewless = delta.kind() == wire::DELTA_KIND_MOVED && delta.view_id() == 0;
    if (viewless) return Push(DeltaReceived{connectionNumber_, 0, std::make_shared<const wire::Delta>(std::move(delta))});
    if (delta.view_id() == 0 || delta.view_id() > lastSentViewId_)
      return Refuse(wire::ERROR_CODE_INVALID_REQUEST,
                    fmt::format("delta {} answers view {}, which was never sent (last {})", delta.sequence(),
                                delta.view_id(), lastSentViewId_));
    const bool forLatest = delta.view_id() == lastSentViewId_;
    if (forLatest && awaitingFirstDelta_) {
      awaitingFirstDelta_ = false;
      const double ms = Milliseconds(Clock::now() - lastViewSentAt_);
      std::lock_guard lock(mutex_);
      status_.viewToFirstDeltaMs = ms;
    }
    // Counters right after convergence let the render thread check that it
    // holds exactly what the SMA thinks it holds.
    if (forLatest && delta.converged()) SendStatsRequest();
    Push(DeltaReceived{connectionNumber_, forLatest ? lastSentSerial_ : 0,
                       std::make_shared<const wire::Delta>(std::move(delta))});
  }

  void SendStatsRequest() {
    wire::Envelope e;
    e.mutable_stats_request()->set_request_id(++nextStatsId_);
    connection_->Send(e);
  }

  void ArmCountersTimer() {
    countersTimer_.expires_after(options_.countersInterval);
    countersTimer_.async_wait([self = shared_from_this()](const error_code& ec) {
      if (ec || !self->ready_) return;
      self->SendStatsRequest();
      self->ArmCountersTimer();
    });
  }

  // --- Shared with the render thread -------------------------------------------

  void Push(SessionEvent event) {
    const size_t bytes = EventBytes(event);
    bool pause = false;
    {
      std::lock_guard lock(mutex_);
      events_.push_back(std::move(event));
      pendingEventBytes_ += bytes;
      if (pendingEventBytes_ > options_.maxPendingEventBytes && !readPaused_) pause = readPaused_ = true;
    }
    if (pause && connection_) {
      log_->debug("render thread is {} bytes behind; pausing reads", pendingEventBytes_);
      connection_->SetReadPaused(true);
    }
  }

  void SetState(ConnectionState state, bool connected = false) {
    std::lock_guard lock(mutex_);
    status_.state = state;
    if (connected) {
      status_.connections = connectionNumber_;
      status_.lastError.clear();
    }
  }

  void RecordError(const std::string& reason) {
    std::lock_guard lock(mutex_);
    status_.lastError = reason;
  }

  SmaSessionOptions options_;
  asio::io_context io_;
  asio::executor_work_guard<asio::io_context::executor_type> work_;
  tcp::resolver resolver_;
  asio::steady_timer retryTimer_;
  asio::steady_timer countersTimer_;
  std::shared_ptr<spdlog::logger> log_;
  const std::string address_;
  std::thread thread_;
  std::atomic<uint64_t> lastSerial_{0};
  std::atomic<uint64_t> lastMoveSerial_{0};

  // Network-thread state.
  bool stopping_ = false;
  std::shared_ptr<net::Connection> connection_;  // the current one, from connect to close
  bool welcomed_ = false;
  bool ready_ = false;  // SceneInfo received on connection_
  std::string permanentError_;  // why retrying cannot help; set once, ends the session
  std::string closeReason_;  // from a fatal ErrorReply on connection_: why it is about to close
  std::optional<wire::SessionOptions> sessionOptions_;  // sent on every connection
  wire::Welcome welcome_;
  uint64_t connectionNumber_ = 0;
  std::chrono::milliseconds backoff_;
  std::optional<CameraView> view_;
  uint64_t viewSerial_ = 0;
  uint64_t nextViewId_ = 1;
  uint64_t lastSentViewId_ = 0;
  uint64_t lastSentSerial_ = 0;
  Clock::time_point lastViewSentAt_;
  bool awaitingFirstDelta_ = false;
  uint64_t nextStatsId_ = 0;

  // Shared, under mutex_.
  mutable std::mutex mutex_;
  std::vector<SessionEvent> events_;
  size_t pendingEventBytes_ = 0;
  bool readPaused_ = false;
  SessionStatus status_;
  std::shared_ptr<net::Connection> statusConnection_;  // for its byte counter
};

SmaSession::SmaSession(SmaSessionOptions options) : impl_(std::make_shared<Impl>(std::move(options))) {}
SmaSession::~SmaSession() { Stop(); }
void SmaSession::Start() { impl_->Start(); }
void SmaSession::Stop() { impl_->Stop(); }
uint64_t SmaSession::SetView(const CameraView& view) { return impl_->SetView(view); }
void SmaSession::SetSessionOptions(const RefinementRequest& request) { impl_->SetSessionOptions(request); }
uint64_t SmaSession::MoveObject(uint32_t object, const RigidTransform& objectToWorld) {
  return impl_->MoveObject(object, objectToWorld);
}
std::vector<SessionEvent> SmaSession::TakeEvents() { return impl_->TakeEvents(); }
SessionStatus SmaSession::Status() const { return impl_->Status(); }
void SmaSession::RequestTexture(uint64_t connection, uint32_t texture) { impl_->RequestTexture(connection, texture); }
void SmaSession::AbandonConnection(uint64_t connection, const std::string& reason) {
  impl_->AbandonConnection(connection, reason);
}

}  // namespace penumbra::client

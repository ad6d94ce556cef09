#include "renderer_link.h"

#include <fmt/format.h>

#include "penumbra/common/logging.h"
#include "penumbra/common/messages.h"

namespace penumbra::sma {

namespace {
using boost::system::error_code;

std::string EndpointLabel(const tcp::endpoint& e) {
  return e.address().is_v6() ? fmt::format("[{}]:{}", e.address().to_string(), e.port())
                             : fmt::format("{}:{}", e.address().to_string(), e.port());
}
}  // namespace

std::shared_ptr<RendererLink> RendererLink::Create(asio::io_context& io, const RendererPoolOptions& options,
                                                   tcp::endpoint endpoint, std::string host, uint32_t index,
                                                   Events events) {
  return std::shared_ptr<RendererLink>(
      new RendererLink(io, options, std::move(endpoint), std::move(host), index, std::move(events)));
}

RendererLink::RendererLink(asio::io_context& io, const RendererPoolOptions& options, tcp::endpoint endpoint,
                           std::string host, uint32_t index, Events events)
    : io_(io),
      options_(options),
      endpoint_(std::move(endpoint)),
      host_(std::move(host)),
      label_(EndpointLabel(endpoint_)),
      index_(index),
      events_(std::move(events)),
      backoff_(options.reconnectMin),
      timer_(io) {}

void RendererLink::Start() {
  asio::post(io_, [self = shared_from_this()] { self->Connect(); });
}

void RendererLink::Connect() {
  {
    std::lock_guard lock(mutex_);
    if (state_ == State::kRemoved) return;
    state_ = State::kConnecting;
  }
  net::AsyncConnectStream(io_, endpoint_, net::TlsClientTarget{options_.tls, host_}, options_.connectTimeout,
                          [self = shared_from_this()](Expected<net::Stream> stream) {
                            if (stream) return self->OnConnected(std::move(*stream));
                            {
                              std::lock_guard lock(self->mutex_);
                              // Said at warning level the first time and then about every reconnectMax, so
                              // that an operator hears of a renderer that cannot be reached without a flood.
                              const bool say = self->connectFailures_++ == 0 || self->backoff_ >= self->options_.reconnectMax;
                              Logger("sma.renderers")
                                  ->log(say ? spdlog::level::warn : spdlog::level::debug, "renderer {}: cannot connect ({})",
                                        self->label_, stream.error().message);
                            }
                            self->OnClosed(stream.error().message);
                          });
}

void RendererLink::OnConnected(net::Stream stream) {
  auto connection = net::Connection::Create(std::move(stream), options_.connection, "renderer " + label_);
  {
    std::lock_guard lock(mutex_);
    if (state_ == State::kRemoved) {
      connection->Close("SMA stopping");
      return;
    }
    connection_ = connection;
    state_ = State::kHandshaking;
  }
  auto self = shared_from_this();
  connection->Start([self](wire::Envelope&& e) { self->OnMessage(std::move(e)); },
                    [self](const std::string& reason) { self->OnClosed(reason); });
  connection->Send(MakeHello(wire::ROLE_SMA, options_.name, options_.sceneHash, options_.authToken));
}

void RendererLink::OnMessage(wire::Envelope&& envelope) {
  auto log = Logger("sma.renderers");
  if (envelope.has_welcome()) {
    const auto& w = envelope.welcome();
    wire::ErrorCode code = wire::ERROR_CODE_UNSPECIFIED;
    if (auto ok = ValidateWelcome(w, wire::ROLE_RENDERER, options_.sceneHash, &code); !ok) {
      log->error("renderer {} refused: {}", label_, ok.error().message);
      BackOffAtLeast(options_.reconnectMax);  // a misconfigured renderer: retry slowly
      Drop(ok.error().message);
      return;
    }
    {
      std::lock_guard lock(mutex_);
      if (state_ != State::kHandshaking) return;
      state_ = State::kReady;
      connectFailures_ = 0;
      peerName_ = Printable(w.server_name());
    }
    log->info("renderer {} ('{}', {} threads) ready", label_, Printable(w.server_name()), w.worker_threads());
    events_.onReady(*this, w);
    return;
  }
  if (envelope.has_error() && envelope.error().code() == wire::ERROR_CODE_AUTH_FAILED) {
    // Permanent until an operator changes a token or TLS flag: said at
    // error level, retried only every reconnectMax.
    log->error("renderer {} refused this SMA (AUTH_FAILED): {} (check --renderer-auth-token-file and the renderer's "
               "--auth-token-file); retrying every {} ms",
               label_, Printable(envelope.error().message(), 256), options_.reconnectMax.count());
    BackOffAtLeast(options_.reconnectMax);
    return;
  }
  events_.onMessage(*this, std::move(envelope));
}

void RendererLink::OnClosed(const std::string& reason) {
  bool wasReady = false;
  {
    std::lock_guard lock(mutex_);
    wasReady = state_ == State::kReady;
    connection_.reset();
    if (state_ != State::kRemoved) ScheduleReconnectLocked();
  }
  events_.onClosed(*this, reason, wasReady);
}

void RendererLink::ScheduleReconnectLocked() {
  state_ = State::kWaiting;
  timer_.expires_after(backoff_);
  backoff_ = std::min(options_.reconnectMax, std::max(options_.reconnectMin, backoff_ * 2));
  timer_.async_wait([self = shared_from_this()](const error_code& ec) {
    if (!ec) self->Connect();
  });
}

bool RendererLink::Send(std::shared_ptr<const std::string> frame) {
  std::shared_ptr<net::Connection> connection;
  {
    std::lock_guard lock(mutex_);
    if (state_ != State::kReady) return false;
    connection = connection_;
  }
  return connection && connection->SendFrame(std::move(frame));
}

void RendererLink::Drop(const std::string& reason) {
  std::shared_ptr<net::Connection> connection;
  {
    std::lock_guard lock(mutex_);
    connection = connection_;
  }
  if (connection) connection->Close(reason);  // OnClosed follows, and reconnects
}

void RendererLink::Remove(const std::string& reason) {
  std::shared_ptr<net::Connection> connection;
  {
    std::lock_guard lock(mutex_);
    state_ = State::kRemoved;
    // Let go of the connection now: its callbacks hold this link, so if the
    // I/O threads stop before its close completes (SIGTERM), the two would
    // keep each other alive past the end (LeakSanitizer saw it).
    connection = std::move(connection_);
  }
  asio::post(io_, [self = shared_from_this()] {
    std::lock_guard lock(self->mutex_);
    self->timer_.cancel();
  });
  if (connection) connection->Close(reason);
}

void RendererLink::BackOffAtLeast(std::chrono::milliseconds wait) {
  std::lock_guard lock(mutex_);
  backoff_ = std::max(backoff_, wait);
}

void RendererLink::ResetBackOff() {
  std::lock_guard lock(mutex_);
  backoff_ = options_.reconnectMin;
}

std::chrono::milliseconds RendererLink::BackOff() const {
  std::lock_guard lock(mutex_);
  return backoff_;
}

bool RendererLink::Ready() const {
  std::lock_guard lock(mutex_);
  return state_ == State::kReady;
}

std::string RendererLink::PeerName() const {
  std::lock_guard lock(mutex_);
  return peerName_;
}

}  // namespace penumbra::sma

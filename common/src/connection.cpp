#include "penumbra/common/connection.h"

#include <sys/resource.h>

#include <algorithm>
#include <array>

#include <fmt/format.h>
#include <openssl/x509.h>

#include "penumbra/common/logging.h"
#include "penumbra/common/messages.h"

namespace penumbra::net {

namespace {
using Clock = std::chrono::steady_clock;
using boost::system::error_code;

constexpr size_t kReadChunkBytes = 64 * 1024;
constexpr size_t kMaxGatherFrames = 64;
constexpr auto kDrainGrace = std::chrono::seconds(2);

std::chrono::milliseconds TickInterval(const ConnectionOptions& o) {
  const auto shortest = std::min(o.heartbeatInterval, o.readTimeout);
  return std::clamp(shortest / 4, std::chrono::milliseconds(20), std::chrono::milliseconds(1000));
}
}  // namespace

std::shared_ptr<Connection> Connection::Create(Stream stream, ConnectionOptions options, std::string id) {
  return std::shared_ptr<Connection>(new Connection(std::move(stream), options, std::move(id)));
}

Connection::Connection(Stream stream, ConnectionOptions options, std::string id)
    : strand_(asio::make_strand(stream.Socket().get_executor())),
      stream_(std::move(stream)),
      tick_(strand_),
      options_(options),
      id_(std::move(id)),
      log_(Logger("net")),
      decoder_(options.maxFrameBytesBeforeHandshake > 0 ? std::min(options.maxFrameBytes, options.maxFrameBytesBeforeHandshake)
                                                        : options.maxFrameBytes),
      readBuffer_(kReadChunkBytes) {
  handshakeDone_ = options.handshakeTimeout.count() <= 0 && options.maxFrameBytesBeforeHandshake == 0;
  handshakeDeadline_ = std::chrono::steady_clock::now() + options.handshakeTimeout;
  error_code ec;
  stream_.Socket().set_option(tcp::no_delay(true), ec);  // small deltas and replies must not wait for Nagle
}

Connection::~Connection() = default;

void Connection::Start(MessageHandler onMessage, CloseHandler onClose) {
  asio::post(strand_, [self = shared_from_this(), onMessage = std::move(onMessage),
                           onClose = std::move(onClose)]() mutable {
    self->onMessage_ = std::move(onMessage);
    self->onClose_ = std::move(onClose);
    self->Begin();
  });
}

void Connection::StartOn(asio::strand<asio::any_io_executor> owner, size_t maxInbox, MessageHandler onMessage,
                         CloseHandler onClose) {
  // Set before the first post to the strand, read there and (the handler) on
  // the owner's strand only after it.
  owner_ = owner;
  maxInbox_ = std::max<size_t>(1, maxInbox);
  ownerOnMessage_ = std::make_shared<MessageHandler>(std::move(onMessage));
  asio::post(strand_, [self = shared_from_this(), owner, onClose = std::move(onClose)]() mutable {
    // The close is posted behind the messages already delivered; the
    // message handler is dropped there, on the owner's strand, after them.
    self->onClose_ = [self, owner, onClose = std::move(onClose)](const std::string& reason) mutable {
      asio::post(owner, [self, onClose = std::move(onClose), reason] {
        self->ownerOnMessage_.reset();
        onClose(reason);
      });
    };
    self->Begin();
  });
}

void Connection::Begin() {
  lastReceive_ = lastSend_ = Clock::now();
  if (closed_) {
    // Closed before it started: still report it, exactly once.
    if (auto handler = std::move(onClose_)) handler("closed before start");
    onMessage_ = nullptr;
    return;
  }
  DoRead();
  ArmTick();
}

void Connection::Deliver(wire::Envelope&& envelope) {
  if (!owner_) {
    if (onMessage_) onMessage_(std::move(envelope));
    return;
  }
  ++inbox_;
  asio::post(*owner_, [self = shared_from_this(), envelope = std::move(envelope)]() mutable {
    if (!self->closed_ && self->ownerOnMessage_) (*self->ownerOnMessage_)(std::move(envelope));
    asio::post(self->strand_, [self] { self->OnOwnerHandled(); });
  });
}

void Connection::OnOwnerHandled() {
  --inbox_;
  // Not reading while neither paused nor draining: stopped for the owner
  // (InboxFull). Its silence meanwhile was not the peer's: no timeout.
  // Frames already buffered are delivered before reading more.
  if (closed_ || reading_ || readPaused_ || draining_ || InboxFull()) return;
  lastReceive_ = Clock::now();
  OnRead(error_code(), 0);
}

bool Connection::Send(const wire::Envelope& envelope) {
  return SendFrame(std::make_shared<const std::string>(EncodeEnvelopeFrame(envelope)));
}

bool Connection::SendFrame(std::shared_ptr<const std::string> frame) {
  if (closed_) return false;
  const size_t size = frame->size();
  if (queuedBytes_.fetch_add(size) + size > options_.maxQueuedBytes) {
    queuedBytes_.fetch_sub(size);
    return false;
  }
  asio::post(strand_, [self = shared_from_this(), frame = std::move(frame)]() mutable {
    if (self->closed_ || self->draining_) {
      self->queuedBytes_.fetch_sub(frame->size());
      return;
    }
    self->writeQueue_.push_back(std::move(frame));
    if (!self->writing_) self->DoWrite();
  });
  return true;
}

void Connection::NotifyWhenQueuedAtMost(size_t bytes, std::function<void()> handler) {
  asio::post(strand_, [self = shared_from_this(), bytes, handler = std::move(handler)]() mutable {
    if (self->closed_) return;
    self->queuedAtMostBytes_ = bytes;
    self->onQueuedAtMost_ = std::move(handler);
    self->MaybeNotifyQueued();
  });
}

void Connection::MaybeNotifyQueued() {
  if (!onQueuedAtMost_ || queuedBytes_.load() > queuedAtMostBytes_) return;
  auto handler = std::move(onQueuedAtMost_);
  onQueuedAtMost_ = nullptr;
  if (owner_)
    asio::post(*owner_, std::move(handler));
  else
    handler();
}

void Connection::FailAndClose(const wire::Envelope& error, std::string reason) {
  auto frame = std::make_shared<const std::string>(EncodeEnvelopeFrame(error));
  asio::post(strand_, [self = shared_from_this(), frame = std::move(frame), reason = std::move(reason)]() mutable {
    if (self->closed_ || self->draining_) return;
    // The error goes out even over the queue limit: it is the last frame.
    self->queuedBytes_.fetch_add(frame->size());
    self->writeQueue_.push_back(std::move(frame));
    self->BeginDrain(std::move(reason));
  });
}

void Connection::CloseAfterFlush(std::string reason) {
  asio::post(strand_, [self = shared_from_this(), reason = std::move(reason)]() mutable {
    if (self->closed_ || self->draining_) return;
    self->BeginDrain(std::move(reason));
  });
}

void Connection::Close(std::string reason) {
  asio::post(strand_, [self = shared_from_this(), reason = std::move(reason)] { self->DoClose(reason); });
}

void Connection::SetReadPaused(bool paused) {
  asio::post(strand_, [self = shared_from_this(), paused] {
    if (self->readPaused_ == paused) return;
    self->readPaused_ = paused;
    if (!paused && !self->closed_) {
      self->lastReceive_ = Clock::now();
      // Frames may already be buffered: deliver them before reading more.
      self->OnRead(error_code(), 0);
    }
  });
}

void Connection::BeginDrain(std::string reason) {
  draining_ = true;
  drainReason_ = std::move(reason);
  drainDeadline_ = Clock::now() + kDrainGrace;
  error_code ec;
  // Stop taking input; the peer still gets what we have queued.
  stream_.Socket().shutdown(tcp::socket::shutdown_receive, ec);
  if (!writing_) {
    if (writeQueue_.empty())
      DoClose(drainReason_);
    else
      DoWrite();
  }
}

void Connection::DoRead() {
  if (closed_ || reading_ || readPaused_ || draining_ || InboxFull()) return;
  reading_ = true;
  stream_.AsyncReadSome(asio::buffer(readBuffer_),
                        asio::bind_executor(strand_, [self = shared_from_this()](const error_code& ec, size_t n) {
                          self->reading_ = false;
                          self->OnRead(ec, n);
                        }));
}

void Connection::OnRead(const error_code& ec, size_t n) {
  if (closed_) return;
  if (ec) {
    if (draining_) return;  // we shut the receive side down ourselves
    // A TLS peer that closes without close_notify reads as stream_truncated.
    const bool closedByPeer = ec == asio::error::eof || ec == asio::ssl::error::stream_truncated;
    DoClose(closedByPeer ? std::string("peer closed the connection") : ec.message());
    return;
  }
  if (n > 0 && bytesReceived_ == 0 && !handshakeDone_ && !stream_.IsTls() &&
      LooksLikeTlsClientHello(reinterpret_cast<const unsigned char*>(readBuffer_.data()), n)) {
    // A TLS client at a plain server: say so here (the peer, waiting for a
    // TLS answer, cannot read a frame).
    const std::string why = "the peer opened a TLS handshake, but this server listens in plain TCP "
                            "(give it --tls-cert and --tls-key, or connect without TLS)";
    log_->warn("{}: {}", id_, why);
    FailAndClose(MakeError(0, wire::ERROR_CODE_AUTH_FAILED, why, true), why);
    return;
  }
  if (n > 0) {
    bytesReceived_ += n;
    lastReceive_ = Clock::now();
    decoder_.Feed(readBuffer_.data(), n);
  }
  while (!closed_ && !draining_ && !readPaused_ && !InboxFull()) {
    auto next = decoder_.Next();
    if (!next) {
      log_->warn("{}: {}", id_, next.error().message);
      FailAndClose(MakeError(0, wire::ERROR_CODE_FRAME_TOO_LARGE, next.error().message, true),
                   next.error().message);
      return;
    }
    if (!next->has_value()) break;
    auto envelope = DecodeEnvelope(**next);
    if (!envelope) {
      log_->warn("{}: {}", id_, envelope.error().message);
      FailAndClose(MakeError(0, wire::ERROR_CODE_BAD_FRAME, envelope.error().message, true),
                   envelope.error().message);
      return;
    }
    if (envelope->has_heartbeat()) continue;
    Deliver(std::move(*envelope));
  }
  DoRead();
}

void Connection::DoWrite() {
  if (closed_ || writeQueue_.empty()) return;
  writing_ = true;
  std::vector<asio::const_buffer> buffers;
  const size_t count = std::min(writeQueue_.size(), kMaxGatherFrames);
  buffers.reserve(count);
  for (size_t i = 0; i < count; ++i) buffers.emplace_back(asio::buffer(*writeQueue_[i]));
  stream_.AsyncWrite(buffers,
                     asio::bind_executor(strand_, [self = shared_from_this(), count](const error_code& ec, size_t n) {
                       self->writing_ = false;
                       if (self->closed_) return;
                       if (ec) {
                         self->DoClose(fmt::format("write failed: {}", ec.message()));
                         return;
                       }
                       self->bytesSent_ += n;
                       self->lastSend_ = Clock::now();
                       for (size_t i = 0; i < count; ++i) {
                         self->queuedBytes_.fetch_sub(self->writeQueue_.front()->size());
                         self->writeQueue_.pop_front();
                       }
                       self->MaybeNotifyQueued();
                       if (!self->writeQueue_.empty())
                         self->DoWrite();
                       else if (self->draining_)
                         self->DoClose(self->drainReason_);
                     }));
}

void Connection::ArmTick() {
  if (closed_) return;
  tick_.expires_after(TickInterval(options_));
  tick_.async_wait(asio::bind_executor(strand_, [self = shared_from_this()](const error_code& ec) {
    if (!ec) self->OnTick();
  }));
}

void Connection::MarkHandshakeDone() {
  const auto mark = [this] {
    handshakeDone_ = true;
    decoder_.SetMaxFrameBytes(options_.maxFrameBytes);
  };
  // On the owner's strand: the strand runs it before it hears that the Hello
  // was handled (OnOwnerHandled, posted after the handler returns), and no
  // frame is read in between (one message at a time before the handshake).
  if (owner_)
    asio::post(strand_, [self = shared_from_this(), mark] { mark(); });
  else
    mark();
}

void Connection::OnTick() {
  if (closed_) return;
  const auto now = Clock::now();
  if (!handshakeDone_ && !draining_ && options_.handshakeTimeout.count() > 0 && now > handshakeDeadline_) {
    const std::string why = fmt::format("no handshake within {} ms", options_.handshakeTimeout.count());
    log_->warn("{}: {}", id_, why);
    FailAndClose(MakeError(0, wire::ERROR_CODE_TIMEOUT, why, true), why);
  } else if (draining_) {
    if (now >= drainDeadline_) {
      DoClose(drainReason_ + " (flush timed out)");
      return;
    }
  } else if (!readPaused_ && !InboxFull() && now - lastReceive_ > options_.readTimeout) {
    const auto ms = std::chrono::duration_cast<std::chrono::milliseconds>(now - lastReceive_).count();
    const std::string why = fmt::format("peer silent for {} ms (read timeout {} ms)", ms, options_.readTimeout.count());
    log_->warn("{}: {}", id_, why);
    FailAndClose(MakeError(0, wire::ERROR_CODE_TIMEOUT, why, true), why);
  } else if (now - lastSend_ >= options_.heartbeatInterval && writeQueue_.empty() && !writing_) {
    lastSend_ = now;
    auto frame = std::make_shared<const std::string>(EncodeEnvelopeFrame(MakeHeartbeat()));
    queuedBytes_.fetch_add(frame->size());
    writeQueue_.push_back(std::move(frame));
    DoWrite();
  }
  ArmTick();
}

void Connection::DoClose(const std::string& reason) {
  if (closed_.exchange(true)) return;
  error_code ec;
  tick_.cancel();
  // No TLS close_notify: the peer reads the closed socket as its end either way.
  stream_.Socket().shutdown(tcp::socket::shutdown_both, ec);
  stream_.Socket().close(ec);
  for (const auto& frame : writeQueue_) queuedBytes_.fetch_sub(frame->size());
  writeQueue_.clear();
  log_->debug("{}: closed: {}", id_, reason);
  onMessage_ = nullptr;
  onQueuedAtMost_ = nullptr;
  // Handlers usually capture their owner; dropping them here breaks the
  // owner <-> connection cycle.
  if (auto handler = std::move(onClose_)) handler(reason);
}

// --- Listener ---------------------------------------------------------------

std::shared_ptr<Listener> Listener::Create(asio::io_context& io, AcceptHandler onAccept) {
  return std::shared_ptr<Listener>(new Listener(io, std::move(onAccept)));
}

Status CheckListenAddress(const HostPort& where) {
  asio::io_context io;
  error_code ec;
  tcp::resolver resolver(io);
  auto results = resolver.resolve(where.host, std::to_string(where.port), tcp::resolver::passive, ec);
  if (ec || results.empty())
    return Fail(fmt::format("cannot resolve listen address {}: {}", where.ToString(),
                            ec ? ec.message() : "no addresses"));
  return Status::Ok();
}

Listener::Listener(asio::io_context& io, AcceptHandler onAccept)
    : io_(io), acceptor_(io), onAccept_(std::move(onAccept)) {}

Expected<tcp::endpoint> Listener::Listen(const HostPort& where) {
  error_code ec;
  tcp::resolver resolver(io_);
  auto results = resolver.resolve(where.host, std::to_string(where.port), tcp::resolver::passive, ec);
  if (ec || results.empty())
    return Fail(fmt::format("cannot resolve listen address {}: {}", where.ToString(), ec.message()));
  const tcp::endpoint endpoint = results.begin()->endpoint();
  acceptor_.open(endpoint.protocol(), ec);
  if (!ec) acceptor_.set_option(asio::socket_base::reuse_address(true), ec);
  if (!ec) acceptor_.bind(endpoint, ec);
  if (!ec) acceptor_.listen(asio::socket_base::max_listen_connections, ec);
  if (ec) return Fail(fmt::format("cannot listen on {}: {}", where.ToString(), ec.message()));
  auto local = acceptor_.local_endpoint(ec);
  if (ec) return Fail(fmt::format("cannot read the bound address of {}: {}", where.ToString(), ec.message()));
  return local;
}

void Listener::Start() {
  asio::post(io_, [self = shared_from_this()] { self->DoAccept(); });
}

void Listener::Stop() {
  stopped_ = true;
  asio::post(io_, [self = shared_from_this()] {
    error_code ec;
    self->acceptor_.close(ec);
  });
}

void Listener::DoAccept() {
  if (stopped_) return;
  acceptor_.async_accept(asio::make_strand(io_), [self = shared_from_this()](const error_code& ec, tcp::socket socket) {
    if (self->stopped_ || ec == asio::error::operation_aborted) return;
    if (ec) {
      // Out of descriptors and similar: the pending connections wait in the
      // backlog while we pause, longer while it lasts; the log hears of it
      // once per throttle interval, not at every retry.
      self->acceptPause_ = std::clamp(self->acceptPause_ * 2, std::chrono::milliseconds(100), std::chrono::milliseconds(2000));
      if (const uint64_t failures = self->acceptFailures_.Note())
        Logger("net")->warn("accept failed: {} ({} time(s) since the last report); pausing accepts for {} ms",
                            ec.message(), failures, self->acceptPause_.count());
      auto timer = std::make_shared<asio::steady_timer>(self->io_, self->acceptPause_);
      timer->async_wait([self, timer](const error_code&) { self->DoAccept(); });
      return;
    }
    self->acceptPause_ = std::chrono::milliseconds(0);
    if (self->tls_)
      self->StartTls(std::move(socket));
    else
      self->onAccept_(Stream(std::move(socket)));
    self->DoAccept();
  });
}

// --- Limits -----------------------------------------------------------------

uint64_t LogThrottle::Note() {
  std::lock_guard lock(mutex_);
  ++held_;
  const auto now = Clock::now();
  if (reported_ && now - lastReport_ < interval_) return 0;
  reported_ = true;
  lastReport_ = now;
  return std::exchange(held_, 0);
}

void RefuseConnection(Stream stream, const wire::Envelope& error) {
  error_code ec;
  stream.Socket().non_blocking(true, ec);
  const std::string frame = EncodeEnvelopeFrame(error);
  stream.WriteNow(asio::buffer(frame), ec);  // non-blocking: what does not fit now is dropped
  // Closing a socket with unread input sends a reset, which may destroy the
  // error at the peer before it is read: take in what has arrived (a Hello,
  // usually) first. Bounded: a peer cannot keep us here.
  std::array<char, 4096> sink;
  for (int i = 0; i < 16 && !ec; ++i) stream.ReadSomeNow(asio::buffer(sink), ec);
  stream.Socket().shutdown(tcp::socket::shutdown_both, ec);
  stream.Socket().close(ec);
}

size_t FitConnectionsToDescriptorLimit(size_t connections, size_t headroom) {
  rlimit limit{};
  if (getrlimit(RLIMIT_NOFILE, &limit) != 0) return connections;
  const rlim_t wanted = rlim_t(connections + headroom);
  if (limit.rlim_cur != RLIM_INFINITY && limit.rlim_cur < wanted) {
    rlimit raised = limit;
    raised.rlim_cur = limit.rlim_max == RLIM_INFINITY ? wanted : std::min(wanted, limit.rlim_max);
    if (setrlimit(RLIMIT_NOFILE, &raised) == 0) limit = raised;
  }
  if (limit.rlim_cur == RLIM_INFINITY || limit.rlim_cur >= wanted) return connections;
  return limit.rlim_cur > headroom ? size_t(limit.rlim_cur - headroom) : 1;
}

void Listener::SetTls(std::shared_ptr<ssl::context> context, std::chrono::milliseconds handshakeTimeout) {
  tls_ = std::move(context);
  tlsHandshakeTimeout_ = handshakeTimeout;
}

namespace {
// One accepted socket on its way to a TLS stream. Everything runs on the
// socket's strand (the timer and the stream share its executor).
struct PendingTlsAccept {
  PendingTlsAccept(tcp::socket s, ssl::context& context)
      : peer(PeerAddress(s)), timer(s.get_executor()), stream(std::make_unique<TlsStream>(std::move(s), context)) {}
  std::string peer;
  asio::steady_timer timer;
  std::unique_ptr<TlsStream> stream;
  std::array<unsigned char, 3> first{};
  bool timedOut = false;
};

// Reads and drops what a refused plain peer still sends until it closes (or
// the handshake deadline closes the socket): closing with unread bytes would
// reset the connection and could destroy the error reply before the peer
// reads it.
void DiscardUntilClosed(const std::shared_ptr<PendingTlsAccept>& pending) {
  auto scratch = std::make_shared<std::array<char, 4096>>();
  pending->stream->next_layer().async_read_some(asio::buffer(*scratch), [pending, scratch](const error_code& ec, size_t) {
    if (!ec) return DiscardUntilClosed(pending);
    pending->timer.cancel();
    error_code ignored;
    pending->stream->next_layer().close(ignored);
  });
}
}  // namespace

void Listener::StartTls(tcp::socket socket) {
  auto pending = std::make_shared<PendingTlsAccept>(std::move(socket), *tls_);
  const auto timeout = tlsHandshakeTimeout_;
  pending->timer.expires_after(timeout);
  pending->timer.async_wait([pending](const error_code& ec) {
    if (ec) return;
    // Closing the socket aborts whichever step is pending.
    pending->timedOut = true;
    error_code ignored;
    pending->stream->next_layer().close(ignored);
  });
  auto failed = [pending, timeout](const std::string& what) {
    pending->timer.cancel();
    if (pending->timedOut)
      Logger("net")->warn("{}: TLS handshake not completed within {} ms; dropped", pending->peer, timeout.count());
    else
      Logger("net")->warn("{}: TLS handshake failed: {}", pending->peer, what);
  };
  // The first bytes tell a TLS ClientHello from a plain Penumbra frame; a
  // plain peer is told, in plain, that TLS is required.
  asio::async_read(
      pending->stream->next_layer(), asio::buffer(pending->first),
      [self = shared_from_this(), pending, failed](const error_code& ec, size_t) {
        if (ec) return failed(ec == asio::error::eof ? std::string("peer closed the connection") : ec.message());
        if (!LooksLikeTlsClientHello(pending->first.data(), pending->first.size())) {
          // Not `failed`: the deadline keeps bounding the goodbye below.
          Logger("net")->warn("{}: TLS handshake failed: the peer speaks plain TCP; this server requires TLS",
                              pending->peer);
          auto frame = std::make_shared<const std::string>(EncodeEnvelopeFrame(
              MakeError(0, wire::ERROR_CODE_AUTH_FAILED,
                        "this server accepts TLS connections only: connect with TLS (--tls-ca on the connecting side)",
                        true)));
          asio::async_write(pending->stream->next_layer(), asio::buffer(*frame),
                            [pending, frame](const error_code& writeEc, size_t) {
                              error_code ignored;
                              pending->stream->next_layer().shutdown(tcp::socket::shutdown_send, ignored);
                              if (!writeEc) return DiscardUntilClosed(pending);
                              pending->stream->next_layer().close(ignored);
                            });
          return;
        }
        pending->stream->async_handshake(ssl::stream_base::server, asio::buffer(pending->first),
                                         [self, pending, failed](const error_code& handshakeEc, size_t) {
                                           if (handshakeEc) return failed(DescribeTlsFailure(handshakeEc, *pending->stream));
                                           pending->timer.cancel();
                                           if (self->stopped_) return;
                                           self->onAccept_(Stream(std::move(pending->stream)));
                                         });
      });
}

// --- Client-side helpers ----------------------------------------------------

Expected<std::vector<tcp::endpoint>> ResolveAll(asio::io_context& io, const HostPort& where) {
  error_code ec;
  tcp::resolver resolver(io);
  auto results = resolver.resolve(where.host, std::to_string(where.port), ec);
  if (ec) return Fail(fmt::format("cannot resolve {}: {}", where.ToString(), ec.message()));
  std::vector<tcp::endpoint> endpoints;
  for (const auto& r : results)
    if (std::find(endpoints.begin(), endpoints.end(), r.endpoint()) == endpoints.end())
      endpoints.push_back(r.endpoint());
  if (endpoints.empty()) return Fail(fmt::format("{} resolves to no address", where.ToString()));
  return endpoints;
}

void AsyncConnect(asio::io_context& io, const tcp::endpoint& endpoint, std::chrono::milliseconds timeout,
                  std::function<void(const error_code&, tcp::socket)> handler) {
  struct State {
    explicit State(asio::io_context& ctx) : socket(asio::make_strand(ctx)), timer(socket.get_executor()) {}
    tcp::socket socket;
    asio::steady_timer timer;
    bool done = false;
    std::function<void(const error_code&, tcp::socket)> handler;
  };
  auto state = std::make_shared<State>(io);
  state->handler = std::move(handler);
  state->timer.expires_after(timeout);
  state->timer.async_wait([state](const error_code& ec) {
    if (ec || state->done) return;
    error_code ignored;
    state->socket.cancel(ignored);
    state->socket.close(ignored);
  });
  state->socket.async_connect(endpoint, [state](const error_code& ec) {
    state->done = true;
    state->timer.cancel();
    if (ec && !state->socket.is_open())
      state->handler(asio::error::timed_out, std::move(state->socket));
    else
      state->handler(ec, std::move(state->socket));
  });
}

void AsyncConnectStream(asio::io_context& io, const tcp::endpoint& endpoint, const TlsClientTarget& tls,
                        std::chrono::milliseconds timeout, std::function<void(Expected<Stream>)> handler) {
  // One deadline for the connection and the handshake; everything runs on
  // the socket's strand.
  struct State {
    explicit State(asio::io_context& ctx) : socket(asio::make_strand(ctx)), timer(socket.get_executor()) {}
    tcp::socket socket;
    std::unique_ptr<TlsStream> stream;  // once connected, with TLS
    asio::steady_timer timer;
    bool timedOut = false;
    std::function<void(Expected<Stream>)> handler;
    tcp::socket& Socket() { return stream ? stream->next_layer() : socket; }
  };
  auto state = std::make_shared<State>(io);
  state->handler = std::move(handler);
  state->timer.expires_after(timeout);
  state->timer.async_wait([state](const error_code& ec) {
    if (ec) return;
    state->timedOut = true;
    error_code ignored;
    state->Socket().close(ignored);
  });
  state->socket.async_connect(endpoint, [state, tls, timeout](const error_code& ec) {
    if (ec) {
      state->timer.cancel();
      return state->handler(Fail(state->timedOut ? fmt::format("no connection within {} ms", timeout.count())
                                                 : ec.message()));
    }
    if (!tls.context) {
      state->timer.cancel();
      return state->handler(Stream(std::move(state->socket)));
    }
    state->stream = std::make_unique<TlsStream>(std::move(state->socket), *tls.context);
    // The certificate must name the host connected to; SNI lets a server
    // behind one address pick the matching certificate.
    state->stream->set_verify_callback(
        [check = ssl::host_name_verification(tls.hostName)](bool preverified, ssl::verify_context& context) mutable {
          if (!preverified) return false;  // the chain failed: OpenSSL's error says why
          if (check(preverified, context)) return true;
          // Recorded so that the failure reads "hostname mismatch", not a bare "verify failed".
          X509_STORE_CTX_set_error(context.native_handle(), X509_V_ERR_HOSTNAME_MISMATCH);
          return false;
        });
    error_code addressEc;
    asio::ip::make_address(tls.hostName, addressEc);
    if (addressEc) SSL_set_tlsext_host_name(state->stream->native_handle(), tls.hostName.c_str());
    state->stream->async_handshake(ssl::stream_base::client, [state, timeout](const error_code& handshakeEc) {
      state->timer.cancel();
      if (state->timedOut)
        return state->handler(Fail(fmt::format("TLS handshake not completed within {} ms", timeout.count())));
      if (handshakeEc) {
        // A refused certificate explains itself; anything else is most often a server without TLS.
        const bool certificateRefused = SSL_get_verify_result(state->stream->native_handle()) != X509_V_OK;
        return state->handler(Error{fmt::format("TLS handshake failed: {}{}", DescribeTlsFailure(handshakeEc, *state->stream),
                                                certificateRefused ? "" : " (does the server listen with TLS, --tls-cert?)"),
                                    certificateRefused});
      }
      state->handler(Stream(std::move(state->stream)));
    });
  });
}

std::string PeerAddress(const tcp::socket& socket) {
  error_code ec;
  const auto endpoint = socket.remote_endpoint(ec);
  if (ec) return "?";
  return endpoint.address().is_v6() ? fmt::format("[{}]:{}", endpoint.address().to_string(), endpoint.port())
                                    : fmt::format("{}:{}", endpoint.address().to_string(), endpoint.port());
}

}  // namespace penumbra::net

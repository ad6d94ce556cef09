#pragma once
// A framed connection carrying wire::Envelopes (Boost.Beast/Asio style)
// over a net::Stream -- plain TCP, or TLS once its handshake is done (tls.h):
// one strand per connection, every handler runs on it; one write queue with a
// byte limit; a size limit on every frame; a read timeout; heartbeats when
// idle. Protocol logic (handshake, requests) belongs to the owner, which
// receives decoded envelopes through a handler.
//
// Threads: Send, Close, FailAndClose, CloseAfterFlush and SetReadPaused may be
// called from any thread, including from inside a handler and while the
// caller holds its own locks: they never run a handler before returning
// (they post to the strand). The handlers run on the connection's strand,
// never concurrently with each other. The owner must not block in a handler.
// An owner whose handlers do real work (the SMA's sessions plan and encode
// deltas) starts the connection with StartOn: its handlers then run on the
// owner's own strand, on the owner's threads, and the I/O thread only reads,
// decodes and writes frames.

#include <atomic>
#include <chrono>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "penumbra/common/asio.h"
#include "penumbra/common/connection_options.h"
#include "penumbra/common/endpoint.h"
#include "penumbra/common/expected.h"
#include "penumbra/common/framing.h"
#include "penumbra/common/tls.h"
#include "penumbra/wire.pb.h"

namespace spdlog {
class logger;
}

namespace penumbra::net {

class Connection : public std::enable_shared_from_this<Connection> {
 public:
  using MessageHandler = std::function<void(wire::Envelope&&)>;
  /// Called exactly once, with why the connection ended.
  using CloseHandler = std::function<void(const std::string& reason)>;

  /// `id` names the connection in every log line ("sma#3 127.0.0.1:51234").
  static std::shared_ptr<Connection> Create(Stream stream, ConnectionOptions options, std::string id);
  static std::shared_ptr<Connection> Create(tcp::socket socket, ConnectionOptions options, std::string id) {
    return Create(Stream(std::move(socket)), options, std::move(id));
  }
  ~Connection();

  /// Begins reading. Heartbeats are answered here and not passed on.
  void Start(MessageHandler onMessage, CloseHandler onClose);
  /// Same, but every handler (messages, close, NotifyWhenQueuedAtMost) runs
  /// on `owner` -- a strand of the owner's threads, not an I/O thread -- in
  /// the order the connection produced them. At most `maxInbox` messages wait
  /// for the owner: beyond that no frame is read (and the read timeout is
  /// suspended) until it catches up, so a peer that sends faster than its
  /// messages are handled fills its socket buffer, not our memory. Before
  /// the handshake one message at a time is delivered, so that the frame
  /// after a Hello is read under the limit MarkHandshakeDone sets.
  /// The connection keeps a copy of `owner`: the owner's execution context
  /// must outlive the connection's (declare it first), and the owner's
  /// queue must be run empty (joined) before the connection's context goes.
  void StartOn(asio::strand<asio::any_io_executor> owner, size_t maxInbox, MessageHandler onMessage,
               CloseHandler onClose);

  /// Queues an envelope. Returns false (and drops it) when the connection is
  /// closing or the queue would exceed maxQueuedBytes. Thread-safe.
  bool Send(const wire::Envelope& envelope);
  /// Same, for an already encoded frame (EncodeEnvelopeFrame), so one
  /// encoding can go to many connections.
  bool SendFrame(std::shared_ptr<const std::string> frame);

  /// Sends `error` (its fatal flag should be set), stops reading, and closes
  /// once the write queue has drained (or after a short grace period).
  void FailAndClose(const wire::Envelope& error, std::string reason);
  /// Stops reading and closes once queued writes are sent.
  void CloseAfterFlush(std::string reason);
  /// Closes now; queued writes are dropped. Thread-safe, idempotent.
  void Close(std::string reason);

  /// The peer has completed its handshake: frames up to maxFrameBytes from
  /// now on, and no handshake deadline. Call on the strand (from the
  /// message handler), so that the next frame is read with the new limit.
  void MarkHandshakeDone();

  /// Backpressure: while paused no reads are issued and the read timeout is
  /// suspended. Thread-safe.
  void SetReadPaused(bool paused);

  /// Calls `handler` once, on the strand, as soon as at most `bytes` are
  /// queued (at once -- posted -- if that is so already): a sender held back
  /// by its own soft limit resumes when the peer has read, without polling.
  /// One handler at a time (a second call replaces the first); dropped
  /// unrun when the connection closes. Thread-safe.
  void NotifyWhenQueuedAtMost(size_t bytes, std::function<void()> handler);

  bool IsOpen() const { return !closed_.load(); }
  size_t QueuedBytes() const { return queuedBytes_.load(); }
  uint64_t BytesSent() const { return bytesSent_.load(); }
  uint64_t BytesReceived() const { return bytesReceived_.load(); }
  const std::string& Id() const { return id_; }
  /// The strand every handler runs on; post here to touch owner state that
  /// handlers also touch.
  const asio::strand<asio::any_io_executor>& Strand() const { return strand_; }

 private:
  Connection(Stream stream, ConnectionOptions options, std::string id);

  void DoRead();
  void OnRead(const boost::system::error_code& ec, size_t n);
  void Begin();  // on the strand: the first read and tick
  // StartOn: no more messages are delivered or read while this many wait.
  bool InboxFull() const { return owner_ && inbox_ >= (handshakeDone_ ? maxInbox_ : 1); }
  void Deliver(wire::Envelope&& envelope);
  void OnOwnerHandled();  // on the strand: the owner handled one message
  void DoWrite();
  void OnWrite(const boost::system::error_code& ec, size_t n);
  void ArmTick();
  void OnTick();
  void DoClose(const std::string& reason);
  void BeginDrain(std::string reason);

  asio::strand<asio::any_io_executor> strand_;
  Stream stream_;
  asio::steady_timer tick_;
  ConnectionOptions options_;
  std::string id_;
  bool handshakeDone_ = false;  // strand
  std::chrono::steady_clock::time_point handshakeDeadline_;
  std::shared_ptr<spdlog::logger> log_;

  // Strand-owned state.
  FrameDecoder decoder_;
  std::vector<char> readBuffer_;
  std::deque<std::shared_ptr<const std::string>> writeQueue_;
  bool writing_ = false;
  bool reading_ = false;
  bool readPaused_ = false;
  bool draining_ = false;  // closing once the queue is empty
  std::string drainReason_;
  std::chrono::steady_clock::time_point lastReceive_;
  std::chrono::steady_clock::time_point lastSend_;
  std::chrono::steady_clock::time_point drainDeadline_;
  MessageHandler onMessage_;
  CloseHandler onClose_;
  std::function<void()> onQueuedAtMost_;  // NotifyWhenQueuedAtMost
  size_t queuedAtMostBytes_ = 0;
  void MaybeNotifyQueued();
  // StartOn: the owner's strand, and the messages posted to it that it has
  // not handled yet (strand-owned). ownerOnMessage_ is set before the first
  // delivery and cleared on the owner's strand after the last.
  std::optional<asio::strand<asio::any_io_executor>> owner_;
  size_t maxInbox_ = 0;
  size_t inbox_ = 0;
  std::shared_ptr<MessageHandler> ownerOnMessage_;

  // Shared with other threads.
  std::atomic<bool> closed_{false};
  std::atomic<size_t> queuedBytes_{0};
  std::atomic<uint64_t> bytesSent_{0};
  std::atomic<uint64_t> bytesReceived_{0};
};

/// Says at most once per interval that something keeps happening (an accept
/// failing, connections refused over a cap), with how often it happened, so
/// that a flood costs one log line per interval. Thread-safe.
class LogThrottle {
 public:
  explicit LogThrottle(std::chrono::milliseconds interval) : interval_(interval) {}
  /// Counts one occurrence. Returns how many occurrences to report now (this
  /// one and those held back since the last report), or 0: stay quiet.
  uint64_t Note();

 private:
  std::mutex mutex_;
  std::chrono::milliseconds interval_;
  std::chrono::steady_clock::time_point lastReport_{};
  bool reported_ = false;
  uint64_t held_ = 0;
};

/// Refuses a just-accepted connection that a server cannot take: sends
/// `error` (fatal) without blocking -- a new socket's send buffer holds it --
/// and closes at once, so the refusal costs no descriptor, strand or timer
/// beyond this call; on a TLS stream the error goes through TLS (the
/// handshake is done). Call on any thread.
void RefuseConnection(Stream stream, const wire::Envelope& error);

/// Makes room for `connections` peer connections plus `headroom` other
/// descriptors (files, outgoing links): raises the soft RLIMIT_NOFILE toward
/// the hard limit when it is lower. Returns how many connections fit, which
/// is `connections` unless even the hard limit is too low.
size_t FitConnectionsToDescriptorLimit(size_t connections, size_t headroom);
/// Resolves a listen address the way Listener::Listen does, without binding,
/// so that a main can report an unresolvable --listen host before spending
/// seconds (or minutes) loading a scene. Blocks for the resolver.
Status CheckListenAddress(const HostPort& where);

/// Accepts TCP connections; each accepted socket gets its own strand.
/// When accepting fails (out of descriptors: EMFILE, ENFILE) it pauses, from
/// 100 ms doubling to 2 s while the failures last, and logs at most one line
/// per 10 s, so that neither the CPU nor the log is flooded.
/// With TLS (SetTls), each accepted socket first completes a TLS handshake
/// on its strand within the handshake timeout -- a peer that does not is
/// dropped and the failure logged -- and only then reaches the handler; a
/// peer that speaks plain Penumbra to a TLS listener gets a plain fatal
/// ErrorReply (AUTH_FAILED, "TLS required") and is closed.
/// Start/Stop are thread-safe.
class Listener : public std::enable_shared_from_this<Listener> {
 public:
  /// Runs on an I/O thread (the new stream's strand or the acceptor's).
  using AcceptHandler = std::function<void(Stream)>;

  static std::shared_ptr<Listener> Create(asio::io_context& io, AcceptHandler onAccept);

  /// Serves TLS with `context` (null: plain TCP, the default). Call before
  /// Start().
  void SetTls(std::shared_ptr<ssl::context> context, std::chrono::milliseconds handshakeTimeout);

  /// Resolves, binds and listens. Port 0 picks a free port; the returned
  /// endpoint says which.
  Expected<tcp::endpoint> Listen(const HostPort& where);
  void Start();
  void Stop();

 private:
  Listener(asio::io_context& io, AcceptHandler onAccept);
  void DoAccept();
  void StartTls(tcp::socket socket);

  asio::io_context& io_;
  std::shared_ptr<ssl::context> tls_;
  std::chrono::milliseconds tlsHandshakeTimeout_{10000};
  tcp::acceptor acceptor_;
  AcceptHandler onAccept_;
  std::atomic<bool> stopped_{false};
  std::chrono::milliseconds acceptPause_{0};  // io_context; grows while accepting fails
  LogThrottle acceptFailures_{std::chrono::seconds(10)};
};

/// Resolves `where` to every address it names (a DNS name behind which
/// several hosts stand yields them all). Blocking; call off the I/O threads.
Expected<std::vector<tcp::endpoint>> ResolveAll(asio::io_context& io, const HostPort& where);

/// Connects a socket (on its own strand executor) within `timeout`.
/// The handler runs on an io_context thread with an error or the socket.
void AsyncConnect(asio::io_context& io, const tcp::endpoint& endpoint, std::chrono::milliseconds timeout,
                  std::function<void(const boost::system::error_code&, tcp::socket)> handler);

/// Connects, and when `tls` has a context completes a TLS handshake that
/// verifies the server's certificate against the context's CA and
/// `tls.hostName` -- connection and handshake together within `timeout`.
/// The handler runs on an io_context thread (the stream's strand) with the
/// stream or a message saying what failed (refused, timed out, which TLS
/// check failed). A server certificate refused by the CA or the host name
/// check is a `permanent` Error: the same server answers the same way
/// again (the client stops; the SMA's renderer links keep retrying, since
/// an operator may replace the renderer's certificate).
void AsyncConnectStream(asio::io_context& io, const tcp::endpoint& endpoint, const TlsClientTarget& tls,
                        std::chrono::milliseconds timeout, std::function<void(Expected<Stream>)> handler);

/// "host:port" of a socket's peer, or "?" when it has none.
std::string PeerAddress(const tcp::socket& socket);
inline std::string PeerAddress(const Stream& stream) { return PeerAddress(stream.Socket()); }

}  // namespace penumbra::net

#pragma once
// ServerSkeleton: what the renderer and the SMA do alike as servers -- the
// listener (TLS, the connection cap with its TOO_MANY_CONNECTIONS refusal,
// the accept back-off of net::Listener), the registry of sessions by id,
// SIGTERM/SIGINT, the periodic stats line, and the graceful shutdown: stop
// accepting, let the tier abandon its work, tell every peer SHUTTING_DOWN,
// and stop the io_context once they are closed or at the drain deadline
// (1 s by default) whatever a peer does.
//
// Threads: the tier owns the io_context and runs it (RunIo). Listen() is
// called before, from the thread that will run it. Accepting runs on I/O
// threads; the signals, the stats hook, the shutdown hook and the drain
// polling run on the control strand (Control()), so with several I/O
// threads they never run at once -- a tier's own server-wide timers are
// bound to it too, so that the shutdown hook may cancel them.
// Shutdown(), Draining(), Sessions(), SessionCount() and Remove() are
// thread-safe.
//
// A Session type needs: a constructor-like factory (given to the skeleton),
// `void Start()` (called once, outside the registry's lock), and
// `net::Connection& Connection()`. The session removes itself (Remove(id))
// when its connection closes.

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include "penumbra/common/connection.h"
#include "penumbra/common/endpoint.h"
#include "penumbra/common/expected.h"
#include "penumbra/common/logging.h"
#include "penumbra/common/tls.h"

namespace penumbra::net {

/// The words and sizes that tell the tiers' servers apart.
struct ServerRole {
  std::string service;  // what peers are told it is: "SMA" -> "SMA is shutting down"
  std::string peer;     // connection ids: "<peer>#<n> <address>" ("client#3 10.0.0.2:51000")
  std::string peers;    // the log's word for its peers: "listening for clients on ..."
  std::string logger;   // the named logger of its lines ("sma", "renderer")
  size_t reservedDescriptors = 64;  // descriptors kept for all but its connections
};

struct ServerSkeletonOptions {
  std::string name;  // the server's name in its log lines ("penumbra-sma")
  ServerRole role;
  HostPort listen{"127.0.0.1", 0};
  ConnectionOptions connection;
  /// TLS for every connection; null: plain TCP. The handshake must complete
  /// within connection.handshakeTimeout.
  std::shared_ptr<ssl::context> tls;
  bool tokenRequired = false;  // only said in the "listening" line
  /// Connections (counting those yet to say Hello) served at once; more are
  /// refused with TOO_MANY_CONNECTIONS and closed at once. Listen() lowers it
  /// to what the descriptor limit allows beside `role.reservedDescriptors`.
  size_t maxConnections = 64;
  std::chrono::milliseconds statsInterval{10000};
  /// Longest wait, on shutdown, for the peers to be told and closed.
  std::chrono::milliseconds drainTimeout{1000};

  /// From a tier's server options, which name their fields alike (listen,
  /// name, tls, authToken, maxConnections, statsInterval and, if it has one,
  /// drainTimeout); `connection` is the peers' connection options.
  template <class TierOptions>
  static ServerSkeletonOptions For(const TierOptions& tier, const ConnectionOptions& connection, ServerRole role) {
    ServerSkeletonOptions out{.name = tier.name,
                              .role = std::move(role),
                              .listen = tier.listen,
                              .connection = connection,
                              .tls = tier.tls,
                              .tokenRequired = !tier.authToken.empty(),
                              .maxConnections = tier.maxConnections,
                              .statsInterval = tier.statsInterval};
    if constexpr (requires { tier.drainTimeout; }) out.drainTimeout = tier.drainTimeout;
    return out;
  }
};

struct ServerHooks {
  /// I/O thread, every statsInterval: the tier's counter line. May be empty.
  std::function<void()> logStats;
  /// I/O thread, once, when shutdown begins (the listener is closed, no
  /// session is added any more), before every peer is told SHUTTING_DOWN:
  /// stop or abandon the tier's work. May be empty.
  std::function<void()> beginShutdown;
};

/// The non-template part; see ServerSkeleton.
class ServerSkeletonBase {
 public:
  ServerSkeletonBase(asio::io_context& io, ServerSkeletonOptions options, ServerHooks hooks);
  virtual ~ServerSkeletonBase();
  ServerSkeletonBase(const ServerSkeletonBase&) = delete;
  ServerSkeletonBase& operator=(const ServerSkeletonBase&) = delete;

  /// Fits the connection cap to the descriptor limit, binds (port 0: any free
  /// port) and returns the bound address. Call before RunIo().
  Expected<tcp::endpoint> Listen();
  /// Arms the signals, starts accepting and the stats timer, runs the
  /// io_context on the calling thread and `ioThreads - 1` more, and returns
  /// once shutdown has drained (or io_context stopped otherwise).
  void RunIo(int ioThreads = 1);
  /// Begins the graceful shutdown. Thread-safe; idempotent.
  void Shutdown();
  bool Draining() const { return draining_.load(); }
  /// The strand of the server-wide timers and the shutdown (see the file
  /// comment): bind a tier's own timer handlers to it
  /// (`asio::bind_executor(Control(), handler)`).
  const asio::strand<asio::io_context::executor_type>& Control() const { return control_; }
  /// The options as fitted by Listen() (maxConnections).
  const ServerSkeletonOptions& Options() const { return options_; }
  virtual size_t SessionCount() const = 0;

 protected:
  virtual void Accept(Stream stream) = 0;
  virtual void TellAndClose(const wire::Envelope& error, const std::string& reason) = 0;
  /// Accept's refusals: while draining, and at the connection cap.
  void RefuseDraining(Stream stream);
  void RefuseAtCap(Stream stream, const std::string& peer);
  std::shared_ptr<Connection> NewConnection(Stream stream, uint64_t id, const std::string& peer);

 private:
  void BeginShutdown();
  void PollDrain();
  void ArmStats();

  asio::io_context& io_;
  asio::strand<asio::io_context::executor_type> control_;
  ServerSkeletonOptions options_;
  ServerHooks hooks_;
  std::shared_ptr<spdlog::logger> log_;
  std::shared_ptr<Listener> listener_;
  asio::signal_set signals_;
  asio::steady_timer statsTimer_;
  asio::steady_timer drainTimer_;
  std::atomic<bool> draining_{false};
  std::chrono::steady_clock::time_point drainDeadline_;
  LogThrottle refusals_{std::chrono::seconds(10)};
};

/// The skeleton with its registry of `Session`s (see the file comment).
template <class Session>
class ServerSkeleton final : public ServerSkeletonBase {
 public:
  /// Makes the session of a new connection; called on an I/O thread under
  /// the registry's lock (so keep it to construction).
  using Factory = std::function<std::shared_ptr<Session>(std::shared_ptr<Connection> connection, uint64_t id)>;

  ServerSkeleton(asio::io_context& io, ServerSkeletonOptions options, ServerHooks hooks, Factory make)
      : ServerSkeletonBase(io, std::move(options), std::move(hooks)), make_(std::move(make)) {}

  std::vector<std::shared_ptr<Session>> Sessions() const {
    std::lock_guard lock(mutex_);
    std::vector<std::shared_ptr<Session>> out;
    out.reserve(sessions_.size());
    for (auto& [id, s] : sessions_) out.push_back(s);
    return out;
  }
  size_t SessionCount() const override {
    std::lock_guard lock(mutex_);
    return sessions_.size();
  }
  void Remove(uint64_t id) {
    std::lock_guard lock(mutex_);
    sessions_.erase(id);
  }

 private:
  void Accept(Stream stream) override {
    if (Draining()) return RefuseDraining(std::move(stream));
    const std::string peer = PeerAddress(stream);
    std::shared_ptr<Session> session;
    {
      std::lock_guard lock(mutex_);
      // Refused at once: idle or anonymous peers cannot exhaust descriptors,
      // and the peers already connected are served as before.
      if (sessions_.size() >= Options().maxConnections) return RefuseAtCap(std::move(stream), peer);
      const uint64_t id = nextId_++;
      session = make_(NewConnection(std::move(stream), id, peer), id);
      sessions_.emplace(id, session);
    }
    session->Start();
  }
  void TellAndClose(const wire::Envelope& error, const std::string& reason) override {
    for (auto& s : Sessions()) s->Connection().FailAndClose(error, reason);
  }

  Factory make_;
  mutable std::mutex mutex_;
  std::unordered_map<uint64_t, std::shared_ptr<Session>> sessions_;
  uint64_t nextId_ = 1;
};

}  // namespace penumbra::net

#pragma once
// RendererServer: accepts SMA connections and shades their ShadeRequests on a
// ShadingPool. Protocol: docs/protocol.md ("Renderer protocol").
//
// Threads and ownership:
//  * Run() runs the I/O loop (acceptor, every connection's strand, signal
//    handling, the stats timer) on the calling thread.
//  * The ShadingPool's workers shade; they hand finished parts to the
//    connection (Connection::Send is thread-safe) and post bookkeeping to the
//    session's strand.
//  * A session owns its connection and the ids of its batches in flight; the
//    server owns the sessions (by id), the listener and the pool.
// Shutdown (SIGTERM, SIGINT or Shutdown()): stop accepting, abandon every
// batch (queued chunks dropped, workers stop within a few dozen paths; the
// SMAs send the samples elsewhere), tell every SMA with a fatal
// SHUTTING_DOWN error, close, return from Run() -- within about a second.
// Connections beyond `maxConnections` are refused (TOO_MANY_CONNECTIONS).

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>

#include "penumbra/common/connection.h"
#include "penumbra/common/endpoint.h"
#include "penumbra/common/expected.h"
#include "penumbra/common/metrics.h"
#include "penumbra/renderer/shade_batch.h"
#include "penumbra/renderer/shading.h"

namespace penumbra {

struct RendererServerOptions {
  HostPort listen{"127.0.0.1", 0};
  std::string name = "penumbra-renderer";
  int workerThreads = 0;  // 0: one per hardware thread
  ShadeLimits limits;
  uint32_t maxBatchesInFlight = 64;  // per connection; more gets OVERLOADED
  net::ConnectionOptions connection{.handshakeTimeout = std::chrono::milliseconds(10000),
                                    .maxFrameBytesBeforeHandshake = 64 * 1024};
  std::chrono::milliseconds statsInterval{10000};  // periodic counters in the log
  /// Longest wait, on shutdown, for the SMAs to be sent SHUTTING_DOWN.
  std::chrono::milliseconds drainTimeout{1000};
  /// Connections (SMAs, and peers that have not said Hello yet) served at
  /// once; more are refused with TOO_MANY_CONNECTIONS and closed at once.
  size_t maxConnections = 64;
  /// Required of every SMA's Hello (constant-time comparison, never
  /// logged); empty: none required.
  std::string authToken;
  /// TLS for every connection (net::MakeTlsServerContext); null: plain TCP.
  /// The TLS handshake must complete within connection.handshakeTimeout.
  std::shared_ptr<net::ssl::context> tls;
};

class RendererServer {
 public:
  /// `shader` (and the scene behind it) must outlive the server.
  RendererServer(const Shader& shader, RendererServerOptions options);
  ~RendererServer();
  RendererServer(const RendererServer&) = delete;
  RendererServer& operator=(const RendererServer&) = delete;

  /// Binds the listening socket; returns the bound address (port 0 picks a
  /// free one). Call before Run().
  Expected<tcp::endpoint> Listen();

  /// Serves until SIGINT/SIGTERM or Shutdown(), then drains and returns.
  void Run();

  /// Begins the graceful shutdown. Thread-safe.
  void Shutdown();

  /// Writes the renderer's metric families (docs/metrics.md): StatsReply's
  /// server counters. Thread-safe; called by the --http endpoint's thread.
  void WriteMetrics(metrics::ExpositionWriter& out) const;
  /// Empty when ready (serving, not draining), else the reason. Thread-safe.
  std::string NotReadyReason() const;

 private:
  class Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace penumbra

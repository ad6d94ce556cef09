#pragma once
// SmaServer: the shading management agent as a network service. It owns the
// subdivision hierarchy and the sample cache (shared by every client), the
// renderer pool, and one session per client; see sma/README.md for the data
// flow and who owns what.
//
// Threads:
//  * I/O threads run the io_context: every client session and renderer
//    connection on its own strand, timers, signal handling.
//  * View workers trace visibility and map it onto the hierarchy, so a
//    client's view never waits behind another's.
//  * State lock (shared_mutex): the hierarchy and the cache. Visibility
//    mapping and delta planning hold it shared; storing samples and
//    refining hold it exclusively, briefly. Lock order: state lock before the
//    renderer pool's lock; never the other way round.

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "penumbra/common/connection.h"
#include "penumbra/common/endpoint.h"
#include "penumbra/common/expected.h"
#include "penumbra/common/scene.h"
#include "penumbra/sma/refinement.h"
#include "penumbra/sma/renderer_pool.h"

namespace penumbra::sma {

struct ToneMappingDefaults {
  float bias = 0.85f;                 // Drago et al. 2003
  float exposure = 1.0f;
  float maxDisplayLuminance = 100.0f;
};

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
  int ioThreads = 1;
  int viewThreads = 2;                 // visibility jobs in parallel (each also uses TBB inside)
  size_t clientSoftQueueBytes = size_t(4) << 20;  // beyond this, a client's deltas are coalesced
  uint32_t maxTrianglesPerDelta = 16384;          // larger changes go in several deltas
  uint64_t maxViewPixels = uint64_t(8192) * 4608;  // larger views are refused (visibility's time and memory)
  std::chrono::milliseconds refreshInterval{100}; // min time between re-mapping a view after new samples
  std::chrono::milliseconds statsInterval{10000};
  ToneMappingDefaults toneMapping;
  /// Improvement (SampleCache::Improve): once a view is shaded, its visible
  /// samples whose irradiance has a relative standard error above
  /// `improveTargetError` get further rounds of `pool.improvePaths` paths,
  /// averaged in and re-sent to every client holding them, until they reach
  /// it or `improveMaxPaths`; the view converges only then. 0 paths: off.
  float improveTargetError = 0.02f;
  uint32_t improveMaxPaths = 1024;
  uint32_t improveBatch = 4096;  // improvements in flight per session
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
  /// Thread-safe.
  void Shutdown();

  class Impl;

 private:
  explicit SmaServer(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace penumbra::sma

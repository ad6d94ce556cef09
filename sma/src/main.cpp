// penumbra-sma: the shading management agent. Loads the scene, connects to
// the renderers, and serves walkthrough clients until SIGTERM. See
// sma/README.md.

#include <chrono>
#include <cstdio>

#include <CLI/CLI.hpp>

#include "penumbra/common/connection.h"
#include "penumbra/common/version.h"
#include "penumbra/common/auth.h"
#include "penumbra/common/endpoint.h"
#include "penumbra/common/logging.h"
#include "penumbra/common/operator_http.h"
#include "penumbra/common/scene.h"
#include "penumbra/sma/server.h"

int main(int argc, char** argv) {
  using namespace penumbra;
  using namespace penumbra::sma;
  CLI::App app{"penumbra-sma: shading cache, visibility, refinement and deltas for Penumbra clients"};
  app.set_version_flag("--version", "penumbra-sma " + std::string(kVersion));
  SmaOptions options;
  std::string scenePath;
  std::string listen = "127.0.0.1:7200";
  std::vector<std::string> renderers;
  std::string portFile;
  std::string logLevel = "info";
  uint32_t maxFrameBytes = options.clientConnection.maxFrameBytes;
  int heartbeatMs = int(options.clientConnection.heartbeatInterval.count());
  int readTimeoutMs = int(options.clientConnection.readTimeout.count());
  int handshakeTimeoutMs = int(options.clientConnection.handshakeTimeout.count());
  int rendererTimeoutMs = int(options.pool.connection.readTimeout.count());
  int statsSeconds = 10;
  int resolveSeconds = int(options.pool.resolveInterval.count() / 1000);
  int batchTimeoutSeconds = int(options.pool.batchTimeout.count() / 1000);
  int quarantineSeconds = int(options.pool.quarantine.count() / 1000);

  app.add_option("--scene", scenePath, "Scene description (.json) or mesh file; must match the renderers'")->required();
  app.add_option("--listen", listen, "Address for clients, HOST:PORT (port 0: any free port)")->capture_default_str();
  app.add_option("--renderer", renderers,
                 "Renderer address HOST:PORT; repeat for several. A name resolving to several addresses "
                 "connects to each, and is re-resolved periodically")
      ->required();
  app.add_option("--paths", options.pool.pathsPerSample,
                 "Paths per sample asked of renderers for refinement (0: their --spp)")
      ->capture_default_str();
  app.add_option("--first-paths", options.pool.firstPaths,
                 "Paths per sample for a new view's first image (stage 1; 0: as --paths): few, so it comes soon")
      ->capture_default_str();
  app.add_option("--improve-paths", options.pool.improvePaths,
                 "Paths per improvement round of a displayed sample (0: no improvement)")
      ->check(CLI::Range(0u, 1u << 16))->capture_default_str();
  app.add_option("--improve-target-error", options.improveTargetError,
                 "Improve displayed samples until their relative standard error is below this")
      ->check(CLI::Range(0.0001f, 1.0f))->capture_default_str();
  app.add_option("--improve-max-paths", options.improveMaxPaths, "... or until they average this many paths")
      ->check(CLI::Range(1u, 1u << 24))->capture_default_str();
  app.add_option("--credits", options.pool.creditsPerRenderer, "Batches in flight per renderer")
      ->check(CLI::Range(1u, 1024u))->capture_default_str();
  app.add_option("--max-batch", options.pool.maxBatchSamples, "Largest batch sent to a renderer")
      ->check(CLI::Range(1u, 1u << 20))->capture_default_str();
  app.add_option("--batch-timeout", batchTimeoutSeconds, "Seconds a batch may stay unanswered before its renderer is dropped")
      ->check(CLI::Range(1, 86400))->capture_default_str();
  app.add_option("--renderer-quarantine", quarantineSeconds,
                 "Seconds a renderer that sent a malformed or impossible reply waits before it is reconnected")
      ->check(CLI::Range(1, 86400))->capture_default_str();
  app.add_option("--resolve-interval", resolveSeconds, "Seconds between re-resolving renderer names")
      ->check(CLI::Range(1, 86400))->capture_default_str();
  std::string criterion = std::string(CriterionName(options.refinement.criterion));
  int maxDepth = options.refinement.maxDepth;
  RefinementParams& refine = options.refinement;
  app.add_option("--criterion", criterion, "Refinement criterion: nld_os, nld_is, rnd, nld_os_rnd or none")
      ->capture_default_str();
  app.add_option("--s-req", refine.sReq, "S_req: normalised luminance difference above which to split")
      ->capture_default_str();
  app.add_option("--refine-batch", refine.batch, "R: leaves chosen per refinement step")->capture_default_str();
  app.add_option("--min-pixels", refine.minPixels, "Leaves covering fewer pixels are never split")->capture_default_str();
  app.add_option("--large-fraction", refine.largeFraction,
                 "NLD_OS: leaves covering more of the image than this are always split")
      ->capture_default_str();
  app.add_option("--probe-fraction", refine.probeFraction,
                 "NLD_OS: leaves covering more of the image than this are probed inside (1: never)")
      ->capture_default_str();
  app.add_option("--aspect-threshold", refine.aspectThreshold,
                 "Propagation: neighbours lower than this times the shared edge split 1->2")
      ->capture_default_str();
  auto* maxDepthAlias =
      app.add_option("--max-depth", maxDepth, "Deprecated alias of --max-refine-depth (the renderer's path length is "
                                              "its --max-bounces)");
  app.add_option("--pixel-fraction", refine.pixelFraction, "NLD_IS / RND budget as a fraction of the image's pixels")
      ->capture_default_str();
  app.add_option("--noise-z", refine.noiseZ,
                 "Luminance differences within this many standard errors count as noise (0: the paper's S)")
      ->capture_default_str();
  app.add_option("--io-threads", options.ioThreads, "Network threads")->check(CLI::Range(1, 64))->capture_default_str();
  app.add_option("--view-threads", options.viewThreads, "Visibility job threads")
      ->check(CLI::Range(1, 64))->capture_default_str();
  app.add_option("--max-frame-bytes", maxFrameBytes, "Largest frame accepted from a client")
      ->check(CLI::Range(1024u, 1u << 30))->capture_default_str();
  app.add_option("--heartbeat-ms", heartbeatMs, "Idle interval after which a heartbeat is sent")
      ->check(CLI::Range(10, 3600000))->capture_default_str();
  app.add_option("--max-view-pixels", options.maxViewPixels,
                 "Largest view (width x height) a client may ask for; visibility costs time and memory per pixel")
      ->check(CLI::Range(uint64_t(1), uint64_t(1) << 28))->capture_default_str();
  app.add_option("--handshake-timeout-ms", handshakeTimeoutMs,
                 "A peer that has not completed its Hello by then is dropped")
      ->check(CLI::Range(10, 3600000))->capture_default_str();
  app.add_option("--read-timeout-ms", readTimeoutMs, "Silence after which a peer is dropped")
      ->check(CLI::Range(10, 3600000))->capture_default_str();
  app.add_option("--renderer-read-timeout-ms", rendererTimeoutMs,
                 "Silence after which a renderer is dropped and its samples go to the others")
      ->check(CLI::Range(10, 3600000))->capture_default_str();
  app.add_option("--client-queue-bytes", options.clientSoftQueueBytes,
                 "Bytes queued to a client above which its deltas are held back and later sent as one")
      ->capture_default_str();
  app.add_option("--stats-interval", statsSeconds, "Seconds between counter lines in the log")
      ->check(CLI::Range(1, 86400))->capture_default_str();
  app.add_option("--exposure", options.toneMapping.exposure, "Default exposure clients apply before tone mapping")
      ->check(CLI::PositiveNumber)->capture_default_str();
  app.add_option("--name", options.name, "Name reported in handshakes and logs")->capture_default_str();
  app.add_option("--port-file", portFile, "Write the bound client port to this file once listening");
  app.add_option("--log-level", logLevel, "trace, debug, info, warn, error, critical or off")->capture_default_str();
  // Cache on disk (issue 12)
  app.add_option("--cache-dir", options.cacheDir,
                 "Keep the sample cache in this directory: restored at start when it holds a snapshot of this "
                 "scene, snapshotted periodically and at SIGTERM/SIGINT (see sma/README.md, \"Cache on disk\")");
  app.add_option_function<int>(
         "--cache-snapshot-interval",
         [&options](const int& seconds) { options.cacheSnapshotInterval = std::chrono::seconds(seconds); },
         "Seconds between cache snapshots (taken only when the cache changed): what a kill -9 can lose")
      ->check(CLI::Range(1, 86400))
      ->default_str(std::to_string(options.cacheSnapshotInterval.count() / 1000));
  // Operator HTTP endpoint (issue 16)
  std::string httpListen, httpPortFile;
  app.add_option("--http", httpListen,
                 "Serve /metrics (Prometheus), /healthz and /readyz on HOST:PORT (port 0: any free port); "
                 "ready once a renderer is connected");
  app.add_option("--http-port-file", httpPortFile, "Write the bound --http port to this file once listening");
  std::string logFormat = "text";
  app.add_option("--log-format", logFormat, "text, or json: one JSON object per log line")->capture_default_str();
  // Resource limits per client (issue 12)
  ClientRefinementLimits& clientLimits = options.clientRefinement;
  app.add_option("--visibility-budget-pixels", options.visibilityBudgetPixels,
                 "Pixels of all clients' views whose visibility the SMA holds at once (~24 bytes each); a view "
                 "that does not fit is refused with LIMIT_EXCEEDED")
      ->check(CLI::Range(uint64_t(1), uint64_t(1) << 34))->capture_default_str();
  app.add_option("--large-view-pixels", options.largeViewPixels,
                 "Views above this many pixels are traced, mapped and refined on one background thread, so they "
                 "never delay smaller views")
      ->check(CLI::Range(uint64_t(1), uint64_t(1) << 34))->capture_default_str();
  app.add_option("--client-min-s-req", clientLimits.minSReq, "Smallest S_req a client may ask for (SessionOptions)")
      ->check(CLI::Range(0.0f, 1.0f))->capture_default_str();
  app.add_option("--client-min-pixels", clientLimits.minMinPixels, "Smallest min_pixels a client may ask for")
      ->check(CLI::Range(0.0f, 1e9f))->capture_default_str();
  app.add_option("--client-max-depth", clientLimits.maxDepth, "Largest max_depth a client may ask for")
      ->check(CLI::Range(1u, 20u))->capture_default_str();
  app.add_option("--client-max-refine-batch", clientLimits.maxBatch, "Largest R (leaves per step) a client may ask for")
      ->check(CLI::Range(1u, 1000000u))->capture_default_str();
  app.add_option("--client-max-refinement-samples", clientLimits.maxSamplesPerView,
                 "New vertices one client's refinement may create for one view; then its refinement ends")
      ->check(CLI::Range(uint64_t(0), uint64_t(1) << 32))->capture_default_str();
  app.add_option("--max-texture-requests", options.maxTextureRequests,
                 "TextureRequests a client may have unanswered; more are refused with LIMIT_EXCEEDED")
      ->check(CLI::Range(1u, 1u << 20))->capture_default_str();
  // Operability (issue 16)
  auto* maxRefineDepth =
      app.add_option("--max-refine-depth", maxDepth, "Refinement: deepest level of the triangle hierarchy a leaf is "
                                                     "split from, [1, 20]")
          ->capture_default_str();
  maxRefineDepth->excludes(maxDepthAlias);
  // Connection limits and shutdown (issue 12)
  app.add_option("--max-connections", options.maxConnections,
                 "Client connections (counting those yet to say Hello) served at once; more are refused with "
                 "TOO_MANY_CONNECTIONS and closed at once")
      ->check(CLI::Range(size_t(1), size_t(1) << 20))->capture_default_str();
  std::string authTokenFile, rendererAuthTokenFile, tlsCert, tlsKey, rendererTlsCa;
  app.add_option("--auth-token-file", authTokenFile,
                 "Require clients to present the token in this file (their --auth-token-file); keep it mode 600");
  app.add_option("--renderer-auth-token-file", rendererAuthTokenFile,
                 "Present the token in this file to renderers (their --auth-token-file): a second secret, so that "
                 "a client's token does not open the renderers");
  auto* certOption = app.add_option("--tls-cert", tlsCert, "Serve clients TLS with this PEM certificate chain");
  auto* keyOption = app.add_option("--tls-key", tlsKey, "... and this unencrypted PEM private key");
  certOption->needs(keyOption);
  keyOption->needs(certOption);
  app.add_option("--renderer-tls-ca", rendererTlsCa,
                 "Connect to renderers with TLS, trusting the CA certificate(s) in this PEM file; each renderer's "
                 "certificate must name its --renderer host");
  CLI11_PARSE(app, argc, argv);

  if (!SetupLogging(logLevel)) {
    std::fprintf(stderr, "penumbra-sma: unknown --log-level '%s'\n", logLevel.c_str());
    return 2;
  }
  if (!SetupLogFormat(logFormat)) {
    std::fprintf(stderr, "penumbra-sma: unknown --log-format '%s' (text or json)\n", logFormat.c_str());
    return 2;
  }
  auto where = ParseHostPort(listen, /*allowPortZero=*/true);
  if (!where) {
    std::fprintf(stderr, "penumbra-sma: --listen: %s\n", where.error().message.c_str());
    return 2;
  }
  options.listen = *where;
  // Before the scene loads (minutes for a big one): a bad host is reported now.
  if (auto ok = net::CheckListenAddress(options.listen); !ok) {
    std::fprintf(stderr, "penumbra-sma: --listen: %s\n", ok.error().message.c_str());
    return 2;
  }
  if (maxDepthAlias->count() > 0)
    Logger("sma")->warn("--max-depth is deprecated: it is the refinement depth, now --max-refine-depth (the "
                        "renderer's path length is --max-bounces)");
  auto parsedCriterion = ParseCriterion(criterion);
  if (!parsedCriterion) {
    std::fprintf(stderr, "penumbra-sma: --criterion: %s\n", parsedCriterion.error().message.c_str());
    return 2;
  }
  refine.criterion = *parsedCriterion;
  if (maxDepth < 1 || maxDepth > 20) {
    std::fprintf(stderr, "penumbra-sma: --max-refine-depth must be in [1, 20]\n");
    return 2;
  }
  refine.maxDepth = uint8_t(maxDepth);
  if (auto ok = refine.Validate(); !ok) {
    std::fprintf(stderr, "penumbra-sma: %s\n", ok.error().message.c_str());
    return 2;
  }
  for (const std::string& r : renderers) {
    auto hp = ParseHostPort(r);
    if (!hp) {
      std::fprintf(stderr, "penumbra-sma: --renderer: %s\n", hp.error().message.c_str());
      return 2;
    }
    options.pool.renderers.push_back(*hp);
  }
  // Secrets and certificates before the scene: a wrong file fails in a moment.
  const auto readToken = [](const std::string& flag, const std::string& path, std::string* out) {
    auto token = ReadAuthTokenFile(path);
    if (!token) {
      std::fprintf(stderr, "penumbra-sma: %s: %s\n", flag.c_str(), token.error().message.c_str());
      return false;
    }
    if (!token->warning.empty()) Logger("sma")->warn("{}", token->warning);
    *out = std::move(token->token);
    return true;
  };
  if (!authTokenFile.empty() && !readToken("--auth-token-file", authTokenFile, &options.authToken)) return 2;
  if (!rendererAuthTokenFile.empty() &&
      !readToken("--renderer-auth-token-file", rendererAuthTokenFile, &options.pool.authToken))
    return 2;
  if (!tlsCert.empty()) {
    auto context = net::MakeTlsServerContext(tlsCert, tlsKey);
    if (!context) {
      std::fprintf(stderr, "penumbra-sma: %s\n", context.error().message.c_str());
      return 2;
    }
    options.tls = std::move(*context);
  }
  if (!rendererTlsCa.empty()) {
    auto context = net::MakeTlsClientContext(rendererTlsCa);
    if (!context) {
      std::fprintf(stderr, "penumbra-sma: --renderer-tls-ca: %s\n", context.error().message.c_str());
      return 2;
    }
    options.pool.tls = std::move(*context);
  }
  options.clientConnection.maxFrameBytes = maxFrameBytes;
  options.clientConnection.heartbeatInterval = std::chrono::milliseconds(heartbeatMs);
  options.clientConnection.readTimeout = std::chrono::milliseconds(readTimeoutMs);
  options.clientConnection.handshakeTimeout = std::chrono::milliseconds(handshakeTimeoutMs);
  options.pool.connection.heartbeatInterval = std::chrono::milliseconds(heartbeatMs);
  options.pool.connection.readTimeout = std::chrono::milliseconds(rendererTimeoutMs);
  options.pool.resolveInterval = std::chrono::seconds(resolveSeconds);
  options.pool.batchTimeout = std::chrono::seconds(batchTimeoutSeconds);
  options.pool.quarantine = std::chrono::seconds(quarantineSeconds);
  options.statsInterval = std::chrono::seconds(statsSeconds);

  // Before the scene loads: liveness holds while it loads, readiness not.
  auto http = OperatorEndpoint::FromFlags(httpListen, httpPortFile, "penumbra_sma");
  if (!http) {
    std::fprintf(stderr, "penumbra-sma: %s\n", http.error().message.c_str());
    return 1;
  }
  auto scene = LoadScene(scenePath);
  if (!scene) {
    std::fprintf(stderr, "penumbra-sma: %s\n", scene.error().message.c_str());
    return 1;
  }
  Logger("sma")->info("building the visibility BVH and the triangle hierarchy");
  const auto buildStart = std::chrono::steady_clock::now();
  auto server = SmaServer::Create(*scene, options);
  if (!server) {
    std::fprintf(stderr, "penumbra-sma: %s\n", server.error().message.c_str());
    return 1;
  }
  auto bound = (*server)->Listen();
  if (!bound) {
    std::fprintf(stderr, "penumbra-sma: %s\n", bound.error().message.c_str());
    return 1;
  }
  Logger("sma")->info("scene '{}' (identity {:016x}): {} triangles, {} vertices, ready for clients after {:.2f} s "
                      "of building; {} renderer address(es)",
                      scene->name, scene->identity, scene->triangles.size(), scene->vertices.size(),
                      std::chrono::duration<double>(std::chrono::steady_clock::now() - buildStart).count(),
                      options.pool.renderers.size());
  if (!portFile.empty()) {
    if (auto written = WritePortFile(portFile, bound->port()); !written) {
      std::fprintf(stderr, "penumbra-sma: %s\n", written.error().message.c_str());
      return 1;
    }
  }
  if (*http) {
    SmaServer* sma = server->get();
    (*http)->Attach({[sma](metrics::ExpositionWriter& out) { sma->WriteMetrics(out); },
                     [sma] { return sma->NotReadyReason(); }});
  }
  (*server)->Run();
  if (*http) (*http)->Detach();
  return 0;
}

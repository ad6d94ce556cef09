// penumbra-renderer: loads a scene, commits it to Embree, and answers
// ShadeRequests from any number of SMAs until SIGTERM. See renderer/README.md.

#include <cstdio>
#include <thread>

#include <CLI/CLI.hpp>

#include "penumbra/common/version.h"
#include "penumbra/common/connection.h"
#include "penumbra/common/auth.h"
#include "penumbra/common/endpoint.h"
#include "penumbra/common/logging.h"
#include "penumbra/common/operator_http.h"
#include "penumbra/common/scene.h"
#include "penumbra/renderer/ray_scene.h"
#include "penumbra/renderer/server.h"
#include "penumbra/renderer/shading.h"

int main(int argc, char** argv) {
  using namespace penumbra;
  CLI::App app{"penumbra-renderer: a path-tracing shading service for Penumbra SMAs"};
  app.set_version_flag("--version", "penumbra-renderer " + std::string(kVersion));
  std::string scenePath;
  std::string listen = "127.0.0.1:7100";
  std::string portFile;
  std::string logLevel = "info";
  std::string name = "penumbra-renderer";
  RendererServerOptions options;
  ShadingSettings shading;
  int threads = 0;
  uint32_t maxFrameBytes = options.connection.maxFrameBytes;
  int heartbeatMs = int(options.connection.heartbeatInterval.count());
  int readTimeoutMs = int(options.connection.readTimeout.count());
  int handshakeTimeoutMs = int(options.connection.handshakeTimeout.count());
  int statsSeconds = 10;

  app.add_option("--scene", scenePath, "Scene description (.json) or mesh file (.obj, .gltf, .glb, ...)")->required();
  app.add_option("--listen", listen, "Address to listen on, HOST:PORT (port 0: any free port)")->capture_default_str();
  app.add_option("--threads", threads, "Shading worker threads (0: one per hardware thread)")
      ->check(CLI::Range(0, 1024))->capture_default_str();
  app.add_option("--spp", shading.pathsPerSample, "Paths per sample unless a request says otherwise")
      ->check(CLI::Range(1, 1 << 20))->capture_default_str();
  app.add_option("--max-spp", shading.maxPathsPerSample,
                 "Adaptive sampling: trace further rounds of paths, up to this many per sample, while a sample's "
                 "relative standard error exceeds --target-error (0: off, every sample gets --spp)")
      ->check(CLI::Range(0, 1 << 20))->capture_default_str();
  app.add_option("--target-error", shading.targetRelativeError,
                 "Adaptive sampling: relative standard error of a sample's irradiance to stop at")
      ->check(CLI::Range(0.001f, 1.0f))->capture_default_str();
  app.add_option("--max-bounces", shading.maxBounces,
                 "Most surfaces a path reflects from after the first (0: direct light only); Russian roulette ends "
                 "paths long before the default cap, so the default is unbiased")
      ->check(CLI::Range(0, 1024))->capture_default_str();
  app.add_option("--seed", shading.seed, "Seed mixed into every sample's random stream")->capture_default_str();
  app.add_option("--max-batch", options.limits.maxBatchSamples, "Largest batch accepted, in samples")
      ->check(CLI::Range(1u, 1u << 22))->capture_default_str();
  app.add_option("--max-in-flight", options.maxBatchesInFlight, "Batches queued per connection before OVERLOADED")
      ->check(CLI::Range(1u, 1u << 16))->capture_default_str();
  app.add_option("--max-frame-bytes", maxFrameBytes, "Largest frame accepted; larger frames close the connection")
      ->check(CLI::Range(1024u, 1u << 30))->capture_default_str();
  app.add_option("--heartbeat-ms", heartbeatMs, "Idle interval after which a heartbeat is sent")
      ->check(CLI::Range(10, 3600000))->capture_default_str();
  app.add_option("--handshake-timeout-ms", handshakeTimeoutMs,
                 "A peer that has not completed its Hello by then is dropped")
      ->check(CLI::Range(10, 3600000))->capture_default_str();
  app.add_option("--read-timeout-ms", readTimeoutMs, "Silence after which a peer is dropped")
      ->check(CLI::Range(10, 3600000))->capture_default_str();
  app.add_option("--stats-interval", statsSeconds, "Seconds between counter lines in the log")
      ->check(CLI::Range(1, 86400))->capture_default_str();
  app.add_option("--name", name, "Name reported in the handshake and logs")->capture_default_str();
  app.add_option("--port-file", portFile, "Write the bound port to this file once listening (for scripts/tests)");
  app.add_option("--log-level", logLevel, "trace, debug, info, warn, error, critical or off")->capture_default_str();
  // Connection limits and shutdown (issue 12)
  app.add_option("--max-connections", options.maxConnections,
                 "Connections (SMAs, and peers yet to say Hello) served at once; more are refused with "
                 "TOO_MANY_CONNECTIONS and closed at once")
      ->check(CLI::Range(size_t(1), size_t(1) << 20))->capture_default_str();
  // Operator HTTP endpoint (issue 16)
  std::string httpListen, httpPortFile;
  app.add_option("--http", httpListen,
                 "Serve /metrics (Prometheus), /healthz and /readyz on HOST:PORT (port 0: any free port); "
                 "ready once the scene is loaded");
  app.add_option("--http-port-file", httpPortFile, "Write the bound --http port to this file once listening");
  std::string logFormat = "text";
  app.add_option("--log-format", logFormat, "text, or json: one JSON object per log line")->capture_default_str();
  std::string authTokenFile, tlsCert, tlsKey;
  app.add_option("--auth-token-file", authTokenFile,
                 "Require SMAs to present the token in this file (their --renderer-auth-token-file); keep it mode 600");
  auto* certOption = app.add_option("--tls-cert", tlsCert, "Serve TLS with this PEM certificate chain (leaf first)");
  auto* keyOption = app.add_option("--tls-key", tlsKey, "... and this unencrypted PEM private key");
  certOption->needs(keyOption);
  keyOption->needs(certOption);
  CLI11_PARSE(app, argc, argv);

  if (!SetupLogging(logLevel)) {
    std::fprintf(stderr, "penumbra-renderer: unknown --log-level '%s'\n", logLevel.c_str());
    return 2;
  }
  if (!SetupLogFormat(logFormat)) {
    std::fprintf(stderr, "penumbra-renderer: unknown --log-format '%s' (text or json)\n", logFormat.c_str());
    return 2;
  }
  auto log = Logger("renderer");
  auto where = ParseHostPort(listen, /*allowPortZero=*/true);
  if (!where) {
    std::fprintf(stderr, "penumbra-renderer: --listen: %s\n", where.error().message.c_str());
    return 2;
  }
  // Before the scene loads (minutes for a big one): a bad host is reported now.
  if (auto ok = net::CheckListenAddress(*where); !ok) {
    std::fprintf(stderr, "penumbra-renderer: --listen: %s\n", ok.error().message.c_str());
    return 2;
  }
  if (!authTokenFile.empty()) {
    auto token = ReadAuthTokenFile(authTokenFile);
    if (!token) {
      std::fprintf(stderr, "penumbra-renderer: --auth-token-file: %s\n", token.error().message.c_str());
      return 2;
    }
    if (!token->warning.empty()) log->warn("{}", token->warning);
    options.authToken = std::move(token->token);
  }
  if (!tlsCert.empty()) {
    auto context = net::MakeTlsServerContext(tlsCert, tlsKey);
    if (!context) {
      std::fprintf(stderr, "penumbra-renderer: %s\n", context.error().message.c_str());
      return 2;
    }
    options.tls = std::move(*context);
  }

  // Before the scene loads: liveness holds while it loads, readiness not.
  auto http = OperatorEndpoint::FromFlags(httpListen, httpPortFile, "penumbra_renderer");
  if (!http) {
    std::fprintf(stderr, "penumbra-renderer: %s\n", http.error().message.c_str());
    return 1;
  }
  auto scene = LoadScene(scenePath);
  if (!scene) {
    std::fprintf(stderr, "penumbra-renderer: %s\n", scene.error().message.c_str());
    return 1;
  }
  auto rays = RayScene::Build(*scene);
  if (!rays) {
    std::fprintf(stderr, "penumbra-renderer: %s\n", rays.error().message.c_str());
    return 1;
  }
  Shader shader(*scene, **rays, shading);

  options.listen = *where;
  options.name = name;
  options.workerThreads = threads > 0 ? threads : int(std::max(1u, std::thread::hardware_concurrency()));
  options.connection.maxFrameBytes = maxFrameBytes;
  options.connection.heartbeatInterval = std::chrono::milliseconds(heartbeatMs);
  options.connection.readTimeout = std::chrono::milliseconds(readTimeoutMs);
  options.connection.handshakeTimeout = std::chrono::milliseconds(handshakeTimeoutMs);
  options.statsInterval = std::chrono::seconds(statsSeconds);

  RendererServer server(shader, options);
  auto bound = server.Listen();
  if (!bound) {
    std::fprintf(stderr, "penumbra-renderer: %s\n", bound.error().message.c_str());
    return 1;
  }
  log->info("scene '{}' (identity {:016x}), {} worker thread(s), {} paths/sample{}, at most {} bounces", scene->name,
            scene->identity, options.workerThreads, shading.pathsPerSample,
            shading.maxPathsPerSample > shading.pathsPerSample
                ? fmt::format(" (adaptive up to {} at {:.3g} relative error)", shading.maxPathsPerSample,
                              shading.targetRelativeError)
                : std::string(),
            shading.maxBounces);
  if (!portFile.empty()) {
    if (auto written = WritePortFile(portFile, bound->port()); !written) {
      std::fprintf(stderr, "penumbra-renderer: %s\n", written.error().message.c_str());
      return 1;
    }
  }
  if (*http) {
    (*http)->Attach({[&server](metrics::ExpositionWriter& out) { server.WriteMetrics(out); },
                     [&server] { return server.NotReadyReason(); }});
  }
  server.Run();
  if (*http) (*http)->Detach();
  return 0;
}

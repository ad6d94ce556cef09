// penumbra-sma: the shading management agent. Loads the scene, connects to
// the renderers, and serves walkthrough clients until SIGTERM. See
// sma/README.md.

#include <chrono>
#include <cstdio>

#include <CLI/CLI.hpp>

#include "penumbra/common/fork_join_annotation.h"
#include "penumbra/common/logging.h"
#include "penumbra/common/scene.h"
#include "penumbra/common/server_main.h"
#include "penumbra/sma/server.h"

int main(int argc, char** argv) {
  using namespace penumbra;
  using namespace penumbra::sma;
  CLI::App app{"penumbra-sma: shading cache, visibility, refinement and deltas for Penumbra clients"};
  SmaOptions options;
  ServerMain serverMain(app,
                        {.program = "penumbra-sma",
                         .listen = "127.0.0.1:7200",
                         .name = options.name,
                         .peers = "clients",
                         .peerTokenFlag = "--auth-token-file",
                         .readyWhen = "once a renderer is connected",
                         .metricsPrefix = "penumbra_sma",
                         .logger = "sma"},
                        options.clientConnection, options.maxConnections);
  std::string scenePath;
  std::vector<std::string> renderers;
  int rendererTimeoutMs = int(options.pool.connection.readTimeout.count());
  int resolveSeconds = int(options.pool.resolveInterval.count() / 1000);
  int batchTimeoutSeconds = int(options.pool.batchTimeout.count() / 1000);
  int quarantineSeconds = int(options.pool.quarantine.count() / 1000);

  app.add_option("--scene", scenePath, "Scene description (.json) or mesh file; must match the renderers'")->required();
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
  app.add_option("--animation-hz", options.animationHz,
                 "Moves per second the SMA makes of each animated object along its path (0: paths not played)")
      ->check(CLI::Range(0.0, 1000.0))->capture_default_str();
  app.add_flag("--invalidate-all-on-move", options.invalidateEverythingOnMove,
               "Every move invalidates every cached sample (a full recomputation: the baseline for benchmarks)");
  app.add_option("--move-test-paths", options.pool.verifyPaths,
                 "Paired samples of the test that keeps a static sample a move's indirect-light bound would "
                 "invalidate (0: no test, the bound invalidates it)")
      ->check(CLI::Range(0u, 1u << 16))->capture_default_str();
  app.add_option("--move-test-direct", options.moveTestDirect,
                 "Also test the samples whose direct light a move may change, instead of re-shading them at once")
      ->capture_default_str();
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
  app.add_option("--session-threads", options.sessionThreads,
                 "Threads that plan and encode the clients' deltas, off the I/O threads (0: on an I/O thread)")
      ->check(CLI::Range(0, 64))->capture_default_str();
  app.add_option("--view-threads", options.viewThreads, "Visibility job threads")
      ->check(CLI::Range(1, 64))->capture_default_str();
  app.add_option("--max-view-pixels", options.maxViewPixels,
                 "Largest view (width x height) a client may ask for; visibility costs time and memory per pixel")
      ->check(CLI::Range(uint64_t(1), uint64_t(1) << 28))->capture_default_str();
  app.add_option("--renderer-read-timeout-ms", rendererTimeoutMs,
                 "Silence after which a renderer is dropped and its samples go to the others")
      ->check(CLI::Range(10, 3600000))->capture_default_str();
  app.add_option("--client-queue-bytes", options.clientSoftQueueBytes,
                 "Bytes queued to a client above which its deltas are held back and later sent as one")
      ->capture_default_str();
  app.add_option("--exposure", options.toneMapping.exposure, "Default exposure clients apply before tone mapping")
      ->check(CLI::PositiveNumber)->capture_default_str();
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
  auto* lingerOption =
      app.add_option("--client-linger-triangles", options.clientLingerTriangles,
                     "Triangles a client keeps, drawn under the depth test, after they leave its view -- the most "
                     "recently seen -- so that turning back shows them at once (0: removed as they leave; with "
                     "--memory-budget 0 unless given: the collector cannot take what a client holds)")
          ->check(CLI::Range(size_t(0), size_t(1) << 24))
          ->capture_default_str();
  app.add_option("--client-max-refinement-samples", clientLimits.maxSamplesPerView,
                 "New vertices one client's refinement may create for one view; then its refinement ends")
      ->check(CLI::Range(uint64_t(0), uint64_t(1) << 32))->capture_default_str();
  app.add_option("--max-texture-requests", options.maxTextureRequests,
                 "TextureRequests a client may have unanswered; more are refused with LIMIT_EXCEEDED")
      ->check(CLI::Range(1u, 1u << 20))->capture_default_str();
  // Memory (issue 15)
  app.add_option_function<double>(
         "--memory-budget",
         [&options](const double& mib) { options.memoryBudgetBytes = uint64_t(mib * 1048576.0); },
         "MiB the SMA's data (sample cache, hierarchy, clients' mirrors) should stay within; 0: unbounded. "
         "The age-based collector collapses the refinement used longest ago to keep it (sma/README.md, \"Memory\")")
      ->check(CLI::Range(0.0, double(uint64_t(1) << 24)))
      ->default_str("0");
  app.add_option("--memory-collect-start", options.memoryCollectStart,
                 "Collection starts when the data in use passes this share of --memory-budget (the paper's T_shafts)")
      ->check(CLI::Range(0.05, 1.0))->capture_default_str();
  app.add_option("--memory-collect-stop", options.memoryCollectStop,
                 "... and stops once it is down to this share (T_min); below --memory-collect-start")
      ->check(CLI::Range(0.01, 1.0))->capture_default_str();
  app.add_option("--memory-min-age", options.memoryMinAgeSeconds,
                 "Seconds: refinement used more recently than this is never collected")
      ->check(CLI::Range(0.0, 3600.0))->capture_default_str();
  // Operability (issue 16)
  auto* maxRefineDepth =
      app.add_option("--max-refine-depth", maxDepth, "Refinement: deepest level of the triangle hierarchy a leaf is "
                                                     "split from, [1, 20]")
          ->capture_default_str();
  maxRefineDepth->excludes(maxDepthAlias);
  std::string movePrediction = options.movePrediction ? "on" : "off";
  app.add_option("--move-prediction", movePrediction,
                 "Movement prediction for moving objects: after each move, shade ahead at the next pose (the animated "
                 "objects' next step, a steady drag's next place) what that move will invalidate, and use it if "
                 "the move lands there (on|off)")
      ->check(CLI::IsMember({"on", "off"}));
  app.add_option("--move-snap", options.moveSnap,
                 "With --move-prediction: a client's move that lands within this distance (scene units; every "
                 "corner of the object and every transform entry) of the place predicted for it is applied at that "
                 "place, so the samples shaded ahead there are used; 0: never")
      ->check(CLI::Range(0.0f, kMoveConfirmTolerance))->capture_default_str();
  // Camera movement prediction (issue 15; sma/README.md, "Movement prediction")
  std::string prediction = options.predictionOn ? "on" : "off";
  double predictionHorizon = options.prediction.horizon.count();
  app.add_option("--prediction", prediction,
                 "Camera movement prediction: with each new view, shade early (after the view's own samples) what the client's camera is expected "
                 "to see next (on|off)")
      ->check(CLI::IsMember({"on", "off"}))->capture_default_str();
  app.add_option("--prediction-horizon", predictionHorizon, "Seconds ahead of the latest view the camera is predicted")
      ->check(CLI::Range(0.01, 10.0))->capture_default_str();
  app.add_option("--prediction-widen", options.prediction.widen,
                 "The predicted view's field of view is widened so that tan(fov/2) grows by this factor")
      ->check(CLI::Range(1.0, 2.0))->capture_default_str();
  app.add_option("--prediction-resolution", options.predictionResolution,
                 "The predicted view is traced at this times the view's width and height")
      ->check(CLI::Range(0.1, 2.0))->capture_default_str();
  std::string rendererAuthTokenFile, rendererTlsCa;
  app.add_option("--renderer-auth-token-file", rendererAuthTokenFile,
                 "Present the token in this file to renderers (their --auth-token-file): a second secret, so that "
                 "a client's token does not open the renderers");
  app.add_option("--renderer-tls-ca", rendererTlsCa,
                 "Connect to renderers with TLS, trusting the CA certificate(s) in this PEM file; each renderer's "
                 "certificate must name its --renderer host");
  CLI11_PARSE(app, argc, argv);
  options.predictionOn = prediction == "on";
  options.movePrediction = movePrediction == "on";
  options.prediction.horizon = std::chrono::duration<double>(predictionHorizon);
  // A memory budget comes first: held triangles cannot be collected, and
  // lingering ones are held for nothing but a faster return.
  if (options.memoryBudgetBytes > 0 && lingerOption->count() == 0) options.clientLingerTriangles = 0;

  if (auto failed = serverMain.Setup()) return *failed;
  if (maxDepthAlias->count() > 0)
    Logger("sma")->warn("--max-depth is deprecated: it is the refinement depth, now --max-refine-depth (the "
                        "renderer's path length is --max-bounces)");
  auto parsedCriterion = ParseCriterion(criterion);
  if (!parsedCriterion) {
    return serverMain.Fail(2, "--criterion: " + parsedCriterion.error().message);
  }
  refine.criterion = *parsedCriterion;
  if (maxDepth < 1 || maxDepth > 20) return serverMain.Fail(2, "--max-refine-depth must be in [1, 20]");
  refine.maxDepth = uint8_t(maxDepth);
  if (auto ok = refine.Validate(); !ok) return serverMain.Fail(2, ok.error().message);
  for (const std::string& r : renderers) {
    auto hp = ParseHostPort(r);
    if (!hp) return serverMain.Fail(2, "--renderer: " + hp.error().message);
    options.pool.renderers.push_back(*hp);
  }
  if (!rendererAuthTokenFile.empty() &&
      !serverMain.ReadToken("--renderer-auth-token-file", rendererAuthTokenFile, &options.pool.authToken))
    return 2;
  if (!rendererTlsCa.empty()) {
    auto context = net::MakeTlsClientContext(rendererTlsCa);
    if (!context) return serverMain.Fail(2, "--renderer-tls-ca: " + context.error().message);
    options.pool.tls = std::move(*context);
  }
  serverMain.Fill(options);
  options.clientConnection = serverMain.Connection();
  options.pool.connection.heartbeatInterval = serverMain.Heartbeat();
  options.pool.connection.readTimeout = std::chrono::milliseconds(rendererTimeoutMs);
  options.pool.resolveInterval = std::chrono::seconds(resolveSeconds);
  options.pool.batchTimeout = std::chrono::seconds(batchTimeoutSeconds);
  options.pool.quarantine = std::chrono::seconds(quarantineSeconds);

  if (auto failed = serverMain.StartHttp()) return *failed;
  [[maybe_unused]] TbbSingleThreadedUnderTsan tbbUnderTsan;  // the process's life (fork_join_annotation.h)
  auto scene = LoadScene(scenePath);
  if (!scene) return serverMain.Fail(1, scene.error().message);
  Logger("sma")->info("building the visibility BVH and the triangle hierarchy");
  const auto buildStart = std::chrono::steady_clock::now();
  auto server = SmaServer::Create(*scene, options);
  if (!server) return serverMain.Fail(1, server.error().message);
  auto bound = (*server)->Listen();
  if (!bound) return serverMain.Fail(1, bound.error().message);
  Logger("sma")->info("scene '{}' (identity {:016x}): {} triangles, {} vertices, ready for clients after {:.2f} s "
                      "of building; {} renderer address(es)",
                      scene->name, scene->identity, scene->triangles.size(), scene->vertices.size(),
                      std::chrono::duration<double>(std::chrono::steady_clock::now() - buildStart).count(),
                      options.pool.renderers.size());
  SmaServer* sma = server->get();
  return serverMain.Serve(bound->port(),
                          {[sma](metrics::ExpositionWriter& out) { sma->WriteMetrics(out); },
                           [sma] { return sma->NotReadyReason(); }},
                          [sma] { sma->Run(); });
}

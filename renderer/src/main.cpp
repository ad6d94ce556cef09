// penumbra-renderer: loads a scene, commits it to Embree, and answers
// ShadeRequests from any number of SMAs until SIGTERM. See renderer/README.md.

#include <thread>

#include <CLI/CLI.hpp>

#include "penumbra/common/logging.h"
#include "penumbra/common/scene.h"
#include "penumbra/common/server_main.h"
#include "penumbra/renderer/ray_scene.h"
#include "penumbra/renderer/server.h"
#include "penumbra/renderer/shading.h"

int main(int argc, char** argv) {
  using namespace penumbra;
  CLI::App app{"penumbra-renderer: a path-tracing shading service for Penumbra SMAs"};
  RendererServerOptions options;
  ServerMain serverMain(app,
                        {.program = "penumbra-renderer",
                         .listen = "127.0.0.1:7100",
                         .name = options.name,
                         .peers = "SMAs",
                         .peerTokenFlag = "--renderer-auth-token-file",
                         .readyWhen = "once the scene is loaded",
                         .metricsPrefix = "penumbra_renderer",
                         .logger = "renderer"},
                        options.connection, options.maxConnections);
  std::string scenePath;
  ShadingSettings shading;
  int threads = 0;

  app.add_option("--scene", scenePath, "Scene description (.json) or mesh file (.obj, .gltf, .glb, ...)")->required();
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
      ->check(CLI::Range(1e-6f, 1.0f))->capture_default_str();
  app.add_option("--max-bounces", shading.maxBounces,
                 "Most surfaces a path reflects from after the first (0: direct light only); Russian roulette ends "
                 "paths long before the default cap, so the default is unbiased")
      ->check(CLI::Range(0, 1024))->capture_default_str();
  app.add_option("--seed", shading.seed, "Seed mixed into every sample's random stream")->capture_default_str();
  app.add_option("--max-batch", options.limits.maxBatchSamples, "Largest batch accepted, in samples")
      ->check(CLI::Range(1u, 1u << 22))->capture_default_str();
  app.add_option("--max-in-flight", options.maxBatchesInFlight, "Batches queued per connection before OVERLOADED")
      ->check(CLI::Range(1u, 1u << 16))->capture_default_str();
  CLI11_PARSE(app, argc, argv);

  if (auto failed = serverMain.Setup()) return *failed;
  auto log = Logger("renderer");
  if (auto failed = serverMain.StartHttp()) return *failed;
  auto scene = LoadScene(scenePath);
  if (!scene) return serverMain.Fail(1, scene.error().message);
  auto rays = RayScene::Build(*scene);
  if (!rays) return serverMain.Fail(1, rays.error().message);
  Shader shader(*scene, **rays, shading);

  serverMain.Fill(options);
  options.workerThreads = threads > 0 ? threads : int(std::max(1u, std::thread::hardware_concurrency()));
  options.connection = serverMain.Connection();

  RendererServer server(shader, options);
  auto bound = server.Listen();
  if (!bound) return serverMain.Fail(1, bound.error().message);
  log->info("scene '{}' (identity {:016x}), {} worker thread(s), {} paths/sample{}, at most {} bounces", scene->name,
            scene->identity, options.workerThreads, shading.pathsPerSample,
            shading.maxPathsPerSample > shading.pathsPerSample
                ? fmt::format(" (adaptive up to {} at {:.3g} relative error)", shading.maxPathsPerSample,
                              shading.targetRelativeError)
                : std::string(),
            shading.maxBounces);
  return serverMain.Serve(bound->port(),
                          {[&server](metrics::ExpositionWriter& out) { server.WriteMetrics(out); },
                           [&server] { return server.NotReadyReason(); }},
                          [&server] { server.Run(); });
}

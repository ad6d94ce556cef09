// End-to-end SMA benchmark on real processes: a renderer, an SMA and a
// scripted client on loopback, on the Sponza scene.
//
// Measured (issue targets in brackets):
//  * new view:    view -> first delta, and stage 1 (every visible initial
//                 triangle shaded, paper §5) with its sample count and the
//                 achieved samples/s [stage 1 <= 1.5 s at 64 paths/vertex];
//  * cached view: view -> first delta and view -> complete display when
//                 alternating between views already in the cache, p50/p99
//                 [complete display <= 50 ms];
//  * walk:        the scene's camera path at 30 views/s, view -> first delta
//                 per frame and bytes per frame.
// Every measurement starts once the SMA has encoded the scene's textures
// (its start-up tail; figures from before a833eaa include it in the new view).
// Baselines measured in the same run: the renderer's own rate on the same
// samples, fed directly over the wire (so stage 1 reads as a fraction of
// what the renderer alone could do), and a stats round trip to the SMA (the
// floor under any view -> delta latency).
//
//   sma_bench [--scene scenes/sponza.json] [--camera atrium] [--spp 64] [--width 1280 --height 720]

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <sstream>
#include <string>
#include <thread>

#include <unistd.h>

#include <CLI/CLI.hpp>

#include "order_statistics.h"
#include "penumbra/common/logging.h"
#include "penumbra/common/messages.h"
#include "penumbra/common/scene.h"
#include "sma_stack.h"

namespace penumbra {
namespace {

namespace fs = std::filesystem;
using namespace penumbra::testing;
using namespace penumbra::bench;

struct Options {
  fs::path scene = fs::path(PENUMBRA_SOURCE_DIR) / "scenes" / "sponza.json";
  std::string camera = "atrium";
  std::string path = "walk";
  int spp = 64;
  int maxBounces = 64;  // the renderer's default
  int width = 1280;
  int height = 720;
  int threads = int(std::max(1u, std::thread::hardware_concurrency()));
  int cachedRounds = 40;
  double walkFps = 30.0;
  bool stage1Only = false;
  int firstPaths = 0;  // the SMA's --first-paths; 0: its default
};

// The renderer's own throughput on `count` of the scene's vertices, asked
// directly over the wire in batches like the SMA's.
Expected<double> DirectRendererRate(uint16_t port, const Scene& scene, size_t count, uint64_t idBase) {
  auto c = WireClient::Connect("127.0.0.1", port);
  if (!c) return c.error();
  if (auto w = c->Handshake(wire::ROLE_SMA, scene.identity); !w) return w.error();
  const size_t batchSize = 256;
  size_t sent = 0, answered = 0;
  uint64_t batchId = 1;
  const auto start = Clock::now();
  auto sendBatch = [&] {
    wire::Envelope e;
    auto* r = e.mutable_shade_request();
    r->set_batch_id(batchId++);
    for (size_t i = 0; i < batchSize && sent < count; ++i, ++sent) {
      const uint32_t t = uint32_t((sent * 7919) % scene.triangles.size());
      const Vertex& v = scene.vertices[scene.triangles[t].v[0]];
      r->add_sample_ids(idBase + sent);
      for (int k = 0; k < 3; ++k) r->add_positions(v.position[k]);
      for (int k = 0; k < 3; ++k) r->add_normals(v.normal[k]);
      r->add_triangle_ids(t);
      r->add_barycentrics(0.0f);
      r->add_barycentrics(0.0f);
    }
    return c->Send(e);
  };
  for (int i = 0; i < 4 && sent < count; ++i) sendBatch();  // as many in flight as the SMA's credits
  while (answered < count) {
    auto e = c->Receive(std::chrono::seconds(600));
    if (!e) return e.error();
    if (!e->has_shade_reply()) continue;
    answered += size_t(e->shade_reply().sample_ids_size());
    if (e->shade_reply().remaining() == 0 && sent < count) sendBatch();
  }
  return double(count) / std::chrono::duration<double>(Clock::now() - start).count();
}

// User + system CPU seconds process `pid` has used (/proc/PID/stat); 0 when unreadable.
double CpuSeconds(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/stat");
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const size_t paren = text.rfind(')');
  if (paren == std::string::npos) return 0.0;
  std::istringstream fields(text.substr(paren + 2));
  std::string field;
  double utime = 0.0, stime = 0.0;
  for (int i = 3; i <= 15 && fields >> field; ++i) {  // fields 14 and 15: utime, stime
    if (i == 14) utime = std::stod(field);
    if (i == 15) stime = std::stod(field);
  }
  return (utime + stime) / double(sysconf(_SC_CLK_TCK));
}

int Run(const Options& o) {
  SetupLogging("warn");
  if (!fs::exists(o.scene)) {
    std::printf("sma_bench: %s not found; skipping\n", o.scene.string().c_str());
    return 0;
  }
  auto scene = LoadScene(o.scene);
  if (!scene) {
    std::printf("sma_bench: %s; skipping (is ../shared/scenes present?)\n", scene.error().message.c_str());
    return 0;
  }
  const CameraPreset* preset = scene->FindCamera(o.camera);
  if (!preset) {
    std::fprintf(stderr, "sma_bench: no camera '%s'\n", o.camera.c_str());
    return 1;
  }
  std::vector<std::string> smaArgs;
  if (o.firstPaths > 0) smaArgs = {"--first-paths", std::to_string(o.firstPaths)};
  auto stack = StartSmaStack({o.scene, PENUMBRA_RENDERER_EXE, PENUMBRA_SMA_EXE, o.threads, o.spp, o.maxBounces, smaArgs});
  if (!stack) return std::fprintf(stderr, "sma_bench: %s\n", stack.error().message.c_str()), 1;
  auto client = SmaTestClient::Connect(stack->sma.port, "sma_bench");
  if (!client) return std::fprintf(stderr, "sma_bench: %s\n", client.error().message.c_str()), 1;

  CameraView atrium;
  atrium.pose = preset->pose;
  atrium.fovYDeg = preset->fovYDeg;
  atrium.width = o.width;
  atrium.height = o.height;
  uint64_t viewId = 1;

  // The SMA encodes every texture of the scene once, on its background
  // thread, from the moment it listens: on a scene with many textures that
  // tail of its start-up would otherwise land in the first view's CPU and
  // wall time (street.json's doubled the SMA's CPU of stage 1). Waited for,
  // bounded, and the wait printed.
  const auto settleStart = std::chrono::steady_clock::now();
  const double texturesToEncode = double(scene->textures.size());
  for (;;) {
    auto encoded = client->Counter("textures_encoded");
    if (!encoded) return std::fprintf(stderr, "sma_bench: %s\n", encoded.error().message.c_str()), 1;
    if (*encoded >= texturesToEncode) break;
    if (std::chrono::steady_clock::now() - settleStart > std::chrono::minutes(2))
      return std::fprintf(stderr, "sma_bench: %.0f of %.0f textures encoded after 2 minutes\n", *encoded,
                          texturesToEncode),
             1;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  std::printf("SMA start-up: %.0f textures encoded %.0f ms after it listened and the client connected\n",
              texturesToEncode,
              std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - settleStart).count());

  // Stage 1 of a new view.
  const double rendererCpuBefore = CpuSeconds(stack->renderer.process.Pid());
  const double smaCpuBefore = CpuSeconds(stack->sma.process.Pid());
  auto stage1 = TimeView(*client, atrium, viewId++, std::chrono::minutes(10), o.stage1Only);
  if (!stage1) return std::fprintf(stderr, "sma_bench: %s\n", stage1.error().message.c_str()), 1;
  if (o.stage1Only) {
    // First complete display of a new view: every visible triangle shaded.
    const double stage1Samples =
        client->Counter("samples_requested").value() - client->Counter("client_refinement_samples").value();
    const double traceMs = client->Counter("client_last_trace_ms").value();
    const double mapMs = client->Counter("client_last_map_ms").value();
    // CPU seconds the renderer and the SMA spent on it: on a loaded machine
    // the wall time stretches, the work does not; work / 2 cores bounds the
    // wall time of an idle 2-core machine from below.
    const double rendererCpuS = CpuSeconds(stack->renderer.process.Pid()) - rendererCpuBefore;
    const double smaCpuS = CpuSeconds(stack->sma.process.Pid()) - smaCpuBefore;
    const double cpuS = rendererCpuS + smaCpuS;
    std::printf("new view (%s, '%s', %dx%d): view->first delta %.1f ms (trace %.1f + map %.1f ms); stage 1 "
                "(complete display) %.1f ms, %.0f samples, %.0f triangles; CPU: renderer %.2f s + SMA %.2f s "
                "(/ %d cores: %.0f ms)\n",
                scene->name.c_str(), o.camera.c_str(), o.width, o.height, stage1->firstDeltaMs, traceMs, mapMs,
                stage1->stage1Ms, stage1Samples, double(client->Mesh().Triangles().size()), rendererCpuS, smaCpuS, o.threads,
                cpuS / o.threads * 1000.0);
    return 0;
  }
  // Stage-1 samples: all asked for, less what refinement asked for after.
  const double samples =
      client->Counter("samples_requested").value() - client->Counter("client_refinement_samples").value();
  const double refinementSamples = client->Counter("client_refinement_samples").value();
  const double triangles = double(client->Mesh().Triangles().size());
  double trianglesSent = 0.0;  // Delta_total: refined-away ones included
  for (const auto& [kind, n] : client->Mesh().added) trianglesSent += double(n);
  const double traceMs = client->Counter("client_last_trace_ms").value();
  const double mapMs = client->Counter("client_last_map_ms").value();
  const double stage1Rate = samples / (stage1->stage1Ms / 1000.0);

  // Baselines: the renderer alone on as many samples; a bare round trip.
  auto direct = DirectRendererRate(stack->renderer.port, *scene, size_t(samples), 1ull << 40);
  if (!direct) return std::fprintf(stderr, "sma_bench: %s\n", direct.error().message.c_str()), 1;
  std::vector<double> rtt;
  for (int i = 0; i < 20; ++i) {
    const auto t0 = Clock::now();
    (void)client->Counter("clients");
    rtt.push_back(Ms(Clock::now() - t0));
  }

  // A second view, shaded too, then alternate: every view is a cached one.
  CameraView other = atrium;
  other.pose.target = atrium.pose.eye + glm::normalize(atrium.pose.target - atrium.pose.eye) * 0.999f +
                      Vec3(0.02f, 0.0f, 0.02f);
  if (!TimeView(*client, other, viewId++)) return 1;
  std::vector<double> cachedFirst, cachedComplete;
  uint64_t cachedBytes = 0;
  const double requestedBefore = client->Counter("samples_requested").value();
  for (int i = 0; i < o.cachedRounds; ++i) {
    auto t = TimeView(*client, i % 2 == 0 ? atrium : other, viewId++);
    if (!t) return std::fprintf(stderr, "sma_bench: %s\n", t.error().message.c_str()), 1;
    cachedFirst.push_back(t->firstDeltaMs);
    cachedComplete.push_back(t->completeMs);
    cachedBytes += t->bytes;
  }
  const double requestedAfter = client->Counter("samples_requested").value();

  // A walk along the scene's path at a fixed rate, not waiting for shading.
  std::vector<double> walkFirst;
  std::vector<double> walkBytes;
  const CameraPath* path = scene->FindPath(o.path);
  if (path) {
    auto walker = SmaTestClient::Connect(stack->sma.port, "sma_bench-walk");
    if (!walker) return 1;
    const double duration = path->DurationSeconds();
    const int frames = std::max(2, int(duration * o.walkFps));
    for (int f = 0; f < frames; ++f) {
      CameraView v = path->ViewAt(duration * f / (frames - 1));
      v.width = o.width;
      v.height = o.height;
      const uint64_t id = uint64_t(f + 1);
      const uint64_t before = walker->Wire().BytesReceived();
      const auto sent = Clock::now();
      walker->SendView(v, id);
      double first = -1.0;
      const auto frameEnd = sent + std::chrono::duration<double>(1.0 / o.walkFps);
      while (Clock::now() < frameEnd || first < 0) {
        auto left = std::chrono::duration_cast<std::chrono::milliseconds>(frameEnd - Clock::now());
        auto e = walker->Wire().Receive(std::max(left, std::chrono::milliseconds(first < 0 ? 5000 : 1)));
        if (!e) {
          if (e.error().message == "timeout" && first >= 0) break;
          if (e.error().message == "timeout") continue;
          return std::fprintf(stderr, "sma_bench: walk: %s\n", e.error().message.c_str()), 1;
        }
        (void)walker->Apply(*e);
        if (first < 0 && e->has_delta() && e->delta().view_id() == id) first = Ms(Clock::now() - sent);
      }
      walkFirst.push_back(first);
      walkBytes.push_back(double(walker->Wire().BytesReceived() - before));
    }
  }

  const double rttP50 = Percentile(rtt, 50);
  std::printf("SMA benchmark: %s, camera '%s', %dx%d, %d paths/vertex, at most %d bounces, renderer threads %d\n",
              scene->name.c_str(), o.camera.c_str(), o.width, o.height, o.spp, o.maxBounces, o.threads);
  std::printf("baselines: stats round trip p50 %.2f ms; renderer alone %.0f samples/s\n", rttP50, *direct);
  std::printf("new view:    view->first delta %.1f ms (visibility: trace %.1f ms + map %.1f ms)\n",
              stage1->firstDeltaMs, traceMs, mapMs);
  std::printf("             stage 1 %.2f s for %.0f samples: %.0f samples/s = %.2f x renderer alone\n",
              stage1->stage1Ms / 1000.0, samples, stage1Rate, stage1Rate / *direct);
  std::printf("             stage 2 (refinement converged) %.2f s, %.0f more samples; %.0f triangles shown\n",
              stage1->completeMs / 1000.0, refinementSamples, triangles);
  std::printf("             %.1f KiB received for %.0f triangles sent: %.1f bytes per triangle\n",
              double(stage1->bytes) / 1024.0, trianglesSent, double(stage1->bytes) / trianglesSent);
  std::printf("cached view: view->first delta p50 %.1f ms p99 %.1f ms; complete display p50 %.1f ms p99 %.1f ms "
              "(%.0f x round trip); %.0f new samples over %d views; %.1f KiB per view\n",
              Percentile(cachedFirst, 50), Percentile(cachedFirst, 99), Percentile(cachedComplete, 50),
              Percentile(cachedComplete, 99), Percentile(cachedComplete, 50) / rttP50, requestedAfter - requestedBefore,
              o.cachedRounds, double(cachedBytes) / 1024.0 / o.cachedRounds);
  if (!walkFirst.empty()) {
    std::printf("walk '%s':  %zu frames at %.0f/s: view->first delta p50 %.1f ms p99 %.1f ms; "
                "bytes/frame p50 %.0f, p99 %.0f, max %.0f\n",
                o.path.c_str(), walkFirst.size(), o.walkFps, Percentile(walkFirst, 50), Percentile(walkFirst, 99),
                Percentile(walkBytes, 50), Percentile(walkBytes, 99), *std::max_element(walkBytes.begin(), walkBytes.end()));
  }
  return 0;
}

}  // namespace
}  // namespace penumbra

int main(int argc, char** argv) {
  penumbra::Options o;
  CLI::App app{"sma_bench: end-to-end SMA latencies and stage-1 time on real processes"};
  app.add_option("--scene", o.scene, "Scene file")->capture_default_str();
  app.add_option("--camera", o.camera, "Camera preset for the new/cached views")->capture_default_str();
  app.add_option("--path", o.path, "Camera path for the walk")->capture_default_str();
  app.add_option("--spp", o.spp, "Paths per vertex")->capture_default_str();
  app.add_option("--max-bounces", o.maxBounces, "Bounces after the sample (0: direct light)")->capture_default_str();
  app.add_option("--width", o.width, "Viewport width")->capture_default_str();
  app.add_option("--height", o.height, "Viewport height")->capture_default_str();
  app.add_option("--threads", o.threads, "Renderer threads")->capture_default_str();
  app.add_option("--cached-rounds", o.cachedRounds, "Cached views timed")->capture_default_str();
  app.add_option("--walk-fps", o.walkFps, "Views per second on the walk")->capture_default_str();
  app.add_option("--first-paths", o.firstPaths, "The SMA's --first-paths (stage-1 paths per sample; 0: its default)")
      ->check(CLI::Range(0, 1 << 20));
  app.add_flag("--stage1-only", o.stage1Only, "Time a new view's first complete display (stage 1) only, then stop");
  CLI11_PARSE(app, argc, argv);
  return penumbra::Run(o);
}

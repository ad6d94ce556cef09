// Renderer throughput against the raw Embree rate measured in the same run.
//
// Shades random scene vertices (with their normals, as the SMA asks) on one
// thread and on all threads, and traces, with the same thread counts, plain
// rtcIntersect1 and rtcOccluded1 queries of cosine-distributed rays from the
// same vertices. The figure of merit is the shader's rays/s over the raw rate
// of the same mix of closest-hit and shadow rays: what fraction of the ray
// tracer's speed survives the shading around it. The machines are shared and
// noisy, so each round takes its own ratio and the report gives medians.
//
//   renderer_bench [--scene scenes/sponza.json] [--samples 4096] [--spp 32] ...

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <thread>
#include <vector>

#include <CLI/CLI.hpp>

#include "order_statistics.h"
#include "penumbra/common/logging.h"
#include "penumbra/common/rng.h"
#include "penumbra/common/scene.h"
#include "penumbra/renderer/ray_scene.h"
#include "penumbra/renderer/shading.h"

namespace penumbra {
namespace {

namespace fs = std::filesystem;

struct Options {
  fs::path scene = fs::path(PENUMBRA_SOURCE_DIR) / "scenes" / "sponza.json";
  int samples = 4096;
  int spp = 32;
  int maxBounces = ShadingSettings{}.maxBounces;
  int rawRays = 1 << 19;
  int threads = int(std::max(1u, std::thread::hardware_concurrency()));
  int rounds = 5;
};

// Shading inputs at random scene vertices: a random corner of a random
// triangle, shaded on the side of its vertex normal.
std::vector<ShadeInput> RandomVertexSamples(const Scene& scene, int count) {
  Pcg32 rng(7, 11);
  std::vector<ShadeInput> inputs(static_cast<size_t>(count));
  for (size_t i = 0; i < inputs.size(); ++i) {
    ShadeInput& in = inputs[i];
    in.sampleId = i;
    in.triangle = rng.NextBelow(uint32_t(scene.triangles.size()));
    const uint32_t corner = rng.NextBelow(3);
    const Vertex& v = scene.vertices[scene.triangles[in.triangle].v[corner]];
    in.position = v.position;
    in.normal = v.normal;
    in.b1 = corner == 1 ? 1.0f : 0.0f;
    in.b2 = corner == 2 ? 1.0f : 0.0f;
  }
  return inputs;
}

// The baseline's rays: cosine-distributed about the samples' normals, from
// origins moved off the surface as the shader moves them.
std::vector<Ray> CosineRaysFrom(const Scene& scene, const std::vector<ShadeInput>& inputs, int count) {
  const Vec3 extent = glm::max(glm::abs(scene.bounds.min), glm::abs(scene.bounds.max));
  const float offset = 1e-5f * std::max({extent.x, extent.y, extent.z});
  Pcg32 rng(13, 17);
  std::vector<Ray> rays(static_cast<size_t>(count));
  for (size_t i = 0; i < rays.size(); ++i) {
    const ShadeInput& in = inputs[i % inputs.size()];
    const float r = std::sqrt(rng.NextFloat());
    const float phi = 2.0f * kPi * rng.NextFloat();
    const Vec3 local(r * std::cos(phi), r * std::sin(phi), std::sqrt(std::max(0.0f, 1.0f - r * r)));
    const Frame frame = Frame::FromNormal(glm::normalize(in.normal));
    rays[i] = Ray{in.position + offset * frame.n, frame.ToWorld(local)};
  }
  return rays;
}

// Runs `work(begin, end)` over [0, count) in chunks on `threads` threads, each
// with flush-to-zero set; returns the wall time in seconds.
double RunParallel(int threads, size_t count, size_t chunk, const std::function<void(size_t, size_t)>& work) {
  std::atomic<size_t> next{0};
  const auto start = std::chrono::steady_clock::now();
  std::vector<std::thread> pool;
  for (int t = 0; t < threads; ++t)
    pool.emplace_back([&] {
      EnableFlushToZero();
      for (size_t begin; (begin = next.fetch_add(chunk)) < count;) work(begin, std::min(count, begin + chunk));
    });
  for (std::thread& th : pool) th.join();
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

struct Rates {
  double rawClosest = 0.0;    // rays/s, rtcIntersect1
  double rawOcclusion = 0.0;  // rays/s, rtcOccluded1
  double samples = 0.0;       // shaded samples/s
  double rays = 0.0;          // shader rays/s
  double ratio = 0.0;         // shader rays/s over the raw rate of the same mix
};

// The raw rate of the shader's mix of closest-hit and shadow rays.
double RawRateOfMix(const ShadeCounters& work, double rawClosest, double rawOcclusion) {
  const double shadow = double(work.shadowRays), closest = double(work.rays - work.shadowRays);
  return (closest + shadow) / (closest / rawClosest + shadow / rawOcclusion);
}

using bench::Median;

// Each round measures the raw rates and the shader back to back and takes
// its own ratio, so that load from other processes, which drifts over
// seconds, mostly cancels; the report is the median of the rounds.
Rates Measure(const RayScene& rays, const Shader& shader, const std::vector<ShadeInput>& inputs,
              const std::vector<Ray>& rawRays, int threads, int rounds, ShadeCounters& work) {
  std::vector<double> rawClosest, rawOcclusion, samples, shaderRays, ratio;
  for (int round = 0; round < rounds; ++round) {
    std::atomic<size_t> sink{0};  // keeps the raw loops' results alive
    const double closest = RunParallel(threads, rawRays.size(), 4096, [&](size_t b, size_t e) {
      sink += rays.TraceRaw(std::span(rawRays).subspan(b, e - b), RayQuery::kClosestHit);
    });
    const double occlusion = RunParallel(threads, rawRays.size(), 4096, [&](size_t b, size_t e) {
      sink += rays.TraceRaw(std::span(rawRays).subspan(b, e - b), RayQuery::kOcclusion);
    });
    std::vector<ShadeCounters> perSample(inputs.size());  // no shared counter to contend for
    const double shading = RunParallel(threads, inputs.size(), 16, [&](size_t b, size_t e) {
      for (size_t i = b; i < e; ++i) shader.Shade(inputs[i], 0, &perSample[i]);
    });
    work = ShadeCounters{};  // the same every round: shading is deterministic
    for (const ShadeCounters& c : perSample) work += c;

    rawClosest.push_back(double(rawRays.size()) / closest);
    rawOcclusion.push_back(double(rawRays.size()) / occlusion);
    samples.push_back(double(inputs.size()) / shading);
    shaderRays.push_back(double(work.rays) / shading);
    ratio.push_back(shaderRays.back() / RawRateOfMix(work, rawClosest.back(), rawOcclusion.back()));
  }
  return Rates{Median(rawClosest), Median(rawOcclusion), Median(samples), Median(shaderRays), Median(ratio)};
}

void Report(const char* label, int threads, const Rates& r, const ShadeCounters& work) {
  std::printf("%s (%d thread%s), medians of the rounds\n", label, threads, threads == 1 ? "" : "s");
  std::printf("  raw Embree   closest-hit %7.3f Mrays/s   occlusion %7.3f Mrays/s   shader's mix %7.3f Mrays/s\n",
              r.rawClosest * 1e-6, r.rawOcclusion * 1e-6, RawRateOfMix(work, r.rawClosest, r.rawOcclusion) * 1e-6);
  std::printf("  shader       %9.0f samples/s   %7.3f Mrays/s   (%.2f rays/path, %.0f%% shadow rays)\n", r.samples,
              r.rays * 1e-6, double(work.rays) / double(work.paths),
              100.0 * double(work.shadowRays) / double(work.rays));
  std::printf("  ratio        shader rays/s / raw rays/s of the same mix = %.3f\n", r.ratio);
}

int Run(const Options& o) {
  // Stay quiet about BVH builds and the like; errors still show.
  SetupLogging("warn");
  auto loadStart = std::chrono::steady_clock::now();
  auto scene = LoadScene(o.scene);
  const fs::path shared = (fs::path(PENUMBRA_SOURCE_DIR) / ".." / "shared").lexically_normal();
  if (!scene && !fs::exists(shared)) {
    std::printf("renderer_bench: skipped: %s is absent, and with it the benchmark scene's mesh (%s)\n",
                shared.c_str(), scene.error().message.c_str());
    return 0;
  }
  if (!scene) {
    std::fprintf(stderr, "renderer_bench: %s\n", scene.error().message.c_str());
    return 1;
  }
  const double loadSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - loadStart).count();
  const auto buildStart = std::chrono::steady_clock::now();
  auto rays = RayScene::Build(*scene);
  if (!rays) {
    std::fprintf(stderr, "renderer_bench: %s\n", rays.error().message.c_str());
    return 1;
  }
  const double buildSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - buildStart).count();

  ShadingSettings settings;
  settings.pathsPerSample = o.spp;
  settings.maxBounces = o.maxBounces;
  const Shader shader(*scene, **rays, settings);
  const std::vector<ShadeInput> inputs = RandomVertexSamples(*scene, o.samples);
  const std::vector<Ray> rawRays = CosineRaysFrom(*scene, inputs, o.rawRays);

  std::printf("scene %s: %zu triangles, %zu emissive, sun %s, sky %s; loaded in %.2f s, BVH in %.2f s\n",
              o.scene.string().c_str(), scene->triangles.size(), scene->emissiveTriangles.size(),
              scene->sun ? "yes" : "no", scene->sky ? "yes" : "no", loadSeconds, buildSeconds);
  std::printf("%d samples at random vertices, %d paths each, at most %d bounces, Russian roulette from %d; "
              "%d raw rays; %d rounds\n",
              o.samples, o.spp, o.maxBounces, settings.russianRouletteDepth, o.rawRays, o.rounds);
  ShadeCounters work;
  const Rates one = Measure(**rays, shader, inputs, rawRays, 1, o.rounds, work);
  Report("single thread", 1, one, work);
  if (o.threads > 1) {
    const Rates all = Measure(**rays, shader, inputs, rawRays, o.threads, o.rounds, work);
    Report("all threads", o.threads, all, work);
    std::printf("scaling      shader %.2fx, raw closest-hit %.2fx on %d threads\n", all.rays / one.rays,
                all.rawClosest / one.rawClosest, o.threads);
  }
  return 0;
}

}  // namespace
}  // namespace penumbra

int main(int argc, char** argv) {
  penumbra::Options o;
  CLI::App app{"Renderer shading throughput against raw Embree rates measured in the same run"};
  app.add_option("--scene", o.scene, "scene file (.json or a mesh)");
  app.add_option("--samples", o.samples, "vertex samples to shade")->check(CLI::NonNegativeNumber);
  app.add_option("--spp", o.spp, "paths per sample")->check(CLI::NonNegativeNumber);
  app.add_option("--max-bounces", o.maxBounces, "bounces after the sample (0: direct light)")->check(CLI::NonNegativeNumber);
  app.add_option("--raw-rays", o.rawRays, "rays per raw Embree measurement")->check(CLI::NonNegativeNumber);
  app.add_option("--threads", o.threads, "threads for the parallel run")->check(CLI::NonNegativeNumber);
  app.add_option("--rounds", o.rounds, "measurement rounds; medians are reported")->check(CLI::NonNegativeNumber);
  CLI11_PARSE(app, argc, argv);
  return penumbra::Run(o);
}

// cache_snapshot_bench: what a snapshot of the SMA's cache (--cache-dir)
// costs at a given size, on a real scene: the hierarchy is refined at random
// leaves until it has --midpoints midpoint vertices, every vertex gets a
// sample, and the bench times the copy under the state lock, encoding,
// the atomic write (with fsync), and the restore (read, check, replay), next
// to building the scene's bare hierarchy, which a start without a cache does
// too. Prints one line per figure.
//
//   build/bench/cache_snapshot_bench --scene scenes/sponza.json --midpoints 1000000 --dir /tmp

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <random>
#include <shared_mutex>

#include <CLI/CLI.hpp>

#include "penumbra/common/logging.h"
#include "penumbra/common/scene.h"
#include "penumbra/sma/cache_snapshot.h"

int main(int argc, char** argv) {
  using namespace penumbra;
  using namespace penumbra::sma;
  using Clock = std::chrono::steady_clock;
  CLI::App app{"cache_snapshot_bench: size and time of an SMA cache snapshot"};
  std::string scenePath = std::string(PENUMBRA_SOURCE_DIR) + "/scenes/sponza.json";
  size_t midpoints = 1000000;
  std::string dir = std::filesystem::temp_directory_path().string();
  app.add_option("--scene", scenePath, "Scene file")->capture_default_str();
  app.add_option("--midpoints", midpoints, "Midpoint vertices to make by refinement")->capture_default_str();
  app.add_option("--dir", dir, "Directory for the snapshot file")->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  if (!SetupLogging("warn")) return 2;
  const auto ms = [](Clock::duration d) { return std::chrono::duration<double, std::milli>(d).count(); };

  auto scene = LoadScene(scenePath);
  if (!scene) {
    std::fprintf(stderr, "cache_snapshot_bench: %s\n", scene.error().message.c_str());
    return 1;
  }
  auto t0 = Clock::now();
  Hierarchy hierarchy(*scene);
  const double bareMs = ms(Clock::now() - t0);
  std::mt19937 rng(1);
  RefineOptions options;
  options.maxDepth = 12;
  const size_t target = hierarchy.BaseVertexCount() + midpoints;
  t0 = Clock::now();
  while (hierarchy.VertexCount() < target)
    hierarchy.Refine(NodeId(std::uniform_int_distribution<size_t>(0, hierarchy.NodeCount() - 1)(rng)), options);
  const double refineMs = ms(Clock::now() - t0);
  SampleCache cache;
  cache.Reserve(hierarchy.VertexCount());
  std::vector<ShadedSample> samples;
  samples.reserve(hierarchy.VertexCount());
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (VertexId v = 0; v < hierarchy.VertexCount(); ++v)
    samples.push_back(ShadedSample{.vertex = v, .radiance = Rgb(u(rng)), .irradiance = Rgb(u(rng)), .paths = 64});
  cache.Store(samples);

  std::shared_mutex mutex;
  t0 = Clock::now();
  const CacheSnapshotData data = CaptureCacheSnapshot(mutex, hierarchy, cache);
  const double copyMs = ms(Clock::now() - t0);
  t0 = Clock::now();
  const std::string bytes = EncodeCacheSnapshot(data);
  const double encodeMs = ms(Clock::now() - t0);
  const std::filesystem::path file = std::filesystem::path(dir) / "cache_snapshot_bench.snapshot";
  t0 = Clock::now();
  if (auto written = WriteFileAtomically(file, bytes); !written) {
    std::fprintf(stderr, "cache_snapshot_bench: %s\n", written.error().message.c_str());
    return 1;
  }
  const double writeMs = ms(Clock::now() - t0);
  t0 = Clock::now();
  auto read = ReadWholeFile(file, uint64_t(1) << 36);
  auto restored = read ? DecodeCacheSnapshot(*read, *scene, RadianceBounds{}) : Expected<RestoredCache>(read.error());
  const double restoreMs = ms(Clock::now() - t0);
  std::filesystem::remove(file);
  if (!restored) {
    std::fprintf(stderr, "cache_snapshot_bench: restore failed: %s\n", restored.error().message.c_str());
    return 1;
  }
  std::printf("scene %s: %zu triangles, %zu base vertices\n", scene->name.c_str(), scene->triangles.size(),
              hierarchy.BaseVertexCount());
  std::printf("hierarchy: %zu nodes, %zu vertices (%zu splits), refined in %.0f ms; bare hierarchy built in %.1f ms\n",
              hierarchy.NodeCount(), hierarchy.VertexCount(), data.splits.size(), refineMs, bareMs);
  std::printf("snapshot: %zu samples, %zu bytes (%.1f MB)\n", data.samples.size(), bytes.size(), double(bytes.size()) / 1e6);
  const size_t holds = 1 + (hierarchy.NodeCount() + 16383) / 16384 + (hierarchy.VertexCount() + 16383) / 16384;
  std::printf("copy under the shared lock: %.1f ms in %zu holds (%.2f ms per hold on average)\n", copyMs, holds,
              copyMs / double(holds));
  std::printf("encode: %.1f ms; write + fsync + rename + fsync dir: %.1f ms\n", encodeMs, writeMs);
  std::printf("restore (read, check, replay %zu splits): %.1f ms, of which a bare hierarchy ~%.1f ms\n",
              restored->splits, restoreMs, bareMs);
  return 0;
}

// sma_memory_bench: what the SMA's data occupies on a real scene (issue 15),
// in its accounting (Hierarchy/SampleCache::MemoryBytes) and in resident
// memory, at three moments:
//   bare      -- the hierarchy and the cache as the SMA builds them at start
//                (SmaServer: Hierarchy(scene), cache.Reserve(VertexCount()));
//   region    -- after a region is "seen": the corners of every base triangle
//                whose centroid lies within --radius of a camera preset's eye
//                are shaded, those triangles refined --levels times (1 -> 4
//                with propagation) and every new vertex shaded: what a client
//                looking around there makes the SMA hold;
//   everything-- the same for every triangle at --levels 0 (every base
//                vertex shaded): what a long walk through the whole model
//                reaches without refinement.
// RSS is the process's (the scene itself included), printed as a difference
// from just after the scene loaded.
//
// --lookup-rounds N (0: skipped) also times Hierarchy::GetVertex on the base
// vertices, whose records are made on first use, against the eager table it
// replaced (a ChunkedArray<SampleVertex> holding the same records: what
// GetVertex indexed before), in the same run: the first pass (which makes
// the records), then N rounds of each, median ns per read, in two orders:
// the roots' corners in root order (as delta building and sample requests
// meet them) and a random permutation (the worst case for the chunk table).
//
//   build/bench/sma_memory_bench --scene scenes/sponza.json --camera atrium --radius 4 --levels 2
//   build/bench/sma_memory_bench --scene scenes/street.json --lookup-rounds 7

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "penumbra/common/logging.h"
#include "penumbra/common/metrics.h"
#include "penumbra/common/scene.h"
#include "order_statistics.h"
#include "penumbra/sma/chunked_array.h"
#include "penumbra/sma/hierarchy.h"
#include "penumbra/sma/sample_cache.h"

int main(int argc, char** argv) {
  using namespace penumbra;
  using namespace penumbra::sma;
  CLI::App app{"sma_memory_bench: the SMA's data in bytes on a real scene"};
  std::string scenePath = std::string(PENUMBRA_SOURCE_DIR) + "/scenes/sponza.json";
  std::string camera = "atrium";
  float radius = 4.0f;
  int levels = 2;
  int lookupRounds = 0;
  app.add_option("--scene", scenePath, "Scene file")->capture_default_str();
  app.add_option("--camera", camera, "Camera preset whose eye is the region's centre")->capture_default_str();
  app.add_option("--radius", radius, "Region radius in scene units")->capture_default_str();
  app.add_option("--levels", levels, "Refinements of the region's triangles")->capture_default_str();
  app.add_option("--lookup-rounds", lookupRounds, "Rounds of the GetVertex timing (0: skip it)")
      ->check(CLI::Range(0, 1000))
      ->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  if (!SetupLogging("warn")) return 2;

  auto scene = LoadScene(scenePath);
  if (!scene) {
    std::fprintf(stderr, "sma_memory_bench: %s\n", scene.error().message.c_str());
    return 1;
  }
  const CameraPreset* preset = nullptr;
  for (const CameraPreset& p : scene->cameras)
    if (p.name == camera) preset = &p;
  if (!preset) {
    std::fprintf(stderr, "sma_memory_bench: the scene has no camera preset '%s'\n", camera.c_str());
    return 1;
  }
  constexpr double kMiB = 1024.0 * 1024.0;
  const double rssLoaded = double(metrics::ResidentMemoryBytes().value_or(0));
  const auto print = [&](const char* what, const Hierarchy& h, const SampleCache& cache) {
    const double rss = double(metrics::ResidentMemoryBytes().value_or(0));
    std::printf("%-10s nodes %9zu  vertices %9zu  shaded %9zu  hierarchy %8.1f MiB  cache %8.1f MiB  "
                "total %8.1f MiB  rss-since-load %8.1f MiB\n",
                what, h.NodeCount(), h.VertexCount(), cache.ShadedCount(), double(h.MemoryBytes()) / kMiB,
                double(cache.MemoryBytes()) / kMiB, double(h.MemoryBytes() + cache.MemoryBytes()) / kMiB,
                (rss - rssLoaded) / kMiB);
  };
  std::printf("scene %s: %zu triangles, %zu vertices, %s\n", scene->name.c_str(), scene->triangles.size(),
              scene->vertices.size(), scene->twoSided ? "two-sided" : "one-sided");

  const auto shade = [](const Hierarchy& h, SampleCache& cache, const std::vector<VertexId>& vertices) {
    std::vector<ShadedSample> samples;
    samples.reserve(vertices.size());
    for (VertexId v : vertices) samples.push_back(ShadedSample{.vertex = v, .radiance = Rgb(0.5f), .paths = 16});
    cache.Store(samples);
    (void)h;
  };
  const auto seeRegion = [&](Hierarchy& h, SampleCache& cache, float r, int refineLevels) {
    std::vector<NodeId> roots;
    for (uint32_t t = 0; t < scene->triangles.size(); ++t) {
      const auto& v = scene->triangles[t].v;
      const Vec3 c = (scene->vertices[v[0]].position + scene->vertices[v[1]].position +
                      scene->vertices[v[2]].position) / 3.0f;
      if (glm::length(c - preset->pose.eye) <= r) {
        roots.push_back(h.RootOf(t, false));
        if (h.TwoSided()) roots.push_back(h.RootOf(t, true));
      }
    }
    std::vector<VertexId> corners;
    for (NodeId id : roots)
      for (VertexId v : h.GetNode(id).v) corners.push_back(v);
    shade(h, cache, corners);
    std::vector<NodeId> leaves = roots;
    RefineOptions options;
    for (int level = 0; level < refineLevels; ++level) {
      std::vector<NodeId> next;
      for (NodeId id : leaves) {
        if (!h.GetNode(id).IsLeaf()) continue;
        const RefineResult result = h.Refine(id, options);
        cache.Reserve(h.VertexCount());
        shade(h, cache, result.newVertices);
        for (NodeId split : result.split) {
          const Node& n = h.GetNode(split);
          for (uint8_t c = 0; c < n.childCount; ++c) next.push_back(n.firstChild + c);
        }
      }
      leaves = std::move(next);
    }
    return roots.size();
  };

  {
    Hierarchy h(*scene);
    SampleCache cache;
    cache.Reserve(h.VertexCount());
    print("bare", h, cache);
    const size_t roots = seeRegion(h, cache, radius, levels);
    std::printf("region: %zu roots within %.1f of '%s', refined %d levels\n", roots, double(radius), camera.c_str(),
                levels);
    print("region", h, cache);
  }
  {
    Hierarchy h(*scene);
    SampleCache cache;
    cache.Reserve(h.VertexCount());
    seeRegion(h, cache, 1e30f, 0);
    print("everything", h, cache);
  }
  if (lookupRounds > 0) {
    const Hierarchy h(*scene);
    std::vector<VertexId> corners;  // the roots' corners, root by root
    for (NodeId r = 0; r < h.RootCount(); ++r)
      for (VertexId v : h.GetNode(r).v) corners.push_back(v);
    std::vector<VertexId> shuffled(h.BaseVertexCount());
    for (VertexId v = 0; v < shuffled.size(); ++v) shuffled[v] = v;
    std::shuffle(shuffled.begin(), shuffled.end(), std::mt19937(1));
    using Clock = std::chrono::steady_clock;
    uint64_t sink = 0;  // printed, so the reads are not optimised away
    const auto nsPerRead = [&](const std::vector<VertexId>& ids, auto read) {
      // An integer sum: a float one would be kept on the stack across the
      // (cold) call that makes records, timing a store-to-load chain.
      uint64_t sum = 0;
      const auto start = Clock::now();
      for (VertexId v : ids) sum += read(v).point;
      const auto end = Clock::now();
      sink += sum;
      return std::chrono::duration<double, std::nano>(end - start).count() / double(ids.size());
    };
    const auto lazy = [&](VertexId v) -> const SampleVertex& { return h.GetVertex(v); };
    const double firstUse = nsPerRead(corners, lazy);  // makes the records
    ChunkedArray<SampleVertex> eager;
    eager.resize(h.BaseVertexCount());
    for (VertexId v = 0; v < h.BaseVertexCount(); ++v) eager[v] = h.GetVertex(v);
    const auto table = [&](VertexId v) -> const SampleVertex& { return eager[v]; };
    std::printf("GetVertex over %zu base vertices: first use (making the records) %.2f ns per read\n",
                h.BaseVertexCount(), firstUse);
    for (const auto& [name, ids] : {std::pair{"root corners", &corners}, std::pair{"shuffled", &shuffled}}) {
      std::vector<double> lazyNs, eagerNs;
      for (int round = 0; round < lookupRounds; ++round) {
        lazyNs.push_back(nsPerRead(*ids, lazy));
        eagerNs.push_back(nsPerRead(*ids, table));
      }
      const double l = bench::Median(lazyNs), e = bench::Median(eagerNs);
      std::printf("  %-12s %9zu reads: made on first use %.2f ns, eager table %.2f ns (median of %d): ratio %.2f\n",
                  name, ids->size(), l, e, lookupRounds, l / e);
    }
    std::printf("(checksum %llu)\n", static_cast<unsigned long long>(sink));
  }
  return 0;
}

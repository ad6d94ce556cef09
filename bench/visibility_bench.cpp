// SMA visibility per view: VisibilityTracer::Trace, MapHitsToNodes, and the
// two together, against raw Embree rates measured in the same run.
//
// One still view (a camera preset, default Sponza's "atrium" at 1280x720) is
// measured in interleaved rounds, so that the load other processes put on
// the shared machine falls on every figure alike. A round runs, on the same
// rays: the raw baselines (one rtcIntersect1 per pixel, on one thread; the
// 4x4 rtcIntersect16 packets Trace uses, recording nothing, on one thread
// and on every thread at once), Trace on one thread, then Trace, Map
// (unrefined and refined) and Trace + Map on all threads. Map's refined
// hierarchy comes from refining every visible leaf a few times; its
// predicate is the SMA's (descend once the split's vertices are shaded),
// with every vertex shaded. Then, if the scene has the camera path, every
// frame of a walk along it is traced and mapped.
//
//   visibility_bench [--scene scenes/sponza.json] [--camera atrium] [--width 1280] [--height 720]
//                    [--rounds 100] [--refine 2] [--path walk] [--frames 120] [--threads N]

#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include <CLI/CLI.hpp>

#include "order_statistics.h"
#include "penumbra/common/logging.h"
#include "penumbra/common/scene.h"
#include "penumbra/sma/hierarchy.h"
#include "penumbra/sma/visibility.h"

namespace penumbra::sma {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

struct Options {
  fs::path scene = fs::path(PENUMBRA_SOURCE_DIR) / "scenes" / "sponza.json";
  std::string camera = "atrium";
  int width = 1280;
  int height = 720;
  int rounds = 100;
  int refine = 2;   // times every visible leaf is refined for the refined map
  std::string path = "walk";
  int frames = 120;
  int threads = int(std::max(1u, std::thread::hardware_concurrency()));
};

// One value per run of a measurement: milliseconds, or a ratio of rates.
class Samples {
 public:
  template <class F>
  void Time(F&& f) {
    const auto start = Clock::now();
    f();
    Add(std::chrono::duration<double, std::milli>(Clock::now() - start).count());
  }
  void Add(double value) { values_.push_back(value); }
  double Last() const { return values_.back(); }
  double Percentile(double p) const { return bench::Percentile(values_, p); }
  double P50() const { return Percentile(50.0); }
  double Best() const { return *std::min_element(values_.begin(), values_.end()); }
  size_t Count() const { return values_.size(); }

 private:
  std::vector<double> values_;
};

// The SMA's predicate (server.cpp): descend once every vertex the split
// added is shaded. Here a byte per vertex, all set.
bool ChildrenShaded(const Node& node, const void* context) {
  const auto& shaded = *static_cast<const std::vector<uint8_t>*>(context);
  for (VertexId m : node.mid)
    if (m != kNoVertex && !shaded[m]) return false;
  return true;
}

bool DescendAlways(const Node&, const void*) { return true; }

// Splits every leaf seen in `hits` once per round, re-tracing nothing: the
// hits stay valid, only the mapping deepens.
void RefineVisibleLeaves(Hierarchy& hierarchy, const HitBuffer& hits, int rounds) {
  VisibleSet visible;
  for (int round = 0; round < rounds; ++round) {
    MapHitsToNodes(hierarchy, hits, DescendAlways, nullptr, visible);
    for (NodeId node : visible.nodes)
      if (hierarchy.GetNode(node).IsLeaf()) hierarchy.Refine(node, RefineOptions{});
  }
}

void PrintHeader(const std::string& title) {
  std::printf("\n  %-34s %8s %8s %8s %9s\n", title.c_str(), "best ms", "p50 ms", "p99 ms", "Mpixel/s");
}

void PrintRow(const char* label, const Samples& t, double pixels) {
  std::printf("  %-34s %8.2f %8.2f %8.2f %9.1f   (%zu runs)\n", label, t.Best(), t.P50(), t.Percentile(99.0),
              pixels / (t.P50() * 1e3), t.Count());
}

int Run(const Options& o) {
  SetupLogging("warn");  // quiet about BVH builds; errors still show
  auto loadStart = Clock::now();
  auto scene = LoadScene(o.scene);
  const fs::path shared = (fs::path(PENUMBRA_SOURCE_DIR) / ".." / "shared").lexically_normal();
  if (!scene && !fs::exists(shared)) {
    std::printf("visibility_bench: skipped: %s is absent, and with it the benchmark scene's mesh (%s)\n",
                shared.c_str(), scene.error().message.c_str());
    return 0;
  }
  if (!scene) {
    std::fprintf(stderr, "visibility_bench: %s\n", scene.error().message.c_str());
    return 1;
  }
  const double loadSeconds = std::chrono::duration<double>(Clock::now() - loadStart).count();
  const CameraPreset* preset = scene->FindCamera(o.camera);
  if (!preset) {
    std::fprintf(stderr, "visibility_bench: %s has no camera \"%s\"\n", o.scene.c_str(), o.camera.c_str());
    return 1;
  }
  const CameraView view{preset->pose, preset->fovYDeg, o.width, o.height};
  if (auto ok = ValidateCameraView(view); !ok) {
    std::fprintf(stderr, "visibility_bench: %s\n", ok.error().message.c_str());
    return 1;
  }

  tbb::task_arena all(o.threads), one(1);
  const auto buildStart = Clock::now();
  auto built = all.execute([&] { return VisibilityTracer::Build(*scene); });
  if (!built) {
    std::fprintf(stderr, "visibility_bench: %s\n", built.error().message.c_str());
    return 1;
  }
  const VisibilityTracer& tracer = **built;
  const double buildSeconds = std::chrono::duration<double>(Clock::now() - buildStart).count();

  HitBuffer hits;
  all.execute([&] { tracer.Trace(view, hits); });
  const Hierarchy unrefined(*scene);
  Hierarchy refined(*scene);
  const auto refineStart = Clock::now();
  all.execute([&] { RefineVisibleLeaves(refined, hits, o.refine); });
  const double refineSeconds = std::chrono::duration<double>(Clock::now() - refineStart).count();
  const std::vector<uint8_t> shaded(refined.VertexCount(), 1);
  VisibleSet visibleUnrefined, visibleRefined;
  all.execute([&] {
    MapHitsToNodes(unrefined, hits, ChildrenShaded, &shaded, visibleUnrefined);
    MapHitsToNodes(refined, hits, ChildrenShaded, &shaded, visibleRefined);
  });
  const double pixels = double(view.width) * double(view.height);
  const size_t background = size_t(std::count(visibleRefined.pixelNode.begin(), visibleRefined.pixelNode.end(), kNoNode));

  std::printf("scene %s: %zu triangles; loaded in %.2f s, BVH (high quality) in %.2f s\n", o.scene.c_str(),
              scene->triangles.size(), loadSeconds, buildSeconds);
  std::printf("view \"%s\" %dx%d, %zu background pixels; %d threads; %d rounds\n", o.camera.c_str(), view.width,
              view.height, background, o.threads, o.rounds);
  std::printf("unrefined: %zu nodes, %zu visible; refined (every visible leaf %d times, %.1f s): %zu nodes, "
              "%zu visible\n",
              unrefined.NodeCount(), visibleUnrefined.nodes.size(), o.refine, refineSeconds, refined.NodeCount(),
              visibleRefined.nodes.size());

  Samples rawSingle, rawPackets, rawPacketsAll, traceOne, trace, mapUnrefined, mapRefined, totalUnrefined, totalRefined;
  // Ratios of rates within each round, where the load from other processes
  // is nearly the same for both sides.
  Samples packetsOverSingle, traceOneOverPackets, traceOverPackets, traceOverPacketsAll;
  size_t rawSingleHits = 0, rawPacketHits = 0;
  for (int round = 0; round < o.rounds; ++round) {
    rawSingle.Time([&] { rawSingleHits = tracer.TraceRaw(view, RawTrace::kSingleRays); });
    rawPackets.Time([&] { rawPacketHits = tracer.TraceRaw(view, RawTrace::kPackets); });
    // The raw packets on every thread at once, each tracing the whole view:
    // what Embree delivers with the cores the machine gives us right now.
    all.execute([&] {
      const auto start = Clock::now();
      tbb::parallel_for(
          0, o.threads, [&](int) { tracer.TraceRaw(view, RawTrace::kPackets); }, tbb::simple_partitioner());
      rawPacketsAll.Add(std::chrono::duration<double, std::milli>(Clock::now() - start).count() / o.threads);
    });
    one.execute([&] { traceOne.Time([&] { tracer.Trace(view, hits); }); });
    all.execute([&] {
      trace.Time([&] { tracer.Trace(view, hits); });
      mapUnrefined.Time([&] { MapHitsToNodes(unrefined, hits, ChildrenShaded, &shaded, visibleUnrefined); });
      mapRefined.Time([&] { MapHitsToNodes(refined, hits, ChildrenShaded, &shaded, visibleRefined); });
      totalUnrefined.Time([&] {
        tracer.Trace(view, hits);
        MapHitsToNodes(unrefined, hits, ChildrenShaded, &shaded, visibleUnrefined);
      });
      totalRefined.Time([&] {
        tracer.Trace(view, hits);
        MapHitsToNodes(refined, hits, ChildrenShaded, &shaded, visibleRefined);
      });
    });
    packetsOverSingle.Add(rawSingle.Last() / rawPackets.Last());
    traceOneOverPackets.Add(rawPackets.Last() / traceOne.Last());
    traceOverPackets.Add(rawPackets.Last() / trace.Last());
    traceOverPacketsAll.Add(rawPacketsAll.Last() / trace.Last());
  }
  std::printf("rays that hit: Trace %zu, raw single rays %zu, raw packets %zu\n", size_t(pixels) - background,
              rawSingleHits, rawPacketHits);

  PrintHeader("per view");
  PrintRow("raw rtcIntersect1, 1 thread", rawSingle, pixels);
  PrintRow("raw rtcIntersect16, 1 thread", rawPackets, pixels);
  PrintRow("raw rtcIntersect16, all threads", rawPacketsAll, pixels);
  PrintRow("Trace, 1 thread", traceOne, pixels);
  PrintRow("Trace", trace, pixels);
  PrintRow("Map, unrefined", mapUnrefined, pixels);
  PrintRow("Map, refined", mapRefined, pixels);
  PrintRow("Trace + Map, unrefined", totalUnrefined, pixels);
  PrintRow("Trace + Map, refined", totalRefined, pixels);
  std::printf("\n  ratios of rates, same rays, median over rounds\n");
  std::printf("  raw packets / raw single rays, 1 thread     %5.2f\n", packetsOverSingle.P50());
  std::printf("  Trace / raw packets, 1 thread               %5.2f   (1: no cost beyond Embree's)\n",
              traceOneOverPackets.P50());
  std::printf("  Trace / raw packets, %d threads              %5.2f   (1: no cost beyond Embree's)\n", o.threads,
              traceOverPacketsAll.P50());
  std::printf("  Trace %d threads / raw packets 1 thread      %5.2f   (%d: perfect scaling on idle cores)\n",
              o.threads, traceOverPackets.P50(), o.threads);
  std::printf("  raw packets %d threads / 1 thread            %5.2f   (the cores the machine gave us)\n",
              o.threads, rawPackets.P50() / rawPacketsAll.P50());

  const CameraPath* path = scene->FindPath(o.path);
  if (!path) {
    std::printf("\nno camera path \"%s\" in the scene: walk skipped\n", o.path.c_str());
    return 0;
  }
  // The walk maps with the unrefined hierarchy and with the refined one,
  // whose refinement sits where the atrium view looked.
  Samples walkTrace, walkMapUnrefined, walkMapRefined;
  all.execute([&] {
    for (int frame = 0; frame < o.frames; ++frame) {
      const double t = path->DurationSeconds() * double(frame) / double(std::max(1, o.frames - 1));
      const CameraView frameView = path->ViewAt(path->keyframes.front().timeSeconds + t);
      walkTrace.Time([&] { tracer.Trace(frameView, hits); });
      walkMapUnrefined.Time([&] { MapHitsToNodes(unrefined, hits, ChildrenShaded, &shaded, visibleUnrefined); });
      walkMapRefined.Time([&] { MapHitsToNodes(refined, hits, ChildrenShaded, &shaded, visibleRefined); });
    }
  });
  const double walkPixels = double(path->width) * double(path->height);
  std::printf("\nwalk \"%s\": %d frames over %.1f s at %dx%d\n", o.path.c_str(), o.frames, path->DurationSeconds(),
              path->width, path->height);
  PrintHeader("per frame");
  PrintRow("Trace", walkTrace, walkPixels);
  PrintRow("Map, unrefined", walkMapUnrefined, walkPixels);
  PrintRow("Map, refined", walkMapRefined, walkPixels);
  return 0;
}

}  // namespace
}  // namespace penumbra::sma

int main(int argc, char** argv) {
  penumbra::sma::Options o;
  CLI::App app{"SMA visibility (trace and map) per view, against raw Embree rates measured in the same run"};
  app.add_option("--scene", o.scene, "scene file (.json or a mesh)");
  app.add_option("--camera", o.camera, "camera preset of the still view");
  app.add_option("--width", o.width, "pixels")->check(CLI::Range(1, 16384));
  app.add_option("--height", o.height, "pixels")->check(CLI::Range(1, 16384));
  app.add_option("--rounds", o.rounds, "interleaved measurement rounds")->check(CLI::PositiveNumber);
  app.add_option("--refine", o.refine, "times every visible leaf is refined")->check(CLI::NonNegativeNumber);
  app.add_option("--path", o.path, "camera path to walk");
  app.add_option("--frames", o.frames, "frames of the walk")->check(CLI::PositiveNumber);
  app.add_option("--threads", o.threads, "TBB threads for the parallel runs")->check(CLI::PositiveNumber);
  CLI11_PARSE(app, argc, argv);
  return penumbra::sma::Run(o);
}

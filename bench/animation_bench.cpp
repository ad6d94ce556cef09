// Movement prediction for moving objects (issue 15), end to end on real
// processes: the SMA plays a scene's animation path on its own clock while a
// scripted client watches a view; the same run is made with
// --move-prediction off, then on (fresh renderer + SMA each, one after the
// other on the same cores).
//
// Per scene epoch the client receives a MOVED delta, then RESHADED deltas
// with the radiance the move changed. Measured, per run, over --seconds after
// the view's stage 1:
//   * the update lag: from a MOVED delta to the first RESHADED delta at its
//     epoch or later (the shadow starting to follow the object);
//   * in time: the fraction of epochs whose first RESHADED arrived before
//     the next MOVED (the display caught up within the step);
//   * vertices updated per epoch (RESHADED vertices at exactly that epoch);
//   * the display's error while it moves: sampled every 100 ms, the share of
//     the vertices the client holds that still show a sample of an older
//     pose (awaiting their reshade);
//   * the SMA's counters: predictions, hits, prepared samples stored,
//     samples shaded in all.
// The figures are printed side by side with on/off ratios from the same
// invocation.
//
//   animation_bench [--scene scenes/cornell-box-animated.json] [--camera front] [--hz 10]
//                   [--seconds 10] [--warmup 60] [--width 320 --height 240] [--spp 32] [--max-bounces 8]

#include <algorithm>
#include <cstdio>
#include <map>

#include <CLI/CLI.hpp>

#include "order_statistics.h"
#include "penumbra/common/logging.h"
#include "sma_stack.h"

namespace penumbra {
namespace {

namespace fs = std::filesystem;
using namespace penumbra::testing;
using namespace penumbra::bench;
using namespace std::chrono_literals;

struct Options {
  fs::path scene = fs::path(PENUMBRA_SOURCE_DIR) / "scenes/cornell-box-animated.json";
  std::string camera = "front";
  double hz = 10.0;
  double seconds = 10.0;
  double warmup = 60.0;
  int width = 320;
  int height = 240;
  int spp = 32;
  int maxBounces = 8;
};

struct RunFigures {
  std::vector<double> staleShare;  // sampled every 100 ms: held vertices awaiting their reshade / held
  std::vector<double> lagsMs;
  size_t epochs = 0;
  size_t inTime = 0;
  std::vector<double> updatedPerEpoch;
  std::map<std::string, double> counters;
};

Expected<RunFigures> RunOnce(const Options& o, bool predict) {
  SmaStackOptions so;
  so.scene = o.scene;
  so.rendererExe = PENUMBRA_RENDERER_EXE;
  so.smaExe = PENUMBRA_SMA_EXE;
  so.rendererThreads = 2;
  so.spp = o.spp;
  so.maxBounces = o.maxBounces;
  so.smaArgs = {"--move-prediction", predict ? "on" : "off", "--animation-hz", fmt::format("{}", o.hz)};
  auto stack = StartSmaStack(so);
  if (!stack) return stack.error();
  auto client = SmaTestClient::Connect(stack->sma.port, "animation-bench");
  if (!client) return client.error();
  auto view = ViewFromPreset(client->Info(), o.camera, o.width, o.height);
  if (!view) return view.error();
  // Stage 1, or --warmup seconds at most: with the object moving all along
  // (and the machine loaded) stage 1 may keep being put off by the moves.
  const auto warmup = std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::duration<double>(o.warmup));
  auto stage1 = TimeView(*client, *view, 1, warmup, /*untilStage1=*/true);
  if (!stage1 && stage1.error().message.find("not converged") == std::string::npos) return stage1.error();
  if (!stage1) std::printf("# prediction %s: stage 1 not reached in %.0f s; measuring from there\n", predict ? "on" : "off", o.warmup);

  RunFigures f;
  std::map<uint64_t, Clock::time_point> movedAt;  // epochs awaiting their first RESHADED
  std::map<uint64_t, double> updated;             // RESHADED vertices per epoch
  uint64_t lastMoved = 0;
  bool lastMovedAnswered = true;
  const auto end = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(o.seconds));
  // The display's error while the object moves: every 100 ms, the share of
  // the vertices the client holds that still show a sample of an older pose
  // (the SMA's per-client counters; answered in the stream, read below).
  constexpr uint64_t kStatsIds = uint64_t(1) << 40;
  uint64_t statsSent = 0;
  auto nextStats = Clock::now();
  while (Clock::now() < end) {
    if (Clock::now() >= nextStats) {
      wire::Envelope stats;
      stats.mutable_stats_request()->set_request_id(kStatsIds + statsSent++);
      client->Wire().Send(stats);  // also keeps the connection alive
      nextStats += 100ms;
    }
    auto e = client->Wire().Receive(10ms);
    if (!e && e.error().message == "timeout") continue;
    if (!e) return e.error();
    if (e->has_stats_reply() && e->stats_reply().request_id() >= kStatsIds) {
      double held = 0.0, awaited = 0.0;
      for (const auto& c : e->stats_reply().counters()) {
        if (c.name() == "client_vertices_held") held = c.value();
        if (c.name() == "client_reshades_awaited") awaited = c.value();
      }
      if (held > 0.0) f.staleShare.push_back(awaited / held);
      continue;
    }
    if (e->has_delta()) {
      const wire::Delta& d = e->delta();
      const auto now = Clock::now();
      if (d.kind() == wire::DELTA_KIND_MOVED && d.scene_epoch() > lastMoved) {
        if (lastMoved != 0) {
          ++f.epochs;
          f.inTime += lastMovedAnswered;
        }
        lastMoved = d.scene_epoch();
        lastMovedAnswered = false;
        movedAt[lastMoved] = now;
      }
      if (d.kind() == wire::DELTA_KIND_RESHADED) {
        updated[d.scene_epoch()] += double(d.updated_vertex_ids_size());
        for (auto it = movedAt.begin(); it != movedAt.end() && it->first <= d.scene_epoch();) {
          f.lagsMs.push_back(Ms(now - it->second));
          if (it->first == lastMoved) lastMovedAnswered = true;
          it = movedAt.erase(it);
        }
      }
    }
    if (auto ok = client->Apply(*e); !ok) return ok.error();
  }
  for (const auto& [epoch, n] : updated) f.updatedPerEpoch.push_back(n);
  for (const char* name : {"moves", "move_predictions", "move_predictions_hit", "move_predictions_missed",
                           "samples_prepared", "samples_prepared_stored", "samples_prepared_dropped",
                           "samples_reshaded_after_move", "samples_stale_refused", "samples_shaded",
                           "last_prepare_ms"}) {
    auto v = client->Counter(name);
    if (!v) return v.error();
    f.counters[name] = *v;
  }
  return f;
}

int Run(const Options& o) {
  SetupLogging("warn");
  std::printf("# animation_bench: %s, camera %s, %dx%d, animation %.0f Hz, %.0f s per run, renderer --spp %d "
              "--max-bounces %d; load %s\n",
              o.scene.filename().string().c_str(), o.camera.c_str(), o.width, o.height, o.hz, o.seconds, o.spp,
              o.maxBounces, LoadAverage().c_str());
  std::map<bool, RunFigures> runs;
  for (bool predict : {false, true}) {
    auto f = RunOnce(o, predict);
    if (!f) {
      std::fprintf(stderr, "animation_bench: prediction %s: %s\n", predict ? "on" : "off", f.error().message.c_str());
      return 1;
    }
    runs[predict] = std::move(*f);
  }
  const RunFigures& off = runs[false];
  const RunFigures& on = runs[true];
  const auto row = [](const char* name, double a, double b, bool ratio) {
    if (ratio && b > 0)
      std::printf("%-44s %12.1f %12.1f %9.2fx\n", name, a, b, a / b);
    else
      std::printf("%-44s %12.1f %12.1f\n", name, a, b);
  };
  std::printf("\n%-44s %12s %12s %10s\n", "", "off", "on", "off/on");
  row("epochs watched", double(off.epochs), double(on.epochs), false);
  row("update lag p50 (ms, MOVED -> first RESHADED)", Percentile(off.lagsMs, 50), Percentile(on.lagsMs, 50), true);
  row("update lag p90 (ms)", Percentile(off.lagsMs, 90), Percentile(on.lagsMs, 90), true);
  row("update lag p99 (ms)", Percentile(off.lagsMs, 99), Percentile(on.lagsMs, 99), true);
  row("epochs updated before the next MOVED (%)", off.epochs ? 100.0 * double(off.inTime) / double(off.epochs) : 0.0,
      on.epochs ? 100.0 * double(on.inTime) / double(on.epochs) : 0.0, false);
  const auto mean = [](const std::vector<double>& v) {
    double sum = 0.0;
    for (double x : v) sum += x;
    return v.empty() ? 0.0 : sum / double(v.size());
  };
  row("held vertices showing an older pose, mean %", 100.0 * mean(off.staleShare), 100.0 * mean(on.staleShare), true);
  row("held vertices showing an older pose, p90 %", 100.0 * Percentile(off.staleShare, 90),
      100.0 * Percentile(on.staleShare, 90), true);
  row("RESHADED vertices per epoch, p50", Percentile(off.updatedPerEpoch, 50), Percentile(on.updatedPerEpoch, 50),
      false);
  for (const auto& [name, value] : on.counters) row(name.c_str(), off.counters.at(name), value, false);
  const double predictions = on.counters.at("move_predictions");
  std::printf("\nprediction hit rate: %.1f %% of %.0f predictions; prepared samples stored: %.1f %% of the re-shading "
              "after moves\n",
              predictions > 0 ? 100.0 * on.counters.at("move_predictions_hit") / predictions : 0.0, predictions,
              on.counters.at("samples_reshaded_after_move") > 0
                  ? 100.0 * on.counters.at("samples_prepared_stored") / on.counters.at("samples_reshaded_after_move")
                  : 0.0);
  return 0;
}

}  // namespace
}  // namespace penumbra

int main(int argc, char** argv) {
  penumbra::Options o;
  CLI::App app{"Movement prediction for an animated object: update lag with --move-prediction off and on"};
  app.add_option("--scene", o.scene);
  app.add_option("--camera", o.camera);
  app.add_option("--hz", o.hz)->check(CLI::Range(0.5, 100.0));
  app.add_option("--seconds", o.seconds)->check(CLI::Range(1.0, 600.0));
  app.add_option("--warmup", o.warmup, "Seconds at most to wait for the view's stage 1 before measuring")
      ->check(CLI::Range(1.0, 600.0));
  app.add_option("--width", o.width)->check(CLI::Range(16, 4096));
  app.add_option("--height", o.height)->check(CLI::Range(16, 4096));
  app.add_option("--spp", o.spp)->check(CLI::Range(1, 65536));
  app.add_option("--max-bounces", o.maxBounces)->check(CLI::Range(1, 64));
  CLI11_PARSE(app, argc, argv);
  return penumbra::Run(o);
}

// Camera movement prediction (issue 15) end to end, with views at fixed
// times: a renderer and an SMA as real processes on loopback, and a scripted
// client (tests/support/sma_client.h) that plays a scene's camera path,
// sending the path's pose every 1/rate s of wall time (the path slowed down
// by --speed) and applying every delta. The same script runs with
// --prediction off and on, alternating, --repeat times each (fresh processes
// and an empty cache every run).
//
// Figures, per mode (medians over the runs; hit rates from the summed counts):
//  * hit rate: of the triangles the client's new views newly displayed, the
//    fraction whose corners were already shaded when the view's visibility
//    was applied (SMA counters view_triangles_new_shaded / view_triangles_new);
//  * view -> complete display p50 / p99: from sending a view until the client
//    has a complete image (a delta saying stage 1 is over: refining or
//    converged) of it or of a later view -- a walking client's views are
//    mostly superseded before their own stage 1;
//  * predicted views traced and samples they asked for.
// Unlike bench/prediction_bench.sh (the GL headless client, whose frame rate
// and so its views follow the machine's load), the views here are the same in
// every run.

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "order_statistics.h"
#include "penumbra/common/logging.h"
#include "penumbra/common/scene.h"
#include "sma_stack.h"

namespace penumbra {
namespace {

using bench::Clock;
using bench::Ms;
using testing::SmaTestClient;

struct Options {
  std::string scene = std::string(PENUMBRA_SOURCE_DIR) + "/scenes/sponza.json";
  std::string path = "walk";
  double speed = 0.5;
  double rate = 5.0;
  int width = 320;
  int height = 240;
  int repeat = 3;
  int spp = 64;
  int maxBounces = 8;
  double horizon = 0.5;
  double widen = 1.15;
  double resolution = 0.5;  // the predicted view's size, times the view's
  double tailSeconds = 4.0;  // after the path's end, the client keeps reading
  std::string smaArgs;       // more SMA flags, split at spaces
};

struct RunFigures {
  double newTriangles = 0, newShaded = 0;
  std::vector<double> completeMs;  // per view sent
  size_t neverComplete = 0;
  double predictedViews = 0, samplesPredicted = 0;
};

Expected<RunFigures> RunOnce(const Options& o, const CameraPath& path, bool prediction) {
  bench::SmaStackOptions so;
  so.scene = o.scene;
  so.rendererExe = PENUMBRA_RENDERER_EXE;
  so.smaExe = PENUMBRA_SMA_EXE;
  so.rendererThreads = 2;
  so.spp = o.spp;
  so.maxBounces = o.maxBounces;
  so.smaArgs = {"--prediction", prediction ? "on" : "off", "--prediction-horizon", std::to_string(o.horizon),
                "--prediction-widen", std::to_string(o.widen), "--prediction-resolution",
                std::to_string(o.resolution)};
  for (std::string& w : bench::SplitWords(o.smaArgs)) so.smaArgs.push_back(std::move(w));
  auto stack = bench::StartSmaStack(so);
  if (!stack) return stack.error();
  auto client = SmaTestClient::Connect(stack->sma.port, "prediction-bench");
  if (!client) return client.error();
  SmaTestClient& c = *client;

  const double wallSeconds = path.DurationSeconds() / o.speed;
  const int views = int(std::floor(wallSeconds * o.rate)) + 1;
  std::vector<Clock::time_point> sent;
  std::map<uint64_t, Clock::time_point> complete;  // view id -> first delta saying its stage 1 is over
  const auto watch = [&](const wire::Envelope& e) {
    if (e.has_delta() && (e.delta().refining() || e.delta().converged()))
      complete.emplace(e.delta().view_id(), Clock::now());
  };
  const auto readUntil = [&](Clock::time_point until) -> Status {
    while (Clock::now() < until) {
      const auto wait = std::chrono::duration_cast<std::chrono::milliseconds>(until - Clock::now());
      auto e = c.Wire().Receive(std::max(wait, std::chrono::milliseconds(1)));
      if (!e && e.error().message == "timeout") continue;
      if (!e) return e.error();
      if (auto ok = c.Apply(*e); !ok) return ok;
      watch(*e);
    }
    return Status::Ok();
  };
  const auto start = Clock::now();
  for (int i = 0; i < views; ++i) {
    const auto at = start + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(i / o.rate));
    if (auto ok = readUntil(at); !ok) return ok.error();
    CameraView view = path.ViewAt(double(i) / o.rate * o.speed);
    view.width = o.width;
    view.height = o.height;
    if (!c.SendView(view, uint64_t(i) + 1)) return Fail("send failed");
    sent.push_back(Clock::now());
  }
  // Heartbeats are not needed: a view goes at least every 1/rate s, and the
  // tail is shorter than the read timeout.
  if (auto ok = readUntil(Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                             std::chrono::duration<double>(o.tailSeconds)));
      !ok)
    return ok.error();

  RunFigures f;
  for (size_t i = 0; i < sent.size(); ++i) {
    // The first complete image of this view or a later one, after it was sent.
    std::optional<Clock::time_point> done;
    for (auto it = complete.lower_bound(uint64_t(i) + 1); it != complete.end(); ++it)
      if (it->second >= sent[i] && (!done || it->second < *done)) done = it->second;
    if (done) f.completeMs.push_back(Ms(*done - sent[i]));
    else ++f.neverComplete;
  }
  const auto counter = [&](const char* name) -> Expected<double> { return c.Counter(name); };
  for (auto [name, out] : {std::pair{"view_triangles_new", &f.newTriangles},
                           std::pair{"view_triangles_new_shaded", &f.newShaded},
                           std::pair{"predicted_views", &f.predictedViews},
                           std::pair{"samples_requested_predicted", &f.samplesPredicted}}) {
    auto v = counter(name);
    if (!v) return v.error();
    *out = *v;
  }
  return f;
}

int Run(const Options& o) {
  SetupLogging("warn");
  auto scene = LoadScene(o.scene);
  if (!scene) {
    std::fprintf(stderr, "prediction_bench: %s\n", scene.error().message.c_str());
    return 1;
  }
  const CameraPath* path = scene->FindPath(o.path);
  if (!path) {
    std::fprintf(stderr, "prediction_bench: %s has no camera path '%s'\n", o.scene.c_str(), o.path.c_str());
    return 1;
  }
  std::printf("prediction_bench: %s#%s at %.2fx its speed (%.1f s), %dx%d, %.1f views/s, horizon %.2f s, widen %.2f, "
              "resolution %.2f, %d run(s) each; load average %s\n",
              o.scene.c_str(), o.path.c_str(), o.speed, path->DurationSeconds() / o.speed, o.width, o.height, o.rate,
              o.horizon, o.widen, o.resolution, o.repeat, bench::LoadAverage().c_str());
  std::map<bool, std::vector<RunFigures>> runs;
  for (int r = 0; r < o.repeat; ++r) {
    for (bool prediction : {false, true}) {
      auto f = RunOnce(o, *path, prediction);
      if (!f) {
        std::fprintf(stderr, "prediction_bench: run %d, prediction %s: %s\n", r + 1, prediction ? "on" : "off",
                     f.error().message.c_str());
        return 1;
      }
      std::printf("  run %d %-3s: hit rate %.3f (%.0f of %.0f), complete p50 %.0f ms p99 %.0f ms, %zu never, "
                  "%.0f predicted views, %.0f samples predicted\n",
                  r + 1, prediction ? "on" : "off", f->newTriangles > 0 ? f->newShaded / f->newTriangles : 0.0,
                  f->newShaded, f->newTriangles, bench::Percentile(f->completeMs, 50), bench::Percentile(f->completeMs, 99),
                  f->neverComplete, f->predictedViews, f->samplesPredicted);
      std::fflush(stdout);
      runs[prediction].push_back(std::move(*f));
    }
  }
  struct Summary {
    double hitRate, p50, p99, never, predicted, samples;
  };
  const auto summarise = [](const std::vector<RunFigures>& rs) {
    double shaded = 0, total = 0;
    std::vector<double> p50, p99, never, predicted, samples;
    for (const RunFigures& f : rs) {
      shaded += f.newShaded;
      total += f.newTriangles;
      p50.push_back(bench::Percentile(f.completeMs, 50));
      p99.push_back(bench::Percentile(f.completeMs, 99));
      never.push_back(double(f.neverComplete));
      predicted.push_back(f.predictedViews);
      samples.push_back(f.samplesPredicted);
    }
    return Summary{total > 0 ? shaded / total : 0.0, bench::Median(p50), bench::Median(p99), bench::Median(never),
                   bench::Median(predicted), bench::Median(samples)};
  };
  const Summary off = summarise(runs[false]), on = summarise(runs[true]);
  const auto ratio = [](double a, double b) { return a > 0 ? fmt::format("{:.2f}", b / a) : std::string("-"); };
  std::printf("\n| | off | on | on/off |\n|---|---|---|---|\n");
  std::printf("| hit rate | %.3f | %.3f | %s |\n", off.hitRate, on.hitRate, ratio(off.hitRate, on.hitRate).c_str());
  std::printf("| view -> complete display p50 (ms) | %.0f | %.0f | %s |\n", off.p50, on.p50, ratio(off.p50, on.p50).c_str());
  std::printf("| view -> complete display p99 (ms) | %.0f | %.0f | %s |\n", off.p99, on.p99, ratio(off.p99, on.p99).c_str());
  std::printf("| views never complete | %.0f | %.0f | |\n", off.never, on.never);
  std::printf("| predicted views traced | %.0f | %.0f | |\n", off.predicted, on.predicted);
  std::printf("| samples asked by prediction | %.0f | %.0f | |\n", off.samples, on.samples);
  std::printf("load average after: %s\n", bench::LoadAverage().c_str());
  return 0;
}

}  // namespace
}  // namespace penumbra

int main(int argc, char** argv) {
  penumbra::Options o;
  CLI::App app{"Camera movement prediction end to end: hit rate and view -> complete display, prediction off vs on"};
  app.add_option("--scene", o.scene)->capture_default_str();
  app.add_option("--path", o.path, "Camera path of the scene file")->capture_default_str();
  app.add_option("--speed", o.speed, "The path played at this times its speed")
      ->check(CLI::Range(0.01, 100.0))->capture_default_str();
  app.add_option("--rate", o.rate, "Views sent per second")->check(CLI::Range(0.5, 120.0))->capture_default_str();
  app.add_option("--width", o.width)->check(CLI::Range(16, 4096))->capture_default_str();
  app.add_option("--height", o.height)->check(CLI::Range(16, 4096))->capture_default_str();
  app.add_option("--repeat", o.repeat)->check(CLI::Range(1, 100))->capture_default_str();
  app.add_option("--spp", o.spp, "The renderer's paths per refinement sample")->check(CLI::Range(1, 65536))->capture_default_str();
  app.add_option("--max-bounces", o.maxBounces)->check(CLI::Range(1, 64))->capture_default_str();
  app.add_option("--horizon", o.horizon)->check(CLI::Range(0.01, 10.0))->capture_default_str();
  app.add_option("--widen", o.widen)->check(CLI::Range(1.0, 2.0))->capture_default_str();
  app.add_option("--resolution", o.resolution, "The predicted view's width and height, times the view's")
      ->check(CLI::Range(0.1, 2.0))->capture_default_str();
  app.add_option("--sma-args", o.smaArgs,
                 "More SMA flags, space-separated (--sma-args='--log-level debug': the SMA's log is bench-sma.log in "
                 "its temporary folder)");
  CLI11_PARSE(app, argc, argv);
  return penumbra::Run(o);
}

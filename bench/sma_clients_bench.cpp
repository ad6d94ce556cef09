// Many clients at once on one SMA, on real processes on loopback: a renderer,
// an SMA and 1, 8, 32 ... scripted clients (tests/support) on Sponza, each
// on its own path (issue 13's "Measure").
//
// Each client count gets a fresh renderer and SMA (cold cache) and runs:
//  A. baseline: stats round trips from an idle client with nothing else
//     going on (the floor under every latency below);
//  B. the probe (client 0) visits its poses: new views, alone;
//  C. alone: the probe asks its (now cached) poses in turn, one every
//     --probe-period: view -> first delta, -> complete display (stage 1
//     over: every visible triangle shaded at least coarsely, the delta
//     that says `refining` or `converged`), -> converged;
//  D. refining: clients 1..n-1 visit their own poses (new views, each
//     waited on until converged, starts staggered over --period) while the
//     probe keeps asking its cached poses as in C;
//  E. cached: all n clients ask their (now cached) poses in turn, one every
//     --period each, phases staggered (for n = 1 this is C).
// Throughout B..E an idle client asks the SMA for its statistics every
// --stats-interval and times the round trip: what an I/O-thread stall
// costs a client that only wants an answer.
//
// Reported per client count (issue targets in brackets):
//  * new view -> first delta p50/p99: the first visits of all n clients'
//    poses (B and D);
//  * cached view -> first delta, -> complete display and -> converged
//    p50/p99 (E) [32 clients: first delta p99 <= 100 ms];
//  * the idle client's stats round trip while views refine (B and D),
//    p50/p99/max, against its baseline (A);
//  * the probe's latency with n-1 others refining (D) over its latency
//    alone (C), p50 and p99 [<= 1.5 x]: to a complete display, and to
//    convergence (which waits for refinement samples the others' work
//    queues ahead of them on the shared renderer).
//
// Client c's poses are fixed by c alone (not by n): pose k lies on the
// scene's camera path at time duration * frac(c * 0.618...) + k * --pose-step,
// its view direction turned about the vertical by c * 137.5 + k * 20 degrees.
// Client 0's pose 0 is the path's first frame.
//
//   sma_clients_bench [--clients 1,8,32] [--width 320 --height 240] [--poses 3] [--results out.tsv]
//                     [--sma-exe PATH --renderer-exe PATH]   (time another build's servers)

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <mutex>
#include <numbers>
#include <thread>

#include <CLI/CLI.hpp>

#include "order_statistics.h"
#include "penumbra/common/logging.h"
#include "penumbra/common/scene.h"
#include "sma_stack.h"

namespace penumbra {
namespace {

namespace fs = std::filesystem;
using namespace penumbra::testing;
using namespace penumbra::bench;

struct Options {
  fs::path scene = fs::path(PENUMBRA_SOURCE_DIR) / "scenes" / "sponza.json";
  std::string path = "walk";
  std::vector<int> clientCounts = {1, 8, 32};
  // Small and cheap views, so that a run of 1, 8 and 32 clients takes
  // minutes on a shared 2-core machine: the SMA's latencies are measured,
  // not the renderer's image.
  int width = 320;
  int height = 240;
  int spp = 16;
  int maxBounces = 4;
  int threads = int(std::max(1u, std::thread::hardware_concurrency()));
  int poses = 3;
  double poseStep = 0.7;        // seconds along the path between a client's poses
  double period = 1.0;          // seconds between a client's views in phase E (and D's stagger)
  double probePeriod = 0.1;     // seconds between the probe's views in C and D
  int probeViews = 32;          // the probe's views alone (C)
  int cachedViews = 96;         // views in E over all clients (at least --min-rounds each)
  int minRounds = 6;            // views per client in E at least
  double statsInterval = 0.02;  // seconds between the idle client's stats requests
  // Improvement rounds of displayed samples are background work that goes
  // on long after a view converged; off, so that the refining phase ends.
  std::string smaArgs = "--improve-paths 0";  // more SMA flags, split at spaces
  std::string rendererExe = PENUMBRA_RENDERER_EXE;
  std::string smaExe = PENUMBRA_SMA_EXE;
  fs::path results;
};

// Client c's pose k (see the header comment).
CameraView ClientPose(const CameraPath& path, int c, int k, const Options& o) {
  constexpr double kGolden = 0.6180339887498949;
  const double duration = path.DurationSeconds();
  const double t = std::fmod(duration * std::fmod(c * kGolden, 1.0) + k * o.poseStep, duration);
  CameraView v = path.ViewAt(t);
  const double yaw = (c * 137.5 + k * 20.0) * std::numbers::pi / 180.0;
  const Vec3 d = v.pose.target - v.pose.eye;  // turned about the vertical (y)
  v.pose.target = v.pose.eye + Vec3(float(std::cos(yaw) * d.x + std::sin(yaw) * d.z), d.y,
                                    float(-std::sin(yaw) * d.x + std::cos(yaw) * d.z));
  v.width = o.width;
  v.height = o.height;
  return v;
}

// One scripted client and its poses.
struct Client {
  SmaTestClient connection;
  std::vector<CameraView> poses;
  uint64_t nextViewId = 1;
};

// Asks the client's poses in turn, view j at start + j * period (or as soon
// as view j-1 converged, if later), while `more(j)`; appends the timings.
Status CycleCachedViews(Client& client, Clock::time_point start, double period, const std::function<bool(int)>& more,
                        std::vector<ViewTiming>& out) {
  for (int j = 0; more(j); ++j) {
    const auto due = start + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(j * period));
    if (auto ok = IdleUntil(client.connection, due); !ok) return ok;
    auto t = TimeView(client.connection, client.poses[size_t(j) % client.poses.size()], client.nextViewId++);
    if (!t) return t.error();
    out.push_back(*t);
  }
  return Status::Ok();
}

// Errors from client threads; the first one fails the count.
class Errors {
 public:
  void Add(const std::string& who, const Status& s) {
    if (s) return;
    std::lock_guard lock(mutex_);
    messages_.push_back(who + ": " + s.error().message);
  }
  std::optional<std::string> First() const {
    std::lock_guard lock(mutex_);
    return messages_.empty() ? std::nullopt : std::optional(messages_.front());
  }

 private:
  mutable std::mutex mutex_;
  std::vector<std::string> messages_;
};

// The idle client: stats round trips every `interval`, each tagged with
// the phase running when it was asked.
class StatsProber {
 public:
  enum Phase { kNewAlone, kAlone, kRefining, kCached, kPhases };

  StatsProber(SmaTestClient client, double interval, Errors& errors)
      : client_(std::move(client)), thread_([this, interval, &errors] { errors.Add("idle client", Run(interval)); }) {}
  ~StatsProber() { Stop(); }

  void SetPhase(Phase p) { phase_ = p; }
  void Stop() {
    stop_ = true;
    if (thread_.joinable()) thread_.join();
  }
  // After Stop().
  std::vector<double> RoundTrips(std::initializer_list<Phase> phases) const {
    std::vector<double> all;
    for (Phase p : phases) all.insert(all.end(), rtt_[p].begin(), rtt_[p].end());
    return all;
  }

 private:
  Status Run(double interval) {
    const auto step = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(interval));
    for (auto next = Clock::now(); !stop_; next += step) {
      std::this_thread::sleep_until(next);
      const Phase p = phase_;
      const auto t0 = Clock::now();
      if (auto ok = RoundTrip(); !ok) return ok;
      rtt_[p].push_back(Ms(Clock::now() - t0));
      next = std::max(next, Clock::now() - step);  // a stall is one long sample, not a burst after it
    }
    return Status::Ok();
  }

  // One StatsRequest answered. Waits up to a minute (SmaTestClient::Counter
  // gives up after 10 s, and a stall that long is a figure, not an error).
  Status RoundTrip() {
    wire::Envelope request;
    request.mutable_stats_request()->set_request_id(++requestId_);
    if (!client_.Wire().Send(request)) return Fail("send failed");
    const auto deadline = Clock::now() + std::chrono::minutes(1);
    while (true) {
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
      if (left.count() <= 0) return Fail("no stats reply within a minute");
      auto e = client_.Wire().Receive(left);
      if (!e) return e.error();
      if (e->has_stats_reply() && e->stats_reply().request_id() == requestId_) return Status::Ok();
      if (auto ok = client_.Apply(*e); !ok) return ok;
    }
  }

  SmaTestClient client_;
  std::atomic<Phase> phase_{kNewAlone};
  std::atomic<bool> stop_{false};
  uint64_t requestId_ = 1u << 20;  // apart from the ids SmaTestClient::Counter uses
  std::vector<double> rtt_[kPhases];
  std::thread thread_;
};

struct CountResult {
  int clients = 0;
  std::vector<double> baselineRtt, busyRtt;
  std::vector<double> newFirst;
  // Complete: stage 1 over (ViewTiming::stage1Ms); converged: ViewTiming::completeMs.
  std::vector<double> cachedFirst, cachedComplete, cachedConverged;
  std::vector<double> aloneFirst, aloneComplete, aloneConverged, loadedFirst, loadedComplete, loadedConverged;
  double cachedNewSamples = 0;  // samples the SMA asked for during E: 0 if the views were all cached
  double samples = 0;           // samples the SMA asked for over the whole count
  double refiningSeconds = 0;   // D's length
  double seconds = 0;
};

Expected<CountResult> RunCount(const Options& o, const CameraPath& path, int n) {
  const auto begin = Clock::now();
  CountResult r;
  r.clients = n;
  auto stack = StartSmaStack({o.scene, o.rendererExe, o.smaExe, o.threads, o.spp, o.maxBounces, SplitWords(o.smaArgs)});
  if (!stack) return stack.error();
  const uint16_t port = stack->sma.port;
  auto progress = [&](const char* phase) {
    std::fprintf(stderr, "sma_clients_bench: %d client(s), %.1f s: %s\n", n,
                 std::chrono::duration<double>(Clock::now() - begin).count(), phase);
  };
  progress("servers up");

  // A: the baseline, nothing else connected.
  auto idle = SmaTestClient::Connect(port, "idle");
  if (!idle) return idle.error();
  for (int i = 0; i < 50; ++i) {
    const auto t0 = Clock::now();
    if (auto c = idle->Counter("clients"); !c) return c.error();
    r.baselineRtt.push_back(Ms(Clock::now() - t0));
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  Errors errors;
  StatsProber prober(std::move(*idle), o.statsInterval, errors);

  std::vector<Client> clients;
  clients.reserve(size_t(n));  // references to clients[0] (the probe) stay valid as the others connect
  auto connect = [&](int c) -> Status {
    auto conn = SmaTestClient::Connect(port, "client-" + std::to_string(c));
    if (!conn) return conn.error();
    Client client{std::move(*conn), {}, 1};
    for (int k = 0; k < o.poses; ++k) client.poses.push_back(ClientPose(path, c, k, o));
    clients.push_back(std::move(client));
    return Status::Ok();
  };

  // B: the probe's new views, alone.
  if (auto ok = connect(0); !ok) return ok.error();
  Client& probe = clients[0];
  for (const CameraView& pose : probe.poses) {
    auto t = TimeView(probe.connection, pose, probe.nextViewId++);
    if (!t) return t.error();
    r.newFirst.push_back(t->firstDeltaMs);
  }

  progress("B (the probe's new views) done");
  // C: the probe alone on its cached poses.
  prober.SetPhase(StatsProber::kAlone);
  std::vector<ViewTiming> alone;
  if (auto ok = CycleCachedViews(probe, Clock::now(), o.probePeriod, [&](int j) { return j < o.probeViews; }, alone);
      !ok)
    return ok.error();
  for (const ViewTiming& t : alone) {
    r.aloneFirst.push_back(t.firstDeltaMs);
    r.aloneComplete.push_back(t.stage1Ms);
    r.aloneConverged.push_back(t.completeMs);
  }

  progress("C (the probe alone) done");
  if (n > 1) {
    // D: the others' new views while the probe keeps asking its cached ones.
    for (int c = 1; c < n; ++c)
      if (auto ok = connect(c); !ok) return ok.error();
    prober.SetPhase(StatsProber::kRefining);
    const auto start = Clock::now();
    std::atomic<int> refining{n - 1};
    std::vector<std::vector<double>> newFirst(static_cast<size_t>(n));
    std::vector<ViewTiming> loaded;
    std::vector<std::thread> threads;
    threads.emplace_back([&] {
      errors.Add("probe", CycleCachedViews(probe, start, o.probePeriod, [&](int) { return refining > 0; }, loaded));
    });
    for (int c = 1; c < n; ++c) {
      threads.emplace_back([&, c] {
        Client& client = clients[size_t(c)];
        auto run = [&]() -> Status {
          const auto stagger = std::chrono::duration<double>(o.period * c / n);
          if (auto ok = IdleUntil(client.connection, start + std::chrono::duration_cast<Clock::duration>(stagger)); !ok)
            return ok;
          for (const CameraView& pose : client.poses) {
            auto t = TimeView(client.connection, pose, client.nextViewId++);
            if (!t) return t.error();
            newFirst[size_t(c)].push_back(t->firstDeltaMs);
          }
          return Status::Ok();
        };
        const Status ok = run();
        --refining;
        errors.Add("client " + std::to_string(c), ok);
        if (ok) errors.Add("client " + std::to_string(c), IdleUntil(client.connection, [&] { return refining == 0; }));
      });
    }
    for (auto& t : threads) t.join();
    r.refiningSeconds = std::chrono::duration<double>(Clock::now() - start).count();
    if (auto e = errors.First()) return Fail(*e);
    for (const auto& v : newFirst) r.newFirst.insert(r.newFirst.end(), v.begin(), v.end());
    for (const ViewTiming& t : loaded) {
      r.loadedFirst.push_back(t.firstDeltaMs);
      r.loadedComplete.push_back(t.stage1Ms);
      r.loadedConverged.push_back(t.completeMs);
    }

    progress("D (others refining) done");
    // E: everyone on cached poses.
    prober.SetPhase(StatsProber::kCached);
    auto requested = [&] { return clients[0].connection.Counter("samples_requested"); };
    auto before = requested();
    if (!before) return before.error();
    const int rounds = std::max(o.minRounds, (o.cachedViews + n - 1) / n);
    const auto cachedStart = Clock::now();
    std::vector<std::vector<ViewTiming>> cached(static_cast<size_t>(n));
    threads.clear();
    for (int c = 0; c < n; ++c) {
      threads.emplace_back([&, c] {
        const auto stagger = std::chrono::duration<double>(o.period * c / n);
        errors.Add("client " + std::to_string(c),
                   CycleCachedViews(clients[size_t(c)], cachedStart + std::chrono::duration_cast<Clock::duration>(stagger),
                                    o.period, [&](int j) { return j < rounds; }, cached[size_t(c)]));
      });
    }
    for (auto& t : threads) t.join();
    if (auto e = errors.First()) return Fail(*e);
    auto after = requested();
    if (!after) return after.error();
    r.cachedNewSamples = *after - *before;
    for (const auto& v : cached) {
      for (const ViewTiming& t : v) {
        r.cachedFirst.push_back(t.firstDeltaMs);
        r.cachedComplete.push_back(t.stage1Ms);
        r.cachedConverged.push_back(t.completeMs);
      }
    }
  } else {
    r.cachedFirst = r.aloneFirst;
    r.cachedComplete = r.aloneComplete;
    r.cachedConverged = r.aloneConverged;
  }
  prober.Stop();
  if (auto e = errors.First()) return Fail(*e);
  auto samples = clients[0].connection.Counter("samples_requested");
  if (!samples) return samples.error();
  r.samples = *samples;
  r.busyRtt = prober.RoundTrips(n > 1 ? std::initializer_list{StatsProber::kNewAlone, StatsProber::kRefining}
                                      : std::initializer_list{StatsProber::kNewAlone});
  r.seconds = std::chrono::duration<double>(Clock::now() - begin).count();
  return r;
}

// One figure of the report: a name (also the key in --results) and its value per count.
struct Row {
  std::string key;
  std::string label;
  std::function<double(const CountResult&)> value;
  const char* format = "%.1f";
};

double Max(const std::vector<double>& v) { return v.empty() ? 0.0 : *std::max_element(v.begin(), v.end()); }
double Ratio(double a, double b) { return b > 0 ? a / b : 0.0; }

int Run(const Options& o) {
  SetupLogging("warn");
  auto scene = LoadScene(o.scene);
  if (!scene) {
    std::printf("sma_clients_bench: %s; skipping (is ../shared/scenes present?)\n", scene.error().message.c_str());
    return 0;
  }
  const CameraPath* path = scene->FindPath(o.path);
  if (!path || path->keyframes.empty()) return std::fprintf(stderr, "sma_clients_bench: no path '%s'\n", o.path.c_str()), 1;
  const std::string loadBefore = LoadAverage();
  std::vector<CountResult> results;
  for (int n : o.clientCounts) {
    auto r = RunCount(o, *path, n);
    if (!r) return std::fprintf(stderr, "sma_clients_bench: %d clients: %s\n", n, r.error().message.c_str()), 1;
    std::fprintf(stderr, "sma_clients_bench: %d client(s) done in %.0f s (refining phase %.1f s), load %s\n", n,
                 r->seconds, r->refiningSeconds, LoadAverage().c_str());
    results.push_back(std::move(*r));
  }

  using R = const CountResult&;
  const std::vector<Row> rows = {
      {"baseline_rtt_p50", "stats round trip, no load (baseline), p50 ms", [](R r) { return Percentile(r.baselineRtt, 50); }, "%.2f"},
      {"baseline_rtt_max", "stats round trip, no load (baseline), max ms", [](R r) { return Max(r.baselineRtt); }, "%.2f"},
      {"new_views", "new views timed", [](R r) { return double(r.newFirst.size()); }, "%.0f"},
      {"new_first_p50", "new view -> first delta, p50 ms", [](R r) { return Percentile(r.newFirst, 50); }},
      {"new_first_p99", "new view -> first delta, p99 ms", [](R r) { return Percentile(r.newFirst, 99); }},
      {"cached_views", "cached views timed", [](R r) { return double(r.cachedFirst.size()); }, "%.0f"},
      {"cached_first_p50", "cached view -> first delta, p50 ms", [](R r) { return Percentile(r.cachedFirst, 50); }},
      {"cached_first_p99", "**cached view -> first delta, p99 ms** [32: <= 100]", [](R r) { return Percentile(r.cachedFirst, 99); }},
      {"cached_complete_p50", "cached view -> complete display, p50 ms", [](R r) { return Percentile(r.cachedComplete, 50); }},
      {"cached_complete_p99", "cached view -> complete display, p99 ms", [](R r) { return Percentile(r.cachedComplete, 99); }},
      {"cached_converged_p50", "cached view -> converged, p50 ms", [](R r) { return Percentile(r.cachedConverged, 50); }},
      {"cached_converged_p99", "cached view -> converged, p99 ms", [](R r) { return Percentile(r.cachedConverged, 99); }},
      {"cached_new_samples", "samples asked during the cached phase", [](R r) { return r.cachedNewSamples; }, "%.0f"},
      {"busy_rtt_p50", "idle client's stats round trip while views refine, p50 ms", [](R r) { return Percentile(r.busyRtt, 50); }, "%.2f"},
      {"busy_rtt_p99", "idle client's stats round trip while views refine, p99 ms", [](R r) { return Percentile(r.busyRtt, 99); }, "%.2f"},
      {"busy_rtt_max", "idle client's stats round trip while views refine, max ms", [](R r) { return Max(r.busyRtt); }, "%.2f"},
      {"alone_complete_p50", "probe alone: cached view -> complete display, p50 ms", [](R r) { return Percentile(r.aloneComplete, 50); }},
      {"alone_complete_p99", "probe alone: cached view -> complete display, p99 ms", [](R r) { return Percentile(r.aloneComplete, 99); }},
      {"alone_converged_p50", "probe alone: cached view -> converged, p50 ms", [](R r) { return Percentile(r.aloneConverged, 50); }},
      {"alone_converged_p99", "probe alone: cached view -> converged, p99 ms", [](R r) { return Percentile(r.aloneConverged, 99); }},
      {"loaded_views", "probe with n-1 others refining: views timed", [](R r) { return double(r.loadedComplete.size()); }, "%.0f"},
      {"loaded_first_p50", "probe with n-1 others refining: -> first delta, p50 ms", [](R r) { return Percentile(r.loadedFirst, 50); }},
      {"loaded_complete_p50", "probe with n-1 others refining: -> complete display, p50 ms", [](R r) { return Percentile(r.loadedComplete, 50); }},
      {"loaded_complete_p99", "probe with n-1 others refining: -> complete display, p99 ms", [](R r) { return Percentile(r.loadedComplete, 99); }},
      {"loaded_converged_p50", "probe with n-1 others refining: -> converged, p50 ms", [](R r) { return Percentile(r.loadedConverged, 50); }},
      {"loaded_converged_p99", "probe with n-1 others refining: -> converged, p99 ms", [](R r) { return Percentile(r.loadedConverged, 99); }},
      {"loaded_ratio_p50", "**probe loaded / alone, complete display p50** [<= 1.5]",
       [](R r) { return Ratio(Percentile(r.loadedComplete, 50), Percentile(r.aloneComplete, 50)); }, "%.2f"},
      {"loaded_ratio_p99", "probe loaded / alone, complete display p99",
       [](R r) { return Ratio(Percentile(r.loadedComplete, 99), Percentile(r.aloneComplete, 99)); }, "%.2f"},
      {"loaded_converged_ratio_p50", "probe loaded / alone, converged p50",
       [](R r) { return Ratio(Percentile(r.loadedConverged, 50), Percentile(r.aloneConverged, 50)); }, "%.2f"},
      {"samples", "samples the SMA asked for, whole count", [](R r) { return r.samples; }, "%.0f"},
      {"refining_seconds", "refining phase (D) length, s", [](R r) { return r.refiningSeconds; }},
      {"seconds", "this count's run, s", [](R r) { return r.seconds; }, "%.0f"},
  };

  std::printf("SMA with many clients: %s, path '%s', %dx%d, %d poses per client, %d paths/vertex, at most %d bounces, "
              "renderer threads %d; load average %s before, %s after\n",
              scene->name.c_str(), o.path.c_str(), o.width, o.height, o.poses, o.spp, o.maxBounces, o.threads,
              loadBefore.c_str(), LoadAverage().c_str());
  std::printf("\n| clients |");
  for (const CountResult& r : results) std::printf(" %d |", r.clients);
  std::printf("\n|---|");
  for (size_t i = 0; i < results.size(); ++i) std::printf("---|");
  std::printf("\n");
  std::ofstream tsv;
  if (!o.results.empty()) tsv.open(o.results);
  for (const Row& row : rows) {
    std::printf("| %s |", row.label.c_str());
    for (const CountResult& r : results) {
      const bool na = r.clients == 1 && row.key.starts_with("loaded");
      char cell[64];
      std::snprintf(cell, sizeof cell, row.format, row.value(r));
      std::printf(" %s |", na ? "-" : cell);
      if (tsv.is_open()) tsv << "n" << r.clients << "." << row.key << '\t' << (na ? "-" : cell) << '\t' << row.label << '\n';
    }
    std::printf("\n");
  }
  return 0;
}

}  // namespace
}  // namespace penumbra

int main(int argc, char** argv) {
  penumbra::Options o;
  CLI::App app{"sma_clients_bench: SMA latencies with many concurrent clients, on real processes"};
  app.add_option("--scene", o.scene, "Scene file")->capture_default_str();
  app.add_option("--path", o.path, "Camera path the clients' poses are taken from")->capture_default_str();
  app.add_option("--clients", o.clientCounts, "Client counts, each on a fresh renderer and SMA")
      ->delimiter(',')->check(CLI::Range(1, 256))->capture_default_str();
  app.add_option("--width", o.width, "Viewport width")->capture_default_str();
  app.add_option("--height", o.height, "Viewport height")->capture_default_str();
  app.add_option("--spp", o.spp, "Paths per vertex")->capture_default_str();
  app.add_option("--max-bounces", o.maxBounces, "Bounces after the sample (0: direct light)")->capture_default_str();
  app.add_option("--threads", o.threads, "Renderer threads")->capture_default_str();
  app.add_option("--poses", o.poses, "Poses per client")->check(CLI::Range(1, 100))->capture_default_str();
  app.add_option("--pose-step", o.poseStep, "Seconds along the path between a client's poses")->capture_default_str();
  app.add_option("--period", o.period, "Seconds between a client's cached views (phase E)")->capture_default_str();
  app.add_option("--probe-period", o.probePeriod, "Seconds between the probe's views")->capture_default_str();
  app.add_option("--probe-views", o.probeViews, "The probe's cached views alone")->check(CLI::Range(1, 10000))
      ->capture_default_str();
  app.add_option("--cached-views", o.cachedViews, "Cached views over all clients (phase E)")->capture_default_str();
  app.add_option("--min-rounds", o.minRounds, "Cached views per client at least (phase E)")->check(CLI::Range(1, 10000))
      ->capture_default_str();
  app.add_option("--stats-interval", o.statsInterval, "Seconds between the idle client's stats requests")
      ->check(CLI::Range(0.001, 10.0))->capture_default_str();
  app.add_option("--sma-args", o.smaArgs, "More SMA flags, space-separated (--sma-args='--criterion none')")
      ->capture_default_str();
  app.add_option("--renderer-exe", o.rendererExe, "penumbra-renderer to run")->capture_default_str();
  app.add_option("--sma-exe", o.smaExe, "penumbra-sma to run")->capture_default_str();
  app.add_option("--results", o.results, "Also write the figures here, one 'n<clients>.<key>\\t<value>\\t<label>' a line");
  CLI11_PARSE(app, argc, argv);
  return penumbra::Run(o);
}

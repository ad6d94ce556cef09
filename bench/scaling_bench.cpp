// Scaling of the renderer tier behind one SMA, on real processes on loopback:
// samples/s with 1 and with 2 renderer processes (one worker thread each),
// and what the SMA spends per sample.
//
// A round starts k renderers and a fresh SMA (cold cache, refinement off by
// default so that all of the view's samples are queued at once and the
// renderers, not the refinement loop, set the pace), sends one large view
// from a scripted client (tests/support) and times view -> converged.
// Per round:
//  * samples/s = samples the SMA requested for the view / (view -> converged);
//  * CPU per sample, from utime + stime in /proc/<pid>/stat over the round:
//    the SMA's, against the renderers' (what shading a sample costs, the
//    baseline). The SMA's is split into a per-view part, measured on the
//    same view asked again by a second client once every sample is cached
//    (visibility and deltas, nothing to shade), and the rest per sample;
//  * bytes per sample on the wire, TCP payload: SMA <-> renderers (the
//    renderers' sockets as `ss -ti` counts them) against the floats a sample
//    must carry (32 B out: position, normal, barycentrics; 24 B back:
//    radiance, irradiance; ids are varints on top), and SMA -> client (the
//    SMA's client_bytes_sent).
// Rounds alternate 1, 2, 1, 2, ... renderers so that load from other
// processes hits both alike; the report gives medians, and the ratio of the
// 2-renderer rate to the 1-renderer rate (ideal 2.0; on a 2-core machine the
// SMA and the client share the two cores with the renderers). How many cores
// the renderers actually got (their CPU time / wall time) tells a tier that
// does not scale from a machine that had no second core to give, and samples
// per renderer CPU second (ideal: the same with 2 as with 1) is the scaling
// that load from other processes does not distort. The machine's own
// baseline is measured in each round too: the cores k busy threads get for a
// second (on a shared virtual machine, two often get much less than 2), so
// the ratio is also given against what the machine could give.
//
//   scaling_bench [--scene scenes/sponza.json --camera atrium --spp 256] [--width 1280 --height 720] [--rounds 3]
//                 [--criterion none]
//
// Without ../shared (Sponza) it uses the Cornell box at many paths per sample.

#include <sys/types.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>

#include <CLI/CLI.hpp>

#include "order_statistics.h"
#include "sma_stack.h"
#include "penumbra/common/logging.h"
#include "penumbra/common/scene.h"
#include "support/service.h"
#include "support/sma_client.h"

namespace penumbra {
namespace {

namespace fs = std::filesystem;
using namespace penumbra::testing;
using Clock = std::chrono::steady_clock;

constexpr double kRequestFloatBytes = 32.0;  // per sample: position, normal, barycentrics
constexpr double kReplyFloatBytes = 24.0;    // per sample: radiance, irradiance

struct Options {
  fs::path scene;
  std::string camera;
  int spp = 0;
  int maxBounces = 64;  // the renderer's default
  int width = 1280;
  int height = 720;
  int rounds = 3;
  int maxRenderers = 2;
  std::string criterion = "none";
};

// CPU seconds (user + system) a process has used so far.
double CpuSeconds(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/stat");
  std::string stat((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  // Fields after the command name, which is in parentheses and may hold spaces.
  std::istringstream rest(stat.substr(stat.rfind(')') + 2));
  std::string field;
  double utime = 0, stime = 0;
  for (int i = 3; i <= 15 && rest >> field; ++i) {  // field 3 is the state
    if (i == 14) utime = std::stod(field);
    if (i == 15) stime = std::stod(field);
  }
  return (utime + stime) / double(::sysconf(_SC_CLK_TCK));
}

// TCP payload through the established sockets whose local port is one of
// `ports`, as the kernel counts it (`ss -tin`): {received, sent}.
Expected<std::pair<double, double>> SocketBytes(const std::vector<uint16_t>& ports) {
  const std::optional<std::string> ss = FindExecutable("ss");
  if (!ss) return Fail("no `ss` (iproute2)");
  auto output = RunCommand(*ss, {"-tinH", "state", "established"});
  if (!output) return output.error();
  std::istringstream lines(*output);
  double received = 0, sent = 0;
  bool ours = false;
  for (std::string line; std::getline(lines, line);) {
    std::istringstream words(line);
    if (!line.empty() && line[0] != ' ' && line[0] != '\t') {  // a socket: Recv-Q Send-Q local peer
      std::string recvQ, sendQ, local;
      words >> recvQ >> sendQ >> local;
      const uint16_t port = uint16_t(std::stoul(local.substr(local.rfind(':') + 1)));
      ours = std::find(ports.begin(), ports.end(), port) != ports.end();
      continue;
    }
    for (std::string w; ours && words >> w;) {  // its details
      if (w.starts_with("bytes_received:")) received += std::stod(w.substr(15));
      if (w.starts_with("bytes_sent:")) sent += std::stod(w.substr(11));
    }
  }
  return std::make_pair(received, sent);
}

// Cores that `k` busy threads get on this machine now: their CPU time over
// `duration` of wall time.
double BusyThreadCores(int k, std::chrono::milliseconds duration) {
  std::vector<double> cpu(size_t(k), 0.0);
  std::vector<std::thread> threads;
  const auto end = Clock::now() + duration;
  for (int i = 0; i < k; ++i) {
    threads.emplace_back([&cpu, end, i] {
      for (volatile uint64_t spin = 0; Clock::now() < end;) spin = spin + 1;
      timespec t{};
      ::clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
      cpu[size_t(i)] = double(t.tv_sec) + 1e-9 * double(t.tv_nsec);
    });
  }
  for (auto& t : threads) t.join();
  double sum = 0;
  for (double c : cpu) sum += c;
  return sum / std::chrono::duration<double>(duration).count();
}

struct Round {
  double machineCores = 0;  // what `renderers` busy threads got just before the round
  double samples = 0;
  double seconds = 0;
  double smaCpu = 0;       // seconds
  double viewCpu = 0;      // seconds of SMA CPU for the same view, all cached
  double rendererCpu = 0;  // seconds, all renderers
  double toRenderers = 0;  // bytes
  double fromRenderers = 0;
  double toClient = 0;
  double SamplesPerSecond() const { return samples / seconds; }
};

Expected<Round> RunRound(const Options& o, const CameraView& view, int renderers) {
  const std::string scene = o.scene.string();
  std::vector<Service> pool;
  std::vector<std::string> smaArgs = {"--scene", scene, "--criterion", o.criterion, "--log-level", "warn"};
  std::vector<uint16_t> ports;
  for (int i = 0; i < renderers; ++i) {
    auto r = StartService(PENUMBRA_RENDERER_EXE,
                          {"--scene", scene, "--threads", "1", "--spp", std::to_string(o.spp), "--max-bounces",
                           std::to_string(o.maxBounces), "--log-level", "warn"},
                          "scaling-renderer", std::chrono::seconds(120));
    if (!r) return r.error();
    smaArgs.insert(smaArgs.end(), {"--renderer", r->Address()});
    ports.push_back(r->port);
    pool.push_back(std::move(*r));
  }
  auto sma = StartService(PENUMBRA_SMA_EXE, smaArgs, "scaling-sma", std::chrono::seconds(120));
  if (!sma) return sma.error();
  auto client = SmaTestClient::Connect(sma->port, "scaling_bench");
  if (!client) return client.error();
  for (int i = 0;; ++i) {  // every renderer connected before the view, so that all get work
    auto n = client->Counter("renderers_connected");
    if (!n) return n.error();
    if (*n >= renderers) break;
    if (i == 1200) return Fail("the renderers did not all connect to the SMA within a minute");
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  auto rendererCpu = [&] {
    double s = 0;
    for (auto& r : pool) s += CpuSeconds(r.process.Pid());
    return s;
  };
  Round round;
  round.machineCores = BusyThreadCores(renderers, std::chrono::seconds(1));
  const double smaCpu0 = CpuSeconds(sma->process.Pid());
  const double rendererCpu0 = rendererCpu();
  auto bytes0 = SocketBytes(ports);
  if (!bytes0) return bytes0.error();
  const auto start = Clock::now();
  if (!client->SendView(view, 1)) return Fail("cannot send the view");
  if (auto ok = client->WaitConverged(1, std::chrono::minutes(30)); !ok) return ok.error();
  round.seconds = std::chrono::duration<double>(Clock::now() - start).count();
  round.smaCpu = CpuSeconds(sma->process.Pid()) - smaCpu0;
  round.rendererCpu = rendererCpu() - rendererCpu0;
  auto bytes1 = SocketBytes(ports);
  if (!bytes1) return bytes1.error();
  round.toRenderers = bytes1->first - bytes0->first;
  round.fromRenderers = bytes1->second - bytes0->second;
  auto samples = client->Counter("samples_requested");
  auto toClient = client->Counter("client_bytes_sent");
  if (!samples || !toClient) return Fail("SMA counters missing");
  round.samples = *samples;
  round.toClient = *toClient;
  if (round.samples <= 0) return Fail("the view needed no samples");

  const double viewCpu0 = CpuSeconds(sma->process.Pid());
  auto cached = SmaTestClient::Connect(sma->port, "scaling_bench-cached");
  if (!cached) return cached.error();
  if (!cached->SendView(view, 1)) return Fail("cannot send the cached view");
  if (auto ok = cached->WaitConverged(1, std::chrono::minutes(5)); !ok) return ok.error();
  round.viewCpu = CpuSeconds(sma->process.Pid()) - viewCpu0;
  return round;
}

using bench::LoadAverage;
using bench::Median;

int Run(Options o) {
  SetupLogging("warn");
  const fs::path scenes = fs::path(PENUMBRA_SOURCE_DIR) / "scenes";
  const bool defaultScene = o.scene.empty();
  auto scene = LoadScene(defaultScene ? scenes / "sponza.json" : o.scene);
  if (defaultScene && !scene) {
    std::printf("scaling_bench: Sponza not available (%s); using the Cornell box\n", scene.error().message.c_str());
    o.scene = scenes / "cornell-box.json";
    if (o.camera.empty()) o.camera = "front";
    if (o.spp == 0) o.spp = 200000;
    scene = LoadScene(o.scene);
  } else if (defaultScene) {
    o.scene = scenes / "sponza.json";
  }
  if (!scene) return std::fprintf(stderr, "scaling_bench: %s\n", scene.error().message.c_str()), 1;
  if (o.camera.empty()) o.camera = "atrium";
  if (o.spp == 0) o.spp = 256;
  const CameraPreset* preset = scene->FindCamera(o.camera);
  if (!preset) return std::fprintf(stderr, "scaling_bench: no camera '%s'\n", o.camera.c_str()), 1;
  CameraView view;
  view.pose = preset->pose;
  view.fovYDeg = preset->fovYDeg;
  view.width = o.width;
  view.height = o.height;

  const std::string loadBefore = LoadAverage();
  std::vector<std::vector<Round>> byCount(size_t(o.maxRenderers) + 1);
  for (int r = 0; r < o.rounds; ++r) {
    for (int k = 1; k <= o.maxRenderers; ++k) {
      auto round = RunRound(o, view, k);
      if (!round) return std::fprintf(stderr, "scaling_bench: %s\n", round.error().message.c_str()), 1;
      std::printf("  round %d, %d renderer(s): %.0f samples in %.2f s = %.0f samples/s; SMA CPU %.2f s\n", r + 1, k,
                  round->samples, round->seconds, round->SamplesPerSecond(), round->smaCpu);
      std::fflush(stdout);
      byCount[size_t(k)].push_back(*round);
    }
  }

  std::printf("Scaling benchmark: %s, camera '%s', %dx%d, %d paths/sample, at most %d bounces, %d round(s), "
              "%u hardware threads; load average %s before, %s after\n",
              o.scene.filename().string().c_str(), o.camera.c_str(), o.width, o.height, o.spp, o.maxBounces, o.rounds,
              std::thread::hardware_concurrency(), loadBefore.c_str(), LoadAverage().c_str());
  auto median = [&](int k, auto field) {
    std::vector<double> v;
    for (const Round& r : byCount[size_t(k)]) v.push_back(field(r));
    return Median(v);
  };
  const double rate1 = median(1, [](const Round& r) { return r.SamplesPerSecond(); });
  const double rendererUs1 = median(1, [](const Round& r) { return 1e6 * r.rendererCpu / r.samples; });
  const double machineCores1 = median(1, [](const Round& r) { return r.machineCores; });
  for (int k = 1; k <= o.maxRenderers; ++k) {
    const double rate = median(k, [](const Round& r) { return r.SamplesPerSecond(); });
    const double samples = median(k, [](const Round& r) { return r.samples; });
    const double smaUs = median(k, [](const Round& r) { return 1e6 * r.smaCpu / r.samples; });
    const double viewMs = median(k, [](const Round& r) { return 1e3 * r.viewCpu; });
    const double perSampleUs = median(k, [](const Round& r) { return 1e6 * (r.smaCpu - r.viewCpu) / r.samples; });
    const double rendererUs = median(k, [](const Round& r) { return 1e6 * r.rendererCpu / r.samples; });
    const double toR = median(k, [](const Round& r) { return r.toRenderers / r.samples; });
    const double fromR = median(k, [](const Round& r) { return r.fromRenderers / r.samples; });
    const double toC = median(k, [](const Round& r) { return r.toClient / r.samples; });
    const double rendererCores = median(k, [](const Round& r) { return r.rendererCpu / r.seconds; });
    const double machineCores = median(k, [](const Round& r) { return r.machineCores; });
    std::printf("%d renderer(s): %.0f samples/s (median) = %.2f x 1 renderer [ideal %d.00; %.2f by what the machine "
                "gave %d busy thread(s): %.2f cores]\n",
                k, rate, rate / rate1, k, machineCores / machineCores1, k, machineCores);
    std::printf("    %.0f samples per view; the renderers got %.2f of %d cores\n", samples, rendererCores, k);
    std::printf("    per renderer CPU second: %.0f samples = %.2f x 1 renderer's [ideal 1.00]\n", 1e6 / rendererUs,
                rendererUs1 / rendererUs);
    std::printf("    SMA CPU %.1f us/sample = %.4f x renderer CPU (%.0f us/sample); of which per view %.0f ms "
                "(the same view, all cached), per sample %.1f us\n",
                smaUs, smaUs / rendererUs, rendererUs, viewMs, perSampleUs);
    std::printf("    wire: to renderers %.1f B/sample, from renderers %.1f B/sample = %.2f x their floats (%.0f B); "
                "to client %.1f B/sample\n",
                toR, fromR, (toR + fromR) / (kRequestFloatBytes + kReplyFloatBytes),
                kRequestFloatBytes + kReplyFloatBytes, toC);
  }
  return 0;
}

}  // namespace
}  // namespace penumbra

int main(int argc, char** argv) {
  penumbra::Options o;
  CLI::App app{"scaling_bench: samples/s with 1 and 2 renderers behind one SMA, and the SMA's cost per sample"};
  app.add_option("--scene", o.scene, "Scene file (default: scenes/sponza.json, else scenes/cornell-box.json)");
  app.add_option("--camera", o.camera, "Camera preset of the view (default: atrium, or front on the Cornell box)");
  app.add_option("--spp", o.spp, "Paths per sample (default: 256 on Sponza, 200000 on the Cornell box)");
  app.add_option("--max-bounces", o.maxBounces, "Bounces after the sample (0: direct light)")->capture_default_str();
  app.add_option("--width", o.width, "Viewport width")->capture_default_str();
  app.add_option("--height", o.height, "Viewport height")->capture_default_str();
  app.add_option("--rounds", o.rounds, "Rounds of each renderer count")->check(CLI::Range(1, 100))->capture_default_str();
  app.add_option("--max-renderers", o.maxRenderers, "Largest renderer count")->check(CLI::Range(1, 64))
      ->capture_default_str();
  app.add_option("--criterion", o.criterion, "The SMA's refinement criterion (none: the view's samples only)")
      ->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  return penumbra::Run(o);
}

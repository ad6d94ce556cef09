// The SMA's cache on disk (--cache-dir), on real processes: a renderer and
// an SMA on the Cornell box, a scripted client (support/sma_client.h) whose
// every delta is checked. A kill -9 loses at most what was shaded since the
// last snapshot; a SIGTERM writes a final snapshot; a bad file or a second SMA
// on the same directory gets a clear message.

#include <signal.h>

#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <thread>

#include <gtest/gtest.h>

#include "penumbra/common/scene.h"
#include "support/service.h"
#include "support/sma_client.h"

namespace penumbra::testing {
namespace {

using namespace std::chrono_literals;

const std::string kScene = std::string(PENUMBRA_SOURCE_DIR) + "/scenes/cornell-box.json";
constexpr int kWidth = 160;
constexpr int kHeight = 120;
constexpr const char* kSnapshotFile = "sma-cache.snapshot";

Service StartRenderer(const std::string& tag) {
  auto s = StartService(PENUMBRA_RENDERER_EXE,
                        {"--scene", kScene, "--threads", "1", "--spp", "16", "--max-bounces", "2"}, tag);
  EXPECT_TRUE(s.ok()) << s.error().message;
  return s.ok() ? std::move(*s) : Service{};
}

// Two ways to converge, each deterministic given the cache, so that a
// restarted SMA has exactly nothing left to do for a view it had converged:
//  * refinement with NLD_OS, so that the cache holds the midpoints of splits,
//    without improvement (a live SMA does not look for splits again once
//    improvement has changed the samples it judged: a restarted one, seeing
//    the improved samples from the start, may split a few leaves more);
//  * improvement without refinement, so that the cache holds samples of
//    several rounds whose paths and errors must come back too.
enum class Mode { kRefine, kImprove };

std::vector<std::string> SmaArgs(const Service& renderer, const std::string& cacheDir, int snapshotSeconds,
                                 Mode mode) {
  std::vector<std::string> args = {"--scene", kScene, "--renderer", renderer.Address(), "--cache-dir", cacheDir,
                                   "--cache-snapshot-interval", std::to_string(snapshotSeconds)};
  if (mode == Mode::kRefine)
    args.insert(args.end(), {"--criterion", "nld_os", "--improve-paths", "0"});
  else
    args.insert(args.end(), {"--criterion", "none", "--improve-paths", "64", "--improve-target-error", "0.02"});
  return args;
}

Service StartSma(const Service& renderer, const std::string& cacheDir, int snapshotSeconds, Mode mode,
                 const std::string& tag) {
  auto s = StartService(PENUMBRA_SMA_EXE, SmaArgs(renderer, cacheDir, snapshotSeconds, mode), tag);
  EXPECT_TRUE(s.ok()) << s.error().message;
  return s.ok() ? std::move(*s) : Service{};
}

CameraView Preset(const SmaTestClient& c, const std::string& name) {
  for (const auto& p : c.Info().cameras())
    if (p.name() == name) return ViewFromPreset(p, kWidth, kHeight);
  ADD_FAILURE() << "no camera preset " << name;
  return CameraView{};
}

double MustCounter(SmaTestClient& c, const std::string& name) {
  auto value = c.Counter(name);
  EXPECT_TRUE(value.ok()) << name << ": " << value.error().message;
  return value.ok() ? *value : -1.0;
}

// Polls until `done()`; false after `timeout`.
bool WaitFor(const std::function<bool()>& done, std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < deadline) {
    if (done()) return true;
    std::this_thread::sleep_for(50ms);
  }
  return false;
}

std::string ReadLog(const Service& s) {
  std::ifstream in(s.process.LogPath());
  return std::string(std::istreambuf_iterator<char>(in), {});
}

TEST(SmaCacheOnDiskTest, AKilledSmaRestartsWithItsCacheAndShadesNothingTheSnapshotHeld) {
  Service renderer = StartRenderer("cache-renderer");
  const std::string cacheDir = MakeTempDir("penumbra-sma-cache");

  // First life: converge, and wait for a snapshot that holds it all.
  Service sma = StartSma(renderer, cacheDir, 1, Mode::kRefine, "cache-sma-1");
  std::map<uint64_t, HeldMesh::Vertex> heldBefore;
  std::set<uint64_t> trianglesBefore;
  double shadedAtKill = 0.0, snapshotSamples = 0.0, nodesBefore = 0.0;
  {
    auto c = SmaTestClient::Connect(sma.port);
    ASSERT_TRUE(c.ok()) << c.error().message;
    EXPECT_EQ(MustCounter(*c, "cache_restored_samples"), 0.0);
    ASSERT_TRUE(c->SendView(Preset(*c, "front"), 1));
    ASSERT_TRUE(c->WaitConverged(1, 180s).ok()) << sma.process.LogTail();
    ASSERT_GT(MustCounter(*c, "client_refinement_splits"), 0.0);
    heldBefore = c->Mesh().Vertices();
    trianglesBefore = c->Mesh().TriangleIds();
    ASSERT_TRUE(WaitFor(
        [&] {
          return MustCounter(*c, "cache_snapshots_written") >= 1.0 &&
                 MustCounter(*c, "cache_snapshot_samples") == MustCounter(*c, "cache_shaded");
        },
        30s))
        << sma.process.LogTail();
    shadedAtKill = MustCounter(*c, "cache_shaded");
    snapshotSamples = MustCounter(*c, "cache_snapshot_samples");
    nodesBefore = MustCounter(*c, "hierarchy_nodes");
    ASSERT_GT(shadedAtKill, 0.0);
  }
  sma.process.Signal(SIGKILL);
  ASSERT_TRUE(sma.process.WaitExit(10s).has_value());
  ASSERT_TRUE(std::filesystem::exists(std::filesystem::path(cacheDir) / kSnapshotFile));

  // Second life: the same view converges from the restored cache.
  Service again = StartSma(renderer, cacheDir, 1, Mode::kRefine, "cache-sma-2");
  auto c = SmaTestClient::Connect(again.port);
  ASSERT_TRUE(c.ok()) << c.error().message;
  EXPECT_EQ(MustCounter(*c, "cache_restored_samples"), snapshotSamples);
  EXPECT_EQ(MustCounter(*c, "cache_shaded"), snapshotSamples);
  EXPECT_EQ(MustCounter(*c, "hierarchy_nodes"), nodesBefore);
  ASSERT_TRUE(c->SendView(Preset(*c, "front"), 1));
  ASSERT_TRUE(c->WaitConverged(1, 180s).ok()) << again.process.LogTail();
  // At most what was shaded after the last snapshot is asked again (here the
  // snapshot held everything, so nothing is).
  const double requested = MustCounter(*c, "samples_requested");
  EXPECT_LE(requested, shadedAtKill - snapshotSamples) << again.process.LogTail();
  EXPECT_EQ(MustCounter(*c, "samples_shaded"), 0.0);
  // The same ids name the same surface points with the same samples: the
  // client holds exactly what it held before the kill.
  EXPECT_EQ(c->Mesh().TriangleIds(), trianglesBefore);
  ASSERT_EQ(c->Mesh().Vertices().size(), heldBefore.size());
  for (const auto& [id, v] : c->Mesh().Vertices()) {
    auto it = heldBefore.find(id);
    ASSERT_NE(it, heldBefore.end()) << "vertex " << id << " was not held before";
    EXPECT_EQ(v.position, it->second.position) << "vertex " << id;
    EXPECT_EQ(v.radiance, it->second.radiance) << "vertex " << id;
    EXPECT_EQ(v.irradiance, it->second.irradiance) << "vertex " << id;
  }
  EXPECT_NE(ReadLog(again).find("cache: restored"), std::string::npos) << again.process.LogTail();

  // A second SMA on the same directory is refused with a clear message.
  auto second = ChildProcess::Spawn(PENUMBRA_SMA_EXE, SmaArgs(renderer, cacheDir, 1, Mode::kRefine), cacheDir + "/second.log");
  ASSERT_TRUE(second.ok()) << second.error().message;
  const auto code = second->WaitExit(60s);
  ASSERT_TRUE(code.has_value()) << second->LogTail();
  EXPECT_EQ(*code, 1);
  EXPECT_NE(second->LogTail().find("another SMA is using it"), std::string::npos) << second->LogTail();
  std::filesystem::remove_all(cacheDir);
}

// A snapshot taken while refinement samples are on their way holds splits
// whose midpoints have no sample. Nothing would ask for them after a restart
// (visibility shows a split's parent until they arrive, refinement never
// splits a node twice), so the restarted SMA asks for them itself.
TEST(SmaCacheOnDiskTest, SplitsSavedBeforeTheirSamplesAreShadedAfterARestart) {
  Service renderer = StartRenderer("cache-mid-renderer");
  const std::string cacheDir = MakeTempDir("penumbra-sma-cache-mid");
  // Refinement samples of 65536 paths each: seconds of work per step on one
  // renderer thread, so snapshots happen while they are on their way.
  std::vector<std::string> slow = SmaArgs(renderer, cacheDir, 1, Mode::kRefine);
  slow.insert(slow.end(), {"--first-paths", "16", "--paths", "65536"});
  auto sma = StartService(PENUMBRA_SMA_EXE, slow, "cache-mid-sma");
  ASSERT_TRUE(sma.ok()) << sma.error().message;
  {
    auto c = SmaTestClient::Connect(sma->port);
    ASSERT_TRUE(c.ok()) << c.error().message;
    ASSERT_TRUE(c->SendView(Preset(*c, "front"), 1));
    ASSERT_TRUE(WaitFor([&] { return MustCounter(*c, "client_refinement_pending") > 0.0; }, 120s))
        << sma->process.LogTail();
    // Two snapshots later, one was surely taken after those splits.
    const double written = MustCounter(*c, "cache_snapshots_written");
    ASSERT_TRUE(WaitFor([&] { return MustCounter(*c, "cache_snapshots_written") >= written + 2.0; }, 60s))
        << sma->process.LogTail();
  }
  sma->process.Signal(SIGKILL);
  ASSERT_TRUE(sma->process.WaitExit(10s).has_value());

  // Restarted with fast samples and no client at all.
  std::vector<std::string> fast = SmaArgs(renderer, cacheDir, 1, Mode::kRefine);
  fast.insert(fast.end(), {"--paths", "16"});
  auto again = StartService(PENUMBRA_SMA_EXE, fast, "cache-mid-sma-2");
  ASSERT_TRUE(again.ok()) << again.error().message;
  const std::string log = ReadLog(*again);
  const std::string marker = " restored midpoints were still unshaded";
  const size_t at = log.find(marker);
  ASSERT_NE(at, std::string::npos) << log;
  const size_t start = log.rfind(' ', at - 1) + 1;
  const double unshaded = std::stod(log.substr(start, at - start));
  ASSERT_GT(unshaded, 0.0) << "every refinement sample arrived before the last snapshot: " << log;
  auto c = SmaTestClient::Connect(again->port);
  ASSERT_TRUE(c.ok()) << c.error().message;
  const double restored = MustCounter(*c, "cache_restored_samples");
  EXPECT_TRUE(WaitFor([&] { return MustCounter(*c, "cache_shaded") == restored + unshaded; }, 120s))
      << "restored " << restored << " + unshaded " << unshaded << ", shaded " << MustCounter(*c, "cache_shaded")
      << "\n" << again->process.LogTail();
  EXPECT_EQ(MustCounter(*c, "samples_requested"), unshaded);
  std::filesystem::remove_all(cacheDir);
}

TEST(SmaCacheOnDiskTest, ASigtermedSmaWritesItsFinalSnapshot) {
  Service renderer = StartRenderer("cache-term-renderer");
  const std::string cacheDir = MakeTempDir("penumbra-sma-cache-term");
  // A corrupt file there to start with: a warning, an empty cache, and the
  // SMA serves as usual.
  {
    std::ofstream(std::filesystem::path(cacheDir) / kSnapshotFile, std::ios::binary) << "PNBRSMAC garbage";
  }
  // An interval no test reaches: only the shutdown writes a snapshot.
  Service sma = StartSma(renderer, cacheDir, 3600, Mode::kImprove, "cache-term-sma");
  double shaded = 0.0;
  {
    auto c = SmaTestClient::Connect(sma.port);
    ASSERT_TRUE(c.ok()) << c.error().message;
    EXPECT_EQ(MustCounter(*c, "cache_restored_samples"), 0.0);
    ASSERT_TRUE(c->SendView(Preset(*c, "corner"), 1));
    ASSERT_TRUE(c->WaitConverged(1, 180s).ok()) << sma.process.LogTail();
    EXPECT_EQ(MustCounter(*c, "cache_snapshots_written"), 0.0);
    shaded = MustCounter(*c, "cache_shaded");
    ASSERT_GT(shaded, 0.0);
    ASSERT_GT(MustCounter(*c, "samples_improved"), 0.0);
  }
  const std::string log = ReadLog(sma);
  EXPECT_NE(log.find("ignored: "), std::string::npos) << log;
  sma.process.Signal(SIGTERM);
  const auto code = sma.process.WaitExit(30s);
  ASSERT_TRUE(code.has_value()) << sma.process.LogTail();
  EXPECT_EQ(*code, 0) << sma.process.LogTail();
  EXPECT_NE(ReadLog(sma).find("cache: snapshot of"), std::string::npos) << sma.process.LogTail();

  Service again = StartSma(renderer, cacheDir, 3600, Mode::kImprove, "cache-term-sma-2");
  auto c = SmaTestClient::Connect(again.port);
  ASSERT_TRUE(c.ok()) << c.error().message;
  EXPECT_EQ(MustCounter(*c, "cache_restored_samples"), shaded) << again.process.LogTail();
  ASSERT_TRUE(c->SendView(Preset(*c, "corner"), 1));
  ASSERT_TRUE(c->WaitConverged(1, 180s).ok()) << again.process.LogTail();
  EXPECT_EQ(MustCounter(*c, "samples_requested"), 0.0) << again.process.LogTail();
  std::filesystem::remove_all(cacheDir);
}

}  // namespace
}  // namespace penumbra::testing

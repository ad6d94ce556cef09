// Penumbra across hosts: two renderer hosts, an SMA host and a client host,
// each a network namespace of its own (support/netns.h), talking over real
// TCP between distinct addresses. The SMA is given one renderer *name*,
// which its host's /etc/hosts resolves to every renderer host's address, as
// Docker's DNS resolves a service to its replicas (deploy/docker-compose.yml);
// the SMA re-resolves it every second. On the client host, the headless
// penumbra-client walks a camera path, and a scripted client (tests/support)
// reads the SMA's counters or drives views itself. Without root (or where the
// kernel refuses namespaces) the tests skip and say why.

#include <cstdlib>
#include <signal.h>

#include <filesystem>
#include <fstream>
#include <functional>
#include <thread>

#include <gtest/gtest.h>

#include "penumbra/common/scene.h"
#include "support/netns.h"
#include "support/sma_client.h"

namespace penumbra::testing {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;

const std::string kScene = std::string(PENUMBRA_SOURCE_DIR) + "/scenes/cornell-box.json";
#ifdef PENUMBRA_CLIENT_EXE
const std::string kClientExe = PENUMBRA_CLIENT_EXE;
#else
const std::string kClientExe;  // this tree builds no GL client
#endif
constexpr uint16_t kRendererPort = 7100;
constexpr uint16_t kSmaPort = 7200;
const std::string kRenderers = "renderers";  // the name the SMA is given
// Slow samples (about 0.1-0.3 s each), in batches of two, so that every
// renderer has work in flight for seconds: long enough to kill, restart and
// rescale while a view is being shaded. Refinement is off: the work is the
// walk's vertices, a fixed amount, whatever the refinement criteria do.
constexpr int kPathsPerSample = 300000;
constexpr int kWidth = 96;
constexpr int kHeight = 72;

// Polls `done` every 50 ms until it holds or `timeout` passes.
bool WaitUntil(const std::function<bool()>& done, std::chrono::milliseconds timeout) {
  const auto deadline = Clock::now() + timeout;
  while (!done()) {
    if (Clock::now() >= deadline) return false;
    std::this_thread::sleep_for(50ms);
  }
  return true;
}

std::string LastLine(const std::string& path) {
  std::ifstream in(path);
  std::string line, last;
  while (std::getline(in, line))
    if (!line.empty()) last = line;
  return last;
}

class MultiHostTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto net = VirtualNetwork::Create();
    if (!net) {
      // Where they must run (scripts/fresh-machine.sh, CI), a skip would hide a broken set-up.
      if (std::getenv("PENUMBRA_REQUIRE_NETNS") != nullptr)
        FAIL() << "PENUMBRA_REQUIRE_NETNS is set, but network namespaces cannot be made: " << net.error().message;
      GTEST_SKIP() << "needs network namespaces, which cannot be made here: " << net.error().message;
    }
    net_ = std::move(*net);
    for (const char* host : {"render1", "render2", "sma", "client"}) {
      auto address = net_->AddHost(host);
      ASSERT_TRUE(address.ok()) << address.error().message;
    }
    dir_ = MakeTempDir("penumbra-multi-host");
  }
  void TearDown() override {
    std::error_code ec;
    if (!dir_.empty()) std::filesystem::remove_all(dir_, ec);
  }

  std::string Endpoint(const std::string& host) const {
    return net_->Address(host) + ":" + std::to_string(kRendererPort);
  }
  // The SMA's /etc/hosts: the renderer name resolves to these hosts.
  void ResolveRenderersTo(const std::vector<std::string>& hosts) {
    std::vector<std::pair<std::string, std::string>> entries;
    for (const auto& h : hosts) entries.emplace_back(kRenderers, net_->Address(h));
    ASSERT_TRUE(net_->SetHostsFile("sma", entries).ok());
  }

  // Starts `exe` on `host`, its output in the test's directory.
  ChildProcess Spawn(const std::string& host, const std::string& exe, const std::vector<std::string>& args) {
    auto process = net_->Spawn(host, exe, args, dir_ + "/" + host + ".log");
    EXPECT_TRUE(process.ok()) << process.error().message;
    return process.ok() ? std::move(*process) : ChildProcess();
  }
  // Starts a server on `host` with --port-file and waits until it listens.
  ChildProcess Start(const std::string& host, const std::string& exe, std::vector<std::string> args) {
    const std::string portFile = dir_ + "/" + host + ".port";
    std::filesystem::remove(portFile);  // a restart must not read the last run's port
    args.insert(args.end(), {"--port-file", portFile, "--log-level", "info"});
    ChildProcess process = Spawn(host, exe, args);
    if (!process.Running()) return process;
    auto port = WaitForPortFile(process, portFile, 60s);
    EXPECT_TRUE(port.ok()) << host << ": " << port.error().message;
    return process;
  }
  ChildProcess StartRenderer(const std::string& host) {
    return Start(host, PENUMBRA_RENDERER_EXE,
                 {"--scene", kScene, "--listen", Endpoint(host), "--threads", "1", "--spp",
                  std::to_string(kPathsPerSample), "--max-bounces", "2", "--name", host});
  }
  ChildProcess StartSma() {
    return Start("sma", PENUMBRA_SMA_EXE,
                 {"--scene", kScene, "--listen", net_->Address("sma") + ":" + std::to_string(kSmaPort), "--renderer",
                  kRenderers + ":" + std::to_string(kRendererPort), "--resolve-interval", "1", "--max-batch", "2",
                  "--credits", "2", "--criterion", "none",
                  // Every sample at the renderers' (slow) --spp, stage 1 too, so that work is in flight when a
                  // renderer is killed.
                  "--first-paths", "0"});
  }
  // A scripted client on the client host (its socket lives there).
  SmaTestClient ConnectClient() {
    auto client = net_->RunOnHost(
        "client", [&] { return SmaTestClient::Connect(net_->Address("sma"), kSmaPort, "multi-host-walker"); });
    EXPECT_TRUE(client.ok()) << client.error().message;
    return std::move(*client);
  }

  // A counter's value, or nullopt when the SMA does not list it.
  static std::optional<double> Counter(SmaTestClient& client, const std::string& name) {
    auto value = client.Counter(name);
    if (!value) return std::nullopt;
    return *value;
  }
  static double Must(SmaTestClient& client, const std::string& name) {
    auto value = client.Counter(name);
    EXPECT_TRUE(value.ok()) << name << ": " << value.error().message;
    return value.ok() ? *value : -1.0;
  }
  // Waits until the renderer queue is empty: every sample asked for answered.
  static bool Drained(SmaTestClient& client) {
    return WaitUntil([&] {
      return Must(client, "samples_queued_visible") + Must(client, "samples_queued_background") +
                 Must(client, "samples_in_flight") == 0.0;
    }, 120s);
  }
  // Every sample the SMA ever asked for is in its cache, exactly once.
  static void ExpectNoSampleLost(SmaTestClient& client) {
    ASSERT_TRUE(Drained(client));
    const double requested = Must(client, "samples_requested");
    EXPECT_GT(requested, 0.0);
    EXPECT_EQ(requested, Must(client, "cache_shaded"));
    EXPECT_EQ(Must(client, "samples_failed"), 0.0);
  }
  static void ExpectShaded(SmaTestClient& client) {
    EXPECT_FALSE(client.Mesh().Triangles().empty());
    for (const auto& [id, v] : client.Mesh().Vertices())
      for (int c = 0; c < 3; ++c) EXPECT_GE(v.radiance[c], 0.0f) << "vertex " << id;
  }
  std::unique_ptr<VirtualNetwork> net_;  // first member: outlives the processes
  std::string dir_;
};

TEST_F(MultiHostTest, RendererHostKilledMidWalkthroughAndRestartedLosesNoSample) {
  if (kClientExe.empty()) GTEST_SKIP() << "penumbra-client is not built in this tree (PENUMBRA_BUILD_CLIENT_GUI=OFF)";
  ResolveRenderersTo({"render1", "render2"});
  ChildProcess render1 = StartRenderer("render1");
  ChildProcess render2 = StartRenderer("render2");
  ChildProcess sma = StartSma();
  ASSERT_FALSE(HasFailure());
  SmaTestClient observer = ConnectClient();  // reads the SMA's counters
  ASSERT_FALSE(HasFailure());
  ASSERT_TRUE(WaitUntil([&] { return Must(observer, "renderers_connected") == 2.0; }, 30s)) << sma.LogTail();

  // The headless client walks the scene's camera path from its own host and
  // exits once the SMA reports the path's last view converged.
  const std::string stats = dir_ + "/client-stats.jsonl";
  ChildProcess walker = Spawn("client", kClientExe,
                              {"--connect", net_->Address("sma") + ":" + std::to_string(kSmaPort), "--headless",
                               "--gl", "egl", "--camera-path", kScene + "#walk", "--until-converged", "--timeout",
                               "300", "--stats", stats});
  ASSERT_FALSE(HasFailure());

  // render2's host loses its renderer mid-walkthrough... (Clients see
  // renderers by index; the SMA's log says which address each index is.)
  auto r2Prefix = RendererCounterPrefix(sma, Endpoint("render2"));
  ASSERT_TRUE(r2Prefix.ok()) << r2Prefix.error().message;
  const std::string r2 = *r2Prefix;
  ASSERT_TRUE(WaitUntil([&] { return Must(observer, r2 + ".samples_in_flight") > 0.0; }, 60s))
      << "render2 never got work\n" << sma.LogTail() << walker.LogTail();
  render2.Signal(SIGKILL);
  ASSERT_TRUE(render2.WaitExit(10s).has_value());
  ASSERT_TRUE(WaitUntil([&] { return Must(observer, r2 + ".connected") == 0.0; }, 30s)) << sma.LogTail();
  EXPECT_GT(Must(observer, "samples_requeued"), 0.0) << "render2's samples in flight were not sent again";
  EXPECT_GE(Must(observer, r2 + ".failures"), 1.0);

  // ...and gets it back: the SMA reconnects on its own and uses it again.
  render2 = StartRenderer("render2");
  ASSERT_FALSE(HasFailure());
  ASSERT_TRUE(WaitUntil([&] { return Must(observer, r2 + ".connected") == 1.0; }, 30s)) << sma.LogTail();
  const double shadedBeforeRestart = Must(observer, r2 + ".samples_shaded");

  // The observer asks for a counter every few seconds meanwhile: a client
  // silent for the SMA's read timeout (20 s) is dropped, and on a loaded
  // machine the walk takes longer than that.
  std::optional<int> exit;
  for (const auto walkDeadline = std::chrono::steady_clock::now() + 300s;
       !exit && std::chrono::steady_clock::now() < walkDeadline;) {
    exit = walker.WaitExit(3s);
    if (!exit) Must(observer, "renderers_connected");
  }
  ASSERT_EQ(exit, 0) << "the headless client did not converge:\n" << walker.LogTail() << sma.LogTail();
  const std::string last = LastLine(stats);
  EXPECT_NE(last.find("\"converged\":true"), std::string::npos) << last;
  EXPECT_EQ(last.find("\"triangles_held\":0,"), std::string::npos) << last;
  ExpectNoSampleLost(observer);
  EXPECT_EQ(Must(observer, "renderers_connected"), 2.0);
  EXPECT_GT(Must(observer, r2 + ".samples_shaded"), shadedBeforeRestart)
      << "the restarted renderer got no work: the walk had none left when it came back";
  EXPECT_TRUE(render1.Running());
  EXPECT_TRUE(sma.Running());
}

TEST_F(MultiHostTest, RenderersJoinAndLeaveThroughDnsWithoutRestartingTheSma) {
  ResolveRenderersTo({"render1"});
  ChildProcess render1 = StartRenderer("render1");
  ChildProcess render2 = StartRenderer("render2");  // running, but not in DNS yet
  ChildProcess sma = StartSma();
  ASSERT_FALSE(HasFailure());
  SmaTestClient client = ConnectClient();
  ASSERT_FALSE(HasFailure());
  ASSERT_TRUE(WaitUntil([&] { return Must(client, "renderers_connected") == 1.0; }, 30s)) << sma.LogTail();
  EXPECT_EQ(Must(client, "renderers"), 1.0);
  // Clients see renderers by index; the SMA's log says which address each is.
  auto r1Prefix = RendererCounterPrefix(sma, Endpoint("render1"));
  ASSERT_TRUE(r1Prefix.ok()) << r1Prefix.error().message;
  const std::string r1 = *r1Prefix;
  EXPECT_FALSE(RendererCounterPrefix(sma, Endpoint("render2"), 0s).ok()) << "render2 is not in DNS yet";

  auto scene = LoadScene(kScene);
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  CameraView view = ViewFromPreset(client.Info().cameras(0), kWidth, kHeight);
  ASSERT_TRUE(client.SendView(view, 1));
  ASSERT_TRUE(WaitUntil([&] { return Must(client, r1 + ".samples_in_flight") > 0.0; }, 30s)) << sma.LogTail();

  // Scale up: the name now resolves to both hosts.
  ResolveRenderersTo({"render1", "render2"});
  auto r2Prefix = RendererCounterPrefix(sma, Endpoint("render2"));
  ASSERT_TRUE(r2Prefix.ok()) << r2Prefix.error().message << "\n" << sma.LogTail();
  const std::string r2 = *r2Prefix;
  ASSERT_TRUE(WaitUntil([&] { return Counter(client, r2 + ".connected") == 1.0; }, 30s))
      << "the SMA did not pick up render2 from DNS\n" << sma.LogTail();
  ASSERT_TRUE(WaitUntil([&] { return Must(client, r2 + ".samples_shaded") > 0.0; }, 30s))
      << "render2 joined but got no work\n" << sma.LogTail();

  // Scale down: render1 leaves the name (it keeps running, as a container
  // being stopped would until it is gone); its unanswered samples move to
  // render2.
  ResolveRenderersTo({"render2"});
  ASSERT_TRUE(WaitUntil([&] { return !Counter(client, r1 + ".connected").has_value(); }, 30s))
      << "the SMA kept render1 after it left DNS\n" << sma.LogTail();
  EXPECT_EQ(Must(client, "renderers"), 1.0);

  auto converged = client.WaitConverged(1, 180s);
  ASSERT_TRUE(converged.ok()) << converged.error().message << "\n" << sma.LogTail();
  ExpectShaded(client);
  ExpectNoSampleLost(client);
  EXPECT_TRUE(sma.Running());

  // render1 really was let go: the only connection it has is ours.
  auto connections = net_->RunOnHost("sma", [&]() -> Expected<double> {
    auto wire = WireClient::Connect(net_->Address("render1"), kRendererPort);
    if (!wire) return wire.error();
    if (auto welcome = wire->Handshake(wire::ROLE_SMA, scene->identity); !welcome) return welcome.error();
    return wire->Counter("connections");
  });
  ASSERT_TRUE(connections.ok()) << connections.error().message;
  EXPECT_EQ(*connections, 1.0);
}

}  // namespace
}  // namespace penumbra::testing

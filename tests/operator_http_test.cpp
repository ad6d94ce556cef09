// The operator HTTP endpoint (--http) of real penumbra-renderer and
// penumbra-sma processes: /healthz, /readyz (503 without a renderer, 200
// with one), /metrics parsed strictly and checked for sane values after a
// client converged, penumbra-stats on top, and hostile HTTP input that must
// get a 4xx and leave the service undisturbed.

#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <csignal>
#include <atomic>
#include <cmath>
#include <fstream>
#include <memory>
#include <set>
#include <thread>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "penumbra/common/metrics.h"
#include "penumbra/common/operator_http.h"
#include "support/http_client.h"
#include "support/process.h"
#include "support/sma_client.h"

namespace penumbra::testing {
namespace {

using namespace std::chrono_literals;
using metrics::Exposition;

const std::string kScene = std::string(PENUMBRA_SOURCE_DIR) + "/scenes/cornell-box.json";

// A port free right now (bound, then released), for a renderer started later.
uint16_t FreePort() {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  ::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a);
  socklen_t len = sizeof a;
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
  ::close(fd);
  return ntohs(a.sin_port);
}

// A tier started with --http 127.0.0.1:0; its two ports from port files.
struct Tier {
  ChildProcess process;
  uint16_t port = 0;
  uint16_t httpPort = 0;
};

Tier Start(const std::string& exe, std::vector<std::string> args, const std::string& tag) {
  const std::string dir = MakeTempDir("penumbra-" + tag);
  args.insert(args.end(), {"--port-file", dir + "/port", "--http", "127.0.0.1:0", "--http-port-file",
                           dir + "/http-port"});
  Tier t;
  auto process = ChildProcess::Spawn(exe, args, dir + "/" + tag + ".log");
  EXPECT_TRUE(process) << (process ? "" : process.error().message);
  if (!process) return t;
  t.process = std::move(*process);
  auto http = WaitForPortFile(t.process, dir + "/http-port", 60s);
  EXPECT_TRUE(http) << (http ? "" : http.error().message) << t.process.LogTail();
  if (http) t.httpPort = *http;
  auto port = WaitForPortFile(t.process, dir + "/port", 60s);
  EXPECT_TRUE(port) << (port ? "" : port.error().message) << t.process.LogTail();
  if (port) t.port = *port;
  return t;
}

Tier StartRenderer(uint16_t port) {
  return Start(PENUMBRA_RENDERER_EXE,
               {"--scene", kScene, "--listen", "127.0.0.1:" + std::to_string(port), "--threads", "1", "--spp", "16",
                "--max-bounces", "2"},
               "ops-renderer");
}

int Status(uint16_t port, const std::string& path) {
  auto reply = HttpGet(port, path);
  EXPECT_TRUE(reply) << path << ": " << (reply ? "" : reply.error().message);
  return reply ? reply->status : 0;
}

// GET /metrics, parse strictly, and check what holds for any exposition of
// ours: every family typed and described, every sample in a declared
// family, counters non-negative, histogram buckets cumulative.
Exposition Scrape(uint16_t port) {
  auto reply = HttpGet(port, "/metrics");
  EXPECT_TRUE(reply) << (reply ? "" : reply.error().message);
  if (!reply) return {};
  EXPECT_EQ(reply->status, 200);
  EXPECT_NE(reply->headers.find("text/plain; version=0.0.4"), std::string::npos) << reply->headers;
  auto parsed = metrics::ParseExposition(reply->body);
  EXPECT_TRUE(parsed) << (parsed ? "" : parsed.error().message) << "\n" << reply->body;
  if (!parsed) return {};
  for (const auto& f : parsed->families) {
    EXPECT_NE(f.type, "untyped") << f.name;
    EXPECT_FALSE(f.help.empty()) << f.name;
    if (f.type == "counter") {
      EXPECT_TRUE(f.name.ends_with("_total")) << f.name;
    }
  }
  for (const auto& s : parsed->samples) {
    const auto* family = parsed->FamilyOf(s);
    EXPECT_NE(family, nullptr) << s.name << " has no # TYPE line";
    EXPECT_TRUE(std::isfinite(s.value) || s.name.ends_with("_bucket")) << s.name;
    if (family && family->type == "counter") {
      EXPECT_GE(s.value, 0.0) << s.name;
    }
    if (family && family->type == "histogram" && s.name.ends_with("_count")) {
      const std::string base = family->name;
      double previous = 0.0;
      for (const auto& b : parsed->samples)
        if (b.name == base + "_bucket") {
          EXPECT_GE(b.value, previous) << base << " buckets are not cumulative";
          previous = b.value;
        }
      EXPECT_EQ(previous, s.value) << base << ": +Inf bucket != _count";
    }
  }
  return std::move(*parsed);
}

double Value(const Exposition& e, const std::string& name, const metrics::Labels& labels = {}) {
  const auto* s = e.Find(name, labels);
  EXPECT_NE(s, nullptr) << "no sample " << name;
  return s ? s->value : NAN;
}

class OperatorHttpTest : public ::testing::Test {
 protected:
  void SetUp() override {
    rendererPort_ = FreePort();
    sma_ = Start(PENUMBRA_SMA_EXE,
                 {"--scene", kScene, "--listen", "127.0.0.1:0", "--renderer",
                  "127.0.0.1:" + std::to_string(rendererPort_), "--criterion", "none", "--resolve-interval", "1",
                  "--log-format", "json"},
                 "ops-sma");
    ASSERT_NE(sma_.httpPort, 0);
    ASSERT_NE(sma_.port, 0);
  }
  void ConnectRenderer() {
    renderer_ = StartRenderer(rendererPort_);
    ASSERT_NE(renderer_.httpPort, 0);
    // The SMA reconnects on its own; ready once it has.
    const auto deadline = std::chrono::steady_clock::now() + 60s;
    while (Status(sma_.httpPort, "/readyz") != 200 && std::chrono::steady_clock::now() < deadline)
      std::this_thread::sleep_for(100ms);
    ASSERT_EQ(Status(sma_.httpPort, "/readyz"), 200) << sma_.process.LogTail();
  }
  void TearDown() override {
    EXPECT_TRUE(sma_.process.Running()) << sma_.process.LogTail();
    if (renderer_.httpPort != 0) {
    EXPECT_TRUE(renderer_.process.Running()) << renderer_.process.LogTail();
  }
  }

  uint16_t rendererPort_ = 0;
  Tier sma_;
  Tier renderer_;
};

TEST_F(OperatorHttpTest, SmaIsAliveButNotReadyWithoutARendererAndReadyWithOne) {
  EXPECT_EQ(Status(sma_.httpPort, "/healthz"), 200);
  auto notReady = HttpGet(sma_.httpPort, "/readyz");
  ASSERT_TRUE(notReady);
  EXPECT_EQ(notReady->status, 503);
  EXPECT_NE(notReady->body.find("no renderer connected"), std::string::npos) << notReady->body;
  const Exposition before = Scrape(sma_.httpPort);
  EXPECT_EQ(Value(before, "penumbra_sma_ready"), 0.0);
  EXPECT_EQ(Value(before, "penumbra_sma_renderers_up"), 0.0);

  ASSERT_NO_FATAL_FAILURE(ConnectRenderer());
  EXPECT_EQ(Status(renderer_.httpPort, "/healthz"), 200);
  EXPECT_EQ(Status(renderer_.httpPort, "/readyz"), 200);
  EXPECT_EQ(Value(Scrape(sma_.httpPort), "penumbra_sma_ready"), 1.0);

  // The renderer goes away: not ready again.
  renderer_.process.Signal(SIGKILL);
  renderer_.process.WaitExit(10s);
  renderer_ = Tier{};
  const auto deadline = std::chrono::steady_clock::now() + 30s;
  while (Status(sma_.httpPort, "/readyz") != 503 && std::chrono::steady_clock::now() < deadline)
    std::this_thread::sleep_for(100ms);
  EXPECT_EQ(Status(sma_.httpPort, "/readyz"), 503);
}

TEST_F(OperatorHttpTest, MetricsAreValidAndSaneAfterAClientConverged) {
  ASSERT_NO_FATAL_FAILURE(ConnectRenderer());
  auto client = SmaTestClient::Connect(sma_.port);
  ASSERT_TRUE(client) << client.error().message;
  const wire::CameraPreset* front = nullptr;
  for (const auto& p : client->Info().cameras())
    if (p.name() == "front") front = &p;
  ASSERT_NE(front, nullptr);
  ASSERT_TRUE(client->SendView(ViewFromPreset(*front, 96, 72), 1));
  ASSERT_TRUE(client->WaitConverged(1, 120s).ok()) << sma_.process.LogTail();

  const Exposition sma = Scrape(sma_.httpPort);
  for (const char* name :
       {"penumbra_sma_build_info", "penumbra_sma_uptime_seconds", "penumbra_sma_resident_memory_bytes",
        "penumbra_sma_ready", "penumbra_sma_clients", "penumbra_sma_hierarchy_nodes",
        "penumbra_sma_cache_shaded_vertices", "penumbra_sma_cache_hits_total", "penumbra_sma_samples_requested_total",
        "penumbra_sma_samples_shaded_total", "penumbra_sma_samples_queued", "penumbra_sma_samples_in_flight",
        "penumbra_sma_renderer_connected", "penumbra_sma_renderer_samples_shaded_total", "penumbra_sma_renderers",
        "penumbra_sma_renderers_up", "penumbra_sma_view_first_delta_seconds", "penumbra_sma_view_shaded_seconds",
        "penumbra_sma_view_converged_seconds"})
    EXPECT_NE(sma.FindFamily(name), nullptr) << name;
  EXPECT_EQ(Value(sma, "penumbra_sma_clients"), 1.0);
  EXPECT_EQ(Value(sma, "penumbra_sma_renderers_up"), 1.0);
  // Renderers are labelled by index, as clients see them; the info family
  // pairs the index with the address, for operators only.
  const std::string rendererAddress = "127.0.0.1:" + std::to_string(rendererPort_);
  EXPECT_EQ(Value(sma, "penumbra_sma_renderer_info", {{"renderer", "1"}, {"address", rendererAddress}}), 1.0);
  EXPECT_EQ(Value(sma, "penumbra_sma_renderer_connected", {{"renderer", "1"}}), 1.0);
  const double shaded = Value(sma, "penumbra_sma_samples_shaded_total");
  // Every sample in the cache was requested and answered at least once
  // (improvement rounds answer some of them again).
  const double requested = Value(sma, "penumbra_sma_samples_requested_total");
  const double cached = Value(sma, "penumbra_sma_cache_shaded_vertices");
  EXPECT_GT(cached, 0.0);
  EXPECT_LE(cached, requested);
  EXPECT_GE(shaded, cached);
  EXPECT_EQ(Value(sma, "penumbra_sma_samples_queued", {{"priority", "visible"}}), 0.0);
  EXPECT_EQ(Value(sma, "penumbra_sma_view_first_delta_seconds_count"), 1.0);
  EXPECT_EQ(Value(sma, "penumbra_sma_view_converged_seconds_count"), 1.0);
  EXPECT_GT(Value(sma, "penumbra_sma_view_converged_seconds_sum"), 0.0);
  EXPECT_LE(Value(sma, "penumbra_sma_view_first_delta_seconds_sum"),
            Value(sma, "penumbra_sma_view_converged_seconds_sum"));
  const double rss = Value(sma, "penumbra_sma_resident_memory_bytes");
  EXPECT_GT(rss, 4e6);
  EXPECT_LT(rss, 8e9);
  // The SMA's data (issue 15): the parts add up to the whole, each is there
  // (the client holds triangles, so its mirror is not empty), and the whole
  // is within what the process holds; no budget was given.
  const double memory = Value(sma, "penumbra_sma_memory_bytes");
  const double cacheBytes = Value(sma, "penumbra_sma_memory_part_bytes", {{"part", "cache"}});
  const double hierarchyBytes = Value(sma, "penumbra_sma_memory_part_bytes", {{"part", "hierarchy"}});
  const double clientBytes = Value(sma, "penumbra_sma_memory_part_bytes", {{"part", "clients"}});
  EXPECT_GT(cacheBytes, 0.0);
  EXPECT_GT(hierarchyBytes, 0.0);
  EXPECT_GT(clientBytes, 0.0);
  EXPECT_EQ(memory, cacheBytes + hierarchyBytes + clientBytes);
  EXPECT_LT(memory, rss);
  EXPECT_EQ(Value(sma, "penumbra_sma_memory_budget_bytes"), 0.0);
  // The same counters a client's StatsRequest reads.
  auto viaProtocol = client->Counter("samples_shaded");
  ASSERT_TRUE(viaProtocol);
  EXPECT_GE(*viaProtocol, shaded);

  const Exposition renderer = Scrape(renderer_.httpPort);
  EXPECT_EQ(Value(renderer, "penumbra_renderer_ready"), 1.0);
  EXPECT_EQ(Value(renderer, "penumbra_renderer_connections"), 1.0);
  EXPECT_EQ(Value(renderer, "penumbra_renderer_worker_threads"), 1.0);
  EXPECT_GE(Value(renderer, "penumbra_renderer_samples_shaded_total"), shaded);
  EXPECT_GE(Value(renderer, "penumbra_renderer_rays_traced_total"),
            Value(renderer, "penumbra_renderer_paths_traced_total"));
  EXPECT_GT(Value(renderer, "penumbra_renderer_resident_memory_bytes"), 4e6);

  // penumbra-stats reads the same endpoint for humans.
  auto printed = RunCommand(PENUMBRA_STATS_EXE, {"127.0.0.1:" + std::to_string(sma_.httpPort)});
  ASSERT_TRUE(printed) << printed.error().message;
  EXPECT_NE(printed->find("renderers up"), std::string::npos) << *printed;
  EXPECT_NE(printed->find("view converged"), std::string::npos) << *printed;
  EXPECT_NE(printed->find("MiB"), std::string::npos) << *printed;
  EXPECT_TRUE(RunCommand(PENUMBRA_STATS_EXE, {"--ready", "127.0.0.1:" + std::to_string(renderer_.httpPort)}));
}

TEST_F(OperatorHttpTest, PenumbraStatsFailsWhenNotReadyOrUnreachable) {
  const std::string address = "127.0.0.1:" + std::to_string(sma_.httpPort);
  EXPECT_FALSE(RunCommand(PENUMBRA_STATS_EXE, {"--ready", address}));  // no renderer yet
  EXPECT_TRUE(RunCommand(PENUMBRA_STATS_EXE, {address}));              // alive: figures print
  auto unreachable = RunCommand(PENUMBRA_STATS_EXE, {"--timeout", "2", "127.0.0.1:" + std::to_string(FreePort())});
  ASSERT_FALSE(unreachable);
  EXPECT_NE(unreachable.error().message.find("connect failed"), std::string::npos) << unreachable.error().message;
}

TEST_F(OperatorHttpTest, HostileRequestsGet4xxAndDoNotDisturbTheService) {
  ASSERT_NO_FATAL_FAILURE(ConnectRenderer());
  auto client = SmaTestClient::Connect(sma_.port);
  ASSERT_TRUE(client) << client.error().message;
  const uint16_t port = sma_.httpPort;

  auto expectStatus = [&](const std::string& request, int status, const std::string& what) {
    auto raw = RawHttpExchange(port, request);
    ASSERT_TRUE(raw) << what << ": " << raw.error().message;
    auto reply = ParseHttpReply(*raw);
    ASSERT_TRUE(reply) << what << ": " << reply.error().message;
    EXPECT_EQ(reply->status, status) << what << ": " << reply->headers;
  };
  expectStatus("GET /metrics HTTP/1.1\r\nHost: x\r\nX-Pad: " + std::string(64 * 1024, 'a') + "\r\n\r\n", 431,
               "64 KiB of headers");
  expectStatus("GET /" + std::string(20000, 'b') + " HTTP/1.1\r\nHost: x\r\n\r\n", 431, "a 20 kB request line");
  expectStatus("POST /metrics HTTP/1.1\r\nHost: x\r\nContent-Length: 3\r\n\r\nabc", 413, "a body");
  expectStatus("DELETE /metrics HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n", 405, "DELETE");
  expectStatus("HELLO THERE\r\n\r\n", 400, "garbage");
  expectStatus(std::string("\x00\x01\x02\xff\r\n\r\n", 8), 400, "binary garbage");
  expectStatus("GET /nope HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n", 404, "an unknown path");
  // Keep-alive: two requests on one connection, both answered.
  auto twice = RawHttpExchange(port,
                               "GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n"
                               "GET /healthz HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n");
  ASSERT_TRUE(twice) << twice.error().message;
  size_t answers = 0;
  for (size_t at = twice->find("HTTP/1.1 200"); at != std::string::npos; at = twice->find("HTTP/1.1 200", at + 1))
    ++answers;
  EXPECT_EQ(answers, 2u) << *twice;

  // More idle connections than the limit (32): the excess are closed at
  // once, and the endpoint answers again when they go.
  {
    std::vector<std::unique_ptr<IdleConnection>> idle;
    for (int i = 0; i < 40; ++i) idle.push_back(std::make_unique<IdleConnection>(port));
    int closed = 0;
    for (auto& c : idle) closed += c->ClosedByPeer(200ms) ? 1 : 0;
    EXPECT_GE(closed, 8);
  }
  // The server frees a slot when it sees the close; allow it a moment.
  const auto deadline = std::chrono::steady_clock::now() + 10s;
  while (Status(port, "/healthz") != 200 && std::chrono::steady_clock::now() < deadline)
    std::this_thread::sleep_for(50ms);
  EXPECT_EQ(Status(port, "/healthz"), 200);
  EXPECT_EQ(Status(port, "/readyz"), 200);
  // An idle connection is dropped after the read timeout (5 s).
  IdleConnection slow(port);
  EXPECT_TRUE(slow.ClosedByPeer(15s));

  // The SMA's own service carried on throughout.
  const wire::CameraPreset* front = nullptr;
  for (const auto& p : client->Info().cameras())
    if (p.name() == "front") front = &p;
  ASSERT_NE(front, nullptr);
  ASSERT_TRUE(client->SendView(ViewFromPreset(*front, 64, 48), 1));
  EXPECT_TRUE(client->WaitConverged(1, 120s).ok()) << sma_.process.LogTail();
  Scrape(port);

  // --log-format json: every line of the SMA's log is one JSON object.
  std::ifstream log(sma_.process.LogPath());
  std::string line;
  int lines = 0;
  while (std::getline(log, line)) {
    if (line.empty()) continue;
    ++lines;
    const auto json = nlohmann::json::parse(line, nullptr, /*allow_exceptions=*/false);
    ASSERT_FALSE(json.is_discarded()) << "not JSON: " << line;
    EXPECT_TRUE(json.contains("level") && json.contains("logger") && json.contains("message")) << line;
  }
  EXPECT_GT(lines, 3);
}

// In-process: the endpoint as a tier's main uses it, before and after the
// tier attaches (a scene loading takes that long; here it is immediate).
TEST(OperatorEndpointTest, NotReadyWhileTheTierLoadsReadyOnceAttachedAndNotAfterDetach) {
  auto endpoint = OperatorEndpoint::Start(HostPort{"127.0.0.1", 0}, "penumbra_test");
  ASSERT_TRUE(endpoint) << endpoint.error().message;
  const uint16_t port = (*endpoint)->Endpoint().port();
  EXPECT_EQ(Status(port, "/healthz"), 200);
  auto loading = HttpGet(port, "/readyz");
  ASSERT_TRUE(loading);
  EXPECT_EQ(loading->status, 503);
  EXPECT_EQ(loading->body, "not ready: loading the scene\n");
  Exposition before = Scrape(port);
  EXPECT_EQ(Value(before, "penumbra_test_ready"), 0.0);
  EXPECT_EQ(before.FindFamily("penumbra_test_widgets"), nullptr);

  std::atomic<bool> ready{false};
  (*endpoint)->Attach({[](metrics::ExpositionWriter& out) {
                         out.Family("penumbra_test_widgets", "gauge", "Widgets");
                         out.Sample("penumbra_test_widgets", 7);
                       },
                       [&ready] { return ready ? std::string() : std::string("warming up"); }});
  auto warming = HttpGet(port, "/readyz");
  ASSERT_TRUE(warming);
  EXPECT_EQ(warming->status, 503);
  EXPECT_EQ(warming->body, "not ready: warming up\n");
  ready = true;
  EXPECT_EQ(Status(port, "/readyz"), 200);
  Exposition attached = Scrape(port);
  EXPECT_EQ(Value(attached, "penumbra_test_ready"), 1.0);
  EXPECT_EQ(Value(attached, "penumbra_test_widgets"), 7.0);

  (*endpoint)->Detach();
  EXPECT_EQ(Status(port, "/readyz"), 503);
  EXPECT_EQ(Scrape(port).FindFamily("penumbra_test_widgets"), nullptr);
  (*endpoint)->Stop();
  EXPECT_FALSE(HttpGet(port, "/healthz", 2s)) << "still serving after Stop()";
}

}  // namespace
}  // namespace penumbra::testing

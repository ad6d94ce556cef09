// Protocol-level tests of penumbra-sma with real penumbra-renderer processes,
// all on free ports, driven by a scripted client whose every delta is checked
// (support/held_mesh.h) and compared with an independent, brute-force
// visibility computation (support/brute_visibility.h).

#include <filesystem>
#include <fstream>
#include <signal.h>

#include <algorithm>
#include <atomic>
#include <cstdio>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <thread>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include "penumbra/common/framing.h"
#include "penumbra/common/messages.h"
#include "penumbra/common/scene.h"
#include "support/brute_visibility.h"
#include "support/service.h"
#include "support/sma_client.h"
#include "support/wire_client.h"

namespace penumbra::testing {
namespace {

using namespace std::chrono_literals;

const std::string kScene = std::string(PENUMBRA_SOURCE_DIR) + "/scenes/cornell-box.json";
constexpr int kWidth = 96;
constexpr int kHeight = 72;

Service MustStart(const std::string& exe, const std::vector<std::string>& args, const std::string& tag) {
  auto s = StartService(exe, args, tag);
  EXPECT_TRUE(s.ok()) << s.error().message;
  return s.ok() ? std::move(*s) : Service{};
}

Service StartRenderer(const std::string& tag, int pathsPerSample = 16, const std::vector<std::string>& extra = {}) {
  std::vector<std::string> args = {"--scene", kScene, "--threads", "1", "--spp", std::to_string(pathsPerSample),
                                   "--max-bounces", "2"};
  args.insert(args.end(), extra.begin(), extra.end());
  return MustStart(PENUMBRA_RENDERER_EXE, args, tag);
}

// `criterion` "none" unless a test is about refinement: the others compare
// held triangles with base-triangle visibility.
Service StartSma(const std::vector<std::string>& renderers, const std::string& tag,
                 const std::vector<std::string>& extra = {}, const std::string& criterion = "none") {
  // The paper's eager removal (the held set is the visible set), unless a
  // test asks for lingering (SmaLingeringTest).
  std::vector<std::string> args = {"--scene", kScene, "--criterion", criterion};
  for (const auto& r : renderers) args.insert(args.end(), {"--renderer", r});
  args.insert(args.end(), extra.begin(), extra.end());
  if (std::find(extra.begin(), extra.end(), "--client-linger-triangles") == extra.end())
    args.insert(args.end(), {"--client-linger-triangles", "0"});
  return MustStart(PENUMBRA_SMA_EXE, args, tag);
}

// The held triangles must be exactly what the brute-force reference sees:
// every clearly visible triangle, and nothing beyond pixel-edge ties.
void ExpectHeldIsVisibleSet(const Scene& scene, const CameraView& view, const HeldMesh& mesh) {
  const BruteVisibility expected = BruteForceVisibleTriangles(scene, view);
  ASSERT_FALSE(expected.certain.empty());
  const std::set<uint64_t> held = mesh.TriangleIds();
  for (uint32_t t : expected.certain) EXPECT_TRUE(held.contains(t)) << "visible triangle " << t << " not held";
  for (uint64_t t : held)
    EXPECT_TRUE(expected.certain.contains(uint32_t(t)) || expected.ties.contains(uint32_t(t)))
        << "triangle " << t << " held but not visible";
}

void ExpectAllShaded(const HeldMesh& mesh) {
  EXPECT_FALSE(mesh.Vertices().empty());
  for (const auto& [id, v] : mesh.Vertices()) {
    for (int c = 0; c < 3; ++c) {
      EXPECT_GE(v.radiance[c], 0.0f) << "vertex " << id;
      EXPECT_GE(v.irradiance[c], 0.0f) << "vertex " << id;
    }
  }
}

CameraView FrontView(const SmaTestClient& c, int width, int height) {
  for (const auto& p : c.Info().cameras())
    if (p.name() == "front") return ViewFromPreset(p, width, height);
  ADD_FAILURE() << "no camera preset front";
  return CameraView{};
}

// Polls the SMA counter `name` until `done(value)`; false after `timeout`.
bool WaitForCounter(SmaTestClient& c, const std::string& name, const std::function<bool(double)>& done,
                    std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < deadline) {
    auto value = c.Counter(name);
    if (!value) return false;
    if (done(*value)) return true;
    std::this_thread::sleep_for(10ms);
  }
  return false;
}

class SmaProtocolTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    auto scene = LoadScene(kScene);
    ASSERT_TRUE(scene.ok()) << scene.error().message;
    scene_ = new Scene(std::move(*scene));
    renderer_ = new Service(StartRenderer("renderer"));
    sma_ = new Service(StartSma({renderer_->Address()}, "sma"));
  }
  static void TearDownTestSuite() {
    delete sma_;
    delete renderer_;
    delete scene_;
  }
  void TearDown() override {
    ASSERT_TRUE(sma_->process.Running()) << sma_->process.LogTail();
    ASSERT_TRUE(renderer_->process.Running()) << renderer_->process.LogTail();
  }

  static SmaTestClient Client(const std::string& name = "test-client") {
    auto c = SmaTestClient::Connect(sma_->port, name);
    EXPECT_TRUE(c.ok()) << c.error().message << "\n" << sma_->process.LogTail();
    return std::move(*c);
  }
  static CameraView Preset(const SmaTestClient& c, const std::string& name) {
    for (const auto& p : c.Info().cameras())
      if (p.name() == name) return ViewFromPreset(p, kWidth, kHeight);
    ADD_FAILURE() << "no camera preset " << name;
    return CameraView{};
  }
  // A view from inside the box toward one corner: sees a few walls only.
  static CameraView CornerView() {
    CameraView v;
    v.pose = CameraPose{Vec3(0.0f, 1.0f, 0.5f), Vec3(-1.0f, 0.3f, -1.0f), Vec3(0, 1, 0)};
    v.fovYDeg = 40.0f;
    v.width = kWidth;
    v.height = kHeight;
    return v;
  }

  static Scene* scene_;
  static Service* renderer_;
  static Service* sma_;
};
Scene* SmaProtocolTest::scene_ = nullptr;
Service* SmaProtocolTest::renderer_ = nullptr;
Service* SmaProtocolTest::sma_ = nullptr;

TEST_F(SmaProtocolTest, HandshakeSendsSceneInfo) {
  SmaTestClient c = Client();
  EXPECT_EQ(c.Welcome().role(), wire::ROLE_SMA);
  EXPECT_EQ(c.Welcome().scene_hash(), scene_->identity);
  EXPECT_EQ(size_t(c.Info().materials_size()), scene_->materials.size());
  EXPECT_GE(c.Info().cameras_size(), 1);
  EXPECT_GT(c.Info().tone_mapping().bias(), 0.0f);
  EXPECT_NEAR(c.Info().bounds_max().y(), scene_->bounds.max.y, 1e-5f);
}

// StatsRequest from any client once returned the renderers' addresses
// ("renderer.127.0.0.1:7100.samples_shaded"). A client sees them by index;
// the addresses are for operators (the log).
TEST_F(SmaProtocolTest, StatsReplyToAClientNamesNoRendererAddress) {
  SmaTestClient c = Client();
  ASSERT_TRUE(WaitForCounter(c, "renderers_connected", [](double n) { return n == 1.0; }, 10s));
  wire::Envelope request;
  request.mutable_stats_request()->set_request_id(77);
  ASSERT_TRUE(c.Wire().Send(request));
  std::optional<wire::StatsReply> reply;
  while (!reply) {
    auto e = c.Wire().Receive(10s);
    ASSERT_TRUE(e.ok()) << e.error().message;
    if (e->has_stats_reply() && e->stats_reply().request_id() == 77) reply = e->stats_reply();
  }
  const std::string port = std::to_string(renderer_->port);
  bool perRenderer = false;
  for (const auto& counter : reply->counters()) {
    EXPECT_EQ(counter.name().find("127.0.0.1"), std::string::npos) << counter.name();
    EXPECT_EQ(counter.name().find(port), std::string::npos) << counter.name();
    perRenderer |= counter.name() == "renderer.1.samples_shaded";
  }
  EXPECT_TRUE(perRenderer) << "the renderer's own counters are still there, by index";
  // The operator's pairing of index and address is in the log.
  auto prefix = RendererCounterPrefix(sma_->process, renderer_->Address());
  ASSERT_TRUE(prefix.ok()) << prefix.error().message;
  EXPECT_EQ(*prefix, "renderer.1");
}

TEST_F(SmaProtocolTest, ViewReceivesExactlyTheVisibleTrianglesAllShaded) {
  SmaTestClient c = Client();
  const CameraView view = Preset(c, "front");
  ASSERT_TRUE(c.SendView(view, 1));
  ASSERT_TRUE(c.WaitConverged(1).ok()) << sma_->process.LogTail();
  ExpectHeldIsVisibleSet(*scene_, view, c.Mesh());
  ExpectAllShaded(c.Mesh());
  EXPECT_EQ(c.Mesh().PendingSamples(), 0u);
  // The first delta answering the view is the cache's (paper's order).
  ASSERT_FALSE(c.Log().empty());
  EXPECT_EQ(c.Log().front().kind, wire::DELTA_KIND_CACHED);
}

TEST_F(SmaProtocolTest, SameViewAgainComesFromTheCacheWithNoRendererRequest) {
  SmaTestClient first = Client("first");
  const CameraView view = Preset(first, "front");
  ASSERT_TRUE(first.SendView(view, 1));
  ASSERT_TRUE(first.WaitConverged(1).ok());
  auto requestedBefore = first.Counter("samples_requested");
  ASSERT_TRUE(requestedBefore.ok()) << requestedBefore.error().message;

  SmaTestClient second = Client("second");
  ASSERT_TRUE(second.SendView(view, 1));
  ASSERT_TRUE(second.WaitConverged(1).ok());
  auto requestedAfter = second.Counter("samples_requested");
  ASSERT_TRUE(requestedAfter.ok());
  EXPECT_EQ(*requestedAfter, *requestedBefore);
  // Everything arrived in the cache delta, nothing had to be rendered.
  EXPECT_EQ(second.Mesh().added[wire::DELTA_KIND_CACHED], second.Mesh().Triangles().size());
  EXPECT_EQ(second.Mesh().added[wire::DELTA_KIND_SHADED], 0u);
  EXPECT_EQ(second.Mesh().TriangleIds(), first.Mesh().TriangleIds());
  auto hitRate = second.Counter("cache_hit_rate");
  ASSERT_TRUE(hitRate.ok());
  EXPECT_GT(*hitRate, 0.0);
}

TEST_F(SmaProtocolTest, MovingTheCameraRemovesAndAddsWhatVisibilityImplies) {
  SmaTestClient c = Client();
  const CameraView a = Preset(c, "front");
  const CameraView b = CornerView();
  ASSERT_TRUE(c.SendView(a, 1));
  ASSERT_TRUE(c.WaitConverged(1).ok());
  const std::set<uint64_t> before = c.Mesh().TriangleIds();
  const size_t logBefore = c.Log().size();
  ASSERT_TRUE(c.SendView(b, 2));
  ASSERT_TRUE(c.WaitConverged(2).ok());
  const std::set<uint64_t> after = c.Mesh().TriangleIds();
  ExpectHeldIsVisibleSet(*scene_, b, c.Mesh());
  size_t added = 0, removed = 0;
  for (size_t i = logBefore; i < c.Log().size(); ++i) {
    added += size_t(c.Log()[i].added);
    removed += size_t(c.Log()[i].removed);
  }
  std::vector<uint64_t> gone, fresh;
  std::set_difference(before.begin(), before.end(), after.begin(), after.end(), std::back_inserter(gone));
  std::set_difference(after.begin(), after.end(), before.begin(), before.end(), std::back_inserter(fresh));
  EXPECT_FALSE(gone.empty());
  EXPECT_EQ(removed, gone.size());
  EXPECT_EQ(added, fresh.size());
}

TEST_F(SmaProtocolTest, TwoClientsAtOnceEachConverge) {
  SmaTestClient a = Client("a");
  SmaTestClient b = Client("b");
  const CameraView va = Preset(a, "front");
  CameraView vb = CornerView();
  vb.pose.target = Vec3(1.0f, 0.4f, -1.0f);  // the other corner
  ASSERT_TRUE(a.SendView(va, 1));
  ASSERT_TRUE(b.SendView(vb, 1));
  ASSERT_TRUE(a.WaitConverged(1).ok());
  ASSERT_TRUE(b.WaitConverged(1).ok());
  ExpectHeldIsVisibleSet(*scene_, va, a.Mesh());
  ExpectHeldIsVisibleSet(*scene_, vb, b.Mesh());
}

TEST_F(SmaProtocolTest, MalformedInputClosesOnlyThatClient) {
  SmaTestClient bystander = Client("bystander");
  auto expectClosedWith = [](WireClient& w, wire::ErrorCode code) {
    bool sawError = false;
    for (int i = 0; i < 20 && !sawError; ++i) {
      auto e = w.Receive(5s);
      if (!e) break;
      sawError = e->has_error() && e->error().code() == code && e->error().fatal();
    }
    EXPECT_TRUE(sawError) << wire::ErrorCode_Name(code);
    EXPECT_TRUE(w.WaitClosed());
  };
  {  // garbage frame
    SmaTestClient c = Client("garbage");
    ASSERT_TRUE(c.Wire().SendRaw(EncodeFrame("\x12\x34 not an envelope \xff\xff")));
    expectClosedWith(c.Wire(), wire::ERROR_CODE_BAD_FRAME);
  }
  {  // NaN camera
    SmaTestClient c = Client("nan");
    CameraView v = Preset(c, "front");
    v.pose.eye.x = std::nanf("");
    ASSERT_TRUE(c.SendView(v, 1));
    expectClosedWith(c.Wire(), wire::ERROR_CODE_INVALID_REQUEST);
  }
  {  // finite, but beyond Embree's range: once an assertion that aborted the SMA
    SmaTestClient c = Client("far");
    CameraView v = Preset(c, "front");
    v.pose.eye = Vec3(1e19f, 0.0f, 0.0f);
    ASSERT_TRUE(c.SendView(v, 1));
    expectClosedWith(c.Wire(), wire::ERROR_CODE_INVALID_REQUEST);
  }
  {  // finite eye and target whose difference overflows to infinity
    SmaTestClient c = Client("overflow");
    CameraView v = Preset(c, "front");
    v.pose.eye = Vec3(3e38f, 0.0f, 0.0f);
    v.pose.target = Vec3(-3e38f, 0.0f, 0.0f);
    ASSERT_TRUE(c.SendView(v, 1));
    expectClosedWith(c.Wire(), wire::ERROR_CODE_INVALID_REQUEST);
  }
  {  // within the camera's limits, beyond what the SMA serves (8192 x 4608 by default)
    SmaTestClient c = Client("large");
    CameraView v = Preset(c, "front");
    v.width = v.height = 16384;
    ASSERT_TRUE(c.SendView(v, 1));
    expectClosedWith(c.Wire(), wire::ERROR_CODE_INVALID_REQUEST);
  }
  {  // absurd viewport
    SmaTestClient c = Client("huge");
    CameraView v = Preset(c, "front");
    v.width = 1 << 20;
    ASSERT_TRUE(c.SendView(v, 1));
    expectClosedWith(c.Wire(), wire::ERROR_CODE_INVALID_REQUEST);
  }
  {  // a message clients do not send
    SmaTestClient c = Client("confused");
    wire::Envelope e;
    e.mutable_shade_request()->set_batch_id(1);
    ASSERT_TRUE(c.Wire().Send(e));
    expectClosedWith(c.Wire(), wire::ERROR_CODE_UNEXPECTED_MESSAGE);
  }
  {  // a 4 kB peer name (it is logged): refused, named by its size only
    auto w = WireClient::Connect("127.0.0.1", sma_->port);
    ASSERT_TRUE(w.ok());
    auto welcome = w->Handshake(wire::ROLE_CLIENT, scene_->identity, 0, std::string(4096, 'x'));
    ASSERT_FALSE(welcome.ok());
    EXPECT_NE(welcome.error().message.find("peer_name"), std::string::npos) << welcome.error().message;
  }
  {  // before its handshake a peer may not declare a large frame (and trickle it)
    auto w = WireClient::Connect("127.0.0.1", sma_->port);
    ASSERT_TRUE(w.ok());
    const uint32_t declared = 16u << 20;
    const std::string header = std::string{char(declared & 0xff), char((declared >> 8) & 0xff),
                                           char((declared >> 16) & 0xff), char((declared >> 24) & 0xff)};
    ASSERT_TRUE(w->SendRaw(header + "partial"));
    expectClosedWith(*w, wire::ERROR_CODE_FRAME_TOO_LARGE);
  }
  {  // a view before the handshake
    auto w = WireClient::Connect("127.0.0.1", sma_->port);
    ASSERT_TRUE(w.ok());
    wire::Envelope e;
    e.mutable_view()->set_view_id(1);
    ASSERT_TRUE(w->Send(e));
    expectClosedWith(*w, wire::ERROR_CODE_HANDSHAKE_REQUIRED);
  }
  // The bystander never noticed.
  const CameraView view = Preset(bystander, "front");
  ASSERT_TRUE(bystander.SendView(view, 1));
  ASSERT_TRUE(bystander.WaitConverged(1).ok());
  ExpectHeldIsVisibleSet(*scene_, view, bystander.Mesh());
}

// A peer that connects and never says Hello (or only heartbeats) is dropped
// after the handshake timeout: idle connections cannot pile up.
TEST(SmaHandshakeTest, APeerWithoutHelloIsDroppedAfterTheHandshakeTimeout) {
  Service renderer = StartRenderer("hs-renderer");
  Service sma = StartSma({renderer.Address()}, "hs-sma", {"--handshake-timeout-ms", "500"});
  auto w = WireClient::Connect("127.0.0.1", sma.port);
  ASSERT_TRUE(w.ok());
  const auto start = std::chrono::steady_clock::now();
  bool timedOut = false;
  for (int i = 0; i < 10 && !timedOut; ++i) {
    wire::Envelope heartbeat;
    heartbeat.mutable_heartbeat();
    (void)w->Send(heartbeat);  // alive, but never a Hello
    auto e = w->Receive(1s);
    timedOut = e.ok() && e->has_error() && e->error().code() == wire::ERROR_CODE_TIMEOUT && e->error().fatal();
  }
  EXPECT_TRUE(timedOut);
  EXPECT_TRUE(w->WaitClosed());
  EXPECT_LT(std::chrono::steady_clock::now() - start, 5s);
  // A well-behaved client is unaffected.
  auto c = SmaTestClient::Connect(sma.port);
  ASSERT_TRUE(c.ok()) << c.error().message;
  ASSERT_TRUE(c->SendView(FrontView(*c, kWidth, kHeight), 1));
  EXPECT_TRUE(c->WaitConverged(1).ok());
}

// --- Connection cap, shutdown, what a client may see (issue 12) -------------------

// Lines of a process's log that contain `text`.
size_t CountLogLines(const ChildProcess& process, const std::string& text) {
  std::ifstream in(process.LogPath());
  size_t count = 0;
  for (std::string line; std::getline(in, line);) count += line.find(text) != std::string::npos;
  return count;
}

// 19,990 idle connections once exhausted the SMA's descriptors. Beyond
// --max-connections a connection gets TOO_MANY_CONNECTIONS and is closed at
// once; the client already connected converges as before, 30 refusals cost
// one log line, and room made by closing lets a new client in.
TEST(SmaLimitsTest, ConnectionsOverTheCapAreRefusedAndTheConnectedClientIsServed) {
  Service renderer = StartRenderer("cap-renderer");
  Service sma = StartSma({renderer.Address()}, "cap-sma", {"--max-connections", "4", "--handshake-timeout-ms", "60000"});
  auto c = SmaTestClient::Connect(sma.port);
  ASSERT_TRUE(c.ok()) << c.error().message;
  std::vector<WireClient> idle;
  for (int i = 0; i < 3; ++i) {
    auto w = WireClient::Connect("127.0.0.1", sma.port);
    ASSERT_TRUE(w.ok());
    idle.push_back(std::move(*w));
  }
  for (int i = 0; i < 30; ++i) {
    auto extra = WireClient::Connect("127.0.0.1", sma.port);
    ASSERT_TRUE(extra.ok());
    if (i % 2 == 0) {  // a client that says Hello at once is refused the same way
      (void)extra->Send(MakeHello(wire::ROLE_CLIENT, "", 0));
    }
    auto e = extra->Receive(5s);
    ASSERT_TRUE(e.ok()) << "connection " << i << ": " << e.error().message;
    ASSERT_TRUE(e->has_error()) << BodyName(*e);
    EXPECT_EQ(e->error().code(), wire::ERROR_CODE_TOO_MANY_CONNECTIONS);
    EXPECT_TRUE(e->error().fatal());
    EXPECT_NE(e->error().message().find("at most 4 connections"), std::string::npos) << e->error().message();
    EXPECT_TRUE(extra->WaitClosed(2s));
  }
  ASSERT_TRUE(c->SendView(FrontView(*c, kWidth, kHeight), 1));
  EXPECT_TRUE(c->WaitConverged(1).ok()) << sma.process.LogTail();
  EXPECT_LE(CountLogLines(sma.process, "refused"), 1u) << sma.process.LogTail();
  idle.clear();
  std::optional<SmaTestClient> late;
  for (int i = 0; i < 50 && !late; ++i) {
    auto attempt = SmaTestClient::Connect(sma.port, "late");
    if (attempt.ok())
      late.emplace(std::move(*attempt));
    else
      std::this_thread::sleep_for(100ms);
  }
  ASSERT_TRUE(late.has_value()) << sma.process.LogTail();
  ASSERT_TRUE(late->SendView(FrontView(*late, kWidth, kHeight), 1));
  EXPECT_TRUE(late->WaitConverged(1).ok());
}

// Receives until the fatal SHUTTING_DOWN error (deltas and the rest
// skipped); false if the connection ends or stays silent first.
bool ReceivesShuttingDown(WireClient& w, std::string* why) {
  while (true) {
    auto e = w.Receive(5s);
    if (!e) {
      *why = e.error().message;
      return false;
    }
    if (e->has_error() && e->error().code() == wire::ERROR_CODE_SHUTTING_DOWN) return e->error().fatal();
  }
}

// SIGTERM while big views were traced and clients flooded refinement took
// 6.9-7.4 s, and closed the clients without a word. The work is abandoned
// now; every client hears SHUTTING_DOWN and the SMA is gone within 2 s.
TEST(SmaShutdownTest, SigtermMidTraceAndUnderARefinementFloodStopsWithinTwoSecondsAndTellsEveryClient) {
  // A real scene when ../shared is there (the figures above are Sponza's);
  // the Cornell box otherwise, with the largest views the SMA takes.
  const std::filesystem::path sponzaMesh =
      std::filesystem::path(PENUMBRA_SOURCE_DIR).parent_path() / "shared/scenes/sponza-dabrovic/sponza.obj";
  const bool sponza = std::filesystem::exists(sponzaMesh);
  const std::string scene = sponza ? std::string(PENUMBRA_SOURCE_DIR) + "/scenes/sponza.json" : kScene;
  const int bigWidth = sponza ? 4096 : 8192, bigHeight = sponza ? 2304 : 4608;
  Service renderer = MustStart(PENUMBRA_RENDERER_EXE, {"--scene", scene, "--threads", "1", "--spp", "64"}, "stop-renderer");
  Service sma = MustStart(PENUMBRA_SMA_EXE,
                          {"--scene", scene, "--renderer", renderer.Address(), "--criterion", "nld_os", "--noise-z", "0",
                           "--view-threads", "2"},
                          "stop-sma");
  ASSERT_FALSE(HasFailure());
  std::vector<SmaTestClient> clients;
  for (int i = 0; i < 4; ++i) {
    auto c = SmaTestClient::Connect(sma.port, "flood-" + std::to_string(i));
    ASSERT_TRUE(c.ok()) << c.error().message;
    clients.push_back(std::move(*c));
  }
  const auto viewOf = [](const SmaTestClient& c, int width, int height) {
    return ViewFromPreset(c.Info().cameras(0), width, height);
  };
  // Refinement asking for everything: no threshold, no pixel floor, huge steps.
  for (auto& c : clients) {
    wire::Envelope options;
    auto* o = options.mutable_session_options();
    o->set_s_req(0.0f);
    o->set_min_pixels(0);
    o->set_batch(100000);
    o->set_max_depth(20);
    ASSERT_TRUE(c.Wire().Send(options));
  }
  // Two clients refine 640x480 views; two ask for big ones, twice, so that
  // traces are running when the signal comes.
  for (int i = 0; i < 4; ++i) {
    const bool big = i >= 2;
    ASSERT_TRUE(clients[size_t(i)].SendView(viewOf(clients[size_t(i)], big ? bigWidth : 640, big ? bigHeight : 480), 1));
  }
  std::this_thread::sleep_for(4s);
  for (int i = 2; i < 4; ++i) {
    CameraView moved = viewOf(clients[size_t(i)], bigWidth, bigHeight);
    moved.pose.eye.y += 0.05f * float(i);
    ASSERT_TRUE(clients[size_t(i)].SendView(moved, 2));
  }
  std::this_thread::sleep_for(100ms);
  ASSERT_TRUE(sma.process.Running()) << sma.process.LogTail();

  const auto start = std::chrono::steady_clock::now();
  sma.process.Signal(SIGTERM);
  for (auto& c : clients) {
    std::string why;
    EXPECT_TRUE(ReceivesShuttingDown(c.Wire(), &why)) << why << "\n" << sma.process.LogTail();
  }
  auto code = sma.process.WaitExit(30s);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  ASSERT_TRUE(code.has_value()) << sma.process.LogTail();
  EXPECT_EQ(*code, 0) << sma.process.LogTail();
  std::printf("SMA (%s): SIGTERM to exit mid-trace under a refinement flood: %.2f s\n", sponza ? "sponza" : "cornell box",
              seconds);
  // 2 s is the goal; the margin is for a loaded test machine.
  EXPECT_LT(seconds, 3.0) << sma.process.LogTail();
}

// A client that falls behind is sent nothing until its queue drains, then
// the difference that built up, in one delta. With a one-byte soft limit
// nearly every delta goes that way: the clients must still end up holding
// exactly what they should, through deltas that obey every rule.
// Every criterion: the catch-up path also re-maps the view, alongside the
// refreshes that refinement waits for.
class SmaSlowClientTest : public ::testing::TestWithParam<const char*> {};

TEST_P(SmaSlowClientTest, CoalescedDeltasKeepEveryClientExact) {
  auto scene = LoadScene(kScene);
  ASSERT_TRUE(scene.ok());
  Service renderer = StartRenderer("slow-renderer");
  Service sma = StartSma({renderer.Address()}, "slow-sma", {"--client-queue-bytes", "1"}, GetParam());
  auto a = SmaTestClient::Connect(sma.port, "a");
  auto b = SmaTestClient::Connect(sma.port, "b");
  ASSERT_TRUE(a.ok() && b.ok());
  const CameraView front = FrontView(*a, 160, 120);
  CameraView corner = front;
  corner.pose.eye.x += 0.5f;
  corner.pose.target.x -= 0.3f;
  ASSERT_TRUE(a->SendView(front, 1));
  ASSERT_TRUE(b->SendView(corner, 1));
  ASSERT_TRUE(b->WaitConverged(1, 180s).ok()) << sma.process.LogTail();
  ASSERT_TRUE(a->WaitConverged(1, 180s).ok()) << sma.process.LogTail();
  for (SmaTestClient* c : {&*a, &*b}) {
    EXPECT_EQ(c->Mesh().CountTVertices(), 0u);
    ExpectAllShaded(c->Mesh());
    auto held = c->Counter("client_triangles_held");
    ASSERT_TRUE(held.ok());
    EXPECT_EQ(size_t(*held), c->Mesh().Triangles().size());  // the SMA's model is the client's
  }
}

INSTANTIATE_TEST_SUITE_P(Criteria, SmaSlowClientTest, ::testing::Values("nld_os", "nld_is", "rnd"),
                         [](const ::testing::TestParamInfo<const char*>& criterion) {
                           return std::string(criterion.param);
                         });

// Lingering (sma/README.md): triangles that leave a client's view stay
// with it, within a budget, so turning back to a view it saw needs nothing
// sent -- the picture is there in the first frame -- while everything the
// view sees is held, as ever.
TEST(SmaLingeringTest, TurningBackToAViewSendsNoTriangle) {
  auto scene = LoadScene(kScene);
  ASSERT_TRUE(scene.ok());
  Service renderer = StartRenderer("linger-r");
  Service sma = StartSma({renderer.Address()}, "linger-sma", {"--client-linger-triangles", "100000"});
  auto c = SmaTestClient::Connect(sma.port);
  ASSERT_TRUE(c.ok()) << c.error().message;
  const CameraView front = FrontView(*c, kWidth, kHeight);
  CameraView corner;  // from inside the box toward one corner: a few walls only
  corner.pose = CameraPose{Vec3(0.0f, 1.0f, 0.5f), Vec3(-1.0f, 0.3f, -1.0f), Vec3(0, 1, 0)};
  corner.fovYDeg = 40.0f;
  corner.width = kWidth;
  corner.height = kHeight;

  ASSERT_TRUE(c->SendView(front, 1));
  ASSERT_TRUE(c->WaitConverged(1).ok()) << sma.process.LogTail();
  const std::set<uint64_t> seenFromFront = c->Mesh().TriangleIds();
  ASSERT_TRUE(c->SendView(corner, 2));
  ASSERT_TRUE(c->WaitConverged(2).ok()) << sma.process.LogTail();
  const std::set<uint64_t> heldInTheCorner = c->Mesh().TriangleIds();
  EXPECT_TRUE(std::includes(heldInTheCorner.begin(), heldInTheCorner.end(), seenFromFront.begin(), seenFromFront.end()))
      << "what the front view showed left the client";
  const BruteVisibility inTheCorner = BruteForceVisibleTriangles(*scene, corner);
  for (uint32_t t : inTheCorner.certain)
    EXPECT_TRUE(heldInTheCorner.contains(t)) << "visible triangle " << t << " not held";
  size_t lingering = 0;  // held, not seen from the corner: without lingering, removed and sent again
  for (uint64_t t : seenFromFront)
    lingering += !inTheCorner.certain.contains(uint32_t(t)) && !inTheCorner.ties.contains(uint32_t(t));
  EXPECT_GT(lingering, 0u);

  const size_t logBefore = c->Log().size();
  ASSERT_TRUE(c->SendView(front, 3));
  ASSERT_TRUE(c->WaitConverged(3).ok()) << sma.process.LogTail();
  size_t added = 0;
  for (size_t i = logBefore; i < c->Log().size(); ++i) added += size_t(c->Log()[i].added);
  EXPECT_EQ(added, 0u) << "turning back had to send triangles";
  for (uint32_t t : BruteForceVisibleTriangles(*scene, front).certain)
    EXPECT_TRUE(c->Mesh().TriangleIds().contains(t)) << "visible triangle " << t << " not held";
  ASSERT_TRUE(sma.process.Running()) << sma.process.LogTail();
}

TEST(SmaRendererFailureTest, KillingOneOfTwoRenderersLosesNoSample) {
  auto scene = LoadScene(kScene);
  ASSERT_TRUE(scene.ok());
  // Slow samples (many paths) in small batches, so both renderers are busy
  // when one dies.
  Service r1 = StartRenderer("r1", 3000);
  Service r2 = StartRenderer("r2", 3000);
  Service sma = StartSma({r1.Address(), r2.Address()}, "sma2", {"--max-batch", "2", "--credits", "2"});
  auto c = SmaTestClient::Connect(sma.port);
  ASSERT_TRUE(c.ok()) << c.error().message;
  // Both renderers connected before the view, so both get work.
  ASSERT_TRUE(WaitForCounter(*c, "renderers_connected", [](double n) { return n == 2.0; }, 10s));
  const CameraView view = FrontView(*c, kWidth, kHeight);
  ASSERT_TRUE(c->SendView(view, 1));
  // Wait until r2 has samples in flight, then kill it.
  auto r2Counters = RendererCounterPrefix(sma.process, r2.Address());
  ASSERT_TRUE(r2Counters.ok()) << r2Counters.error().message;
  ASSERT_TRUE(WaitForCounter(*c, *r2Counters + ".samples_in_flight", [](double n) { return n > 0.0; }, 10s))
      << "renderer 2 never got work";
  r2.process.Signal(SIGKILL);
  ASSERT_TRUE(c->WaitConverged(1, 180s).ok()) << sma.process.LogTail();
  ExpectHeldIsVisibleSet(*scene, view, c->Mesh());
  ExpectAllShaded(c->Mesh());
  auto requeued = c->Counter("samples_requeued");
  ASSERT_TRUE(requeued.ok());
  EXPECT_GT(*requeued, 0.0);
  auto requested = c->Counter("samples_requested");
  auto shaded = c->Counter("cache_shaded");
  ASSERT_TRUE(requested.ok() && shaded.ok());
  EXPECT_EQ(*requested, *shaded);  // every sample asked for is in the cache, none twice
}

TEST(SmaRendererFailureTest, ARendererThatStopsAnsweringIsDroppedAndItsWorkMoved) {
  auto scene = LoadScene(kScene);
  ASSERT_TRUE(scene.ok());
  // Heartbeats well inside the SMA's renderer timeout, so only the frozen one is dropped.
  Service r1 = StartRenderer("stall-r1", 3000, {"--heartbeat-ms", "200"});
  Service r2 = StartRenderer("stall-r2", 3000, {"--heartbeat-ms", "200"});
  // A short read timeout: a silent renderer is noticed within a second.
  Service sma = StartSma({r1.Address(), r2.Address()}, "stall-sma",
                         {"--max-batch", "2", "--credits", "2", "--renderer-read-timeout-ms", "1000", "--heartbeat-ms", "200"});
  auto c = SmaTestClient::Connect(sma.port);
  ASSERT_TRUE(c.ok()) << c.error().message;
  ASSERT_TRUE(WaitForCounter(*c, "renderers_connected", [](double n) { return n == 2.0; }, 10s));
  const CameraView view = FrontView(*c, kWidth, kHeight);
  ASSERT_TRUE(c->SendView(view, 1));
  auto r2Counters = RendererCounterPrefix(sma.process, r2.Address());
  ASSERT_TRUE(r2Counters.ok()) << r2Counters.error().message;
  ASSERT_TRUE(WaitForCounter(*c, *r2Counters + ".samples_in_flight", [](double n) { return n > 0.0; }, 10s))
      << "renderer 2 never got work";
  // Frozen, not dead: its socket stays open but nothing comes out of it.
  r2.process.Signal(SIGSTOP);
  ASSERT_TRUE(c->WaitConverged(1, 180s).ok()) << sma.process.LogTail();
  r2.process.Signal(SIGCONT);
  ExpectHeldIsVisibleSet(*scene, view, c->Mesh());
  auto requeued = c->Counter("samples_requeued");
  ASSERT_TRUE(requeued.ok());
  EXPECT_GT(*requeued, 0.0);
  auto failures = c->Counter(*r2Counters + ".failures");
  ASSERT_TRUE(failures.ok());
  EXPECT_GE(*failures, 1.0);
}

// A hostile renderer, played by the test: it handshakes, takes the first
// ShadeRequest and answers it with `answer(request)`, then keeps the
// connection open and answers nothing more.
class FakeRenderer {
 public:
  using Answer = std::function<wire::ShadeReply(const wire::ShadeRequest&)>;
  FakeRenderer(uint64_t sceneHash, Answer answer) {
    auto listener = WireListener::Listen();
    EXPECT_TRUE(listener.ok());
    listener_ = std::make_unique<WireListener>(std::move(*listener));
    thread_ = std::thread([this, sceneHash, answer = std::move(answer)] {
      auto sma = listener_->Accept(20s);
      if (!sma) return;
      auto hello = sma->Receive();
      if (!hello || !hello->has_hello()) return;
      wire::Envelope welcome;
      auto* w = welcome.mutable_welcome();
      w->set_protocol_version(kProtocolVersion);
      w->set_role(wire::ROLE_RENDERER);
      w->set_server_name("hostile-renderer");
      w->set_scene_hash(sceneHash);
      w->set_max_frame_bytes(16u << 20);
      w->set_max_batch_samples(64);
      w->set_worker_threads(1);
      w->set_max_batches_in_flight(1);
      if (!sma->Send(welcome)) return;
      while (!stop_) {
        auto e = sma->Receive(200ms);
        if (!e) {
          if (e.error().message == "timeout") continue;
          return;
        }
        if (!e->has_shade_request() || answered_) continue;
        wire::Envelope reply;
        *reply.mutable_shade_reply() = answer(e->shade_request());
        answered_ = sma->Send(reply);
      }
    });
  }
  ~FakeRenderer() {
    stop_ = true;
    thread_.join();
  }
  std::string Address() const { return "127.0.0.1:" + std::to_string(listener_->Port()); }
  bool Answered() const { return answered_; }

 private:
  std::unique_ptr<WireListener> listener_;
  std::atomic<bool> stop_{false};
  std::atomic<bool> answered_{false};
  std::thread thread_;
};

// A reply part with one sample per id of the request, all with `radiance`.
wire::ShadeReply ReplyWith(const wire::ShadeRequest& request, int count, float radiance) {
  wire::ShadeReply reply;
  reply.set_batch_id(request.batch_id());
  for (int i = 0; i < count && i < request.sample_ids_size(); ++i) {
    reply.add_sample_ids(request.sample_ids(i));
    for (int c = 0; c < 3; ++c) {
      reply.add_radiance(radiance);
      reply.add_irradiance(radiance);
    }
    reply.add_irradiance_stderr(0.0f);
  }
  reply.set_remaining(uint32_t(request.sample_ids_size() - reply.sample_ids_size()));
  return reply;
}

// An SMA served by `hostile` and an honest renderer, and a client whose
// front view converges through them once both are connected.
struct BesideAHostileRenderer {
  explicit BesideAHostileRenderer(const FakeRenderer& hostile)
      : hostile(hostile),
        honest(StartRenderer("honest")),
        sma(StartSma({hostile.Address(), honest.Address()}, "hostile-sma")) {}

  void ConvergeTheFrontView() {
    auto connected = SmaTestClient::Connect(sma.port);
    ASSERT_TRUE(connected.ok()) << connected.error().message;
    client.emplace(std::move(*connected));
    ASSERT_TRUE(WaitForCounter(*client, "renderers_connected", [](double n) { return n == 2.0; }, 10s));
    view = FrontView(*client, kWidth, kHeight);
    ASSERT_TRUE(client->SendView(view, 1));
    ASSERT_TRUE(client->WaitConverged(1, 120s).ok()) << sma.process.LogTail();
    EXPECT_TRUE(hostile.Answered());
  }

  const FakeRenderer& hostile;
  Service honest;
  Service sma;
  std::optional<SmaTestClient> client;
  CameraView view;
};

// Ends with every sample the SMA asked for stored once, nothing in flight.
void ExpectNothingLost(SmaTestClient& c) {
  auto requested = c.Counter("samples_requested");
  auto shaded = c.Counter("cache_shaded");
  auto inFlight = c.Counter("samples_in_flight");
  ASSERT_TRUE(requested.ok() && shaded.ok() && inFlight.ok());
  EXPECT_EQ(*requested, *shaded);
  EXPECT_EQ(*inFlight, 0.0);
}

// A reply part whose first sample is good and second is not once lost the
// first for ever: it was marked answered before the link was dropped, so it
// was neither stored nor requeued, and the view never converged.
TEST(SmaHostileRendererTest, AGoodSampleBeforeABadOneInOneReplyIsNotLost) {
  auto scene = LoadScene(kScene);
  ASSERT_TRUE(scene.ok());
  FakeRenderer hostile(scene->identity, [](const wire::ShadeRequest& request) {
    wire::ShadeReply reply = ReplyWith(request, 2, 0.1f);
    reply.set_sample_ids(1, uint64_t(1) << 40);  // a sample it was not asked for
    return reply;
  });
  BesideAHostileRenderer run(hostile);
  ASSERT_NO_FATAL_FAILURE(run.ConvergeTheFrontView());
  auto& c = run.client;
  ExpectHeldIsVisibleSet(*scene, run.view, c->Mesh());
  ExpectNothingLost(*c);
  auto hostileCounters = RendererCounterPrefix(run.sma.process, hostile.Address());
  ASSERT_TRUE(hostileCounters.ok()) << hostileCounters.error().message;
  auto bad = c->Counter(*hostileCounters + ".bad_replies");
  ASSERT_TRUE(bad.ok());
  EXPECT_EQ(*bad, 1.0);
}

// Finite but impossible radiance (3e38, -1e30) was stored and served to every
// client: one bad renderer of two turned the image black. It is refused,
// counted, and its renderer quarantined; the honest one shades the view.
TEST(SmaHostileRendererTest, ImpossibleRadianceIsRejectedAndItsRendererQuarantined) {
  auto scene = LoadScene(kScene);
  ASSERT_TRUE(scene.ok());
  const float brightest = scene->MaxEmittedRadiance();
  for (float poison : {3e38f, -1e30f, 1e6f * brightest}) {
    SCOPED_TRACE(poison);
    FakeRenderer hostile(scene->identity,
                         [poison](const wire::ShadeRequest& request) { return ReplyWith(request, 64, poison); });
    BesideAHostileRenderer run(hostile);
    ASSERT_NO_FATAL_FAILURE(run.ConvergeTheFrontView());
    auto& c = run.client;
    for (const auto& [id, v] : c->Mesh().Vertices())
      for (int ch = 0; ch < 3; ++ch) {
        ASSERT_GE(v.radiance[ch], 0.0f) << "vertex " << id;
        ASSERT_LE(v.radiance[ch], 100.0f * brightest) << "vertex " << id;
      }
    ExpectNothingLost(*c);
    auto rejected = c->Counter("samples_rejected");
    auto hostileCounters = RendererCounterPrefix(run.sma.process, hostile.Address());
    ASSERT_TRUE(hostileCounters.ok()) << hostileCounters.error().message;
    auto connected = c->Counter(*hostileCounters + ".connected");
    ASSERT_TRUE(rejected.ok() && connected.ok());
    EXPECT_GE(*rejected, 1.0);
    EXPECT_EQ(*connected, 0.0) << "quarantined, not reconnected at once";
  }
}

// --- Improvement in place -----------------------------------------------------------

// A view is first shaded with few paths (a first image soon); then its noisy
// samples get further rounds, averaged in, and clients receive the better
// estimates (IMPROVED deltas) for the vertices they hold. Measured against
// 4096-path samples of the same vertices, the improved image is much closer
// than the first one.
TEST(SmaImprovementTest, NoisySamplesAreImprovedInPlaceAndResent) {
  auto scene = LoadScene(kScene);
  ASSERT_TRUE(scene.ok());
  Service renderer = StartRenderer("improve-r", 16);
  const auto heldRadiance = [&](const std::vector<std::string>& flags, std::map<uint64_t, Rgb>* out,
                                uint64_t* updates) {
    std::vector<std::string> args = {"--first-paths"};
    args.insert(args.end(), flags.begin(), flags.end());
    Service sma = StartSma({renderer.Address()}, "improve-sma", args);
    auto c = SmaTestClient::Connect(sma.port);
    ASSERT_TRUE(c.ok()) << c.error().message;
    const CameraView view = FrontView(*c, kWidth, kHeight);
    ASSERT_TRUE(c->SendView(view, 1));
    ASSERT_TRUE(c->WaitConverged(1, 120s).ok()) << sma.process.LogTail();
    ExpectHeldIsVisibleSet(*scene, view, c->Mesh());
    auto pending = c->Counter("client_improvements_pending");
    ASSERT_TRUE(pending.ok());
    EXPECT_EQ(*pending, 0.0) << "converged with improvements outstanding";
    for (const auto& [id, v] : c->Mesh().Vertices()) (*out)[id] = v.radiance;
    *updates = c->Mesh().updates;
  };
  std::map<uint64_t, Rgb> first, improved, reference;
  uint64_t firstUpdates = 0, improvedUpdates = 0, referenceUpdates = 0;
  heldRadiance({"16", "--improve-paths", "0"}, &first, &firstUpdates);
  heldRadiance({"16", "--improve-paths", "64", "--improve-target-error", "0.01", "--improve-max-paths", "1024"},
               &improved, &improvedUpdates);
  heldRadiance({"4096", "--improve-paths", "0"}, &reference, &referenceUpdates);
  EXPECT_EQ(firstUpdates, 0u);
  EXPECT_GT(improvedUpdates, 0u);
  ASSERT_EQ(first.size(), reference.size());
  ASSERT_EQ(improved.size(), reference.size());
  double firstError = 0.0, improvedError = 0.0, total = 0.0;
  for (const auto& [id, r] : reference) {
    total += Luminance(r);
    firstError += std::abs(Luminance(first.at(id)) - Luminance(r));
    improvedError += std::abs(Luminance(improved.at(id)) - Luminance(r));
  }
  ASSERT_GT(total, 0.0);
  // 16 paths against up to 1024: the noise falls several times over.
  EXPECT_LT(improvedError, 0.5 * firstError) << "relative error: first " << firstError / total << ", improved "
                                             << improvedError / total;
}

// --- Real models' geometry ------------------------------------------------------

// tests/data/inverted_room.obj (make_inverted_room.py): a room mirror-
// symmetric about x = 0 whose right wall is wound facing out of it, and
// stair risers whose corner vertices are buried in the tread slabs. Shaded
// one-sided, the right wall read black; shaded where they lie, the risers'
// corners read black and no criterion split the risers. With both sides
// shaded on their own and buried samples shaded where their surface emerges,
// the right wall reads like its mirror image and no riser vertex is dark.
TEST(SmaRealGeometryTest, OutwardWoundWallsAndBuriedRisersAreLit) {
  const std::string sceneFile = std::string(PENUMBRA_SOURCE_DIR) + "/tests/data/inverted_room.json";
  auto scene = LoadScene(sceneFile);
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  ASSERT_TRUE(scene->twoSided);
  auto renderer = StartService(PENUMBRA_RENDERER_EXE, {"--scene", sceneFile, "--threads", "2", "--spp", "64"}, "room-r");
  ASSERT_TRUE(renderer.ok()) << renderer.error().message;
  auto sma = StartService(PENUMBRA_SMA_EXE, {"--scene", sceneFile, "--renderer", renderer->Address(), "--criterion",
                                             "nld_os"},
                          "room-sma");
  ASSERT_TRUE(sma.ok()) << sma.error().message;
  auto c = SmaTestClient::Connect(sma->port);
  ASSERT_TRUE(c.ok()) << c.error().message;
  CameraView view;
  for (const auto& p : c->Info().cameras())
    if (p.name() == "walls") view = ViewFromPreset(p, 160, 120);
  ASSERT_TRUE(c->SendView(view, 1));
  ASSERT_TRUE(c->WaitConverged(1, 180s).ok()) << sma->process.LogTail();

  // Mean luminance of the held vertices of triangles lying wholly on a plane.
  const auto meanOn = [&](auto onPlane) {
    double sum = 0.0;
    std::set<uint64_t> counted;
    for (const auto& [id, corners] : c->Mesh().Triangles()) {
      bool all = true;
      for (uint64_t v : corners) all = all && onPlane(c->Mesh().Vertices().at(v).position);
      if (!all) continue;
      for (uint64_t v : corners)
        if (counted.insert(v).second) sum += Luminance(c->Mesh().Vertices().at(v).radiance);
    }
    return std::make_pair(counted.empty() ? 0.0 : sum / double(counted.size()), counted.size());
  };
  const auto near = [](float a, float b) { return std::abs(a - b) < 1e-4f; };
  const auto [left, leftCount] = meanOn([&](const Vec3& p) { return near(p.x, -1.0f); });
  const auto [right, rightCount] = meanOn([&](const Vec3& p) { return near(p.x, 1.0f); });
  const auto [back, backCount] = meanOn([&](const Vec3& p) { return near(p.z, -1.0f); });
  ASSERT_GT(leftCount, 0u);
  ASSERT_GT(rightCount, 0u);
  ASSERT_GT(backCount, 0u);
  EXPECT_GT(left, 0.0);
  // Mirror images, each vertex a Monte Carlo estimate of 64 paths.
  EXPECT_NEAR(right / left, 1.0, 0.15) << "left " << left << ", right (wound outward) " << right;

  // Every vertex of a riser (z = -0.6 or -0.8, facing the room) is lit.
  size_t riserVertices = 0;
  for (const auto& [id, v] : c->Mesh().Vertices()) {
    if (!near(v.position.z, -0.6f) && !near(v.position.z, -0.8f)) continue;
    if (std::abs(v.position.x) > 0.5f + 1e-4f) continue;
    ++riserVertices;
    EXPECT_GT(Luminance(v.radiance), 0.2 * back) << "riser vertex " << id << " at (" << v.position.x << ", "
                                                 << v.position.y << ", " << v.position.z << ")";
  }
  EXPECT_GE(riserVertices, 8u);
}

// --- Refinement (founding paper §4) -------------------------------------------

// Everything the client holds once a refined view converges: a conforming
// mesh, refined below the base triangles, every vertex shaded.
void ExpectRefinedAndConforming(SmaTestClient& c, size_t baseTriangles) {
  size_t children = 0;
  for (uint64_t id : c.Mesh().TriangleIds()) children += id >= baseTriangles;
  EXPECT_GT(children, 0u) << "no refined triangle held";
  EXPECT_EQ(c.Mesh().CountTVertices(), 0u);
  ExpectAllShaded(c.Mesh());
  size_t refinedDeltas = 0;
  for (const auto& d : c.Log()) refinedDeltas += d.kind == wire::DELTA_KIND_REFINED;
  EXPECT_GT(refinedDeltas, 0u);
  auto splits = c.Counter("client_refinement_splits");
  ASSERT_TRUE(splits.ok()) << splits.error().message;
  EXPECT_GT(*splits, 0.0);
}

TEST(SmaRefinementTest, NldOsRefinesTheViewAndConverges) {
  auto scene = LoadScene(kScene);
  ASSERT_TRUE(scene.ok());
  Service renderer = StartRenderer("refine-renderer");
  Service sma = StartSma({renderer.Address()}, "refine-sma", {"--noise-z", "0"}, "nld_os");
  auto c = SmaTestClient::Connect(sma.port);
  ASSERT_TRUE(c.ok()) << c.error().message;
  ASSERT_TRUE(c->SendView(FrontView(*c, 320, 240), 1));
  ASSERT_TRUE(c->WaitConverged(1, 180s).ok()) << sma.process.LogTail();
  ExpectRefinedAndConforming(*c, scene->triangles.size());
  auto stage1 = c->Counter("client_stage1_ms");
  auto stage2 = c->Counter("client_stage2_ms");
  ASSERT_TRUE(stage1.ok() && stage2.ok());
  EXPECT_GT(*stage1, 0.0);
  EXPECT_GE(*stage2, *stage1);
}

// NLD_IS on a real scene, whose first view sends megabytes (so the client's
// queue backs up and the catch-up path re-maps the view while refresh timers
// wait). It once waited forever here, in the experiment, for a refresh that
// had already run; that race depends on timing this test does not control,
// so it guards the path rather than reproducing it every time.
TEST(SmaRefinementTest, NldIsConvergesOnTheBreakfastRoom) {
  const std::string scene = std::string(PENUMBRA_SOURCE_DIR) + "/scenes/breakfast-room.json";
  const std::filesystem::path mesh =
      std::filesystem::path(PENUMBRA_SOURCE_DIR).parent_path() / "shared/scenes/breakfast-room";
  if (!std::filesystem::exists(mesh)) GTEST_SKIP() << mesh << " is absent (clone ../shared beside the repository)";
  Service renderer = MustStart(PENUMBRA_RENDERER_EXE,
                               {"--scene", scene, "--threads", "2", "--spp", "16", "--max-bounces", "2"}, "br-renderer");
  Service sma = MustStart(PENUMBRA_SMA_EXE,
                          {"--scene", scene, "--renderer", renderer.Address(), "--criterion", "nld_is", "--noise-z",
                           "0", "--pixel-fraction", "0.25", "--paths", "16", "--improve-paths", "0"},
                          "br-sma");
  auto c = SmaTestClient::Connect(sma.port);
  ASSERT_TRUE(c.ok()) << c.error().message;
  CameraView view{};
  for (const auto& p : c->Info().cameras())
    if (p.name() == "table") view = ViewFromPreset(p, 480, 270);
  ASSERT_EQ(view.width, 480) << "no camera preset table";
  ASSERT_TRUE(c->SendView(view, 1));
  ASSERT_TRUE(c->WaitConverged(1, 120s).ok()) << sma.process.LogTail();
  // (Conformity on the real scenes is SceneConformityTest's: this mesh's
  // own T-junctions would count here.)
  auto splits = c->Counter("client_refinement_splits");
  ASSERT_TRUE(splits.ok());
  EXPECT_GT(*splits, 0.0) << "NLD_IS refined nothing";
}

TEST(SmaRefinementTest, ClientChoosesItsCriterionAndANewViewSupersedesRefinement) {
  auto scene = LoadScene(kScene);
  ASSERT_TRUE(scene.ok());
  Service renderer = StartRenderer("options-renderer");
  Service sma = StartSma({renderer.Address()}, "options-sma");  // refinement off by default here
  auto c = SmaTestClient::Connect(sma.port);
  ASSERT_TRUE(c.ok()) << c.error().message;
  // Out of range: refused, nothing else happens.
  wire::Envelope bad;
  bad.mutable_session_options()->set_s_req(7.0f);
  ASSERT_TRUE(c->Wire().Send(bad));
  auto error = c->Wire().Receive(5s);
  ASSERT_TRUE(error.ok() && error->has_error());
  EXPECT_EQ(error->error().code(), wire::ERROR_CODE_INVALID_REQUEST);
  EXPECT_FALSE(error->error().fatal());

  wire::Envelope options;
  options.mutable_session_options()->set_criterion("rnd");
  options.mutable_session_options()->set_pixel_fraction(0.02f);
  ASSERT_TRUE(c->Wire().Send(options));
  // A first view, superseded at once by a second: only the second converges.
  CameraView first = FrontView(*c, 160, 120);
  first.pose.eye.x += 0.3f;
  ASSERT_TRUE(c->SendView(first, 1));
  ASSERT_TRUE(c->SendView(FrontView(*c, 160, 120), 2));
  ASSERT_TRUE(c->WaitConverged(2, 180s).ok()) << sma.process.LogTail();
  ExpectRefinedAndConforming(*c, scene->triangles.size());
}

}  // namespace
}  // namespace penumbra::testing
namespace penumbra::testing {
namespace {

// Receives deltas (applied to the client's mesh) until one satisfies `wanted`.
Expected<wire::Delta> WaitForDelta(SmaTestClient& c, const std::function<bool(const wire::Delta&)>& wanted,
                                   std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < deadline) {
    auto envelope = c.Wire().Receive(500ms);
    if (!envelope) continue;  // nothing yet
    if (auto ok = c.Apply(*envelope); !ok) return ok.error();
    if (envelope->has_delta() && wanted(envelope->delta())) return envelope->delta();
  }
  return Fail("no such delta in time");
}

// Issue 16: the client is told how many renderers the SMA has (a view with
// none waits forever, and the HUD says so) and how far stage 1 has come.
// Issue 16: an unresolvable --listen host is reported before the scene loads
// (which takes minutes for a big scene), by the SMA and the renderer alike.
TEST(ListenAddressTest, AnUnresolvableHostIsReportedBeforeTheSceneLoads) {
  const std::string dir = MakeTempDir("penumbra-listen-test");
  const std::vector<std::pair<std::string, std::vector<std::string>>> runs = {
      {PENUMBRA_SMA_EXE, {"--scene", kScene, "--renderer", "127.0.0.1:1", "--listen", "nosuchhost.invalid:7200"}},
      {PENUMBRA_RENDERER_EXE, {"--scene", kScene, "--listen", "nosuchhost.invalid:0"}}};
  for (size_t i = 0; i < runs.size(); ++i) {
    const auto& [exe, args] = runs[i];
    auto process = ChildProcess::Spawn(exe, args, fmt::format("{}/run-{}.log", dir, i));
    ASSERT_TRUE(process.ok()) << process.error().message;
    const auto exit = process->WaitExit(30s);
    ASSERT_TRUE(exit.has_value()) << exe;
    EXPECT_EQ(*exit, 2) << process->LogTail();
    const std::string log = process->LogTail();
    EXPECT_NE(log.find("cannot resolve listen address nosuchhost.invalid"), std::string::npos) << log;
    EXPECT_EQ(log.find("[scene]"), std::string::npos) << "the scene was loaded first:\n" << log;
  }
}

TEST(SmaProgressTest, DeltasSayHowManyRenderersAreConnectedAndHowFarStage1Is) {
  uint16_t port = 0;
  {
    auto probe = WireListener::Listen();
    ASSERT_TRUE(probe.ok());
    port = probe->Port();
  }
  const std::string rendererAddress = fmt::format("127.0.0.1:{}", port);
  Service sma = StartSma({rendererAddress}, "progress-sma");
  auto c = SmaTestClient::Connect(sma.port);
  ASSERT_TRUE(c.ok()) << c.error().message;

  // No renderer: the view's samples wait, and the delta says why.
  ASSERT_TRUE(c->SendView(FrontView(*c, kWidth, kHeight), 1));
  auto waiting = WaitForDelta(*c, [](const wire::Delta& d) { return d.view_id() == 1; }, 15s);
  ASSERT_TRUE(waiting.ok()) << waiting.error().message << "\n" << sma.process.LogTail();
  ASSERT_TRUE(waiting->has_renderers_connected());
  EXPECT_EQ(waiting->renderers_connected(), 0u);
  EXPECT_GT(waiting->pending_samples(), 0u);
  EXPECT_EQ(waiting->stage1_samples_total(), waiting->pending_samples()) << "a fresh cache has nothing";
  EXPECT_EQ(waiting->stage1_samples_done(), 0u);
  EXPECT_FALSE(waiting->converged());

  // A renderer appears where the SMA looks: it connects, and stage 1 completes.
  const std::string dir = MakeTempDir("penumbra-progress-renderer");
  auto renderer = ChildProcess::Spawn(PENUMBRA_RENDERER_EXE,
                                      {"--scene", kScene, "--threads", "1", "--spp", "16", "--max-bounces", "2",
                                       "--listen", rendererAddress},
                                      dir + "/renderer.log");
  ASSERT_TRUE(renderer.ok()) << renderer.error().message;
  auto done = WaitForDelta(*c, [](const wire::Delta& d) { return d.view_id() == 1 && d.converged(); }, 60s);
  ASSERT_TRUE(done.ok()) << done.error().message << "\n" << sma.process.LogTail() << "\n" << renderer->LogTail();
  ASSERT_TRUE(done->has_renderers_connected());
  EXPECT_EQ(done->renderers_connected(), 1u);
  EXPECT_EQ(done->stage1_samples_total(), waiting->stage1_samples_total());
  EXPECT_EQ(done->stage1_samples_done(), done->stage1_samples_total());
  EXPECT_EQ(done->pending_samples(), 0u);

  // The renderer goes away: the client hears of it without moving.
  renderer->Signal(SIGKILL);
  auto lost = WaitForDelta(
      *c, [](const wire::Delta& d) { return d.has_renderers_connected() && d.renderers_connected() == 0; }, 15s);
  ASSERT_TRUE(lost.ok()) << lost.error().message << "\n" << sma.process.LogTail();
  EXPECT_EQ(lost->kind(), wire::DELTA_KIND_STATUS);
}

}  // namespace
}  // namespace penumbra::testing

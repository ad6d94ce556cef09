// Resource limits per client (issue 12), on real penumbra-sma and
// penumbra-renderer processes: each limit answers its offender with a clear
// ErrorReply (or simply costs it nothing), and a normal client beside it
// still converges. Figures (RSS, CPU, latency) are printed for the record;
// the thresholds are generous, since the machine may be loaded.

#include <netinet/in.h>
#include <netinet/tcp.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <sstream>
#include <thread>

#include <gtest/gtest.h>

#include "penumbra/common/framing.h"
#include "penumbra/common/image_io.h"
#include "penumbra/common/messages.h"
#include "penumbra/common/scene.h"
#include "support/sanitizer_time.h"
#include "support/service.h"
#include "support/sma_client.h"
#include "support/wire_client.h"

namespace penumbra::testing {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;

const std::string kCornell = std::string(PENUMBRA_SOURCE_DIR) + "/scenes/cornell-box.json";

Service MustStart(const std::string& exe, const std::vector<std::string>& args, const std::string& tag) {
  auto s = StartService(exe, args, tag);
  EXPECT_TRUE(s.ok()) << s.error().message;
  return s.ok() ? std::move(*s) : Service{};
}

Service StartRenderer(const std::string& scene, const std::string& tag) {
  return MustStart(PENUMBRA_RENDERER_EXE,
                   {"--scene", scene, "--threads", "1", "--spp", "16", "--max-bounces", "2"}, tag);
}

Service StartSma(const std::string& scene, const Service& renderer, const std::string& tag,
                 const std::vector<std::string>& extra) {
  std::vector<std::string> args = {"--scene", scene, "--renderer", renderer.Address()};
  args.insert(args.end(), extra.begin(), extra.end());
  return MustStart(PENUMBRA_SMA_EXE, args, tag);
}

CameraView Preset(const SmaTestClient& c, const std::string& name, int width, int height) {
  for (const auto& p : c.Info().cameras())
    if (p.name() == name) return ViewFromPreset(p, width, height);
  ADD_FAILURE() << "no camera preset " << name;
  return CameraView{};
}

// A field of /proc/<pid>/status in MiB ("VmHWM", "VmRSS"), -1 if unreadable.
double StatusMegabytes(pid_t pid, const std::string& field) {
  std::ifstream status("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(status, line))
    if (line.rfind(field + ":", 0) == 0) return std::stod(line.substr(field.size() + 1)) / 1024.0;
  return -1.0;
}

// CPU seconds (user + system) the process has used so far.
double CpuSeconds(pid_t pid) {
  std::ifstream stat("/proc/" + std::to_string(pid) + "/stat");
  std::string text((std::istreambuf_iterator<char>(stat)), std::istreambuf_iterator<char>());
  // Fields after the command name (which may hold spaces) start after ')'.
  std::istringstream rest(text.substr(text.rfind(')') + 2));
  std::string field;
  unsigned long long utime = 0, stime = 0;
  for (int i = 3; rest >> field; ++i) {
    if (i == 14) utime = std::stoull(field);
    if (i == 15) {
      stime = std::stoull(field);
      break;
    }
  }
  return double(utime + stime) / double(::sysconf(_SC_CLK_TCK));
}

// The next ErrorReply on `w` within `timeout` (other frames are skipped).
std::optional<wire::ErrorReply> NextError(WireClient& w, std::chrono::milliseconds timeout) {
  const auto deadline = Clock::now() + timeout;
  while (Clock::now() < deadline) {
    auto e = w.Receive(std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now()));
    if (!e) return std::nullopt;
    if (e->has_error()) return e->error();
  }
  return std::nullopt;
}

wire::Envelope ViewEnvelope(const CameraView& view, uint64_t id) {
  wire::Envelope e;
  auto* v = e.mutable_view();
  v->set_view_id(id);
  auto set = [](wire::Vec3* out, const Vec3& in) {
    out->set_x(in.x);
    out->set_y(in.y);
    out->set_z(in.z);
  };
  set(v->mutable_eye(), view.pose.eye);
  set(v->mutable_target(), view.pose.target);
  set(v->mutable_up(), view.pose.up);
  v->set_fov_y_deg(view.fovYDeg);
  v->set_width(uint32_t(view.width));
  v->set_height(uint32_t(view.height));
  return e;
}

// --- 1. Visibility memory ----------------------------------------------------

// Two clients ask for the largest view the SMA serves; together they would
// exceed the visibility budget, so the second is refused (LIMIT_EXCEEDED,
// not fatal) while a small view beside them converges at once. When the
// first leaves, the second's retry is served.
TEST(SmaVisibilityBudgetTest, AViewOverTheBudgetIsRefusedAndASmallViewIsNotHeldUp) {
  Service renderer = StartRenderer(kCornell, "budget-renderer");
  Service sma = StartSma(kCornell, renderer, "budget-sma",
                         {"--criterion", "none", "--max-view-pixels", std::to_string(2048 * 2048),
                          "--visibility-budget-pixels", std::to_string(6 << 20), "--large-view-pixels",
                          std::to_string(1 << 20)});
  auto big1 = SmaTestClient::Connect(sma.port, "big1");
  auto big2 = SmaTestClient::Connect(sma.port, "big2");
  auto small = SmaTestClient::Connect(sma.port, "small");
  ASSERT_TRUE(big1.ok() && big2.ok() && small.ok());
  const CameraView bigView = Preset(*big1, "front", 2048, 2048);
  ASSERT_TRUE(big1->SendView(bigView, 1));
  ASSERT_TRUE(big1->WaitConverged(1, 120s).ok()) << sma.process.LogTail();
  auto reserved = big1->Counter("visibility_pixels_reserved");
  ASSERT_TRUE(reserved.ok());
  EXPECT_EQ(*reserved, 2048.0 * 2048.0);

  ASSERT_TRUE(big2->SendView(bigView, 1));
  auto refused = NextError(big2->Wire(), 10s);
  ASSERT_TRUE(refused.has_value());
  EXPECT_EQ(refused->code(), wire::ERROR_CODE_LIMIT_EXCEEDED);
  EXPECT_FALSE(refused->fatal());
  EXPECT_EQ(refused->request_id(), 1u);
  EXPECT_NE(refused->message().find("visibility budget"), std::string::npos) << refused->message();
  std::printf("refusal: %s\n", refused->message().c_str());
  EXPECT_TRUE(big2->Counter("clients").ok());  // still connected

  // big1 moves (a new large trace, on the background thread) while the small
  // client's view is answered beside it.
  CameraView moved = bigView;
  moved.pose.eye.x += 0.3f;
  ASSERT_TRUE(big1->SendView(moved, 2));
  const auto smallStart = Clock::now();
  ASSERT_TRUE(small->SendView(Preset(*small, "front", 160, 120), 1));
  ASSERT_TRUE(small->WaitConverged(1, 60s).ok()) << sma.process.LogTail();
  const double smallSeconds = std::chrono::duration<double>(Clock::now() - smallStart).count();
  auto firstDelta = small->Counter("client_last_view_to_first_delta_ms");
  ASSERT_TRUE(firstDelta.ok());
  std::printf("small view beside a %dx%d trace: first delta %.1f ms, converged in %.2f s; SMA peak RSS %.0f MiB\n",
              2048, 2048, *firstDelta, smallSeconds, StatusMegabytes(sma.process.Pid(), "VmHWM"));
  EXPECT_LT(*firstDelta, 5000.0);
  ASSERT_TRUE(big1->WaitConverged(2, 120s).ok()) << sma.process.LogTail();

  // The first client leaves: its pixels are free, and the second's retry fits.
  big1 = Fail("closed");
  // Its close and big2's retry arrive on different connections, which two
  // I/O threads handle in either order: retry once the SMA has let the
  // pixels go (the retry raced the close and was refused in one CI run).
  const auto releasedBy = Clock::now() + ScaledTimeout(10s);
  while (true) {
    auto held = small->Counter("visibility_pixels_reserved");
    ASSERT_TRUE(held.ok());
    if (*held < 2048.0 * 2048.0) break;
    ASSERT_LT(Clock::now(), releasedBy) << "the closed client's pixels were never released";
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  ASSERT_TRUE(big2->SendView(bigView, 2));
  ASSERT_TRUE(big2->WaitConverged(2, 120s).ok()) << sma.process.LogTail();
  EXPECT_TRUE(sma.process.Running());
}

// Not a test: the measurement behind the visibility budget's defaults, run
// by hand (--gtest_also_run_disabled_tests) against any penumbra-sma. Three
// clients ask for the largest default view (8192 x 4608) and a fourth for a
// small one; prints the small view's latency and the SMA's peak RSS.
TEST(SmaVisibilityBudgetTest, DISABLED_MeasureThreeLargestViewsBesideASmallOne) {
  Service renderer = StartRenderer(kCornell, "measure-renderer");
  // PENUMBRA_MEASURE_SMA: another penumbra-sma to measure (e.g. a build before the budget).
  const char* exe = std::getenv("PENUMBRA_MEASURE_SMA");
  Service sma = MustStart(exe != nullptr ? exe : PENUMBRA_SMA_EXE,
                          {"--scene", kCornell, "--renderer", renderer.Address(), "--criterion", "none"}, "measure-sma");
  std::vector<SmaTestClient> big;
  for (int i = 0; i < 3; ++i) {
    auto c = SmaTestClient::Connect(sma.port, "big");
    ASSERT_TRUE(c.ok());
    big.push_back(std::move(*c));
  }
  auto small = SmaTestClient::Connect(sma.port, "small");
  ASSERT_TRUE(small.ok());
  for (auto& c : big) ASSERT_TRUE(c.SendView(Preset(c, "front", 8192, 4608), 1));
  std::this_thread::sleep_for(100ms);
  const auto start = Clock::now();
  ASSERT_TRUE(small->SendView(Preset(*small, "front", 160, 120), 1));
  double firstDelta = -1.0;
  while (firstDelta < 0.0) {
    auto e = small->Wire().Receive(300s);
    ASSERT_TRUE(e.ok());
    ASSERT_TRUE(small->Apply(*e).ok());
    if (e->has_delta()) firstDelta = std::chrono::duration<double>(Clock::now() - start).count();
  }
  ASSERT_TRUE(small->WaitConverged(1, 300s).ok());
  const double converged = std::chrono::duration<double>(Clock::now() - start).count();
  int served = 0, refused = 0;
  for (auto& c : big) {
    auto e = c.Wire().Receive(300s);
    ASSERT_TRUE(e.ok());
    served += e->has_delta();
    refused += e->has_error();
  }
  std::printf("3 views of 8192x4608 (%d served, %d refused) beside a 160x120 view: its first delta after %.2f s, "
              "converged after %.2f s; SMA peak RSS %.0f MiB\n",
              served, refused, firstDelta, converged, StatusMegabytes(sma.process.Pid(), "VmHWM"));
}

// --- 2. Refinement a client may ask for --------------------------------------

// The fuzzed options of issue 12 (s_req 0, min_pixels 0, max_depth 20,
// R 1e6) are refused, each by name; options at the limits are taken, and
// the refinement they drive is capped per view. Memory stays bounded while
// the client keeps moving for ~20 s.
TEST(SmaRefinementLimitsTest, FuzzedSessionOptionsAreRefusedAndRefinementIsCapped) {
  constexpr int kCap = 2000;
  Service renderer = StartRenderer(kCornell, "refine-renderer");
  Service sma = StartSma(kCornell, renderer, "refine-sma",
                         {"--criterion", "nld_os", "--client-max-refinement-samples", std::to_string(kCap)});
  auto c = SmaTestClient::Connect(sma.port, "fuzzer");
  ASSERT_TRUE(c.ok());
  auto expectRefused = [&](const wire::SessionOptions& o, const std::string& field) {
    wire::Envelope e;
    *e.mutable_session_options() = o;
    ASSERT_TRUE(c->Wire().Send(e));
    auto error = NextError(c->Wire(), 5s);
    ASSERT_TRUE(error.has_value()) << field;
    EXPECT_EQ(error->code(), wire::ERROR_CODE_INVALID_REQUEST);
    EXPECT_FALSE(error->fatal());
    EXPECT_NE(error->message().find(field), std::string::npos) << error->message();
    std::printf("%s: %s\n", field.c_str(), error->message().c_str());
  };
  wire::SessionOptions fuzzed;
  fuzzed.set_s_req(0.0f);
  fuzzed.set_min_pixels(0.0f);
  fuzzed.set_max_depth(20);
  fuzzed.set_batch(1000000);
  expectRefused(fuzzed, "s_req");
  wire::SessionOptions one;
  one.set_min_pixels(0.0f);
  expectRefused(one, "min_pixels");
  one = {};
  one.set_max_depth(20);
  expectRefused(one, "max_depth");
  one = {};
  one.set_batch(1000000);
  expectRefused(one, "batch");

  // The most a client may ask for: taken (no error), and bounded.
  wire::SessionOptions most;
  most.set_s_req(0.01f);
  most.set_min_pixels(1.0f);
  most.set_max_depth(16);
  most.set_batch(1024);
  {
    wire::Envelope e;
    *e.mutable_session_options() = most;
    ASSERT_TRUE(c->Wire().Send(e));
  }
  const CameraView front = Preset(*c, "front", 640, 480);
  // One view: its refinement stops at the cap (plus at most one step: R
  // leaves, a few new vertices each) and the view converges.
  ASSERT_TRUE(c->SendView(front, 1));
  ASSERT_TRUE(c->WaitConverged(1, 180s).ok()) << sma.process.LogTail();
  auto firstView = c->Counter("client_refinement_samples");
  ASSERT_TRUE(firstView.ok());
  std::printf("one view at the client limits: %.0f refinement samples (cap %d)\n", *firstView, kCap);
  EXPECT_GE(*firstView, double(kCap));
  EXPECT_LE(*firstView, double(kCap + 6 * 1024));
  EXPECT_NE(sma.process.LogTail(100000).find("refinement stopped at"), std::string::npos);

  // ~20 s of moving about at the limits: memory stays bounded.
  const double rssStart = ResidentMegabytes(sma.process.Pid());
  uint64_t views = 1;
  const auto start = Clock::now();
  double rssMax = rssStart;
  while (Clock::now() - start < 20s) {
    CameraView v = front;
    v.pose.eye.x += 0.05f * float(views % 7);
    v.pose.eye.y += 0.04f * float(views % 5);
    ASSERT_TRUE(c->SendView(v, ++views));
    const auto until = Clock::now() + 2s;
    while (Clock::now() < until) {
      auto e = c->Wire().Receive(200ms);
      if (e.ok()) {
        ASSERT_TRUE(c->Apply(*e).ok()) << "an error for options at the limits";
      }
    }
    rssMax = std::max(rssMax, ResidentMegabytes(sma.process.Pid()));
  }
  auto samples = c->Counter("client_refinement_samples");
  ASSERT_TRUE(samples.ok()) << samples.error().message;
  std::printf("20 s of refinement at the client limits over %llu views: %.0f samples created, SMA RSS %.0f -> "
              "%.0f MiB (peak %.0f MiB, +%.0f MiB)\n",
              (unsigned long long)views, *samples, rssStart, ResidentMegabytes(sma.process.Pid()), rssMax,
              rssMax - rssStart);
  // At most the cap per view, plus one step's overshoot (R leaves, each
  // with its propagation).
  EXPECT_LE(*samples, double(views) * double(kCap + 6 * 1024));
  EXPECT_LT(rssMax - rssStart, 400.0);  // the issue: +1.6 GiB in 80 s
  EXPECT_TRUE(sma.process.Running());
}

// Not a test: the fuzzed options of issue 12 sent as they are, and the SMA's
// RSS over ~20 s of views, printed; run by hand against any penumbra-sma
// (PENUMBRA_MEASURE_SMA, e.g. a build from before the limits).
TEST(SmaRefinementLimitsTest, DISABLED_MeasureFuzzedOptions) {
  Service renderer = StartRenderer(kCornell, "fuzzed-renderer");
  const char* exe = std::getenv("PENUMBRA_MEASURE_SMA");
  Service sma = MustStart(exe != nullptr ? exe : PENUMBRA_SMA_EXE,
                          {"--scene", kCornell, "--renderer", renderer.Address(), "--criterion", "nld_os"},
                          "fuzzed-sma");
  auto c = SmaTestClient::Connect(sma.port, "fuzzer");
  ASSERT_TRUE(c.ok());
  wire::Envelope e;
  e.mutable_session_options()->set_s_req(0.0f);
  e.mutable_session_options()->set_min_pixels(0.0f);
  e.mutable_session_options()->set_max_depth(20);
  e.mutable_session_options()->set_batch(1000000);
  ASSERT_TRUE(c->Wire().Send(e));
  const CameraView front = Preset(*c, "front", 640, 480);
  const double rssStart = ResidentMegabytes(sma.process.Pid());
  const auto start = Clock::now();
  uint64_t views = 0;
  while (Clock::now() - start < 20s) {
    CameraView v = front;
    v.pose.eye.x += 0.05f * float(views % 7);
    ASSERT_TRUE(c->SendView(v, ++views));
    const auto until = Clock::now() + 2s;
    while (Clock::now() < until) (void)c->Wire().Receive(200ms);
  }
  std::printf("fuzzed options, 20 s over %llu views: SMA RSS %.0f -> %.0f MiB\n", (unsigned long long)views, rssStart,
              ResidentMegabytes(sma.process.Pid()));
}

// --- 3. Texture request flood --------------------------------------------------

// A scene of three quads, each with its own 2048^2 texture, and a lamp.
std::string WriteTexturedScene(const std::string& dir) {
  for (int t = 0; t < 3; ++t) {
    const int side = 2048;
    std::vector<float> rgb(size_t(side) * side * 3);
    for (int y = 0; y < side; ++y)
      for (int x = 0; x < side; ++x)
        for (int c = 0; c < 3; ++c)
          rgb[(size_t(y) * side + size_t(x)) * 3 + size_t(c)] = float((x * (t + 1) + y * (c + 1)) % 256) / 255.0f;
    EXPECT_TRUE(WriteImage(dir + "/tex" + std::to_string(t) + ".png", side, side, rgb).ok());
  }
  std::ofstream mtl(dir + "/flood.mtl");
  for (int t = 0; t < 3; ++t) mtl << "newmtl m" << t << "\nKd 1 1 1\nmap_Kd tex" << t << ".png\n\n";
  mtl << "newmtl lamp\nKd 0.5 0.5 0.5\nKe 4 4 4\n";
  std::ofstream obj(dir + "/flood.obj");
  obj << "mtllib flood.mtl\n";
  for (int q = 0; q < 4; ++q) {
    const float x = float(q) * 1.1f;
    obj << "v " << x << " 0 0\nv " << x + 1 << " 0 0\nv " << x + 1 << " 1 0\nv " << x << " 1 0\n";
  }
  obj << "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n";
  for (int q = 0; q < 4; ++q) {
    const int b = q * 4;
    obj << "usemtl " << (q < 3 ? "m" + std::to_string(q) : std::string("lamp")) << "\n";
    obj << "f " << b + 1 << "/1 " << b + 2 << "/2 " << b + 3 << "/3 " << b + 4 << "/4\n";
  }
  return dir + "/flood.obj";
}

TEST(SmaTextureFloodTest, ABurstOfTextureRequestsDoesNotHoldUpAnotherClient) {
  const std::string scene = WriteTexturedScene(MakeTempDir("penumbra-flood-scene"));
  Service renderer = StartRenderer(scene, "flood-renderer");
  Service sma = StartSma(scene, renderer, "flood-sma", {"--criterion", "none", "--max-texture-requests", "2"});
  auto flooder = SmaTestClient::Connect(sma.port, "flooder");
  ASSERT_TRUE(flooder.ok());
  ASSERT_EQ(flooder->Info().texture_count(), 3u);
  // 300 requests in one burst, textures 0, 1, 2, 0, 1, 2, ...
  std::string burst;
  for (int i = 0; i < 300; ++i) {
    wire::Envelope e;
    e.mutable_texture_request()->set_texture(uint32_t(i % 3));
    burst += EncodeEnvelopeFrame(e);
  }
  ASSERT_TRUE(flooder->Wire().SendRaw(burst));
  const auto start = Clock::now();

  // Another client handshakes and converges meanwhile, promptly.
  auto other = SmaTestClient::Connect(sma.port, "other");
  ASSERT_TRUE(other.ok()) << other.error().message;
  const double handshakeSeconds = std::chrono::duration<double>(Clock::now() - start).count();
  CameraView view;
  view.pose = CameraPose{Vec3(2.15f, 0.5f, 3.0f), Vec3(2.15f, 0.5f, 0.0f), Vec3(0, 1, 0)};
  view.fovYDeg = 60.0f;
  view.width = 160;
  view.height = 120;
  ASSERT_TRUE(other->SendView(view, 1));
  ASSERT_TRUE(other->WaitConverged(1, 60s).ok()) << sma.process.LogTail();
  const double convergedSeconds = std::chrono::duration<double>(Clock::now() - start).count();
  std::printf("beside a burst of 300 texture requests: handshake after %.3f s, converged after %.3f s\n",
              handshakeSeconds, convergedSeconds);
  EXPECT_LT(handshakeSeconds, 2.0);
  EXPECT_LT(convergedSeconds, 20.0);

  // The flooder: each of the two textures it may have outstanding exactly
  // once, and a clear refusal for the third.
  std::map<uint32_t, int> received;
  int refusals = 0;
  std::string refusal;
  const auto deadline = Clock::now() + 20s;
  while (Clock::now() < deadline) {
    auto e = flooder->Wire().Receive(received.size() >= 2 ? 2s : 20s);
    if (!e) break;
    if (e->has_texture_data()) {
      const auto& d = e->texture_data();
      EXPECT_EQ(d.rgb8().size(), size_t(d.width()) * d.height() * 3);
      ++received[d.texture()];
    }
    if (e->has_error()) {
      EXPECT_EQ(e->error().code(), wire::ERROR_CODE_LIMIT_EXCEEDED) << e->error().message();
      EXPECT_FALSE(e->error().fatal());
      refusal = e->error().message();
      ++refusals;
    }
  }
  std::printf("flooder: %zu textures received, %d requests refused (%s)\n", received.size(), refusals,
              refusal.c_str());
  EXPECT_EQ(received, (std::map<uint32_t, int>{{0, 1}, {1, 1}}));
  EXPECT_GT(refusals, 0);
  EXPECT_NE(refusal.find("--max-texture-requests"), std::string::npos) << refusal;
  // Now that nothing is outstanding, the third is served.
  wire::Envelope again;
  again.mutable_texture_request()->set_texture(2);
  ASSERT_TRUE(flooder->Wire().Send(again));
  bool got = false;
  for (int i = 0; i < 20 && !got; ++i) {
    auto e = flooder->Wire().Receive(10s);
    if (!e) break;
    got = e->has_texture_data() && e->texture_data().texture() == 2;
  }
  EXPECT_TRUE(got);
  auto encoded = flooder->Counter("textures_encoded");
  ASSERT_TRUE(encoded.ok());
  EXPECT_EQ(*encoded, 3.0);
  EXPECT_TRUE(sma.process.Running());
}

// --- 4. No work for clients that cannot take it ---------------------------------

// A client that sends views as fast as it can and never reads, with a small
// receive buffer so that its SMA's queue backs up soon.
class NonReadingClient {
 public:
  NonReadingClient(uint16_t port, std::vector<CameraView> views) : views_(std::move(views)) {
    fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
    int small = 4096;
    ::setsockopt(fd_, SOL_SOCKET, SO_RCVBUF, &small, sizeof small);
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_port = htons(port);
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    connected_ = ::connect(fd_, reinterpret_cast<sockaddr*>(&address), sizeof address) == 0;
    connected_ = connected_ && Write(EncodeEnvelopeFrame(MakeHello(wire::ROLE_CLIENT, "never-reads", 0)));
    thread_ = std::thread([this] {
      for (uint64_t id = 1; !stop_ && connected_; ++id) {
        if (!Write(EncodeEnvelopeFrame(ViewEnvelope(views_[id % views_.size()], id)))) break;
        ++sent_;
        std::this_thread::sleep_for(10ms);
      }
    });
  }
  ~NonReadingClient() {
    stop_ = true;
    thread_.join();
    ::close(fd_);
  }
  bool Connected() const { return connected_; }
  uint64_t Sent() const { return sent_; }

 private:
  bool Write(const std::string& bytes) {
    size_t done = 0;
    while (done < bytes.size()) {
      const ssize_t n = ::send(fd_, bytes.data() + done, bytes.size() - done, MSG_NOSIGNAL);
      if (n <= 0) return false;
      done += size_t(n);
    }
    return true;
  }

  int fd_ = -1;
  bool connected_ = false;
  std::vector<CameraView> views_;
  std::atomic<bool> stop_{false};
  std::atomic<uint64_t> sent_{0};
  std::thread thread_;
};

TEST(SmaNonReadingClientTest, ClientsThatNeverReadCostTheSmaLittle) {
  Service renderer = StartRenderer(kCornell, "noread-renderer");
  // Fine refinement and no improvement: a large mesh, soon in the cache.
  // No lingering: each turn must be a large delta (below), not a view the
  // client still holds.
  Service sma = StartSma(kCornell, renderer, "noread-sma",
                         {"--criterion", "nld_os", "--min-pixels", "1", "--s-req", "0.01", "--improve-paths", "0",
                          "--client-queue-bytes", "65536", "--client-linger-triangles", "0"});
  auto normal = SmaTestClient::Connect(sma.port, "normal");
  ASSERT_TRUE(normal.ok());
  // A refined view of the box, in the cache before the clients that never
  // read arrive; they alternate between it and looking away from the box, so
  // that each of their views is a large delta (everything added, or
  // everything removed).
  const CameraView front = Preset(*normal, "front", 960, 720);
  CameraView away = front;
  away.pose.target = front.pose.eye + (front.pose.eye - front.pose.target);
  // Their views are full-HD, so that tracing them costs what it would --
  // except under ThreadSanitizer, whose SMA traces on one TBB thread
  // (fork_join_annotation.h) about 10x slower: there a quarter of that, or
  // their queues take minutes to back up.
  const int muteWidth = ThreadSanitizerBuild() ? 960 : 1920, muteHeight = ThreadSanitizerBuild() ? 540 : 1080;
  CameraView muteFront = Preset(*normal, "front", muteWidth, muteHeight), muteAway = away;
  muteAway.width = muteWidth;
  muteAway.height = muteHeight;
  ASSERT_TRUE(normal->SendView(front, 1));
  ASSERT_TRUE(normal->WaitConverged(1, 120s).ok()) << sma.process.LogTail();

  std::vector<std::unique_ptr<NonReadingClient>> mute;
  for (int i = 0; i < 4; ++i) {
    mute.push_back(std::make_unique<NonReadingClient>(sma.port, std::vector<CameraView>{muteFront, muteAway}));
    ASSERT_TRUE(mute.back()->Connected());
  }
  // The normal client stays in touch meanwhile (the SMA drops a silent peer).
  auto idle = [&](std::chrono::seconds duration) {
    const auto until = Clock::now() + duration;
    while (Clock::now() < until) {
      wire::Envelope heartbeat;
      heartbeat.mutable_heartbeat();
      ASSERT_TRUE(normal->Wire().Send(heartbeat));
      auto e = normal->Wire().Receive(1s);
      if (e.ok()) {
        ASSERT_TRUE(normal->Apply(*e).ok());
      }
    }
  };
  // Their queues back up once the kernel's socket buffers (~4 MB each on
  // loopback) are full; from then on they should cost next to nothing.
  const auto start = Clock::now();
  double backedUp = 0.0;
  while (backedUp < 4.0 && Clock::now() - start < ScaledTimeout(120s)) {
    idle(1s);
    auto n = normal->Counter("clients_backed_up");
    ASSERT_TRUE(n.ok());
    backedUp = *n;
  }
  ASSERT_EQ(backedUp, 4.0) << "the clients that never read never backed up\n" << sma.process.LogTail(3000);
  std::printf("their queues backed up after %.1f s\n", std::chrono::duration<double>(Clock::now() - start).count());
  auto traces0 = normal->Counter("visibility_traces");
  ASSERT_TRUE(traces0.ok());
  const double cpu0 = CpuSeconds(sma.process.Pid());
  const auto t0 = Clock::now();
  idle(5s);
  const double cores = (CpuSeconds(sma.process.Pid()) - cpu0) / std::chrono::duration<double>(Clock::now() - t0).count();
  auto traces1 = normal->Counter("visibility_traces");
  ASSERT_TRUE(traces1.ok());
  uint64_t views = 0;
  for (const auto& m : mute) views += m->Sent();
  std::printf("4 clients that never read (%llu views sent): over 5 s, %.0f traces, SMA CPU %.2f cores\n",
              (unsigned long long)views, *traces1 - *traces0, cores);
  // A trace now and then: a backed-up queue may drain a little as the kernel
  // grows a socket's buffer.
  EXPECT_LE(*traces1 - *traces0, 20.0);
  EXPECT_LT(cores, 0.3) << sma.process.LogTail(3000);  // the issue: 1.8 cores
  // A normal client beside them converges on a new view.
  CameraView moved = front;
  moved.pose.eye.x += 0.5f;
  ASSERT_TRUE(normal->SendView(moved, 2));
  ASSERT_TRUE(normal->WaitConverged(2, 120s).ok()) << sma.process.LogTail();
  EXPECT_TRUE(sma.process.Running());
}

}  // namespace
}  // namespace penumbra::testing

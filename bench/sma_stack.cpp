#include "sma_stack.h"

#include <algorithm>
#include <fstream>
#include <sstream>
#include <thread>

#include <fmt/format.h>

namespace penumbra::bench {

using namespace penumbra::testing;

namespace {

constexpr std::chrono::seconds kHeartbeatInterval{5};  // docs/protocol.md, connection life cycle

bool SendHeartbeat(SmaTestClient& client) {
  wire::Envelope heartbeat;
  heartbeat.mutable_heartbeat()->set_sent_unix_ms(uint64_t(
      std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::system_clock::now().time_since_epoch())
          .count()));
  return client.Wire().Send(heartbeat);
}

}  // namespace

Expected<SmaStack> StartSmaStack(const SmaStackOptions& o) {
  auto renderer = StartService(o.rendererExe,
                               {"--scene", o.scene.string(), "--threads", std::to_string(o.rendererThreads), "--spp",
                                std::to_string(o.spp), "--max-bounces", std::to_string(o.maxBounces), "--log-level",
                                "warn"},
                               "bench-renderer", std::chrono::seconds(120));
  if (!renderer) return Fail("renderer: " + renderer.error().message);
  std::vector<std::string> smaArgs = {"--scene", o.scene.string(), "--renderer", renderer->Address()};
  // Quiet unless the caller asks for a level (its log is bench-sma.log in the SMA's temporary folder).
  if (std::find(o.smaArgs.begin(), o.smaArgs.end(), "--log-level") == o.smaArgs.end())
    smaArgs.insert(smaArgs.end(), {"--log-level", "warn"});
  smaArgs.insert(smaArgs.end(), o.smaArgs.begin(), o.smaArgs.end());
  auto sma = StartService(o.smaExe, smaArgs, "bench-sma", std::chrono::seconds(120));
  if (!sma) return Fail("SMA: " + sma.error().message);
  auto client = SmaTestClient::Connect(sma->port, "bench-link-wait");
  if (!client) return client.error();
  for (int i = 0;; ++i) {
    auto n = client->Counter("renderers_connected");
    if (!n) return n.error();
    if (*n >= 1.0) break;
    if (i == 1200) return Fail("the SMA did not connect to its renderer within a minute");
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  return SmaStack{std::move(*renderer), std::move(*sma)};
}

Expected<ViewTiming> TimeView(SmaTestClient& client, const CameraView& view, uint64_t viewId,
                              std::chrono::milliseconds timeout, bool untilStage1) {
  ViewTiming t;
  const uint64_t bytesBefore = client.Wire().BytesReceived();
  const auto start = Clock::now();
  const auto deadline = start + timeout;
  if (!client.SendView(view, viewId)) return Fail("send failed");
  auto lastSent = start;
  while (true) {
    const auto now = Clock::now();
    if (now >= deadline) return Fail(fmt::format("view {} not converged in {} ms", viewId, timeout.count()));
    if (now - lastSent >= kHeartbeatInterval) {
      if (!SendHeartbeat(client)) return Fail("send failed");
      lastSent = now;
    }
    const auto wait = std::chrono::duration_cast<std::chrono::milliseconds>(
        std::min(lastSent + kHeartbeatInterval, deadline) - now);
    auto e = client.Wire().Receive(std::max(wait, std::chrono::milliseconds(1)));
    if (!e && e.error().message == "timeout") continue;
    if (!e) return e.error();
    if (auto ok = client.Apply(*e); !ok) return ok.error();
    if (!e->has_delta() || e->delta().view_id() != viewId) continue;
    if (t.firstDeltaMs < 0) t.firstDeltaMs = Ms(Clock::now() - start);
    if (t.stage1Ms < 0 && (e->delta().refining() || e->delta().converged())) t.stage1Ms = Ms(Clock::now() - start);
    if (e->delta().converged() || (untilStage1 && t.stage1Ms >= 0)) break;
  }
  t.completeMs = Ms(Clock::now() - start);
  t.bytes = client.Wire().BytesReceived() - bytesBefore;
  return t;
}

Status IdleUntil(SmaTestClient& client, const std::function<bool()>& done) {
  auto lastSent = Clock::now();
  while (!done()) {
    if (Clock::now() - lastSent >= kHeartbeatInterval) {
      if (!SendHeartbeat(client)) return Fail("send failed");
      lastSent = Clock::now();
    }
    auto e = client.Wire().Receive(std::chrono::milliseconds(10));
    if (!e && e.error().message == "timeout") continue;
    if (!e) return e.error();
    if (auto ok = client.Apply(*e); !ok) return ok;
  }
  return Status::Ok();
}

Status IdleUntil(SmaTestClient& client, Clock::time_point until) {
  return IdleUntil(client, [until] { return Clock::now() >= until; });
}

std::vector<std::string> SplitWords(const std::string& text) {
  std::vector<std::string> words;
  std::istringstream in(text);
  for (std::string w; in >> w;) words.push_back(w);
  return words;
}

std::string LoadAverage() {
  std::ifstream in("/proc/loadavg");
  std::string one, five, fifteen;
  in >> one >> five >> fifteen;
  return one.empty() ? "?" : one + " " + five + " " + fifteen;
}

}  // namespace penumbra::bench

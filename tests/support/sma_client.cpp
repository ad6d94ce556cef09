#include "support/sma_client.h"

#include <algorithm>
#include <cctype>
#include <fstream>
#include <thread>

#include <fmt/format.h>

#include "penumbra/common/messages.h"
#include "support/sanitizer_time.h"

namespace penumbra::testing {

using Clock = std::chrono::steady_clock;
constexpr std::chrono::seconds kHeartbeatInterval{5};  // docs/protocol.md, connection life cycle

Expected<SmaTestClient> SmaTestClient::Connect(uint16_t port, const std::string& name) {
  return Connect("127.0.0.1", port, name);
}

Expected<SmaTestClient> SmaTestClient::Connect(const std::string& host, uint16_t port, const std::string& name) {
  auto wire = WireClient::Connect(host, port);
  if (!wire) return wire.error();
  SmaTestClient client(std::move(*wire));
  auto welcome = client.wire_.Handshake(wire::ROLE_CLIENT, 0, 0, name);
  if (!welcome) return welcome.error();
  client.welcome_ = *welcome;
  auto info = client.wire_.Receive();
  if (!info) return info.error();
  if (!info->has_scene_info()) return Fail(fmt::format("expected scene_info after welcome, got {}", BodyName(*info)));
  client.info_ = info->scene_info();
  return client;
}

bool SmaTestClient::SendView(const CameraView& view, uint64_t viewId) {
  wire::Envelope e;
  auto* v = e.mutable_view();
  v->set_view_id(viewId);
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
  lastSent_ = Clock::now();
  return wire_.Send(e);
}

Status SmaTestClient::Apply(const wire::Envelope& e) {
  if (e.has_error()) return Fail(fmt::format("SMA error {}: {}", wire::ErrorCode_Name(e.error().code()), e.error().message()));
  if (!e.has_delta()) return Status::Ok();
  const wire::Delta& d = e.delta();
  if (auto ok = mesh_.Apply(d); !ok) return ok;
  log_.push_back(DeltaRecord{d.kind(), d.view_id(), d.triangle_ids_size(), d.removed_triangles_size()});
  return Status::Ok();
}

Status SmaTestClient::WaitConverged(uint64_t viewId, std::chrono::milliseconds timeout) {
  timeout = ScaledTimeout(timeout);
  const auto deadline = Clock::now() + timeout;
  while (!(mesh_.LastViewId() == viewId && mesh_.Converged())) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
    if (left.count() <= 0)
      return Fail(fmt::format("view {} not converged in {} ms (last delta: view {}, {} pending)", viewId,
                              timeout.count(), mesh_.LastViewId(), mesh_.PendingSamples()));
    if (Clock::now() - lastSent_ >= kHeartbeatInterval) {
      wire::Envelope heartbeat;
      heartbeat.mutable_heartbeat()->set_sent_unix_ms(uint64_t(std::chrono::duration_cast<std::chrono::milliseconds>(
          std::chrono::system_clock::now().time_since_epoch()).count()));
      if (!wire_.Send(heartbeat)) return Fail("send failed");
      lastSent_ = Clock::now();
    }
    const auto untilHeartbeat =
        std::chrono::duration_cast<std::chrono::milliseconds>(lastSent_ + kHeartbeatInterval - Clock::now());
    auto e = wire_.Receive(std::clamp(untilHeartbeat, std::chrono::milliseconds(1), left));
    if (!e && e.error().message == "timeout") continue;
    if (!e) return e.error();
    if (auto ok = Apply(*e); !ok) return ok;
  }
  return Status::Ok();
}

Expected<double> SmaTestClient::Counter(const std::string& name, std::chrono::milliseconds timeout) {
  const uint64_t id = nextStatsId_++;
  wire::Envelope request;
  request.mutable_stats_request()->set_request_id(id);
  if (!wire_.Send(request)) return Fail("send failed");
  lastSent_ = Clock::now();
  const auto deadline = Clock::now() + ScaledTimeout(timeout);
  while (Clock::now() < deadline) {
    auto e = wire_.Receive(std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now()));
    if (!e) {
      if (Clock::now() >= deadline) break;  // the wait ran out, not the connection
      return e.error();
    }
    if (e->has_stats_reply() && e->stats_reply().request_id() == id) {
      for (const auto& c : e->stats_reply().counters())
        if (c.name() == name) return c.value();
      return Fail(fmt::format("no counter '{}'", name));
    }
    if (auto ok = Apply(*e); !ok) return ok.error();
  }
  return Fail(fmt::format("no stats reply within {} ms", ScaledTimeout(timeout).count()));
}

Expected<std::string> RendererCounterPrefix(const ChildProcess& sma, const std::string& address,
                                            std::chrono::milliseconds timeout) {
  const std::string marker = "renderer endpoint " + address + " added as ";
  const auto deadline = Clock::now() + timeout;
  while (true) {
    std::ifstream log(sma.LogPath());
    for (std::string line; std::getline(log, line);) {
      const size_t at = line.find(marker);
      if (at == std::string::npos) continue;
      std::string prefix = line.substr(at + marker.size());
      while (!prefix.empty() && std::isspace(static_cast<unsigned char>(prefix.back()))) prefix.pop_back();
      return prefix;
    }
    if (Clock::now() >= deadline) return Fail(fmt::format("the SMA's log never added renderer {}", address));
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
}

CameraView ViewFromPreset(const wire::CameraPreset& preset, int width, int height) {
  CameraView view;
  view.pose.eye = Vec3(preset.eye().x(), preset.eye().y(), preset.eye().z());
  view.pose.target = Vec3(preset.target().x(), preset.target().y(), preset.target().z());
  view.pose.up = Vec3(preset.up().x(), preset.up().y(), preset.up().z());
  view.fovYDeg = preset.fov_y_deg();
  view.width = width;
  view.height = height;
  return view;
}

Expected<CameraView> ViewFromPreset(const wire::SceneInfo& info, const std::string& name, int width, int height) {
  for (const auto& preset : info.cameras())
    if (preset.name() == name) return ViewFromPreset(preset, width, height);
  return Fail("the scene has no camera preset '" + name + "'");
}

}  // namespace penumbra::testing

#include "support/fake_sma.h"

#include <fmt/format.h>

#include "penumbra/common/check.h"
#include "penumbra/common/messages.h"
#include "penumbra/common/wire_convert.h"

namespace penumbra::testing {

namespace {
using Clock = std::chrono::steady_clock;

void Set(wire::Vec3* v, float x, float y, float z) {
  v->set_x(x);
  v->set_y(y);
  v->set_z(z);
}
}  // namespace

wire::SceneInfo UnitSquareSceneInfo() {
  wire::SceneInfo info;
  info.set_name("unit-square");
  Set(info.mutable_bounds_min(), 0, 0, 0);
  Set(info.mutable_bounds_max(), 1, 1, 0);
  auto* camera = info.add_cameras();
  camera->set_name("front");
  Set(camera->mutable_eye(), 0.5f, 0.5f, 2.0f);
  Set(camera->mutable_target(), 0.5f, 0.5f, 0.0f);
  Set(camera->mutable_up(), 0, 1, 0);
  camera->set_fov_y_deg(45.0f);
  auto* grey = info.add_materials();
  Set(grey->mutable_albedo(), 0.5f, 0.5f, 0.5f);
  Set(grey->mutable_emission(), 0, 0, 0);
  grey->set_texture(-1);
  auto* textured = info.add_materials();
  Set(textured->mutable_albedo(), 1, 1, 1);
  Set(textured->mutable_emission(), 0, 0, 0);
  textured->set_texture(0);
  info.set_texture_count(1);
  info.mutable_tone_mapping()->set_bias(0.85f);
  info.mutable_tone_mapping()->set_exposure(1.0f);
  info.mutable_tone_mapping()->set_max_display_luminance(100.0f);
  return info;
}

ClientScene UnitSquareScene(uint64_t identity) {
  auto scene = ClientSceneFromWire(UnitSquareSceneInfo(), identity);
  PENUMBRA_CHECK(scene.ok(), "the unit square's SceneInfo is valid");
  return std::move(*scene);
}

Status ServeClientHandshake(WireClient& client, const wire::SceneInfo& info, uint64_t sceneHash) {
  auto hello = client.Receive();
  if (!hello) return Fail(fmt::format("waiting for hello: {}", hello.error().message));
  if (!hello->has_hello()) return Fail(fmt::format("expected hello, got {}", BodyName(*hello)));
  if (hello->hello().role() != wire::ROLE_CLIENT)
    return Fail(fmt::format("hello from role {}", wire::Role_Name(hello->hello().role())));
  wire::Envelope welcome;
  auto* w = welcome.mutable_welcome();
  w->set_protocol_version(kProtocolVersion);
  w->set_role(wire::ROLE_SMA);
  w->set_server_name("fake-sma");
  w->set_scene_hash(sceneHash);
  w->set_max_frame_bytes(16u << 20);
  wire::Envelope sceneInfo;
  *sceneInfo.mutable_scene_info() = info;
  if (!client.Send(welcome) || !client.Send(sceneInfo)) return Fail("sending welcome and scene_info failed");
  return Status::Ok();
}

Expected<wire::View> ReceiveView(WireClient& client, std::chrono::milliseconds timeout) {
  const auto deadline = Clock::now() + timeout;
  while (true) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
    if (left.count() <= 0) return Fail("timeout");
    auto e = client.Receive(left);
    if (!e) return e.error();
    if (e->has_view()) return e->view();
  }
}

}  // namespace penumbra::testing

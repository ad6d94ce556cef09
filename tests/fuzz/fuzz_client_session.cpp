// What a client does with the frames an SMA sends, in the order its session
// (client/src/session.cpp) and model (client_model.cpp) handle them: a
// Welcome (ValidateWelcome), a SceneInfo (ClientSceneFromWire, then the mesh
// store is reset with its materials and texture count), then deltas
// (the session's view-id check, then MeshStore::Apply), texture data
// (ClientModel's size checks) and stats replies. A refused message ends the
// connection as the session does, and the next frames start a new one.
// Input: a stream of frames (4-byte little-endian length + Envelope).

#include "fuzz_support.h"
#include "penumbra/client/client_model.h"
#include "penumbra/client/session.h"
#include "penumbra/common/wire_convert.h"

namespace {

using namespace penumbra;

// The requests the model makes of the session, remembered as the session would act on them.
class Requests : public client::SessionRequests {
 public:
  void RequestTexture(uint64_t, uint32_t) override { ++texturesRequested; }
  void AbandonConnection(uint64_t, const std::string&) override { abandoned = true; }
  uint64_t texturesRequested = 0;
  bool abandoned = false;
};

// The last view id the fuzzed client "sent": deltas must answer one up to it.
constexpr uint64_t kLastSentViewId = 1000;

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const bool quiet = (fuzz::QuietLogs(), true);
  (void)quiet;
  client::ClientModel model;
  Requests requests;
  uint64_t connection = 1;
  std::optional<wire::Welcome> welcome;
  bool ready = false;
  auto drop = [&] {
    model.Apply({client::Disconnected{connection, "refused"}}, requests);
    ++connection;
    welcome.reset();
    ready = false;
    requests.abandoned = false;
  };
  for (wire::Envelope& envelope : fuzz::DecodeFrameStream(data, size)) {
    if (envelope.has_error()) continue;  // logged only
    if (!welcome) {
      wire::ErrorCode code = wire::ERROR_CODE_UNSPECIFIED;
      if (!envelope.has_welcome() || !ValidateWelcome(envelope.welcome(), wire::ROLE_SMA, 0, &code)) {
        drop();
        continue;
      }
      (void)Printable(envelope.welcome().server_name());
      welcome = envelope.welcome();
      continue;
    }
    if (!ready) {
      auto scene = envelope.has_scene_info() ? ClientSceneFromWire(envelope.scene_info(), welcome->scene_hash())
                                             : Expected<ClientScene>(Fail("no scene_info"));
      if (!scene) {
        drop();
        continue;
      }
      PENUMBRA_CHECK(scene->textureCount <= kMaxSceneTextures, "a texture count over the limit was accepted");
      ready = true;
      model.Apply({client::Connected{connection, std::move(*scene)}}, requests);
      continue;
    }
    std::vector<client::SessionEvent> events;
    switch (envelope.body_case()) {
      case wire::Envelope::kDelta: {
        const uint64_t viewId = envelope.delta().view_id();
        // As the session: a MOVED may come before any view (view id 0).
        const bool viewless = envelope.delta().kind() == wire::DELTA_KIND_MOVED && viewId == 0;
        if (!viewless && (viewId == 0 || viewId > kLastSentViewId)) {
          drop();
          continue;
        }
        events.push_back(client::DeltaReceived{connection, viewId,
                                                std::make_shared<const wire::Delta>(std::move(*envelope.mutable_delta()))});
        break;
      }
      case wire::Envelope::kTextureData: {
        wire::TextureData& t = *envelope.mutable_texture_data();
        events.push_back(
            client::TextureReceived{connection, t.texture(), t.width(), t.height(), std::move(*t.mutable_rgb8())});
        break;
      }
      case wire::Envelope::kStatsReply: {
        client::SmaCountersReceived counters{connection, {}};
        for (const auto& c : envelope.stats_reply().counters()) counters.counters[c.name()] = c.value();
        events.push_back(std::move(counters));
        break;
      }
      default:
        drop();
        continue;
    }
    model.Apply(std::move(events), requests);
    for (const auto& texture : model.TakeTextures())
      PENUMBRA_CHECK(texture.rgb8.size() == size_t(texture.width) * size_t(texture.height) * 3,
                     "a texture of the wrong size was accepted");
    (void)model.Converged(kLastSentViewId);
    (void)model.Mesh().HeldLuminance();
    if (requests.abandoned) drop();
  }
  return 0;
}

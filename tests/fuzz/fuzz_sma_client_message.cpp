// What an SMA does with one frame from a client: decode the envelope, then
// check a Hello (ValidateHello), turn a View into a camera view
// (ViewFromWire: finite, in range, at most --max-view-pixels), apply
// SessionOptions to the refinement parameters (ApplySessionOptions,
// common/wire_convert.h), answer
// a TextureRequest (CheckTextureRequest, then EncodeTextureData of a small
// texture, with a budget the request's id picks so that the halving loop
// runs), check a MoveObject against a scene with a movable and an animated
// object (CheckMoveObject, then the next pose), and read a StatsRequest.
// Input: one frame payload.

#include "fuzz_support.h"
#include "penumbra/common/scene.h"
#include "penumbra/common/wire_convert.h"
#include "penumbra/sma/client_requests.h"
#include "penumbra/sma/scene_moves.h"
#include "penumbra/sma/texture_frames.h"

namespace {
const penumbra::Texture& SmallTexture() {
  static const penumbra::Texture texture = [] {
    penumbra::fuzz::QuietLogs();
    penumbra::Texture t;
    t.width = 37;
    t.height = 19;
    for (int i = 0; i < t.width * t.height; ++i)
      t.texels.push_back(penumbra::Rgb(float(i % 7) / 6.0f, float(i % 5) / 4.0f, float(i % 3) / 2.0f));
    return t;
  }();
  return texture;
}
// A floor, a movable quad and an animated one.
const penumbra::Scene& SceneWithObjects() {
  static const penumbra::Scene scene = [] {
    using namespace penumbra;
    SceneBuilder b;
    const uint32_t m = b.AddMaterial(Material{});
    b.AddQuad(Vec3(-1.0f, 0.0f, -1.0f), Vec3(0, 0, 2), Vec3(2, 0, 0), m);
    MovableObject box;
    box.name = "box";
    b.BeginObject(box);
    b.AddQuad(Vec3(-0.5f, 0.0f, -0.5f), Vec3(0, 0, 1), Vec3(1, 0, 0), m);
    MovableObject spinner;
    spinner.name = "spinner";
    ObjectAnimation path;
    path.keys = {ObjectKeyframe{0.0f, RigidTransform{}},
                 ObjectKeyframe{1.0f, RigidTransform{glm::mat3(1.0f), Vec3(0.0f, 1.0f, 0.0f)}}};
    spinner.animation = path;
    b.BeginObject(spinner);
    b.AddQuad(Vec3(-0.1f, 0.0f, -0.1f), Vec3(0, 0, 0.2f), Vec3(0.2f, 0, 0), m);
    b.EndObject();
    Scene s;
    PENUMBRA_CHECK(b.BuildInto(s).ok(), "the fuzz scene did not build");
    return s;
  }();
  return scene;
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace penumbra;
  const Texture& texture = SmallTexture();
  auto envelope = DecodeEnvelope(std::string_view(reinterpret_cast<const char*>(data), size));
  if (!envelope) return 0;
  constexpr uint64_t kMaxViewPixels = 8192ull * 4608ull;  // the SMA's default
  switch (envelope->body_case()) {
    case wire::Envelope::kHello: {
      wire::ErrorCode code = wire::ERROR_CODE_UNSPECIFIED;
      (void)ValidateHello(envelope->hello(), wire::ROLE_CLIENT, 0x1234, &code);
      (void)Printable(envelope->hello().peer_name());
      break;
    }
    case wire::Envelope::kView: {
      if (auto view = sma::ViewFromWire(envelope->view(), kMaxViewPixels)) {
        PENUMBRA_CHECK(uint64_t(view->width) * uint64_t(view->height) <= kMaxViewPixels, "view over the limit");
        PENUMBRA_CHECK(ValidateCameraView(*view).ok(), "an invalid view was accepted");
      }
      break;
    }
    case wire::Envelope::kSessionOptions: {
      if (auto params = ApplySessionOptions(RefinementParams{}, envelope->session_options()))
        PENUMBRA_CHECK(params->Validate().ok(), "invalid refinement parameters were accepted");
      break;
    }
    case wire::Envelope::kTextureRequest: {
      const auto& request = envelope->texture_request();
      if (sma::CheckTextureRequest(request, 1)) {
        const size_t budget = size_t(request.texture() + 1) * 61;
        wire::TextureData out = sma::EncodeTextureData(texture, request.texture(), budget);
        PENUMBRA_CHECK(out.rgb8().size() == size_t(out.width()) * out.height() * 3, "texture size mismatch");
      }
      break;
    }
    case wire::Envelope::kMoveObject: {
      const Scene& scene = SceneWithObjects();
      if (auto move = sma::CheckMoveObject(envelope->move_object(), scene)) {
        PENUMBRA_CHECK(move->object < scene.objects.size(), "a move of an unknown object was accepted");
        PENUMBRA_CHECK(!scene.objects[move->object].animation, "a move of an animated object was accepted");
        PENUMBRA_CHECK(IsFinite(move->objectToWorld.translation), "a non-finite move was accepted");
        const std::vector<sma::ObjectMove> moves{*move};
        if (auto next = sma::NextPose(ScenePose::Initial(scene), moves))
          PENUMBRA_CHECK(next->epoch == 1, "a move from epoch 0 did not make epoch 1");
      }
      break;
    }
    case wire::Envelope::kStatsRequest:
      (void)envelope->stats_request().request_id();
      break;
    default:
      break;
  }
  return 0;
}

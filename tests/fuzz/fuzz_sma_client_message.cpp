// What an SMA does with one frame from a client: decode the envelope, then
// check a Hello (ValidateHello), turn a View into a camera view
// (ViewFromWire: finite, in range, at most --max-view-pixels), apply
// SessionOptions to the refinement parameters (ApplySessionOptions,
// common/wire_convert.h), answer
// a TextureRequest (CheckTextureRequest, then EncodeTextureData of a small
// texture, with a budget the request's id picks so that the halving loop
// runs), and read a StatsRequest. Input: one frame payload.

#include "fuzz_support.h"
#include "penumbra/common/scene.h"
#include "penumbra/common/wire_convert.h"
#include "penumbra/sma/client_requests.h"
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
    case wire::Envelope::kStatsRequest:
      (void)envelope->stats_request().request_id();
      break;
    default:
      break;
  }
  return 0;
}

// What an SMA's renderer pool does with one frame from a renderer: decode
// the envelope, then check a Welcome (ValidateWelcome), or check a
// ShadeReply part's arrays (CheckShadeReplyShape), decode each sample
// (DecodeReplySample), decode the whole part (DecodeShadeReply) and check
// its values against what the Cornell box can produce
// (RadianceBounds::Check), as the SampleScheduler does before it looks the
// samples up among those in flight. Input: one frame payload.

#include <memory>

#include "fuzz_support.h"
#include "penumbra/common/scene.h"
#include "penumbra/sma/shade_codec.h"

namespace {
const penumbra::sma::RadianceBounds& Bounds() {
  static const penumbra::sma::RadianceBounds bounds = [] {
    penumbra::fuzz::QuietLogs();
    auto loaded = penumbra::LoadScene(penumbra::fuzz::ScenesDir() / "cornell-box.json");
    if (!loaded) std::abort();
    return penumbra::sma::RadianceBounds::ForScene(*loaded);
  }();
  return bounds;
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace penumbra;
  const sma::RadianceBounds& bounds = Bounds();
  auto envelope = DecodeEnvelope(std::string_view(reinterpret_cast<const char*>(data), size));
  if (!envelope) return 0;
  if (envelope->has_welcome()) {
    wire::ErrorCode code = wire::ERROR_CODE_UNSPECIFIED;
    (void)ValidateWelcome(envelope->welcome(), wire::ROLE_RENDERER, 0x1234, &code);
    (void)Printable(envelope->welcome().server_name());
  } else if (envelope->has_shade_reply()) {
    const auto& reply = envelope->shade_reply();
    if (!sma::CheckShadeReplyShape(reply)) return 0;
    for (int i = 0; i < reply.sample_ids_size(); ++i) {
      auto sample = sma::DecodeReplySample(reply, i, 64);
      if (!sample) break;
      if (bounds.Check(*sample)) {
        PENUMBRA_CHECK(sample->paths >= 1, "a sample of no path was accepted");
      }
    }
    if (auto samples = sma::DecodeShadeReply(reply, 64)) {
      PENUMBRA_CHECK(samples->size() == size_t(reply.sample_ids_size()), "a decoded part lost samples");
      for (const auto& sample : *samples) PENUMBRA_CHECK(sample.paths >= 1, "a sample of no path was decoded");
    }
  }
  return 0;
}

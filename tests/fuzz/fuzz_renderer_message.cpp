// What a renderer does with one frame from an SMA: decode the envelope, then
// check a Hello (ValidateHello) or turn a ShadeRequest into shader inputs
// (DecodeShadeRequest, which runs ValidateShadeInput on every sample against
// the scene). The scene is the shipped Cornell box, as in CI's stack runs.
// Input: one frame payload (a serialized wire::Envelope).

#include <memory>

#include "fuzz_support.h"
#include "penumbra/common/scene.h"
#include "penumbra/renderer/shade_batch.h"

namespace {
const penumbra::Scene& CornellBox() {
  static const auto scene = [] {
    penumbra::fuzz::QuietLogs();
    auto loaded = penumbra::LoadScene(penumbra::fuzz::ScenesDir() / "cornell-box.json");
    if (!loaded) std::abort();
    return std::make_unique<penumbra::Scene>(std::move(*loaded));
  }();
  return *scene;
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace penumbra;
  const Scene& scene = CornellBox();
  auto envelope = DecodeEnvelope(std::string_view(reinterpret_cast<const char*>(data), size));
  if (!envelope) return 0;
  if (envelope->has_hello()) {
    wire::ErrorCode code = wire::ERROR_CODE_UNSPECIFIED;
    (void)ValidateHello(envelope->hello(), wire::ROLE_SMA, scene.identity, &code);
    (void)Printable(envelope->hello().peer_name());
  } else if (envelope->has_shade_request()) {
    const ShadeLimits limits;  // the renderer's defaults
    auto inputs = DecodeShadeRequest(envelope->shade_request(), scene, limits);
    if (inputs) PENUMBRA_CHECK(inputs->size() <= limits.maxBatchSamples, "a batch over the limit was accepted");
  }
  return 0;
}

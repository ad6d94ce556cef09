// What a renderer does with one frame from an SMA: decode the envelope, then
// check a Hello (ValidateHello) or turn a ShadeRequest into shader inputs:
// its pose (DecodeShadePose: epoch and 12 floats per movable object, each a
// rigid transform) and its samples at that pose (DecodeShadeRequest, which
// runs ValidateShadeInput on every sample against the scene). Two scenes,
// as in CI's stack runs: the shipped Cornell box (no movable object: any
// transform is an error) and the same box with a movable one
// (cornell-box-floating.json). Input: one frame payload (a serialized
// wire::Envelope); the corpus holds requests of both kinds.

#include <cmath>
#include <memory>
#include <string>

#include "fuzz_support.h"
#include "penumbra/common/scene.h"
#include "penumbra/renderer/shade_batch.h"

namespace {
const penumbra::Scene& Load(const std::string& file) {
  penumbra::fuzz::QuietLogs();
  auto loaded = penumbra::LoadScene(penumbra::fuzz::ScenesDir() / file);
  if (!loaded) std::abort();
  return *new penumbra::Scene(std::move(*loaded));  // for the process's life
}
const penumbra::Scene& CornellBox() {
  static const penumbra::Scene& scene = Load("cornell-box.json");
  return scene;
}
const penumbra::Scene& FloatingBox() {
  static const penumbra::Scene& scene = Load("cornell-box-floating.json");
  return scene;
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace penumbra;
  auto envelope = DecodeEnvelope(std::string_view(reinterpret_cast<const char*>(data), size));
  if (!envelope) return 0;
  for (const Scene* scene : {&CornellBox(), &FloatingBox()}) {
    if (envelope->has_hello()) {
      wire::ErrorCode code = wire::ERROR_CODE_UNSPECIFIED;
      (void)ValidateHello(envelope->hello(), wire::ROLE_SMA, scene->identity, &code);
      (void)Printable(envelope->hello().peer_name());
    } else if (envelope->has_shade_request()) {
      const ShadeLimits limits;  // the renderer's defaults
      const wire::ShadeRequest& request = envelope->shade_request();
      auto pose = DecodeShadePose(request, *scene);
      if (pose) {
        PENUMBRA_CHECK(pose->objectToWorld.size() == scene->objects.size(), "a pose for another scene was accepted");
        for (const RigidTransform& t : pose->objectToWorld)
          for (float v : t.ToRowMajor()) PENUMBRA_CHECK(std::isfinite(v), "a transform that is not finite was accepted");
      }
      auto inputs = DecodeShadeRequest(request, *scene, limits);
      if (inputs) {
        PENUMBRA_CHECK(pose.ok(), "samples accepted at a pose that was refused");
        PENUMBRA_CHECK(inputs->size() <= limits.maxBatchSamples, "a batch over the limit was accepted");
      }
    }
  }
  return 0;
}

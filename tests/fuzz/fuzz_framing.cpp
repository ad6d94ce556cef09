// Framing (common FrameDecoder) and envelope decoding, as every connection
// of the three processes runs them on the bytes a peer sends. The first
// input byte chooses how the rest is cut into reads (TCP delivers any cut).

#include <algorithm>

#include "fuzz_support.h"
#include "penumbra/common/check.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace penumbra;
  static const bool quiet = (fuzz::QuietLogs(), true);
  (void)quiet;
  if (size < 1) return 0;
  const size_t chunk = size_t(data[0]) + 1;
  ++data;
  --size;
  // A small limit, so that the over-limit path is reached too.
  FrameDecoder decoder(4096);
  size_t delivered = 0;
  size_t framed = 0;
  while (delivered < size) {
    const size_t n = std::min(chunk, size - delivered);
    decoder.Feed(data + delivered, n);
    delivered += n;
    for (;;) {
      auto frame = decoder.Next();
      if (!frame) {
        // A framing error is final: every later call repeats it.
        PENUMBRA_CHECK(!decoder.Next(), "a framing error must be final");
        return 0;
      }
      if (!*frame) break;
      PENUMBRA_CHECK((*frame)->size() <= decoder.MaxFrameBytes(), "a frame over the limit was returned");
      framed += kFrameHeaderBytes + (*frame)->size();
      if (auto envelope = DecodeEnvelope(**frame)) (void)BodyName(*envelope);
    }
    PENUMBRA_CHECK(framed + decoder.Buffered() == delivered, "bytes lost or duplicated");
  }
  return 0;
}

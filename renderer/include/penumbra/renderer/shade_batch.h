#pragma once
// Translation between wire ShadeRequest/ShadeReply messages and the shader's
// ShadeInput/ShadeOutput, with every field checked. Plain code, no sockets.

#include <cstdint>
#include <span>
#include <vector>

#include "penumbra/common/expected.h"
#include "penumbra/renderer/shading.h"
#include "penumbra/wire.pb.h"

namespace penumbra {

struct ShadeLimits {
  uint32_t maxBatchSamples = 16384;
  uint32_t maxPathsPerSample = 65536;
};

/// Decodes a request into shader inputs. Fails, naming the field and the
/// sample index, when the parallel arrays disagree in length, the batch is
/// empty or over the limit, the path count is over the limit, or any sample
/// fails ValidateShadeInput.
Expected<std::vector<ShadeInput>> DecodeShadeRequest(const wire::ShadeRequest& request, const Scene& scene,
                                                     const ShadeLimits& limits);

/// Fills one reply part: results for `inputs[i]` are `outputs[i]`.
void FillShadeReply(uint64_t batchId, std::span<const ShadeInput> inputs, std::span<const ShadeOutput> outputs,
                    uint32_t remaining, const ShadeCounters& counters, wire::ShadeReply* reply);

}  // namespace penumbra

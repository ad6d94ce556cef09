#include "penumbra/sma/client_limits.h"

#include <fmt/format.h>

namespace penumbra::sma {

bool VisibilityBudget::Resize(uint64_t& held, uint64_t pixels) {
  std::lock_guard lock(mutex_);
  if (pixels > held) {
    const uint64_t more = pixels - held;
    if (used_ + more > capacity_) return false;
    used_ += more;
  } else {
    used_ -= held - pixels;
  }
  held = pixels;
  return true;
}

uint64_t VisibilityBudget::Used() const {
  std::lock_guard lock(mutex_);
  return used_;
}

Status CheckClientRefinement(const RefinementParams& requested, const RefinementParams& current,
                             const ClientRefinementLimits& limits) {
  if (requested.sReq != current.sReq && requested.sReq < limits.minSReq)
    return Fail(fmt::format("s_req = {} is below this SMA's minimum {} (--client-min-s-req)", requested.sReq,
                            limits.minSReq));
  if (requested.minPixels != current.minPixels && requested.minPixels < limits.minMinPixels)
    return Fail(fmt::format("min_pixels = {} is below this SMA's minimum {} (--client-min-pixels)", requested.minPixels,
                            limits.minMinPixels));
  if (requested.maxDepth != current.maxDepth && requested.maxDepth > limits.maxDepth)
    return Fail(fmt::format("max_depth = {} is above this SMA's maximum {} (--client-max-depth)", requested.maxDepth,
                            limits.maxDepth));
  if (requested.batch != current.batch && requested.batch > limits.maxBatch)
    return Fail(fmt::format("batch (R) = {} is above this SMA's maximum {} (--client-max-refine-batch)",
                            requested.batch, limits.maxBatch));
  return Status::Ok();
}

}  // namespace penumbra::sma

#pragma once
// What one client may cost the SMA (issue 12): the visibility memory all
// clients' views hold together, and the refinement a client may ask for.
// Pure logic, unit-tested in sma/tests/client_limits_test.cpp; the server
// (server.cpp) applies it and answers the offender with an ErrorReply.

#include <cstdint>
#include <mutex>

#include "penumbra/common/expected.h"
#include "penumbra/sma/refinement.h"

namespace penumbra::sma {

/// Visibility buffers cost about this much per pixel of a client's view: the
/// hit (16 bytes), the node it maps to (4), and a re-map's new node buffer
/// while the old one is still shown (4).
inline constexpr uint64_t kVisibilityBytesPerPixel = 24;

/// Pixels of visibility buffers held across every client, against a fixed
/// capacity. Each holder (a session) keeps one reservation: the pixels of
/// the largest buffer it may hold at once. Thread-safe.
class VisibilityBudget {
 public:
  explicit VisibilityBudget(uint64_t capacityPixels) : capacity_(capacityPixels) {}
  VisibilityBudget(const VisibilityBudget&) = delete;
  VisibilityBudget& operator=(const VisibilityBudget&) = delete;

  /// Changes a holder's reservation from `held` to `pixels`. Shrinking always
  /// succeeds; growing succeeds when the total stays within the capacity.
  /// On success `held` becomes `pixels`; on failure nothing changes.
  bool Resize(uint64_t& held, uint64_t pixels);
  uint64_t Used() const;
  uint64_t Capacity() const { return capacity_; }

 private:
  const uint64_t capacity_;
  mutable std::mutex mutex_;
  uint64_t used_ = 0;
};

/// Bounds on the refinement a client may ask for with SessionOptions. The
/// operator's own defaults (the SMA's --s-req, ... flags) are not bound by
/// them; a client asking for a value beyond them is refused.
struct ClientRefinementLimits {
  float minSReq = 0.01f;       // --client-min-s-req: a smaller S_req splits on noise
  float minMinPixels = 1.0f;   // --client-min-pixels: leaves under a pixel are invisible
  uint32_t maxDepth = 16;      // --client-max-depth
  uint32_t maxBatch = 1024;    // --client-max-refine-batch: R, leaves per step (the state lock is held for a step)
  /// --client-max-refinement-samples: new vertices one client's refinement
  /// may create for one view; beyond it the view's refinement ends.
  uint64_t maxSamplesPerView = 500000;
};

/// Checks the fields of `requested` that differ from `current` (what the
/// client has now, starting from the operator's defaults) against `limits`.
/// The error names the field, the value asked, the limit and its flag.
Status CheckClientRefinement(const RefinementParams& requested, const RefinementParams& current,
                             const ClientRefinementLimits& limits);

/// Whether a client's texture request may be taken: it has `outstanding`
/// requests not yet answered, at most `maxOutstanding`. A repeat of an
/// outstanding request is not a new one (the caller drops it: one answer
/// serves both).
inline bool TextureRequestAllowed(size_t outstanding, size_t maxOutstanding) { return outstanding < maxOutstanding; }

}  // namespace penumbra::sma

#pragma once
// The refinement a view session runs (founding paper §4; the criteria are
// described in sma/include/penumbra/sma/refinement.h): the parameters the
// SMA starts each session with (its flags), and what a client may ask to
// change with SessionOptions. Shared by the SMA and the client so that the
// criterion names and the ranges are written once; the wire conversion is in
// wire_convert.h. No protobuf here.
//
// Threads: plain values and immutable tables; any thread.

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>

#include "penumbra/common/expected.h"

namespace penumbra {

enum class Criterion : uint8_t { kNone, kNldOs, kNldIs, kRnd, kNldOsRnd };

/// A criterion's name on the wire and in flags, and what it means to a user.
struct CriterionEntry {
  Criterion criterion;
  std::string_view name;
  std::string_view meaning;
};

/// Every criterion, in the order a user cycles through them (the client's
/// panel and C key): the SMA's default first, "none" last.
std::span<const CriterionEntry> Criteria();
/// "nld_os, nld_is, rnd, nld_os_rnd or none", for help texts and errors.
std::string CriterionNameList();
/// The criterion named `name`, or "unknown criterion 'x' (the list)".
Expected<Criterion> ParseCriterion(std::string_view name);
std::string_view CriterionName(Criterion c);

struct RefinementParams {
  Criterion criterion = Criterion::kNldOs;
  float sReq = 0.04f;             // S above which a leaf (or quadrant) is split
  uint32_t batch = 64;            // R: leaves chosen per step
  float minPixels = 6.0f;         // leaves covering fewer pixels are never split
  float largeFraction = 1.0f / 32.0f;  // NLD_OS: leaves covering more of the image are always split
  float aspectThreshold = 1.2f;   // propagation: slim neighbours split 1 -> 2 (RefineOptions)
  uint8_t maxDepth = 12;          // leaves this deep are not split
  float pixelFraction = 0.1f;     // NLD_IS, RND: budget as a fraction of the image's pixels
  float noiseZ = 2.0f;            // differences within this many standard errors are noise; 0: the paper's S
  float probeFraction = 1.0f / 16384.0f;  // NLD_OS: interior probes of leaves covering more of the image; 1: none
  uint64_t seed = 1;              // RND's random stream

  /// The largest maxDepth Validate() accepts.
  static constexpr uint32_t kMaxDepthLimit = 20;

  /// Checks ranges: sReq in [0, 1], batch in [1, 1e6], minPixels >= 0,
  /// largeFraction in (0, 1], aspectThreshold > 0, maxDepth in [1, 20],
  /// pixelFraction in (0, 1], noiseZ in [0, 10], probeFraction in (0, 1].
  Status Validate() const;
};

/// What a client asks to change in its session's refinement (SessionOptions):
/// the fields that are set replace the session's; the others keep theirs.
struct RefinementRequest {
  std::optional<Criterion> criterion;
  std::optional<float> sReq;
  std::optional<uint32_t> batch;
  std::optional<float> minPixels;
  std::optional<float> largeFraction;
  std::optional<float> aspectThreshold;
  std::optional<uint32_t> maxDepth;  // checked against kMaxDepthLimit before it narrows
  std::optional<float> pixelFraction;
  std::optional<float> noiseZ;

  bool Empty() const;
  /// `current` with the fields that are set replaced, or why the result is
  /// refused ("session options: <RefinementParams::Validate's message>").
  /// The one place a client's refinement request is validated.
  Expected<RefinementParams> AppliedTo(const RefinementParams& current) const;
};

}  // namespace penumbra

#include "penumbra/common/refinement_params.h"

#include <array>
#include <cmath>

#include <fmt/format.h>

namespace penumbra {

namespace {

constexpr std::array<CriterionEntry, 5> kCriteria{{
    {Criterion::kNldOs, "nld_os", "split where neighbouring samples differ in brightness (object space)"},
    {Criterion::kNldIs, "nld_is", "split where the image differs most (image space), within a pixel budget"},
    {Criterion::kRnd, "rnd", "split at random, within a pixel budget (a baseline)"},
    {Criterion::kNldOsRnd, "nld_os_rnd", "object-space differences, plus random splits"},
    {Criterion::kNone, "none", "no refinement: the base mesh only"},
}};

}  // namespace

std::span<const CriterionEntry> Criteria() { return kCriteria; }

std::string CriterionNameList() {
  std::string list;
  for (size_t i = 0; i < kCriteria.size(); ++i) {
    if (i > 0) list += i + 1 == kCriteria.size() ? " or " : ", ";
    list += kCriteria[i].name;
  }
  return list;
}

Expected<Criterion> ParseCriterion(std::string_view name) {
  for (const CriterionEntry& entry : kCriteria)
    if (entry.name == name) return entry.criterion;
  return Fail(fmt::format("unknown criterion '{}' ({})", name, CriterionNameList()));
}

std::string_view CriterionName(Criterion c) {
  for (const CriterionEntry& entry : kCriteria)
    if (entry.criterion == c) return entry.name;
  return "?";
}

Status RefinementParams::Validate() const {
  auto bad = [](const char* what, double v) { return Fail(fmt::format("{} = {} is out of range", what, v)); };
  if (!(sReq >= 0.0f && sReq <= 1.0f)) return bad("s_req", sReq);
  if (batch < 1 || batch > 1000000) return bad("batch (R)", batch);
  if (!(minPixels >= 0.0f && std::isfinite(minPixels))) return bad("min_pixels", minPixels);
  if (!(largeFraction > 0.0f && largeFraction <= 1.0f)) return bad("large_fraction", largeFraction);
  if (!(aspectThreshold > 0.0f && std::isfinite(aspectThreshold))) return bad("aspect_threshold", aspectThreshold);
  if (maxDepth < 1 || maxDepth > kMaxDepthLimit) return bad("max_depth", maxDepth);
  if (!(pixelFraction > 0.0f && pixelFraction <= 1.0f)) return bad("pixel_fraction", pixelFraction);
  if (!(noiseZ >= 0.0f && noiseZ <= 10.0f)) return bad("noise_z", noiseZ);
  if (!(probeFraction > 0.0f && probeFraction <= 1.0f)) return bad("probe_fraction", probeFraction);
  return Status::Ok();
}

bool RefinementRequest::Empty() const {
  return !criterion && !sReq && !batch && !minPixels && !largeFraction && !aspectThreshold && !maxDepth &&
         !pixelFraction && !noiseZ;
}

Expected<RefinementParams> RefinementRequest::AppliedTo(const RefinementParams& current) const {
  // maxDepth narrows to 8 bits: a value that would wrap is refused before it does.
  if (maxDepth && *maxDepth > RefinementParams::kMaxDepthLimit)
    return Fail(fmt::format("session options: max_depth = {} is out of range", *maxDepth));
  RefinementParams p = current;
  if (criterion) p.criterion = *criterion;
  if (sReq) p.sReq = *sReq;
  if (batch) p.batch = *batch;
  if (minPixels) p.minPixels = *minPixels;
  if (largeFraction) p.largeFraction = *largeFraction;
  if (aspectThreshold) p.aspectThreshold = *aspectThreshold;
  if (maxDepth) p.maxDepth = uint8_t(*maxDepth);
  if (pixelFraction) p.pixelFraction = *pixelFraction;
  if (noiseZ) p.noiseZ = *noiseZ;
  if (auto ok = p.Validate(); !ok) return Fail("session options: " + ok.error().message);
  return p;
}

}  // namespace penumbra

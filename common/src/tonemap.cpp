#include "penumbra/common/tonemap.h"

#include <cmath>

namespace penumbra {

ViewLuminance MeasureLuminance(std::span<const Rgb> radiance) {
  double logSum = 0.0;
  float max = 0.0f;
  size_t n = 0;
  for (const Rgb& c : radiance) {
    const float l = Luminance(c);
    if (!(l > 0.0f) || !std::isfinite(l)) continue;
    logSum += std::log(double(l));
    max = std::max(max, l);
    ++n;
  }
  if (n == 0) return ViewLuminance{};
  return ViewLuminance{max, float(std::exp(logSum / double(n)))};
}

float DragoDisplayLuminance(float lw, const ViewLuminance& view, const DragoParams& params) {
  if (!(lw > 0.0f)) return 0.0f;
  // World luminances relative to the adaptation luminance; the exposure
  // brightens by lowering the adaptation level.
  const float adaptation = std::max(view.logAverage, 1e-9f) / std::max(params.exposure, 1e-9f);
  const float l = lw / adaptation;
  const float lmax = std::max(view.max / adaptation, 1e-6f);
  const float biasPower = std::log(params.bias) / std::log(0.5f);
  const float scale = params.maxDisplayLuminance * 0.01f / std::log10(lmax + 1.0f);
  const float ld = scale * std::log(l + 1.0f) / std::log(2.0f + 8.0f * std::pow(l / lmax, biasPower));
  return std::clamp(ld, 0.0f, 1.0f);
}

Rgb ToneMapDrago(const Rgb& radiance, const ViewLuminance& view, const DragoParams& params) {
  const float lw = Luminance(radiance);
  if (!(lw > 0.0f)) return Rgb(0.0f);
  return glm::clamp(radiance * (DragoDisplayLuminance(lw, view, params) / lw), Rgb(0.0f), Rgb(1.0f));
}

}  // namespace penumbra

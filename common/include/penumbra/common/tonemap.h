#pragma once
// Tone mapping shared by every tier: the client's shader mirrors these
// functions in GLSL, the SMA's refinement criteria (NLD, paper eq. 1) use the
// tone-mapped luminance, and screenshots and experiments map images with the
// same code, so "what the user sees" means one thing everywhere.
//
// Drago, Myszkowski, Annen, Chiba 2003, "Adaptive Logarithmic Mapping for
// Displaying High Contrast Scenes", eq. 4:
//
//   Ld = (Ldmax * 0.01 / log10(Lwmax + 1)) * ln(Lw + 1) / ln(2 + 8 (Lw / Lwmax)^(ln b / ln 0.5))
//
// with world luminances Lw, Lwmax divided by the world adaptation luminance
// (the view's log-average, scaled by the exposure), Ldmax the display's
// maximum luminance (100 cd/m^2) and b the bias (0.85). Ld is relative
// display luminance, 1 = white. Colour is carried by scaling linear RGB by
// Ld / Lw, then encoded for the display with the sRGB transfer function.

#include <span>

#include "penumbra/common/math.h"

namespace penumbra {

struct DragoParams {
  float bias = 0.85f;                  // b: 0.7 (more contrast) .. 0.9 (more detail in darks)
  float maxDisplayLuminance = 100.0f;  // Ldmax, cd/m^2
  float exposure = 1.0f;               // multiplies the world adaptation luminance's effect
};

/// What the operator adapts to: the view's maximum and log-average world
/// luminance (both > 0).
struct ViewLuminance {
  float max = 1.0f;
  float logAverage = 1.0f;
};

/// The statistics of a set of linear radiances (a frame's vertices or
/// pixels). Zero and negative luminances are ignored; an empty or black set
/// gives {1, 1}.
ViewLuminance MeasureLuminance(std::span<const Rgb> radiance);

/// Relative display luminance in [0, 1] for world luminance `lw` (>= 0).
float DragoDisplayLuminance(float lw, const ViewLuminance& view, const DragoParams& params);

/// Linear RGB radiance -> display-linear RGB in [0, 1] (before sRGB encoding).
Rgb ToneMapDrago(const Rgb& radiance, const ViewLuminance& view, const DragoParams& params);

/// The simple alternative: radiance * exposure, clamped (before sRGB encoding).
inline Rgb ToneMapExposure(const Rgb& radiance, float exposure) {
  return glm::clamp(radiance * exposure, Rgb(0.0f), Rgb(1.0f));
}

}  // namespace penumbra

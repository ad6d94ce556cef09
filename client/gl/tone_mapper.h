#pragma once
// The tone-mapping pass: radiance image -> display colour, in a fragment
// shader that mirrors common/tonemap.h exactly (Drago et al. 2003, then the
// sRGB transfer function), or the simple alternative, exposure then gamma.
//
// Threads: render thread, with the context current.

#include "gl/gl_objects.h"
#include "penumbra/common/tonemap.h"

namespace penumbra::client::gl {

enum class ToneOperator { kDrago, kExposureGamma };

/// The user's tone-mapping controls.
struct ToneSettings {
  ToneOperator op = ToneOperator::kDrago;
  /// Photographic stops added to the scene's exposure (both operators).
  float exposureStops = 0.0f;
  /// kExposureGamma: display value = clamp(radiance * exposure)^(1 / gamma).
  float gamma = 2.2f;
};

/// What a pixel of the background (no surface drawn) shows.
inline constexpr float kBackgroundDisplay[3] = {0.06f, 0.06f, 0.08f};

class ToneMapper {
 public:
  static Expected<ToneMapper> Create();

  /// Maps the radiance texture (RGBA32F, same size as the bound framebuffer's
  /// viewport; alpha 0 = background) into the bound framebuffer.
  ///  * kDrago: ToneMapDrago(radiance, adaptation, params with exposure
  ///    scaled by 2^exposureStops), sRGB-encoded, exactly as the CPU code.
  ///  * kExposureGamma: ToneMapExposure(radiance, e) with
  ///    e = 2^exposureStops * 0.18 / adaptation.logAverage (the view's
  ///    log-average maps to mid-grey at 0 stops), then the gamma curve.
  void Draw(GLuint radianceTexture, const ViewLuminance& adaptation, const DragoParams& sceneParams,
            const ToneSettings& settings) const;

 private:
  ToneMapper(Program program, VertexArray empty) : program_(std::move(program)), empty_(std::move(empty)) {}
  Program program_;
  VertexArray empty_;  // core profile draws need a bound vertex array
};

}  // namespace penumbra::client::gl

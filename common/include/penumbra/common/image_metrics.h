#pragma once
// Image comparison for experiments: how far an image is from a reference.
//
//  * Relative mean absolute error on linear radiance:
//      relMAE = sum |image - reference| / sum |reference|   (all pixels, all channels)
//  * SSIM (Wang, Bovik, Sheikh, Simoncelli 2004) on what a viewer sees:
//    both images tone-mapped with Drago 2003 using the *reference's*
//    luminance statistics (so they are mapped identically), sRGB-encoded,
//    converted to luma; 11x11 Gaussian window (sigma 1.5), C1 = (0.01)^2,
//    C2 = (0.03)^2, mean over the image.
//  * Mean ratio: mean luminance of the image over the reference's (a bias:
//    1 means neither darker nor brighter on the whole).
//  * A box blur of both images first (radius 2: 5x5) takes the Monte Carlo
//    noise of a reference out of the comparison.

#include <span>
#include <vector>

#include "penumbra/common/expected.h"
#include "penumbra/common/tonemap.h"

namespace penumbra {

/// A linear RGB image, row-major, row 0 at the top.
struct RgbImage {
  int width = 0;
  int height = 0;
  std::vector<Rgb> pixels;
};

Expected<double> RelativeMeanAbsoluteError(const RgbImage& image, const RgbImage& reference);

/// Mean luminance of `image` divided by that of `reference`.
Expected<double> MeanLuminanceRatio(const RgbImage& image, const RgbImage& reference);

/// Each pixel the mean of the (2 radius + 1)^2 pixels around it, clamped
/// to the image at its borders. radius 0: a copy.
RgbImage BoxBlur(const RgbImage& image, int radius);

/// Display luma in [0, 1] of every pixel: Drago with `view`, then sRGB.
std::vector<float> DisplayLuma(const RgbImage& image, const ViewLuminance& view, const DragoParams& params);

/// SSIM of two single-channel images of the same size (values in [0, 1]).
Expected<double> Ssim(std::span<const float> a, std::span<const float> b, int width, int height);

/// SSIM of `image` against `reference` as described above.
Expected<double> ToneMappedSsim(const RgbImage& image, const RgbImage& reference, const DragoParams& params = {});

}  // namespace penumbra

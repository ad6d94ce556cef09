// penumbra-image-tool: the image side of experiments.
//
//   penumbra-image-tool compare REFERENCE.exr IMAGE.exr
//       One JSON line: {"rel_mae": .., "ssim": ..} (common/image_metrics.h).
//   penumbra-image-tool tonemap IN.exr OUT.png [--like REFERENCE.exr] [--exposure STOPS]
//       Drago 2003 (common/tonemap.h) with the luminance statistics of
//       REFERENCE (default: of IN itself), so that every image of one view
//       is mapped identically, then sRGB.
//
// Exit codes: 0 ok, 1 bad input (one line on stderr), 2 bad usage.

#include <cmath>
#include <cstdio>
#include <string>

#include <CLI/CLI.hpp>

#include "penumbra/common/image_io.h"
#include "penumbra/common/image_metrics.h"
#include "penumbra/common/logging.h"
#include "penumbra/common/tonemap.h"

namespace penumbra {
namespace {

Expected<RgbImage> Load(const std::string& path) {
  auto image = ReadImage(path);
  if (!image) return image.error();
  RgbImage out{image->width, image->height, {}};
  out.pixels.reserve(size_t(image->width) * size_t(image->height));
  for (size_t i = 0; i + 2 < image->rgb.size(); i += 3)
    out.pixels.push_back(Rgb(image->rgb[i], image->rgb[i + 1], image->rgb[i + 2]));
  return out;
}

int Compare(const std::string& referencePath, const std::string& imagePath) {
  auto reference = Load(referencePath);
  auto image = Load(imagePath);
  if (!reference || !image) {
    std::fprintf(stderr, "penumbra-image-tool: %s\n", (!reference ? reference : image).error().message.c_str());
    return 1;
  }
  auto mae = RelativeMeanAbsoluteError(*image, *reference);
  auto ssim = ToneMappedSsim(*image, *reference);
  if (!mae || !ssim) {
    std::fprintf(stderr, "penumbra-image-tool: %s\n", (!mae ? mae.error() : ssim.error()).message.c_str());
    return 1;
  }
  std::printf("{\"rel_mae\": %.6f, \"ssim\": %.6f}\n", *mae, *ssim);
  return 0;
}

int ToneMap(const std::string& in, const std::string& out, const std::string& like, float exposureStops) {
  auto image = Load(in);
  if (!image) {
    std::fprintf(stderr, "penumbra-image-tool: %s\n", image.error().message.c_str());
    return 1;
  }
  ViewLuminance view = MeasureLuminance(image->pixels);
  if (!like.empty()) {
    auto reference = Load(like);
    if (!reference) {
      std::fprintf(stderr, "penumbra-image-tool: %s\n", reference.error().message.c_str());
      return 1;
    }
    view = MeasureLuminance(reference->pixels);
  }
  DragoParams params;
  params.exposure = std::exp2(exposureStops);
  std::vector<float> rgb;
  rgb.reserve(image->pixels.size() * 3);
  for (const Rgb& p : image->pixels) {
    const Rgb mapped = ToneMapDrago(p, view, params);
    rgb.insert(rgb.end(), {mapped.r, mapped.g, mapped.b});
  }
  if (auto ok = WriteImage(out, image->width, image->height, rgb); !ok) {
    std::fprintf(stderr, "penumbra-image-tool: %s\n", ok.error().message.c_str());
    return 1;
  }
  return 0;
}

}  // namespace
}  // namespace penumbra

int main(int argc, char** argv) {
  CLI::App app{"penumbra-image-tool: compare images with a reference, tone-map EXR to PNG"};
  app.require_subcommand(1);
  std::string a, b, like;
  float exposure = 0.0f;
  auto* compare = app.add_subcommand("compare", "Relative MAE and tone-mapped SSIM of IMAGE against REFERENCE");
  compare->add_option("reference", a, "Reference image (linear EXR)")->required();
  compare->add_option("image", b, "Image to judge (linear EXR)")->required();
  auto* tonemap = app.add_subcommand("tonemap", "Drago-map a linear image to PNG");
  tonemap->add_option("in", a, "Linear image")->required();
  tonemap->add_option("out", b, "Output PNG")->required();
  tonemap->add_option("--like", like, "Map with this image's luminance statistics (e.g. the reference)");
  tonemap->add_option("--exposure", exposure, "Exposure in stops")->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  penumbra::SetupLogging("warn");
  if (*compare) return penumbra::Compare(a, b);
  return penumbra::ToneMap(a, b, like, exposure);
}

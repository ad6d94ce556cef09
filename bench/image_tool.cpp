// penumbra-image-tool: the image side of experiments.
//
//   penumbra-image-tool compare REFERENCE.exr IMAGE.exr [--blur R]
//       One JSON line: {"rel_mae": .., "ssim": .., "mean_ratio": ..}
//       (common/image_metrics.h), after a box blur of radius R of both
//       (default 0; 2 takes a noisy reference's noise out). With
//       --error-map OUT.png, also a picture of where the error is; with
//       --split F, also the figures over the dim pixels (reference at most F
//       times its mean luminance) and the bright ones, a line each.
//   penumbra-image-tool tonemap IN.exr OUT.png [--like REFERENCE.exr] [--exposure STOPS]
//       Drago 2003 (common/tonemap.h) with the luminance statistics of
//       REFERENCE (default: of IN itself), so that every image of one view
//       is mapped identically, then sRGB.
//   penumbra-image-tool check-cornell-box IMAGE.png
//       Whether IMAGE (the client's tone-mapped PNG of the Cornell box's
//       "front" preset) is a sane picture of it: lit, few black pixels, the
//       red wall on the left and the green wall on the right. One JSON line
//       with the figures; exit 1 when a check fails (scripts/run.sh
//       --headless-check).
//
// Exit codes: 0 ok, 1 bad input (one line on stderr), 2 bad usage.

#include <cmath>
#include <cstdio>
#include <iostream>
#include <sstream>
#include <algorithm>
#include <string>
#include <vector>

#include <fmt/format.h>

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

// Where the relative MAE comes from: each pixel's |image - reference|
// (summed over channels), over the mean per pixel of the reference's sum,
// red where the image is brighter, blue where darker; full at 1 (a pixel off
// by as much as the average pixel). The relative MAE is this map's mean.
Status WriteErrorMap(const std::string& path, const RgbImage& image, const RgbImage& reference) {
  double total = 0.0;
  for (const Rgb& p : reference.pixels) total += double(p.r) + double(p.g) + double(p.b);
  const double meanPixel = total / double(std::max<size_t>(1, reference.pixels.size()));
  std::vector<float> rgb;
  rgb.reserve(image.pixels.size() * 3);
  for (size_t i = 0; i < image.pixels.size(); ++i) {
    const Rgb& a = image.pixels[i];
    const Rgb& b = reference.pixels[i];
    const double error = std::abs(a.r - b.r) + std::abs(a.g - b.g) + std::abs(a.b - b.b);
    const float v = meanPixel > 0.0 ? float(std::min(1.0, error / meanPixel)) : 0.0f;
    const bool brighter = Luminance(a) > Luminance(b);
    rgb.insert(rgb.end(), {brighter ? v : 0.0f, 0.0f, brighter ? 0.0f : v});
  }
  return WriteImage(path, image.width, image.height, rgb);
}

// The relative MAE restricted to the reference's pixels at most `factor`
// times its mean luminance ("dim": walls, furniture) and to the others
// ("bright": sun patches, windows, lights), with each part's share of the
// total error. A bright sun patch whose edge moves by a pixel outweighs a
// wall's blotches in the whole-image figure.
void PrintSplit(const RgbImage& image, const RgbImage& reference, double factor) {
  double meanLuminance = 0.0;
  for (const Rgb& p : reference.pixels) meanLuminance += Luminance(p);
  meanLuminance /= double(std::max<size_t>(1, reference.pixels.size()));
  double error[2] = {0.0, 0.0}, total[2] = {0.0, 0.0}, sum[2] = {0.0, 0.0}, refSum[2] = {0.0, 0.0};
  size_t count[2] = {0, 0};
  for (size_t i = 0; i < image.pixels.size(); ++i) {
    const Rgb& a = image.pixels[i];
    const Rgb& b = reference.pixels[i];
    const int part = Luminance(b) > factor * meanLuminance ? 1 : 0;
    for (int c = 0; c < 3; ++c) {
      error[part] += std::abs(double(a[c]) - double(b[c]));
      total[part] += std::abs(double(b[c]));
    }
    sum[part] += Luminance(a);
    refSum[part] += Luminance(b);
    ++count[part];
  }
  const double allError = error[0] + error[1];
  const char* names[2] = {"dim", "bright"};
  for (int part = 0; part < 2; ++part)
    std::printf("{\"part\": \"%s\", \"pixels\": %zu, \"rel_mae\": %.6f, \"mean_ratio\": %.6f, \"error_share\": %.4f}\n",
                names[part], count[part], total[part] > 0.0 ? error[part] / total[part] : 0.0,
                refSum[part] > 0.0 ? sum[part] / refSum[part] : 0.0, allError > 0.0 ? error[part] / allError : 0.0);
}

int Compare(const std::string& referencePath, const std::string& imagePath, int blur,
            const std::string& errorMap = {}, double split = 0.0) {
  auto reference = Load(referencePath);
  auto image = Load(imagePath);
  if (!reference || !image) {
    std::fprintf(stderr, "penumbra-image-tool: %s\n", (!reference ? reference : image).error().message.c_str());
    return 1;
  }
  const RgbImage a = BoxBlur(*image, blur), b = BoxBlur(*reference, blur);
  if (!errorMap.empty() && a.pixels.size() == b.pixels.size()) {
    if (auto ok = WriteErrorMap(errorMap, a, b); !ok) {
      std::fprintf(stderr, "penumbra-image-tool: %s\n", ok.error().message.c_str());
      return 1;
    }
  }
  auto mae = RelativeMeanAbsoluteError(a, b);
  auto ssim = ToneMappedSsim(a, b);
  auto ratio = MeanLuminanceRatio(a, b);
  if (!mae || !ssim || !ratio) {
    std::fprintf(stderr, "penumbra-image-tool: %s\n",
                 (!mae ? mae.error() : !ssim ? ssim.error() : ratio.error()).message.c_str());
    return 1;
  }
  std::printf("{\"rel_mae\": %.6f, \"ssim\": %.6f, \"mean_ratio\": %.6f}\n", *mae, *ssim, *ratio);
  if (split > 0.0) PrintSplit(a, b, split);
  return 0;
}

// compare-list: one "REFERENCE IMAGE BLUR" per line of stdin, one JSON line
// (Compare's, or {"error": ...}) per line on stdout, in order: a
// walkthrough judges thousands of frames, and a process each is slow.
int CompareList() {
  std::string line;
  while (std::getline(std::cin, line)) {
    std::istringstream words(line);
    std::string reference, image;
    int blur = 0;
    if (!(words >> reference >> image >> blur) || blur < 0 || blur > 64) {
      std::printf("{\"error\": \"expected REFERENCE IMAGE BLUR (0..64)\"}\n");
      continue;
    }
    if (Compare(reference, image, blur) != 0) std::printf("{\"error\": \"see stderr\"}\n");
    std::fflush(stdout);
  }
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

// Mean colour of the pixels in the column range [x0, x1) and row range [y0, y1),
// as fractions of the image size.
Rgb MeanOf(const RgbImage& image, float x0, float x1, float y0, float y1) {
  Rgb sum(0.0f);
  int n = 0;
  for (int y = int(y0 * image.height); y < int(y1 * image.height); ++y)
    for (int x = int(x0 * image.width); x < int(x1 * image.width); ++x, ++n)
      sum += image.pixels[size_t(y) * size_t(image.width) + size_t(x)];
  return n > 0 ? sum / float(n) : Rgb(0.0f);
}

int CheckCornellBox(const std::string& path) {
  auto image = Load(path);
  if (!image) {
    std::fprintf(stderr, "penumbra-image-tool: %s\n", image.error().message.c_str());
    return 1;
  }
  if (image->width < 16 || image->height < 16) {
    std::fprintf(stderr, "penumbra-image-tool: %s: %dx%d is too small to judge\n", path.c_str(), image->width,
                 image->height);
    return 1;
  }
  size_t black = 0;
  Rgb mean(0.0f);
  for (const Rgb& p : image->pixels) {
    black += std::max({p.r, p.g, p.b}) <= 1.0f / 255.0f;
    mean += p;
  }
  mean /= float(image->pixels.size());
  const float blackFraction = float(black) / float(image->pixels.size());
  // The side walls, at mid height: in the front preset the box spans about
  // 14 % to 86 % of the width, the side walls its outer sixths.
  const Rgb left = MeanOf(*image, 0.17f, 0.25f, 0.35f, 0.65f);
  const Rgb right = MeanOf(*image, 0.75f, 0.83f, 0.35f, 0.65f);
  const Rgb centre = MeanOf(*image, 0.4f, 0.6f, 0.4f, 0.6f);
  std::vector<std::string> problems;
  if (blackFraction > 0.05f) problems.push_back(fmt::format("{:.1f} % of the pixels are black", 100 * blackFraction));
  if (!(Luminance(mean) >= 0.05f && Luminance(centre) >= 0.05f))
    problems.push_back(fmt::format("the image is dark (mean luminance {:.3f}, centre {:.3f})", Luminance(mean),
                                   Luminance(centre)));
  if (!(left.r > 1.25f * left.g && left.r > 1.25f * left.b)) problems.push_back("the left wall is not red");
  if (!(right.g > 1.25f * right.r && right.g > 1.25f * right.b)) problems.push_back("the right wall is not green");
  std::printf("{\"black_fraction\": %.4f, \"mean\": [%.4f, %.4f, %.4f], \"left_wall\": [%.4f, %.4f, %.4f], "
              "\"right_wall\": [%.4f, %.4f, %.4f], \"sane\": %s}\n",
              blackFraction, mean.r, mean.g, mean.b, left.r, left.g, left.b, right.r, right.g, right.b,
              problems.empty() ? "true" : "false");
  for (const std::string& p : problems) std::fprintf(stderr, "penumbra-image-tool: %s: %s\n", path.c_str(), p.c_str());
  return problems.empty() ? 0 : 1;
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
  int blur = 0;
  compare->add_option("--blur", blur, "Box-blur both by this radius first (2: a 5x5 window)")
      ->check(CLI::Range(0, 64))->capture_default_str();
  std::string errorMap;
  compare->add_option("--error-map", errorMap,
                      "Also write where the error is (PNG: red brighter, blue darker than the reference; full at the "
                      "mean pixel)");
  double split = 0.0;
  compare->add_option("--split", split,
                      "Also the figures over the reference's pixels at most this many times its mean luminance "
                      "and over the rest, one JSON line each")
      ->check(CLI::Range(0.0, 1e6));
  auto* compareList = app.add_subcommand(
      "compare-list", "compare for each line 'REFERENCE IMAGE BLUR' of stdin; one JSON line each on stdout");
  auto* tonemap = app.add_subcommand("tonemap", "Drago-map a linear image to PNG");
  tonemap->add_option("in", a, "Linear image")->required();
  tonemap->add_option("out", b, "Output PNG")->required();
  tonemap->add_option("--like", like, "Map with this image's luminance statistics (e.g. the reference)");
  tonemap->add_option("--exposure", exposure, "Exposure in stops")->capture_default_str();
  auto* cornell = app.add_subcommand("check-cornell-box", "Whether IMAGE is a sane render of the Cornell box's front view");
  cornell->add_option("image", a, "Tone-mapped PNG of the front preset")->required();
  CLI11_PARSE(app, argc, argv);
  penumbra::SetupLogging("warn");
  if (*compare) return penumbra::Compare(a, b, blur, errorMap, split);
  if (*compareList) return penumbra::CompareList();
  if (*cornell) return penumbra::CheckCornellBox(a);
  return penumbra::ToneMap(a, b, like, exposure);
}

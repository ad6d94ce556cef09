#include "penumbra/common/image_metrics.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>

namespace penumbra {

namespace {

Status SameSize(const RgbImage& a, const RgbImage& b) {
  if (a.width != b.width || a.height != b.height || a.pixels.size() != size_t(a.width) * size_t(a.height) ||
      b.pixels.size() != a.pixels.size())
    return Fail(fmt::format("images differ in size: {}x{} and {}x{}", a.width, a.height, b.width, b.height));
  if (a.pixels.empty()) return Fail("empty image");
  return Status::Ok();
}

// Separable 11-tap Gaussian blur, sigma 1.5, edges clamped.
std::vector<double> Blur(const std::vector<double>& in, int w, int h) {
  constexpr int kRadius = 5;
  double kernel[2 * kRadius + 1];
  double sum = 0.0;
  for (int i = -kRadius; i <= kRadius; ++i) sum += kernel[i + kRadius] = std::exp(-double(i * i) / (2.0 * 1.5 * 1.5));
  for (double& k : kernel) k /= sum;
  std::vector<double> tmp(in.size()), out(in.size());
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      double v = 0.0;
      for (int i = -kRadius; i <= kRadius; ++i) v += kernel[i + kRadius] * in[size_t(y) * size_t(w) + size_t(std::clamp(x + i, 0, w - 1))];
      tmp[size_t(y) * size_t(w) + size_t(x)] = v;
    }
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      double v = 0.0;
      for (int i = -kRadius; i <= kRadius; ++i) v += kernel[i + kRadius] * tmp[size_t(std::clamp(y + i, 0, h - 1)) * size_t(w) + size_t(x)];
      out[size_t(y) * size_t(w) + size_t(x)] = v;
    }
  return out;
}

}  // namespace

Expected<double> RelativeMeanAbsoluteError(const RgbImage& image, const RgbImage& reference) {
  if (auto ok = SameSize(image, reference); !ok) return ok.error();
  double error = 0.0, total = 0.0;
  for (size_t i = 0; i < image.pixels.size(); ++i)
    for (int c = 0; c < 3; ++c) {
      error += std::abs(double(image.pixels[i][c]) - double(reference.pixels[i][c]));
      total += std::abs(double(reference.pixels[i][c]));
    }
  if (!(total > 0.0)) return Fail("the reference is black");
  return error / total;
}

Expected<double> MeanLuminanceRatio(const RgbImage& image, const RgbImage& reference) {
  if (auto ok = SameSize(image, reference); !ok) return ok.error();
  double a = 0.0, b = 0.0;
  for (size_t i = 0; i < image.pixels.size(); ++i) {
    a += Luminance(image.pixels[i]);
    b += Luminance(reference.pixels[i]);
  }
  if (!(b > 0.0)) return Fail("the reference is black");
  return a / b;
}

RgbImage BoxBlur(const RgbImage& image, int radius) {
  if (radius <= 0 || image.pixels.empty()) return image;
  const int w = image.width, h = image.height;
  // Separable: rows, then columns, each a running window clamped at the borders.
  const auto pass = [radius](const std::vector<Rgb>& in, int n, int lines, bool alongRows) {
    std::vector<Rgb> out(in.size());
    for (int line = 0; line < lines; ++line) {
      const auto at = [&](int k) -> const Rgb& {
        k = std::clamp(k, 0, n - 1);
        return in[alongRows ? size_t(line) * size_t(n) + size_t(k) : size_t(k) * size_t(lines) + size_t(line)];
      };
      for (int k = 0; k < n; ++k) {
        Rgb sum(0.0f);
        for (int d = -radius; d <= radius; ++d) sum += at(k + d);
        out[alongRows ? size_t(line) * size_t(n) + size_t(k) : size_t(k) * size_t(lines) + size_t(line)] =
            sum / float(2 * radius + 1);
      }
    }
    return out;
  };
  RgbImage out{w, h, pass(image.pixels, w, h, true)};
  out.pixels = pass(out.pixels, h, w, false);
  return out;
}

std::vector<float> DisplayLuma(const RgbImage& image, const ViewLuminance& view, const DragoParams& params) {
  std::vector<float> luma(image.pixels.size());
  for (size_t i = 0; i < image.pixels.size(); ++i) {
    const Rgb mapped = ToneMapDrago(image.pixels[i], view, params);
    luma[i] = 0.2126f * LinearToSrgb(mapped.r) + 0.7152f * LinearToSrgb(mapped.g) + 0.0722f * LinearToSrgb(mapped.b);
  }
  return luma;
}

Expected<double> Ssim(std::span<const float> a, std::span<const float> b, int width, int height) {
  const size_t n = size_t(width) * size_t(height);
  if (a.size() != n || b.size() != n || n == 0) return Fail("SSIM needs two images of the given size");
  std::vector<double> x(a.begin(), a.end()), y(b.begin(), b.end()), xx(n), yy(n), xy(n);
  for (size_t i = 0; i < n; ++i) {
    xx[i] = x[i] * x[i];
    yy[i] = y[i] * y[i];
    xy[i] = x[i] * y[i];
  }
  const auto mx = Blur(x, width, height), my = Blur(y, width, height);
  const auto sxx = Blur(xx, width, height), syy = Blur(yy, width, height), sxy = Blur(xy, width, height);
  constexpr double c1 = 0.01 * 0.01, c2 = 0.03 * 0.03;
  double sum = 0.0;
  for (size_t i = 0; i < n; ++i) {
    const double vx = sxx[i] - mx[i] * mx[i], vy = syy[i] - my[i] * my[i], cxy = sxy[i] - mx[i] * my[i];
    sum += ((2.0 * mx[i] * my[i] + c1) * (2.0 * cxy + c2)) / ((mx[i] * mx[i] + my[i] * my[i] + c1) * (vx + vy + c2));
  }
  return sum / double(n);
}

Expected<double> ToneMappedSsim(const RgbImage& image, const RgbImage& reference, const DragoParams& params) {
  if (auto ok = SameSize(image, reference); !ok) return ok.error();
  const ViewLuminance view = MeasureLuminance(reference.pixels);
  const auto a = DisplayLuma(image, view, params);
  const auto b = DisplayLuma(reference, view, params);
  return Ssim(a, b, image.width, image.height);
}

}  // namespace penumbra

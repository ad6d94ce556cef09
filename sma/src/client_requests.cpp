#include "penumbra/sma/client_requests.h"

#include <algorithm>
#include <cmath>
#include <string>

#include <fmt/format.h>

#include "penumbra/common/math.h"

namespace penumbra::sma {

namespace {
Vec3 FromWire(const wire::Vec3& v) { return Vec3(v.x(), v.y(), v.z()); }
}  // namespace

Expected<CameraView> ViewFromWire(const wire::View& v, uint64_t maxViewPixels) {
  CameraView view;
  view.pose = CameraPose{FromWire(v.eye()), FromWire(v.target()), FromWire(v.up())};
  view.fovYDeg = v.fov_y_deg();
  view.width = int(std::min<uint32_t>(v.width(), 1u << 30));
  view.height = int(std::min<uint32_t>(v.height(), 1u << 30));
  if (auto ok = ValidateCameraView(view); !ok) return Fail(fmt::format("view {}: {}", v.view_id(), ok.error().message));
  // Visibility costs time and memory per pixel (a 16384^2 view took 4.2 GiB).
  if (uint64_t(view.width) * uint64_t(view.height) > maxViewPixels)
    return Fail(fmt::format("view {}: {}x{} pixels; this SMA serves at most {} per view", v.view_id(), view.width,
                            view.height, maxViewPixels));
  return view;
}

Expected<RefinementParams> ApplySessionOptions(const RefinementParams& current, const wire::SessionOptions& o) {
  RefinementParams p = current;
  if (!o.criterion().empty()) {
    auto c = ParseCriterion(o.criterion());
    if (!c) return c.error();
    p.criterion = *c;
  }
  if (o.has_s_req()) p.sReq = o.s_req();
  if (o.has_batch()) p.batch = o.batch();
  if (o.has_min_pixels()) p.minPixels = o.min_pixels();
  if (o.has_large_fraction()) p.largeFraction = o.large_fraction();
  if (o.has_aspect_threshold()) p.aspectThreshold = o.aspect_threshold();
  if (o.has_pixel_fraction()) p.pixelFraction = o.pixel_fraction();
  if (o.has_noise_z()) p.noiseZ = o.noise_z();
  if (o.has_max_depth()) p.maxDepth = uint8_t(std::clamp<uint32_t>(o.max_depth(), 0, 255));
  if (o.has_max_depth() && o.max_depth() > 20)
    return Fail(fmt::format("session options: max_depth = {} is out of range", o.max_depth()));
  if (auto ok = p.Validate(); !ok) return Fail("session options: " + ok.error().message);
  return p;
}

Status CheckTextureRequest(const wire::TextureRequest& request, size_t textureCount) {
  if (request.texture() >= textureCount)
    return Fail(fmt::format("texture {} does not exist ({} textures)", request.texture(), textureCount));
  return Status::Ok();
}

wire::TextureData DownscaledTexture(const Texture& t, uint32_t index, size_t budgetBytes) {
  // Halve until the texels fit in the budget.
  int step = 1;
  while (size_t(t.width / step) * size_t(t.height / step) * 3 > budgetBytes && step < 1 << 12) step *= 2;
  const int w = std::max(1, t.width / step), h = std::max(1, t.height / step);
  std::string rgb(size_t(w) * size_t(h) * 3, '\0');
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      // Box-filter the step x step block in linear space.
      Rgb sum(0.0f);
      for (int dy = 0; dy < step; ++dy)
        for (int dx = 0; dx < step; ++dx)
          sum += t.texels[size_t(std::min(t.height - 1, y * step + dy)) * size_t(t.width) +
                          size_t(std::min(t.width - 1, x * step + dx))];
      sum /= float(step * step);
      for (int c = 0; c < 3; ++c)
        rgb[(size_t(y) * size_t(w) + size_t(x)) * 3 + size_t(c)] = char(std::lround(LinearToSrgb(sum[c]) * 255.0f));
    }
  wire::TextureData data;
  data.set_texture(index);
  data.set_width(uint32_t(w));
  data.set_height(uint32_t(h));
  data.set_rgb8(std::move(rgb));
  return data;
}

}  // namespace penumbra::sma

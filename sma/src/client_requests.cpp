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

}  // namespace penumbra::sma

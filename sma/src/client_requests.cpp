#include "penumbra/sma/client_requests.h"

#include <algorithm>
#include <cmath>
#include <string>

#include <fmt/format.h>

#include "penumbra/common/math.h"
#include "penumbra/common/wire_convert.h"

namespace penumbra::sma {

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

Status CheckTextureRequest(const wire::TextureRequest& request, size_t textureCount) {
  if (request.texture() >= textureCount)
    return Fail(fmt::format("texture {} does not exist ({} textures)", request.texture(), textureCount));
  return Status::Ok();
}

}  // namespace penumbra::sma

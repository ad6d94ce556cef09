#include "penumbra/client/texture_filtering.h"

#include <algorithm>
#include <array>
#include <cctype>
#include <string>

namespace penumbra::client {

bool IsSoftwareRasterizer(std::string_view glRenderer) {
  std::string lower(glRenderer);
  std::transform(lower.begin(), lower.end(), lower.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  constexpr std::array<std::string_view, 4> kSoftware = {"llvmpipe", "softpipe", "swrast", "swiftshader"};
  return std::any_of(kSoftware.begin(), kSoftware.end(),
                     [&](std::string_view name) { return lower.find(name) != std::string::npos; });
}

float ChooseAnisotropy(std::optional<float> requested, std::string_view glRenderer, float implementationMax) {
  constexpr float kGpuDefault = 16.0f;
  const float wanted = requested ? *requested : (IsSoftwareRasterizer(glRenderer) ? 1.0f : kGpuDefault);
  return std::max(1.0f, std::min(wanted, std::max(implementationMax, 1.0f)));
}

}  // namespace penumbra::client

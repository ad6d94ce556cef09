#pragma once
// Small vector-math vocabulary on top of GLM. Colours are linear RGB in
// glm::vec3; directions are unit vectors unless a name says otherwise.

#include <glm/geometric.hpp>
#include <glm/vec2.hpp>
#include <glm/vec3.hpp>

#include <algorithm>
#include <cmath>
#include <limits>

namespace penumbra {

using Vec2 = glm::vec2;
using Vec3 = glm::vec3;
using Rgb = glm::vec3;  // linear RGB radiance, irradiance or albedo

inline constexpr float kPi = 3.14159265358979323846f;
inline constexpr float kInvPi = 1.0f / kPi;

/// Rec. 709 / sRGB-primaries luminance of a linear RGB value.
inline float Luminance(const Rgb& c) { return 0.2126f * c.r + 0.7152f * c.g + 0.0722f * c.b; }

inline bool IsFinite(const Vec3& v) {
  return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z);
}

/// sRGB transfer function, decoding an encoded value in [0,1] to linear.
inline float SrgbToLinear(float c) {
  return c <= 0.04045f ? c / 12.92f : std::pow((c + 0.055f) / 1.055f, 2.4f);
}
inline float LinearToSrgb(float c) {
  c = std::clamp(c, 0.0f, 1.0f);
  return c <= 0.0031308f ? 12.92f * c : 1.055f * std::pow(c, 1.0f / 2.4f) - 0.055f;
}

/// Axis-aligned bounding box; empty when min > max.
struct Bounds3 {
  Vec3 min{std::numeric_limits<float>::max()};
  Vec3 max{-std::numeric_limits<float>::max()};

  void Extend(const Vec3& p) {
    min = glm::min(min, p);
    max = glm::max(max, p);
  }
  bool Empty() const { return min.x > max.x; }
  Vec3 Diagonal() const { return Empty() ? Vec3(0) : max - min; }
  Vec3 Center() const { return 0.5f * (min + max); }
};

/// Orthonormal basis with `n` as local z (Duff et al. 2017, branchless).
struct Frame {
  Vec3 s, t, n;

  static Frame FromNormal(const Vec3& n) {
    const float sign = std::copysign(1.0f, n.z);
    const float a = -1.0f / (sign + n.z);
    const float b = n.x * n.y * a;
    return Frame{Vec3(1.0f + sign * n.x * n.x * a, sign * b, -sign * n.x),
                 Vec3(b, sign + n.y * n.y * a, -n.y), n};
  }
  Vec3 ToWorld(const Vec3& local) const { return local.x * s + local.y * t + local.z * n; }
  Vec3 ToLocal(const Vec3& world) const {
    return Vec3(glm::dot(world, s), glm::dot(world, t), glm::dot(world, n));
  }
};

}  // namespace penumbra

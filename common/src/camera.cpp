#include "penumbra/common/camera.h"

#include <cmath>
#include <fstream>
#include <sstream>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

namespace penumbra {

Status ValidateCameraView(const CameraView& v) {
  const auto& p = v.pose;
  if (!IsFinite(p.eye) || !IsFinite(p.target) || !IsFinite(p.up))
    return Fail("camera eye, target and up must be finite");
  // Embree's ray origins must stay well inside float range (it asserts on
  // larger ones), and eye - target must not overflow to infinity.
  for (const Vec3* point : {&p.eye, &p.target})
    for (int axis = 0; axis < 3; ++axis)
      if (!(std::abs((*point)[axis]) <= kMaxCameraCoordinate))
        return Fail(fmt::format("camera eye and target coordinates must lie within +-{:g}", kMaxCameraCoordinate));
  for (int axis = 0; axis < 3; ++axis)
    if (!(std::abs(p.up[axis]) <= kMaxCameraCoordinate))
      return Fail(fmt::format("camera up coordinates must lie within +-{:g}", kMaxCameraCoordinate));
  const Vec3 forward = p.target - p.eye;
  if (glm::length(forward) <= 0.0f) return Fail("camera eye and target coincide");
  if (glm::length(p.up) <= 0.0f) return Fail("camera up is the zero vector");
  if (glm::length(glm::cross(glm::normalize(forward), glm::normalize(p.up))) < 1e-4f)
    return Fail("camera up is parallel to the view direction");
  if (!(v.fovYDeg >= 1.0f && v.fovYDeg <= 179.0f))
    return Fail(fmt::format("vertical field of view {} is outside [1, 179] degrees", v.fovYDeg));
  if (v.width < 1 || v.height < 1 || v.width > 16384 || v.height > 16384)
    return Fail(fmt::format("viewport {}x{} is outside 1..16384 pixels per side", v.width, v.height));
  return Status::Ok();
}

PinholeCamera::PinholeCamera(const CameraView& view)
    : origin_(view.pose.eye),
      forward_(glm::normalize(view.pose.target - view.pose.eye)),
      right_(glm::normalize(glm::cross(forward_, view.pose.up))),
      up_(glm::cross(right_, forward_)),
      tanHalfFovY_(std::tan(0.5f * view.fovYDeg * kPi / 180.0f)),
      aspect_(float(view.width) / float(view.height)),
      width_(view.width),
      height_(view.height) {}

Vec3 PinholeCamera::DirectionThrough(float px, float py) const {
  const float sx = (2.0f * px / float(width_) - 1.0f) * tanHalfFovY_ * aspect_;
  const float sy = (1.0f - 2.0f * py / float(height_)) * tanHalfFovY_;
  return glm::normalize(forward_ + sx * right_ + sy * up_);
}

std::optional<Vec2> PinholeCamera::PixelOf(const Vec3& p) const {
  const Vec3 d = p - origin_;
  const float depth = glm::dot(d, forward_);
  if (!(depth > 0.0f)) return std::nullopt;
  const float sx = glm::dot(d, right_) / depth, sy = glm::dot(d, up_) / depth;
  return Vec2(0.5f * float(width_) * (sx / (tanHalfFovY_ * aspect_) + 1.0f),
              0.5f * float(height_) * (1.0f - sy / tanHalfFovY_));
}

double CameraPath::DurationSeconds() const {
  return keyframes.empty() ? 0.0 : keyframes.back().timeSeconds - keyframes.front().timeSeconds;
}

CameraPose CameraPath::PoseAt(double t) const {
  if (keyframes.size() == 1 || t <= keyframes.front().timeSeconds) return keyframes.front().pose;
  if (t >= keyframes.back().timeSeconds) return keyframes.back().pose;
  size_t i = 1;
  while (keyframes[i].timeSeconds < t) ++i;
  const auto& a = keyframes[i - 1];
  const auto& b = keyframes[i];
  // A stop (two equal keyframes) gives exactly their pose: a mix of equal
  // values can differ from them in the last bit, and a client would then send
  // a "new" view every frame of the stop.
  if (a.pose.eye == b.pose.eye && a.pose.target == b.pose.target && a.pose.up == b.pose.up) return a.pose;
  const double span = b.timeSeconds - a.timeSeconds;
  const float s = span > 0.0 ? float((t - a.timeSeconds) / span) : 1.0f;
  CameraPose pose;
  pose.eye = glm::mix(a.pose.eye, b.pose.eye, s);
  pose.target = glm::mix(a.pose.target, b.pose.target, s);
  pose.up = glm::mix(a.pose.up, b.pose.up, s);
  // Looking along up (or nearly: 10x the validation's margin): up from the
  // keyframes' right vectors instead, which are perpendicular to their own
  // views and so, near a crossing of the vertical, to this one's too. The
  // street walk's path crossed it at 472.12 s and the SMA refused the view.
  const Vec3 forward = glm::normalize(pose.target - pose.eye);
  if (glm::length(glm::cross(forward, glm::normalize(pose.up))) < 1e-3f) {
    for (const CameraPose* k : {&a.pose, &b.pose}) {
      const Vec3 right = glm::cross(glm::normalize(k->target - k->eye), glm::normalize(k->up));
      const Vec3 up = glm::cross(right, forward);
      if (glm::length(up) > 1e-2f) {
        pose.up = glm::normalize(up);
        return pose;
      }
    }
    // Both keyframes' right vectors lie along this view: any perpendicular.
    const Vec3 axis = std::abs(forward.x) < 0.9f ? Vec3(1.0f, 0.0f, 0.0f) : Vec3(0.0f, 0.0f, 1.0f);
    pose.up = glm::normalize(glm::cross(glm::cross(forward, axis), forward));
  }
  return pose;
}

CameraView CameraPath::ViewAt(double t) const {
  CameraView view;
  view.pose = PoseAt(t);
  view.fovYDeg = fovYDeg;
  view.width = width;
  view.height = height;
  return view;
}

namespace {

using Json = nlohmann::json;

Expected<Vec3> ReadVec3(const Json& parent, const char* key, std::string_view where, bool required,
                        Vec3 fallback = Vec3(0.0f)) {
  if (!parent.contains(key)) {
    if (required) return Fail(fmt::format("{}: missing \"{}\"", where, key));
    return fallback;
  }
  const Json& v = parent.at(key);
  if (!v.is_array() || v.size() != 3 || !v[0].is_number() || !v[1].is_number() || !v[2].is_number())
    return Fail(fmt::format("{}: \"{}\" must be an array of 3 numbers", where, key));
  const Vec3 out(v[0].get<float>(), v[1].get<float>(), v[2].get<float>());
  if (!IsFinite(out)) return Fail(fmt::format("{}: \"{}\" is not finite", where, key));
  return out;
}

}  // namespace

Expected<CameraPath> ParseCameraPathJson(std::string_view text, std::string_view sourceName) {
  Json doc = Json::parse(text.begin(), text.end(), nullptr, /*allow_exceptions=*/false);
  if (doc.is_discarded()) return Fail(fmt::format("{}: not valid JSON", sourceName));
  if (!doc.is_object()) return Fail(fmt::format("{}: a camera path must be a JSON object", sourceName));
  CameraPath path;
  auto number = [&](const char* key, double fallback) -> Expected<double> {
    if (!doc.contains(key)) return fallback;
    if (!doc[key].is_number()) return Fail(fmt::format("{}: \"{}\" must be a number", sourceName, key));
    return doc[key].get<double>();
  };
  auto fov = number("fov_y_deg", 45.0);
  if (!fov) return fov.error();
  auto width = number("width", 640);
  if (!width) return width.error();
  auto height = number("height", 480);
  if (!height) return height.error();
  path.fovYDeg = float(*fov);
  path.width = int(*width);
  path.height = int(*height);
  if (doc.contains("name") && doc["name"].is_string()) path.name = doc["name"].get<std::string>();
  if (!doc.contains("keyframes") || !doc["keyframes"].is_array() || doc["keyframes"].empty())
    return Fail(fmt::format("{}: \"keyframes\" must be a non-empty array", sourceName));
  for (size_t i = 0; i < doc["keyframes"].size(); ++i) {
    const Json& k = doc["keyframes"][i];
    const std::string where = fmt::format("{}: keyframe {}", sourceName, i);
    if (!k.is_object()) return Fail(fmt::format("{} must be an object", where));
    CameraKeyframe key;
    if (k.contains("t")) {
      if (!k["t"].is_number()) return Fail(fmt::format("{}: \"t\" must be a number", where));
      key.timeSeconds = k["t"].get<double>();
    } else if (i > 0) {
      return Fail(fmt::format("{}: missing \"t\"", where));
    }
    auto eye = ReadVec3(k, "eye", where, true);
    if (!eye) return eye.error();
    auto target = ReadVec3(k, "target", where, true);
    if (!target) return target.error();
    auto up = ReadVec3(k, "up", where, false, Vec3(0.0f, 1.0f, 0.0f));
    if (!up) return up.error();
    key.pose = CameraPose{*eye, *target, *up};
    if (!std::isfinite(key.timeSeconds) ||
        (!path.keyframes.empty() && key.timeSeconds < path.keyframes.back().timeSeconds))
      return Fail(fmt::format("{}: times must be finite and non-decreasing", where));
    path.keyframes.push_back(key);
  }
  for (size_t i = 0; i < path.keyframes.size(); ++i) {
    if (auto ok = ValidateCameraView(path.ViewAt(path.keyframes[i].timeSeconds)); !ok)
      return Fail(fmt::format("{}: keyframe {}: {}", sourceName, i, ok.error().message));
  }
  return path;
}

Expected<CameraPath> LoadCameraPath(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return Fail(fmt::format("{}: cannot open camera path file", path.string()));
  std::ostringstream text;
  text << in.rdbuf();
  auto parsed = ParseCameraPathJson(text.str(), path.string());
  if (parsed && parsed->name.empty()) parsed->name = path.stem().string();
  return parsed;
}

}  // namespace penumbra

#include "scene_file.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <fstream>
#include <initializer_list>
#include <limits>
#include <sstream>
#include <string_view>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "io_util.h"

namespace penumbra {
namespace {

namespace fs = std::filesystem;
// Ordered, so that cameras and paths keep the order of the file: the first
// camera is the scene's default view.
using Json = nlohmann::ordered_json;

constexpr float kDegToRad = kPi / 180.0f;

Expected<std::string> ReadTextFile(const fs::path& path) {
  if (auto ok = io::CheckRegularFile(path); !ok) return ok.error();
  std::ifstream in(path, std::ios::binary);
  std::ostringstream text;
  text << in.rdbuf();
  if (!in) return Fail(fmt::format("{}: cannot read the file", path.string()));
  return text.str();
}

Expected<Json> ParseJson(const std::string& text, const std::string& fileName) {
  try {
    return Json::parse(text);
  } catch (const Json::exception& e) {
    // e.what() gives the line and column.
    return Fail(fmt::format("{}: not valid JSON: {}", fileName, io::OneLine(e.what())));
  }
}

// Reads typed, validated values out of one scene file's JSON; every error
// message starts with the file name and the position in the document
// ("scene.json: sun: ...").
class JsonReader {
 public:
  explicit JsonReader(std::string fileName) : fileName_(std::move(fileName)) {}

  Error Problem(std::string_view context, std::string_view what) const {
    return context.empty() ? Fail(fmt::format("{}: {}", fileName_, what))
                           : Fail(fmt::format("{}: {}: {}", fileName_, context, what));
  }

  /// Unknown keys are errors, so that a typo is not silently ignored.
  Status CheckKeys(const Json& object, std::string_view context,
                   std::initializer_list<std::string_view> allowed) const {
    for (const auto& item : object.items()) {
      if (std::find(allowed.begin(), allowed.end(), item.key()) == allowed.end())
        return Problem(context, fmt::format("unknown key \"{}\" (expected one of: {})", item.key(),
                                            fmt::join(allowed, ", ")));
    }
    return Status::Ok();
  }

  Expected<const Json*> Object(const Json& parent, std::string_view context, const char* key) const {
    const Json& value = parent.at(key);
    if (!value.is_object()) return Problem(context, fmt::format("\"{}\" must be an object", key));
    return &value;
  }

  Expected<std::string> String(const Json& parent, std::string_view context, const char* key) const {
    if (!parent.contains(key)) return Problem(context, fmt::format("missing \"{}\"", key));
    const Json& value = parent.at(key);
    if (!value.is_string() || value.get_ref<const std::string&>().empty())
      return Problem(context, fmt::format("\"{}\" must be a non-empty string", key));
    return value.get<std::string>();
  }

  /// A finite number in [min, max]; `fallback` when the key is absent.
  Expected<float> Number(const Json& parent, std::string_view context, const char* key, float min, float max,
                         std::optional<float> fallback = std::nullopt) const {
    if (!parent.contains(key)) {
      if (fallback) return *fallback;
      return Problem(context, fmt::format("missing \"{}\"", key));
    }
    const Json& value = parent.at(key);
    const float x = value.is_number() ? value.get<float>() : NAN;
    if (!(std::isfinite(x) && x >= min && x <= max))
      return Problem(context, fmt::format("\"{}\" must be a number in [{}, {}]", key, min, max));
    return x;
  }

  /// Three finite numbers; `fallback` when the key is absent.
  Expected<Vec3> Vector(const Json& parent, std::string_view context, const char* key,
                        std::optional<Vec3> fallback = std::nullopt) const {
    if (!parent.contains(key)) {
      if (fallback) return *fallback;
      return Problem(context, fmt::format("missing \"{}\"", key));
    }
    const Json& value = parent.at(key);
    Vec3 v(NAN);
    if (value.is_array() && value.size() == 3 && value[0].is_number() && value[1].is_number() &&
        value[2].is_number())
      v = Vec3(value[0].get<float>(), value[1].get<float>(), value[2].get<float>());
    if (!IsFinite(v)) return Problem(context, fmt::format("\"{}\" must be an array of 3 finite numbers", key));
    return v;
  }

  /// A non-zero direction (not normalised).
  Expected<Vec3> Direction(const Json& parent, std::string_view context, const char* key,
                           std::optional<Vec3> fallback = std::nullopt) const {
    auto v = Vector(parent, context, key, fallback);
    if (v && glm::length(*v) == 0.0f) return Problem(context, fmt::format("\"{}\" must not be zero", key));
    return v;
  }

  /// Three finite numbers >= 0 (radiance, irradiance, emission).
  Expected<Rgb> NonNegativeRgb(const Json& parent, std::string_view context, const char* key,
                               float max = std::numeric_limits<float>::max()) const {
    auto v = Vector(parent, context, key);
    if (v && !(glm::all(glm::greaterThanEqual(*v, Rgb(0.0f))) && glm::all(glm::lessThanEqual(*v, Rgb(max)))))
      return Problem(context, max < std::numeric_limits<float>::max()
                                  ? fmt::format("\"{}\" must be 3 numbers in [0, {}]", key, max)
                                  : fmt::format("\"{}\" must be 3 non-negative numbers", key));
    return v;
  }

  /// Exactly one of the keys in `a` (all of them) or the keys in `b`.
  Expected<bool> EitherOr(const Json& parent, std::string_view context, std::initializer_list<const char*> a,
                          std::initializer_list<const char*> b) const {
    auto count = [&](std::initializer_list<const char*> keys) {
      return std::count_if(keys.begin(), keys.end(), [&](const char* k) { return parent.contains(k); });
    };
    const auto haveA = count(a), haveB = count(b);
    auto names = [](std::initializer_list<const char*> keys) {
      return fmt::format("\"{}\"", fmt::join(keys, "\" + \""));
    };
    if (!((haveA == std::ssize(a) && haveB == 0) || (haveA == 0 && haveB == std::ssize(b))))
      return Problem(context, fmt::format("give either {} or {}", names(a), names(b)));
    return haveA > 0;
  }

 private:
  std::string fileName_;
};

// Direction toward the sun from angles in a +Y-up world: azimuth 0 is +Z,
// 90 is +X.
Vec3 DirectionFromAngles(float elevationDeg, float azimuthDeg) {
  const float e = elevationDeg * kDegToRad, a = azimuthDeg * kDegToRad;
  return Vec3(std::cos(e) * std::sin(a), std::sin(e), std::cos(e) * std::cos(a));
}

Expected<SunLight> ParseSun(const JsonReader& r, const Json& j) {
  const std::string_view ctx = "sun";
  if (auto ok = r.CheckKeys(j, ctx, {"direction", "elevation_deg", "azimuth_deg", "radiance", "irradiance",
                                     "angular_diameter_deg"});
      !ok)
    return ok.error();
  SunLight sun;
  auto byVector = r.EitherOr(j, ctx, {"direction"}, {"elevation_deg", "azimuth_deg"});
  if (!byVector) return byVector.error();
  if (*byVector) {
    auto direction = r.Direction(j, ctx, "direction");
    if (!direction) return direction.error();
    sun.directionToSun = glm::normalize(*direction);
  } else {
    auto elevation = r.Number(j, ctx, "elevation_deg", -90.0f, 90.0f);
    if (!elevation) return elevation.error();
    auto azimuth = r.Number(j, ctx, "azimuth_deg", -360.0f, 360.0f);
    if (!azimuth) return azimuth.error();
    sun.directionToSun = DirectionFromAngles(*elevation, *azimuth);
  }
  auto diameter = r.Number(j, ctx, "angular_diameter_deg", 0.01f, 90.0f, 0.53f);
  if (!diameter) return diameter.error();
  sun.angularDiameterRad = *diameter * kDegToRad;

  auto byRadiance = r.EitherOr(j, ctx, {"radiance"}, {"irradiance"});
  if (!byRadiance) return byRadiance.error();
  auto value = r.NonNegativeRgb(j, ctx, *byRadiance ? "radiance" : "irradiance");
  if (!value) return value.error();
  // Irradiance at normal incidence = radiance x the disc's solid angle.
  sun.radiance = *byRadiance ? *value : *value / sun.SolidAngle();
  return sun;
}

Expected<SkyLight> ParseSky(const JsonReader& r, const Json& j) {
  const std::string_view ctx = "sky";
  if (auto ok = r.CheckKeys(j, ctx, {"radiance", "zenith", "horizon", "ground", "up"}); !ok) return ok.error();
  SkyLight sky;
  auto up = r.Direction(j, ctx, "up", Vec3(0.0f, 1.0f, 0.0f));
  if (!up) return up.error();
  sky.up = glm::normalize(*up);
  auto uniform = r.EitherOr(j, ctx, {"radiance"}, {"zenith", "horizon", "ground"});
  if (!uniform) return uniform.error();
  if (*uniform) {
    auto radiance = r.NonNegativeRgb(j, ctx, "radiance");
    if (!radiance) return radiance.error();
    sky.zenith = sky.horizon = sky.ground = *radiance;
    return sky;
  }
  for (auto [key, field] : {std::pair{"zenith", &sky.zenith}, {"horizon", &sky.horizon}, {"ground", &sky.ground}}) {
    auto radiance = r.NonNegativeRgb(j, ctx, key);
    if (!radiance) return radiance.error();
    *field = *radiance;
  }
  return sky;
}

Expected<MaterialOverride> ParseMaterialOverride(const JsonReader& r, const std::string& name, const Json& j) {
  const std::string ctx = fmt::format("materials.{}", name);
  if (!j.is_object()) return r.Problem(ctx, "must be an object");
  if (auto ok = r.CheckKeys(j, ctx, {"albedo", "emission"}); !ok) return ok.error();
  MaterialOverride o;
  o.name = name;
  if (j.contains("albedo")) {
    auto albedo = r.NonNegativeRgb(j, ctx, "albedo", 1.0f);
    if (!albedo) return albedo.error();
    o.albedo = *albedo;
  }
  if (j.contains("emission")) {
    auto emission = r.NonNegativeRgb(j, ctx, "emission");
    if (!emission) return emission.error();
    o.emission = *emission;
  }
  return o;
}

Expected<QuadLight> ParseQuadLight(const JsonReader& r, size_t index, const Json& j) {
  const std::string ctx = fmt::format("quad_lights[{}]", index);
  if (!j.is_object()) return r.Problem(ctx, "must be an object");
  if (auto ok = r.CheckKeys(j, ctx, {"name", "corner", "edge1", "edge2", "radiance"}); !ok) return ok.error();
  QuadLight q;
  auto name = r.String(j, ctx, "name");
  if (!name) return name.error();
  q.name = *name;
  for (auto [key, field] : {std::pair{"corner", &q.corner}, {"edge1", &q.edge1}, {"edge2", &q.edge2}}) {
    auto v = r.Vector(j, ctx, key);
    if (!v) return v.error();
    *field = *v;
  }
  if (glm::length(glm::cross(q.edge1, q.edge2)) == 0.0f)
    return r.Problem(ctx, "\"edge1\" and \"edge2\" span no area");
  auto radiance = r.NonNegativeRgb(j, ctx, "radiance");
  if (!radiance) return radiance.error();
  q.radiance = *radiance;
  return q;
}

Expected<CameraPreset> ParseCamera(const JsonReader& r, const std::string& name, const Json& j) {
  const std::string ctx = fmt::format("cameras.{}", name);
  if (!j.is_object()) return r.Problem(ctx, "must be an object");
  if (auto ok = r.CheckKeys(j, ctx, {"eye", "target", "up", "fov_y_deg"}); !ok) return ok.error();
  CameraPreset camera;
  camera.name = name;
  auto eye = r.Vector(j, ctx, "eye");
  if (!eye) return eye.error();
  auto target = r.Vector(j, ctx, "target");
  if (!target) return target.error();
  auto up = r.Direction(j, ctx, "up", Vec3(0.0f, 1.0f, 0.0f));
  if (!up) return up.error();
  auto fov = r.Number(j, ctx, "fov_y_deg", 1.0f, 179.0f, 45.0f);
  if (!fov) return fov.error();
  camera.pose = CameraPose{*eye, *target, *up};
  camera.fovYDeg = *fov;
  CameraView view;
  view.pose = camera.pose;
  view.fovYDeg = camera.fovYDeg;
  if (auto ok = ValidateCameraView(view); !ok) return r.Problem(ctx, ok.error().message);
  return camera;
}

// A camera path, inline or in a file of its own ({"file": "..."}), in
// ParseCameraPathJson's format.
Expected<CameraPath> ParseCameraPath(const JsonReader& r, const fs::path& sceneDir, const std::string& sceneFile,
                                     const std::string& name, const Json& j) {
  const std::string ctx = fmt::format("paths.{}", name);
  if (!j.is_object()) return r.Problem(ctx, "must be an object");
  const bool inFile = j.contains("file");
  // Errors from a path file name both the scene file and the path file.
  auto problem = [&](const Error& e) { return inFile ? r.Problem(ctx, e.message) : e; };

  Json body = j;
  std::string bodyName = fmt::format("{}: {}", sceneFile, ctx);
  if (inFile) {
    if (auto ok = r.CheckKeys(j, ctx, {"file"}); !ok) return ok.error();
    auto file = r.String(j, ctx, "file");
    if (!file) return file.error();
    bodyName = (sceneDir / *file).string();
    auto text = ReadTextFile(sceneDir / *file);
    if (!text) return problem(text.error());
    auto doc = ParseJson(*text, bodyName);
    if (!doc) return problem(doc.error());
    body = std::move(*doc);
  }
  // ParseCameraPathJson ignores keys it does not know; catch typos here.
  const JsonReader bodyReader(bodyName);
  if (body.is_object()) {
    if (auto ok = bodyReader.CheckKeys(body, "", {"name", "fov_y_deg", "width", "height", "keyframes"}); !ok)
      return problem(ok.error());
    if (body.contains("keyframes") && body["keyframes"].is_array()) {
      for (size_t i = 0; i < body["keyframes"].size(); ++i) {
        const Json& key = body["keyframes"][i];
        if (!key.is_object()) continue;  // ParseCameraPathJson reports it
        if (auto ok = bodyReader.CheckKeys(key, fmt::format("keyframe {}", i), {"t", "eye", "target", "up"}); !ok)
          return problem(ok.error());
      }
    }
  }
  auto path = ParseCameraPathJson(body.dump(), bodyName);
  if (!path) return problem(path.error());
  path->name = name;  // the key in the scene file names the path
  return path;
}

// --- Movable objects (issue 14) ----------------------------------------------

// A rigid transform, either {"matrix": [12 numbers, 3x4 row-major]} or any
// of {"translate": [x, y, z], "rotate_deg": a, "axis": [x, y, z]} (rotation
// about the axis through the origin, then the translation). Either way it is
// checked by RigidTransform::FromRowMajor, so the rules are the wire's.
Expected<RigidTransform> ParseTransform(const JsonReader& r, const Json& j, std::string_view ctx) {
  std::array<float, 12> m{};
  if (j.contains("matrix")) {
    for (const char* key : {"translate", "rotate_deg", "axis"})
      if (j.contains(key)) return r.Problem(ctx, fmt::format("give either \"matrix\" or \"{}\", not both", key));
    const Json& matrix = j.at("matrix");
    if (!matrix.is_array() || matrix.size() != 12)
      return r.Problem(ctx, "\"matrix\" must be an array of 12 numbers (3x4, row-major: rotation | translation)");
    for (size_t i = 0; i < 12; ++i) {
      if (!matrix[i].is_number()) return r.Problem(ctx, fmt::format("\"matrix\" entry {} is not a number", i));
      m[i] = matrix[i].get<float>();
    }
  } else {
    auto translate = r.Vector(j, ctx, "translate", Vec3(0.0f));
    if (!translate) return translate.error();
    if (j.contains("axis") && !j.contains("rotate_deg")) return r.Problem(ctx, "\"axis\" without \"rotate_deg\"");
    auto angle = r.Number(j, ctx, "rotate_deg", -3600.0f, 3600.0f, 0.0f);
    if (!angle) return angle.error();
    auto axis = r.Direction(j, ctx, "axis", Vec3(0.0f, 1.0f, 0.0f));
    if (!axis) return axis.error();
    m = RigidTransform::FromAxisAngle(*axis, *angle * kDegToRad, *translate).ToRowMajor();
  }
  auto transform = RigidTransform::FromRowMajor(m);
  if (!transform) return r.Problem(ctx, transform.error().message);
  return *transform;
}

// The "transform" of an object or an instance (`ctx` names it): an object
// holding only ParseTransform's keys.
Expected<RigidTransform> ParsePlacement(const JsonReader& r, const Json& j, const std::string& ctx) {
  auto transformJson = r.Object(j, ctx, "transform");
  if (!transformJson) return transformJson.error();
  const std::string transformCtx = ctx + ".transform";
  if (auto ok = r.CheckKeys(**transformJson, transformCtx, {"translate", "rotate_deg", "axis", "matrix"}); !ok)
    return ok.error();
  return ParseTransform(r, **transformJson, transformCtx);
}

Expected<ObjectAnimation> ParseObjectAnimation(const JsonReader& r, const Json& j, const std::string& ctx) {
  if (!j.is_object()) return r.Problem(ctx, "must be an object");
  if (auto ok = r.CheckKeys(j, ctx, {"loop", "keyframes"}); !ok) return ok.error();
  ObjectAnimation animation;
  if (j.contains("loop")) {
    if (!j["loop"].is_boolean()) return r.Problem(ctx, "\"loop\" must be true or false");
    animation.loop = j["loop"].get<bool>();
  }
  if (!j.contains("keyframes")) return r.Problem(ctx, "missing \"keyframes\"");
  const Json& keys = j["keyframes"];
  if (!keys.is_array() || keys.size() < 2 || keys.size() > kMaxObjectKeyframes)
    return r.Problem(ctx, fmt::format("\"keyframes\" must be an array of 2 to {} keyframes", kMaxObjectKeyframes));
  animation.keys.reserve(keys.size());
  for (size_t i = 0; i < keys.size(); ++i) {
    const std::string keyCtx = fmt::format("{}.keyframes[{}]", ctx, i);
    const Json& key = keys[i];
    if (!key.is_object()) return r.Problem(keyCtx, "must be an object");
    // A keyframe is a transform (ParseTransform) at a time.
    if (auto ok = r.CheckKeys(key, keyCtx, {"t", "translate", "rotate_deg", "axis", "matrix"}); !ok) return ok.error();
    auto t = r.Number(key, keyCtx, "t", 0.0f, kMaxKeyframeTimeS);
    if (!t) return t.error();
    if (i == 0 && *t != 0.0f) return r.Problem(keyCtx, "the first keyframe must be at \"t\": 0");
    if (i > 0 && !(*t > animation.keys.back().timeS))
      return r.Problem(keyCtx, fmt::format("\"t\" ({}) must be after the previous keyframe's ({})", *t,
                                           animation.keys.back().timeS));
    auto transform = ParseTransform(r, key, keyCtx);
    if (!transform) return transform.error();
    animation.keys.push_back(ObjectKeyframe{*t, *transform});
  }
  return animation;
}

Expected<ObjectDescription> ParseObject(const JsonReader& r, const fs::path& sceneDir, const std::string& name,
                                        const Json& j) {
  // Names go into log lines, error messages and every client's object list.
  const auto hasControl = [](const std::string& text) {
    return std::any_of(text.begin(), text.end(), [](char c) { return (unsigned char)c < 0x20 || c == 0x7f; });
  };
  if (name.empty() || name.size() > kMaxObjectNameBytes || hasControl(name))
    return r.Problem("objects", fmt::format("an object's name must have 1 to {} bytes and no control characters",
                                            kMaxObjectNameBytes));
  const std::string ctx = fmt::format("objects.{}", name);
  if (!j.is_object()) return r.Problem(ctx, "must be an object");
  if (auto ok = r.CheckKeys(j, ctx, {"group", "mesh", "pivot", "transform", "animation"}); !ok) return ok.error();
  ObjectDescription o;
  o.name = name;
  auto byGroup = r.EitherOr(j, ctx, {"group"}, {"mesh"});
  if (!byGroup) return byGroup.error();
  if (*byGroup) {
    const Json& group = j["group"];
    const auto isName = [&](const Json& v) {
      return v.is_string() && !v.get_ref<const std::string&>().empty() && !hasControl(v.get_ref<const std::string&>());
    };
    if (isName(group)) {
      o.groups.push_back(group.get<std::string>());
    } else if (group.is_array() && !group.empty() && group.size() <= kMaxObjectGroups &&
               std::all_of(group.begin(), group.end(), isName)) {
      for (const Json& g : group) o.groups.push_back(g.get<std::string>());
    } else {
      return r.Problem(ctx, fmt::format("\"group\" must be a non-empty string (no control characters) or an array "
                                        "of 1 to {} of them",
                                        kMaxObjectGroups));
    }
    if (j.contains("pivot")) {
      auto pivot = r.Vector(j, ctx, "pivot");
      if (!pivot) return pivot.error();
      o.pivot = *pivot;
    }
  } else {
    auto mesh = r.String(j, ctx, "mesh");
    if (!mesh) return mesh.error();
    o.meshPath = sceneDir / *mesh;
    if (j.contains("pivot"))
      return r.Problem(ctx, "\"pivot\" is for \"group\" objects (a mesh file's own origin is its pivot)");
  }
  if (j.contains("transform") && j.contains("animation"))
    return r.Problem(ctx, "give either \"transform\" or \"animation\" (its first keyframe places the object)");
  if (j.contains("transform")) {
    auto transform = ParsePlacement(r, j, ctx);
    if (!transform) return transform.error();
    o.placement = *transform;
  }
  if (j.contains("animation")) {
    auto animation = ParseObjectAnimation(r, j["animation"], ctx + ".animation");
    if (!animation) return animation.error();
    o.placement = animation->keys.front().objectToWorld;
    o.animation = std::move(*animation);
  }
  return o;
}

// --- Static instances (issue 15) ----------------------------------------------

Expected<InstanceDescription> ParseInstance(const JsonReader& r, const fs::path& sceneDir, size_t index,
                                            const Json& j) {
  const std::string ctx = fmt::format("instances[{}]", index);
  if (!j.is_object()) return r.Problem(ctx, "must be an object");
  if (auto ok = r.CheckKeys(j, ctx, {"mesh", "transform"}); !ok) return ok.error();
  InstanceDescription instance;
  auto mesh = r.String(j, ctx, "mesh");
  if (!mesh) return mesh.error();
  instance.meshPath = sceneDir / *mesh;
  if (j.contains("transform")) {
    auto transform = ParsePlacement(r, j, ctx);
    if (!transform) return transform.error();
    instance.meshToWorld = *transform;
  }
  return instance;
}

}  // namespace

Expected<SceneDescription> ParseSceneFile(const fs::path& path) {
  const std::string fileName = path.string();
  auto text = ReadTextFile(path);
  if (!text) return text.error();
  auto parsed = ParseJson(*text, fileName);
  if (!parsed) return parsed.error();
  const Json& doc = *parsed;
  const JsonReader r(fileName);
  if (!doc.is_object()) return r.Problem("", "a scene file must be a JSON object");
  if (auto ok = r.CheckKeys(doc, "", {"name", "mesh", "crease_angle_deg", "emission_scale", "two_sided", "materials", "sun",
                                      "sky", "quad_lights", "cameras", "paths", "objects",
                                      "instances"});
      !ok)
    return ok.error();

  SceneDescription d;
  d.sourcePath = path;
  const fs::path sceneDir = path.parent_path();
  d.name = path.stem().string();
  if (doc.contains("name")) {
    auto name = r.String(doc, "", "name");
    if (!name) return name.error();
    d.name = *name;
  }
  auto mesh = r.String(doc, "", "mesh");
  if (!mesh) return mesh.error();
  d.meshPath = sceneDir / *mesh;
  if (doc.contains("crease_angle_deg")) {
    auto crease = r.Number(doc, "", "crease_angle_deg", 0.0f, 180.0f);
    if (!crease) return crease.error();
    d.creaseAngleDeg = *crease;
  }
  if (doc.contains("two_sided")) {
    if (!doc["two_sided"].is_boolean()) return r.Problem("", "\"two_sided\" must be true or false");
    d.twoSided = doc["two_sided"].get<bool>();
  }
  auto scale = r.Number(doc, "", "emission_scale", 0.0f, std::numeric_limits<float>::max(), 1.0f);
  if (!scale) return scale.error();
  d.emissionScale = *scale;

  if (doc.contains("materials")) {
    auto materials = r.Object(doc, "", "materials");
    if (!materials) return materials.error();
    for (const auto& item : (*materials)->items()) {
      auto o = ParseMaterialOverride(r, item.key(), item.value());
      if (!o) return o.error();
      d.materialOverrides.push_back(std::move(*o));
    }
  }
  if (doc.contains("sun")) {
    auto sunJson = r.Object(doc, "", "sun");
    if (!sunJson) return sunJson.error();
    auto sun = ParseSun(r, **sunJson);
    if (!sun) return sun.error();
    d.sun = *sun;
  }
  if (doc.contains("sky")) {
    auto skyJson = r.Object(doc, "", "sky");
    if (!skyJson) return skyJson.error();
    auto sky = ParseSky(r, **skyJson);
    if (!sky) return sky.error();
    d.sky = *sky;
  }
  if (doc.contains("quad_lights")) {
    const Json& quads = doc["quad_lights"];
    if (!quads.is_array()) return r.Problem("", "\"quad_lights\" must be an array");
    for (size_t i = 0; i < quads.size(); ++i) {
      auto q = ParseQuadLight(r, i, quads[i]);
      if (!q) return q.error();
      d.quadLights.push_back(std::move(*q));
    }
  }
  if (doc.contains("cameras")) {
    auto cameras = r.Object(doc, "", "cameras");
    if (!cameras) return cameras.error();
    for (const auto& item : (*cameras)->items()) {
      auto camera = ParseCamera(r, item.key(), item.value());
      if (!camera) return camera.error();
      d.cameras.push_back(std::move(*camera));
    }
  }
  if (doc.contains("paths")) {
    auto paths = r.Object(doc, "", "paths");
    if (!paths) return paths.error();
    for (const auto& item : (*paths)->items()) {
      auto cameraPath = ParseCameraPath(r, sceneDir, fileName, item.key(), item.value());
      if (!cameraPath) return cameraPath.error();
      d.paths.push_back(std::move(*cameraPath));
    }
  }
  if (doc.contains("objects")) {
    auto objects = r.Object(doc, "", "objects");
    if (!objects) return objects.error();
    if ((*objects)->size() > kMaxSceneObjects)
      return r.Problem("objects", fmt::format("{} objects; at most {} may move", (*objects)->size(), kMaxSceneObjects));
    for (const auto& item : (*objects)->items()) {
      auto object = ParseObject(r, sceneDir, item.key(), item.value());
      if (!object) return object.error();
      d.objects.push_back(std::move(*object));
    }
  }
  if (doc.contains("instances")) {
    const Json& instances = doc["instances"];
    if (!instances.is_array()) return r.Problem("", "\"instances\" must be an array");
    if (instances.size() > kMaxSceneInstances)
      return r.Problem("instances", fmt::format("{} instances; at most {} are supported", instances.size(),
                                                kMaxSceneInstances));
    d.instances.reserve(instances.size());
    for (size_t i = 0; i < instances.size(); ++i) {
      auto instance = ParseInstance(r, sceneDir, i, instances[i]);
      if (!instance) return instance.error();
      d.instances.push_back(std::move(*instance));
    }
  }
  return d;
}

Status ApplyToBuilder(const SceneDescription& d, SceneBuilder& builder) {
  // The scale is for the meshes' own emission, so it comes before the quads;
  // the overrides come after them, so that one can also set a quad's albedo
  // (a quad of radiance 0 is a plain surface: a street's paving).
  for (Material& m : builder.Materials()) m.emission *= d.emissionScale;
  for (const QuadLight& q : d.quadLights) {
    Material m;
    m.name = q.name;
    m.emission = q.radiance;
    builder.AddQuad(q.corner, q.edge1, q.edge2, builder.AddMaterial(std::move(m)));
  }
  for (const MaterialOverride& o : d.materialOverrides) {
    bool found = false;
    for (Material& m : builder.Materials()) {
      if (m.name != o.name) continue;
      found = true;
      if (o.albedo) m.albedo = *o.albedo;
      if (o.emission) m.emission = *o.emission;
    }
    if (!found)
      return Fail(fmt::format("{}: materials: no material of {}{}{} is named \"{}\"", d.sourcePath.string(),
                              d.meshPath.string(), d.instances.empty() ? "" : ", the instanced meshes",
                              d.quadLights.empty() ? "" : ", the quad lights", o.name));
  }
  return Status::Ok();
}

}  // namespace penumbra

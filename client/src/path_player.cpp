#include "penumbra/client/path_player.h"

#include <filesystem>
#include <fstream>
#include <sstream>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "penumbra/common/check.h"

namespace penumbra::client {

Expected<CameraPath> LoadCameraPathSpec(std::string_view spec) {
  const size_t hash = spec.rfind('#');
  if (hash == std::string_view::npos) return LoadCameraPath(std::string(spec));
  const std::string file(spec.substr(0, hash));
  const std::string name(spec.substr(hash + 1));
  std::ifstream in(file, std::ios::binary);
  if (!in) return Fail(fmt::format("{}: cannot open scene file", file));
  std::ostringstream text;
  text << in.rdbuf();
  const auto doc = nlohmann::json::parse(text.str(), nullptr, /*allow_exceptions=*/false);
  if (doc.is_discarded() || !doc.is_object()) return Fail(fmt::format("{}: not a JSON object", file));
  const auto paths = doc.find("paths");
  if (paths == doc.end() || !paths->is_object() || !paths->contains(name))
    return Fail(fmt::format("{}: no camera path named '{}' in its \"paths\"", file, name));
  const nlohmann::json& entry = paths->at(name);
  // A path in a file of its own ({"file": "..."}, relative to the scene
  // file, as docs/scenes.md says and the scene loader reads it).
  if (entry.is_object() && entry.contains("file")) {
    if (entry.size() != 1 || !entry["file"].is_string())
      return Fail(fmt::format("{}: paths.{}: a path file is given as {{\"file\": \"NAME.json\"}} alone", file, name));
    const std::filesystem::path pathFile =
        std::filesystem::path(file).parent_path() / entry["file"].get<std::string>();
    auto path = LoadCameraPath(pathFile);
    if (path) path->name = name;
    return path;
  }
  auto path = ParseCameraPathJson(entry.dump(), std::string(spec));
  if (path && path->name.empty()) path->name = name;
  return path;
}

CameraPath StillPath(const CameraPreset& preset, int width, int height) {
  CameraPath path;
  path.name = preset.name;
  path.fovYDeg = preset.fovYDeg;
  path.width = width;
  path.height = height;
  path.keyframes.push_back(CameraKeyframe{0.0, preset.pose});
  return path;
}

PathPlayer::PathPlayer(CameraPath path) : path_(std::move(path)) {
  PENUMBRA_CHECK(!path_.keyframes.empty(), "a camera path has at least one keyframe");
}

CameraView PathPlayer::ViewAt(std::chrono::duration<double> elapsed) const {
  return path_.ViewAt(path_.keyframes.front().timeSeconds + elapsed.count());
}

bool PathPlayer::Finished(std::chrono::duration<double> elapsed) const {
  return elapsed.count() >= path_.DurationSeconds();
}

}  // namespace penumbra::client

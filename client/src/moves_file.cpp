#include "penumbra/client/moves_file.h"

#include <cerrno>
#include <cmath>
#include <fstream>
#include <map>
#include <sstream>

#include <fmt/format.h>
#include <glm/trigonometric.hpp>

#include "penumbra/common/logging.h"

namespace penumbra::client {

namespace {

constexpr float kMaxTranslation = 1e7f;

// Splits a line into words; "double quoted" words may hold spaces. A '#'
// outside quotes starts a comment.
Expected<std::vector<std::string>> Words(std::string_view line) {
  std::vector<std::string> words;
  size_t i = 0;
  while (i < line.size()) {
    const char c = line[i];
    if (c == ' ' || c == '\t' || c == '\r') {
      ++i;
    } else if (c == '#') {
      break;
    } else if (c == '"') {
      const size_t end = line.find('"', i + 1);
      if (end == std::string_view::npos) return Fail("a quoted name has no closing quote");
      words.emplace_back(line.substr(i + 1, end - i - 1));
      i = end + 1;
    } else {
      size_t end = i;
      while (end < line.size() && line[end] != ' ' && line[end] != '\t' && line[end] != '\r' && line[end] != '#') ++end;
      words.emplace_back(line.substr(i, end - i));
      i = end;
    }
  }
  return words;
}

Expected<double> Number(const std::vector<std::string>& words, size_t index, std::string_view what) {
  if (index >= words.size()) return Fail(fmt::format("{} is missing", what));
  const std::string& word = words[index];
  char* end = nullptr;
  errno = 0;
  const double value = std::strtod(word.c_str(), &end);
  if (word.empty() || end != word.c_str() + word.size() || errno == ERANGE || !std::isfinite(value))
    return Fail(fmt::format("{} '{}' is not a finite number", what, Printable(word, 32)));
  return value;
}

Expected<Vec3> Triple(const std::vector<std::string>& words, size_t index, std::string_view what) {
  Vec3 v(0.0f);
  for (int c = 0; c < 3; ++c) {
    auto x = Number(words, index + size_t(c), fmt::format("{} {}", what, "xyz"[c]));
    if (!x) return x.error();
    v[c] = float(*x);
    if (!std::isfinite(v[c])) return Fail(fmt::format("{} {} is out of range", what, "xyz"[c]));
  }
  return v;
}

Expected<ScriptedMove> ParseLine(const std::vector<std::string>& words, double previousTime) {
  ScriptedMove move;
  auto time = Number(words, 0, "the time");
  if (!time) return time.error();
  if (*time < 0.0) return Fail(fmt::format("the time {} is negative", *time));
  if (*time < previousTime)
    return Fail(fmt::format("the time {} is earlier than the move before it ({})", *time, previousTime));
  move.timeS = *time;
  if (words.size() < 2 || words[1].empty()) return Fail("the object's name is missing");
  move.object = words[1];
  size_t i = 2;
  while (i < words.size()) {
    const std::string& word = words[i];
    if (word == "translate") {
      if (move.translation) return Fail("'translate' is given twice");
      auto t = Triple(words, i + 1, "translate");
      if (!t) return t.error();
      if (std::abs(t->x) > kMaxTranslation || std::abs(t->y) > kMaxTranslation || std::abs(t->z) > kMaxTranslation)
        return Fail(fmt::format("translate ({}, {}, {}) is beyond {}", t->x, t->y, t->z, kMaxTranslation));
      move.translation = *t;
      i += 4;
    } else if (word == "rotate") {
      if (move.rotation) return Fail("'rotate' is given twice");
      auto angle = Number(words, i + 1, "the rotation angle (degrees)");
      if (!angle) return angle.error();
      if (i + 2 >= words.size() || words[i + 2] != "about")
        return Fail("'rotate DEG' is followed by 'about AX AY AZ'");
      auto axis = Triple(words, i + 3, "the rotation axis");
      if (!axis) return axis.error();
      const float length = glm::length(*axis);
      if (!(length > 1e-6f) || !std::isfinite(length)) return Fail("the rotation axis is zero");
      move.rotation = ScriptedRotation{float(*angle), *axis / length};
      i += 6;
    } else {
      return Fail(fmt::format("unknown word '{}' (expected 'translate X Y Z' or 'rotate DEG about AX AY AZ')",
                              Printable(word, 32)));
    }
  }
  if (!move.translation && !move.rotation) return Fail("the move has neither 'translate' nor 'rotate'");
  return move;
}

}  // namespace

Expected<std::vector<ScriptedMove>> ParseMoves(std::string_view text) {
  std::vector<ScriptedMove> moves;
  double previousTime = 0.0;
  int lineNumber = 0;
  size_t start = 0;
  while (start <= text.size()) {
    size_t end = text.find('\n', start);
    if (end == std::string_view::npos) end = text.size();
    const std::string_view line = text.substr(start, end - start);
    ++lineNumber;
    start = end + 1;
    auto words = Words(line);
    if (!words) return Fail(fmt::format("line {}: {}", lineNumber, words.error().message));
    if (words->empty()) continue;
    if (moves.size() >= kMaxScriptedMoves)
      return Fail(fmt::format("line {}: more than {} moves", lineNumber, kMaxScriptedMoves));
    auto move = ParseLine(*words, previousTime);
    if (!move) return Fail(fmt::format("line {}: {}", lineNumber, move.error().message));
    move->line = lineNumber;
    previousTime = move->timeS;
    moves.push_back(std::move(*move));
  }
  if (moves.empty()) return Fail("no moves (each line: <t_seconds> <object> [translate X Y Z] "
                                 "[rotate DEG about AX AY AZ])");
  return moves;
}

Expected<std::vector<ScriptedMove>> LoadMovesFile(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return Fail(fmt::format("moves file {}: cannot open it", path.string()));
  std::string text(kMaxMovesFileBytes + 1, '\0');
  in.read(text.data(), std::streamsize(text.size()));
  text.resize(size_t(in.gcount()));
  if (text.size() > kMaxMovesFileBytes)
    return Fail(fmt::format("moves file {}: larger than {} bytes", path.string(), kMaxMovesFileBytes));
  auto moves = ParseMoves(text);
  if (!moves) return Fail(fmt::format("moves file {}: {}", path.string(), moves.error().message));
  return moves;
}

Expected<std::vector<BoundMove>> BindMoves(std::span<const ScriptedMove> moves, const ClientScene& scene) {
  std::map<uint32_t, RigidTransform> current;
  std::vector<BoundMove> bound;
  bound.reserve(moves.size());
  for (const ScriptedMove& move : moves) {
    const uint32_t id = scene.FindObject(move.object);
    if (id == 0) {
      std::string names;
      for (const ClientObject& o : scene.objects) names += (names.empty() ? "" : ", ") + o.name;
      return Fail(fmt::format("line {}: the scene '{}' has no movable object '{}' (it has: {})", move.line,
                              Printable(scene.name), Printable(move.object),
                              names.empty() ? "none" : Printable(names, 512)));
    }
    const ClientObject& object = scene.objects[id - 1];
    if (object.animated)
      return Fail(fmt::format("line {}: object '{}' follows its animation path; the SMA refuses moves of it",
                              move.line, Printable(move.object)));
    auto [it, first] = current.try_emplace(id, object.objectToWorld);
    RigidTransform& t = it->second;
    if (move.translation) t.translation = *move.translation;
    if (move.rotation)
      t.rotation = RigidTransform::FromAxisAngle(move.rotation->axis, glm::radians(move.rotation->angleDeg), Vec3(0))
                       .rotation;
    bound.push_back(BoundMove{move.timeS, id, t, move.line});
  }
  return bound;
}

std::vector<BoundMove> MovesPlayer::Due(std::chrono::duration<double> elapsed) {
  std::vector<BoundMove> due;
  while (next_ < moves_.size() && moves_[next_].timeS <= elapsed.count()) due.push_back(moves_[next_++]);
  return due;
}

}  // namespace penumbra::client

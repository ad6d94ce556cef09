#pragma once
// Scripted object moves for headless runs (--moves FILE, issue 14): a small
// text format, one move per line,
//
//   # comment
//   <t_seconds> <object> [translate X Y Z] [rotate DEG about AX AY AZ]
//
// e.g. "1.5 box translate 0.1 0.3 0.2 rotate 30 about 0 1 0". <object> is
// the movable object's name (double-quoted when it holds spaces: "my
// chair"). Both parts are absolute: the object's new object-to-world
// transform has that translation and the rotation of DEG degrees about that
// axis. A part left out keeps its value from the object's previous scripted
// move (from the SceneInfo for its first). Times are seconds after the
// script starts (the client starts it when the first view has converged)
// and never decrease.
//
// Threads: plain values and pure functions; any thread.

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <span>
#include <string_view>
#include <vector>

#include "penumbra/common/client_scene.h"
#include "penumbra/common/expected.h"
#include "penumbra/common/math.h"
#include "penumbra/common/rigid_transform.h"

namespace penumbra::client {

/// The longest moves file read, and the most moves it may hold.
inline constexpr size_t kMaxMovesFileBytes = size_t(4) << 20;
inline constexpr size_t kMaxScriptedMoves = 100000;

struct ScriptedRotation {
  float angleDeg = 0.0f;
  Vec3 axis{0.0f, 1.0f, 0.0f};  // unit
};

/// One line of a moves file.
struct ScriptedMove {
  double timeS = 0.0;
  std::string object;  // a name, resolved against the SceneInfo by BindMoves
  std::optional<Vec3> translation;
  std::optional<ScriptedRotation> rotation;
  int line = 0;  // 1-based, for messages
};

/// Parses a moves file's text. Fails with "line N: ..." for a bad time
/// (negative, not finite, earlier than the line before), a missing object, an
/// unknown word, a number missing or not finite, a zero rotation axis, a
/// translation beyond 1e7, a move with neither part, or more than
/// kMaxScriptedMoves moves.
Expected<std::vector<ScriptedMove>> ParseMoves(std::string_view text);
/// Reads and parses `path` (at most kMaxMovesFileBytes); messages name the file.
Expected<std::vector<ScriptedMove>> LoadMovesFile(const std::filesystem::path& path);

/// A move ready to send: object id and its whole new transform.
struct BoundMove {
  double timeS = 0.0;
  uint32_t object = 0;  // ClientScene id, 1..N
  RigidTransform objectToWorld;
  int line = 0;
};

/// Resolves names against the scene the SMA serves and fills in the parts
/// left out. Fails for an object the scene does not have ("the scene has:
/// ...") or one the SMA animates (it refuses moves of those).
Expected<std::vector<BoundMove>> BindMoves(std::span<const ScriptedMove> moves, const ClientScene& scene);

/// Plays bound moves in time: Due() returns those whose time has come, once each.
class MovesPlayer {
 public:
  explicit MovesPlayer(std::vector<BoundMove> moves) : moves_(std::move(moves)) {}
  std::vector<BoundMove> Due(std::chrono::duration<double> elapsed);
  bool Finished() const { return next_ >= moves_.size(); }
  size_t Sent() const { return next_; }
  size_t Total() const { return moves_.size(); }

 private:
  std::vector<BoundMove> moves_;
  size_t next_ = 0;
};

}  // namespace penumbra::client

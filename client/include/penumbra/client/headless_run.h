#pragma once
// When a headless run (penumbra-client --headless) is done or has failed,
// and which snapshots it writes on the way: the goal (--until-converged,
// --frames, --seconds), the timeouts (--connect-timeout, --timeout), the
// periodic radiance snapshots (--snapshot-every) and the screenshots'
// formats and pixel filter (--screenshot, --supersample). Plain logic of
// what the frame loop observes: no GL, no session, so it is unit-tested with
// made-up observations and clocks (tests/headless_run_test.cpp); the GL
// frame loop (gl/client_app.cpp) observes, draws and writes.
//
// Threads: render thread only; not thread-safe.

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "penumbra/client/session.h"

namespace penumbra::client {

enum class StopWhen { kConverged, kFrames, kSeconds };

struct HeadlessGoal {
  StopWhen stopWhen = StopWhen::kConverged;
  uint64_t frames = 0;   // kFrames: the run draws this many frames
  double seconds = 0.0;  // kSeconds: the run lasts this long
  /// Give up when no connection has existed for this long.
  std::chrono::seconds connectTimeout{15};
  /// kConverged: give up when not converged this long after the start.
  std::chrono::seconds convergeTimeout{600};
  /// After convergence, how long to wait for the SMA's counters (which
  /// confirm the client holds what the SMA sent) before finishing without them.
  std::chrono::milliseconds countersGrace{2000};
};

/// What the frame loop knows at the start of a frame.
struct HeadlessObservation {
  uint64_t framesDrawn = 0;      // before this frame
  bool pathFinished = false;     // the camera path has been played to its end
  bool converged = false;        // ClientModel::Converged for the latest view sent
  bool countersCurrent = false;  // the SMA's counters arrived after the last delta applied
  ConnectionState connection = ConnectionState::kConnecting;
  std::chrono::steady_clock::time_point disconnectedSince;  // SessionStatus's
  std::string lastError;                                    // SessionStatus's
  uint64_t samplesPending = 0;  // for the timeout's message
  uint64_t trianglesHeld = 0;
};

class HeadlessRun {
 public:
  using Clock = std::chrono::steady_clock;

  /// `smaAddress` names the SMA in messages; `start` is when the run began.
  HeadlessRun(HeadlessGoal goal, std::string smaAddress, Clock::time_point start);

  /// True when the frame about to be drawn is the run's last (then the
  /// screenshot is written and the client exits 0). kConverged: the path has
  /// ended and the final view converged, and the SMA's counters have
  /// confirmed what is held or countersGrace has passed since convergence.
  bool GoalMet(const HeadlessObservation& seen, Clock::time_point now);

  /// Why the run fails now (exit 1, this as the last log line), if it does:
  /// no connection for connectTimeout; kConverged and not done within
  /// convergeTimeout of the start.
  std::optional<std::string> Failure(const HeadlessObservation& seen, Clock::time_point now) const;

 private:
  const HeadlessGoal goal_;
  const std::string smaAddress_;
  const Clock::time_point start_;
  std::optional<Clock::time_point> convergedSince_;
};

/// --snapshot-every: every `every` (when the image has changed since the
/// last snapshot and something is held) the radiance goes to
/// <prefix>_<frame>.exr, the frame being the statistics line's.
class SnapshotSchedule {
 public:
  using Clock = std::chrono::steady_clock;

  /// `every` <= 0: no snapshots.
  SnapshotSchedule(std::chrono::duration<double> every, std::filesystem::path prefix);

  /// The file to write for this frame, or none. `sequence` is the mesh's
  /// last applied delta (the image changes only with it).
  std::optional<std::filesystem::path> Due(Clock::time_point now, uint64_t trianglesHeld, uint64_t sequence,
                                           uint64_t frame) const;
  /// The snapshot Due() named was written.
  void Written(Clock::time_point now, uint64_t sequence);
  /// Writing it failed: no more snapshots (the error is logged once).
  void Stop() { stopped_ = true; }

 private:
  const std::chrono::duration<double> every_;
  const std::filesystem::path prefix_;
  bool stopped_ = false;
  std::optional<Clock::time_point> last_;
  uint64_t lastSequence_ = 0;
};

/// .exr and .hdr screenshots hold linear radiance; others (.png, .jpg) the
/// tone-mapped display image.
bool IsRadianceFile(const std::filesystem::path& path);
/// .exr screenshots also hold the coverage as alpha: the share of the
/// pixel's samples where a surface (or the sky) was drawn, 0 for background.
bool StoresCoverage(const std::filesystem::path& path);

/// The file-name stem of an interactive screenshot, "penumbra-SCENE-TIME".
/// The scene's name comes from the SMA, so it is made safe for a file name:
/// only ASCII letters, digits, '-', '_' and '.' are kept (others become
/// '_'), at most 64 of them, never "." or ".." or a leading '.', "scene"
/// when nothing is left -- a hostile SMA's "../../x" cannot choose where
/// the file goes.
std::string ScreenshotStem(std::string_view sceneName, std::string_view timestamp);

/// --supersample: `pixels` of `channels` floats each (width x height, rows
/// top first; RGB, or 1 for a coverage mask) averaged over boxes of n x n
/// into (width / n) x (height / n) pixels, the pixel filter of offline
/// references. n <= 1: the pixels as they are.
std::vector<float> BoxFilter(std::span<const float> pixels, int width, int height, int n, int channels = 3);

}  // namespace penumbra::client

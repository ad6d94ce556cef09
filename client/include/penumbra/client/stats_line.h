#pragma once
// Per-frame statistics as JSON lines (--stats FILE): one object per frame,
// flushed at once so that a test or a script can follow the file while the
// client runs. Field names are documented in client/README.md.

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <optional>
#include <string>

#include "penumbra/client/client_model.h"
#include "penumbra/common/expected.h"

namespace penumbra::client {

/// This process's resident memory (Linux /proc/self/status: VmRSS, VmHWM);
/// zeros where it cannot be read.
struct ProcessMemory {
  uint64_t residentBytes = 0;
  uint64_t peakResidentBytes = 0;
};
ProcessMemory ReadProcessMemory();

struct FrameStats {
  uint64_t frame = 0;
  double timeSeconds = 0.0;  // since the client started
  uint64_t trianglesHeld = 0;
  uint64_t verticesHeld = 0;
  uint64_t bytesReceived = 0;  // over every connection
  uint32_t samplesPending = 0;
  bool converged = false;      // the current view is final (ClientModel::Converged)
  bool refining = false;       // the SMA refines the view (stage 2)
  uint64_t trianglesAdded = 0; // triangles received since the connection began (Delta_total)
  std::optional<double> viewToFirstDeltaMs;
  double fps = 0.0;
  ProcessMemory memory;
  std::string connection;      // ToString(ConnectionState)
  uint64_t connections = 0;    // handshakes so far
  std::optional<SmaReport> sma;
  uint64_t sceneEpoch = 0;     // of the last MOVED applied (or the SceneInfo): movable objects' places
  uint64_t movesSent = 0;      // MoveObject requests sent (a drag, or --moves)
  uint64_t movesPending = 0;   // objects whose last move the SMA has neither confirmed nor refused
};

/// The JSON object for one frame, without a newline. Absent optionals are null.
std::string FormatStatsLine(const FrameStats& stats);

class StatsLineWriter {
 public:
  /// Creates (truncates) `path`.
  static Expected<StatsLineWriter> Open(const std::filesystem::path& path);
  /// Appends one line and flushes it.
  Status Write(const FrameStats& stats);

 private:
  StatsLineWriter(std::ofstream out, std::filesystem::path path) : out_(std::move(out)), path_(std::move(path)) {}
  std::ofstream out_;
  std::filesystem::path path_;
};

}  // namespace penumbra::client

#pragma once
// Child processes for cross-process tests: start a real Penumbra executable,
// find the port it bound, signal it, wait for it. Output goes to a log file
// whose tail a failing test prints.

#include <sys/types.h>

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "penumbra/common/expected.h"

namespace penumbra::testing {

class ChildProcess {
 public:
  /// Starts `exe` with `args`; stdout and stderr go to `logPath`.
  /// No process (Running() is false).
  ChildProcess() = default;
  static Expected<ChildProcess> Spawn(const std::string& exe, const std::vector<std::string>& args,
                                      const std::string& logPath);
  ChildProcess(ChildProcess&& other) noexcept;
  ChildProcess& operator=(ChildProcess&& other) noexcept;
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;
  /// Kills (SIGKILL) and reaps a process still running.
  ~ChildProcess();

  pid_t Pid() const { return pid_; }
  void Signal(int signal) const;
  bool Running();
  /// Exit code (or 128 + signal) once the process has ended within `timeout`.
  std::optional<int> WaitExit(std::chrono::milliseconds timeout);
  /// Last `bytes` of the process's output, for failure messages.
  std::string LogTail(size_t bytes = 4000) const;
  const std::string& LogPath() const { return logPath_; }

 private:
  ChildProcess(pid_t pid, std::string logPath) : pid_(pid), logPath_(std::move(logPath)) {}
  pid_t pid_ = -1;
  std::optional<int> exitCode_;
  std::string logPath_;
};

/// Waits until `process` writes its port to `portFile` (--port-file).
Expected<uint16_t> WaitForPortFile(ChildProcess& process, const std::string& portFile,
                                   std::chrono::milliseconds timeout);

/// Resident memory of process `pid` in MiB (VmRSS), or -1 when it cannot be read.
double ResidentMegabytes(pid_t pid);

/// A fresh directory under the system temp dir for one test's files.
std::string MakeTempDir(const std::string& prefix);

/// The path of executable `name` on PATH or in the system directories root's
/// tools live in (/usr/sbin, /sbin), or nullopt.
std::optional<std::string> FindExecutable(const std::string& name);

/// Runs `exe args...` to the end and returns its output (stdout and stderr);
/// fails, with that output, when it exits non-zero or outlives `timeout`.
Expected<std::string> RunCommand(const std::string& exe, const std::vector<std::string>& args,
                                 std::chrono::milliseconds timeout = std::chrono::seconds(30));

}  // namespace penumbra::testing

#pragma once
// Starting Penumbra servers for cross-process tests: each gets a free port
// (--listen 127.0.0.1:0 --port-file) and a log file in a fresh directory.

#include <chrono>
#include <cstdint>
#include <string>
#include <vector>

#include "penumbra/common/expected.h"
#include "support/process.h"

namespace penumbra::testing {

struct Service {
  ChildProcess process;
  uint16_t port = 0;
  std::string dir;  // its log and port file live here

  std::string Address() const { return "127.0.0.1:" + std::to_string(port); }
};

/// Starts `exe args... --listen 127.0.0.1:0 --port-file <dir>/port` and waits
/// until it listens.
Expected<Service> StartService(const std::string& exe, const std::vector<std::string>& args, const std::string& tag,
                               std::chrono::milliseconds timeout = std::chrono::seconds(60));

}  // namespace penumbra::testing

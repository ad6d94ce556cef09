#include "support/xvfb.h"

#include <filesystem>
#include <thread>

#include <fmt/format.h>

namespace penumbra::testing {

Expected<XvfbServer> XvfbServer::Start(const std::string& logDir, int width, int height) {
  namespace fs = std::filesystem;
  std::string lastError = "every display from :90 to :199 is taken";
  for (int n = 90; n < 200; ++n) {
    const std::string socket = fmt::format("/tmp/.X11-unix/X{}", n);
    if (fs::exists(socket) || fs::exists(fmt::format("/tmp/.X{}-lock", n))) continue;
    const std::string display = fmt::format(":{}", n);
    auto process = ChildProcess::Spawn("/usr/bin/Xvfb",
                                       {display, "-screen", "0", fmt::format("{}x{}x24", width, height), "-nolisten",
                                        "tcp"},
                                       fmt::format("{}/xvfb-{}.log", logDir, n));
    if (!process) return process.error();
    // Ready once its socket exists; another server may win the race for N.
    for (int i = 0; i < 200; ++i) {
      if (fs::exists(socket)) return XvfbServer(std::move(*process), display);
      if (!process->Running()) break;
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    lastError = fmt::format("Xvfb {} did not start: {}", display, process->LogTail(500));
  }
  return Fail(lastError);
}

}  // namespace penumbra::testing

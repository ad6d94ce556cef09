#pragma once
// A private X server (Xvfb) for tests of windowed OpenGL code, on a display
// number nobody else uses. Stopped when destroyed.

#include <string>

#include "penumbra/common/expected.h"
#include "support/process.h"

namespace penumbra::testing {

class XvfbServer {
 public:
  /// Starts `Xvfb :N -screen 0 WxHx24 -nolisten tcp` on the first free N
  /// from 90 and waits until it accepts clients. Its log goes to `logDir`.
  static Expected<XvfbServer> Start(const std::string& logDir, int width = 1280, int height = 720);

  /// ":N", for DISPLAY.
  const std::string& Display() const { return display_; }

 private:
  XvfbServer(ChildProcess process, std::string display) : process_(std::move(process)), display_(std::move(display)) {}
  ChildProcess process_;
  std::string display_;
};

}  // namespace penumbra::testing

#pragma once
// HOST:PORT parsing for --listen / --renderer / --connect flags.

#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>

#include "penumbra/common/expected.h"

namespace penumbra {

struct HostPort {
  std::string host;  // name, IPv4, or IPv6 (given in brackets: [::1]:7000)
  uint16_t port = 0;

  std::string ToString() const;
};

/// Parses "host:port", "[v6]:port" or ":port" (host then "0.0.0.0").
/// Port 0 is accepted only when `allowPortZero` (listen on any free port).
Expected<HostPort> ParseHostPort(std::string_view text, bool allowPortZero = false);

/// Writes `port` to `path` atomically (write then rename), so that a script
/// or test waiting for the file never reads a partial number.
Status WritePortFile(const std::filesystem::path& path, uint16_t port);

}  // namespace penumbra

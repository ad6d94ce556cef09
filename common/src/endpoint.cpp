#include "penumbra/common/endpoint.h"

#include <charconv>
#include <fstream>

#include <fmt/format.h>

namespace penumbra {

std::string HostPort::ToString() const {
  return host.find(':') != std::string::npos ? fmt::format("[{}]:{}", host, port)
                                             : fmt::format("{}:{}", host, port);
}

Expected<HostPort> ParseHostPort(std::string_view text, bool allowPortZero) {
  HostPort out;
  std::string_view portText;
  if (!text.empty() && text.front() == '[') {
    const auto close = text.find(']');
    if (close == std::string_view::npos || close + 1 >= text.size() || text[close + 1] != ':')
      return Fail(fmt::format("'{}' is not HOST:PORT (IPv6 hosts are written [addr]:port)", text));
    out.host = std::string(text.substr(1, close - 1));
    portText = text.substr(close + 2);
  } else {
    const auto colon = text.rfind(':');
    if (colon == std::string_view::npos)
      return Fail(fmt::format("'{}' is not HOST:PORT (missing ':port')", text));
    out.host = std::string(text.substr(0, colon));
    portText = text.substr(colon + 1);
    if (out.host.find(':') != std::string::npos)
      return Fail(fmt::format("'{}' is not HOST:PORT (write IPv6 hosts as [addr]:port)", text));
  }
  if (out.host.empty()) out.host = "0.0.0.0";
  unsigned value = 0;
  const auto [ptr, ec] = std::from_chars(portText.data(), portText.data() + portText.size(), value);
  if (portText.empty() || ec != std::errc() || ptr != portText.data() + portText.size() || value > 65535)
    return Fail(fmt::format("'{}': port '{}' is not a number from {} to 65535", text, portText,
                            allowPortZero ? 0 : 1));
  if (value == 0 && !allowPortZero)
    return Fail(fmt::format("'{}': port 0 is not allowed here", text));
  out.port = uint16_t(value);
  return out;
}

Status WritePortFile(const std::filesystem::path& path, uint16_t port) {
  std::filesystem::path tmp = path;
  tmp += ".tmp";
  {
    std::ofstream out(tmp);
    out << port << "\n";
    if (!out) return Fail(fmt::format("cannot write port file {}", tmp.string()));
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) return Fail(fmt::format("cannot write port file {}: {}", path.string(), ec.message()));
  return Status::Ok();
}

}  // namespace penumbra

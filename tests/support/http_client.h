#pragma once
// A minimal HTTP/1.1 client on plain POSIX sockets, independent of the
// servers' Boost.Beast code, for tests of the --http operator endpoint:
// well-formed GETs, and arbitrary (malformed, oversized) bytes.

#include <chrono>
#include <cstdint>
#include <string>
#include <string_view>

#include "penumbra/common/expected.h"

namespace penumbra::testing {

struct HttpReply {
  int status = 0;
  std::string headers;  // status line and header lines, as received
  std::string body;
};

/// Connects to 127.0.0.1:`port`, sends `request` as is, and returns what
/// arrives until the server closes the connection (or `timeout`; an error
/// then says so).
Expected<std::string> RawHttpExchange(uint16_t port, std::string_view request,
                                      std::chrono::milliseconds timeout = std::chrono::seconds(10));

/// Splits a raw response into status, headers and body (Content-Length).
Expected<HttpReply> ParseHttpReply(const std::string& raw);

/// GET `path` with "Connection: close".
Expected<HttpReply> HttpGet(uint16_t port, const std::string& path,
                            std::chrono::milliseconds timeout = std::chrono::seconds(10));

/// A TCP connection that stays open until destroyed (for connection limits).
class IdleConnection {
 public:
  explicit IdleConnection(uint16_t port);
  ~IdleConnection();
  IdleConnection(const IdleConnection&) = delete;
  IdleConnection& operator=(const IdleConnection&) = delete;
  bool Connected() const { return fd_ >= 0; }
  /// True if the server closed it within `timeout` (a read returns 0 or fails).
  bool ClosedByPeer(std::chrono::milliseconds timeout);

 private:
  int fd_ = -1;
};

}  // namespace penumbra::testing

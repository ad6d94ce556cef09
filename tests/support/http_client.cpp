#include "support/http_client.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include <fmt/format.h>

namespace penumbra::testing {

using Clock = std::chrono::steady_clock;

namespace {

int ConnectLoopback(uint16_t port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  if (fd < 0) return -1;
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_port = htons(port);
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (::connect(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) != 0) {
    ::close(fd);
    return -1;
  }
  return fd;
}

}  // namespace

Expected<std::string> RawHttpExchange(uint16_t port, std::string_view request, std::chrono::milliseconds timeout) {
  const int fd = ConnectLoopback(port);
  if (fd < 0) return Fail(fmt::format("connect 127.0.0.1:{}: {}", port, std::strerror(errno)));
  // Send what the server takes; it may answer and close before reading all
  // of an oversized request, so a failed send is not an error here.
  size_t sent = 0;
  while (sent < request.size()) {
    const ssize_t n = ::send(fd, request.data() + sent, request.size() - sent, MSG_NOSIGNAL);
    if (n <= 0) break;
    sent += size_t(n);
  }
  std::string received;
  const auto deadline = Clock::now() + timeout;
  for (;;) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
    if (left.count() <= 0) {
      ::close(fd);
      return Fail(fmt::format("127.0.0.1:{}: no close within {} ms; received '{}'", port, timeout.count(), received));
    }
    pollfd p{fd, POLLIN, 0};
    if (::poll(&p, 1, int(left.count())) <= 0) continue;
    char buffer[8192];
    const ssize_t n = ::recv(fd, buffer, sizeof buffer, 0);
    if (n <= 0) break;  // closed (or reset after an oversized request: keep what came)
    received.append(buffer, size_t(n));
  }
  ::close(fd);
  return received;
}

Expected<HttpReply> ParseHttpReply(const std::string& raw) {
  const size_t end = raw.find("\r\n\r\n");
  if (end == std::string::npos) return Fail("no complete HTTP header in '" + raw + "'");
  HttpReply reply;
  reply.headers = raw.substr(0, end);
  reply.body = raw.substr(end + 4);
  if (raw.rfind("HTTP/1.1 ", 0) != 0 || raw.size() < 12) return Fail("not an HTTP/1.1 status line: '" + raw + "'");
  reply.status = std::atoi(raw.c_str() + 9);
  return reply;
}

Expected<HttpReply> HttpGet(uint16_t port, const std::string& path, std::chrono::milliseconds timeout) {
  auto raw = RawHttpExchange(
      port, fmt::format("GET {} HTTP/1.1\r\nHost: 127.0.0.1:{}\r\nConnection: close\r\n\r\n", path, port), timeout);
  if (!raw) return raw.error();
  return ParseHttpReply(*raw);
}

IdleConnection::IdleConnection(uint16_t port) : fd_(ConnectLoopback(port)) {}

IdleConnection::~IdleConnection() {
  if (fd_ >= 0) ::close(fd_);
}

bool IdleConnection::ClosedByPeer(std::chrono::milliseconds timeout) {
  if (fd_ < 0) return true;
  pollfd p{fd_, POLLIN, 0};
  if (::poll(&p, 1, int(timeout.count())) <= 0) return false;
  char c;
  return ::recv(fd_, &c, 1, 0) <= 0;
}

}  // namespace penumbra::testing

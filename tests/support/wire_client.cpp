#include "wire_client.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include <fmt/format.h>

#include "penumbra/common/messages.h"

namespace penumbra::testing {

using Clock = std::chrono::steady_clock;

Expected<WireClient> WireClient::Connect(const std::string& host, uint16_t port, std::chrono::milliseconds timeout) {
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  addrinfo* result = nullptr;
  if (int rc = getaddrinfo(host.c_str(), std::to_string(port).c_str(), &hints, &result); rc != 0)
    return Fail(fmt::format("resolve {}: {}", host, gai_strerror(rc)));
  const auto deadline = Clock::now() + timeout;
  std::string lastError = "no address";
  // Retry until the deadline: the server may still be starting.
  while (Clock::now() < deadline) {
    for (addrinfo* a = result; a != nullptr; a = a->ai_next) {
      const int fd = ::socket(a->ai_family, a->ai_socktype, a->ai_protocol);
      if (fd < 0) continue;
      if (::connect(fd, a->ai_addr, a->ai_addrlen) == 0) {
        freeaddrinfo(result);
        int one = 1;
        ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
        return WireClient(fd);
      }
      lastError = std::strerror(errno);
      ::close(fd);
    }
    ::usleep(20000);
  }
  freeaddrinfo(result);
  return Fail(fmt::format("connect {}:{}: {}", host, port, lastError));
}

WireClient::WireClient(WireClient&& other) noexcept
    : fd_(other.fd_), decoder_(std::move(other.decoder_)), bytesReceived_(other.bytesReceived_) {
  other.fd_ = -1;
}

WireClient& WireClient::operator=(WireClient&& other) noexcept {
  if (this != &other) {
    if (fd_ >= 0) ::close(fd_);
    fd_ = other.fd_;
    decoder_ = std::move(other.decoder_);
    bytesReceived_ = other.bytesReceived_;
    other.fd_ = -1;
  }
  return *this;
}

WireClient::~WireClient() {
  if (fd_ >= 0) ::close(fd_);
}

bool WireClient::SendRaw(std::string_view bytes) {
  size_t sent = 0;
  while (sent < bytes.size()) {
    const ssize_t n = ::send(fd_, bytes.data() + sent, bytes.size() - sent, MSG_NOSIGNAL);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    sent += size_t(n);
  }
  return true;
}

bool WireClient::Send(const wire::Envelope& envelope) { return SendRaw(EncodeEnvelopeFrame(envelope)); }

Expected<wire::Envelope> WireClient::Receive(std::chrono::milliseconds timeout, bool skipHeartbeats) {
  const auto deadline = Clock::now() + timeout;
  while (true) {
    auto next = decoder_.Next();
    if (!next) return next.error();
    if (next->has_value()) {
      auto envelope = DecodeEnvelope(**next);
      if (!envelope) return envelope.error();
      if (skipHeartbeats && envelope->has_heartbeat()) continue;
      return envelope;
    }
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
    if (left.count() <= 0) return Fail("timeout");
    pollfd p{fd_, POLLIN, 0};
    const int rc = ::poll(&p, 1, int(left.count()));
    if (rc < 0 && errno == EINTR) continue;
    if (rc == 0) return Fail("timeout");
    char buffer[65536];
    const ssize_t n = ::recv(fd_, buffer, sizeof buffer, 0);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return Fail("closed");
    bytesReceived_ += uint64_t(n);
    decoder_.Feed(buffer, size_t(n));
  }
}

bool WireClient::WaitClosed(std::chrono::milliseconds timeout) {
  const auto deadline = Clock::now() + timeout;
  while (Clock::now() < deadline) {
    auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
    auto r = Receive(left, /*skipHeartbeats=*/true);
    if (!r && r.error().message == "closed") return true;
    if (!r && r.error().message == "timeout") return false;
  }
  return false;
}

Expected<wire::Welcome> WireClient::Handshake(wire::Role role, uint64_t sceneHash, uint32_t version,
                                              const std::string& name) {
  if (!Send(MakeHello(role, name, sceneHash, {}, version == 0 ? kProtocolVersion : version)))
    return Fail("send hello failed");
  auto reply = Receive();
  if (!reply) return reply.error();
  if (reply->has_error())
    return Fail(fmt::format("{}: {}", wire::ErrorCode_Name(reply->error().code()), reply->error().message()));
  if (!reply->has_welcome()) return Fail(fmt::format("expected welcome, got {}", BodyName(*reply)));
  return reply->welcome();
}

Expected<double> WireClient::Counter(const std::string& name, std::chrono::milliseconds timeout) {
  static uint64_t nextId = 1000000;
  const uint64_t id = nextId++;
  wire::Envelope request;
  request.mutable_stats_request()->set_request_id(id);
  if (!Send(request)) return Fail("send stats request failed");
  const auto deadline = Clock::now() + timeout;
  while (Clock::now() < deadline) {
    auto reply = Receive(std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now()));
    if (!reply) return reply.error();
    if (!reply->has_stats_reply() || reply->stats_reply().request_id() != id) continue;  // other traffic
    for (const auto& c : reply->stats_reply().counters())
      if (c.name() == name) return c.value();
    return Fail(fmt::format("no counter named '{}'", name));
  }
  return Fail("timeout");
}

Expected<WireListener> WireListener::Listen(uint16_t port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  if (fd < 0) return Fail(fmt::format("socket: {}", std::strerror(errno)));
  int one = 1;
  ::setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  address.sin_port = htons(port);
  if (::bind(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) != 0 || ::listen(fd, 16) != 0) {
    const std::string error = std::strerror(errno);
    ::close(fd);
    return Fail(fmt::format("listen on 127.0.0.1:{}: {}", port, error));
  }
  socklen_t length = sizeof address;
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&address), &length);
  return WireListener(fd, ntohs(address.sin_port));
}

WireListener::WireListener(WireListener&& other) noexcept : fd_(other.fd_), port_(other.port_) { other.fd_ = -1; }

WireListener& WireListener::operator=(WireListener&& other) noexcept {
  if (this != &other) {
    if (fd_ >= 0) ::close(fd_);
    fd_ = other.fd_;
    port_ = other.port_;
    other.fd_ = -1;
  }
  return *this;
}

WireListener::~WireListener() {
  if (fd_ >= 0) ::close(fd_);
}

Expected<WireClient> WireListener::Accept(std::chrono::milliseconds timeout) {
  pollfd p{fd_, POLLIN, 0};
  int rc;
  do {
    rc = ::poll(&p, 1, int(timeout.count()));
  } while (rc < 0 && errno == EINTR);
  if (rc == 0) return Fail("timeout");
  if (rc < 0) return Fail(fmt::format("poll: {}", std::strerror(errno)));
  const int fd = ::accept(fd_, nullptr, nullptr);
  if (fd < 0) return Fail(fmt::format("accept: {}", std::strerror(errno)));
  int one = 1;
  ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
  return WireClient(fd);
}

}  // namespace penumbra::testing

#pragma once
// A blocking wire-protocol client over plain POSIX sockets, for tests. It
// deliberately shares no networking code with the servers under test (only
// the framing and the message definitions), so it checks them independently.

#include <chrono>
#include <cstdint>
#include <string>
#include <string_view>

#include "penumbra/common/expected.h"
#include "penumbra/common/framing.h"
#include "penumbra/wire.pb.h"

namespace penumbra::testing {

class WireClient {
 public:
  static Expected<WireClient> Connect(const std::string& host, uint16_t port,
                                      std::chrono::milliseconds timeout = std::chrono::seconds(5));
  WireClient(WireClient&& other) noexcept;
  WireClient& operator=(WireClient&& other) noexcept;
  WireClient(const WireClient&) = delete;
  WireClient& operator=(const WireClient&) = delete;
  ~WireClient();

  bool SendRaw(std::string_view bytes);
  bool Send(const wire::Envelope& envelope);

  /// The next envelope (heartbeats skipped unless asked for). Errors:
  /// "timeout" when nothing arrived in time, "closed" when the peer closed,
  /// or a decoding problem.
  Expected<wire::Envelope> Receive(std::chrono::milliseconds timeout = std::chrono::seconds(10),
                                   bool skipHeartbeats = true);

  /// Whether the peer closes the connection within `timeout` (frames that
  /// arrive meanwhile are discarded).
  bool WaitClosed(std::chrono::milliseconds timeout = std::chrono::seconds(5));

  /// Sends Hello and returns the Welcome (or the error the peer answered).
  Expected<wire::Welcome> Handshake(wire::Role role, uint64_t sceneHash, uint32_t version = 0,
                                    const std::string& name = "test-client");

  /// Bytes received on this connection so far.
  uint64_t BytesReceived() const { return bytesReceived_; }

  /// Sends a StatsRequest and returns the named counter's value.
  Expected<double> Counter(const std::string& name, std::chrono::milliseconds timeout = std::chrono::seconds(5));

 private:
  friend class WireListener;
  explicit WireClient(int fd) : fd_(fd), decoder_(1u << 30) {}
  int fd_ = -1;
  FrameDecoder decoder_;
  uint64_t bytesReceived_ = 0;
};

/// A listening socket on 127.0.0.1, for tests that play a server (a fake
/// SMA): each accepted connection is a WireClient.
class WireListener {
 public:
  /// Listens on `port` (0: any free port).
  static Expected<WireListener> Listen(uint16_t port = 0);
  WireListener(WireListener&& other) noexcept;
  WireListener& operator=(WireListener&& other) noexcept;
  WireListener(const WireListener&) = delete;
  WireListener& operator=(const WireListener&) = delete;
  ~WireListener();

  uint16_t Port() const { return port_; }
  /// The next connection; "timeout" when none arrives in time.
  Expected<WireClient> Accept(std::chrono::milliseconds timeout = std::chrono::seconds(10));

 private:
  WireListener(int fd, uint16_t port) : fd_(fd), port_(port) {}
  int fd_ = -1;
  uint16_t port_ = 0;
};

}  // namespace penumbra::testing

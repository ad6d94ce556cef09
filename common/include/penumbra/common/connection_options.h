#pragma once
// The limits and timers of one net::Connection (connection.h), apart from it
// so that a component can carry them in its own options without including
// the connection, and with it the generated protobuf code.

#include <chrono>
#include <cstddef>
#include <cstdint>

#include "penumbra/common/framing.h"

namespace penumbra::net {

struct ConnectionOptions {
  uint32_t maxFrameBytes = kDefaultMaxFrameBytes;  // larger incoming frames close the connection
  size_t maxQueuedBytes = size_t(64) << 20;        // Send() refuses beyond this
  std::chrono::milliseconds readTimeout{20000};    // silence longer than this closes
  std::chrono::milliseconds heartbeatInterval{5000};  // idle sender sends a Heartbeat
  /// For servers: a peer must complete its handshake (the owner calls
  /// MarkHandshakeDone) within this time, and until then frames larger than
  /// maxFrameBytesBeforeHandshake close the connection -- so that idle or
  /// trickling anonymous peers cost neither descriptors for long nor memory.
  /// 0: no such limit (connecting sides, whose peer they chose).
  std::chrono::milliseconds handshakeTimeout{0};
  uint32_t maxFrameBytesBeforeHandshake = 0;
};

}  // namespace penumbra::net

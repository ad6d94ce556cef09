#pragma once
// Length-prefixed framing, kept apart from sockets so it is tested with bytes.
//
// A frame is a 4-byte unsigned little-endian payload length followed by the
// payload (one serialized wire::Envelope). A length above the connection's
// limit is an error: the decoder refuses it before buffering the payload, so
// a peer cannot make us allocate more than the limit.

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "penumbra/common/expected.h"

namespace penumbra {

inline constexpr size_t kFrameHeaderBytes = 4;
inline constexpr uint32_t kDefaultMaxFrameBytes = 16u << 20;

/// Appends `payload` as one frame (header + bytes) to `out`.
void AppendFrame(std::string& out, std::string_view payload);
std::string EncodeFrame(std::string_view payload);

/// Incremental decoder: feed it whatever the socket delivered, then take
/// complete frames out. Not thread-safe; one per connection.
class FrameDecoder {
 public:
  explicit FrameDecoder(uint32_t maxFrameBytes = kDefaultMaxFrameBytes);

  /// Appends received bytes.
  void Feed(const void* data, size_t size);

  /// The next complete frame's payload, std::nullopt when more bytes are
  /// needed, or an Error when the stream is unusable (frame over the limit).
  /// The returned view stays valid until the next call to Feed or Next.
  /// After an error every later call returns the same error.
  Expected<std::optional<std::string_view>> Next();

  /// Bytes received but not yet returned as frames.
  size_t Buffered() const { return buffer_.size() - readPos_; }
  uint32_t MaxFrameBytes() const { return maxFrameBytes_; }
  /// Changes the limit for frames not yet begun (a handshake raises it).
  void SetMaxFrameBytes(uint32_t maxFrameBytes) { maxFrameBytes_ = maxFrameBytes; }

 private:
  uint32_t maxFrameBytes_;
  std::vector<char> buffer_;
  size_t readPos_ = 0;
  std::optional<Error> error_;
};

}  // namespace penumbra

#include "penumbra/common/framing.h"

#include <cstring>

#include <fmt/format.h>

namespace penumbra {

void AppendFrame(std::string& out, std::string_view payload) {
  const auto n = uint32_t(payload.size());
  const char header[kFrameHeaderBytes] = {char(n & 0xff), char((n >> 8) & 0xff),
                                          char((n >> 16) & 0xff), char((n >> 24) & 0xff)};
  out.append(header, kFrameHeaderBytes);
  out.append(payload);
}

std::string EncodeFrame(std::string_view payload) {
  std::string out;
  out.reserve(kFrameHeaderBytes + payload.size());
  AppendFrame(out, payload);
  return out;
}

FrameDecoder::FrameDecoder(uint32_t maxFrameBytes) : maxFrameBytes_(maxFrameBytes) {}

void FrameDecoder::Feed(const void* data, size_t size) {
  if (error_) return;
  // Compact once the consumed prefix dominates, so the buffer does not grow
  // without bound on a long-lived connection.
  if (readPos_ > 0 && readPos_ >= buffer_.size() / 2) {
    buffer_.erase(buffer_.begin(), buffer_.begin() + std::ptrdiff_t(readPos_));
    readPos_ = 0;
  }
  const auto* bytes = static_cast<const char*>(data);
  buffer_.insert(buffer_.end(), bytes, bytes + size);
}

Expected<std::optional<std::string_view>> FrameDecoder::Next() {
  if (error_) return *error_;
  const size_t available = buffer_.size() - readPos_;
  if (available < kFrameHeaderBytes) return std::optional<std::string_view>{};
  const auto* h = reinterpret_cast<const unsigned char*>(buffer_.data() + readPos_);
  const uint32_t length = uint32_t(h[0]) | (uint32_t(h[1]) << 8) | (uint32_t(h[2]) << 16) |
                          (uint32_t(h[3]) << 24);
  if (length > maxFrameBytes_) {
    error_ = Fail(fmt::format("frame of {} bytes exceeds the limit of {} bytes", length, maxFrameBytes_));
    return *error_;
  }
  if (available - kFrameHeaderBytes < length) return std::optional<std::string_view>{};
  std::string_view payload(buffer_.data() + readPos_ + kFrameHeaderBytes, length);
  readPos_ += kFrameHeaderBytes + length;
  return std::optional<std::string_view>{payload};
}

}  // namespace penumbra
